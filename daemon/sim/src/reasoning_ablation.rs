//! The paper's ablations of the reasoning stage, defined for the offline knowledge reasoner.
//!
//! The paper ablates its LLM agents; the knowledge reasoner is deterministic, so each ablation
//! is defined by the information or the division of labour it takes away, and applied to the
//! same fused nodes (identical node sets, as in the paper):
//!
//! - [`ReasoningSetup::FlatNodeList`] — "a flat list of node attributes instead of the prior
//!   graph". The reasoner gets each node's label, kind and centre only: no boxes, no fused
//!   object-part links, no neighbour structure. It must rebuild what the prior graph gives:
//!   a part's object is the nearest object centre within the neighbour radius among the
//!   objects whose category has that part in the knowledge base (else the nearest object);
//!   object relations come from centres alone (A `on` B, B `under` A when A's centre is
//!   10–80 cm higher and within 30 cm horizontally; `next to` when the centres are within
//!   30 cm vertically and 1 m horizontally). Functional relations and affordances then follow
//!   from these links as usual.
//! - [`ReasoningSetup::Single`] — "a single reasoner instead of the split". One reasoner with
//!   one context, the prior graph's neighbourhoods: without the remote agent's candidate
//!   selection, remote targets farther than the neighbour radius are out of reach (a wall
//!   switch and its ceiling light, a remote and its TV); without the affordance agent's
//!   conditioning on the connected object, a part's affordances come from its own label (the
//!   object its label names, else the part's defaults).
//! - [`ReasoningSetup::Split`] — the normal setup (`op3dsg_runtime::reasoner::GraphEnricher` as the
//!   daemon runs it).
//!
//! [`ReasoningSetup::variant`] turns a setup into the runtime's [`ReasoningVariant`], which the
//! benchmark hands its enricher ([`GraphEnricher::with_variant`]).

use std::sync::Arc;

use glam::Vec3;
use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind, relation_id};
use serde::{Deserialize, Serialize};

use op3dsg_runtime::graph::{GraphEdge, SceneGraph};
use op3dsg_runtime::knowledge::{KnowledgeBase, ObjectId};
use op3dsg_runtime::prior::{self, PriorConfig, PriorGraph};
use op3dsg_runtime::reasoner::{GraphEnricher, KnowledgeReasoner, Reasoner, ReasonerOutput, ReasoningVariant};

use crate::knowledge_variants::KnowledgeVariants;

/// How the reasoning stage is set up.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReasoningSetup {
    /// Prior graph, split reasoning (the method).
    #[default]
    Split,
    /// A flat node list instead of the prior graph.
    FlatNodeList,
    /// One reasoner instead of the split.
    Single,
}

impl ReasoningSetup {
    /// The runtime's variant of the reasoning stage for this setup (`None`: the method as the
    /// daemon runs it).
    pub fn variant(self) -> Option<Box<dyn ReasoningVariant>> {
        match self {
            Self::Split => None,
            Self::FlatNodeList => Some(Box::new(FlatNodeList)),
            Self::Single => Some(Box::new(SingleSplit)),
        }
    }

    /// `enricher` with the reasoning stage set up as `self`.
    pub fn apply(self, enricher: GraphEnricher) -> GraphEnricher {
        match self.variant() {
            Some(variant) => enricher.with_variant(variant),
            None => enricher,
        }
    }
}

/// [`ReasoningSetup::FlatNodeList`]: the reasoner gets the graph a flat node list lets it rebuild.
#[derive(Debug)]
struct FlatNodeList;

impl ReasoningVariant for FlatNodeList {
    fn prior(&self, graph: &mut SceneGraph, knowledge: &KnowledgeBase, config: &PriorConfig) -> Option<PriorGraph> {
        *graph = flat_node_list(graph, knowledge, config.neighbour_radius_m);
        let mut prior = prior::build(graph, knowledge, config);
        let part_of = relation_id("part of").map_or(0, |(_, id)| id);
        prior.spatial_edges.retain(|e| e.relation_id == part_of);
        let relations = flat_object_relations(&prior);
        prior.spatial_edges.extend(relations.iter().cloned());
        graph.edges.extend(relations);
        Some(prior)
    }
}

/// [`ReasoningSetup::Single`]: one reasoner instead of the split.
#[derive(Debug)]
struct SingleSplit;

impl ReasoningVariant for SingleSplit {
    fn reasoner(&self, knowledge: &Arc<KnowledgeBase>, config: &PriorConfig) -> Option<Box<dyn Reasoner>> {
        Some(Box::new(SingleReasoner::new(knowledge, config.neighbour_radius_m)))
    }
}

/// Vertical centre offset range of a centre-only `on`, metres.
const FLAT_ON_DZ_M: (f32, f32) = (0.1, 0.8);
/// Horizontal centre distance of a centre-only `on`, metres.
const FLAT_ON_DH_M: f32 = 0.3;
/// Vertical centre offset of a centre-only `next to`, metres.
const FLAT_NEXT_TO_DZ_M: f32 = 0.3;
/// Horizontal centre distance of a centre-only `next to`, metres.
const FLAT_NEXT_TO_DH_M: f32 = 1.0;

/// The knowledge reasoner as a single reasoner (see the module docs).
#[derive(Debug, Clone)]
pub struct SingleReasoner {
    inner: KnowledgeReasoner,
    knowledge: Arc<KnowledgeBase>,
}

impl SingleReasoner {
    /// A single reasoner over `knowledge` whose context is the neighbourhood of
    /// `neighbour_radius_m`.
    pub fn new(knowledge: &KnowledgeBase, neighbour_radius_m: f32) -> Self {
        let knowledge = Arc::new(knowledge.with_remote_reach(neighbour_radius_m));
        Self { inner: KnowledgeReasoner::new(knowledge.clone()), knowledge }
    }
}

impl Reasoner for SingleReasoner {
    fn name(&self) -> &'static str {
        "knowledge-single"
    }

    fn reason(&mut self, prior: &PriorGraph) -> ReasonerOutput {
        let mut output = self.inner.reason(prior);
        for affordances in &mut output.affordances {
            let Some(node) = prior.index_of(affordances.node_id).map(|i| &prior.nodes[i]) else { continue };
            let Some(resolved) = node.category else { continue };
            if let Some(part) = resolved.part() {
                affordances.affordance_bits = self.knowledge.part_affordances(part, resolved.object_hint);
            }
        }
        output.affordances.retain(|a| a.affordance_bits != 0);
        output
    }
}

/// The graph a flat node list lets the reasoner rebuild (see the module docs): parents and
/// `part of` edges from centres and knowledge, nothing else. Object relations come from
/// [`flat_object_relations`].
pub fn flat_node_list(graph: &SceneGraph, knowledge: &KnowledgeBase, neighbour_radius_m: f32) -> SceneGraph {
    let part_of = relation_id("part of").map_or(0, |(_, id)| id);
    let mut flat = graph.clone();
    flat.edges.clear();
    let objects: Vec<(u32, Vec3, Option<ObjectId>)> = graph
        .nodes
        .iter()
        .filter(|n| n.kind == NodeKind::Object)
        .map(|n| (n.id, Vec3::from(n.centre_m), knowledge.object_category(&n.label)))
        .collect();
    for node in &mut flat.nodes {
        node.parent_id = None;
        if node.kind != NodeKind::Part {
            continue;
        }
        let centre = Vec3::from(node.centre_m);
        let part = knowledge.resolve(&node.label).and_then(|r| r.part());
        let fits = |o: &Option<ObjectId>| match (part, o) {
            (Some(p), Some(o)) => knowledge.pair(p, *o).is_some(),
            _ => false,
        };
        let nearest = |only_fitting: bool| {
            objects
                .iter()
                .filter(|(_, c, o)| c.distance(centre) <= neighbour_radius_m && (!only_fitting || fits(o)))
                .min_by(|a, b| a.1.distance(centre).total_cmp(&b.1.distance(centre)))
                .map(|(id, _, _)| *id)
        };
        node.parent_id = nearest(true).or_else(|| nearest(false));
    }
    for node in &flat.nodes {
        if let Some(parent) = node.parent_id {
            flat.edges.push(GraphEdge {
                source_id: node.id,
                target_id: parent,
                kind: EdgeKind::Spatial,
                relation_id: part_of,
                confidence: node.confidence,
                origin: EdgeOrigin::Geometry,
            });
        }
    }
    flat
}

/// Object relations from centres alone (see the module docs), for neighbouring objects of
/// `prior` (z up).
pub fn flat_object_relations(prior: &PriorGraph) -> Vec<GraphEdge> {
    let mut edges = Vec::new();
    let id = |phrase: &str| relation_id(phrase).map_or(0, |(_, id)| id);
    for &(i, j) in &prior.neighbours {
        let (a, b) = (&prior.nodes[i as usize], &prior.nodes[j as usize]);
        if a.kind != NodeKind::Object || b.kind != NodeKind::Object {
            continue;
        }
        let d = a.centre_m - b.centre_m;
        let dh = d.truncate().length();
        let confidence = a.confidence.min(b.confidence);
        let edge = |source: u32, target: u32, phrase: &str| GraphEdge {
            source_id: source,
            target_id: target,
            kind: EdgeKind::Spatial,
            relation_id: id(phrase),
            confidence,
            origin: EdgeOrigin::Geometry,
        };
        if dh <= FLAT_ON_DH_M && (FLAT_ON_DZ_M.0..=FLAT_ON_DZ_M.1).contains(&d.z.abs()) {
            let (upper, lower) = if d.z > 0.0 { (a.id, b.id) } else { (b.id, a.id) };
            edges.push(edge(upper, lower, "on"));
            edges.push(edge(lower, upper, "under"));
        } else if d.z.abs() <= FLAT_NEXT_TO_DZ_M && dh <= FLAT_NEXT_TO_DH_M {
            edges.push(edge(a.id.min(b.id), a.id.max(b.id), "next to"));
        }
    }
    edges
}

#[cfg(test)]
mod tests {
    use op3dsg_runtime::graph::GraphNode;

    use super::*;

    fn node(id: u32, label: &str, kind: NodeKind, parent: Option<u32>, centre: [f32; 3], half: [f32; 3]) -> GraphNode {
        let c = Vec3::from(centre);
        let h = Vec3::from(half);
        GraphNode {
            id,
            kind,
            parent_id: parent,
            label: label.to_owned(),
            confidence: 1.0,
            centre_m: centre,
            box_min_m: (c - h).to_array(),
            box_max_m: (c + h).to_array(),
            obb: Default::default(),
            observation_count: 3,
            affordance_bits: 0,
            last_seen_stamp_ns: 0,
            first_seen_stamp_ns: 0,
            missing: false,
            ..Default::default()
        }
    }

    /// A wide cabinet whose handle sits at its right edge, next to a drawer stack: fusion's
    /// box-based parent is the cabinet; by centres alone the drawer is nearer.
    #[test]
    fn a_flat_list_loses_what_boxes_tell() {
        let kb = KnowledgeBase::builtin().unwrap();
        let graph = SceneGraph {
            version: 1,
            stamp_ns: 0,
            nodes: vec![
                node(1, "cabinet", NodeKind::Object, None, [0.6, 0.3, 0.45], [0.6, 0.3, 0.45]),
                node(2, "drawer", NodeKind::Object, None, [1.45, 0.3, 0.75], [0.25, 0.3, 0.15]),
                node(3, "cabinet handle", NodeKind::Part, Some(1), [1.15, 0.61, 0.75], [0.01, 0.01, 0.06]),
                node(4, "knob", NodeKind::Part, Some(1), [1.1, 0.61, 0.5], [0.015, 0.015, 0.015]),
            ],
            edges: Vec::new(),
        };
        let flat = flat_node_list(&graph, &kb, 1.0);
        let parent = |id: u32| flat.nodes.iter().find(|n| n.id == id).unwrap().parent_id;
        // Knobs fit both cabinets and drawers: the nearer centre wins, the drawer.
        assert_eq!(parent(4), Some(2));
        // The handle's label names no object the flat list trusts more than distance either.
        assert_eq!(parent(3), Some(2));
        assert_eq!(flat.edges.len(), 2);
        // Centre-only relations: the drawer's centre is 30 cm higher and 85 cm away: next to.
        let prior = prior::build(&flat, &kb, &PriorConfig::default());
        let relations = flat_object_relations(&prior);
        assert_eq!(relations.len(), 1);
        assert_eq!(op3dsg_ipc_types::relation_phrase(relations[0].relation_id), Some("next to"));
    }

    #[test]
    fn a_single_reasoner_reaches_only_its_neighbourhood() {
        let kb = Arc::new(KnowledgeBase::builtin().unwrap());
        let graph = SceneGraph {
            version: 1,
            stamp_ns: 0,
            nodes: vec![
                node(1, "tv", NodeKind::Object, None, [0.0, 0.0, 1.0], [0.5, 0.05, 0.3]),
                node(2, "remote control", NodeKind::Object, None, [0.0, 3.0, 0.45], [0.08, 0.03, 0.01]),
                node(3, "nightstand", NodeKind::Object, None, [3.0, 0.0, 0.3], [0.2, 0.2, 0.3]),
                node(4, "knob", NodeKind::Part, Some(3), [3.0, 0.22, 0.45], [0.015, 0.015, 0.015]),
            ],
            edges: Vec::new(),
        };
        let prior = prior::build(&graph, &kb, &PriorConfig::default());
        let split = KnowledgeReasoner::new(kb.clone()).reason(&prior);
        let single = SingleReasoner::new(&kb, 1.0).reason(&prior);
        let remote = |o: &ReasonerOutput| o.functional.iter().any(|f| f.source_id == 2 && f.target_id == 1);
        assert!(remote(&split), "{split:?}");
        assert!(!remote(&single), "{single:?}");
        // A knob on a nightstand: pinch_pull (conditioned on the nightstand) vs the knob's own
        // default (rotate).
        let bits = |o: &ReasonerOutput| o.affordances.iter().find(|a| a.node_id == 4).map(|a| a.affordance_bits);
        let names = |b: Option<u16>| op3dsg_ipc_types::affordance_names(b.unwrap_or(0)).collect::<Vec<_>>();
        assert_eq!(names(bits(&split)), ["pinch_pull"]);
        assert_eq!(names(bits(&single)), ["rotate"]);
    }
}
