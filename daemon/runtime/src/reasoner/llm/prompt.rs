//! Prompt construction: exactly one prompt per agent per refresh, built from one prior-graph
//! version (ids, labels, centres, box sizes, part-of structure), never one call per pair.
//!
//! - **local** lists every part-of pair (part and parent object, with geometry) and asks which
//!   canonical functional relation, if any, the part performs on its object;
//! - **remote** lists the remotable candidates: sources whose knowledge category has a remote
//!   template (remote control, switch, outlet, ...) and, per source, the objects of the
//!   template's target categories within its distance; the answer may only pick among those pairs;
//! - **affordances** lists every node with its box size and, for a part, its parent object, and
//!   asks for its affordances among the 9 canonical classes.
//!
//! Coordinates and sizes are metres rounded to centimetres. Where a list would exceed
//! `max_prompt_items`, the most confident items are kept (ties: lower id first).

use std::fmt::Write as _;

use glam::Vec3;
use op3dsg_ipc_types::{AFFORDANCES, FUNCTIONAL_RELATIONS, NodeKind};
use rustc_hash::FxHashSet;
use serde_json::{Value, json};

use crate::knowledge::KnowledgeBase;
use crate::prior::{PriorGraph, PriorNode};

/// The three agents.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Agent {
    /// Local functional relations over part-of pairs.
    Local,
    /// Remote functional relations over remotable candidates.
    Remote,
    /// Affordances per node.
    Affordances,
}

impl Agent {
    /// All agents, in a fixed order.
    pub const ALL: [Agent; 3] = [Agent::Local, Agent::Remote, Agent::Affordances];

    /// Name used in logs and in the schema name.
    pub fn name(self) -> &'static str {
        match self {
            Agent::Local => "local_relations",
            Agent::Remote => "remote_relations",
            Agent::Affordances => "affordances",
        }
    }
}

/// One prompt: a system and a user message, and the JSON schema its answer must follow.
#[derive(Debug, Clone, PartialEq)]
pub struct Prompt {
    /// Which agent.
    pub agent: Agent,
    /// System message: the task and the canonical labels.
    pub system: String,
    /// User message: the graph data as JSON.
    pub user: String,
    /// JSON schema of the answer.
    pub schema: Value,
}

/// The prompts of one refresh and what the gate needs to check their answers.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PromptSet {
    /// Graph version the prompts were built from.
    pub graph_version: u64,
    /// At most one prompt per agent (an agent with nothing to ask about gets none).
    pub prompts: Vec<Prompt>,
    /// Remote pairs `(source_id, target_id)` the remote agent may answer with.
    pub remote_candidates: FxHashSet<(u32, u32)>,
}

fn round_cm(v: Vec3) -> [f64; 3] {
    let r = |x: f32| (f64::from(x) * 100.0).round() / 100.0;
    [r(v.x), r(v.y), r(v.z)]
}

fn size_of(node: &PriorNode) -> Vec3 {
    (node.box_max_m - node.box_min_m).max(Vec3::ZERO)
}

fn node_json(node: &PriorNode) -> Value {
    json!({
        "id": node.id,
        "label": node.label,
        "centre_m": round_cm(node.centre_m),
        "size_m": round_cm(size_of(node)),
    })
}

/// Keeps the `max` most confident of `items` (ties: earlier first), in their original order.
fn keep_most_confident<T>(items: &mut Vec<(f32, T)>, max: usize) {
    if items.len() <= max {
        return;
    }
    let mut order: Vec<usize> = (0..items.len()).collect();
    order.sort_by(|&a, &b| items[b].0.total_cmp(&items[a].0).then(a.cmp(&b)));
    let mut keep = vec![false; items.len()];
    for &i in &order[..max] {
        keep[i] = true;
    }
    let mut i = 0;
    items.retain(|_| {
        i += 1;
        keep[i - 1]
    });
}

fn quoted_list(items: &[&str]) -> String {
    let mut s = String::new();
    for (i, item) in items.iter().enumerate() {
        let _ = write!(s, "{}\"{item}\"", if i == 0 { "" } else { ", " });
    }
    s
}

const COMMON: &str = "You annotate a 3D scene graph built by a robot. Coordinates are metres in the world frame \
(centre_m: box centre, size_m: axis-aligned box extents). Use only the node ids given. Answer with one JSON object \
following the schema, nothing else. Give a confidence in [0, 1] per item. Leave out anything you are unsure of.";

fn relation_schema(name: &str, source: &str, target: &str) -> Value {
    json!({
        "type": "object",
        "additionalProperties": false,
        "required": ["relations"],
        "properties": {
            "relations": {
                "type": "array",
                "items": {
                    "type": "object",
                    "additionalProperties": false,
                    "required": [source, target, "relation", "confidence"],
                    "properties": {
                        source: {"type": "integer"},
                        target: {"type": "integer"},
                        "relation": {"type": "string", "enum": FUNCTIONAL_RELATIONS},
                        "confidence": {"type": "number"}
                    }
                }
            }
        },
        "title": name
    })
}

fn affordance_schema() -> Value {
    json!({
        "type": "object",
        "additionalProperties": false,
        "required": ["affordances"],
        "properties": {
            "affordances": {
                "type": "array",
                "items": {
                    "type": "object",
                    "additionalProperties": false,
                    "required": ["node_id", "affordances", "confidence"],
                    "properties": {
                        "node_id": {"type": "integer"},
                        "affordances": {"type": "array", "items": {"type": "string", "enum": AFFORDANCES}},
                        "confidence": {"type": "number"}
                    }
                }
            }
        },
        "title": "affordances"
    })
}

/// Builds the prompts of one refresh from `prior`.
pub fn build(prior: &PriorGraph, knowledge: &KnowledgeBase, max_items: usize) -> PromptSet {
    let mut set = PromptSet { graph_version: prior.version, ..PromptSet::default() };
    set.prompts.extend(local_prompt(prior, max_items));
    set.prompts.extend(remote_prompt(prior, knowledge, max_items, &mut set.remote_candidates));
    set.prompts.extend(affordance_prompt(prior, max_items));
    set
}

/// The node of `id` in `prior`.
fn node_of(prior: &PriorGraph, id: u32) -> Option<&PriorNode> {
    prior.index_of(id).map(|i| &prior.nodes[i])
}

/// The local agent's prompt: part-of pairs (none without one).
fn local_prompt(prior: &PriorGraph, max_items: usize) -> Option<Prompt> {
    let node = |id: u32| node_of(prior, id);
    let mut pairs: Vec<(f32, Value)> = Vec::new();
    for part in prior.nodes.iter().filter(|n| n.kind == NodeKind::Part) {
        let Some(parent) = part.parent_id.and_then(node) else { continue };
        pairs.push((
            part.confidence.min(parent.confidence),
            json!({"part": node_json(part), "object": node_json(parent)}),
        ));
    }
    keep_most_confident(&mut pairs, max_items);
    if pairs.is_empty() {
        return None;
    }
    let system = format!(
        "{COMMON}\nTask: for each part-of pair below, say which functional relation the part performs on its \
         object, choosing exactly one of: {}. Answer as {{\"relations\": [{{\"part_id\", \"object_id\", \
         \"relation\", \"confidence\"}}]}}; leave out pairs without such a relation.",
        quoted_list(&FUNCTIONAL_RELATIONS)
    );
    let user =
        json!({"graph_version": prior.version, "part_of_pairs": pairs.into_iter().map(|(_, v)| v).collect::<Vec<_>>()});
    Some(Prompt {
        agent: Agent::Local,
        system,
        user: user.to_string(),
        schema: relation_schema("local_relations", "part_id", "object_id"),
    })
}

/// The remote agent's prompt: sources with a remote template and their candidate targets, each
/// pair offered added to `offered` (none without one).
fn remote_prompt(
    prior: &PriorGraph,
    knowledge: &KnowledgeBase,
    max_items: usize,
    offered: &mut FxHashSet<(u32, u32)>,
) -> Option<Prompt> {
    let node = |id: u32| node_of(prior, id);
    let mut candidates: Vec<(f32, Value)> = Vec::new();
    for source in &prior.nodes {
        let Some(resolved) = source.category else { continue };
        let mut targets: Vec<(f32, u32)> = Vec::new();
        for template in knowledge.remote_templates_for(resolved.category) {
            for target in prior.nodes.iter().filter(|n| n.kind == NodeKind::Object && n.id != source.id) {
                if Some(target.id) == source.parent_id {
                    continue;
                }
                let Some(object) = target.category.and_then(|c| c.object()) else { continue };
                let distance = source.centre_m.distance(target.centre_m);
                if template.targets.contains(&object) && distance <= template.max_distance_m {
                    targets.push((distance, target.id));
                }
            }
        }
        targets.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        targets.dedup_by_key(|t| t.1);
        if targets.is_empty() {
            continue;
        }
        let listed: Vec<Value> = targets
            .iter()
            .filter_map(|&(distance, id)| {
                let target = node(id)?;
                let mut v = node_json(target);
                v["distance_m"] = json!((f64::from(distance) * 100.0).round() / 100.0);
                Some(v)
            })
            .collect();
        candidates.push((source.confidence, json!({"source": node_json(source), "candidate_targets": listed})));
        for (_, id) in targets {
            offered.insert((source.id, id));
        }
    }
    keep_most_confident(&mut candidates, max_items);
    // Pairs of sources that were cut are no longer allowed.
    let kept: FxHashSet<u64> = candidates.iter().filter_map(|(_, v)| v["source"]["id"].as_u64()).collect();
    offered.retain(|(s, _)| kept.contains(&u64::from(*s)));
    if candidates.is_empty() {
        return None;
    }
    let system = format!(
        "{COMMON}\nTask: each source below can act on an object at a distance (a remote control on a TV, a \
         switch on a light, an outlet powering an appliance, ...). For each source pick the target among its \
         candidate_targets that it acts on, if any, and the functional relation, exactly one of: {}. Answer as \
         {{\"relations\": [{{\"source_id\", \"target_id\", \"relation\", \"confidence\"}}]}}.",
        quoted_list(&FUNCTIONAL_RELATIONS)
    );
    let user =
        json!({"graph_version": prior.version, "sources": candidates.into_iter().map(|(_, v)| v).collect::<Vec<_>>()});
    Some(Prompt {
        agent: Agent::Remote,
        system,
        user: user.to_string(),
        schema: relation_schema("remote_relations", "source_id", "target_id"),
    })
}

/// The affordance agent's prompt: every node, a part with its parent object (none without
/// nodes).
fn affordance_prompt(prior: &PriorGraph, max_items: usize) -> Option<Prompt> {
    let node = |id: u32| node_of(prior, id);
    let mut nodes: Vec<(f32, Value)> = Vec::new();
    for n in &prior.nodes {
        let mut v = node_json(n);
        v["kind"] = json!(if n.kind == NodeKind::Part { "part" } else { "object" });
        if let Some(parent) = n.parent_id.and_then(node) {
            v["parent"] = json!({"id": parent.id, "label": parent.label, "size_m": round_cm(size_of(parent))});
        }
        nodes.push((n.confidence, v));
    }
    keep_most_confident(&mut nodes, max_items);
    if nodes.is_empty() {
        return None;
    }
    let system = format!(
        "{COMMON}\nTask: for each node below, list how a robot hand would interact with it, using only these \
         affordance classes: {}. Consider the parent object and the box size (a handle on a cabinet door is \
         pulled, a knob on a stove is rotated). Answer as {{\"affordances\": [{{\"node_id\", \"affordances\", \
         \"confidence\"}}]}}; leave out nodes without any.",
        quoted_list(&AFFORDANCES)
    );
    let user = json!({"graph_version": prior.version, "nodes": nodes.into_iter().map(|(_, v)| v).collect::<Vec<_>>()});
    Some(Prompt { agent: Agent::Affordances, system, user: user.to_string(), schema: affordance_schema() })
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::graph::{GraphNode, SceneGraph};
    use crate::prior::{self, PriorConfig};

    fn node(id: u32, label: &str, kind: NodeKind, parent: Option<u32>, min: [f32; 3], max: [f32; 3]) -> GraphNode {
        let centre = (Vec3::from(min) + Vec3::from(max)) * 0.5;
        GraphNode {
            id,
            kind,
            parent_id: parent,
            label: label.to_owned(),
            confidence: 0.9,
            centre_m: centre.to_array(),
            box_min_m: min,
            box_max_m: max,
            obb: Default::default(),
            observation_count: 5,
            affordance_bits: 0,
            last_seen_stamp_ns: 0,
            first_seen_stamp_ns: 0,
            missing: false,
            ..Default::default()
        }
    }

    /// A small kitchen corner: a cabinet with a handle, a stove with a knob, a TV, a remote,
    /// and a far-away TV the remote cannot reach.
    pub(crate) fn corner() -> SceneGraph {
        SceneGraph {
            version: 12,
            stamp_ns: 0,
            nodes: vec![
                node(1, "cabinet", NodeKind::Object, None, [0.0, 0.0, 0.0], [0.6, 0.6, 0.9]),
                node(2, "stove", NodeKind::Object, None, [1.0, 0.0, 0.0], [1.6, 0.6, 0.9]),
                node(3, "tv", NodeKind::Object, None, [3.0, 2.0, 1.0], [4.0, 2.1, 1.6]),
                node(4, "remote control", NodeKind::Object, None, [3.2, 0.5, 0.5], [3.35, 0.55, 0.53]),
                node(5, "cabinet handle", NodeKind::Part, Some(1), [0.3, -0.03, 0.5], [0.4, 0.0, 0.52]),
                node(6, "stove knob", NodeKind::Part, Some(2), [1.2, -0.03, 0.8], [1.24, 0.0, 0.84]),
                node(7, "tv", NodeKind::Object, None, [40.0, 40.0, 1.0], [41.0, 40.1, 1.6]),
            ],
            edges: Vec::new(),
        }
    }

    pub(crate) fn corner_prior() -> (PriorGraph, KnowledgeBase) {
        let kb = KnowledgeBase::builtin().unwrap();
        let prior = prior::build(&corner(), &kb, &PriorConfig::default());
        (prior, kb)
    }

    #[test]
    fn one_prompt_per_agent_with_ids_labels_and_geometry() {
        let (prior, kb) = corner_prior();
        let set = build(&prior, &kb, 400);
        assert_eq!(set.graph_version, 12);
        let agents: Vec<Agent> = set.prompts.iter().map(|p| p.agent).collect();
        assert_eq!(agents, Agent::ALL, "exactly one prompt per agent");

        let local: Value = serde_json::from_str(&set.prompts[0].user).unwrap();
        let pairs = local["part_of_pairs"].as_array().unwrap();
        assert_eq!(pairs.len(), 2, "one entry per part-of pair, all in one prompt");
        assert_eq!(pairs[0]["part"]["id"], 5);
        assert_eq!(pairs[0]["part"]["label"], "cabinet handle");
        assert_eq!(pairs[0]["object"]["id"], 1);
        assert_eq!(pairs[0]["object"]["label"], "cabinet");
        assert_eq!(pairs[0]["object"]["centre_m"], json!([0.3, 0.3, 0.45]));
        assert_eq!(pairs[0]["object"]["size_m"], json!([0.6, 0.6, 0.9]));
        assert_eq!(pairs[1]["part"]["label"], "stove knob");
        assert!(set.prompts[0].system.contains("\"pull to open or close\""));

        let remote: Value = serde_json::from_str(&set.prompts[1].user).unwrap();
        let sources = remote["sources"].as_array().unwrap();
        assert_eq!(sources.len(), 1, "{sources:?}");
        assert_eq!(sources[0]["source"]["label"], "remote control");
        let targets: Vec<u64> =
            sources[0]["candidate_targets"].as_array().unwrap().iter().map(|t| t["id"].as_u64().unwrap()).collect();
        assert_eq!(targets, [3], "the far TV is no candidate");
        assert!(set.remote_candidates.contains(&(4, 3)) && !set.remote_candidates.contains(&(4, 7)));

        let affordances: Value = serde_json::from_str(&set.prompts[2].user).unwrap();
        let nodes = affordances["nodes"].as_array().unwrap();
        assert_eq!(nodes.len(), 7);
        let knob = nodes.iter().find(|n| n["id"] == 6).unwrap();
        assert_eq!(knob["kind"], "part");
        assert_eq!(knob["parent"]["label"], "stove");
        assert_eq!(knob["size_m"], json!([0.04, 0.03, 0.04]));
        assert!(set.prompts[2].system.contains("\"hook_pull\""));
    }

    #[test]
    fn prompt_size_is_capped_by_confidence() {
        let (mut prior, kb) = corner_prior();
        prior.nodes[6].confidence = 0.1; // the far TV
        let set = build(&prior, &kb, 6);
        let affordances: Value = serde_json::from_str(&set.prompts[2].user).unwrap();
        let ids: Vec<u64> =
            affordances["nodes"].as_array().unwrap().iter().map(|n| n["id"].as_u64().unwrap()).collect();
        assert_eq!(ids, [1, 2, 3, 4, 5, 6]);
    }

    #[test]
    fn an_empty_graph_needs_no_call() {
        let kb = KnowledgeBase::builtin().unwrap();
        let set = build(&PriorGraph::default(), &kb, 400);
        assert!(set.prompts.is_empty());
    }
}
