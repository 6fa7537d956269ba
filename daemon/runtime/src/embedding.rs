//! Embeddings: fixed-size text embeddings (all-MiniLM-L6-v2's 384 floats), semantic features of
//! any length, their normalisation and cosine, and the [`PhraseEmbedder`] trait through which
//! knowledge, reasoning and queries embed phrases without knowing the model behind it (the text
//! encoder implements it). A leaf: it imports nothing of the stages.

use std::sync::{Arc, Mutex};

/// Length of an embedding.
pub const EMBEDDING_DIM: usize = 384;
/// One label's embedding: unit length (L2), so the dot product is the cosine.
pub type Embedding = [f32; EMBEDDING_DIM];

/// Cosine similarity of two embeddings (both unit length, so the dot product).
pub fn cosine(a: &Embedding, b: &Embedding) -> f32 {
    dot(a, b)
}

/// Dot product of two semantic features (the cosine when both are L2-normalised).
#[inline]
pub fn dot(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(x, y)| x * y).sum()
}

/// L2-normalises a semantic feature in place (a zero vector stays zero).
pub fn normalise(v: &mut [f32]) {
    let norm = dot(v, v).sqrt();
    if norm > 0.0 {
        v.iter_mut().for_each(|x| *x /= norm);
    }
}

/// Embeds phrases for the nearest-canonical-phrase mapping.
pub trait PhraseEmbedder: Send {
    /// Unit-length embeddings of `phrases`, in order.
    fn embed(&mut self, phrases: &[&str]) -> Result<Vec<Embedding>, String>;
}

/// An embedder shared by the reasoners of one thread or benchmark scene (embedding is
/// serialised through the lock).
pub type SharedEmbedder = Arc<Mutex<Box<dyn PhraseEmbedder>>>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cosine_of_unit_vectors() {
        let mut a = [0.0; EMBEDDING_DIM];
        let mut b = [0.0; EMBEDDING_DIM];
        a[0] = 1.0;
        b[0] = 0.6;
        b[1] = 0.8;
        assert!((cosine(&a, &a) - 1.0).abs() < 1e-6);
        assert!((cosine(&a, &b) - 0.6).abs() < 1e-6);
    }
}
