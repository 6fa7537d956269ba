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
//! answers; `daemon/sim/tests/it/model_families.rs` runs the families on them.
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
//! answers; `daemon/sim/tests/it/open_vocab.rs` runs the adapter on it.
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[detector.open_vocab]` ([`OpenVocabConfig`]) |
//! | `tensors.rs` | the tensors each family's model must have |
//! | `prompts.rs` | the prompt list and its encoding |
//! | this file | [`OpenVocabDetector`]: inference and decoding |

mod config;
mod prompts;
mod tensors;
#[cfg(test)]
mod tests;

pub use config::{
    BoxFormat, Family, OpenVocabConfig, OutputNames, PromptConfig, ScoreActivation, TextEncoderKind, TextInput,
    TextInputKind,
};
pub use prompts::prompt_list;
use prompts::{PromptCache, PromptEncoder};
use tensors::contract_tensors;

use std::path::PathBuf;
use std::sync::Arc;

use op3dsg_drivers::frame::Frame;
use op3dsg_ipc_types::NodeKind;
use ort::session::Session;
use ort::session::SessionInputValue;
use ort::value::TensorRef;

use super::candidates::Prompt;
use super::depth_mask::PixelBox;
use super::image_input::{ImageInput, Placement, prepare};
use super::mask_decoder::BoxMasks;
use super::tagger::ImageTagger;
use super::yolox::iou;
use super::{Detection, Detector, DetectorError, Mask, greedy_suppress};
use crate::embedding::{EMBEDDING_DIM, normalise};
use crate::knowledge::KnowledgeBase;
use crate::onnx::clip_text::{ClipTextEncoder, ClipTokenizer, Tokens};
use crate::onnx::contract::{self, user_model};
use crate::onnx::text_encoder::{TextEncoder, TextEncoderConfig};
use crate::onnx::{OnnxError, OnnxRuntime, SessionSpec, open_session, resolve_path};

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

impl std::fmt::Debug for OpenVocabDetector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpenVocabDetector")
            .field("family", &self.config.family)
            .field("model_path", &self.model_path)
            .field("prompts", &self.prompts.len())
            .finish_non_exhaustive()
    }
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
        let bad = |message: String| {
            DetectorError::Backend(format!("open-vocabulary detector ({}): {message}", self.model_path.display()))
        };

        let (box_shape, boxes) = float_output(&outputs, &names.boxes).map_err(bad)?;
        let box_dims = rows(&box_shape, 2, "boxes").map_err(bad)?;
        let n = box_dims[0];
        if box_dims[1] != 4 {
            return Err(bad(format!("output boxes has shape {box_shape:?}, expected [N, 4]")));
        }
        let (score_shape, scores) = float_output(&outputs, &names.scores).map_err(bad)?;
        let best = best_per_region(&outputs, names, n, p, &score_shape, scores).map_err(bad)?;
        let mut regions = decode_regions(boxes, &best, names, &self.config, placement);
        regions.sort_by(|a, b| b.score.total_cmp(&a.score).then(a.row.cmp(&b.row)));
        let nms = self.config.nms_iou_threshold;
        let kept = greedy_suppress(regions, self.config.max_detections, |k, r| {
            k.prompt == r.prompt && iou(&k.bbox, &r.bbox) > nms
        });

        let (masks, embeddings) = optional_outputs(&outputs, names, n).map_err(bad)?;
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

/// The output `name` as an f32 tensor: its shape and data.
fn float_output<'o>(
    outputs: &'o ort::session::SessionOutputs<'_>,
    name: &str,
) -> Result<(Vec<i64>, &'o [f32]), String> {
    outputs
        .get(name)
        .ok_or_else(|| format!("no output {name}"))?
        .try_extract_tensor::<f32>()
        .map(|(shape, data)| (shape.to_vec(), data))
        .map_err(|e| format!("output {name}: {e}"))
}

/// The optional outputs: per-region mask planes `(h, w, data)` and region embeddings `(D, data)`.
type OptionalOutputs<'o> = (Option<(usize, usize, &'o [f32])>, Option<(usize, &'o [f32])>);

/// The optional outputs of the `n` regions, checked against `n`.
fn optional_outputs<'o>(
    outputs: &'o ort::session::SessionOutputs<'_>,
    names: &OutputNames,
    n: usize,
) -> Result<OptionalOutputs<'o>, String> {
    let float = |name: &str| float_output(outputs, name);
    let masks = match &names.masks {
        Some(name) => {
            let (shape, data) = float(name)?;
            let dims = rows(&shape, 3, "masks")?;
            if dims[0] != n {
                return Err(format!("output {name} has shape {shape:?}, expected [{n}, h, w]"));
            }
            Some((dims[1], dims[2], data))
        }
        None => None,
    };
    let embeddings = match &names.region_embeddings {
        Some(name) => {
            let (shape, data) = float(name)?;
            let dims = rows(&shape, 2, "region_embeddings")?;
            if dims[0] != n {
                return Err(format!("output {name} has shape {shape:?}, expected [{n}, D]"));
            }
            Some((dims[1], data))
        }
        None => None,
    };
    Ok((masks, embeddings))
}

/// The best `(score, prompt)` of each of the `n` regions: from the prompt-index output, or the
/// highest of each region's `p` scores (ties to the earlier prompt).
fn best_per_region(
    outputs: &ort::session::SessionOutputs<'_>,
    names: &OutputNames,
    n: usize,
    p: usize,
    score_shape: &[i64],
    scores: &[f32],
) -> Result<Vec<(f32, usize)>, String> {
    let mut best: Vec<(f32, usize)> = Vec::with_capacity(n);
    match &names.prompt_index {
        Some(index_name) => {
            if rows(score_shape, 1, "scores")? != [n] {
                return Err(format!("output scores has shape {score_shape:?}, expected [{n}]"));
            }
            let value = outputs.get(index_name.as_str()).ok_or_else(|| format!("no output {index_name}"))?;
            let indices: Vec<i64> = match value.try_extract_tensor::<i64>() {
                Ok((_, data)) => data.to_vec(),
                Err(_) => value
                    .try_extract_tensor::<i32>()
                    .map(|(_, data)| data.iter().map(|v| i64::from(*v)).collect())
                    .map_err(|e| format!("output {index_name}: expected int64 or int32: {e}"))?,
            };
            if indices.len() != n {
                return Err(format!("output {index_name} has {} entries, expected {n}", indices.len()));
            }
            for (score, index) in scores.iter().zip(indices) {
                let prompt = usize::try_from(index)
                    .ok()
                    .filter(|i| *i < p)
                    .ok_or_else(|| format!("output {index_name}: prompt index {index} outside the {p} prompts"))?;
                best.push((*score, prompt));
            }
        }
        None => {
            let dims = rows(score_shape, 2, "scores")?;
            if dims != [n, p] {
                return Err(format!(
                    "output scores has shape {score_shape:?}, expected [{n}, {p}] (regions x prompts)"
                ));
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
    Ok(best)
}

/// The regions whose calibrated score passes the threshold, boxes in image pixels.
fn decode_regions(
    boxes: &[f32],
    best: &[(f32, usize)],
    names: &OutputNames,
    config: &OpenVocabConfig,
    placement: Placement,
) -> Vec<Region> {
    let (in_w, in_h) = (config.input.width as f32, config.input.height as f32);
    let Placement { sx, sy } = placement;
    let mut regions: Vec<Region> = Vec::new();
    for (row, (b, &(score, prompt))) in boxes.chunks_exact(4).zip(best).enumerate() {
        let score = config.calibration.apply(names.score_activation.apply(score));
        if score.is_nan() || score <= config.score_threshold {
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
    regions
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
