//! Mapping the free labels of an answer onto the canonical tables: by normalised text, and with
//! a phrase embedder by the nearest canonical phrase.

use op3dsg_ipc_types::{AFFORDANCES, FUNCTIONAL_RELATION_BASE, FUNCTIONAL_RELATIONS};

use crate::embedding::{Embedding, PhraseEmbedder, cosine};

/// Lower case; `_`, `-` and punctuation as spaces; whitespace collapsed.
pub fn normalise(label: &str) -> String {
    let cleaned: String = label.to_lowercase().chars().map(|c| if c.is_alphanumeric() { c } else { ' ' }).collect();
    cleaned.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// One canonical table with its normalised forms and (lazily) its embeddings.
pub(super) struct Table {
    phrases: &'static [&'static str],
    normalised: Vec<String>,
    embeddings: Option<Vec<Embedding>>,
}

impl Table {
    fn new(phrases: &'static [&'static str]) -> Self {
        Self { phrases, normalised: phrases.iter().map(|p| normalise(p)).collect(), embeddings: None }
    }
}

/// Maps free labels onto the canonical tables.
pub struct LabelMapper {
    relations: Table,
    affordances: Table,
    embedder: Option<Box<dyn PhraseEmbedder>>,
    min_similarity: f32,
}

impl std::fmt::Debug for LabelMapper {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LabelMapper")
            .field("embedder", &self.embedder.is_some())
            .field("min_similarity", &self.min_similarity)
            .finish()
    }
}

impl LabelMapper {
    /// A mapper; `embedder` enables the nearest-phrase fallback at `min_similarity`.
    pub fn new(embedder: Option<Box<dyn PhraseEmbedder>>, min_similarity: f32) -> Self {
        Self {
            relations: Table::new(&FUNCTIONAL_RELATIONS),
            affordances: Table::new(&AFFORDANCES),
            embedder,
            min_similarity,
        }
    }

    fn map(table: &mut Table, embedder: &mut Option<Box<dyn PhraseEmbedder>>, min: f32, label: &str) -> Option<usize> {
        if let Some(i) = table.phrases.iter().position(|p| *p == label) {
            return Some(i);
        }
        let key = normalise(label);
        if let Some(i) = table.normalised.iter().position(|p| *p == key) {
            return Some(i);
        }
        let embedder = embedder.as_mut()?;
        if key.is_empty() {
            return None;
        }
        if table.embeddings.is_none() {
            // Embedded as normalised text ("hook pull"), like the labels compared with them.
            let phrases: Vec<&str> = table.normalised.iter().map(String::as_str).collect();
            match embedder.embed(&phrases) {
                Ok(e) if e.len() == phrases.len() => table.embeddings = Some(e),
                Ok(_) | Err(_) => return None,
            }
        }
        let embedded = embedder.embed(&[key.as_str()]).ok()?;
        let query = embedded.first()?;
        let (best, similarity) = table
            .embeddings
            .as_ref()?
            .iter()
            .enumerate()
            .map(|(i, e)| (i, cosine(query, e)))
            .max_by(|a, b| a.1.total_cmp(&b.1))?;
        (similarity >= min).then_some(best)
    }

    /// Canonical functional relation id for `label`.
    pub fn relation(&mut self, label: &str) -> Option<u16> {
        Self::map(&mut self.relations, &mut self.embedder, self.min_similarity, label)
            .map(|i| FUNCTIONAL_RELATION_BASE + i as u16)
    }

    /// Affordance bit index for `label`.
    pub fn affordance(&mut self, label: &str) -> Option<usize> {
        Self::map(&mut self.affordances, &mut self.embedder, self.min_similarity, label)
    }
}
