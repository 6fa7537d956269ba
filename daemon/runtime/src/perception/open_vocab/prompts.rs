//! The detector's vocabulary: the prompt list (knowledge-guided part candidates) and its
//! encoding into the model's text input, embeddings cached by text.

use std::sync::Arc;

use op3dsg_ipc_types::NodeKind;

use super::PromptConfig;
use crate::knowledge::KnowledgeBase;
use crate::onnx::OnnxError;
use crate::onnx::clip_text::{ClipTextEncoder, ClipTokenizer, Tokens};
use crate::onnx::text_encoder::TextEncoder;
use crate::perception::candidates::{PartCandidates, Prompt, PromptList};

/// The prompt list of `config` (see the module docs).
pub fn prompt_list(config: &PromptConfig, knowledge: Arc<KnowledgeBase>) -> Vec<Prompt> {
    let candidates = PartCandidates::new(knowledge, config.part_prompts);
    let tags: Vec<&str> = config.objects.iter().map(String::as_str).collect();
    let mut list = PromptList::default();
    candidates.prompts(&tags, &mut list);
    for part in &config.parts {
        let text = crate::knowledge::normalise(part);
        let category = candidates.knowledge().resolve(&text);
        list.push(Prompt {
            text,
            kind: NodeKind::Part,
            part: category.as_ref().and_then(|r| r.part()),
            object: category.and_then(|r| r.object_hint),
        });
    }
    list.prompts
}

/// Turns prompts into the model's text input (embeddings or tokens).
pub(super) enum PromptEncoder {
    /// The vocabulary is built into the model.
    None,
    /// MiniLM sentence embeddings (`[text_encoder]`).
    Minilm(TextEncoder),
    /// CLIP text features (`[detector.open_vocab.clip]`).
    Clip(ClipTextEncoder),
    /// CLIP tokens, rows of `length`.
    Tokens { tokenizer: ClipTokenizer, length: usize },
}

/// Prompt embeddings already computed, by text; emptied when it reaches [`PromptCache::MAX`].
#[derive(Default)]
pub(super) struct PromptCache(std::collections::HashMap<String, Vec<f32>>);

impl PromptCache {
    /// Entries kept at most (512-float rows: 8 MiB).
    const MAX: usize = 4096;
}

impl PromptEncoder {
    /// The text input of `prompts`: `[P, dim]` embeddings (new texts encoded, known ones from
    /// `cache`) or tokens.
    pub(super) fn encode(
        &mut self,
        prompts: &[Prompt],
        cache: &mut PromptCache,
        dim: usize,
    ) -> Result<(Vec<f32>, Tokens), OnnxError> {
        let texts: Vec<&str> = prompts.iter().map(|p| p.text.as_str()).collect();
        if texts.is_empty() {
            return Ok((Vec::new(), Tokens::default()));
        }
        let mut missing: Vec<&str> = texts.iter().copied().filter(|t| !cache.0.contains_key(*t)).collect();
        if cache.0.len() + missing.len() > PromptCache::MAX {
            cache.0.clear();
            missing = texts.clone();
        }
        let rows: Vec<Vec<f32>> = match self {
            Self::None => return Ok((Vec::new(), Tokens::default())),
            Self::Tokens { tokenizer, length } => return Ok((Vec::new(), tokenizer.encode(&texts, *length)?)),
            _ if missing.is_empty() => Vec::new(),
            Self::Minilm(encoder) => encoder.encode_batch(&missing)?.iter().map(|row| row.to_vec()).collect(),
            Self::Clip(encoder) => encoder.encode(&missing)?.chunks(dim.max(1)).map(<[f32]>::to_vec).collect(),
        };
        for (text, row) in missing.iter().zip(rows) {
            cache.0.insert((*text).to_owned(), row);
        }
        let embeddings = texts.iter().flat_map(|t| cache.0[*t].iter().copied()).collect();
        Ok((embeddings, Tokens::default()))
    }
}
