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

pub mod ablation;
pub mod fallback;
mod knowledge;
pub mod llm;

pub use ablation::ReasoningSetup;
pub use knowledge::KnowledgeReasoner;

use std::sync::Arc;

use op3dsg_ipc_types::{EdgeKind, EdgeOrigin};
use rustc_hash::FxHashMap;

use crate::config::{Profile, ReasonerKind};
use crate::graph::{GraphEdge, SceneGraph};
use crate::knowledge::{KnowledgeBase, KnowledgeError};
use crate::prior::{self, PriorConfig, PriorGraph};

/// Why the enricher could not be made; `field` names the profile key.
#[derive(Debug, thiserror::Error)]
pub enum EnricherError {
    /// The knowledge base did not load.
    #[error(transparent)]
    Knowledge(#[from] KnowledgeError),
    /// The text encoder of the label fallback did not load (`[text_encoder] enabled = true`).
    #[error("{0}")]
    TextEncoder(String),
    /// The LLM refiner could not start.
    #[error("{field}: {reason}")]
    Llm {
        /// Profile key at fault.
        field: &'static str,
        /// What went wrong.
        reason: String,
    },
}

/// What the fusion thread (and the batch runner) run on each graph they publish: the prior
/// graph's spatial relations, then the reasoner's functional relations and affordances, then
/// (with `kind = "llm"`) the LLM refiner's latest verified result.
pub struct GraphEnricher {
    knowledge: Arc<KnowledgeBase>,
    prior_config: PriorConfig,
    prior_builder: prior::PriorBuilder,
    reasoner: Box<dyn Reasoner>,
    refiner: Option<llm::LlmRefiner>,
    /// Every LLM agent's last accepted result, re-checked against and applied to every graph
    /// until a newer one arrives (items whose nodes are gone or changed kind are dropped and
    /// counted `stale` once).
    llm_result: Option<llm::LlmResult>,
    /// Batch runs: the refiner only refreshes through [`GraphEnricher::refine_now`].
    synchronous: bool,
    setup: ReasoningSetup,
    /// The embedding fallback's encoder for labels the tables do not know ([`fallback`]).
    label_embedder: Option<fallback::SharedEmbedder>,
    /// The knowledge reasoner's fallback counts on the last graph.
    fallback_counts: fallback::FallbackCounts,
}

impl std::fmt::Debug for GraphEnricher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GraphEnricher")
            .field("objects", &self.knowledge.objects().len())
            .field("prior_config", &self.prior_config)
            .field("reasoner", &self.reasoner.name())
            .field("refiner", &self.refiner)
            .field("setup", &self.setup)
            .finish()
    }
}

impl GraphEnricher {
    /// The enricher `[reasoner]` asks for; `None` with `kind = "none"`.
    pub fn from_profile(profile: &Profile) -> Result<Option<Self>, EnricherError> {
        let config = &profile.reasoner;
        if config.kind == ReasonerKind::None {
            return Ok(None);
        }
        let knowledge = Arc::new(KnowledgeBase::from_profile_dir(config.knowledge_dir.as_deref())?);
        let prior_config = PriorConfig {
            up_axis: profile.world.up_axis,
            neighbour_radius_m: config.neighbour_radius_m,
            contact_tolerance_m: config.contact_tolerance_m,
            next_to_gap_m: config.next_to_gap_m,
            min_footprint_overlap: config.min_footprint_overlap,
            inside_tolerance_m: config.inside_tolerance_m,
        };
        // With the text encoder on, labels the tables do not know take their nearest category.
        let label_embedder = if profile.text_encoder.enabled {
            Some(fallback::load_embedder(profile).map_err(EnricherError::TextEncoder)?)
        } else {
            None
        };
        let reasoner: Box<dyn Reasoner> =
            Box::new(KnowledgeReasoner::with_embedder(knowledge.clone(), label_embedder.clone()));
        let refiner = match config.kind {
            ReasonerKind::Llm => Some(start_refiner(profile, knowledge.clone())?),
            ReasonerKind::Knowledge | ReasonerKind::None => None,
        };
        let prior_builder =
            prior::PriorBuilder::with_fallback(fallback::LabelFallback::new(&knowledge, label_embedder.clone()));
        Ok(Some(Self {
            knowledge,
            prior_config,
            prior_builder,
            reasoner,
            refiner,
            llm_result: None,
            synchronous: false,
            setup: ReasoningSetup::Split,
            label_embedder,
            fallback_counts: fallback::FallbackCounts::default(),
        }))
    }

    /// Records the LLM refiner's calls (`/op3dsg/llm`) through `recorder`; nothing without
    /// `kind = "llm"`.
    pub fn record_llm_to(&self, recorder: &crate::record::RecordSender) {
        if let Some(refiner) = &self.refiner {
            refiner.record_to(recorder.clone());
        }
    }

    /// The LLM refiner's counters (`None` without `kind = "llm"`).
    pub fn refiner_stats(&self) -> Option<Arc<llm::RefinerStats>> {
        self.refiner.as_ref().map(|r| r.stats().clone())
    }

    /// The same enricher with the reasoning stage set up as `setup` (the paper's ablations; see
    /// [`ablation`]).
    pub fn with_setup(mut self, setup: ReasoningSetup) -> Self {
        self.setup = setup;
        self.remake_reasoner();
        self
    }

    /// The same enricher reasoning with `knowledge` instead of the profile's tables (the
    /// leave-one-category-out benchmark gives it tables that lack one category).
    pub fn with_knowledge(mut self, knowledge: Arc<KnowledgeBase>) -> Self {
        self.knowledge = knowledge;
        self.remake_reasoner();
        self
    }

    /// The same enricher with `embedder` for the nearest-category fallback ([`fallback`]), as
    /// `[text_encoder] enabled = true` gives it.
    pub fn with_label_embedder(mut self, embedder: fallback::SharedEmbedder) -> Self {
        self.label_embedder = Some(embedder);
        self.remake_reasoner();
        self
    }

    /// The knowledge reasoner's fallback counts on the last graph enriched (zero for the
    /// single-reasoner ablation).
    pub fn fallback_counts(&self) -> fallback::FallbackCounts {
        self.fallback_counts
    }

    fn remake_reasoner(&mut self) {
        // A new builder: its label cache and fallback belong to the old tables or embedder.
        self.prior_builder = prior::PriorBuilder::with_fallback(fallback::LabelFallback::new(
            &self.knowledge,
            self.label_embedder.clone(),
        ));
        self.reasoner = if self.setup == ReasoningSetup::Single {
            Box::new(ablation::SingleReasoner::new(&self.knowledge, self.prior_config.neighbour_radius_m))
        } else {
            Box::new(KnowledgeReasoner::with_embedder(self.knowledge.clone(), self.label_embedder.clone()))
        };
    }

    /// Adds the prior graph's object relations and the reasoner's results to `graph` (fusion's
    /// `part of` edges are already there; `graph.version` is set), then the LLM refiner's latest
    /// verified result, and hands the prior graph to the refiner. Never waits for the refiner.
    pub fn enrich(&mut self, graph: &mut SceneGraph) -> Arc<PriorGraph> {
        if self.setup == ReasoningSetup::FlatNodeList {
            *graph = ablation::flat_node_list(graph, &self.knowledge, self.prior_config.neighbour_radius_m);
            let mut prior = prior::build(graph, &self.knowledge, &self.prior_config);
            let part_of = op3dsg_ipc_types::relation_id("part of").map_or(0, |(_, id)| id);
            prior.spatial_edges.retain(|e| e.relation_id == part_of);
            let relations = ablation::flat_object_relations(&prior);
            prior.spatial_edges.extend(relations.iter().cloned());
            graph.edges.extend(relations);
            let output = self.reasoner.reason(&prior);
            self.fallback_counts = output.fallback;
            apply(graph, &output, EdgeOrigin::Knowledge);
            return Arc::new(prior);
        }
        let prior = Arc::new(self.prior_builder.build(graph, &self.knowledge, &self.prior_config));
        let part_of = op3dsg_ipc_types::relation_id("part of").map_or(0, |(_, id)| id);
        // Fusion's own part-of edges are in the graph already; the prior graph's attachments not.
        graph.edges.extend(
            prior
                .spatial_edges
                .iter()
                .filter(|e| {
                    e.relation_id != part_of || prior.attached.binary_search(&(e.source_id, e.target_id)).is_ok()
                })
                .cloned(),
        );
        for &(part_id, object_id) in &prior.attached {
            if let Ok(i) = graph.nodes.binary_search_by_key(&part_id, |n| n.id) {
                graph.nodes[i].parent_id = Some(object_id);
            }
        }
        let output = self.reasoner.reason(&prior);
        self.fallback_counts = output.fallback;
        apply(graph, &output, EdgeOrigin::Knowledge);
        if self.refiner.is_some() && !self.synchronous {
            if let Some(result) = self.refiner.as_ref().and_then(llm::LlmRefiner::try_result) {
                self.llm_result = Some(result);
            }
            self.apply_llm(graph);
            if let Some(refiner) = &self.refiner {
                refiner.offer(prior.clone());
            }
        }
        prior
    }

    /// Batch runs: [`GraphEnricher::enrich`] stops feeding the refiner; each graph is refined
    /// with [`GraphEnricher::refine_now`] instead.
    pub fn set_synchronous(&mut self, synchronous: bool) {
        self.synchronous = synchronous;
        if let Some(refiner) = &self.refiner {
            refiner.set_synchronous(synchronous);
        }
    }

    /// Batch runs: hands `prior` (of `graph`, already enriched) to the refiner for a refresh
    /// whatever changed, waits up to `timeout` for its verified result and applies it, so that a
    /// deterministic server gives a deterministic graph. Returns whether a result arrived.
    pub fn refine_now(&mut self, graph: &mut SceneGraph, prior: Arc<PriorGraph>, timeout: std::time::Duration) -> bool {
        let Some(refiner) = &self.refiner else { return false };
        while refiner.try_result().is_some() {}
        refiner.offer_forced(prior);
        match refiner.wait_result(timeout) {
            Some(result) => {
                self.llm_result = Some(result);
                self.apply_llm(graph);
                true
            }
            None => false,
        }
    }

    /// Applies every agent's last accepted result to `graph`, each item re-checked against it
    /// first (its nodes there with the kind they had; a local relation's part still on its
    /// object). Items that fail are dropped here and counted `stale` by the refiner, which
    /// prunes its own copy against the same graph's prior.
    fn apply_llm(&mut self, graph: &mut SceneGraph) {
        let Some(result) = &mut self.llm_result else { return };
        let nodes = &graph.nodes;
        result.retain_valid(|id| {
            nodes.binary_search_by_key(&id, |n| n.id).ok().map(|i| (nodes[i].kind, nodes[i].parent_id))
        });
        apply(graph, &result.merged(), EdgeOrigin::Llm);
    }
}

/// The refiner `[reasoner.llm]` asks for: the key from its file or variable, the text encoder
/// for the nearest-phrase mapping when `[text_encoder]` is enabled.
fn start_refiner(profile: &Profile, knowledge: Arc<KnowledgeBase>) -> Result<llm::LlmRefiner, EnricherError> {
    let config = &profile.reasoner.llm;
    let key = llm::client::load_api_key(config).map_err(|(field, reason)| EnricherError::Llm { field, reason })?;
    if key.is_none() && !config.api_key_env.is_empty() {
        tracing::info!(variable = %config.api_key_env, "no LLM API key set; requests carry no Authorization header");
    }
    let embedder: Option<Box<dyn llm::gate::PhraseEmbedder>> = if profile.text_encoder.enabled {
        let runtime = crate::onnx::OnnxRuntime::init(&profile.onnx)
            .map_err(|e| EnricherError::Llm { field: "onnx", reason: e.to_string() })?;
        let encoder = crate::onnx::text_encoder::TextEncoder::new(&runtime, &profile.text_encoder)
            .map_err(|e| EnricherError::Llm { field: "text_encoder", reason: e.to_string() })?;
        Some(Box::new(encoder))
    } else {
        None
    };
    let mapper = llm::gate::LabelMapper::new(embedder, config.embedding_min_similarity);
    llm::LlmRefiner::start(config, llm::RefinerParts { knowledge, key, mapper })
        .map_err(|reason| EnricherError::Llm { field: "reasoner.llm", reason })
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
    /// How often the knowledge reasoner fell back for labels its tables do not know
    /// ([`fallback`]); zero from other reasoners.
    pub fallback: fallback::FallbackCounts,
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
    let exists = |nodes: &[crate::graph::GraphNode], id: u32| nodes.binary_search_by_key(&id, |n| n.id).is_ok();
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
