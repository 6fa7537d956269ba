//! The offline knowledge reasoner: deterministic, no network, the default.
//!
//! For a prior graph it concludes:
//!
//! - **Affordances** per node. An object gets its category's own affordances (a remote control:
//!   `key_press`). A part gets the affordances of its object-part pair, conditioned on the
//!   parent's category (a knob on a cabinet: `rotate`, `pinch_pull`; on a drawer:
//!   `pinch_pull`); without a parent, or when the parent's category lacks that part, the
//!   category named in the part's own label ("drawer knob" → drawer), else the part's defaults.
//!   Confidence: the node's.
//! - **Local relations** on part-of pairs: the template of the pair (part category, parent
//!   category), part → parent, confidence [`LOCAL_CONFIDENCE`] × the part's confidence. When the
//!   parent's category has no such pair but the part's label names an object category that does
//!   ("oven handle" fused onto a "stove"), that template is used towards the parent with
//!   [`HINTED_LOCAL_CONFIDENCE`].
//! - **Remote relations** for nodes without a local relation (a wall switch, a wall outlet, a
//!   power strip's outlets, a remote control, a loose knob): for each remote template of the
//!   node's category, among the objects (centre to centre within the template's
//!   `max_distance_m`, not the node itself nor its own parent) whose category is one of the
//!   template's targets: with `choose = "nearest"` (default) the nearest, ties to the earlier
//!   listed target; with `choose = "listed_order"` the nearest of the earliest listed category
//!   present (a remote control picks the TV over the game console beside it). Nearest within a
//!   distance stands in for "in the same room", which the graph does not know yet.
//!   Confidence: the template's × the source node's.
//! - **Labels the tables do not know** ([`super::fallback`]): a node whose label resolves to
//!   nothing takes its nearest known category by text embedding (with an embedder), and a known
//!   part on a parent of unknown category gets the part-label rule (what that part does on most
//!   objects of the tables); both are counted in [`ReasonerOutput::fallback`].
//! - **Spatial corrections**: none (geometry decides spatial relations; LLM agents may
//!   propose corrections later).
//!
//! Remote search is a scan over the objects per source node: sources are few (switches,
//! outlets, remotes) and the distances (up to 10 m) are far beyond the neighbour radius.

use std::sync::Arc;

use op3dsg_ipc_types::NodeKind;

use super::{FunctionalRelation, NodeAffordances, Reasoner, ReasonerOutput};
use crate::embedding::SharedEmbedder;
use crate::knowledge::fallback::{EMBEDDING_CONFIDENCE, FallbackCounts, LabelFallback, RULE_CONFIDENCE};
use crate::knowledge::{Category, KnowledgeBase, ObjectId, PartId, Resolved, TargetChoice};
use crate::prior::{PriorGraph, PriorNode};

/// Confidence factor of a local relation from the parent's own pair.
pub const LOCAL_CONFIDENCE: f32 = 0.9;
/// Confidence factor of a local relation taken from the object named in the part's label.
pub const HINTED_LOCAL_CONFIDENCE: f32 = 0.6;

/// The offline knowledge reasoner.
#[derive(Debug, Clone)]
pub struct KnowledgeReasoner {
    knowledge: Arc<KnowledgeBase>,
    fallback: LabelFallback,
}

/// A node's category as the reasoner uses it: from the tables, or found by the embedding
/// fallback (with its confidence factor).
#[derive(Debug, Clone, Copy)]
struct Effective {
    resolved: Resolved,
    factor: f32,
}

impl KnowledgeReasoner {
    /// A reasoner over `knowledge`, with the part-label rule for unknown parents and no
    /// embedding fallback.
    pub fn new(knowledge: Arc<KnowledgeBase>) -> Self {
        Self::with_embedder(knowledge, None)
    }

    /// A reasoner over `knowledge` whose labels the tables do not know fall back as
    /// [`super::fallback`] says; `embedder` enables the nearest-category fallback.
    pub fn with_embedder(knowledge: Arc<KnowledgeBase>, embedder: Option<SharedEmbedder>) -> Self {
        let fallback = LabelFallback::new(&knowledge, embedder);
        Self { knowledge, fallback }
    }

    /// Every prior node's category: the resolved one, else the nearest by embedding.
    fn effective(&mut self, prior: &PriorGraph, counts: &mut FallbackCounts) -> Vec<Option<Effective>> {
        prior
            .nodes
            .iter()
            .map(|node| {
                if let Some(resolved) = node.category {
                    // The prior graph's builder may have used the embedding fallback already.
                    if node.by_embedding {
                        counts.by_embedding += 1;
                        return Some(Effective { resolved, factor: EMBEDDING_CONFIDENCE });
                    }
                    return Some(Effective { resolved, factor: 1.0 });
                }
                match self.fallback.nearest(&node.label, node.kind == NodeKind::Object) {
                    Some((category, _)) => {
                        counts.by_embedding += 1;
                        Some(Effective {
                            resolved: Resolved { category, object_hint: None },
                            factor: EMBEDDING_CONFIDENCE,
                        })
                    }
                    None => {
                        counts.unresolved += 1;
                        None
                    }
                }
            })
            .collect()
    }
}

impl Reasoner for KnowledgeReasoner {
    fn name(&self) -> &'static str {
        "knowledge"
    }

    fn reason(&mut self, prior: &PriorGraph) -> ReasonerOutput {
        let mut output = ReasonerOutput { graph_version: prior.version, ..ReasonerOutput::default() };
        let mut counts = FallbackCounts::default();
        let effective = self.effective(prior, &mut counts);
        let graph = Effectives { prior, effective: &effective };
        for (index, node) in prior.nodes.iter().enumerate() {
            let Some(Effective { resolved, factor }) = effective[index] else { continue };
            let has_local = match resolved.category {
                Category::Object(object) => {
                    let bits = self.knowledge.object(object).affordance_bits;
                    if bits != 0 {
                        output.affordances.push(NodeAffordances {
                            node_id: node.id,
                            affordance_bits: bits,
                            confidence: factor * node.confidence,
                        });
                    }
                    false
                }
                Category::Part(part) => {
                    self.reason_about_part(part, node, Effective { resolved, factor }, &graph, &mut output, &mut counts)
                }
            };
            if !has_local {
                remote_relations(&self.knowledge, node, Effective { resolved, factor }, &graph, &mut output);
            }
        }
        output.fallback = counts;
        output
    }
}

/// The prior graph's nodes with their categories as the reasoner uses them.
struct Effectives<'a> {
    prior: &'a PriorGraph,
    effective: &'a [Option<Effective>],
}

impl Effectives<'_> {
    /// The object category of node `i` and its confidence factor, if it is an object the
    /// reasoner knows.
    fn object_of(&self, i: usize) -> Option<(ObjectId, f32)> {
        self.effective[i].and_then(|e| e.resolved.object().map(|o| (o, e.factor)))
    }
}

impl KnowledgeReasoner {
    /// A part's affordances and its local relation to its object (the parent, the category its
    /// own label names, or by the fallbacks); whether it got a local relation.
    fn reason_about_part(
        &mut self,
        part: PartId,
        node: &PriorNode,
        Effective { resolved, factor }: Effective,
        graph: &Effectives<'_>,
        output: &mut ReasonerOutput,
        counts: &mut FallbackCounts,
    ) -> bool {
        let kb = &*self.knowledge;
        let mut has_local = false;
        let parent_index = node.parent_id.and_then(|id| graph.prior.index_of(id));
        let parent = parent_index.and_then(|i| graph.object_of(i));
        let (parent, parent_factor) = (parent.map(|(p, _)| p), parent.map_or(1.0, |(_, f)| f));
        let mut conditioned_on = parent
            .filter(|p| kb.pair(part, *p).is_some())
            .or(resolved.object_hint.filter(|h| kb.pair(part, *h).is_some()));
        let unknown_parent =
            parent_index.filter(|i| graph.effective[*i].is_none_or(|e| e.factor < 1.0)).map(|i| &graph.prior.nodes[i]);
        // A parent of unknown category: the nearest known category that has this part.
        let mut parent = parent;
        let mut parent_factor = parent_factor;
        if let (None, Some(p)) = (conditioned_on, unknown_parent) {
            let has_part = |o| kb.pair(part, o).is_some();
            if let Some((nearest, _)) = self.fallback.nearest_object_where(&p.label, &has_part) {
                counts.parts_by_embedding += 1;
                conditioned_on = Some(nearest);
                parent = Some(nearest);
                parent_factor = EMBEDDING_CONFIDENCE;
            }
        }
        // The part-label rule: a known part on a parent whose category is unknown,
        // or whose nearest category has no such part.
        let by_rule = conditioned_on.is_none() && unknown_parent.is_some();
        let rule = by_rule.then(|| self.fallback.rule(part));
        let bits = match rule {
            Some(rule) => rule.affordance_bits,
            None => kb.part_affordances(part, conditioned_on),
        };
        let base = factor * if rule.is_some() { RULE_CONFIDENCE } else { parent_factor };
        if bits != 0 {
            output.affordances.push(NodeAffordances {
                node_id: node.id,
                affordance_bits: bits,
                confidence: base * node.confidence,
            });
        }
        if let Some(parent_id) = node.parent_id {
            let local = match (parent, rule) {
                (_, Some(rule)) => rule.relation_id.map(|r| (r, LOCAL_CONFIDENCE)),
                (Some(parent), None) => kb.local_relation(part, parent).map(|r| (r, LOCAL_CONFIDENCE)).or_else(|| {
                    let hint = resolved.object_hint.filter(|_| kb.pair(part, parent).is_none())?;
                    kb.local_relation(part, hint).map(|r| (r, HINTED_LOCAL_CONFIDENCE))
                }),
                // An unknown parent: the object the part's own label names ("oven
                // handle"), if the tables have that pair.
                (None, None) => resolved
                    .object_hint
                    .and_then(|hint| kb.local_relation(part, hint))
                    .map(|r| (r, HINTED_LOCAL_CONFIDENCE)),
            };
            if let Some((relation_id, local_factor)) = local {
                has_local = true;
                output.functional.push(FunctionalRelation {
                    source_id: node.id,
                    target_id: parent_id,
                    relation_id,
                    confidence: local_factor * base * node.confidence,
                    remote: false,
                });
            }
        }
        if rule.is_some() && (has_local || bits != 0) {
            counts.by_part_rule += 1;
        }
        has_local
    }
}

/// A node's remote relations: for each template of its category, the best target object
/// within reach.
fn remote_relations(
    kb: &KnowledgeBase,
    node: &PriorNode,
    Effective { resolved, factor }: Effective,
    graph: &Effectives<'_>,
    output: &mut ReasonerOutput,
) {
    for template in kb.remote_templates_for(resolved.category) {
        let mut best: Option<(f32, usize, u32, f32)> = None;
        for (candidate_index, candidate) in graph.prior.nodes.iter().enumerate() {
            if candidate.kind != NodeKind::Object || candidate.id == node.id || Some(candidate.id) == node.parent_id {
                continue;
            }
            let Some((target, target_factor)) = graph.object_of(candidate_index) else { continue };
            let Some(rank) = template.targets.iter().position(|t| *t == target) else { continue };
            let distance = node.centre_m.distance(candidate.centre_m);
            if distance.is_nan() || distance > template.max_distance_m {
                continue;
            }
            let better = best.is_none_or(|(d, r, _, _)| match template.choose {
                TargetChoice::Nearest => (distance, rank) < (d, r),
                TargetChoice::ListedOrder => (rank, distance) < (r, d),
            });
            if better {
                best = Some((distance, rank, candidate.id, target_factor));
            }
        }
        if let Some((_, _, target_id, target_factor)) = best {
            output.functional.push(FunctionalRelation {
                source_id: node.id,
                target_id,
                relation_id: template.relation_id,
                confidence: template.confidence * factor * target_factor * node.confidence,
                remote: true,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use glam::Vec3;
    use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, affordance_names, relation_phrase};

    use super::*;
    use crate::graph::{GraphEdge, GraphNode, SceneGraph};
    use crate::prior::{self, PriorConfig};

    fn node(id: u32, label: &str, parent: Option<u32>, centre: [f32; 3], half: f32) -> GraphNode {
        let c = Vec3::from(centre);
        GraphNode {
            id,
            kind: if label_is_part(label) { NodeKind::Part } else { NodeKind::Object },
            parent_id: parent,
            label: label.to_owned(),
            confidence: 1.0,
            centre_m: centre,
            box_min_m: (c - half).to_array(),
            box_max_m: (c + half).to_array(),
            obb: Default::default(),
            observation_count: 3,
            affordance_bits: 0,
            last_seen_stamp_ns: 0,
            first_seen_stamp_ns: 0,
            missing: false,
            ..Default::default()
        }
    }

    fn label_is_part(label: &str) -> bool {
        let kb = KnowledgeBase::builtin().unwrap();
        kb.resolve(label).and_then(|r| r.part()).is_some()
    }

    fn graph(nodes: Vec<GraphNode>) -> SceneGraph {
        let edges = nodes
            .iter()
            .filter_map(|n| n.parent_id.map(|p| (n.id, p)))
            .map(|(source_id, target_id)| GraphEdge {
                source_id,
                target_id,
                kind: EdgeKind::Spatial,
                relation_id: 0,
                confidence: 1.0,
                origin: EdgeOrigin::Geometry,
            })
            .collect();
        SceneGraph { version: 1, stamp_ns: 0, nodes, edges }
    }

    /// `(source, target, phrase, remote)` and `(node, affordances)` of the reasoner's output.
    #[allow(clippy::type_complexity)]
    fn run(g: &SceneGraph) -> (Vec<(u32, u32, &'static str, bool)>, Vec<(u32, Vec<&'static str>)>) {
        let kb = Arc::new(KnowledgeBase::builtin().unwrap());
        let prior = prior::build(g, &kb, &PriorConfig::default());
        let output = KnowledgeReasoner::new(kb).reason(&prior);
        assert_eq!(output.graph_version, g.version);
        let relations = output
            .functional
            .iter()
            .map(|r| (r.source_id, r.target_id, relation_phrase(r.relation_id).unwrap_or("?"), r.remote))
            .collect();
        let affordances =
            output.affordances.iter().map(|a| (a.node_id, affordance_names(a.affordance_bits).collect())).collect();
        (relations, affordances)
    }

    #[test]
    fn parts_of_an_unknown_object_follow_the_part_label_rule() {
        let kb = Arc::new(KnowledgeBase::builtin().unwrap());
        // A piece of furniture no table lists.
        let mut g = graph(vec![
            node(1, "thingamajig", None, [0.0, 0.0, 0.3], 0.25),
            node(2, "handle", Some(1), [0.0, -0.25, 0.4], 0.01),
            node(3, "cabinet", None, [2.0, 0.0, 0.4], 0.3),
            node(4, "handle", Some(3), [2.0, -0.3, 0.6], 0.01),
        ]);
        let prior = prior::build(&g, &kb, &PriorConfig::default());
        let output = KnowledgeReasoner::new(kb.clone()).reason(&prior);
        let relation = |id: u32| output.functional.iter().find(|r| r.source_id == id).cloned().unwrap();
        // The handle on the unknown nightstand: what handles do on most objects, less confident.
        let (unknown, known) = (relation(2), relation(4));
        assert_eq!((unknown.target_id, relation_phrase(unknown.relation_id)), (1, Some("pull to open or close")));
        assert!(unknown.confidence < known.confidence, "{unknown:?} {known:?}");
        assert_eq!(output.fallback, FallbackCounts { unresolved: 1, by_part_rule: 1, ..FallbackCounts::default() });
        // A nightstand, which the tables list, falls back to nothing.
        g.nodes[0].label = "nightstand".to_owned();
        let output = KnowledgeReasoner::new(kb.clone()).reason(&prior::build(&g, &kb, &PriorConfig::default()));
        assert_eq!(output.fallback, FallbackCounts::default());
    }

    /// "larder" embeds exactly like "cabinet"; every other phrase is orthogonal to both.
    struct Larder;
    impl crate::embedding::PhraseEmbedder for Larder {
        fn embed(&mut self, phrases: &[&str]) -> Result<Vec<crate::embedding::Embedding>, String> {
            use std::hash::{Hash, Hasher};
            Ok(phrases
                .iter()
                .map(|p| {
                    let mut e = [0.0f32; crate::embedding::EMBEDDING_DIM];
                    let index = if *p == "larder" || *p == "cabinet" {
                        0
                    } else {
                        let mut h = std::collections::hash_map::DefaultHasher::new();
                        p.hash(&mut h);
                        1 + (h.finish() as usize) % (e.len() - 1)
                    };
                    e[index] = 1.0;
                    e
                })
                .collect())
        }
    }

    #[test]
    fn an_unknown_object_is_reasoned_as_its_nearest_category_by_embedding() {
        let kb = Arc::new(KnowledgeBase::builtin().unwrap());
        let embedder: crate::embedding::SharedEmbedder = Arc::new(std::sync::Mutex::new(Box::new(Larder)));
        let g = graph(vec![
            node(1, "larder", None, [0.0, 0.0, 0.4], 0.3),
            node(2, "handle", Some(1), [0.0, -0.3, 0.6], 0.01),
            node(3, "cabinet", None, [2.0, 0.0, 0.4], 0.3),
            node(4, "handle", Some(3), [2.0, -0.3, 0.6], 0.01),
        ]);
        let prior = prior::build(&g, &kb, &PriorConfig::default());
        let output = KnowledgeReasoner::with_embedder(kb.clone(), Some(embedder.clone())).reason(&prior);
        let relation = |output: &ReasonerOutput, id: u32| output.functional.iter().find(|r| r.source_id == id).cloned();
        let (unknown, known) = (relation(&output, 2).unwrap(), relation(&output, 4).unwrap());
        assert_eq!((unknown.target_id, unknown.relation_id), (1, known.relation_id));
        assert!((unknown.confidence - EMBEDDING_CONFIDENCE * known.confidence).abs() < 1e-6, "{unknown:?} {known:?}");
        assert_eq!(output.fallback, FallbackCounts { by_embedding: 1, ..FallbackCounts::default() });
        // Without an embedder the handle falls back to the part-label rule, less confident still.
        let output = KnowledgeReasoner::new(kb.clone()).reason(&prior);
        let rule = relation(&output, 2).unwrap();
        assert!(rule.confidence < unknown.confidence, "{rule:?}");
        assert_eq!(output.fallback, FallbackCounts { unresolved: 1, by_part_rule: 1, ..FallbackCounts::default() });
        // A prior graph built with the fallback carries the category, flagged, and it is counted once.
        let mut builder = prior::PriorBuilder::with_fallback(crate::knowledge::fallback::LabelFallback::new(
            &kb,
            Some(embedder.clone()),
        ));
        let flagged = builder.build(&g, &kb, &PriorConfig::default());
        assert!(flagged.nodes[0].by_embedding && flagged.nodes[0].category.is_some());
        let output = KnowledgeReasoner::with_embedder(kb, Some(embedder)).reason(&flagged);
        assert_eq!(relation(&output, 2).map(|r| r.confidence), Some(unknown.confidence));
        assert_eq!(output.fallback, FallbackCounts { by_embedding: 1, ..FallbackCounts::default() });
    }

    #[test]
    fn a_stove_with_knobs_and_an_oven_handle() {
        let g = graph(vec![
            node(1, "stove", None, [1.0, 0.3, 0.45], 0.3),
            node(2, "stove knob", Some(1), [0.9, 0.0, 0.8], 0.02),
            node(3, "stove knob", Some(1), [1.1, 0.0, 0.8], 0.02),
            node(4, "oven handle", Some(1), [1.0, 0.0, 0.6], 0.02),
        ]);
        let (relations, affordances) = run(&g);
        assert_eq!(
            relations,
            [
                (2, 1, "rotate to adjust the setting or temperature", false),
                (3, 1, "rotate to adjust the setting or temperature", false),
                (4, 1, "pull to open or close", false),
            ]
        );
        assert_eq!(affordances, [(2, vec!["rotate"]), (3, vec!["rotate"]), (4, vec!["hook_pull"])]);
    }

    #[test]
    fn a_remote_controls_the_nearest_tv() {
        let g = graph(vec![
            node(1, "tv", None, [0.0, 0.0, 1.0], 0.4),
            node(2, "television", None, [9.0, 0.0, 1.0], 0.4),
            node(3, "remote control", None, [2.0, 1.0, 0.5], 0.05),
            node(4, "sofa", None, [2.0, 1.5, 0.4], 0.4),
            node(5, "game console", None, [1.5, 0.5, 0.3], 0.1),
        ]);
        let (relations, affordances) = run(&g);
        assert_eq!(relations, [(3, 1, "remote to control", true)]);
        assert_eq!(affordances, [(3, vec!["key_press"])]);
    }

    #[test]
    fn a_light_switch_turns_on_a_lamp_and_a_lamp_switch_stays_local() {
        let g = graph(vec![
            node(1, "ceiling light", None, [2.0, 2.0, 2.6], 0.2),
            node(2, "light switch", None, [0.0, 0.5, 1.1], 0.04),
            node(3, "lamp", None, [3.0, 3.0, 0.8], 0.15),
            node(4, "lamp switch", Some(3), [3.0, 2.85, 0.7], 0.01),
        ]);
        let (relations, affordances) = run(&g);
        assert_eq!(relations, [(2, 1, "turn on or turn off", true), (4, 3, "turn on or turn off", false)]);
        assert_eq!(affordances, [(2, vec!["tip_push"]), (4, vec!["tip_push"])]);
    }

    #[test]
    fn an_outlet_powers_the_nearest_appliance_but_not_its_own_strip() {
        let g = graph(vec![
            node(1, "kettle", None, [1.0, 0.3, 1.0], 0.1),
            node(2, "toaster", None, [1.9, 0.3, 1.0], 0.1),
            node(3, "power outlet", None, [1.2, 0.0, 1.1], 0.04),
            node(4, "power strip", None, [5.0, 0.2, 0.05], 0.15),
            node(5, "power outlet", Some(4), [5.0, 0.2, 0.1], 0.02),
            node(6, "tv", None, [5.5, 0.2, 1.0], 0.4),
            node(7, "unicorn", None, [1.2, 0.1, 1.0], 0.1),
        ]);
        let (relations, affordances) = run(&g);
        assert_eq!(
            relations,
            [(3, 1, "provide power", true), (4, 6, "provide power", true), (5, 6, "provide power", true)]
        );
        assert_eq!(affordances, [(3, vec!["plug_in", "unplug"]), (5, vec!["plug_in", "unplug"])]);
    }

    #[test]
    fn affordances_follow_the_parent_and_apply_drops_vanished_nodes() {
        let mut g = graph(vec![
            node(1, "cabinet", None, [0.0, 0.0, 0.4], 0.3),
            node(2, "knob", Some(1), [0.0, -0.3, 0.6], 0.01),
            node(3, "nightstand", None, [2.0, 0.0, 0.3], 0.25),
            node(4, "drawer knob", Some(3), [2.0, -0.25, 0.4], 0.01),
            node(5, "knob", None, [4.0, 0.0, 1.0], 0.01),
        ]);
        let (relations, affordances) = run(&g);
        assert_eq!(relations, [(2, 1, "rotate to open or close", false), (4, 3, "pull to open or close", false)]);
        assert_eq!(affordances, [(2, vec!["rotate", "pinch_pull"]), (4, vec!["pinch_pull"]), (5, vec!["rotate"])]);

        let kb = Arc::new(KnowledgeBase::builtin().unwrap());
        let prior = prior::build(&g, &kb, &PriorConfig::default());
        let output = KnowledgeReasoner::new(kb).reason(&prior);
        g.nodes.retain(|n| n.id != 4);
        let dropped = super::super::apply(&mut g, &output, EdgeOrigin::Knowledge);
        assert_eq!(dropped, 2, "the vanished knob's relation and affordances");
        let functional: Vec<_> = g.edges.iter().filter(|e| e.kind == EdgeKind::Functional).collect();
        assert_eq!(functional.len(), 1);
        assert_eq!(functional[0].origin, EdgeOrigin::Knowledge);
        assert_eq!(g.nodes[1].affordance_bits, op3dsg_ipc_types::affordance_bits(["rotate", "pinch_pull"]).unwrap());
        let origins: Vec<_> = g.nodes[1].affordance_origins().collect();
        assert_eq!(origins, [("rotate", EdgeOrigin::Knowledge), ("pinch_pull", EdgeOrigin::Knowledge)]);
        // Applying twice adds nothing.
        super::super::apply(&mut g, &output, EdgeOrigin::Knowledge);
        assert_eq!(g.edges.iter().filter(|e| e.kind == EdgeKind::Functional).count(), 1);
        // The same affordances from an LLM agent confirm them: knowledge+llm.
        super::super::apply(&mut g, &output, EdgeOrigin::Llm);
        let origins: Vec<_> = g.nodes[1].affordance_origins().collect();
        assert_eq!(origins, [("rotate", EdgeOrigin::KnowledgeAndLlm), ("pinch_pull", EdgeOrigin::KnowledgeAndLlm)]);
    }
}
