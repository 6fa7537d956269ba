//! Open-vocabulary detectors through ONNX Runtime: a user's exported object/part detector that
//! takes its vocabulary as text embeddings or tokens at run time plugs in by profile alone
//! (`[detector] kind = "open_vocab"`, `[detector.open_vocab]`).
//!
//! # Families
//!
//! `family` picks the export layout; every family goes through the same decoding below, the
//! named ones with `text` and `outputs` fixed (setting either is refused), and the file is
//! checked against the layout at start ([`crate::onnx::contract`]: a tensor that is missing or
//! has another dtype or shape is refused naming the profile key and listing the file's tensors).
//! `sha256` (optional) is checked first. `P` is the number of prompts, `A` of candidate regions.
//!
//! - `generic` (default): `text` and `outputs` as the profile states them (next section).
//! - `yolo_world`: YOLO-World with a text-feature input (YOLO-World's `easydeploy` DeployModel
//!   with post-processing and without NMS, as `wkentaro/yolo-world-onnx`'s `export_onnx.py`
//!   writes it). In: `input.name` (default `images`) float32 `[1, 3, H, W]` (640 x 640, RGB,
//!   0..1, letterbox, pad 114), `text_features` float32 `[1, P, D]`: the prompts through the CLIP
//!   text encoder of `[detector.open_vocab.clip]`, L2-normalised (`D` = `clip.dim`, 512). Out:
//!   `scores` float32 `[1, A, P]` (post-sigmoid), `boxes` float32 `[1, A, 4]` (`x0 y0 x1 y1` in
//!   input pixels). YOLO-World's own scripts centre the letterbox; op3dsg places it top-left
//!   (the convolutional detector is translation-equivariant; boxes are mapped back either way).
//! - `owl`: OWL-ViT / OWLv2 as Hugging Face optimum exports them (`optimum-cli export onnx
//!   --model google/owlv2-base-patch16-ensemble --task zero-shot-object-detection owlv2/`). In:
//!   `input_ids` int64 `[P, L]` and `attention_mask` int64 `[P, L]` (CLIP's BPE,
//!   [`crate::onnx::clip_text::ClipTokenizer`], zero-padded to the export's `L`, 16, or
//!   `text.context_length`), `input.name` (`pixel_values`) float32 `[1, 3, H, W]` (OWLv2: 960,
//!   CLIP mean/std, padded bottom/right with grey: `resize = "letterbox"`, `pad_value = 127.5`;
//!   OWL-ViT: 768, `resize = "stretch"`). Out: `logits` float32 `[1, A, P]` (a sigmoid gives
//!   the score), `pred_boxes` float32 `[1, A, 4]` (`cx cy w h` normalised to the input).
//!
//! `scripts/reference/model_standins.py` writes a stand-in of each with these tensors and known
//! answers; `daemon/sim/tests/model_families.rs` runs the families on them.
//!
//! # Model contract (`generic`)
//!
//! Inputs:
//! - the image, `[1, 3, H, W]` float32, as `[detector.open_vocab.input]` states it (name, size,
//!   colour order, letterbox or stretch, scale, mean, std, pad; see [`super::image_input`]);
//! - with `text.kind = "embeddings"`: the prompts' embeddings `[P, D]` float32 (tensor
//!   `text.name`; `[1, P, D]` with `text.batch_axis`), one L2-normalised row per prompt from
//!   `[text_encoder]` (`text.encoder = "minilm"`, D = 384) or the CLIP text encoder of
//!   `[detector.open_vocab.clip]` (`"clip"`); with `text.kind = "tokens"`: CLIP tokens
//!   `[P, L]` int64 (`text.name`) and, when `text.attention_mask` names one, the mask `[P, L]`
//!   int64; with `text.kind = "none"` the vocabulary is baked into the model and the prompt list
//!   names its classes in the model's order.
//!
//! Outputs (names in `[detector.open_vocab.outputs]`), `N` candidate regions:
//! - `boxes` `[N, 4]` (a leading batch axis of 1 is accepted everywhere): `xyxy` or `cxcywh`
//!   (`box_format`), in network input pixels or normalised to [0, 1] (`boxes_normalised`);
//! - `scores`: either `[N]` together with `prompt_index` `[N]` (int64 or int32: which prompt),
//!   or, with `prompt_index` unset, `[N, P]` (a score per prompt; the best one is taken, ties
//!   to the earlier prompt); `score_activation = "sigmoid"` for logits;
//! - optional `masks` `[N, h, w]`: per-region mask probabilities over the whole network input
//!   (any resolution), thresholded at `mask_threshold`; without them the mask is segmented from
//!   depth inside the box ([`super::depth_mask`]), as for box-only detectors;
//! - optional `region_embeddings` `[N, D]`: each region's embedding, passed to fusion as the
//!   detection's semantic feature (L2-normalised) when it has the text encoder's dimension.
//!
//! Post-processing: scores above `score_threshold`, greedy NMS per prompt at
//! `nms_iou_threshold`, at most `max_detections`, boxes mapped back to image pixels and clipped.
//!
//! # Prompts: knowledge-guided part candidates
//!
//! The prompt list is built by [`super::candidates::PartCandidates`] from the object tags of
//! `[detector.open_vocab.prompts] objects`: with `part_prompts = "knowledge"` (the default) the
//! knowledge base's interactive parts of every tagged object, phrased "<tag> <part>" ("cabinet
//! handle", "stove knob"), so the detector looks for the parts those objects have and fusion's
//! lexical rule attaches each to its object, plus a few small things a tagger misses (light
//! switch, power outlet, remote control); `"generic"` a fixed generic part vocabulary instead;
//! `"all"` the tags alone. Then `parts`, as given. Duplicates are dropped, order kept.
//!
//! With `[detector.open_vocab.tagger]` ([`super::tagger`], e.g. RAM) the object tags are chosen
//! per keyframe: `objects` (always looked for, may be empty) followed by the tagger's tags for
//! that keyframe, and the prompt list is rebuilt when they change, new prompts encoded once and
//! kept (up to 4096 texts). A keyframe with no tag and no listed object is not run.
//!
//! `scripts/reference/open_vocab_fixture.py` writes a tiny model with this contract and known
//! answers; `daemon/sim/tests/open_vocab.rs` runs the adapter on it.

use std::path::PathBuf;

use op3dsg_drivers::frame::Frame;
use op3dsg_ipc_types::NodeKind;
use ort::session::Session;
use ort::session::SessionInputValue;
use ort::value::TensorRef;
use serde::{Deserialize, Serialize};

use super::depth_mask::{DepthMaskConfig, PixelBox};
use super::image_input::{ImageInput, Placement, prepare};
use super::mask_decoder::{BoxMasks, MaskDecoderConfig};
use super::tagger::{ImageTagger, TaggerConfig};
use super::yolox::iou;
use super::{
    Detection, Detector, DetectorError, Mask, ScoreCalibration, greedy_suppress, normalise, validate_detection_limits,
};
use std::sync::Arc;

use super::candidates::{CandidateMode, PartCandidates, Prompt, PromptList};
use crate::knowledge::KnowledgeBase;
use crate::onnx::clip_text::{ClipTextConfig, ClipTextEncoder, ClipTokenizer, Tokens, user_model};
use crate::onnx::contract::{self, Dim, FLOAT, INDEX, INT64, TensorSpec};
use crate::onnx::text_encoder::{EMBEDDING_DIM, TextEncoder, TextEncoderConfig};
use crate::onnx::{ExecutionProvider, OnnxError, OnnxRuntime, SessionSpec, open_session, resolve_path};

/// Which export layout the model has (`detector.open_vocab.family`): `generic` is described
/// field by field by `text` and `outputs`; the others fix both to the layout of a published
/// export (module docs, "Families").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Family {
    /// `text` and `outputs` as the profile states them.
    #[default]
    Generic,
    /// YOLO-World with a text-feature input (CLIP text features in, scores and boxes out).
    YoloWorld,
    /// OWL-ViT / OWLv2 (CLIP tokens in, logits and normalised centre boxes out).
    Owl,
}

impl Family {
    /// The profile spelling.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Generic => "generic",
            Self::YoloWorld => "yolo_world",
            Self::Owl => "owl",
        }
    }

    /// The text input and outputs of this family (`config`'s own for `generic`).
    pub fn contract(self, config: &OpenVocabConfig) -> (TextInput, OutputNames) {
        match self {
            Self::Generic => (config.text.clone(), config.outputs.clone()),
            Self::YoloWorld => (
                TextInput {
                    kind: TextInputKind::Embeddings,
                    name: "text_features".to_owned(),
                    encoder: TextEncoderKind::Clip,
                    batch_axis: true,
                    ..TextInput::default()
                },
                OutputNames {
                    boxes: "boxes".to_owned(),
                    scores: "scores".to_owned(),
                    prompt_index: None,
                    ..OutputNames::default()
                },
            ),
            Self::Owl => (
                TextInput {
                    kind: TextInputKind::Tokens,
                    name: "input_ids".to_owned(),
                    attention_mask: Some("attention_mask".to_owned()),
                    ..TextInput::default()
                },
                OutputNames {
                    boxes: "pred_boxes".to_owned(),
                    box_format: BoxFormat::Cxcywh,
                    boxes_normalised: true,
                    scores: "logits".to_owned(),
                    prompt_index: None,
                    score_activation: ScoreActivation::Sigmoid,
                    ..OutputNames::default()
                },
            ),
        }
    }
}

/// How the model receives its vocabulary.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TextInputKind {
    /// `[P, D]` prompt embeddings from `encoder`.
    #[default]
    Embeddings,
    /// `[P, L]` int64 CLIP tokens (and an attention mask), tokenised here with CLIP's BPE.
    Tokens,
    /// Baked into the model; the prompt list names its classes in order.
    None,
}

/// Which text encoder makes the prompt embeddings.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TextEncoderKind {
    /// `[text_encoder]` (all-MiniLM-L6-v2, 384-d).
    #[default]
    Minilm,
    /// The CLIP text encoder of `[detector.open_vocab.clip]`.
    Clip,
}

/// `[detector.open_vocab.text]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TextInput {
    /// Embeddings, tokens or none.
    pub kind: TextInputKind,
    /// Tensor name of the embeddings or token ids.
    pub name: String,
    /// Embeddings: `minilm` or `clip`.
    pub encoder: TextEncoderKind,
    /// Embeddings: fed as `[1, P, D]` (with a batch axis) instead of `[P, D]`.
    pub batch_axis: bool,
    /// Tokens: the attention-mask input, if the model has one.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub attention_mask: Option<String>,
    /// Tokens: row length when the model's input does not fix it (OWL: 16).
    pub context_length: usize,
}

impl Default for TextInput {
    fn default() -> Self {
        Self {
            kind: TextInputKind::Embeddings,
            name: "text_embeddings".to_owned(),
            encoder: TextEncoderKind::Minilm,
            batch_axis: false,
            attention_mask: None,
            context_length: 16,
        }
    }
}

/// What turns a raw score into one in [0, 1].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ScoreActivation {
    /// The model's scores are probabilities already.
    #[default]
    None,
    /// Logits: `1 / (1 + e^-x)`.
    Sigmoid,
}

impl ScoreActivation {
    fn apply(self, x: f32) -> f32 {
        match self {
            Self::None => x,
            Self::Sigmoid => 1.0 / (1.0 + (-x).exp()),
        }
    }
}

/// Box encoding of the `boxes` output.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum BoxFormat {
    /// Corners `x0, y0, x1, y1`.
    #[default]
    Xyxy,
    /// Centre and size `cx, cy, w, h`.
    Cxcywh,
}

/// `[detector.open_vocab.outputs]`: output tensor names and encodings.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OutputNames {
    /// `[N, 4]` boxes.
    pub boxes: String,
    /// Box encoding.
    pub box_format: BoxFormat,
    /// Boxes normalised to [0, 1] of the input size (else network pixels).
    pub boxes_normalised: bool,
    /// `[N]` (with `prompt_index`) or `[N, P]` scores.
    pub scores: String,
    /// `[N]` prompt index per region; unset: `scores` is `[N, P]`.
    pub prompt_index: Option<String>,
    /// Optional `[N, h, w]` mask probabilities over the network input.
    pub masks: Option<String>,
    /// Optional `[N, D]` region embeddings.
    pub region_embeddings: Option<String>,
    /// `none` (scores are probabilities) or `sigmoid` (logits).
    pub score_activation: ScoreActivation,
}

impl Default for OutputNames {
    fn default() -> Self {
        Self {
            boxes: "boxes".to_owned(),
            box_format: BoxFormat::Xyxy,
            boxes_normalised: false,
            scores: "scores".to_owned(),
            prompt_index: Some("prompt_index".to_owned()),
            masks: None,
            region_embeddings: None,
            score_activation: ScoreActivation::None,
        }
    }
}

/// `[detector.open_vocab.prompts]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PromptConfig {
    /// Object tags (kind object).
    pub objects: Vec<String>,
    /// Part prompts given as they are (kind part), after the generated ones.
    pub parts: Vec<String>,
    /// Part prompts generated from the tags: `knowledge`, `generic` or `all` (none).
    pub part_prompts: CandidateMode,
}

impl Default for PromptConfig {
    fn default() -> Self {
        Self { objects: Vec::new(), parts: Vec::new(), part_prompts: CandidateMode::Knowledge }
    }
}

/// `[detector.open_vocab]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OpenVocabConfig {
    /// Export layout: `generic`, `yolo_world` or `owl` (module docs, "Families").
    pub family: Family,
    /// The ONNX model. Relative paths in a profile file are relative to that file.
    pub model_path: PathBuf,
    /// Optional sha256 of `model_path`, checked at start.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
    /// Image input contract.
    pub input: ImageInput,
    /// Text input contract.
    pub text: TextInput,
    /// Output names and encodings.
    pub outputs: OutputNames,
    /// The vocabulary.
    pub prompts: PromptConfig,
    /// Score calibration onto fusion's scale (`[detector.open_vocab.calibration]`), applied
    /// before `score_threshold`.
    pub calibration: ScoreCalibration,
    /// Keep regions scoring above this (after calibration). (0, 1).
    pub score_threshold: f32,
    /// Per-prompt NMS IoU. (0, 1].
    pub nms_iou_threshold: f32,
    /// At most this many detections per frame.
    pub max_detections: usize,
    /// Mask probability at or above which a pixel is inside. (0, 1).
    pub mask_threshold: f32,
    /// ONNX Runtime intra-op threads of each worker's session.
    pub intra_op_threads: usize,
    /// Execution provider; unset: `[onnx] execution_provider`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub execution_provider: Option<ExecutionProvider>,
    /// Masks from depth for models without a mask output.
    pub depth_mask: DepthMaskConfig,
    /// CLIP's tokenizer and text encoder (`text.encoder = "clip"`, `text.kind = "tokens"`, the
    /// `yolo_world` and `owl` families).
    pub clip: ClipTextConfig,
    /// A SAM-family mask decoder: its masks replace those from depth for models without a mask
    /// output ([`super::mask_decoder`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mask_decoder: Option<MaskDecoderConfig>,
    /// An image tagger whose tags for each keyframe join `prompts.objects` as that keyframe's
    /// object tags ([`super::tagger`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tagger: Option<TaggerConfig>,
}

impl Default for OpenVocabConfig {
    fn default() -> Self {
        Self {
            family: Family::Generic,
            model_path: PathBuf::from("open_vocab.onnx"),
            sha256: None,
            input: ImageInput::default(),
            text: TextInput::default(),
            outputs: OutputNames::default(),
            prompts: PromptConfig::default(),
            calibration: ScoreCalibration::default(),
            score_threshold: 0.3,
            nms_iou_threshold: 0.5,
            max_detections: 100,
            mask_threshold: 0.5,
            intra_op_threads: 1,
            execution_provider: None,
            depth_mask: DepthMaskConfig::default(),
            clip: ClipTextConfig::default(),
            mask_decoder: None,
            tagger: None,
        }
    }
}

impl OpenVocabConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if self.model_path.as_os_str().is_empty() {
            return Err(format!("{path}.model_path: must not be empty"));
        }
        contract::validate_sha256(&format!("{path}.sha256"), self.sha256.as_deref())?;
        self.calibration.validate(&format!("{path}.calibration"))?;
        self.input.validate(&format!("{path}.input"))?;
        if self.family != Family::Generic {
            let family = self.family.as_str();
            if self.text != TextInput::default() {
                return Err(format!(
                    "{path}.text: only with family = \"generic\"; family = \"{family}\" fixes the text input (see the README, \"Bringing your own models\")"
                ));
            }
            if self.outputs != OutputNames::default() {
                return Err(format!(
                    "{path}.outputs: only with family = \"generic\"; family = \"{family}\" fixes the outputs (see the README, \"Bringing your own models\")"
                ));
            }
        }
        let (text, _) = self.family.contract(self);
        if text.kind == TextInputKind::Tokens && !(3..=1024).contains(&text.context_length) {
            return Err(format!("{path}.text.context_length: must be within [3, 1024], got {}", text.context_length));
        }
        if let Some(decoder) = &self.mask_decoder {
            decoder.validate(&format!("{path}.mask_decoder"))?;
        }
        if text.kind == TextInputKind::Tokens || text.encoder == TextEncoderKind::Clip {
            self.clip.validate(&format!("{path}.clip"))?;
        }
        validate_detection_limits(
            path,
            self.score_threshold,
            self.nms_iou_threshold,
            self.max_detections,
            self.intra_op_threads,
        )?;
        if !(self.mask_threshold > 0.0 && self.mask_threshold < 1.0) {
            return Err(format!("{path}.mask_threshold: must be within (0, 1), got {}", self.mask_threshold));
        }
        if let Some(tagger) = &self.tagger {
            tagger.validate(&format!("{path}.tagger"))?;
            if text.kind == TextInputKind::None {
                return Err(format!(
                    "{path}.tagger: needs a model that takes its vocabulary (text.kind \"embeddings\" or \"tokens\"); this one has it built in"
                ));
            }
        } else if self.prompts.objects.is_empty() && self.prompts.parts.is_empty() {
            return Err(format!("{path}.prompts: list at least one object tag or part prompt (or set a tagger)"));
        }
        if let Some(p) = self.prompts.objects.iter().chain(&self.prompts.parts).find(|p| p.trim().is_empty()) {
            return Err(format!("{path}.prompts: empty prompt {p:?}"));
        }
        self.depth_mask.validate(&format!("{path}.depth_mask"))
    }
}

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

/// A decoded region before masks: image-pixel box, score, prompt, row in the outputs.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Region {
    bbox: [f32; 4],
    score: f32,
    prompt: usize,
    row: usize,
}

/// The open-vocabulary detector of one worker: its own session, the prompts' embeddings or
/// tokens and a depth segmenter.
pub struct OpenVocabDetector {
    session: Session,
    config: OpenVocabConfig,
    /// The family's (or the profile's, for `generic`) text input and outputs.
    text: TextInput,
    outputs: OutputNames,
    model_path: PathBuf,
    prompts: Vec<Prompt>,
    /// `[P, D]` row-major (empty unless `text.kind = "embeddings"`).
    text_embeddings: Vec<f32>,
    text_dim: usize,
    /// `[P, L]` (empty unless `text.kind = "tokens"`).
    tokens: Tokens,
    input: Vec<f32>,
    box_masks: BoxMasks,
    /// The object tags the prompts were built from.
    frame_objects: Vec<String>,
    knowledge: Arc<KnowledgeBase>,
    /// With `[detector.open_vocab.tagger]`: the tagger, and what encodes the prompts it seeds.
    tagger: Option<ImageTagger>,
    encoder: Option<PromptEncoder>,
    cache: PromptCache,
}

/// Turns prompts into the model's text input (embeddings or tokens).
enum PromptEncoder {
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
struct PromptCache(std::collections::HashMap<String, Vec<f32>>);

impl PromptCache {
    /// Entries kept at most (512-float rows: 8 MiB).
    const MAX: usize = 4096;
}

impl PromptEncoder {
    /// The text input of `prompts`: `[P, dim]` embeddings (new texts encoded, known ones from
    /// `cache`) or tokens.
    fn encode(
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

impl std::fmt::Debug for OpenVocabDetector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpenVocabDetector")
            .field("family", &self.config.family)
            .field("model_path", &self.model_path)
            .field("prompts", &self.prompts.len())
            .finish_non_exhaustive()
    }
}

/// The tensors `config`'s model must have: `(inputs, outputs, what)`, `what` naming the
/// contract for messages.
fn contract_tensors(
    config: &OpenVocabConfig,
    text: &TextInput,
    outputs: &OutputNames,
    text_dim: usize,
) -> (Vec<TensorSpec>, Vec<TensorSpec>, String) {
    const KEY: &str = "detector.open_vocab";
    let family = config.family;
    // Family layouts are named by the family key, generic ones by the key of each name.
    let key = |field: &str| match family {
        Family::Generic => format!("{KEY}.{field}"),
        _ => format!("{KEY}.family = \"{}\"", family.as_str()),
    };
    let image =
        Some(vec![Dim::Is(1), Dim::Is(3), Dim::Is(config.input.height.into()), Dim::Is(config.input.width.into())]);
    let mut inputs = vec![TensorSpec::new(&config.input.name, &format!("{KEY}.input.name"), FLOAT, image)];
    match text.kind {
        TextInputKind::None => {}
        TextInputKind::Embeddings => {
            let mut dims = vec![Dim::Any("P"), Dim::Is(text_dim as i64)];
            if text.batch_axis {
                dims.insert(0, Dim::Is(1));
            }
            inputs.push(TensorSpec::new(&text.name, &key("text.name"), FLOAT, Some(dims)));
        }
        TextInputKind::Tokens => {
            let tokens = || Some(vec![Dim::Any("P"), Dim::Any("L")]);
            inputs.push(TensorSpec::new(&text.name, &key("text.name"), INT64, tokens()));
            if let Some(mask) = &text.attention_mask {
                inputs.push(TensorSpec::new(mask, &key("text.attention_mask"), INT64, tokens()));
            }
        }
    }
    let (boxes, scores) = match family {
        // Generic outputs may carry a batch axis or not; their shapes are checked when run.
        Family::Generic => (None, None),
        _ => (Some(vec![Dim::Is(1), Dim::Any("A"), Dim::Is(4)]), Some(vec![Dim::Is(1), Dim::Any("A"), Dim::Any("P")])),
    };
    let mut outs = vec![
        TensorSpec::new(&outputs.boxes, &key("outputs.boxes"), FLOAT, boxes),
        TensorSpec::new(&outputs.scores, &key("outputs.scores"), FLOAT, scores),
    ];
    for (field, name, dtypes) in [
        ("outputs.prompt_index", &outputs.prompt_index, INDEX),
        ("outputs.masks", &outputs.masks, FLOAT),
        ("outputs.region_embeddings", &outputs.region_embeddings, FLOAT),
    ] {
        if let Some(name) = name {
            outs.push(TensorSpec::new(name, &key(field), dtypes, None));
        }
    }
    let what = match family {
        Family::Generic => format!("the profile's contract ({KEY})"),
        _ => format!("the {} family's export layout ({KEY}.family)", family.as_str()),
    };
    (inputs, outs, what)
}

impl OpenVocabDetector {
    /// Loads the model, checks its sha256 (when set) and its inputs and outputs against the
    /// family's or the profile's contract, and encodes the prompts (with `text_encoder` or the
    /// CLIP encoder when the model takes embeddings, CLIP's tokenizer when it takes tokens).
    pub fn new(
        runtime: &OnnxRuntime,
        config: &OpenVocabConfig,
        knowledge: Arc<KnowledgeBase>,
        text_encoder: &TextEncoderConfig,
    ) -> Result<Self, OnnxError> {
        config.validate("detector.open_vocab").map_err(OnnxError::InvalidConfig)?;
        let (text, outputs) = config.family.contract(config);
        let model_path =
            resolve_path(&config.model_path, "open-vocabulary detector (ONNX)", "detector.open_vocab.model_path")
                .map_err(user_model)?;
        contract::verify_sha256(&model_path, config.sha256.as_deref(), "detector.open_vocab.sha256")?;
        let (session, _) = open_session(
            runtime,
            SessionSpec {
                what: "open-vocabulary detector",
                model_path: &model_path,
                provider: config.execution_provider.unwrap_or(runtime.execution_provider()),
                intra_threads: config.intra_op_threads,
            },
        )?;
        let text_dim = match text.encoder {
            TextEncoderKind::Minilm => EMBEDDING_DIM,
            TextEncoderKind::Clip => config.clip.dim,
        };
        let (inputs, outs, what) = contract_tensors(config, &text, &outputs, text_dim);
        contract::check(&session, &model_path, &what, &inputs, &outs)?;

        let mut encoder = match (text.kind, text.encoder) {
            (TextInputKind::None, _) => PromptEncoder::None,
            (TextInputKind::Embeddings, TextEncoderKind::Minilm) => {
                if !text_encoder.enabled {
                    return Err(OnnxError::InvalidConfig(
                        "text_encoder.enabled: must be true: detector.open_vocab.text.kind = \"embeddings\" encodes the prompts with it"
                            .to_owned(),
                    ));
                }
                PromptEncoder::Minilm(TextEncoder::new(runtime, text_encoder)?)
            }
            (TextInputKind::Embeddings, TextEncoderKind::Clip) => {
                PromptEncoder::Clip(ClipTextEncoder::new(runtime, &config.clip, "detector.open_vocab.clip")?)
            }
            (TextInputKind::Tokens, _) => {
                let tokenizer =
                    ClipTokenizer::new(&config.clip.tokenizer_path, "detector.open_vocab.clip.tokenizer_path")?;
                // The export's own row length when it fixes one, else the profile's.
                let fixed = session
                    .inputs()
                    .iter()
                    .find(|i| i.name() == text.name)
                    .and_then(|i| i.dtype().tensor_shape().and_then(|s| s.get(1).copied()))
                    .filter(|d| *d > 0);
                let length = fixed.map_or(text.context_length, |d| d as usize);
                PromptEncoder::Tokens { tokenizer, length }
            }
        };
        let prompts = prompt_list(&config.prompts, knowledge.clone());
        let mut cache = PromptCache::default();
        let (text_embeddings, tokens) = encoder.encode(&prompts, &mut cache, text_dim)?;
        let tagger = match &config.tagger {
            Some(tagger) => Some(ImageTagger::new(runtime, tagger, "detector.open_vocab.tagger")?),
            None => None,
        };
        // The encoder stays only where a tagger changes the prompts from keyframe to keyframe.
        let encoder = tagger.is_some().then_some(encoder);
        let box_masks = BoxMasks::new(
            runtime,
            &config.depth_mask,
            config.mask_decoder.as_ref(),
            "detector.open_vocab.mask_decoder",
        )?;
        tracing::info!(
            model = %model_path.display(),
            family = config.family.as_str(),
            mask_decoder = box_masks.has_decoder(),
            prompts = prompts.len(),
            parts = prompts.iter().filter(|p| p.kind == NodeKind::Part).count(),
            tagger = tagger.is_some(),
            "open-vocabulary detector loaded"
        );
        Ok(Self {
            session,
            config: config.clone(),
            text,
            outputs,
            model_path,
            prompts,
            text_embeddings,
            text_dim,
            tokens,
            input: Vec::new(),
            box_masks,
            frame_objects: config.prompts.objects.clone(),
            knowledge,
            tagger,
            encoder,
            cache,
        })
    }

    /// With a tagger: this keyframe's object tags (the profile's, then the tagger's) and, when
    /// they differ from the last keyframe's, the prompts built from them and their text input.
    fn follow_tags(&mut self, frame: &Frame) -> Result<(), DetectorError> {
        let (Some(tagger), Some(encoder)) = (self.tagger.as_mut(), self.encoder.as_mut()) else { return Ok(()) };
        let tags = tagger.tag(frame).map_err(DetectorError::Backend)?;
        let mut objects = self.config.prompts.objects.clone();
        for (tag, _) in tags {
            if !objects.contains(&tag) {
                objects.push(tag);
            }
        }
        if objects == self.frame_objects {
            return Ok(());
        }
        let config = PromptConfig { objects, ..self.config.prompts.clone() };
        self.prompts = prompt_list(&config, self.knowledge.clone());
        let encoded = encoder.encode(&self.prompts, &mut self.cache, self.text_dim);
        let (embeddings, tokens) = encoded.map_err(|e| self.backend("encoding the tagged prompts", e))?;
        self.text_embeddings = embeddings;
        self.tokens = tokens;
        tracing::debug!(frame = frame.seq, tags = ?config.objects, prompts = self.prompts.len(), "prompts from the image tagger");
        self.frame_objects = config.objects;
        Ok(())
    }

    /// The vocabulary, in prompt-index order.
    pub fn prompts(&self) -> &[Prompt] {
        &self.prompts
    }

    fn backend(&self, context: &str, message: impl std::fmt::Display) -> DetectorError {
        DetectorError::Backend(format!("{context} ({}): {message}", self.model_path.display()))
    }
}

/// The rows of a float output with a trailing shape `[N, ...]` (a leading batch axis of 1
/// dropped), or why not.
fn rows(shape: &[i64], rank: usize, what: &str) -> Result<Vec<usize>, String> {
    let dims: &[i64] = if shape.len() == rank + 1 && shape[0] == 1 { &shape[1..] } else { shape };
    if dims.len() != rank || dims.iter().any(|d| *d < 0) {
        return Err(format!(
            "output {what} has shape {shape:?}, expected rank {rank} (optionally with a batch axis of 1)"
        ));
    }
    Ok(dims.iter().map(|d| *d as usize).collect())
}

impl Detector for OpenVocabDetector {
    fn detect(&mut self, frame: &Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError> {
        out.clear();
        let intr = frame.intrinsics;
        if frame.rgb.len() != intr.pixel_count() * 3 {
            return Err(DetectorError::Frame { seq: frame.seq, reason: "no RGB image of the frame's size".to_owned() });
        }
        if self.tagger.is_some() {
            self.follow_tags(frame)?;
            if self.prompts.is_empty() {
                return Ok(()); // nothing tagged, nothing listed: nothing to look for
            }
        }
        let spec = &self.config.input;
        let placement = prepare(&frame.rgb, intr.width, intr.height, spec, &mut self.input);
        let image =
            TensorRef::from_array_view(([1usize, 3, spec.height as usize, spec.width as usize], self.input.as_slice()))
                .map_err(|e| self.backend("image tensor", e))?;
        let p = self.prompts.len();
        let mut inputs = vec![(spec.name.as_str(), SessionInputValue::from(image))];
        match self.text.kind {
            TextInputKind::None => {}
            TextInputKind::Embeddings => {
                let shape = if self.text.batch_axis { vec![1, p, self.text_dim] } else { vec![p, self.text_dim] };
                let text = TensorRef::from_array_view((shape, self.text_embeddings.as_slice()))
                    .map_err(|e| self.backend("text tensor", e))?;
                inputs.push((self.text.name.as_str(), text.into()));
            }
            TextInputKind::Tokens => {
                let shape = [p, self.tokens.context_length];
                let ids = TensorRef::from_array_view((shape, self.tokens.ids.as_slice()))
                    .map_err(|e| self.backend("token tensor", e))?;
                inputs.push((self.text.name.as_str(), ids.into()));
                if let Some(name) = &self.text.attention_mask {
                    let mask = TensorRef::from_array_view((shape, self.tokens.mask.as_slice()))
                        .map_err(|e| self.backend("attention-mask tensor", e))?;
                    inputs.push((name.as_str(), mask.into()));
                }
            }
        }
        let outputs = self.session.run(inputs).map_err(|e| {
            DetectorError::Backend(format!("running the open-vocabulary detector ({}): {e}", self.model_path.display()))
        })?;
        let names = &self.outputs;
        let float = |name: &str| {
            outputs
                .get(name)
                .ok_or_else(|| format!("no output {name}"))?
                .try_extract_tensor::<f32>()
                .map(|(shape, data)| (shape.to_vec(), data))
                .map_err(|e| format!("output {name}: {e}"))
        };
        let bad = |message: String| {
            DetectorError::Backend(format!("open-vocabulary detector ({}): {message}", self.model_path.display()))
        };

        let (box_shape, boxes) = float(&names.boxes).map_err(bad)?;
        let box_dims = rows(&box_shape, 2, "boxes").map_err(bad)?;
        let n = box_dims[0];
        if box_dims[1] != 4 {
            return Err(bad(format!("output boxes has shape {box_shape:?}, expected [N, 4]")));
        }
        let (score_shape, scores) = float(&names.scores).map_err(bad)?;
        // (score, prompt) per region.
        let mut best: Vec<(f32, usize)> = Vec::with_capacity(n);
        match &names.prompt_index {
            Some(index_name) => {
                if rows(&score_shape, 1, "scores").map_err(bad)? != [n] {
                    return Err(bad(format!("output scores has shape {score_shape:?}, expected [{n}]")));
                }
                let value = outputs.get(index_name.as_str()).ok_or_else(|| bad(format!("no output {index_name}")))?;
                let indices: Vec<i64> = match value.try_extract_tensor::<i64>() {
                    Ok((_, data)) => data.to_vec(),
                    Err(_) => value
                        .try_extract_tensor::<i32>()
                        .map(|(_, data)| data.iter().map(|v| i64::from(*v)).collect())
                        .map_err(|e| bad(format!("output {index_name}: expected int64 or int32: {e}")))?,
                };
                if indices.len() != n {
                    return Err(bad(format!("output {index_name} has {} entries, expected {n}", indices.len())));
                }
                for (score, index) in scores.iter().zip(indices) {
                    let prompt = usize::try_from(index).ok().filter(|i| *i < p).ok_or_else(|| {
                        bad(format!("output {index_name}: prompt index {index} outside the {p} prompts"))
                    })?;
                    best.push((*score, prompt));
                }
            }
            None => {
                let dims = rows(&score_shape, 2, "scores").map_err(bad)?;
                if dims != [n, p] {
                    return Err(bad(format!(
                        "output scores has shape {score_shape:?}, expected [{n}, {p}] (regions x prompts)"
                    )));
                }
                for row in scores.chunks_exact(p) {
                    let (prompt, score) = row
                        .iter()
                        .copied()
                        .enumerate()
                        // Ties go to the earlier prompt (objects come before their parts).
                        .max_by(|a, b| a.1.total_cmp(&b.1).then(b.0.cmp(&a.0)))
                        .unwrap_or((0, f32::NEG_INFINITY));
                    best.push((score, prompt));
                }
            }
        }

        let (in_w, in_h) = (spec.width as f32, spec.height as f32);
        let Placement { sx, sy } = placement;
        let mut regions: Vec<Region> = Vec::new();
        for (row, (b, &(score, prompt))) in boxes.chunks_exact(4).zip(&best).enumerate() {
            let score = self.config.calibration.apply(names.score_activation.apply(score));
            if score.is_nan() || score <= self.config.score_threshold {
                continue;
            }
            let mut v = [b[0], b[1], b[2], b[3]];
            if names.boxes_normalised {
                v = [v[0] * in_w, v[1] * in_h, v[2] * in_w, v[3] * in_h];
            }
            if names.box_format == BoxFormat::Cxcywh {
                v = [v[0] - v[2] / 2.0, v[1] - v[3] / 2.0, v[0] + v[2] / 2.0, v[1] + v[3] / 2.0];
            }
            let bbox = [v[0] / sx, v[1] / sy, v[2] / sx, v[3] / sy];
            if bbox.iter().all(|c| c.is_finite()) {
                regions.push(Region { bbox, score, prompt, row });
            }
        }
        regions.sort_by(|a, b| b.score.total_cmp(&a.score).then(a.row.cmp(&b.row)));
        let nms = self.config.nms_iou_threshold;
        let kept = greedy_suppress(regions, self.config.max_detections, |k, r| {
            k.prompt == r.prompt && iou(&k.bbox, &r.bbox) > nms
        });

        let masks = match &names.masks {
            Some(name) => {
                let (shape, data) = float(name).map_err(bad)?;
                let dims = rows(&shape, 3, "masks").map_err(bad)?;
                if dims[0] != n {
                    return Err(bad(format!("output {name} has shape {shape:?}, expected [{n}, h, w]")));
                }
                Some((dims[1], dims[2], data))
            }
            None => None,
        };
        let embeddings = match &names.region_embeddings {
            Some(name) => {
                let (shape, data) = float(name).map_err(bad)?;
                let dims = rows(&shape, 2, "region_embeddings").map_err(bad)?;
                if dims[0] != n {
                    return Err(bad(format!("output {name} has shape {shape:?}, expected [{n}, D]")));
                }
                Some((dims[1], data))
            }
            None => None,
        };
        self.box_masks.begin_frame();
        for r in kept {
            let Some(pixel_box) = PixelBox::from_float(r.bbox, intr.width, intr.height) else { continue };
            let mask = match &masks {
                Some((mh, mw, data)) => {
                    let plane = &data[r.row * mh * mw..(r.row + 1) * mh * mw];
                    mask_from_probabilities(plane, *mw, *mh, pixel_box, placement, spec, self.config.mask_threshold)
                }
                None => self.box_masks.mask(frame, r.bbox, pixel_box)?,
            };
            let Some(mask) = mask else { continue };
            let semantic_feature = embeddings.as_ref().and_then(|(d, data)| {
                (*d == EMBEDDING_DIM).then(|| {
                    let mut f = data[r.row * d..(r.row + 1) * d].to_vec();
                    normalise(&mut f);
                    f
                })
            });
            let prompt = &self.prompts[r.prompt];
            out.push(Detection {
                label: prompt.text.clone(),
                kind: prompt.kind,
                score: r.score,
                mask,
                semantic_feature,
            });
        }
        Ok(())
    }

    fn name(&self) -> &str {
        "open_vocab"
    }
}

/// The image pixels of `pixel_box` whose mask probability (sampled nearest from the `mw x mh`
/// plane over the network input) is at least `threshold`; `None` when none is.
fn mask_from_probabilities(
    plane: &[f32],
    mw: usize,
    mh: usize,
    pixel_box: PixelBox,
    placement: Placement,
    spec: &ImageInput,
    threshold: f32,
) -> Option<Mask> {
    let (width, height) = (pixel_box.x1 - pixel_box.x0, pixel_box.y1 - pixel_box.y0);
    let mut data = vec![0u8; (width * height) as usize];
    let (kx, ky) = (mw as f32 / spec.width as f32, mh as f32 / spec.height as f32);
    for y in pixel_box.y0..pixel_box.y1 {
        let my = (((y as f32 + 0.5) * placement.sy * ky) as usize).min(mh - 1);
        for x in pixel_box.x0..pixel_box.x1 {
            let mx = (((x as f32 + 0.5) * placement.sx * kx) as usize).min(mw - 1);
            if plane[my * mw + mx] >= threshold {
                data[((y - pixel_box.y0) * width + (x - pixel_box.x0)) as usize] = 1;
            }
        }
    }
    let mask = Mask { x0: pixel_box.x0, y0: pixel_box.y0, width, height, data };
    (mask.area() > 0).then_some(mask)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn knowledge_guided_prompts_add_each_tagged_objects_parts() {
        let kb = Arc::new(KnowledgeBase::builtin().unwrap());
        let config = PromptConfig {
            objects: vec!["cabinet".into(), "Stove".into()],
            parts: vec!["Door Handle".into()],
            part_prompts: CandidateMode::Knowledge,
        };
        let prompts = prompt_list(&config, kb.clone());
        let texts: Vec<&str> = prompts.iter().map(|p| p.text.as_str()).collect();
        assert_eq!(&texts[..2], ["cabinet", "stove"]);
        assert!(prompts[..2].iter().all(|p| p.kind == NodeKind::Object));
        let generated = prompts.iter().filter(|p| p.text.starts_with("cabinet ") || p.text.starts_with("stove "));
        assert!(generated.clone().count() >= 3 && generated.clone().all(|p| p.kind == NodeKind::Part));
        assert!(texts.contains(&"light switch"), "small things a tagger misses are added: {texts:?}");
        assert!(
            texts.contains(&"cabinet handle") && texts.contains(&"cabinet knob") && texts.contains(&"stove knob"),
            "{texts:?}"
        );
        assert_eq!(texts.last(), Some(&"door handle"), "listed parts come last, normalised");
        let plain = prompt_list(&PromptConfig { part_prompts: CandidateMode::All, ..config }, kb);
        assert_eq!(plain.iter().map(|p| p.text.as_str()).collect::<Vec<_>>(), ["cabinet", "stove", "door handle"]);
    }

    #[test]
    fn masks_are_sampled_through_the_placement() {
        // 4x4 mask over an 8x8 input; the frame was letterboxed at r = 0.5 (16x16 image).
        let mut plane = vec![0.0f32; 16];
        plane[5] = 0.9; // mask cell (1, 1) = input pixels 2..4 = image pixels 4..8
        let spec = ImageInput { width: 8, height: 8, ..ImageInput::default() };
        let bbox = PixelBox { x0: 0, y0: 0, x1: 16, y1: 16 };
        let mask = mask_from_probabilities(&plane, 4, 4, bbox, Placement { sx: 0.5, sy: 0.5 }, &spec, 0.5).unwrap();
        assert_eq!(mask.area(), 16);
        assert!(mask.contains(4, 4) && mask.contains(7, 7) && !mask.contains(8, 8) && !mask.contains(3, 4));
        assert!(mask_from_probabilities(&plane, 4, 4, bbox, Placement { sx: 0.5, sy: 0.5 }, &spec, 0.95).is_none());
    }

    #[test]
    fn validation_names_the_field() {
        let config = OpenVocabConfig::default();
        assert_eq!(
            config.validate("detector.open_vocab").unwrap_err(),
            "detector.open_vocab.prompts: list at least one object tag or part prompt (or set a tagger)"
        );
        let config = OpenVocabConfig {
            prompts: PromptConfig { objects: vec!["tv".into()], ..PromptConfig::default() },
            mask_threshold: 1.0,
            ..OpenVocabConfig::default()
        };
        assert!(config.validate("detector.open_vocab").unwrap_err().starts_with("detector.open_vocab.mask_threshold"));
    }
}
