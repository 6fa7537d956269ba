//! Open-vocabulary detectors through ONNX Runtime: a user's exported object/part detector that
//! takes its vocabulary as text embeddings at run time plugs in by profile alone
//! (`[detector] kind = "open_vocab"`, `[detector.open_vocab]`).
//!
//! # Model contract
//!
//! Inputs:
//! - the image, `[1, 3, H, W]` float32, as `[detector.open_vocab.input]` states it (name, size,
//!   colour order, letterbox or stretch, scale, mean, std, pad; see [`super::image_input`]);
//! - with `text.kind = "embeddings"`: the prompts' embeddings `[P, D]` float32 (tensor
//!   `text.name`), one L2-normalised row per prompt from the profile's `[text_encoder]`; with
//!   `text.kind = "none"` the vocabulary is baked into the model and the prompt list names its
//!   classes in the model's order.
//!
//! Outputs (names in `[detector.open_vocab.outputs]`), `N` candidate regions:
//! - `boxes` `[N, 4]` (a leading batch axis of 1 is accepted everywhere): `xyxy` or `cxcywh`
//!   (`box_format`), in network input pixels or normalised to [0, 1] (`boxes_normalised`);
//! - `scores`: either `[N]` together with `prompt_index` `[N]` (int64 or int32: which prompt),
//!   or, with `prompt_index` unset, `[N, P]` (a score per prompt; the best one is taken);
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
//! `scripts/reference/open_vocab_fixture.py` writes a tiny model with this contract and known
//! answers; `daemon/tests/open_vocab.rs` runs the adapter on it.

use std::path::PathBuf;

use op3dsg_drivers::frame::Frame;
use op3dsg_ipc_types::NodeKind;
use ort::session::Session;
use ort::value::TensorRef;
use serde::{Deserialize, Serialize};

use super::depth_mask::{DepthMaskConfig, DepthSegmenter, PixelBox};
use super::image_input::{ImageInput, Placement, prepare};
use super::yolox::iou;
use super::{Detection, Detector, DetectorError, Mask, greedy_suppress, normalise, validate_detection_limits};
use std::sync::Arc;

use super::candidates::{CandidateMode, PartCandidates, Prompt, PromptList};
use crate::knowledge::KnowledgeBase;
use crate::onnx::text_encoder::{EMBEDDING_DIM, TextEncoder, TextEncoderConfig};
use crate::onnx::{ExecutionProvider, OnnxError, OnnxRuntime, SessionSpec, open_session, resolve_path};

/// How the model receives its vocabulary.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TextInputKind {
    /// `[P, D]` prompt embeddings from `[text_encoder]`.
    #[default]
    Embeddings,
    /// Baked into the model; the prompt list names its classes in order.
    None,
}

/// `[detector.open_vocab.text]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct TextInput {
    /// Embeddings or none.
    pub kind: TextInputKind,
    /// Tensor name of the embeddings.
    pub name: String,
}

impl Default for TextInput {
    fn default() -> Self {
        Self { kind: TextInputKind::Embeddings, name: "text_embeddings".to_owned() }
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
    /// The ONNX model. Relative paths in a profile file are relative to that file.
    pub model_path: PathBuf,
    /// Image input contract.
    pub input: ImageInput,
    /// Text input contract.
    pub text: TextInput,
    /// Output names and encodings.
    pub outputs: OutputNames,
    /// The vocabulary.
    pub prompts: PromptConfig,
    /// Keep regions scoring above this. (0, 1).
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
}

impl Default for OpenVocabConfig {
    fn default() -> Self {
        Self {
            model_path: PathBuf::from("open_vocab.onnx"),
            input: ImageInput::default(),
            text: TextInput::default(),
            outputs: OutputNames::default(),
            prompts: PromptConfig::default(),
            score_threshold: 0.3,
            nms_iou_threshold: 0.5,
            max_detections: 100,
            mask_threshold: 0.5,
            intra_op_threads: 1,
            execution_provider: None,
            depth_mask: DepthMaskConfig::default(),
        }
    }
}

impl OpenVocabConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if self.model_path.as_os_str().is_empty() {
            return Err(format!("{path}.model_path: must not be empty"));
        }
        self.input.validate(&format!("{path}.input"))?;
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
        if self.prompts.objects.is_empty() && self.prompts.parts.is_empty() {
            return Err(format!("{path}.prompts: list at least one object tag or part prompt"));
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

/// The open-vocabulary detector of one worker: its own session, the prompts' embeddings and a
/// depth segmenter.
pub struct OpenVocabDetector {
    session: Session,
    config: OpenVocabConfig,
    model_path: PathBuf,
    prompts: Vec<Prompt>,
    /// `[P, D]` row-major (empty with `text.kind = "none"`).
    text_embeddings: Vec<f32>,
    input: Vec<f32>,
    segmenter: DepthSegmenter,
}

impl std::fmt::Debug for OpenVocabDetector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpenVocabDetector")
            .field("model_path", &self.model_path)
            .field("prompts", &self.prompts.len())
            .finish_non_exhaustive()
    }
}

impl OpenVocabDetector {
    /// Loads the model, checks its inputs and outputs against the profile's contract and
    /// encodes the prompts (with `text_encoder` when the model takes embeddings).
    pub fn new(
        runtime: &OnnxRuntime,
        config: &OpenVocabConfig,
        knowledge: Arc<KnowledgeBase>,
        text_encoder: &TextEncoderConfig,
    ) -> Result<Self, OnnxError> {
        config.validate("detector.open_vocab").map_err(OnnxError::InvalidConfig)?;
        let model_path =
            resolve_path(&config.model_path, "open-vocabulary detector (ONNX)", "detector.open_vocab.model_path")?;
        let (session, _) = open_session(
            runtime,
            SessionSpec {
                what: "open-vocabulary detector",
                model_path: &model_path,
                provider: config.execution_provider.unwrap_or(runtime.execution_provider()),
                intra_threads: config.intra_op_threads,
            },
        )?;
        let bad = |message: String| OnnxError::BadModel { path: model_path.clone(), message };
        let inputs: Vec<&str> = session.inputs().iter().map(|i| i.name()).collect();
        let outputs: Vec<&str> = session.outputs().iter().map(|o| o.name()).collect();
        let mut wanted_inputs = vec![("detector.open_vocab.input.name", config.input.name.as_str())];
        if config.text.kind == TextInputKind::Embeddings {
            wanted_inputs.push(("detector.open_vocab.text.name", config.text.name.as_str()));
        }
        for (key, name) in wanted_inputs {
            if !inputs.contains(&name) {
                return Err(bad(format!("no input {name:?} ({key}); the model's inputs are {inputs:?}")));
            }
        }
        let o = &config.outputs;
        let wanted_outputs = [
            Some(("boxes", o.boxes.as_str())),
            Some(("scores", o.scores.as_str())),
            o.prompt_index.as_deref().map(|n| ("prompt_index", n)),
            o.masks.as_deref().map(|n| ("masks", n)),
            o.region_embeddings.as_deref().map(|n| ("region_embeddings", n)),
        ];
        for (key, name) in wanted_outputs.into_iter().flatten() {
            if !outputs.contains(&name) {
                return Err(bad(format!(
                    "no output {name:?} (detector.open_vocab.outputs.{key}); the model's outputs are {outputs:?}"
                )));
            }
        }
        let prompts = prompt_list(&config.prompts, knowledge);
        let text_embeddings = match config.text.kind {
            TextInputKind::None => Vec::new(),
            TextInputKind::Embeddings => {
                if !text_encoder.enabled {
                    return Err(OnnxError::InvalidConfig(
                        "text_encoder.enabled: must be true: detector.open_vocab.text.kind = \"embeddings\" encodes the prompts with it"
                            .to_owned(),
                    ));
                }
                let mut encoder = TextEncoder::new(runtime, text_encoder)?;
                let texts: Vec<&str> = prompts.iter().map(|p| p.text.as_str()).collect();
                encoder.encode_batch(&texts)?.iter().flatten().copied().collect()
            }
        };
        tracing::info!(
            model = %model_path.display(),
            prompts = prompts.len(),
            parts = prompts.iter().filter(|p| p.kind == NodeKind::Part).count(),
            "open-vocabulary detector loaded"
        );
        Ok(Self {
            session,
            config: config.clone(),
            model_path,
            prompts,
            text_embeddings,
            input: Vec::new(),
            segmenter: DepthSegmenter::new(config.depth_mask.clone()),
        })
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
        let spec = &self.config.input;
        let placement = prepare(&frame.rgb, intr.width, intr.height, spec, &mut self.input);
        let image =
            TensorRef::from_array_view(([1usize, 3, spec.height as usize, spec.width as usize], self.input.as_slice()))
                .map_err(|e| self.backend("image tensor", e))?;
        let p = self.prompts.len();
        let outputs = if self.config.text.kind == TextInputKind::Embeddings {
            let text = TensorRef::from_array_view(([p, EMBEDDING_DIM], self.text_embeddings.as_slice()))
                .map_err(|e| self.backend("text tensor", e))?;
            self.session.run(ort::inputs![spec.name.as_str() => image, self.config.text.name.as_str() => text])
        } else {
            self.session.run(ort::inputs![spec.name.as_str() => image])
        }
        .map_err(|e| {
            DetectorError::Backend(format!("running the open-vocabulary detector ({}): {e}", self.model_path.display()))
        })?;
        let names = &self.config.outputs;
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
                        .max_by(|a, b| a.1.total_cmp(&b.1))
                        .unwrap_or((0, f32::NEG_INFINITY));
                    best.push((score, prompt));
                }
            }
        }

        let (in_w, in_h) = (spec.width as f32, spec.height as f32);
        let Placement { sx, sy } = placement;
        let mut regions: Vec<Region> = Vec::new();
        for (row, (b, &(score, prompt))) in boxes.chunks_exact(4).zip(&best).enumerate() {
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
        let has_depth = frame.depth.len() == intr.pixel_count();
        let depth_m = |i: usize| if has_depth { frame.depth_m(i) } else { 0.0 };
        for r in kept {
            let Some(pixel_box) = PixelBox::from_float(r.bbox, intr.width, intr.height) else { continue };
            let mask = match &masks {
                Some((mh, mw, data)) => {
                    let plane = &data[r.row * mh * mw..(r.row + 1) * mh * mw];
                    mask_from_probabilities(plane, *mw, *mh, pixel_box, placement, spec, self.config.mask_threshold)
                }
                None => self.segmenter.segment(&depth_m, intr.width, pixel_box),
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
            "detector.open_vocab.prompts: list at least one object tag or part prompt"
        );
        let config = OpenVocabConfig {
            prompts: PromptConfig { objects: vec!["tv".into()], ..PromptConfig::default() },
            mask_threshold: 1.0,
            ..OpenVocabConfig::default()
        };
        assert!(config.validate("detector.open_vocab").unwrap_err().starts_with("detector.open_vocab.mask_threshold"));
    }
}
