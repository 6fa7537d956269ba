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

use std::collections::{HashMap, HashSet};
use std::fmt::Write as _;

use glam::Vec3;
use op3dsg_drivers::graph_json::GraphJson;
use serde::Serialize;

use crate::eval::fusion_match::{label_alternatives, normalise_label};

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

/// The vocabularies texts are ranked in (see the module docs).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Vocabulary {
    /// Node labels (normalised, alternatives split), objects and parts together.
    pub node_labels: Vec<String>,
    /// Functional relation phrases.
    pub functional: Vec<String>,
    /// Spatial relation phrases.
    pub spatial: Vec<String>,
    /// Affordance phrases (`hook pull`).
    pub affordances: Vec<String>,
}

fn push_unique(into: &mut Vec<String>, text: String) {
    if !text.is_empty() && !into.contains(&text) {
        into.push(text);
    }
}

/// `hook_pull` → `hook pull`.
pub fn affordance_phrase(name: &str) -> String {
    normalise_label(&name.replace('_', " "))
}

impl Vocabulary {
    /// The canonical relation and affordance vocabularies with no node labels.
    pub fn canonical() -> Self {
        let mut v = Self::default();
        for p in op3dsg_ipc_types::FUNCTIONAL_RELATIONS {
            push_unique(&mut v.functional, normalise_label(p));
        }
        for p in op3dsg_ipc_types::SPATIAL_RELATIONS {
            push_unique(&mut v.spatial, normalise_label(p));
        }
        for a in op3dsg_ipc_types::AFFORDANCES {
            push_unique(&mut v.affordances, affordance_phrase(a));
        }
        v
    }

    /// Adds the labels, relation phrases and affordances of a ground-truth graph.
    pub fn add_ground_truth(&mut self, gt: &GraphJson) {
        for node in &gt.nodes {
            for alternative in label_alternatives(&node.label) {
                push_unique(&mut self.node_labels, alternative);
            }
            for a in &node.affordances {
                push_unique(&mut self.affordances, affordance_phrase(a));
            }
        }
        for edge in &gt.edges {
            let phrase = normalise_label(&edge.relation);
            match edge.kind.as_str() {
                "functional" => push_unique(&mut self.functional, phrase),
                _ => push_unique(&mut self.spatial, phrase),
            }
        }
    }

    /// Adds node labels (each split into its alternatives).
    pub fn add_node_labels<'a>(&mut self, labels: impl IntoIterator<Item = &'a str>) {
        for label in labels {
            for alternative in label_alternatives(label) {
                push_unique(&mut self.node_labels, alternative);
            }
        }
    }

    /// The canonical vocabularies plus everything in `gts`.
    pub fn from_ground_truths<'a>(gts: impl IntoIterator<Item = &'a GraphJson>) -> Self {
        let mut v = Self::canonical();
        for gt in gts {
            v.add_ground_truth(gt);
        }
        v
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

/// One predicted node paired with a ground-truth node of its kind whose box it overlaps.
#[derive(Debug, Clone, Copy)]
struct Overlap {
    pred: usize,
    rank: usize,
    iou: f32,
    iop: f32,
}

/// Intersection volume, IoU and IoP (intersection over `pred`'s volume) of two boxes.
pub fn box_overlap(pred_min: Vec3, pred_max: Vec3, gt_min: Vec3, gt_max: Vec3) -> (f32, f32, f32) {
    let size = |min: Vec3, max: Vec3| (max - min).max(Vec3::ZERO);
    let inter = size(pred_min.max(gt_min), pred_max.min(gt_max));
    let inter_volume = inter.x * inter.y * inter.z;
    let pred_volume = {
        let s = size(pred_min, pred_max);
        s.x * s.y * s.z
    };
    let gt_volume = {
        let s = size(gt_min, gt_max);
        s.x * s.y * s.z
    };
    let union = pred_volume + gt_volume - inter_volume;
    let iou = if union > 0.0 { inter_volume / union } else { 0.0 };
    let iop = if pred_volume > 0.0 { inter_volume / pred_volume } else { 0.0 };
    (inter_volume, iou, iop)
}

/// Evaluates predicted graphs against ground truth with one embedder and vocabulary, caching
/// every embedding it computes.
pub struct RecallEvaluator<'a> {
    embedder: &'a mut dyn PhraseEmbedder,
    vocabulary: Vocabulary,
    cache: HashMap<String, Vec<f32>>,
}

impl std::fmt::Debug for RecallEvaluator<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecallEvaluator").field("vocabulary", &self.vocabulary).finish()
    }
}

fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl<'a> RecallEvaluator<'a> {
    /// An evaluator ranking in `vocabulary` with `embedder`.
    pub fn new(embedder: &'a mut dyn PhraseEmbedder, vocabulary: Vocabulary) -> Self {
        Self { embedder, vocabulary, cache: HashMap::new() }
    }

    /// The vocabulary.
    pub fn vocabulary(&self) -> &Vocabulary {
        &self.vocabulary
    }

    /// Embeds every text not yet cached, in one batch.
    fn prepare<'t>(&mut self, texts: impl IntoIterator<Item = &'t str>) -> Result<(), String> {
        let mut missing: Vec<&str> = Vec::new();
        for t in texts {
            if !self.cache.contains_key(t) && !missing.contains(&t) {
                missing.push(t);
            }
        }
        if missing.is_empty() {
            return Ok(());
        }
        let vectors = self.embedder.embed(&missing)?;
        if vectors.len() != missing.len() {
            return Err(format!("the embedder returned {} vectors for {} phrases", vectors.len(), missing.len()));
        }
        for (t, v) in missing.into_iter().zip(vectors) {
            self.cache.insert(t.to_owned(), v);
        }
        Ok(())
    }

    /// Rank of `target` in `vocabulary` by similarity to `query` (both embedded already): the
    /// entries at least as similar as `target`, `target` included.
    fn rank(&self, vocabulary: &[String], query: &str, target: &str) -> usize {
        let q = &self.cache[query];
        let t = dot(q, &self.cache[target]);
        let others = vocabulary.iter().filter(|v| v.as_str() != target && dot(q, &self.cache[v.as_str()]) >= t).count();
        others + 1
    }

    /// Scores `pred` against `gt`. `scored(gt_id)` selects the ground-truth nodes to score
    /// (edges and affordances of unscored nodes are not scored either); `None` scores all.
    /// Ground-truth labels missing from the vocabulary are ranked as if they were in it.
    pub fn evaluate(
        &mut self,
        pred: &GraphJson,
        gt: &GraphJson,
        scored: Option<&dyn Fn(u32) -> bool>,
    ) -> Result<RecallReport, String> {
        let is_scored = |id: u32| scored.is_none_or(|f| f(id));
        let norm = |s: &str| normalise_label(s);
        // Embed everything once.
        let mut texts: Vec<String> = Vec::new();
        let v = &self.vocabulary;
        texts.extend(v.node_labels.iter().chain(&v.functional).chain(&v.spatial).chain(&v.affordances).cloned());
        for n in &pred.nodes {
            texts.push(norm(&n.label));
            texts.extend(n.affordances.iter().map(|a| affordance_phrase(a)));
        }
        for n in &gt.nodes {
            texts.extend(label_alternatives(&n.label));
            texts.extend(n.affordances.iter().map(|a| affordance_phrase(a)));
        }
        for e in pred.edges.iter().chain(&gt.edges) {
            texts.push(norm(&e.relation));
        }
        self.prepare(texts.iter().map(String::as_str))?;
        // Vocabularies extended by ground-truth texts they lack.
        let mut node_vocabulary = self.vocabulary.node_labels.clone();
        let mut functional_vocabulary = self.vocabulary.functional.clone();
        let mut spatial_vocabulary = self.vocabulary.spatial.clone();
        let mut affordance_vocabulary = self.vocabulary.affordances.clone();
        for n in &gt.nodes {
            for a in label_alternatives(&n.label) {
                push_unique(&mut node_vocabulary, a);
            }
            for a in &n.affordances {
                push_unique(&mut affordance_vocabulary, affordance_phrase(a));
            }
        }
        for e in &gt.edges {
            let phrase = norm(&e.relation);
            match e.kind.as_str() {
                "functional" => push_unique(&mut functional_vocabulary, phrase),
                _ => push_unique(&mut spatial_vocabulary, phrase),
            }
        }

        let gt_index: HashMap<u32, usize> = gt.nodes.iter().enumerate().map(|(i, n)| (n.id, i)).collect();
        let pred_index: HashMap<u32, usize> = pred.nodes.iter().enumerate().map(|(i, n)| (n.id, i)).collect();
        let pred_labels: Vec<String> = pred.nodes.iter().map(|n| norm(&n.label)).collect();

        // Node overlaps and ranks.
        let mut overlaps: Vec<Vec<Overlap>> = Vec::with_capacity(gt.nodes.len());
        for g in &gt.nodes {
            let alternatives: Vec<String> = label_alternatives(&g.label).collect();
            let mut list = Vec::new();
            for (pi, p) in pred.nodes.iter().enumerate() {
                if p.kind != g.kind {
                    continue;
                }
                let (inter, iou, iop) = box_overlap(
                    Vec3::from(p.box_min_m),
                    Vec3::from(p.box_max_m),
                    Vec3::from(g.box_min_m),
                    Vec3::from(g.box_max_m),
                );
                if inter <= 0.0 {
                    continue;
                }
                let rank = alternatives
                    .iter()
                    .map(|a| self.rank(&node_vocabulary, &pred_labels[pi], a))
                    .min()
                    .unwrap_or(usize::MAX);
                list.push(Overlap { pred: pi, rank, iou, iop });
            }
            overlaps.push(list);
        }
        // Best rank of a ground-truth node under a criterion on the overlap.
        let best = |gi: usize, accept: &dyn Fn(&Overlap) -> bool| -> Option<usize> {
            overlaps[gi].iter().filter(|o| accept(o)).map(|o| o.rank).min()
        };
        // Predicted nodes retrieving ground-truth node `gi` at K.
        let retrievers = |gi: usize, k: usize| -> HashSet<usize> {
            overlaps[gi].iter().filter(|o| o.rank <= k).map(|o| o.pred).collect()
        };

        let mut report = RecallReport::default();
        let f = &mut report.figures;
        f.predicted_nodes = pred.nodes.len();
        let mut pred_used = vec![false; pred.nodes.len()];
        for (gi, g) in gt.nodes.iter().enumerate() {
            if !is_scored(g.id) {
                continue;
            }
            let any = best(gi, &|_| true);
            let iou10 = best(gi, &|o| o.iou >= STRICT_IOU);
            let iop25 = best(gi, &|o| o.iop >= STRICT_IOP);
            let (node, strict_iou, strict_iop) = match g.kind.as_str() {
                "object" => (&mut f.object, &mut f.object_iou10, &mut f.object_iop25),
                "part" => (&mut f.part, &mut f.part_iou10, &mut f.part_iop25),
                _ => continue,
            };
            node.count(any);
            strict_iou.count(iou10);
            strict_iop.count(iop25);
            f.overall.count(any);
            f.overall_iou10.count(iou10);
            f.overall_iop25.count(iop25);
            for o in overlaps[gi].iter().filter(|o| o.rank <= KS[K10]) {
                pred_used[o.pred] = true;
            }
            let best_overlap = overlaps[gi].iter().min_by_key(|o| o.rank);
            report.nodes.push(NodeResult {
                id: g.id,
                kind: g.kind.clone(),
                label: g.label.clone(),
                best_rank: best_overlap.map(|o| o.rank),
                best_predicted_label: best_overlap.map(|o| pred.nodes[o.pred].label.clone()),
            });
        }
        f.predicted_unmatched = pred_used.iter().filter(|u| !**u).count();

        // Affordances.
        for (gi, g) in gt.nodes.iter().enumerate() {
            if !is_scored(g.id) {
                continue;
            }
            for a in &g.affordances {
                let target = affordance_phrase(a);
                let mut best_rank: Option<usize> = None;
                for o in &overlaps[gi] {
                    for pa in &pred.nodes[o.pred].affordances {
                        let rank = self.rank(&affordance_vocabulary, &affordance_phrase(pa), &target);
                        best_rank = Some(best_rank.map_or(rank, |b| b.min(rank)));
                    }
                }
                f.affordance.count(best_rank);
                let miss = std::array::from_fn(|k| match best_rank {
                    Some(r) if r <= KS[k] => None,
                    _ if overlaps[gi].is_empty() => Some(AffordanceMiss::NoNode),
                    _ => Some(AffordanceMiss::WrongAffordance),
                });
                report.affordances.push(AffordanceResult { node: g.id, affordance: a.clone(), miss });
            }
        }

        // Predicted edges by kind, as node indices.
        let pred_edges: Vec<(usize, usize, &str, String)> = pred
            .edges
            .iter()
            .filter_map(|e| {
                let s = *pred_index.get(&e.source)?;
                let t = *pred_index.get(&e.target)?;
                Some((s, t, e.kind.as_str(), norm(&e.relation)))
            })
            .collect();

        // Triplets.
        let mut pairs: HashSet<(u32, u32)> = HashSet::new();
        let mut pair_list: Vec<(usize, usize)> = Vec::new();
        for e in &gt.edges {
            let (Some(&si), Some(&ti)) = (gt_index.get(&e.source), gt_index.get(&e.target)) else { continue };
            if !(is_scored(e.source) && is_scored(e.target)) {
                continue;
            }
            let key = (e.source.min(e.target), e.source.max(e.target));
            if pairs.insert(key) {
                pair_list.push((si, ti));
            }
            let relation = norm(&e.relation);
            let functional = e.kind == "functional";
            let vocabulary = if functional { &functional_vocabulary } else { &spatial_vocabulary };
            let symmetric = relation == "next to";
            let mut miss = [None; 3];
            for (k_index, k) in KS.into_iter().enumerate() {
                let sources = retrievers(si, k);
                let targets = retrievers(ti, k);
                if sources.is_empty() || targets.is_empty() {
                    miss[k_index] = Some(EdgeMiss::EndpointNotRetrieved);
                    continue;
                }
                let joins = |ps: usize, pt: usize| {
                    (sources.contains(&ps) && targets.contains(&pt))
                        || (symmetric && sources.contains(&pt) && targets.contains(&ps))
                };
                let candidates: Vec<&String> = pred_edges
                    .iter()
                    .filter(|(ps, pt, kind, _)| *kind == e.kind && joins(*ps, *pt))
                    .map(|(_, _, _, r)| r)
                    .collect();
                if candidates.is_empty() {
                    miss[k_index] = Some(EdgeMiss::MissingEdge);
                    continue;
                }
                let best_rank =
                    candidates.iter().map(|r| self.rank(vocabulary, r, &relation)).min().unwrap_or(usize::MAX);
                if best_rank > k {
                    miss[k_index] = Some(EdgeMiss::WrongRelation);
                }
            }
            let counter = if functional { &mut f.functional } else { &mut f.spatial };
            counter.total += 1;
            for (k_index, m) in miss.iter().enumerate() {
                counter.retrieved[k_index] += usize::from(m.is_none());
            }
            report.edges.push(EdgeResult {
                source: e.source,
                target: e.target,
                kind: e.kind.clone(),
                relation: e.relation.clone(),
                miss,
            });
        }

        // Associated node pairs.
        for (si, ti) in pair_list {
            f.associated.total += 1;
            for (k_index, k) in KS.into_iter().enumerate() {
                let sources = retrievers(si, k);
                let targets = retrievers(ti, k);
                let joined = pred_edges.iter().any(|(ps, pt, _, _)| {
                    (sources.contains(ps) && targets.contains(pt)) || (sources.contains(pt) && targets.contains(ps))
                });
                f.associated.retrieved[k_index] += usize::from(joined);
            }
        }
        Ok(report)
    }
}

fn cell(recall: &Recall, k: usize) -> String {
    recall.percent(k).map_or_else(|| "-".to_owned(), |p| format!("{p:.1}"))
}

/// A text report of one evaluation: the figures with their counts, then the misses at K = 3.
pub fn text_report(report: &RecallReport) -> String {
    let f = &report.figures;
    let mut s = String::new();
    let _ = writeln!(s, "{:<26} {:>7} {:>7} {:>7} {:>7}", "metric", "items", "R@3", "R@5", "R@10");
    let rows: [(&str, &Recall); 13] = [
        ("object node", &f.object),
        ("part node", &f.part),
        ("overall node", &f.overall),
        ("object node IoU>=0.10", &f.object_iou10),
        ("part node IoU>=0.10", &f.part_iou10),
        ("overall node IoU>=0.10", &f.overall_iou10),
        ("object node IoP>=0.25", &f.object_iop25),
        ("part node IoP>=0.25", &f.part_iop25),
        ("overall node IoP>=0.25", &f.overall_iop25),
        ("affordance", &f.affordance),
        ("functional triplet", &f.functional),
        ("spatial triplet", &f.spatial),
        ("associated node", &f.associated),
    ];
    for (name, r) in rows {
        let _ = writeln!(s, "{:<26} {:>7} {:>7} {:>7} {:>7}", name, r.total, cell(r, K3), cell(r, K5), cell(r, K10));
    }
    let _ = writeln!(
        s,
        "predicted nodes {}, of which {} retrieve no ground-truth node at R@10",
        f.predicted_nodes, f.predicted_unmatched
    );
    let missed: Vec<&NodeResult> = report.nodes.iter().filter(|n| n.best_rank.is_none_or(|r| r > KS[K3])).collect();
    if !missed.is_empty() {
        let _ = writeln!(s, "\nnodes not retrieved at R@3:");
        for n in missed {
            match (&n.best_rank, &n.best_predicted_label) {
                (Some(rank), Some(label)) => {
                    let _ = writeln!(
                        s,
                        "  {} {} '{}': best overlapping '{}' ranks it {rank}",
                        n.kind, n.id, n.label, label
                    );
                }
                _ => {
                    let _ = writeln!(s, "  {} {} '{}': no predicted {} overlaps it", n.kind, n.id, n.label, n.kind);
                }
            }
        }
    }
    let missed: Vec<&EdgeResult> = report.edges.iter().filter(|e| e.miss[K3].is_some()).collect();
    if !missed.is_empty() {
        let _ = writeln!(s, "\nedges not retrieved at R@3:");
        for e in missed {
            let why = e.miss[K3].map_or("", EdgeMiss::as_str);
            let _ = writeln!(s, "  {} {} --[{}]--> {}: {why}", e.kind, e.source, e.relation, e.target);
        }
    }
    s
}

#[cfg(test)]
mod tests {
    use op3dsg_drivers::graph_json::{EdgeJson, NodeJson};

    use super::*;

    /// Embeds a phrase as a fixed vector from a table: texts in the same group share a
    /// direction, so their similarity is high; groups are orthogonal; `near` pairs get a
    /// similarity between.
    struct TableEmbedder {
        dims: HashMap<String, Vec<f32>>,
        calls: usize,
    }

    impl TableEmbedder {
        fn new(entries: &[(&str, &[f32])]) -> Self {
            let dims = entries
                .iter()
                .map(|(t, v)| {
                    let norm = v.iter().map(|x| x * x).sum::<f32>().sqrt();
                    ((*t).to_owned(), v.iter().map(|x| x / norm).collect())
                })
                .collect();
            Self { dims, calls: 0 }
        }
    }

    impl PhraseEmbedder for TableEmbedder {
        fn embed(&mut self, phrases: &[&str]) -> Result<Vec<Vec<f32>>, String> {
            self.calls += 1;
            phrases.iter().map(|p| self.dims.get(*p).cloned().ok_or_else(|| format!("no vector for '{p}'"))).collect()
        }
    }

    /// One-hot vectors over 16 dimensions for every phrase the tests use, with a few synonyms
    /// made close.
    fn embedder() -> TableEmbedder {
        let mut entries: Vec<(String, Vec<f32>)> = Vec::new();
        let one_hot = |i: usize| {
            let mut v = vec![0.0f32; 40];
            v[i] = 1.0;
            v
        };
        let labels = [
            "cabinet",
            "drawer",
            "sink",
            "tv",
            "cabinet handle",
            "drawer handle",
            "knob",
            "handle",
            "faucet",
            "remote control",
            "lamp",
            "chair",
        ];
        for (i, l) in labels.iter().enumerate() {
            entries.push(((*l).to_owned(), one_hot(i)));
        }
        // "cupboard" is close to "cabinet", then to "drawer".
        let mut cupboard = one_hot(0);
        cupboard[1] = 0.5;
        entries.push(("cupboard".to_owned(), cupboard));
        // A predicted "pull" is as close to four handle-ish labels, "handle" best.
        let mut pull = vec![0.0f32; 40];
        pull[4] = 0.8;
        pull[5] = 0.8;
        pull[7] = 0.9;
        pull[6] = 0.7;
        entries.push(("pull".to_owned(), pull));
        let mut offset = labels.len();
        for p in op3dsg_ipc_types::FUNCTIONAL_RELATIONS.iter().chain(&op3dsg_ipc_types::SPATIAL_RELATIONS) {
            entries.push(((*p).to_owned(), one_hot(offset)));
            offset += 1;
        }
        let mut opens = one_hot(labels.len()); // "pull to open or close"
        opens[labels.len() + 10] = 0.9; // close to "rotate to open or close"
        entries.push(("open it".to_owned(), opens));
        for a in op3dsg_ipc_types::AFFORDANCES {
            entries.push((affordance_phrase(a), one_hot(offset % 40)));
            offset += 1;
        }
        let refs: Vec<(&str, &[f32])> = entries.iter().map(|(t, v)| (t.as_str(), v.as_slice())).collect();
        TableEmbedder::new(&refs)
    }

    fn node(id: u32, label: &str, kind: &str, min: [f32; 3], max: [f32; 3]) -> NodeJson {
        NodeJson {
            id,
            label: label.to_owned(),
            kind: kind.to_owned(),
            parent: None,
            centre_m: [(min[0] + max[0]) / 2.0, (min[1] + max[1]) / 2.0, (min[2] + max[2]) / 2.0],
            box_min_m: min,
            box_max_m: max,
            affordances: Vec::new(),
            confidence: 1.0,
            observation_count: 0,
        }
    }

    fn edge(source: u32, target: u32, kind: &str, relation: &str) -> EdgeJson {
        EdgeJson {
            source,
            target,
            kind: kind.to_owned(),
            relation: relation.to_owned(),
            confidence: 1.0,
            origin: "ground_truth".to_owned(),
        }
    }

    /// Ground truth: two cabinets, a sink, their handles and a faucet, with edges.
    fn ground_truth() -> GraphJson {
        let mut gt = GraphJson::new("test");
        gt.nodes = vec![
            node(1, "cabinet", "object", [0.0, 0.0, 0.0], [0.6, 0.6, 0.9]),
            node(2, "cabinet", "object", [0.6, 0.0, 0.0], [1.2, 0.6, 0.9]),
            node(3, "sink", "object", [0.0, 0.0, 0.9], [0.6, 0.6, 0.95]),
            node(4, "cabinet handle", "part", [0.5, 0.6, 0.7], [0.52, 0.63, 0.8]),
            node(5, "handle / knob", "part", [1.1, 0.6, 0.7], [1.12, 0.63, 0.8]),
            node(6, "faucet", "part", [0.28, 0.05, 0.95], [0.32, 0.25, 1.2]),
        ];
        gt.nodes[3].affordances = vec!["hook_pull".to_owned()];
        gt.nodes[4].affordances = vec!["hook_pull".to_owned(), "rotate".to_owned()];
        gt.edges = vec![
            edge(4, 1, "spatial", "part of"),
            edge(5, 2, "spatial", "part of"),
            edge(3, 1, "spatial", "on"),
            edge(1, 2, "spatial", "next to"),
            edge(4, 1, "functional", "pull to open or close"),
            edge(5, 2, "functional", "pull to open or close"),
            edge(6, 3, "functional", "control the water flow"),
        ];
        gt
    }

    fn vocabulary(gt: &GraphJson) -> Vocabulary {
        let mut v = Vocabulary::from_ground_truths([gt]);
        v.add_node_labels(["drawer", "tv", "drawer handle", "remote control", "lamp", "chair"]);
        v
    }

    #[test]
    fn a_perfect_prediction_retrieves_everything() {
        let gt = ground_truth();
        let mut pred = gt.clone();
        // "handle / knob" is not a predictable label; the detector says "knob".
        pred.nodes[4].label = "knob".to_owned();
        let mut e = embedder();
        let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
        let report = evaluator.evaluate(&pred, &gt, None).unwrap();
        let f = report.figures;
        for (name, r) in [
            ("object", f.object),
            ("part", f.part),
            ("overall", f.overall),
            ("iou", f.overall_iou10),
            ("iop", f.overall_iop25),
            ("affordance", f.affordance),
            ("functional", f.functional),
            ("spatial", f.spatial),
            ("associated", f.associated),
        ] {
            assert!(r.total > 0, "{name}");
            assert_eq!(r.retrieved, [r.total; 3], "{name}: {r:?}");
        }
        assert_eq!((f.object.total, f.part.total, f.overall.total), (3, 3, 6));
        assert_eq!(f.affordance.total, 3);
        assert_eq!((f.functional.total, f.spatial.total), (3, 4));
        // Pairs: (4,1) (5,2) (3,1) (1,2) (6,3): functional duplicates of part-of pairs count once.
        assert_eq!(f.associated.total, 5);
        assert_eq!(f.predicted_unmatched, 0);
    }

    #[test]
    fn known_recall_on_a_hand_built_prediction() {
        let gt = ground_truth();
        let mut pred = GraphJson::new("pred");
        pred.nodes = vec![
            // Cabinet 1 called "cupboard": ranks "cabinet" first.
            node(10, "cupboard", "object", [0.05, 0.05, 0.05], [0.55, 0.55, 0.85]),
            // Cabinet 2 called "tv": label wrong, so not retrieved at any K ≤ 10? It ranks "cabinet"
            // behind "tv" and every other one-hot label at equal similarity (ties count against).
            node(11, "tv", "object", [0.7, 0.0, 0.0], [1.2, 0.6, 0.9]),
            // Sink box offset so that it does not overlap the ground truth: missed.
            node(12, "sink", "object", [2.0, 2.0, 0.9], [2.6, 2.6, 0.95]),
            // Handle 4 as "pull": "handle" first, "cabinet handle" second (ties with "drawer
            // handle", which counts against): rank 3.
            node(13, "pull", "part", [0.5, 0.6, 0.7], [0.52, 0.63, 0.8]),
            // Handle 5 as "knob", its box only touching the ground truth's 10 % (IoU < 0.10).
            node(14, "knob", "part", [1.1, 0.62, 0.79], [1.2, 0.7, 0.85]),
            // The faucet is an object here: kinds must agree, so it is missed.
            node(15, "faucet", "object", [0.28, 0.05, 0.95], [0.32, 0.25, 1.2]),
        ];
        pred.nodes[3].affordances = vec!["hook_pull".to_owned()];
        pred.nodes[4].affordances = vec!["pinch_pull".to_owned()];
        pred.edges = vec![
            edge(13, 10, "spatial", "part of"),
            edge(14, 11, "spatial", "part of"),
            edge(10, 11, "spatial", "next to"),
            // Relation phrase "open it": ranks "pull to open or close" 1st.
            edge(13, 10, "functional", "open it"),
            // Between retrieved nodes but the wrong relation entirely.
            edge(14, 11, "functional", "provide power"),
        ];
        let mut e = embedder();
        let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
        let report = evaluator.evaluate(&pred, &gt, None).unwrap();
        let f = report.figures;
        // Objects: cabinet 1 retrieved; cabinet 2 ("tv") not; sink not.
        assert_eq!(f.object, Recall { total: 3, retrieved: [1, 1, 1] });
        // Parts: handle 4 rank 3; handle/knob 5 via "knob" rank 1; faucet missed.
        assert_eq!(f.part, Recall { total: 3, retrieved: [2, 2, 2] });
        assert_eq!(f.overall, Recall { total: 6, retrieved: [3, 3, 3] });
        // Strict IoU: node 14 overlaps node 5 by 0.02*0.01*0.01 of a 0.02*0.03*0.1 box; below 0.10.
        assert_eq!(f.part_iou10.retrieved, [1, 1, 1]);
        // Strict IoP: node 14's box mostly outside the ground truth too.
        assert_eq!(f.part_iop25.retrieved, [1, 1, 1]);
        // Affordances: handle 4 hook_pull retrieved; node 5's hook_pull and rotate only at
        // K = 10 (pinch_pull is one-hot elsewhere: every one of the 9 phrases ties, rank 9).
        assert_eq!(f.affordance, Recall { total: 3, retrieved: [1, 1, 3] });
        // Functional: (4 pull 1) retrieved; (5 pull 2) endpoint 2 not retrieved; (6 water 3) not.
        assert_eq!(f.functional, Recall { total: 3, retrieved: [1, 1, 1] });
        let why = |s: u32, t: u32, kind: &str| {
            report.edges.iter().find(|e| e.source == s && e.target == t && e.kind == kind).unwrap().miss[K3]
        };
        assert_eq!(why(5, 2, "functional"), Some(EdgeMiss::EndpointNotRetrieved));
        assert_eq!(why(4, 1, "functional"), None);
        // Spatial: (4 part of 1) retrieved; the rest lack an endpoint.
        assert_eq!(f.spatial, Recall { total: 4, retrieved: [1, 1, 1] });
        assert_eq!(why(1, 2, "spatial"), Some(EdgeMiss::EndpointNotRetrieved));
        // Pairs: only (4,1).
        assert_eq!(f.associated, Recall { total: 5, retrieved: [1, 1, 1] });
        // Predicted nodes retrieving nothing: 11 (tv), 12 (sink elsewhere), 15 (faucet object).
        assert_eq!(f.predicted_unmatched, 3);
        let handle = report.nodes.iter().find(|n| n.id == 4).unwrap();
        assert_eq!((handle.best_rank, handle.best_predicted_label.as_deref()), (Some(3), Some("pull")));
    }

    #[test]
    fn rank_depends_on_k_and_the_relation_phrase() {
        let gt = ground_truth();
        let mut pred = gt.clone();
        pred.nodes[4].label = "knob".to_owned();
        // "open it" ranks "pull to open or close" 1st and "rotate to open or close" 2nd: a
        // predicted "rotate to open or close" ranks the ground truth's "pull ..." only by ties
        // (one-hot): last of 11.
        for e in &mut pred.edges {
            if e.relation == "pull to open or close" {
                e.relation = "rotate to open or close".to_owned();
            }
        }
        let mut e = embedder();
        let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
        let report = evaluator.evaluate(&pred, &gt, None).unwrap();
        assert_eq!(report.figures.functional, Recall { total: 3, retrieved: [1, 1, 1] });
        let miss = report.edges.iter().find(|e| e.source == 4 && e.kind == "functional").unwrap().miss;
        assert_eq!(miss, [Some(EdgeMiss::WrongRelation); 3]);
        // A missing edge between retrieved nodes is told apart.
        let mut pred2 = gt.clone();
        pred2.nodes[4].label = "knob".to_owned();
        pred2.edges.retain(|e| e.relation != "control the water flow");
        let report = evaluator.evaluate(&pred2, &gt, None).unwrap();
        let miss = report.edges.iter().find(|e| e.source == 6).unwrap().miss;
        assert_eq!(miss, [Some(EdgeMiss::MissingEdge); 3]);
        assert_eq!(report.figures.associated.retrieved, [4, 4, 4]);
    }

    #[test]
    fn k_separates_ranks_and_the_filter_limits_the_scored_set() {
        // A one-hot "chair" prediction for cabinet 1 ranks "cabinet" behind every label
        // (ties count against): rank = vocabulary size > 10. With "cupboard" it is first.
        let gt = ground_truth();
        let mut pred = gt.clone();
        pred.nodes[4].label = "knob".to_owned();
        pred.nodes[0].label = "chair".to_owned();
        let mut e = embedder();
        let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
        let report = evaluator.evaluate(&pred, &gt, None).unwrap();
        assert_eq!(report.figures.object.retrieved, [2, 2, 2]);
        // "pull" for the cabinet handle: rank 3, so retrieved at 3, 5 and 10.
        pred.nodes[0].label = "cabinet".to_owned();
        pred.nodes[3].label = "pull".to_owned();
        let report = evaluator.evaluate(&pred, &gt, None).unwrap();
        assert_eq!(report.figures.part.retrieved, [3, 3, 3]);
        // Only score nodes 1..=3: parts and every edge touching them drop out.
        let only_objects = |id: u32| id <= 3;
        let report = evaluator.evaluate(&pred, &gt, Some(&only_objects)).unwrap();
        assert_eq!(report.figures.part.total, 0);
        assert_eq!(report.figures.object.total, 3);
        assert_eq!(report.figures.functional.total, 0);
        assert_eq!(report.figures.spatial.total, 2);
        assert_eq!(report.figures.affordance.total, 0);
    }

    #[test]
    fn a_middle_rank_is_retrieved_at_five_but_not_three() {
        // Build a vocabulary where "pull" ranks "cabinet handle" 4th: add "drawer handle" and
        // "knob" above it by similarity.
        let gt = ground_truth();
        let mut pred = gt.clone();
        pred.nodes[4].label = "knob".to_owned();
        pred.nodes[3].label = "pull".to_owned();
        let mut e = embedder();
        // Make "cabinet handle" less similar than "knob" (0.7) by overriding the "pull" vector.
        let mut pull = [0.0f32; 40];
        pull[4] = 0.6;
        pull[5] = 0.8;
        pull[7] = 0.9;
        pull[6] = 0.7;
        let norm = pull.iter().map(|x| x * x).sum::<f32>().sqrt();
        e.dims.insert("pull".to_owned(), pull.iter().map(|x| x / norm).collect());
        let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
        let report = evaluator.evaluate(&pred, &gt, None).unwrap();
        // handle 4: rank 4 → not at 3, yes at 5 and 10; the other two parts retrieved.
        assert_eq!(report.figures.part.retrieved, [2, 3, 3]);
        // Its triplets follow the node: (4 part of 1) and (4 pull 1) only from K = 5.
        assert_eq!(report.figures.functional.retrieved, [2, 3, 3]);
    }

    #[test]
    fn embeddings_are_computed_once_per_text() {
        let gt = ground_truth();
        let mut pred = gt.clone();
        pred.nodes[4].label = "knob".to_owned();
        let mut e = embedder();
        {
            let mut evaluator = RecallEvaluator::new(&mut e, vocabulary(&gt));
            evaluator.evaluate(&pred, &gt, None).unwrap();
            evaluator.evaluate(&pred, &gt, None).unwrap();
        }
        assert_eq!(e.calls, 1);
    }

    #[test]
    fn box_overlap_figures() {
        let (inter, iou, iop) = box_overlap(Vec3::ZERO, Vec3::splat(1.0), Vec3::splat(0.5), Vec3::splat(1.5));
        assert!((inter - 0.125).abs() < 1e-6);
        assert!((iou - 0.125 / 1.875).abs() < 1e-6);
        assert!((iop - 0.125).abs() < 1e-6);
        // Touching faces: no volume.
        let (inter, iou, iop) = box_overlap(Vec3::ZERO, Vec3::splat(1.0), Vec3::new(1.0, 0.0, 0.0), Vec3::splat(2.0));
        assert_eq!((inter, iou, iop), (0.0, 0.0, 0.0));
        // A flat predicted box has no volume.
        let (_, iou, iop) = box_overlap(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0), Vec3::ZERO, Vec3::splat(1.0));
        assert_eq!((iou, iop), (0.0, 0.0));
    }

    /// The protocol on the real encoder (all-MiniLM-L6-v2; needs `.models/`, fails with the
    /// set-up hint without it): synonyms and compound part names retrieve their ground truth
    /// within the top 3 of the benchmark's vocabulary, an unrelated label does not.
    #[test]
    fn minilm_ranks_synonyms_first() {
        use op3dsg_runtime::onnx::text_encoder::{TextEncoder, TextEncoderConfig};
        use op3dsg_runtime::onnx::{OnnxConfig, OnnxRuntime};
        let runtime = OnnxRuntime::init(&OnnxConfig::default()).unwrap_or_else(|e| panic!("{e}"));
        let mut encoder = TextEncoder::new(&runtime, &TextEncoderConfig::default()).unwrap_or_else(|e| panic!("{e}"));
        let gt = ground_truth();
        let mut vocabulary = vocabulary(&gt);
        vocabulary.add_node_labels(["stove", "stove knob", "fridge", "fridge handle", "toilet", "flush button", "bed"]);
        let mut evaluator = RecallEvaluator::new(&mut encoder, vocabulary);
        let mut pred = gt.clone();
        pred.nodes[0].label = "cupboard".to_owned();
        pred.nodes[2].label = "washbasin".to_owned();
        pred.nodes[3].label = "cupboard handle".to_owned();
        pred.nodes[4].label = "knob".to_owned();
        pred.nodes[5].label = "tap".to_owned();
        let report = evaluator.evaluate(&pred, &gt, None).unwrap();
        let rank = |id: u32| report.nodes.iter().find(|n| n.id == id).and_then(|n| n.best_rank).unwrap();
        for id in [1, 3, 4, 5] {
            assert!(rank(id) <= 3, "node {id}: rank {}", rank(id));
        }
        assert!(rank(6) <= 5, "tap -> faucet: rank {}", rank(6));
        // Relation phrases rank their canonical form first.
        assert_eq!(report.figures.functional.retrieved[K3], report.figures.functional.total);
        pred.nodes[0].label = "banana".to_owned();
        let report = evaluator.evaluate(&pred, &gt, None).unwrap();
        let cabinet = report.nodes.iter().find(|n| n.id == 1).unwrap();
        assert!(cabinet.best_rank.unwrap() > 3, "{cabinet:?}");
    }
}
