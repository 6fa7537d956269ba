//! The evaluator: embeds every text once (the cache lives as long as the evaluator), ranks a text
//! in a vocabulary by similarity, and runs an evaluation's stages in order (nodes, affordances,
//! triplets and associated pairs).

use std::collections::HashMap;

use op3dsg_drivers::graph_json::GraphJson;

use super::nodes::{self, Overlap};
use super::{PhraseEmbedder, RecallReport, Vocabulary, affordance_phrase, triplets};
use crate::eval::fusion_match::{label_alternatives, normalise_label};

/// Evaluates predicted graphs against ground truth with one embedder and vocabulary, caching
/// every embedding it computes.
pub struct RecallEvaluator<'a> {
    embedder: &'a mut dyn PhraseEmbedder,
    vocabulary: Vocabulary,
    cache: EmbeddingCache,
}

impl std::fmt::Debug for RecallEvaluator<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecallEvaluator").field("vocabulary", &self.vocabulary).finish()
    }
}

/// The embedding of every text seen so far.
#[derive(Default)]
pub(super) struct EmbeddingCache {
    vectors: HashMap<String, Vec<f32>>,
}

fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

impl EmbeddingCache {
    /// Rank of `target` in `vocabulary` by similarity to `query` (both embedded already): the
    /// entries at least as similar as `target`, `target` included.
    pub(super) fn rank(&self, vocabulary: &[String], query: &str, target: &str) -> usize {
        let q = &self.vectors[query];
        let t = dot(q, &self.vectors[target]);
        let others =
            vocabulary.iter().filter(|v| v.as_str() != target && dot(q, &self.vectors[v.as_str()]) >= t).count();
        others + 1
    }
}

/// What the stages of one evaluation share.
pub(super) struct Scoring<'e> {
    /// Embeddings of every text of the evaluation.
    pub(super) cache: &'e EmbeddingCache,
    /// The predicted graph.
    pub(super) pred: &'e GraphJson,
    /// The ground-truth graph.
    pub(super) gt: &'e GraphJson,
    /// The evaluator's vocabulary extended by the ground-truth texts it lacks.
    pub(super) vocabulary: Vocabulary,
    /// Per ground-truth node, the predicted nodes overlapping it ([`nodes::overlaps`]).
    pub(super) overlaps: Vec<Vec<Overlap>>,
    scored: Option<&'e dyn Fn(u32) -> bool>,
}

impl Scoring<'_> {
    /// Whether the ground-truth node `id` is scored.
    pub(super) fn is_scored(&self, id: u32) -> bool {
        self.scored.is_none_or(|f| f(id))
    }
}

impl<'a> RecallEvaluator<'a> {
    /// An evaluator ranking in `vocabulary` with `embedder`.
    pub fn new(embedder: &'a mut dyn PhraseEmbedder, vocabulary: Vocabulary) -> Self {
        Self { embedder, vocabulary, cache: EmbeddingCache::default() }
    }

    /// The vocabulary.
    pub fn vocabulary(&self) -> &Vocabulary {
        &self.vocabulary
    }

    /// Embeds every text not yet cached, in one batch.
    fn prepare<'t>(&mut self, texts: impl IntoIterator<Item = &'t str>) -> Result<(), String> {
        let mut missing: Vec<&str> = Vec::new();
        for t in texts {
            if !self.cache.vectors.contains_key(t) && !missing.contains(&t) {
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
            self.cache.vectors.insert(t.to_owned(), v);
        }
        Ok(())
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
        // Embed everything once.
        let texts = texts_to_embed(&self.vocabulary, pred, gt);
        self.prepare(texts.iter().map(String::as_str))?;
        // Vocabularies extended by ground-truth texts they lack.
        let mut vocabulary = self.vocabulary.clone();
        vocabulary.add_ground_truth(gt);
        let overlaps = nodes::overlaps(&self.cache, pred, gt, &vocabulary.node_labels);
        let scoring = Scoring { cache: &self.cache, pred, gt, vocabulary, overlaps, scored };

        let mut report = RecallReport::default();
        nodes::score_nodes(&scoring, &mut report);
        nodes::score_affordances(&scoring, &mut report);
        triplets::score_edges(&scoring, &mut report);
        Ok(report)
    }
}

/// Every text an evaluation of `pred` against `gt` ranks, in the order they are embedded: the
/// vocabulary, predicted labels and affordances, ground-truth label alternatives and
/// affordances, then every relation phrase.
fn texts_to_embed(vocabulary: &Vocabulary, pred: &GraphJson, gt: &GraphJson) -> Vec<String> {
    let norm = |s: &str| normalise_label(s);
    let mut texts: Vec<String> = Vec::new();
    let v = vocabulary;
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
    texts
}
