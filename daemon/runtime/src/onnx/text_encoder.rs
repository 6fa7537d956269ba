//! Text encoder: a label ("cabinet handle") → a 384-d unit vector, so labels can be compared by
//! cosine similarity (the paper's semantic similarity s^s).
//!
//! The model is all-MiniLM-L6-v2 (Sentence-BERT, the benchmark protocol's text model), int8, as
//! ONNX (`.models/minilm/model.onnx`, inputs `input_ids`, `attention_mask`, `token_type_ids`,
//! output `last_hidden_state` [batch, seq, 384]), with its WordPiece tokenizer read from
//! `tokenizer.json` by the `tokenizers` crate. An embedding is the mean of the token states
//! under the attention mask, L2-normalised, exactly as sentence-transformers computes it;
//! `scripts/reference/text_encoder_reference.py` computes the same with onnxruntime's Python API
//! and printed the reference values the tests assert.
//!
//! Labels repeat constantly (every frame sees the same few dozen), so [`TextEncoder::encode_batch`]
//! answers from a cache first and runs the model once for the labels it has not seen, all of
//! them in one batch (padded to the longest). Cost on the development machine (2 shared cores,
//! one intra-op thread, release): about 2.0-2.2 ms for a single label, 1.1-1.8 ms per label in
//! batches of 16 to 64 (the same as onnxruntime's Python API on the same input); 64 cache hits
//! take about 6 µs (`cargo bench -p op3dsg-runtime --bench text_encoder`).
//!
//! **Ownership.** `ort`'s `Session::run` takes `&mut self`, and so do all encoding methods here:
//! a [`TextEncoder`] belongs to one thread at a time. It is `Send` (build it on one thread, move
//! it to its worker) but deliberately not `Sync`; a pool of workers holds one encoder each.
//!
//! ```no_run
//! use op3dsg_runtime::embedding::cosine;
//! use op3dsg_runtime::onnx::{OnnxConfig, OnnxRuntime, text_encoder::{TextEncoder, TextEncoderConfig}};
//! let runtime = OnnxRuntime::init(&OnnxConfig::default())?;
//! let mut encoder = TextEncoder::new(&runtime, &TextEncoderConfig::default())?;
//! let handles = encoder.encode_batch(&["cabinet handle", "drawer handle", "bathtub"])?;
//! assert!(cosine(&handles[0], &handles[1]) > cosine(&handles[0], &handles[2]));
//! # Ok::<(), op3dsg_runtime::onnx::OnnxError>(())
//! ```

use std::cell::Cell;
use std::collections::HashMap;
use std::marker::PhantomData;
use std::path::{Path, PathBuf};

use ndarray::{Axis, Ix3};
use ort::session::Session;
use ort::value::TensorRef;
use serde::{Deserialize, Serialize};
use tokenizers::Tokenizer;

use super::{OnnxConfig, OnnxError, OnnxRuntime, SessionSpec, open_session, resolve_path};
use crate::embedding::{EMBEDDING_DIM, Embedding, PhraseEmbedder, SharedEmbedder};

/// Labels run through the model in one call at most; longer batches are split (bounds the
/// tensors: 64 x 128 tokens x 384 floats = 12 MB at worst).
pub const MAX_BATCH: usize = 64;
/// The position-embedding table of the model (BERT): no sequence may be longer.
pub const MODEL_MAX_SEQUENCE_LENGTH: usize = 512;

const INPUT_IDS: &str = "input_ids";
const ATTENTION_MASK: &str = "attention_mask";
const TOKEN_TYPE_IDS: &str = "token_type_ids";
const LAST_HIDDEN_STATE: &str = "last_hidden_state";

/// `[text_encoder]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TextEncoderConfig {
    /// Load the encoder at start-up (the daemon stops if its files are missing). Off in the base
    /// profile: the synthetic pipeline needs no model.
    pub enabled: bool,
    /// all-MiniLM-L6-v2 as ONNX. Relative: to the working directory, else the source tree.
    pub model_path: PathBuf,
    /// Its `tokenizer.json`. Relative like `model_path`.
    pub tokenizer_path: PathBuf,
    /// Tokens per label at most, `[CLS]` and `[SEP]` included; longer labels are truncated.
    pub max_sequence_length: usize,
    /// ONNX Runtime intra-op threads for this session (1: the encoder runs on its caller's
    /// thread only and never competes with the pipeline's other threads).
    pub intra_op_threads: usize,
    /// Labels kept in the cache (0 = no cache). When it is full it is emptied and refilled.
    pub cache_capacity: usize,
}

impl Default for TextEncoderConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            model_path: PathBuf::from(".models/minilm/model.onnx"),
            tokenizer_path: PathBuf::from(".models/minilm/tokenizer.json"),
            max_sequence_length: 128,
            intra_op_threads: 1,
            cache_capacity: 4096,
        }
    }
}

impl TextEncoderConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        for (field, value) in [("model_path", &self.model_path), ("tokenizer_path", &self.tokenizer_path)] {
            if value.as_os_str().is_empty() {
                return Err(format!("{path}.{field}: must not be empty"));
            }
        }
        if !(4..=MODEL_MAX_SEQUENCE_LENGTH).contains(&self.max_sequence_length) {
            return Err(format!(
                "{path}.max_sequence_length: must be within [4, {MODEL_MAX_SEQUENCE_LENGTH}], got {}",
                self.max_sequence_length
            ));
        }
        if !(1..=64).contains(&self.intra_op_threads) {
            return Err(format!("{path}.intra_op_threads: must be within [1, 64], got {}", self.intra_op_threads));
        }
        if self.cache_capacity > 1_000_000 {
            return Err(format!("{path}.cache_capacity: must be at most 1000000, got {}", self.cache_capacity));
        }
        Ok(())
    }
}

/// Cache counters since the encoder was made.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct CacheStats {
    /// Labels answered without running the model (from the cache, or a repeat within a batch).
    pub hits: u64,
    /// Labels the model ran for.
    pub misses: u64,
    /// Times the cache was full and emptied.
    pub clears: u64,
    /// Labels in the cache now.
    pub entries: usize,
}

/// all-MiniLM-L6-v2 with its tokenizer, reusable input buffers and a label cache. Owned by one
/// thread (`Send`, not `Sync`); see the module docs.
pub struct TextEncoder {
    session: Session,
    tokenizer: Tokenizer,
    model_path: PathBuf,
    cache: HashMap<Box<str>, Embedding>,
    cache_capacity: usize,
    stats: CacheStats,
    // Model inputs, [batch, seq] row-major; grown on demand and reused.
    input_ids: Vec<i64>,
    attention_mask: Vec<i64>,
    token_type_ids: Vec<i64>,
    encodings: Vec<tokenizers::Encoding>,
    // Per-call scratch for the cached path: indices of the labels to run, and where each
    // missing label's embedding is in `fresh`.
    unique_misses: Vec<usize>,
    miss_slot: Vec<(usize, usize)>,
    fresh: Vec<Embedding>,
    /// `Cell` is `Send` and not `Sync`: the encoder may move between threads but is never
    /// shared by reference across them (every method needs `&mut self` anyway).
    _one_thread: PhantomData<Cell<()>>,
}

impl std::fmt::Debug for TextEncoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("TextEncoder")
            .field("model_path", &self.model_path)
            .field("cache_capacity", &self.cache_capacity)
            .field("stats", &self.cache_stats())
            .finish_non_exhaustive()
    }
}

impl TextEncoder {
    /// Loads the model and tokenizer named by `config` (paths resolved like the runtime
    /// library's). A missing file is [`OnnxError::FileMissing`] naming it and the set-up script.
    pub fn new(runtime: &OnnxRuntime, config: &TextEncoderConfig) -> Result<Self, OnnxError> {
        config.validate("text_encoder").map_err(OnnxError::InvalidConfig)?;
        let model_path =
            resolve_path(&config.model_path, "text encoder model (all-MiniLM-L6-v2 ONNX)", "text_encoder.model_path")?;
        let tokenizer_path = resolve_path(
            &config.tokenizer_path,
            "text encoder tokenizer (tokenizer.json)",
            "text_encoder.tokenizer_path",
        )?;

        let mut tokenizer = Tokenizer::from_file(&tokenizer_path).map_err(|e| OnnxError::BadModel {
            path: tokenizer_path.clone(),
            message: format!("not a tokenizer: {e}"),
        })?;
        // The file pads every label to 128 tokens; padding to the longest label of a batch is
        // done here instead (identical embeddings, a fraction of the work).
        tokenizer.with_padding(None);
        tokenizer
            .with_truncation(Some(tokenizers::TruncationParams {
                max_length: config.max_sequence_length,
                ..tokenizers::TruncationParams::default()
            }))
            .map_err(|e| OnnxError::BadModel { path: tokenizer_path.clone(), message: format!("truncation: {e}") })?;

        let (session, _) = open_session(
            runtime,
            SessionSpec {
                what: "text encoder",
                model_path: &model_path,
                provider: runtime.execution_provider(),
                intra_threads: config.intra_op_threads,
            },
        )?;
        check_contract(&session, &model_path)?;
        tracing::info!(
            model = %model_path.display(),
            tokenizer = %tokenizer_path.display(),
            max_sequence_length = config.max_sequence_length,
            intra_op_threads = config.intra_op_threads,
            "text encoder loaded"
        );
        Ok(Self {
            session,
            tokenizer,
            model_path,
            cache: HashMap::with_capacity(config.cache_capacity.min(4096)),
            cache_capacity: config.cache_capacity,
            stats: CacheStats::default(),
            input_ids: Vec::new(),
            attention_mask: Vec::new(),
            token_type_ids: Vec::new(),
            encodings: Vec::with_capacity(MAX_BATCH),
            unique_misses: Vec::new(),
            miss_slot: Vec::new(),
            fresh: Vec::new(),
            _one_thread: PhantomData,
        })
    }

    /// The model file in use.
    pub fn model_path(&self) -> &Path {
        &self.model_path
    }

    /// One label (cached).
    pub fn encode(&mut self, label: &str) -> Result<Embedding, OnnxError> {
        if let Some(embedding) = self.cache.get(label) {
            self.stats.hits += 1;
            return Ok(*embedding);
        }
        let mut out = std::mem::take(&mut self.fresh);
        let result = self.encode_uncached_into(&[label], &mut out);
        let embedding = out.first().copied();
        self.fresh = out;
        result?;
        let embedding = embedding.ok_or_else(|| self.bad_output("no embedding for one label".to_owned()))?;
        self.stats.misses += 1;
        self.remember(label, &embedding);
        Ok(embedding)
    }

    /// Several labels, in order (cached). See [`TextEncoder::encode_batch_into`].
    pub fn encode_batch(&mut self, labels: &[&str]) -> Result<Vec<Embedding>, OnnxError> {
        let mut out = Vec::with_capacity(labels.len());
        self.encode_batch_into(labels, &mut out)?;
        Ok(out)
    }

    /// Several labels into `out` (cleared first; its allocation is reused), in the order given.
    /// Labels in the cache are copied from it; the others, each distinct label once, run through
    /// the model together and are added to the cache.
    pub fn encode_batch_into(&mut self, labels: &[&str], out: &mut Vec<Embedding>) -> Result<(), OnnxError> {
        out.clear();
        let mut unique = std::mem::take(&mut self.unique_misses);
        let mut slots = std::mem::take(&mut self.miss_slot);
        unique.clear();
        slots.clear();
        for (index, label) in labels.iter().enumerate() {
            if let Some(embedding) = self.cache.get(*label) {
                self.stats.hits += 1;
                out.push(*embedding);
                continue;
            }
            // Placeholder, filled after the model ran.
            out.push([0.0; EMBEDDING_DIM]);
            match unique.iter().position(|&u| labels[u] == *label) {
                Some(slot) => {
                    self.stats.hits += 1;
                    slots.push((index, slot));
                }
                None => {
                    slots.push((index, unique.len()));
                    unique.push(index);
                }
            }
        }
        let result = if unique.is_empty() { Ok(()) } else { self.run_misses(labels, &unique, &slots, out) };
        self.unique_misses = unique;
        self.miss_slot = slots;
        if result.is_err() {
            out.clear();
        }
        result
    }

    fn run_misses(
        &mut self,
        labels: &[&str],
        unique: &[usize],
        slots: &[(usize, usize)],
        out: &mut [Embedding],
    ) -> Result<(), OnnxError> {
        let mut fresh = std::mem::take(&mut self.fresh);
        fresh.clear();
        let mut result = Ok(());
        for chunk in unique.chunks(MAX_BATCH) {
            // Small per-call list of borrowed labels (no string copies).
            let chunk_labels: Vec<&str> = chunk.iter().map(|&i| labels[i]).collect();
            let start = fresh.len();
            result = self.run_model(&chunk_labels, &mut fresh);
            if result.is_err() {
                break;
            }
            debug_assert_eq!(fresh.len(), start + chunk.len());
        }
        if result.is_ok() {
            self.stats.misses += unique.len() as u64;
            for &(index, slot) in slots {
                out[index] = fresh[slot];
            }
            for (slot, &index) in unique.iter().enumerate() {
                self.remember(labels[index], &fresh[slot]);
            }
        }
        self.fresh = fresh;
        result
    }

    /// Runs the model for every label, bypassing the cache (for measurements and checks). `out`
    /// is cleared first.
    pub fn encode_uncached_into(&mut self, labels: &[&str], out: &mut Vec<Embedding>) -> Result<(), OnnxError> {
        out.clear();
        for chunk in labels.chunks(MAX_BATCH) {
            self.run_model(chunk, out)?;
        }
        Ok(())
    }

    /// Cache counters.
    pub fn cache_stats(&self) -> CacheStats {
        CacheStats { entries: self.cache.len(), ..self.stats }
    }

    /// Empties the cache (counters are kept).
    pub fn clear_cache(&mut self) {
        self.cache.clear();
    }

    fn remember(&mut self, label: &str, embedding: &Embedding) {
        if self.cache_capacity == 0 {
            return;
        }
        if self.cache.len() >= self.cache_capacity {
            self.cache.clear();
            self.stats.clears += 1;
            tracing::debug!(capacity = self.cache_capacity, "text encoder cache full, emptied");
        }
        self.cache.insert(label.into(), *embedding);
    }

    fn bad_output(&self, message: String) -> OnnxError {
        OnnxError::BadModel { path: self.model_path.clone(), message }
    }

    /// Tokenises, pads to the longest label, runs the session once and appends one pooled,
    /// normalised embedding per label to `out`. `labels.len() <= MAX_BATCH`.
    fn run_model(&mut self, labels: &[&str], out: &mut Vec<Embedding>) -> Result<(), OnnxError> {
        if labels.is_empty() {
            return Ok(());
        }
        self.encodings.clear();
        for label in labels {
            let encoding = self.tokenizer.encode_fast(*label, true).map_err(|e| OnnxError::BadModel {
                path: self.model_path.clone(),
                message: format!("cannot tokenise {label:?}: {e}"),
            })?;
            self.encodings.push(encoding);
        }
        let batch = labels.len();
        let seq = self.encodings.iter().map(tokenizers::Encoding::len).max().unwrap_or(0).max(1);
        let len = batch * seq;
        for buffer in [&mut self.input_ids, &mut self.attention_mask, &mut self.token_type_ids] {
            buffer.clear();
            buffer.resize(len, 0);
        }
        for (row, encoding) in self.encodings.iter().enumerate() {
            let base = row * seq;
            let n = encoding.len();
            let widen = |dst: &mut [i64], src: &[u32]| dst.iter_mut().zip(src).for_each(|(d, &s)| *d = i64::from(s));
            widen(&mut self.input_ids[base..base + n], encoding.get_ids());
            widen(&mut self.attention_mask[base..base + n], encoding.get_attention_mask());
            widen(&mut self.token_type_ids[base..base + n], encoding.get_type_ids());
        }

        let ort_error = |context: &str, e: ort::Error| OnnxError::Ort {
            context: format!("{context} ({})", self.model_path.display()),
            message: e.to_string(),
        };
        let shape = [batch, seq];
        let input_ids = TensorRef::from_array_view((shape, self.input_ids.as_slice()))
            .map_err(|e| ort_error("input_ids tensor", e))?;
        let attention_mask = TensorRef::from_array_view((shape, self.attention_mask.as_slice()))
            .map_err(|e| ort_error("attention_mask tensor", e))?;
        let token_type_ids = TensorRef::from_array_view((shape, self.token_type_ids.as_slice()))
            .map_err(|e| ort_error("token_type_ids tensor", e))?;
        let outputs = self
            .session
            .run(ort::inputs![
                INPUT_IDS => input_ids,
                ATTENTION_MASK => attention_mask,
                TOKEN_TYPE_IDS => token_type_ids,
            ])
            .map_err(|e| OnnxError::Ort {
                context: format!("running the text encoder ({})", self.model_path.display()),
                message: e.to_string(),
            })?;
        let hidden = outputs
            .get(LAST_HIDDEN_STATE)
            .ok_or_else(|| OnnxError::BadModel {
                path: self.model_path.clone(),
                message: format!("no output {LAST_HIDDEN_STATE}"),
            })?
            .try_extract_array::<f32>()
            .map_err(|e| OnnxError::Ort {
                context: format!("reading {LAST_HIDDEN_STATE} ({})", self.model_path.display()),
                message: e.to_string(),
            })?;
        if hidden.shape() != [batch, seq, EMBEDDING_DIM] {
            return Err(OnnxError::BadModel {
                path: self.model_path.clone(),
                message: format!(
                    "{LAST_HIDDEN_STATE} has shape {:?}, expected [{batch}, {seq}, {EMBEDDING_DIM}]",
                    hidden.shape()
                ),
            });
        }
        let hidden = hidden.into_dimensionality::<Ix3>().map_err(|e| OnnxError::BadModel {
            path: self.model_path.clone(),
            message: format!("{LAST_HIDDEN_STATE}: {e}"),
        })?;

        for (row, states) in hidden.axis_iter(Axis(0)).enumerate() {
            let mask = &self.attention_mask[row * seq..(row + 1) * seq];
            let mut pooled = [0.0f32; EMBEDDING_DIM];
            let mut count = 0.0f32;
            for (token, &m) in states.axis_iter(Axis(0)).zip(mask) {
                if m == 0 {
                    continue;
                }
                count += 1.0;
                pooled.iter_mut().zip(token.iter()).for_each(|(p, &v)| *p += v);
            }
            let count = count.max(1e-9);
            pooled.iter_mut().for_each(|p| *p /= count);
            let norm = pooled.iter().map(|v| v * v).sum::<f32>().sqrt().max(1e-12);
            pooled.iter_mut().for_each(|p| *p /= norm);
            out.push(pooled);
        }
        Ok(())
    }
}

/// A text encoder made from `[onnx]` and `[text_encoder]` (whether or not `enabled` is set: the
/// caller asks for it), shared behind a lock as the label fallback's embedder. The error names
/// what could not be loaded.
pub fn load_shared(onnx: &OnnxConfig, config: &TextEncoderConfig) -> Result<SharedEmbedder, String> {
    let runtime = OnnxRuntime::init(onnx).map_err(|e| format!("onnx: {e}"))?;
    let encoder = TextEncoder::new(&runtime, config).map_err(|e| format!("text_encoder: {e}"))?;
    Ok(std::sync::Arc::new(std::sync::Mutex::new(Box::new(encoder))))
}

impl PhraseEmbedder for TextEncoder {
    fn embed(&mut self, phrases: &[&str]) -> Result<Vec<Embedding>, String> {
        self.encode_batch(phrases).map_err(|e| e.to_string())
    }
}

/// The model must have the three BERT inputs and a [.., .., 384] `last_hidden_state`.
fn check_contract(session: &Session, model_path: &Path) -> Result<(), OnnxError> {
    let bad = |message: String| OnnxError::BadModel { path: model_path.to_path_buf(), message };
    for name in [INPUT_IDS, ATTENTION_MASK, TOKEN_TYPE_IDS] {
        if !session.inputs().iter().any(|input| input.name() == name) {
            let found: Vec<&str> = session.inputs().iter().map(|i| i.name()).collect();
            return Err(bad(format!("model has no input {name} (inputs: {found:?}); expected all-MiniLM-L6-v2")));
        }
    }
    let output = session
        .outputs()
        .iter()
        .find(|o| o.name() == LAST_HIDDEN_STATE)
        .ok_or_else(|| bad(format!("model has no output {LAST_HIDDEN_STATE}; expected all-MiniLM-L6-v2")))?;
    let width = output.dtype().tensor_shape().and_then(|shape| shape.last().copied());
    if width != Some(EMBEDDING_DIM as i64) {
        return Err(bad(format!("{LAST_HIDDEN_STATE} must end in {EMBEDDING_DIM}, model says {width:?}")));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn assert_send<T: Send>() {}

    #[test]
    fn encoder_is_send() {
        // And not Sync: `PhantomData<Cell<()>>` (checked by the compiler, not at run time).
        assert_send::<TextEncoder>();
    }

    #[test]
    fn config_validation_names_the_field() {
        let ok = TextEncoderConfig::default();
        assert_eq!(ok.validate("text_encoder"), Ok(()));
        let bad = TextEncoderConfig { max_sequence_length: 1000, ..ok.clone() };
        assert_eq!(
            bad.validate("text_encoder"),
            Err("text_encoder.max_sequence_length: must be within [4, 512], got 1000".to_owned())
        );
        let bad = TextEncoderConfig { intra_op_threads: 0, ..ok.clone() };
        assert!(bad.validate("text_encoder").unwrap_err().starts_with("text_encoder.intra_op_threads: "));
        let bad = TextEncoderConfig { model_path: PathBuf::new(), ..ok };
        assert_eq!(bad.validate("text_encoder"), Err("text_encoder.model_path: must not be empty".to_owned()));
    }
}
