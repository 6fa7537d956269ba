//! What the knowledge reasoner does with labels its knowledge base does not know: an
//! open-vocabulary detector names things no table lists.
//!
//! Two fallbacks, tried in this order, each counted in [`FallbackCounts`]:
//!
//! 1. **Nearest known category by text embedding** (only with an embedder, [`SharedEmbedder`]:
//!    the MiniLM text encoder when `[text_encoder] enabled = true`). A node whose label resolves
//!    to nothing is embedded (normalised label) and compared by cosine with every label of the
//!    knowledge base of its own kind (object nodes with object names and synonyms, part nodes
//!    with part names and synonyms). The nearest counts as the node's category when the cosine is
//!    at least [`DEFAULT_MIN_SIMILARITY`]; the node then gets that category's affordances, object-part
//!    pairs and remote templates, with confidences scaled by [`EMBEDDING_CONFIDENCE`]. It is also
//!    a target candidate of remote templates by that category. A "cooker" the tables do not list
//!    is reasoned about as its nearest neighbour, "stove".
//!    A known part on an object whose category is unknown, or whose nearest category has no such
//!    part ("knob" on a "nightstand" the tables lost, nearest "bed"), is reasoned as on the
//!    nearest known category *that has the part* (a "dresser"), by the parent label's embedding,
//!    same threshold and confidence factor.
//! 2. **Part-label rule**. A part whose own label is known ("handle", "knob") on a parent whose
//!    category is unknown, or whose (nearest) category has no such pair, gets what that part
//!    does on most objects of the knowledge base: the most frequent local relation over the
//!    pairs of the part category (ties: the earlier object in the tables), and the affordances
//!    most often given with it. This is how "a handle on X is pulled to open X" and "a knob on X
//!    is rotated to adjust X" come out of the tables without naming X, with confidence
//!    [`RULE_CONFIDENCE`]. The rule is computed from the loaded tables, so a knowledge base that
//!    lacks a category gives the rule of the remaining ones.
//!
//! What it cannot do: the part's geometry is not used (a knob that opens a door and one that
//! sets a temperature look alike in a box), and an unknown object with no known part gets no
//! affordances without an embedder.

use rustc_hash::FxHashMap;
use serde::Serialize;

use super::{Category, KnowledgeBase, ObjectId, PartId, PartPair, normalise};
use crate::embedding::{Embedding, SharedEmbedder, cosine};

/// Least cosine between an unknown label and its nearest known label for the embedding
/// fallback. MiniLM puts synonyms at 0.6-0.9 and unrelated household objects below 0.4.
pub const DEFAULT_MIN_SIMILARITY: f32 = 0.5;
/// Confidence factor of what comes from a category found by embedding.
pub const EMBEDDING_CONFIDENCE: f32 = 0.7;
/// Confidence factor of what comes from the part-label rule.
pub const RULE_CONFIDENCE: f32 = 0.5;

/// How often each fallback was used on one prior graph (or, added up, on several).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize)]
pub struct FallbackCounts {
    /// Nodes with an unknown label given their nearest known category by embedding.
    pub by_embedding: usize,
    /// Nodes with an unknown label left without a category (no embedder, or nothing near).
    pub unresolved: usize,
    /// Parts on an object of unknown category (or of a nearest category without that part)
    /// reasoned as on the nearest known category that has the part, by embedding.
    pub parts_by_embedding: usize,
    /// Parts given a local relation or affordances by the part-label rule.
    pub by_part_rule: usize,
}

impl FallbackCounts {
    /// Adds another count.
    pub fn add(&mut self, other: &FallbackCounts) {
        self.by_embedding += other.by_embedding;
        self.unresolved += other.unresolved;
        self.parts_by_embedding += other.parts_by_embedding;
        self.by_part_rule += other.by_part_rule;
    }
}

/// What a part category does on most objects: the part-label rule.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PartRule {
    /// Most frequent local relation over the part's pairs.
    pub relation_id: Option<u16>,
    /// Affordances most often given with it.
    pub affordance_bits: u16,
}

/// The fallbacks of one knowledge base (module docs).
#[derive(Clone)]
pub struct LabelFallback {
    embedder: Option<SharedEmbedder>,
    min_similarity: f32,
    /// Labels of the knowledge base with their category, and their embeddings once computed.
    table: Vec<(String, Category)>,
    embeddings: Option<Vec<Embedding>>,
    /// Unknown labels already looked up: the nearest category and its cosine.
    cache: FxHashMap<String, Option<(Category, f32)>>,
    rules: Vec<PartRule>,
}

impl std::fmt::Debug for LabelFallback {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LabelFallback")
            .field("embedder", &self.embedder.is_some())
            .field("min_similarity", &self.min_similarity)
            .field("labels", &self.table.len())
            .finish()
    }
}

impl LabelFallback {
    /// The fallbacks of `knowledge`; `embedder` enables the nearest-category one.
    pub fn new(knowledge: &KnowledgeBase, embedder: Option<SharedEmbedder>) -> Self {
        let mut table: Vec<(String, Category)> = knowledge.labels().map(|(l, c)| (l.to_owned(), c)).collect();
        table.sort_by(|a, b| a.0.cmp(&b.0));
        let rules = (0..knowledge.parts().len()).map(|p| part_rule(knowledge, PartId(p as u16))).collect();
        Self {
            embedder,
            min_similarity: DEFAULT_MIN_SIMILARITY,
            table,
            embeddings: None,
            cache: FxHashMap::default(),
            rules,
        }
    }

    /// Whether the embedding fallback is available.
    pub fn has_embedder(&self) -> bool {
        self.embedder.is_some()
    }

    /// The part-label rule of `part`.
    pub fn rule(&self, part: PartId) -> PartRule {
        self.rules.get(part.0 as usize).copied().unwrap_or(PartRule { relation_id: None, affordance_bits: 0 })
    }

    /// The nearest known category of `label` among the labels naming objects (`object`) or
    /// parts, with its cosine; `None` without an embedder, when embedding fails, or when the
    /// nearest is below the threshold.
    pub fn nearest(&mut self, label: &str, object: bool) -> Option<(Category, f32)> {
        let key = normalise(label);
        let cache_key = format!("{}{key}", if object { "o:" } else { "p:" });
        if let Some(hit) = self.cache.get(&cache_key) {
            return *hit;
        }
        let found = self.lookup(&key, object);
        self.cache.insert(cache_key, found);
        found
    }

    /// The nearest known object category of `label` among those `keep` accepts (with its
    /// cosine, at least the threshold): for a part on an object of unknown category, the
    /// nearest known category that has that part. Not cached (the label's embedding is, by the
    /// encoder).
    pub fn nearest_object_where(&mut self, label: &str, keep: &dyn Fn(ObjectId) -> bool) -> Option<(ObjectId, f32)> {
        let key = normalise(label);
        let found = self.search(&key, &|c| matches!(c, Category::Object(o) if keep(o)))?;
        match found {
            (Category::Object(o), s) => Some((o, s)),
            (Category::Part(_), _) => None,
        }
    }

    fn lookup(&mut self, key: &str, object: bool) -> Option<(Category, f32)> {
        self.search(key, &|c| matches!(c, Category::Object(_)) == object)
    }

    fn search(&mut self, key: &str, keep: &dyn Fn(Category) -> bool) -> Option<(Category, f32)> {
        let embedder = self.embedder.as_ref()?;
        if key.is_empty() {
            return None;
        }
        let mut embedder = embedder.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if self.embeddings.is_none() {
            let phrases: Vec<&str> = self.table.iter().map(|(l, _)| l.as_str()).collect();
            match embedder.embed(&phrases) {
                Ok(e) if e.len() == phrases.len() => self.embeddings = Some(e),
                Ok(_) | Err(_) => return None,
            }
        }
        let query = embedder.embed(&[key]).ok()?.into_iter().next()?;
        drop(embedder);
        let embeddings = self.embeddings.as_ref()?;
        let (best, similarity) = self
            .table
            .iter()
            .zip(embeddings)
            .filter(|((_, c), _)| keep(*c))
            .map(|((_, c), e)| (*c, cosine(&query, e)))
            .fold(None, |best: Option<(Category, f32)>, (c, s)| match best {
                Some((_, b)) if b >= s => best,
                _ => Some((c, s)),
            })?;
        (similarity >= self.min_similarity).then_some((best, similarity))
    }
}

/// The most frequent local relation of `part` over the objects that have it (ties: the earlier
/// object), and the affordances most often given with that relation.
fn part_rule(knowledge: &KnowledgeBase, part: PartId) -> PartRule {
    let pairs: Vec<(ObjectId, &PartPair)> = knowledge
        .objects()
        .iter()
        .enumerate()
        .flat_map(|(o, object)| object.parts.iter().map(move |p| (ObjectId(o as u16), p)))
        .filter(|(_, p)| p.part == part)
        .collect();
    let most = |values: Vec<Option<u16>>| -> Option<Option<u16>> {
        let mut counts: Vec<(Option<u16>, usize)> = Vec::new();
        for v in values {
            match counts.iter_mut().find(|(x, _)| *x == v) {
                Some((_, n)) => *n += 1,
                None => counts.push((v, 1)),
            }
        }
        // The first of the most frequent: `max_by_key` keeps the last, so scan by hand.
        let mut best: Option<(Option<u16>, usize)> = None;
        for (v, n) in counts {
            if best.is_none_or(|(_, b)| n > b) {
                best = Some((v, n));
            }
        }
        best.map(|(v, _)| v)
    };
    let with_relation: Vec<Option<u16>> = pairs.iter().map(|(_, p)| p.relation_id).filter(Option::is_some).collect();
    let relation_id = most(with_relation).flatten();
    let bits: Vec<Option<u16>> =
        pairs.iter().filter(|(_, p)| p.relation_id == relation_id).map(|(_, p)| Some(p.affordance_bits)).collect();
    let affordance_bits = most(bits).flatten().unwrap_or(knowledge.part(part).affordance_bits);
    PartRule { relation_id, affordance_bits }
}

#[cfg(test)]
mod tests {
    use std::sync::{Arc, Mutex};

    use op3dsg_ipc_types::relation_phrase;

    use super::*;
    use crate::embedding::{EMBEDDING_DIM, PhraseEmbedder};

    #[test]
    fn part_rules_come_from_the_tables() {
        let kb = KnowledgeBase::builtin().unwrap();
        let fallback = LabelFallback::new(&kb, None);
        let rule = |label: &str| fallback.rule(kb.resolve(label).unwrap().part().unwrap());
        assert_eq!(rule("handle").relation_id.and_then(relation_phrase), Some("pull to open or close"));
        assert!(rule("knob").relation_id.is_some());
    }

    /// Embeds a phrase as a one-hot vector of its first letter: "cooker" is near "cabinet".
    struct Letters;
    impl PhraseEmbedder for Letters {
        fn embed(&mut self, phrases: &[&str]) -> Result<Vec<Embedding>, String> {
            Ok(phrases
                .iter()
                .map(|p| {
                    let mut e = [0.0f32; EMBEDDING_DIM];
                    e[usize::from(p.bytes().next().unwrap_or(b'a')) % e.len()] = 1.0;
                    e
                })
                .collect())
        }
    }

    #[test]
    fn nearest_keeps_to_the_node_kind_and_the_threshold() {
        let kb = KnowledgeBase::builtin().unwrap();
        let shared: SharedEmbedder = Arc::new(Mutex::new(Box::new(Letters)));
        let mut fallback = LabelFallback::new(&kb, Some(shared));
        let (category, similarity) = fallback.nearest("cupboardish", true).unwrap();
        let Category::Object(object) = category else { panic!("{category:?}: not an object") };
        assert!(kb.object(object).name.starts_with('c') && similarity > 0.99, "{category:?} {similarity}");
        // Part nodes are compared with part labels only.
        assert!(fallback.nearest("cupboardish", false).is_none_or(|(c, _)| matches!(c, Category::Part(_))));
        // Nothing starts with the same letter: orthogonal, below the threshold.
        assert!(fallback.nearest("\u{1}", true).is_none());
        assert!(LabelFallback::new(&kb, None).nearest("cupboardish", true).is_none());
    }
}
