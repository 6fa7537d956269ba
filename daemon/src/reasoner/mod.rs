//! Reasoners: turn a versioned [`PriorGraph`] into functional relations (local and remote),
//! affordances per node and spatial corrections, each with node ids and a confidence.
//!
//! One interface, [`Reasoner`], so that the offline [`KnowledgeReasoner`] (deterministic, the
//! default) and later LLM agents are interchangeable. A reasoner never writes into the graph
//! itself: its [`ReasonerOutput`] names the graph version it was computed from and is applied by
//! the owner of the graph with [`apply`], which drops anything whose nodes no longer exist.
//!
//! ```
//! use op3dsg_daemon::{knowledge::KnowledgeBase, prior, reasoner::{self, Reasoner}};
//! let kb = std::sync::Arc::new(KnowledgeBase::builtin().unwrap());
//! let mut graph = op3dsg_daemon::graph::SceneGraph::default();
//! let prior = prior::build(&graph, &kb, &prior::PriorConfig::default());
//! let output = reasoner::KnowledgeReasoner::new(kb).reason(&prior);
//! reasoner::apply(&mut graph, &output, op3dsg_ipc_types::EdgeOrigin::Knowledge);
//! ```

pub mod ablation;
mod knowledge;

pub use ablation::ReasoningSetup;
pub use knowledge::KnowledgeReasoner;

use std::path::Path;
use std::sync::Arc;

use op3dsg_ipc_types::{EdgeKind, EdgeOrigin};

use crate::config::{Profile, ReasonerKind};
use crate::graph::{GraphEdge, SceneGraph};
use crate::knowledge::{KnowledgeBase, KnowledgeError};
use crate::prior::{self, PriorConfig, PriorGraph};

/// What the fusion thread (and the batch runner) run on each graph they publish: the prior
/// graph's spatial relations, then the reasoner's functional relations and affordances.
pub struct GraphEnricher {
    knowledge: Arc<KnowledgeBase>,
    prior_config: PriorConfig,
    reasoner: Box<dyn Reasoner>,
    setup: ReasoningSetup,
}

impl std::fmt::Debug for GraphEnricher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GraphEnricher")
            .field("objects", &self.knowledge.objects().len())
            .field("prior_config", &self.prior_config)
            .field("reasoner", &self.reasoner.name())
            .field("setup", &self.setup)
            .finish()
    }
}

impl GraphEnricher {
    /// The enricher `[reasoner]` asks for; `None` with `kind = "none"`.
    pub fn from_profile(profile: &Profile) -> Result<Option<Self>, KnowledgeError> {
        let config = &profile.reasoner;
        if config.kind == ReasonerKind::None {
            return Ok(None);
        }
        let knowledge = Arc::new(match &config.knowledge_dir {
            Some(dir) => KnowledgeBase::load_dir(Path::new(dir))?,
            None => KnowledgeBase::builtin()?,
        });
        let prior_config = PriorConfig {
            up_axis: profile.world.up_axis,
            neighbour_radius_m: config.neighbour_radius_m,
            contact_tolerance_m: config.contact_tolerance_m,
            next_to_gap_m: config.next_to_gap_m,
            min_footprint_overlap: config.min_footprint_overlap,
            inside_tolerance_m: config.inside_tolerance_m,
        };
        let reasoner: Box<dyn Reasoner> = match config.kind {
            ReasonerKind::Knowledge | ReasonerKind::None => Box::new(KnowledgeReasoner::new(knowledge.clone())),
        };
        Ok(Some(Self { knowledge, prior_config, reasoner, setup: ReasoningSetup::Split }))
    }

    /// The same enricher with the reasoning stage set up as `setup` (the paper's ablations; see
    /// [`ablation`]).
    pub fn with_setup(mut self, setup: ReasoningSetup) -> Self {
        self.setup = setup;
        if setup == ReasoningSetup::Single {
            self.reasoner =
                Box::new(ablation::SingleReasoner::new(&self.knowledge, self.prior_config.neighbour_radius_m));
        } else {
            self.reasoner = Box::new(KnowledgeReasoner::new(self.knowledge.clone()));
        }
        self
    }

    /// Adds the prior graph's object relations and the reasoner's results to `graph` (fusion's
    /// `part of` edges are already there). Returns the prior graph for callers that want it.
    pub fn enrich(&mut self, graph: &mut SceneGraph) -> PriorGraph {
        if self.setup == ReasoningSetup::FlatNodeList {
            *graph = ablation::flat_node_list(graph, &self.knowledge, self.prior_config.neighbour_radius_m);
            let mut prior = prior::build(graph, &self.knowledge, &self.prior_config);
            let part_of = op3dsg_ipc_types::relation_id("part of").map_or(0, |(_, id)| id);
            prior.spatial_edges.retain(|e| e.relation_id == part_of);
            let relations = ablation::flat_object_relations(&prior);
            prior.spatial_edges.extend(relations.iter().cloned());
            graph.edges.extend(relations);
            let output = self.reasoner.reason(&prior);
            apply(graph, &output, EdgeOrigin::Knowledge);
            return prior;
        }
        let prior = prior::build(graph, &self.knowledge, &self.prior_config);
        let part_of = op3dsg_ipc_types::relation_id("part of").map_or(0, |(_, id)| id);
        graph.edges.extend(prior.spatial_edges.iter().filter(|e| e.relation_id != part_of).cloned());
        let output = self.reasoner.reason(&prior);
        apply(graph, &output, EdgeOrigin::Knowledge);
        prior
    }
}

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
}

/// A reasoner over prior graphs.
pub trait Reasoner: Send {
    /// Short name for logs and health (`knowledge`, ...).
    fn name(&self) -> &'static str;
    /// Reasons over one prior-graph version.
    fn reason(&mut self, prior: &PriorGraph) -> ReasonerOutput;
}

/// Applies `output` to `graph`: functional edges (with `origin`) and affordance bits for nodes
/// that still exist, spatial corrections likewise. Returns how many items were dropped because
/// a node is gone.
pub fn apply(graph: &mut SceneGraph, output: &ReasonerOutput, origin: EdgeOrigin) -> usize {
    let exists = |nodes: &[crate::graph::GraphNode], id: u32| nodes.binary_search_by_key(&id, |n| n.id).is_ok();
    let mut dropped = 0;
    for relation in &output.functional {
        if !(exists(&graph.nodes, relation.source_id) && exists(&graph.nodes, relation.target_id)) {
            dropped += 1;
            continue;
        }
        let duplicate = graph.edges.iter().any(|e| {
            e.kind == EdgeKind::Functional
                && e.source_id == relation.source_id
                && e.target_id == relation.target_id
                && e.relation_id == relation.relation_id
        });
        if !duplicate {
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
            Ok(i) => graph.nodes[i].affordance_bits |= affordances.affordance_bits,
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

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, affordance_names, relation_phrase};

    use crate::batch::{self, VisibilityThresholds};

    /// With no LLM, the synthetic kitchen's published graph carries part-of, functional edges and
    /// affordances that agree with the scene's ground truth.
    #[test]
    fn the_kitchen_graph_gets_functional_edges_and_affordances() {
        let mut profile = crate::config::load(None, &[]).unwrap().profile;
        profile.source.synthetic.frame_count = Some(600);
        let run = batch::run(&profile, &VisibilityThresholds::default()).unwrap();
        let graph = &run.graph;
        let label = |id: u32| graph.nodes.iter().find(|n| n.id == id).map_or("?", |n| n.label.as_str());
        let functional: Vec<(&str, &str, &str)> = graph
            .edges
            .iter()
            .filter(|e| e.kind == EdgeKind::Functional)
            .inspect(|e| assert_eq!(e.origin, EdgeOrigin::Knowledge))
            .map(|e| (label(e.source_id), relation_phrase(e.relation_id).unwrap_or("?"), label(e.target_id)))
            .collect();
        assert!(
            functional.contains(&("stove knob", "rotate to adjust the setting or temperature", "stove")),
            "{functional:?}"
        );
        assert!(functional.iter().any(|(_, r, t)| *r == "control the water flow" && *t == "sink"), "{functional:?}");
        // Every handle fused onto a cabinet: "pull to open or close" to it and "hook_pull".
        let mut handles = 0;
        for part in graph.nodes.iter().filter(|n| n.label.ends_with("handle")) {
            let Some(parent) = part.parent_id else { continue };
            if label(parent) != "cabinet" {
                continue;
            }
            handles += 1;
            assert!(
                graph.edges.iter().any(|e| e.source_id == part.id
                    && e.target_id == parent
                    && relation_phrase(e.relation_id) == Some("pull to open or close")),
                "{} {}",
                part.id,
                part.label
            );
            assert_eq!(affordance_names(part.affordance_bits).collect::<Vec<_>>(), ["hook_pull"]);
        }
        assert!(handles >= 2, "{handles} cabinet handles");
        assert!(graph.edges.iter().any(|e| e.kind == EdgeKind::Spatial && e.relation_id != 0), "object relations");
    }
}
