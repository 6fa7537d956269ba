//! Reasoners: turn a versioned [`PriorGraph`] into functional relations (local and remote),
//! affordances per node and spatial corrections, each with node ids and a confidence.
//!
//! One interface, [`Reasoner`], for the offline [`KnowledgeReasoner`] (deterministic, the
//! default, run on every published graph); the LLM agents ([`llm`]) run asynchronously beside it
//! and produce the same [`ReasonerOutput`], applied on later graphs. A reasoner never writes into the graph
//! itself: its [`ReasonerOutput`] names the graph version it was computed from and is applied by
//! the owner of the graph with [`apply`], which drops anything whose nodes no longer exist.
//!
//! ```
//! use op3dsg_runtime::{knowledge::KnowledgeBase, prior, reasoner::{self, Reasoner}};
//! let kb = std::sync::Arc::new(KnowledgeBase::builtin().unwrap());
//! let mut graph = op3dsg_runtime::graph::SceneGraph::default();
//! let prior = prior::build(&graph, &kb, &prior::PriorConfig::default());
//! let output = reasoner::KnowledgeReasoner::new(kb).reason(&prior);
//! reasoner::apply(&mut graph, &output, op3dsg_ipc_types::EdgeOrigin::Knowledge);
//! ```

//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[reasoner]` ([`ReasonerConfig`]; `[reasoner.llm]` is in [`llm`]) |
//! | `enricher.rs` | [`GraphEnricher`] and [`enrich`]: prior graph, reasoner and LLM refiner on each published graph |
//! | `knowledge.rs` | [`KnowledgeReasoner`] |
//! | `llm/` | the LLM agents, their verification gate and the asynchronous refiner |

mod config;
mod enricher;
mod knowledge;
pub mod llm;

pub use config::{ReasonerConfig, ReasonerKind};
pub use enricher::{EnricherError, EnricherSetup, GraphEnricher, ReasoningVariant, Refinement, enrich};
pub use knowledge::KnowledgeReasoner;

use op3dsg_ipc_types::{EdgeKind, EdgeOrigin};
use rustc_hash::FxHashMap;

use crate::graph::{GraphEdge, GraphNode, SceneGraph};
use crate::knowledge::fallback::FallbackCounts;
use crate::prior::PriorGraph;

/// A functional relation: `source_id` acts on `target_id`.
#[derive(Debug, Clone, PartialEq)]
pub struct FunctionalRelation {
    /// Acting node (a part, or an object such as a remote control).
    pub source_id: u32,
    /// Acted-on object.
    pub target_id: u32,
    /// Canonical functional relation id (`op3dsg_ipc_types::relation_id`).
    pub relation_id: u16,
    /// Confidence in [0, 1].
    pub confidence: f32,
    /// `false`: a local relation on a part-of pair; `true`: a remote relation.
    pub remote: bool,
}

/// Affordances of one node.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeAffordances {
    /// The node.
    pub node_id: u32,
    /// Bit set over `op3dsg_ipc_types::AFFORDANCES`.
    pub affordance_bits: u16,
    /// Confidence in [0, 1].
    pub confidence: f32,
}

/// A proposed change to a spatial edge.
#[derive(Debug, Clone, PartialEq)]
pub struct SpatialCorrection {
    /// Source node.
    pub source_id: u32,
    /// Target node.
    pub target_id: u32,
    /// Canonical spatial relation id.
    pub relation_id: u16,
    /// `true`: add the edge; `false`: remove it.
    pub add: bool,
    /// Confidence in [0, 1].
    pub confidence: f32,
}

/// What a reasoner concluded about one prior-graph version.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReasonerOutput {
    /// Version of the prior graph it was computed from.
    pub graph_version: u64,
    /// Functional relations.
    pub functional: Vec<FunctionalRelation>,
    /// Affordances per node.
    pub affordances: Vec<NodeAffordances>,
    /// Spatial corrections.
    pub spatial_corrections: Vec<SpatialCorrection>,
    /// How often the knowledge reasoner fell back for labels its tables do not know
    /// (`crate::knowledge::fallback`); zero from other reasoners.
    pub fallback: FallbackCounts,
}

/// A reasoner over prior graphs.
pub trait Reasoner: Send {
    /// Short name for logs and health (`knowledge`, ...).
    fn name(&self) -> &'static str;
    /// Reasons over one prior-graph version.
    fn reason(&mut self, prior: &PriorGraph) -> ReasonerOutput;
}

/// Knowledge and the LLM agreeing on an edge.
fn combined_origin(existing: EdgeOrigin, new: EdgeOrigin) -> EdgeOrigin {
    match (existing, new) {
        (EdgeOrigin::Knowledge, EdgeOrigin::Llm) | (EdgeOrigin::Llm, EdgeOrigin::Knowledge) => {
            EdgeOrigin::KnowledgeAndLlm
        }
        (existing, _) => existing,
    }
}

/// Applies `output` to `graph`: functional edges (with `origin`; an edge already there from the
/// other of knowledge and LLM becomes `knowledge+llm`) and affordance bits for nodes that still
/// exist (each marked with `origin`, so one given by both is `knowledge+llm` too), spatial
/// corrections likewise. Returns how many items were dropped because
/// a node is gone.
pub fn apply(graph: &mut SceneGraph, output: &ReasonerOutput, origin: EdgeOrigin) -> usize {
    let exists = |nodes: &[GraphNode], id: u32| nodes.binary_search_by_key(&id, |n| n.id).is_ok();
    let mut dropped = 0;
    // The graph's functional edges by (source, target, relation): one lookup per relation
    // instead of a scan of every edge (this runs on the fusion thread for each published graph).
    let mut functional: FxHashMap<(u32, u32, u16), usize> = FxHashMap::default();
    for (i, e) in graph.edges.iter().enumerate().filter(|(_, e)| e.kind == EdgeKind::Functional) {
        functional.entry((e.source_id, e.target_id, e.relation_id)).or_insert(i);
    }
    for relation in &output.functional {
        if !(exists(&graph.nodes, relation.source_id) && exists(&graph.nodes, relation.target_id)) {
            dropped += 1;
            continue;
        }
        let key = (relation.source_id, relation.target_id, relation.relation_id);
        if let Some(&i) = functional.get(&key) {
            let edge = &mut graph.edges[i];
            edge.origin = combined_origin(edge.origin, origin);
            edge.confidence = edge.confidence.max(relation.confidence.clamp(0.0, 1.0));
        } else {
            functional.insert(key, graph.edges.len());
            graph.edges.push(GraphEdge {
                source_id: relation.source_id,
                target_id: relation.target_id,
                kind: EdgeKind::Functional,
                relation_id: relation.relation_id,
                confidence: relation.confidence.clamp(0.0, 1.0),
                origin,
            });
        }
    }
    for affordances in &output.affordances {
        match graph.nodes.binary_search_by_key(&affordances.node_id, |n| n.id) {
            Ok(i) => graph.nodes[i].add_affordances(affordances.affordance_bits, origin),
            Err(_) => dropped += 1,
        }
    }
    for correction in &output.spatial_corrections {
        if !(exists(&graph.nodes, correction.source_id) && exists(&graph.nodes, correction.target_id)) {
            dropped += 1;
            continue;
        }
        let same = |e: &GraphEdge| {
            e.kind == EdgeKind::Spatial
                && e.source_id == correction.source_id
                && e.target_id == correction.target_id
                && e.relation_id == correction.relation_id
        };
        if correction.add {
            if !graph.edges.iter().any(same) {
                graph.edges.push(GraphEdge {
                    source_id: correction.source_id,
                    target_id: correction.target_id,
                    kind: EdgeKind::Spatial,
                    relation_id: correction.relation_id,
                    confidence: correction.confidence.clamp(0.0, 1.0),
                    origin,
                });
            }
        } else {
            graph.edges.retain(|e| !same(e));
        }
    }
    dropped
}
