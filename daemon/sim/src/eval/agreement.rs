//! How often the knowledge base gives the synthetic ground truth's answer.
//!
//! The synthetic rooms' functional relations and affordances come from their own table
//! (`op3dsg_synthetic::truth`, authored from the benchmark's definitions, with rooms that differ
//! from the usual answer), not from the knowledge base. This module measures how far the two
//! agree: the ground-truth nodes of a room (labels, parents, boxes: perfect perception) go
//! through the profile's prior graph and the offline knowledge reasoner, and what comes out is
//! compared with the ground truth.
//!
//! - **Functional edges**: the ground truth's `(source, target, relation)` triplets and the
//!   knowledge base's; agreement = triplets in both / triplets in either (an edge the knowledge
//!   base adds that the room does not have, such as an empty outlet powering the kettle beside
//!   it, counts against it like one it misses).
//! - **Affordances**: per node that has affordances in either, whether the two sets are equal.
//!
//! Items that concern a drawn deviation ([`op3dsg_synthetic::Scene::deviations`]) are counted
//! apart as well, so a report shows agreement on the usual entries and on the unusual rooms.
//! These figures bound what the reasoner can reach with correct labels and parents: a
//! disagreement is recall the knowledge base alone cannot get, whatever perception does.

use std::collections::{BTreeMap, BTreeSet};

use op3dsg_drivers::graph_json::GraphJson;
use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind};
use op3dsg_runtime::config::Profile;
use op3dsg_runtime::embedding::SharedEmbedder;
use op3dsg_runtime::graph::{GraphEdge, GraphNode, SceneGraph};
use op3dsg_runtime::knowledge::fallback::FallbackCounts;
use op3dsg_runtime::pipeline::make_enricher;
use op3dsg_runtime::reasoner::ReasonerKind;
use op3dsg_runtime::world::OrientedBox;
use serde::Serialize;

/// Agreeing items out of all.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Share {
    /// Items where the knowledge base's answer equals the ground truth.
    pub agree: usize,
    /// Items.
    pub total: usize,
}

impl Share {
    /// Percent, `None` without items.
    pub fn percent(&self) -> Option<f64> {
        (self.total > 0).then(|| 100.0 * self.agree as f64 / self.total as f64)
    }

    fn count(&mut self, agrees: bool) {
        self.total += 1;
        self.agree += usize::from(agrees);
    }

    fn add(&mut self, other: &Share) {
        self.agree += other.agree;
        self.total += other.total;
    }
}

/// Agreement of the knowledge base with the ground truth (module docs).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Agreement {
    /// Functional triplets, all.
    pub functional: Share,
    /// Affordance sets, all nodes.
    pub affordance: Share,
    /// Functional triplets whose source is a deviation's instance.
    pub functional_deviations: Share,
    /// Affordance sets of deviations' instances.
    pub affordance_deviations: Share,
    /// Deviations drawn, by name.
    pub deviations: BTreeMap<String, usize>,
    /// Disagreements by kind and label (`functional light switch: ground truth none; knowledge
    /// base turn on or turn off -> ceiling light`), with counts.
    pub disagreements: BTreeMap<String, usize>,
}

impl Agreement {
    /// Adds another scene's figures.
    pub fn add(&mut self, other: &Agreement) {
        self.functional.add(&other.functional);
        self.affordance.add(&other.affordance);
        self.functional_deviations.add(&other.functional_deviations);
        self.affordance_deviations.add(&other.affordance_deviations);
        for (k, n) in &other.deviations {
            *self.deviations.entry(k.clone()).or_insert(0) += n;
        }
        for (k, n) in &other.disagreements {
            *self.disagreements.entry(k.clone()).or_insert(0) += n;
        }
    }
}

/// The knowledge base's answer on the ground truth's own nodes: `ground_truth`'s nodes (label,
/// kind, parent, box) and `part of` edges through `profile`'s prior graph and the offline
/// knowledge reasoner (whatever `reasoner.kind` the profile names), as graph JSON.
pub fn knowledge_answer(ground_truth: &GraphJson, profile: &Profile) -> Result<GraphJson, String> {
    Ok(knowledge_answer_with(ground_truth, profile, None, None)?.0)
}

/// [`knowledge_answer`] reasoning with `knowledge` instead of the profile's tables when given,
/// and `embedder` for the reasoner's nearest-category fallback; with the fallback's counts.
pub fn knowledge_answer_with(
    ground_truth: &GraphJson,
    profile: &Profile,
    knowledge: Option<std::sync::Arc<op3dsg_runtime::knowledge::KnowledgeBase>>,
    embedder: Option<SharedEmbedder>,
) -> Result<(GraphJson, FallbackCounts), String> {
    let mut profile = profile.clone();
    profile.reasoner.kind = ReasonerKind::Knowledge;
    let mut enricher = make_enricher(&profile)
        .map_err(|e| e.to_string())?
        .ok_or_else(|| "the profile builds no knowledge reasoner".to_owned())?;
    if let Some(knowledge) = knowledge {
        enricher = enricher.with_knowledge(knowledge);
    }
    if let Some(embedder) = embedder {
        enricher = enricher.with_label_embedder(embedder);
    }
    let part_of = op3dsg_ipc_types::relation_id("part of").map_or(0, |(_, id)| id);
    let mut nodes: Vec<GraphNode> = ground_truth
        .nodes
        .iter()
        .map(|n| GraphNode {
            id: n.id,
            kind: if n.kind == "part" { NodeKind::Part } else { NodeKind::Object },
            parent_id: n.parent,
            label: n.label.clone(),
            confidence: 1.0,
            centre_m: n.centre_m,
            box_min_m: n.box_min_m,
            box_max_m: n.box_max_m,
            obb: OrientedBox::axis_aligned(n.box_min_m, n.box_max_m, profile.world.up_axis),
            observation_count: profile.fusion.min_observations.max(1),
            affordance_bits: 0,
            last_seen_stamp_ns: 0,
            first_seen_stamp_ns: 0,
            missing: false,
            ..Default::default()
        })
        .collect();
    nodes.sort_by_key(|n| n.id);
    let edges = ground_truth
        .edges
        .iter()
        .filter(|e| e.kind == "spatial" && e.relation == "part of")
        .map(|e| GraphEdge {
            source_id: e.source,
            target_id: e.target,
            kind: EdgeKind::Spatial,
            relation_id: part_of,
            confidence: 1.0,
            origin: EdgeOrigin::Geometry,
        })
        .collect();
    let mut graph = SceneGraph { version: 1, stamp_ns: 0, nodes, edges };
    enricher.enrich(&mut graph);
    Ok((graph.to_json(&ground_truth.source), enricher.fallback_counts()))
}

fn label(graph: &GraphJson, id: u32) -> &str {
    graph.nodes.iter().find(|n| n.id == id).map_or("?", |n| n.label.as_str())
}

/// Measures the agreement of `profile`'s knowledge base with `ground_truth`; `deviations` are
/// the ids of the nodes a drawn deviation concerns, with the deviation's name.
pub fn measure(ground_truth: &GraphJson, deviations: &[(u32, &str)], profile: &Profile) -> Result<Agreement, String> {
    let answer = knowledge_answer(ground_truth, profile)?;
    Ok(compare(ground_truth, &answer, deviations))
}

/// Compares a ground truth with the knowledge base's answer on its nodes (module docs).
pub fn compare(ground_truth: &GraphJson, answer: &GraphJson, deviations: &[(u32, &str)]) -> Agreement {
    let mut agreement = Agreement::default();
    for (_, name) in deviations {
        *agreement.deviations.entry((*name).to_owned()).or_insert(0) += 1;
    }
    let is_deviation = |id: u32| deviations.iter().any(|(d, _)| *d == id);
    let triplets = |g: &GraphJson| -> BTreeSet<(u32, u32, String)> {
        g.edges.iter().filter(|e| e.kind == "functional").map(|e| (e.source, e.target, e.relation.clone())).collect()
    };
    let (truth, kb) = (triplets(ground_truth), triplets(answer));
    let describe = |set: &BTreeSet<(u32, u32, String)>, source: u32| -> String {
        let list: Vec<String> = set
            .iter()
            .filter(|(s, _, _)| *s == source)
            .map(|(_, t, r)| format!("{r} -> {}", label(ground_truth, *t)))
            .collect();
        if list.is_empty() { "none".to_owned() } else { list.join(", ") }
    };
    let mut reported = BTreeSet::new();
    for item in truth.union(&kb) {
        let agrees = truth.contains(item) && kb.contains(item);
        agreement.functional.count(agrees);
        if is_deviation(item.0) {
            agreement.functional_deviations.count(agrees);
        }
        if !agrees && reported.insert(item.0) {
            let key = format!(
                "functional {}: ground truth {}; knowledge base {}",
                label(ground_truth, item.0),
                describe(&truth, item.0),
                describe(&kb, item.0)
            );
            *agreement.disagreements.entry(key).or_insert(0) += 1;
        }
    }
    for node in &ground_truth.nodes {
        let truth: BTreeSet<&str> = node.affordances.iter().map(String::as_str).collect();
        let kb: BTreeSet<&str> = answer
            .nodes
            .iter()
            .find(|n| n.id == node.id)
            .map(|n| n.affordances.iter().map(String::as_str).collect())
            .unwrap_or_default();
        if truth.is_empty() && kb.is_empty() {
            continue;
        }
        let agrees = truth == kb;
        agreement.affordance.count(agrees);
        if is_deviation(node.id) {
            agreement.affordance_deviations.count(agrees);
        }
        if !agrees {
            let on = node.parent.map(|p| format!(" on {}", label(ground_truth, p))).unwrap_or_default();
            let set = |s: &BTreeSet<&str>| {
                if s.is_empty() { "none".to_owned() } else { s.iter().copied().collect::<Vec<_>>().join(" ") }
            };
            let key =
                format!("affordance {}{on}: ground truth {}; knowledge base {}", node.label, set(&truth), set(&kb));
            *agreement.disagreements.entry(key).or_insert(0) += 1;
        }
    }
    agreement
}

fn pct(share: &Share) -> String {
    share.percent().map_or_else(|| "-".to_owned(), |p| format!("{p:.1} %"))
}

/// The text block of a report.
pub fn text(agreement: &Agreement) -> String {
    use std::fmt::Write as _;
    let a = agreement;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "\nground truth vs knowledge base (every ground-truth node of the scenes, reasoner on ground-truth labels and \
         parents):"
    );
    let _ = writeln!(
        s,
        "  functional triplets agree {} of {} ({}); affordance sets agree {} of {} ({})",
        a.functional.agree,
        a.functional.total,
        pct(&a.functional),
        a.affordance.agree,
        a.affordance.total,
        pct(&a.affordance)
    );
    let drawn: Vec<String> = a.deviations.iter().map(|(k, n)| format!("{k} {n}")).collect();
    let _ = writeln!(
        s,
        "  rooms' deviations drawn: {}; on them functional {} of {} ({}), affordances {} of {} ({})",
        if drawn.is_empty() { "none".to_owned() } else { drawn.join(", ") },
        a.functional_deviations.agree,
        a.functional_deviations.total,
        pct(&a.functional_deviations),
        a.affordance_deviations.agree,
        a.affordance_deviations.total,
        pct(&a.affordance_deviations)
    );
    let mut v: Vec<(&String, &usize)> = a.disagreements.iter().collect();
    v.sort_by(|x, y| y.1.cmp(x.1).then(x.0.cmp(y.0)));
    for (k, n) in v.iter().take(12) {
        let _ = writeln!(s, "  {n:>4} x {k}");
    }
    if v.len() > 12 {
        let _ = writeln!(s, "  ... {} more kinds of disagreement (the JSON has all)", v.len() - 12);
    }
    s
}
