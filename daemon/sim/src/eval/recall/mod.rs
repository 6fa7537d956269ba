//! The benchmark's evaluation protocol (paper, section "Metrics"): retrieval-based recall at K of
//! nodes, affordances, functional and spatial triplets and associated node pairs, comparing a
//! predicted graph with a ground-truth graph (both `op3dsg.graph/1`, see
//! [`op3dsg_drivers::graph_json`]). `op3dsg eval --pred <graph.json> --gt <gt.json>` runs it on
//! two files; `op3dsg bench quality` runs it on every scene of the synthetic benchmark.
//!
//! ## The protocol
//!
//! Text is compared by the cosine similarity of sentence embeddings (all-MiniLM-L6-v2, the
//! Sentence-BERT model the paper uses for phrases; the encoder is injected through
//! [`PhraseEmbedder`], so tests can use a hand-made similarity). For a predicted text `q` and a
//! vocabulary `V`, the **rank** of a ground-truth text `t ∈ V` is the number of vocabulary
//! entries at least as similar to `q` as `t` is (`t` itself included), so rank 1 is the best.
//!
//! - **Node R@K.** A ground-truth node `g` is retrieved at K when some predicted node `p` *of the
//!   same kind* has a 3D box IoU > 0 with it and `g`'s label ranks within the top K of the
//!   node-label vocabulary by similarity to `p`'s label. Reported for objects, parts and overall
//!   (objects and parts pooled).
//! - **Strict node R@K**: the same with IoU ≥ 0.10, and with IoP ≥ 0.25 (intersection over the
//!   *predicted* box's volume) instead of IoU > 0. The paper reports them at K = 3.
//! - **Affordance R@K.** Every (ground-truth node, affordance) pair is one item. It is retrieved
//!   when some predicted node of the same kind with IoU > 0 with the node carries an affordance
//!   whose phrase ranks the ground-truth affordance within the top K of the affordance
//!   vocabulary — "solely based on affordance phrase similarity, independent of node label".
//! - **Functional / spatial triplet R@K.** A ground-truth edge `(s, r, t)` is retrieved at K when
//!   a predicted edge of the same kind `(s', r', t')` has `s'` retrieving `s` at K, `t'`
//!   retrieving `t` at K (both by the node criterion above) and `r` ranks within the top K of
//!   that kind's relation vocabulary by similarity to `r'`.
//! - **Associated node R@K.** Every ground-truth edge (functional or spatial) gives an unordered
//!   node pair (duplicates counted once). A pair is retrieved at K when some predicted edge, of
//!   either kind and in either direction, joins two predicted nodes that retrieve its two nodes
//!   at K. The relation label is ignored.
//! - K = 3, 5 and 10 ([`KS`]).
//!
//! ## Choices the paper leaves open
//!
//! - **Vocabularies.** The node-label vocabulary is the set of ground-truth labels of the whole
//!   benchmark (one vocabulary for all scenes of a run; for two files, the ground truth file's
//!   labels, optionally extended with `--vocabulary`), objects and parts together. A label with
//!   alternatives (`handle / knob`) contributes each alternative as its own entry, and the node
//!   counts as retrieved when *any* alternative ranks within K. The relation vocabularies are
//!   the canonical phrases (`op3dsg_ipc_types::FUNCTIONAL_RELATIONS`, `SPATIAL_RELATIONS`) plus
//!   any other phrase the ground truth uses; the affordance vocabulary is the 9 canonical
//!   affordances, written as phrases (`hook_pull` → `hook pull`). With 9 affordances and 7
//!   spatial phrases, R@10 is trivially satisfied for the phrase part of those metrics.
//! - **Ties** count against the prediction (a vocabulary entry as similar as the ground-truth
//!   text ranks before it), so a degenerate similarity cannot retrieve anything by accident.
//! - **Kinds.** Predicted and ground-truth nodes are only paired within a kind (object with
//!   object, part with part): otherwise a predicted `cabinet` overlapping a ground-truth
//!   `cabinet handle` would retrieve the handle through the label ranking alone.
//! - **No one-to-one assignment**, as in the retrieval protocol the paper follows: one predicted
//!   node may retrieve several ground-truth nodes. [`RecallReport`] also counts predicted nodes
//!   that retrieve nothing, so over-merged or spurious predictions stay visible.
//! - **Direction.** Triplets are directed (`handle part of cabinet`, `remote remote to control
//!   tv`), except `next to`, which matches in either direction.
//! - **Boxes** are the axis-aligned boxes of the JSON files. A box with zero extent along an axis
//!   has zero volume: its IoU is 0 and its IoP is 0.
//! - **Scoring set.** `op3dsg eval` scores every ground-truth node, edge and affordance. The
//!   synthetic benchmark passes an eligibility filter: nodes the camera saw in fewer keyframes
//!   than fusion evaluation's `min_visible_keyframes` (3) are not scored, nor edges and
//!   affordances that involve them (a scan only covers what it saw; see
//!   [`crate::eval::fusion_match`]).
//!
//! ## The code
//!
//! | module | what |
//! |---|---|
//! | `vocabulary` | [`Vocabulary`]: the texts ranked against, and [`affordance_phrase`] |
//! | `evaluator` | [`RecallEvaluator`]: the embedding cache, ranking, and the order of an evaluation's stages |
//! | `nodes` | box overlaps ([`box_overlap`]), node R@K (plain and strict) and affordance R@K |
//! | `triplets` | functional and spatial triplet R@K, associated node-pair R@K |
//! | `report` | [`text_report`] |
//!
//! This module holds the protocol's constants, the [`PhraseEmbedder`] seam and the figures and
//! per-item results an evaluation returns.

use serde::Serialize;

mod evaluator;
mod nodes;
mod report;
#[cfg(test)]
mod tests;
mod triplets;
mod vocabulary;

pub use evaluator::RecallEvaluator;
pub use nodes::box_overlap;
pub use report::text_report;
pub use vocabulary::{Vocabulary, affordance_phrase};

/// The K of R@K, in the order every per-K array uses.
pub const KS: [usize; 3] = [3, 5, 10];
/// Index of K = 3 in [`KS`].
pub const K3: usize = 0;
/// Index of K = 5 in [`KS`].
pub const K5: usize = 1;
/// Index of K = 10 in [`KS`].
pub const K10: usize = 2;
/// IoU threshold of the strict IoU variant.
pub const STRICT_IOU: f32 = 0.10;
/// IoP threshold of the strict IoP variant.
pub const STRICT_IOP: f32 = 0.25;

/// Turns phrases into embeddings whose dot product is their similarity (unit vectors).
pub trait PhraseEmbedder {
    /// One unit vector per phrase, in order. The error names what failed.
    fn embed(&mut self, phrases: &[&str]) -> Result<Vec<Vec<f32>>, String>;
}

impl PhraseEmbedder for op3dsg_runtime::onnx::text_encoder::TextEncoder {
    fn embed(&mut self, phrases: &[&str]) -> Result<Vec<Vec<f32>>, String> {
        let embeddings = self.encode_batch(phrases).map_err(|e| e.to_string())?;
        Ok(embeddings.iter().map(|e| e.to_vec()).collect())
    }
}

/// Retrieved items out of a total, per K.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct Recall {
    /// Items scored.
    pub total: usize,
    /// Items retrieved at each K of [`KS`].
    pub retrieved: [usize; 3],
}

impl Recall {
    /// Recall at `KS[k]` in percent; `None` without items.
    pub fn percent(&self, k: usize) -> Option<f64> {
        (self.total > 0).then(|| 100.0 * self.retrieved[k] as f64 / self.total as f64)
    }

    /// Adds another count.
    pub fn add(&mut self, other: &Recall) {
        self.total += other.total;
        for (a, b) in self.retrieved.iter_mut().zip(other.retrieved) {
            *a += b;
        }
    }

    /// Counts one more item, retrieved at rank `retrieved_at` (`None`: not at all).
    fn count(&mut self, retrieved_at: Option<usize>) {
        self.total += 1;
        if let Some(rank) = retrieved_at {
            for (count, k) in self.retrieved.iter_mut().zip(KS) {
                *count += usize::from(rank <= k);
            }
        }
    }
}

/// All figures of one evaluation (or of several added together).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct RecallFigures {
    /// Object node R@K.
    pub object: Recall,
    /// Part node R@K.
    pub part: Recall,
    /// Object and part nodes together.
    pub overall: Recall,
    /// Object node R@K with IoU ≥ 0.10.
    pub object_iou10: Recall,
    /// Part node R@K with IoU ≥ 0.10.
    pub part_iou10: Recall,
    /// Overall node R@K with IoU ≥ 0.10.
    pub overall_iou10: Recall,
    /// Object node R@K with IoP ≥ 0.25.
    pub object_iop25: Recall,
    /// Part node R@K with IoP ≥ 0.25.
    pub part_iop25: Recall,
    /// Overall node R@K with IoP ≥ 0.25.
    pub overall_iop25: Recall,
    /// Affordance R@K.
    pub affordance: Recall,
    /// Functional triplet R@K.
    pub functional: Recall,
    /// Spatial triplet R@K.
    pub spatial: Recall,
    /// Associated node-pair R@K.
    pub associated: Recall,
    /// Predicted nodes.
    pub predicted_nodes: usize,
    /// Predicted nodes that retrieve no scored ground-truth node at K = 10.
    pub predicted_unmatched: usize,
}

impl RecallFigures {
    /// Adds another evaluation's counts (a benchmark pools its scenes).
    pub fn add(&mut self, o: &RecallFigures) {
        self.object.add(&o.object);
        self.part.add(&o.part);
        self.overall.add(&o.overall);
        self.object_iou10.add(&o.object_iou10);
        self.part_iou10.add(&o.part_iou10);
        self.overall_iou10.add(&o.overall_iou10);
        self.object_iop25.add(&o.object_iop25);
        self.part_iop25.add(&o.part_iop25);
        self.overall_iop25.add(&o.overall_iop25);
        self.affordance.add(&o.affordance);
        self.functional.add(&o.functional);
        self.spatial.add(&o.spatial);
        self.associated.add(&o.associated);
        self.predicted_nodes += o.predicted_nodes;
        self.predicted_unmatched += o.predicted_unmatched;
    }
}

/// What became of one scored ground-truth node.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct NodeResult {
    /// Ground-truth id.
    pub id: u32,
    /// `object` or `part`.
    pub kind: String,
    /// Ground-truth label.
    pub label: String,
    /// Best rank of its label over the predicted nodes of its kind with IoU > 0 (`None`: no
    /// predicted node of its kind overlaps it).
    pub best_rank: Option<usize>,
    /// The predicted label that gave `best_rank`.
    pub best_predicted_label: Option<String>,
    /// The 3D box IoU of the predicted node that gave `best_rank` with this node.
    pub best_iou: Option<f32>,
}

/// Why a ground-truth edge is not retrieved at some K.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
pub enum EdgeMiss {
    /// Its source or target node is not retrieved at K.
    EndpointNotRetrieved,
    /// Both nodes are retrieved, but no predicted edge of its kind joins them.
    MissingEdge,
    /// A predicted edge joins them, but its relation phrase ranks the ground truth's below K.
    WrongRelation,
}

impl EdgeMiss {
    /// Short text for tables.
    pub fn as_str(self) -> &'static str {
        match self {
            EdgeMiss::EndpointNotRetrieved => "endpoint not retrieved",
            EdgeMiss::MissingEdge => "missing edge",
            EdgeMiss::WrongRelation => "wrong relation",
        }
    }
}

/// What became of one scored ground-truth edge.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct EdgeResult {
    /// Source id (ground truth).
    pub source: u32,
    /// Target id (ground truth).
    pub target: u32,
    /// `functional` or `spatial`.
    pub kind: String,
    /// Relation phrase.
    pub relation: String,
    /// Per K of [`KS`]: `None` when retrieved, else why not.
    pub miss: [Option<EdgeMiss>; 3],
}

/// Why a ground-truth affordance is not retrieved at some K.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize)]
pub enum AffordanceMiss {
    /// No predicted node of the node's kind overlaps it.
    NoNode,
    /// Overlapping nodes exist, but none carries an affordance close enough.
    WrongAffordance,
}

/// What became of one scored ground-truth affordance.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct AffordanceResult {
    /// Ground-truth node id.
    pub node: u32,
    /// Affordance name.
    pub affordance: String,
    /// Per K of [`KS`]: `None` when retrieved, else why not.
    pub miss: [Option<AffordanceMiss>; 3],
}

/// The result of [`RecallEvaluator::evaluate`].
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct RecallReport {
    /// The figures.
    pub figures: RecallFigures,
    /// Per scored ground-truth node.
    pub nodes: Vec<NodeResult>,
    /// Per scored ground-truth edge.
    pub edges: Vec<EdgeResult>,
    /// Per scored ground-truth affordance.
    pub affordances: Vec<AffordanceResult>,
}

impl RecallReport {
    /// The plain node, affordance and triplet recalls over the items that involve the
    /// ground-truth nodes `involved` selects: those nodes, their affordances, and the edges with
    /// such a node at either end (the strict, associated and predicted-node counts stay zero).
    pub fn subset(&self, involved: &dyn Fn(u32) -> bool) -> RecallFigures {
        let mut f = RecallFigures::default();
        for node in self.nodes.iter().filter(|n| involved(n.id)) {
            let bucket = if node.kind == "object" { &mut f.object } else { &mut f.part };
            bucket.count(node.best_rank);
            f.overall.count(node.best_rank);
        }
        let at = |miss: &[Option<bool>; 3]| -> Option<usize> {
            KS.iter().zip(miss).find(|(_, m)| m.is_none()).map(|(k, _)| *k)
        };
        for a in self.affordances.iter().filter(|a| involved(a.node)) {
            f.affordance.count(at(&a.miss.map(|m| m.map(|_| true))));
        }
        for e in self.edges.iter().filter(|e| involved(e.source) || involved(e.target)) {
            let bucket = if e.kind == "functional" { &mut f.functional } else { &mut f.spatial };
            bucket.count(at(&e.miss.map(|m| m.map(|_| true))));
        }
        f
    }
}
