//! CLIP's text side: the BPE tokenizer (through the `tokenizers` crate, from the
//! `tokenizer.json` that `./scripts/setup-models.sh` converts from the vocabulary file of PyPI's
//! `open_clip_torch`) and a CLIP text encoder a user exports, for detectors that take CLIP text
//! features (YOLO-World) or CLIP tokens (OWL-ViT / OWLv2).
//!
//! # Tokens
//!
//! As open_clip's `SimpleTokenizer`: lower-cased, whitespace collapsed, CLIP's word pattern,
//! byte-level BPE with `</w>` word ends, `<|startoftext|>` (49406) first and `<|endoftext|>`
//! (49407) last, zero-padded to the context length; a longer text is cut and its last token
//! set to `<|endoftext|>`. The attention mask is 1 over the real tokens. (open_clip also runs
//! `ftfy` and HTML unescaping, which change nothing for plain prompts.)
//!
//! # Text encoder contract (`[detector.open_vocab.clip]`)
//!
//! - in `input` (default `input_ids`): int64 `[N, context_length]` (default 77), the tokens;
//! - optionally `attention_mask`: int64 `[N, context_length]` (Hugging Face
//!   `CLIPTextModelWithProjection` exports have it; open_clip's do not);
//! - out `output` (default `text_embeds`): float32 `[N, dim]` (512 for ViT-B/32, 768 for ViT-L/14),
//!   L2-normalised here.
//!
//! Export, e.g. with open_clip: `torch.onnx.export(TextOnly(model), open_clip.tokenize(["a"]),
//! "clip_text.onnx", input_names=["input_ids"], output_names=["text_embeds"],
//! dynamic_axes={"input_ids": {0: "N"}, "text_embeds": {0: "N"}})`, where `TextOnly.forward`
//! returns `model.encode_text(tokens)`.

use std::path::{Path, PathBuf};

use ort::session::Session;
use ort::value::TensorRef;
use serde::{Deserialize, Serialize};
use tokenizers::Tokenizer;

use super::contract::{self, Dim, FLOAT, INT64, TensorSpec, user_model};
use super::{OnnxError, OnnxRuntime, SessionSpec, open_session, resolve_path};

/// `<|startoftext|>`.
pub const START_OF_TEXT: u32 = 49406;
/// `<|endoftext|>`.
pub const END_OF_TEXT: u32 = 49407;
/// Where `./scripts/setup-models.sh` writes CLIP's tokenizer.
pub const DEFAULT_TOKENIZER_PATH: &str = ".models/clip/tokenizer.json";

/// `[detector.open_vocab.clip]`: CLIP's tokenizer and, for detectors that take text features,
/// the CLIP text encoder.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClipTextConfig {
    /// The text encoder, as ONNX (a user's export). Relative paths in a profile file are
    /// relative to that file.
    pub model_path: PathBuf,
    /// Optional sha256 of `model_path`, checked at start.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
    /// CLIP's BPE as a `tokenizer.json` (`./scripts/setup-models.sh` writes the default).
    pub tokenizer_path: PathBuf,
    /// Token input name.
    pub input: String,
    /// Attention-mask input name, if the export has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub attention_mask: Option<String>,
    /// Output name of the `[N, dim]` text features.
    pub output: String,
    /// Tokens per text, start and end included (77 for CLIP).
    pub context_length: usize,
    /// Width of the text features.
    pub dim: usize,
    /// ONNX Runtime intra-op threads.
    pub intra_op_threads: usize,
}

impl Default for ClipTextConfig {
    fn default() -> Self {
        Self {
            model_path: PathBuf::from("clip_text.onnx"),
            sha256: None,
            tokenizer_path: PathBuf::from(DEFAULT_TOKENIZER_PATH),
            input: "input_ids".to_owned(),
            attention_mask: None,
            output: "text_embeds".to_owned(),
            context_length: 77,
            dim: 512,
            intra_op_threads: 1,
        }
    }
}

impl ClipTextConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        for (field, value) in [("model_path", &self.model_path), ("tokenizer_path", &self.tokenizer_path)] {
            if value.as_os_str().is_empty() {
                return Err(format!("{path}.{field}: must not be empty"));
            }
        }
        contract::validate_sha256(&format!("{path}.sha256"), self.sha256.as_deref())?;
        if !(3..=1024).contains(&self.context_length) {
            return Err(format!("{path}.context_length: must be within [3, 1024], got {}", self.context_length));
        }
        if !(1..=8192).contains(&self.dim) {
            return Err(format!("{path}.dim: must be within [1, 8192], got {}", self.dim));
        }
        if !(1..=64).contains(&self.intra_op_threads) {
            return Err(format!("{path}.intra_op_threads: must be within [1, 64], got {}", self.intra_op_threads));
        }
        Ok(())
    }
}

/// Token ids and attention mask of a batch, `[N, context_length]` row-major.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Tokens {
    /// Ids, zero-padded.
    pub ids: Vec<i64>,
    /// 1 over real tokens.
    pub mask: Vec<i64>,
    /// Row length.
    pub context_length: usize,
}

/// CLIP's BPE tokenizer (see the module docs).
#[derive(Clone)]
pub struct ClipTokenizer {
    tokenizer: Tokenizer,
    path: PathBuf,
}

impl std::fmt::Debug for ClipTokenizer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClipTokenizer").field("path", &self.path).finish_non_exhaustive()
    }
}

impl ClipTokenizer {
    /// Loads `tokenizer.json` (resolved like model paths); `key` is the profile key naming it.
    pub fn new(configured: &Path, key: &str) -> Result<Self, OnnxError> {
        let path = resolve_path(configured, "CLIP tokenizer (tokenizer.json)", key)?;
        let mut tokenizer = Tokenizer::from_file(&path)
            .map_err(|e| OnnxError::BadModel { path: path.clone(), message: format!("not a tokenizer: {e}") })?;
        tokenizer.with_padding(None);
        let _ = tokenizer.with_truncation(None);
        let this = Self { tokenizer, path };
        let probe = this.ids("a")?;
        if probe.first() != Some(&START_OF_TEXT) || probe.last() != Some(&END_OF_TEXT) {
            return Err(OnnxError::BadModel {
                path: this.path,
                message: format!(
                    "not CLIP's tokenizer: \"a\" gives {probe:?}, expected <|startoftext|> ({START_OF_TEXT}) .. <|endoftext|> ({END_OF_TEXT}); run ./scripts/setup-models.sh"
                ),
            });
        }
        Ok(this)
    }

    /// The ids of one text, start and end tokens included, not padded.
    pub fn ids(&self, text: &str) -> Result<Vec<u32>, OnnxError> {
        self.tokenizer.encode_fast(text, true).map(|e| e.get_ids().to_vec()).map_err(|e| OnnxError::BadModel {
            path: self.path.clone(),
            message: format!("cannot tokenise {text:?}: {e}"),
        })
    }

    /// `texts` as `[N, context_length]` tokens (see the module docs).
    pub fn encode(&self, texts: &[&str], context_length: usize) -> Result<Tokens, OnnxError> {
        let mut tokens = Tokens {
            ids: vec![0; texts.len() * context_length],
            mask: vec![0; texts.len() * context_length],
            context_length,
        };
        for (row, text) in texts.iter().enumerate() {
            let mut ids = self.ids(text)?;
            if ids.len() > context_length {
                ids.truncate(context_length);
                ids[context_length - 1] = END_OF_TEXT;
            }
            let base = row * context_length;
            for (i, id) in ids.iter().enumerate() {
                tokens.ids[base + i] = i64::from(*id);
                tokens.mask[base + i] = 1;
            }
        }
        Ok(tokens)
    }
}

/// A CLIP text encoder export with its tokenizer. Owned by one thread (`Session::run` takes
/// `&mut self`).
pub struct ClipTextEncoder {
    session: Session,
    tokenizer: ClipTokenizer,
    config: ClipTextConfig,
    model_path: PathBuf,
}

impl std::fmt::Debug for ClipTextEncoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ClipTextEncoder").field("model_path", &self.model_path).finish_non_exhaustive()
    }
}

impl ClipTextEncoder {
    /// Loads the encoder of `config` (section `key`, e.g. `detector.open_vocab.clip`): checks its
    /// sha256 when set and its tensors against the contract of the module docs.
    pub fn new(runtime: &OnnxRuntime, config: &ClipTextConfig, key: &str) -> Result<Self, OnnxError> {
        config.validate(key).map_err(OnnxError::InvalidConfig)?;
        let model_path = resolve_path(&config.model_path, "CLIP text encoder (ONNX)", &format!("{key}.model_path"))
            .map_err(user_model)?;
        contract::verify_sha256(&model_path, config.sha256.as_deref(), &format!("{key}.sha256"))?;
        let tokenizer = ClipTokenizer::new(&config.tokenizer_path, &format!("{key}.tokenizer_path"))?;
        let (session, _) = open_session(
            runtime,
            SessionSpec {
                what: "CLIP text encoder",
                model_path: &model_path,
                provider: runtime.execution_provider(),
                intra_threads: config.intra_op_threads,
            },
        )?;
        let tokens = || Some(vec![Dim::Any("N"), Dim::Is(config.context_length as i64)]);
        let mut inputs = vec![TensorSpec::new(&config.input, &format!("{key}.input"), INT64, tokens())];
        if let Some(mask) = &config.attention_mask {
            inputs.push(TensorSpec::new(mask, &format!("{key}.attention_mask"), INT64, tokens()));
        }
        let outputs = [TensorSpec::new(
            &config.output,
            &format!("{key}.output"),
            FLOAT,
            Some(vec![Dim::Any("N"), Dim::Is(config.dim as i64)]),
        )];
        contract::check(&session, &model_path, &format!("the CLIP text encoder contract ({key})"), &inputs, &outputs)?;
        Ok(Self { session, tokenizer, config: config.clone(), model_path })
    }

    /// The tokenizer.
    pub fn tokenizer(&self) -> &ClipTokenizer {
        &self.tokenizer
    }

    /// Width of a feature.
    pub fn dim(&self) -> usize {
        self.config.dim
    }

    /// L2-normalised features of `texts`, `[N, dim]` row-major.
    pub fn encode(&mut self, texts: &[&str]) -> Result<Vec<f32>, OnnxError> {
        if texts.is_empty() {
            return Ok(Vec::new());
        }
        let tokens = self.tokenizer.encode(texts, self.config.context_length)?;
        let shape = [texts.len(), tokens.context_length];
        let ort_error = |context: &str, e: ort::Error| OnnxError::Ort {
            context: format!("{context} ({})", self.model_path.display()),
            message: e.to_string(),
        };
        let ids =
            TensorRef::from_array_view((shape, tokens.ids.as_slice())).map_err(|e| ort_error("token tensor", e))?;
        let mut inputs = vec![(self.config.input.as_str(), ort::session::SessionInputValue::from(ids))];
        if let Some(name) = &self.config.attention_mask {
            let mask =
                TensorRef::from_array_view((shape, tokens.mask.as_slice())).map_err(|e| ort_error("mask tensor", e))?;
            inputs.push((name.as_str(), mask.into()));
        }
        let outputs = self.session.run(inputs).map_err(|e| ort_error("running the CLIP text encoder", e))?;
        let (out_shape, data) = outputs
            .get(self.config.output.as_str())
            .ok_or_else(|| OnnxError::BadModel {
                path: self.model_path.clone(),
                message: format!("no output {:?}", self.config.output),
            })?
            .try_extract_tensor::<f32>()
            .map_err(|e| ort_error("reading the text features", e))?;
        if out_shape[..] != [texts.len() as i64, self.config.dim as i64] {
            return Err(OnnxError::BadModel {
                path: self.model_path.clone(),
                message: format!(
                    "output {:?} has shape {out_shape:?}, expected [{}, {}]",
                    self.config.output,
                    texts.len(),
                    self.config.dim
                ),
            });
        }
        let mut features = data.to_vec();
        features.chunks_exact_mut(self.config.dim).for_each(crate::embedding::normalise);
        Ok(features)
    }
}
