//! `[detector.open_vocab]`: the model's family and contract, its prompts and thresholds (the
//! fields are described in the module docs of [`super`]).

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::onnx::ExecutionProvider;
use crate::onnx::clip_text::ClipTextConfig;
use crate::onnx::contract;
use crate::perception::candidates::CandidateMode;
use crate::perception::depth_mask::DepthMaskConfig;
use crate::perception::image_input::ImageInput;
use crate::perception::mask_decoder::MaskDecoderConfig;
use crate::perception::tagger::TaggerConfig;
use crate::perception::{ScoreCalibration, validate_detection_limits};

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
    pub(super) fn apply(self, x: f32) -> f32 {
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
                    "{path}.text: only with family = \"generic\"; family = \"{family}\" fixes the text input (see docs/models.md, \"Bringing your own models\")"
                ));
            }
            if self.outputs != OutputNames::default() {
                return Err(format!(
                    "{path}.outputs: only with family = \"generic\"; family = \"{family}\" fixes the outputs (see docs/models.md, \"Bringing your own models\")"
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
