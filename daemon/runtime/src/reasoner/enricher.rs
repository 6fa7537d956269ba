//! What the fusion thread (and the batch runner) run on each graph they publish: the prior
//! graph's spatial relations, then the reasoner's functional relations and affordances, then
//! (with `reasoner.kind = "llm"`) the LLM refiner's latest verified result.

use std::sync::Arc;
use std::time::Duration;

use op3dsg_ipc_types::EdgeOrigin;

use super::config::{ReasonerConfig, ReasonerKind};
use super::{KnowledgeReasoner, Reasoner, apply, llm};
use crate::embedding::{PhraseEmbedder, SharedEmbedder};
use crate::graph::SceneGraph;
use crate::knowledge::fallback::{FallbackCounts, LabelFallback};
use crate::knowledge::{KnowledgeBase, KnowledgeError};
use crate::onnx::text_encoder::TextEncoderConfig;
use crate::onnx::{OnnxConfig, OnnxRuntime, text_encoder};
use crate::prior::{PriorBuilder, PriorConfig, PriorGraph};
use crate::world::UpAxis;

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

/// What an enricher is made from: `[reasoner]`, the world's up axis, and the text encoder when
/// the profile enables it (`[onnx]`, `[text_encoder]`): labels the tables do not know take their
/// nearest category, and the LLM gate maps phrases to the nearest canonical one.
#[derive(Debug, Clone, Copy)]
pub struct EnricherSetup<'a> {
    /// `[reasoner]`.
    pub reasoner: &'a ReasonerConfig,
    /// `world.up_axis`.
    pub up_axis: UpAxis,
    /// `[onnx]` and `[text_encoder]` with `[text_encoder] enabled = true`, else `None`.
    pub text_encoder: Option<(&'a OnnxConfig, &'a TextEncoderConfig)>,
}

/// A variant of the reasoning stage for evaluation (the paper's ablations live in `op3dsg-sim`):
/// it may replace the reasoner, and the prior graph the reasoner gets. The daemon runs none.
pub trait ReasoningVariant: Send + std::fmt::Debug {
    /// The reasoner over `knowledge` with the prior graph's tolerances `prior`; `None`: the
    /// knowledge reasoner of the method.
    fn reasoner(&self, knowledge: &Arc<KnowledgeBase>, prior: &PriorConfig) -> Option<Box<dyn Reasoner>> {
        let _ = (knowledge, prior);
        None
    }

    /// Replaces the prior graph stage: changes `graph` into what the variant's reasoner sees and
    /// returns its prior graph; `None`: the method's prior graph. A variant's prior graph is not
    /// offered to the LLM refiner.
    fn prior(&self, graph: &mut SceneGraph, knowledge: &KnowledgeBase, prior: &PriorConfig) -> Option<PriorGraph> {
        let _ = (graph, knowledge, prior);
        None
    }
}

/// The prior graph, the reasoner and the LLM refiner applied to each published graph (module
/// docs).
pub struct GraphEnricher {
    knowledge: Arc<KnowledgeBase>,
    prior_config: PriorConfig,
    prior_builder: PriorBuilder,
    reasoner: Box<dyn Reasoner>,
    refiner: Option<llm::LlmRefiner>,
    /// Every LLM agent's last accepted result, re-checked against and applied to every graph
    /// until a newer one arrives (items whose nodes are gone or changed kind are dropped and
    /// counted `stale` once).
    llm_result: Option<llm::LlmResult>,
    /// Batch runs: the refiner only refreshes through [`GraphEnricher::refine_now`].
    synchronous: bool,
    variant: Option<Box<dyn ReasoningVariant>>,
    /// The embedding fallback's encoder for labels the tables do not know
    /// (`crate::knowledge::fallback`).
    label_embedder: Option<SharedEmbedder>,
    /// The knowledge reasoner's fallback counts on the last graph.
    fallback_counts: FallbackCounts,
}

impl std::fmt::Debug for GraphEnricher {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GraphEnricher")
            .field("objects", &self.knowledge.objects().len())
            .field("prior_config", &self.prior_config)
            .field("reasoner", &self.reasoner.name())
            .field("refiner", &self.refiner)
            .field("variant", &self.variant)
            .finish()
    }
}

impl GraphEnricher {
    /// The enricher `setup.reasoner` asks for; `None` with `kind = "none"`.
    pub fn from_setup(setup: EnricherSetup<'_>) -> Result<Option<Self>, EnricherError> {
        let config = setup.reasoner;
        if config.kind == ReasonerKind::None {
            return Ok(None);
        }
        let knowledge = Arc::new(KnowledgeBase::from_profile_dir(config.knowledge_dir.as_deref())?);
        let prior_config = config.prior(setup.up_axis);
        // With the text encoder on, labels the tables do not know take their nearest category.
        let label_embedder = match setup.text_encoder {
            Some((onnx, encoder)) => {
                Some(text_encoder::load_shared(onnx, encoder).map_err(EnricherError::TextEncoder)?)
            }
            None => None,
        };
        let reasoner: Box<dyn Reasoner> =
            Box::new(KnowledgeReasoner::with_embedder(knowledge.clone(), label_embedder.clone()));
        let refiner = match config.kind {
            ReasonerKind::Llm => Some(start_refiner(config, setup.text_encoder, knowledge.clone())?),
            ReasonerKind::Knowledge | ReasonerKind::None => None,
        };
        let prior_builder = PriorBuilder::with_fallback(LabelFallback::new(&knowledge, label_embedder.clone()));
        Ok(Some(Self {
            knowledge,
            prior_config,
            prior_builder,
            reasoner,
            refiner,
            llm_result: None,
            synchronous: false,
            variant: None,
            label_embedder,
            fallback_counts: FallbackCounts::default(),
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

    /// The same enricher with the reasoning stage replaced as `variant` says (evaluation only).
    pub fn with_variant(mut self, variant: Box<dyn ReasoningVariant>) -> Self {
        self.variant = Some(variant);
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

    /// The same enricher with `embedder` for the nearest-category fallback
    /// (`crate::knowledge::fallback`), as `[text_encoder] enabled = true` gives it.
    pub fn with_label_embedder(mut self, embedder: SharedEmbedder) -> Self {
        self.label_embedder = Some(embedder);
        self.remake_reasoner();
        self
    }

    /// The knowledge reasoner's fallback counts on the last graph enriched (zero for reasoners
    /// without a fallback).
    pub fn fallback_counts(&self) -> FallbackCounts {
        self.fallback_counts
    }

    fn remake_reasoner(&mut self) {
        // A new builder: its label cache and fallback belong to the old tables or embedder.
        self.prior_builder =
            PriorBuilder::with_fallback(LabelFallback::new(&self.knowledge, self.label_embedder.clone()));
        self.reasoner = self
            .variant
            .as_ref()
            .and_then(|variant| variant.reasoner(&self.knowledge, &self.prior_config))
            .unwrap_or_else(|| {
                Box::new(KnowledgeReasoner::with_embedder(self.knowledge.clone(), self.label_embedder.clone()))
            });
    }

    /// Adds the prior graph's object relations and the reasoner's results to `graph` (fusion's
    /// `part of` edges are already there; `graph.version` is set), then the LLM refiner's latest
    /// verified result, and hands the prior graph to the refiner. Never waits for the refiner.
    pub fn enrich(&mut self, graph: &mut SceneGraph) -> Arc<PriorGraph> {
        let variant_prior =
            self.variant.as_ref().and_then(|variant| variant.prior(graph, &self.knowledge, &self.prior_config));
        if let Some(prior) = variant_prior {
            self.reason(graph, &prior);
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
        self.reason(graph, &prior);
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

    /// The reasoner's results on `prior`, applied to `graph`.
    fn reason(&mut self, graph: &mut SceneGraph, prior: &PriorGraph) {
        let output = self.reasoner.reason(prior);
        self.fallback_counts = output.fallback;
        apply(graph, &output, EdgeOrigin::Knowledge);
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
    pub fn refine_now(&mut self, graph: &mut SceneGraph, prior: Arc<PriorGraph>, timeout: Duration) -> bool {
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

/// How a graph receives the LLM refiner's answer (with `reasoner.kind = "llm"`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Refinement {
    /// The refiner's latest verified result is applied and the new prior graph offered to it;
    /// nothing waits (the pipeline: the fusion thread never waits on the network).
    Asynchronous,
    /// The graph is refined now: its prior graph is sent and the answer awaited up to the given
    /// time (the batch runner, so that a deterministic server gives a deterministic graph).
    Await(Duration),
}

/// Adds the prior graph (spatial relations, part → object attachment) and the reasoner's
/// functional relations and affordances to `graph`, then the LLM refiner's answer as
/// `refinement` says. Returns the prior graph. The pipeline's fusion thread and the batch runner
/// both call this on each graph they publish.
pub fn enrich(enricher: &mut GraphEnricher, graph: &mut SceneGraph, refinement: Refinement) -> Arc<PriorGraph> {
    let prior = enricher.enrich(graph);
    if let Refinement::Await(timeout) = refinement {
        enricher.refine_now(graph, prior.clone(), timeout);
    }
    prior
}

/// The refiner `[reasoner.llm]` asks for: the key from its file or variable, the text encoder
/// for the nearest-phrase mapping when `[text_encoder]` is enabled.
fn start_refiner(
    config: &ReasonerConfig,
    text_encoder: Option<(&OnnxConfig, &TextEncoderConfig)>,
    knowledge: Arc<KnowledgeBase>,
) -> Result<llm::LlmRefiner, EnricherError> {
    let config = &config.llm;
    let key = llm::client::load_api_key(config).map_err(|(field, reason)| EnricherError::Llm { field, reason })?;
    if key.is_none() && !config.api_key_env.is_empty() {
        tracing::info!(variable = %config.api_key_env, "no LLM API key set; requests carry no Authorization header");
    }
    let embedder: Option<Box<dyn PhraseEmbedder>> = match text_encoder {
        Some((onnx, encoder_config)) => {
            let runtime =
                OnnxRuntime::init(onnx).map_err(|e| EnricherError::Llm { field: "onnx", reason: e.to_string() })?;
            let encoder = text_encoder::TextEncoder::new(&runtime, encoder_config)
                .map_err(|e| EnricherError::Llm { field: "text_encoder", reason: e.to_string() })?;
            Some(Box::new(encoder))
        }
        None => None,
    };
    let mapper = llm::gate::LabelMapper::new(embedder, config.embedding_min_similarity);
    llm::LlmRefiner::start(config, llm::RefinerParts { knowledge, key, mapper })
        .map_err(|reason| EnricherError::Llm { field: "reasoner.llm", reason })
}
