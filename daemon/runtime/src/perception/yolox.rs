//! YOLOX detector through ONNX Runtime (closed vocabulary: the 80 COCO classes).
//!
//! Model contract (YOLOX-nano as exported by Megvii's `export_onnx.py`, see the model README):
//! - input `images`: float32 `[1, 3, S, S]` (S = `input_size`, 416 for nano), **BGR**, 0..255,
//!   no mean / std; the frame is *letterboxed*: scaled by `r = min(S / h, S / w)` to
//!   `(floor(w r), floor(h r))` with bilinear interpolation (half-pixel centres, like OpenCV's
//!   `INTER_LINEAR`, rounded to integers like OpenCV's 8-bit output), placed at the top-left,
//!   the rest filled with 114;
//! - output `output`: float32 `[1, A, 5 + C]`, one row per anchor point of the grids at strides
//!   8, 16, 32 (row-major: stride, then y, then x): `cx, cy, w, h` grid-relative, objectness,
//!   `C` class scores. Decoding: `xy = (raw_xy + grid) * stride`, `wh = exp(raw_wh) * stride`;
//!   score of class `c` = objectness x class score.
//!
//! Post-processing ([`postprocess`]): candidates with score > `score_threshold` (every class of
//! an anchor may be one), greedy non-maximum suppression per class at `nms_iou_threshold`
//! (IoU of continuous boxes, no "+1"), the survivors sorted by score, at most
//! `max_detections`, boxes divided by `r` (image pixels, not clipped).
//!
//! `scripts/reference/yolox_reference.py` runs the same model with onnxruntime's Python API and
//! the same letterbox on an ICL-NUIM frame; `daemon/runtime/tests/it/yolox.rs` checks these functions
//! against its numbers.
//!
//! Sliced inference ([`YoloxDetector::detect_sliced`], `tiles = [columns, rows]`): besides the
//! whole frame, each of a grid of overlapping tiles ([`tile_rects`]) is letterboxed to the full
//! input, so small objects get several times the pixels; [`merge_sliced`] drops tile boxes cut
//! by a tile edge and suppresses duplicates across passes.
//!
//! The [`YoloxDetector`] then maps COCO classes to the profile's labels (`class_map`; classes not
//! in it are dropped), and segments each box from the depth image ([`super::depth_mask`]); a
//! box without enough depth gives no detection. Semantic features: none (fusion compares
//! labels).
//!
//! Cost (`OP3DSG_REFERENCE_PYTHON="env PYTHONPATH=/tmp/ortpy python3" cargo bench -p
//! op3dsg-runtime --bench detector`, development machine, 2 cores, load 1.3-1.9, one intra-op
//! thread): inference 14.6 ms per frame median (letterbox 1.7 ms of it); `session.run`
//! 12.85 ms vs 12.74 ms for onnxruntime's Python API on the same pixels in the same run, i.e.
//! 0.99 x its speed (1.01 x in an earlier run); whole detector (masks from depth included)
//! 16.1 ms. Throughput, one session per worker: 65.9 frames/s with one worker, 129.1 with two;
//! with 2x2 tiles (five inferences a frame) 13.5 and 26.4 frames/s.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use op3dsg_drivers::frame::Frame;
use op3dsg_ipc_types::NodeKind;
use ort::session::Session;
use ort::value::TensorRef;
use serde::{Deserialize, Serialize};

use super::ScoreCalibration;
use super::depth_mask::{DepthMaskConfig, PixelBox};
use super::image_input::{ColourOrder, ImageInput, Resize, prepare};
use super::mask_decoder::{BoxMasks, MaskDecoderConfig};
use super::{Detection, Detector, DetectorError, greedy_suppress, validate_detection_limits};
use crate::onnx::{ExecutionProvider, OnnxError, OnnxRuntime, SessionSpec, open_session, resolve_path};

/// The COCO class names in the model's output order (copied from the model's folder).
pub const COCO_CLASSES_TXT: &str = include_str!("../../data/models/yolox_nano/coco_classes.txt");
/// Strides of the YOLOX heads.
pub const STRIDES: [u32; 3] = [8, 16, 32];
/// Letterbox padding value.
pub const PAD_VALUE: f32 = 114.0;

/// Where a missing YOLOX model comes from: no package registry distributes one, so neither
/// `setup-models.sh` nor the op3dsg package has it; the operator places it.
pub const MODEL_HINT: &str = "no package registry distributes YOLOX weights: place a YOLOX ONNX export there yourself \
     (YOLOX-nano, Apache-2.0: model/yolox_nano.onnx of github.com/Kazuhito00/YOLOX-ONNX-TFLite-Sample). \
     Installed op3dsg (/etc/op3dsg/op3dsgd.toml): sudo install -D -m 0644 yolox_nano.onnx /etc/op3dsg/models/yolox_nano.onnx; \
     a checkout (profiles/stretch3-d435i.toml): install -D -m 0644 yolox_nano.onnx .models/yolox_nano/yolox_nano.onnx \
     (the development setup has it in ../shared/data/models/yolox_nano/); or point detector.yolox.model_path at it";

const INPUT_NAME: &str = "images";
const OUTPUT_NAME: &str = "output";

/// The 80 COCO class names.
pub fn coco_classes() -> Vec<&'static str> {
    COCO_CLASSES_TXT.lines().map(str::trim).filter(|l| !l.is_empty()).collect()
}

/// `[detector.yolox]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct YoloxConfig {
    /// The ONNX model. Relative paths in a profile file are relative to that file.
    pub model_path: PathBuf,
    /// Optional sha256 of `model_path`, checked at start.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
    /// Square network input side, pixels (416 for YOLOX-nano).
    pub input_size: u32,
    /// Keep candidates with objectness x class score above this (the raw score). (0, 1).
    pub score_threshold: f32,
    /// Maps the kept detections' scores onto fusion's scale (`[detector.yolox.calibration]`,
    /// [`super::ScoreCalibration`]); the threshold above applies to the raw score.
    pub calibration: ScoreCalibration,
    /// Per-class NMS: drop a box whose IoU with a higher-scored box of its class exceeds this.
    pub nms_iou_threshold: f32,
    /// At most this many detections per frame.
    pub max_detections: usize,
    /// ONNX Runtime intra-op threads of each worker's session.
    pub intra_op_threads: usize,
    /// Execution provider of the detector's sessions (`cpu`, `cuda`, `openvino`); unset: the
    /// one of `[onnx]`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub execution_provider: Option<ExecutionProvider>,
    /// COCO class name → our label. Classes not listed are dropped.
    pub class_map: BTreeMap<String, String>,
    /// Sliced inference: `[columns, rows]` of overlapping tiles, each run through the model at
    /// full input size besides the whole frame. `[1, 1]` (the default): the whole frame only.
    pub tiles: [u32; 2],
    /// Overlap of neighbouring tiles, fraction of a tile's side, [0, 0.9]. An object narrower
    /// than the overlap lies wholly inside some tile.
    pub tile_overlap: f32,
    /// `[detector.yolox.depth_mask]`.
    pub depth_mask: DepthMaskConfig,
    /// `[detector.yolox.mask_decoder]`: a SAM-family mask decoder whose masks replace those from
    /// depth ([`super::mask_decoder`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mask_decoder: Option<MaskDecoderConfig>,
}

impl Default for YoloxConfig {
    fn default() -> Self {
        Self {
            model_path: PathBuf::from("yolox_nano.onnx"),
            sha256: None,
            input_size: 416,
            score_threshold: 0.3,
            calibration: ScoreCalibration::default(),
            nms_iou_threshold: 0.45,
            max_detections: 100,
            intra_op_threads: 1,
            execution_provider: None,
            class_map: BTreeMap::new(),
            tiles: [1, 1],
            tile_overlap: 0.2,
            depth_mask: DepthMaskConfig::default(),
            mask_decoder: None,
        }
    }
}

impl YoloxConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if self.model_path.as_os_str().is_empty() {
            return Err(format!("{path}.model_path: must not be empty"));
        }
        crate::onnx::contract::validate_sha256(&format!("{path}.sha256"), self.sha256.as_deref())?;
        if self.input_size == 0 || !self.input_size.is_multiple_of(32) || self.input_size > 4096 {
            return Err(format!(
                "{path}.input_size: must be a multiple of 32 within [32, 4096], got {}",
                self.input_size
            ));
        }
        validate_detection_limits(
            path,
            self.score_threshold,
            self.nms_iou_threshold,
            self.max_detections,
            self.intra_op_threads,
        )?;
        if !self.tiles.iter().all(|t| (1..=8).contains(t)) {
            return Err(format!("{path}.tiles: columns and rows must be within [1, 8], got {:?}", self.tiles));
        }
        if !(0.0..=0.9).contains(&self.tile_overlap) {
            return Err(format!("{path}.tile_overlap: must be within [0, 0.9], got {}", self.tile_overlap));
        }
        let classes = coco_classes();
        for (class, label) in &self.class_map {
            if !classes.contains(&class.as_str()) {
                return Err(format!("{path}.class_map.{class}: not a COCO class of the model"));
            }
            if label.trim().is_empty() {
                return Err(format!("{path}.class_map.{class}: the label must not be empty"));
            }
        }
        if let Some(decoder) = &self.mask_decoder {
            decoder.validate(&format!("{path}.mask_decoder"))?;
        }
        self.calibration.validate(&format!("{path}.calibration"))?;
        self.depth_mask.validate(&format!("{path}.depth_mask"))
    }
}

/// One decoded, suppressed box.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct YoloxBox {
    /// `[x0, y0, x1, y1]` in image pixels (not clipped).
    pub bbox: [f32; 4],
    /// Objectness x class score.
    pub score: f32,
    /// COCO class index.
    pub class: usize,
}

/// Letterboxes an RGB8 image (`width x height`) into `out` as the model's BGR float32 NCHW
/// `[1, 3, size, size]` input (0..255, padded with 114). Returns the scale `r` (network pixels
/// per image pixel).
pub fn letterbox(rgb: &[u8], width: u32, height: u32, size: u32, out: &mut Vec<f32>) -> f32 {
    prepare(rgb, width, height, &input_spec(size), out).sx
}

/// YOLOX's input contract as an [`ImageInput`].
pub fn input_spec(size: u32) -> ImageInput {
    ImageInput {
        name: INPUT_NAME.to_owned(),
        width: size,
        height: size,
        colour_order: ColourOrder::Bgr,
        resize: Resize::Letterbox,
        scale: 1.0,
        mean: [0.0; 3],
        std: [1.0; 3],
        pad_value: PAD_VALUE,
    }
}

/// Decodes the raw output rows (`[A, 5 + C]`, row-major) of a `size` input, thresholds,
/// suppresses per class and maps boxes back by `1 / r`. See the module docs.
pub fn postprocess(
    raw: &[f32],
    size: u32,
    num_classes: usize,
    r: f32,
    score_threshold: f32,
    nms_iou_threshold: f32,
    max_detections: usize,
) -> Vec<YoloxBox> {
    let row_len = 5 + num_classes;
    let mut candidates: Vec<YoloxBox> = Vec::new();
    let mut row = 0usize;
    for stride in STRIDES {
        let g = size / stride;
        for gy in 0..g {
            for gx in 0..g {
                let Some(v) = raw.get(row * row_len..(row + 1) * row_len) else {
                    return Vec::new();
                };
                row += 1;
                let objectness = v[4];
                if objectness <= score_threshold {
                    // Class scores are <= 1, so no class of this anchor can pass.
                    continue;
                }
                let st = stride as f32;
                let cx = (v[0] + gx as f32) * st;
                let cy = (v[1] + gy as f32) * st;
                let bw = v[2].exp() * st;
                let bh = v[3].exp() * st;
                let bbox = [(cx - bw / 2.0) / r, (cy - bh / 2.0) / r, (cx + bw / 2.0) / r, (cy + bh / 2.0) / r];
                for (class, &cls) in v[5..].iter().enumerate() {
                    let score = objectness * cls;
                    if score > score_threshold {
                        candidates.push(YoloxBox { bbox, score, class });
                    }
                }
            }
        }
    }
    suppress(candidates, nms_iou_threshold, max_detections)
}

/// Greedy non-maximum suppression per class: highest score first (ties by class, then input
/// order: the sort is stable), a box dropped when its IoU with a kept box of its class exceeds
/// `nms_iou_threshold`; at most `max_detections` kept.
fn suppress(mut candidates: Vec<YoloxBox>, nms_iou_threshold: f32, max_detections: usize) -> Vec<YoloxBox> {
    candidates.sort_by(|a, b| b.score.total_cmp(&a.score).then(a.class.cmp(&b.class)));
    greedy_suppress(candidates, max_detections, |k, c| k.class == c.class && iou(&k.bbox, &c.bbox) > nms_iou_threshold)
}

/// Intersection over union of two `[x0, y0, x1, y1]` boxes.
pub fn iou(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let inter = iw * ih;
    let area = |x: &[f32; 4]| (x[2] - x[0]).max(0.0) * (x[3] - x[1]).max(0.0);
    let union = area(a) + area(b) - inter;
    if union > 0.0 { inter / union } else { 0.0 }
}

/// One YOLOX session with its input buffer: the raw model, image in, boxes out. Owned by one
/// thread (`run` needs `&mut`).
pub struct YoloxModel {
    session: Session,
    model_path: PathBuf,
    provider: ExecutionProvider,
    input_size: u32,
    num_classes: usize,
    input: Vec<f32>,
    raw: Vec<f32>,
}

impl std::fmt::Debug for YoloxModel {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("YoloxModel").field("model_path", &self.model_path).finish_non_exhaustive()
    }
}

impl YoloxModel {
    /// Loads the model file (resolved like [`resolve_path`]; a missing file names the profile
    /// key) into a new session on `runtime`.
    pub fn new(runtime: &OnnxRuntime, config: &YoloxConfig) -> Result<Self, OnnxError> {
        config.validate("detector.yolox").map_err(OnnxError::InvalidConfig)?;
        let model_path = resolve_path(&config.model_path, "YOLOX model (ONNX)", "detector.yolox.model_path").map_err(
            |e| match e {
                OnnxError::FileMissing { what, looked_for, setting } => {
                    OnnxError::ModelMissing { what, looked_for, setting, hint: MODEL_HINT }
                }
                other => other,
            },
        )?;
        crate::onnx::contract::verify_sha256(&model_path, config.sha256.as_deref(), "detector.yolox.sha256")?;
        let provider = config.execution_provider.unwrap_or(runtime.execution_provider());
        let (session, provider) = open_session(
            runtime,
            SessionSpec {
                what: "YOLOX model",
                model_path: &model_path,
                provider,
                intra_threads: config.intra_op_threads,
            },
        )?;
        let has_input = session.inputs().iter().any(|i| i.name() == INPUT_NAME);
        let has_output = session.outputs().iter().any(|o| o.name() == OUTPUT_NAME);
        if !has_input || !has_output {
            return Err(OnnxError::BadModel {
                path: model_path,
                message: format!("expected input {INPUT_NAME:?} and output {OUTPUT_NAME:?} (a YOLOX export)"),
            });
        }
        let num_classes = coco_classes().len();
        tracing::info!(model = %model_path.display(), input_size = config.input_size, provider = provider.as_str(), "YOLOX model loaded");
        Ok(Self {
            session,
            model_path,
            provider,
            input_size: config.input_size,
            num_classes,
            input: Vec::new(),
            raw: Vec::new(),
        })
    }

    /// The model file in use.
    pub fn model_path(&self) -> &Path {
        &self.model_path
    }

    /// The execution provider the session really runs on (the CPU after a fallback).
    pub fn provider(&self) -> ExecutionProvider {
        self.provider
    }

    /// Letterboxes `rgb` and runs the model; returns the letterbox scale. The raw output rows
    /// are then in [`YoloxModel::raw_output`].
    pub fn infer(&mut self, rgb: &[u8], width: u32, height: u32) -> Result<f32, OnnxError> {
        let r = letterbox(rgb, width, height, self.input_size, &mut self.input);
        let s = self.input_size as usize;
        let model_path = &self.model_path;
        let ort_error = |context: &str, e: ort::Error| OnnxError::Ort {
            context: format!("{context} ({})", model_path.display()),
            message: e.to_string(),
        };
        let tensor = TensorRef::from_array_view(([1usize, 3, s, s], self.input.as_slice()))
            .map_err(|e| ort_error("YOLOX input tensor", e))?;
        let outputs =
            self.session.run(ort::inputs![INPUT_NAME => tensor]).map_err(|e| ort_error("running YOLOX", e))?;
        let value = outputs.get(OUTPUT_NAME).ok_or_else(|| OnnxError::BadModel {
            path: model_path.clone(),
            message: format!("no output {OUTPUT_NAME}"),
        })?;
        let (shape, data) = value.try_extract_tensor::<f32>().map_err(|e| ort_error("reading YOLOX output", e))?;
        let anchors: usize = STRIDES.iter().map(|st| ((self.input_size / st) as usize).pow(2)).sum();
        let expected = [1i64, anchors as i64, (5 + self.num_classes) as i64];
        if shape.as_ref() != expected {
            return Err(OnnxError::BadModel {
                path: model_path.clone(),
                message: format!("output has shape {:?}, expected {expected:?}", shape.as_ref()),
            });
        }
        self.raw.clear();
        self.raw.extend_from_slice(data);
        Ok(r)
    }

    /// The raw output rows of the last [`YoloxModel::infer`], `[A * (5 + C)]`.
    pub fn raw_output(&self) -> &[f32] {
        &self.raw
    }

    /// [`YoloxModel::infer`] then [`postprocess`].
    pub fn detect_boxes(
        &mut self,
        rgb: &[u8],
        width: u32,
        height: u32,
        score_threshold: f32,
        nms_iou_threshold: f32,
        max_detections: usize,
    ) -> Result<Vec<YoloxBox>, OnnxError> {
        let r = self.infer(rgb, width, height)?;
        Ok(postprocess(
            &self.raw,
            self.input_size,
            self.num_classes,
            r,
            score_threshold,
            nms_iou_threshold,
            max_detections,
        ))
    }
}

/// The YOLOX detector of one worker: its own session, class map and depth segmenter.
#[derive(Debug)]
pub struct YoloxDetector {
    model: YoloxModel,
    config: YoloxConfig,
    /// Our label per COCO class index (None: dropped).
    labels: Vec<Option<String>>,
    box_masks: BoxMasks,
    /// One tile's pixels (sliced inference).
    tile_rgb: Vec<u8>,
}

impl YoloxDetector {
    /// Loads a session for one worker.
    pub fn new(runtime: &OnnxRuntime, config: &YoloxConfig) -> Result<Self, OnnxError> {
        let model = YoloxModel::new(runtime, config)?;
        let labels = coco_classes().iter().map(|c| config.class_map.get(*c).cloned()).collect();
        Ok(Self {
            model,
            config: config.clone(),
            labels,
            box_masks: BoxMasks::new(
                runtime,
                &config.depth_mask,
                config.mask_decoder.as_ref(),
                "detector.yolox.mask_decoder",
            )?,
            tile_rgb: Vec::new(),
        })
    }

    /// The whole frame's boxes, and with `tiles` set each tile's, merged (see [`merge_sliced`]).
    pub fn detect_sliced(&mut self, rgb: &[u8], width: u32, height: u32) -> Result<Vec<YoloxBox>, OnnxError> {
        let c = &self.config;
        let whole =
            self.model.detect_boxes(rgb, width, height, c.score_threshold, c.nms_iou_threshold, c.max_detections)?;
        if c.tiles == [1, 1] {
            return Ok(whole);
        }
        let rects = tile_rects(width, height, c.tiles, c.tile_overlap);
        let mut tiled = Vec::with_capacity(rects.len());
        for rect in &rects {
            let [x0, y0, x1, y1] = *rect;
            let (tw, th) = (x1 - x0, y1 - y0);
            self.tile_rgb.clear();
            for y in y0..y1 {
                let start = ((y * width + x0) * 3) as usize;
                self.tile_rgb.extend_from_slice(&rgb[start..start + (tw * 3) as usize]);
            }
            let boxes = self.model.detect_boxes(
                &self.tile_rgb,
                tw,
                th,
                c.score_threshold,
                c.nms_iou_threshold,
                c.max_detections,
            )?;
            tiled.push((*rect, boxes));
        }
        Ok(merge_sliced(whole, &tiled, width, height, c.nms_iou_threshold, c.max_detections))
    }
}

/// The tiles of sliced inference, `[x0, y0, x1, y1)` in pixels, row by row: `tiles = [columns,
/// rows]` tiles of equal size covering the frame, neighbours overlapping by `overlap` of a
/// tile's side (the side is `L / (n - (n - 1) overlap)`, rounded up).
pub fn tile_rects(width: u32, height: u32, tiles: [u32; 2], overlap: f32) -> Vec<[u32; 4]> {
    let spans = |length: u32, n: u32| -> Vec<(u32, u32)> {
        let n = n.max(1);
        let side = ((length as f32 / (n as f32 - (n - 1) as f32 * overlap)).ceil() as u32).clamp(1, length.max(1));
        (0..n)
            .map(|i| {
                let start =
                    if n == 1 { 0 } else { ((length - side) as f32 * i as f32 / (n - 1) as f32).round() as u32 };
                (start, start + side)
            })
            .collect()
    };
    let columns = spans(width, tiles[0]);
    let rows = spans(height, tiles[1]);
    rows.iter().flat_map(|&(y0, y1)| columns.iter().map(move |&(x0, x1)| [x0, y0, x1, y1])).collect()
}

/// A tile box this close to a tile edge that lies inside the frame, as a fraction of the tile's
/// side, is cut by the tile (the model rarely places a cut object's box exactly on the edge).
pub const TILE_EDGE_FRACTION: f32 = 0.03;
/// Across passes, a box is suppressed by a better one of its class covering this fraction of
/// the smaller of the two.
pub const SLICED_MIN_COVER: f32 = 0.6;

/// Merges the whole frame's boxes with each tile's (tile pixels, shifted here into the frame).
/// A tile box touching a tile edge that lies inside the frame is dropped: the tile cut the
/// object, which the whole frame or a neighbouring tile sees whole (any object narrower than
/// the overlap lies wholly inside some tile). The rest are suppressed together per class, by
/// score: a box goes when a better one of its class overlaps it by IoU above
/// `nms_iou_threshold` (as [`postprocess`] within one pass) or covers [`SLICED_MIN_COVER`] of
/// the smaller box (a tile's view of a piece of an object the whole frame saw whole, e.g. a
/// chair's arm reported as a chair).
pub fn merge_sliced(
    whole: Vec<YoloxBox>,
    tiled: &[([u32; 4], Vec<YoloxBox>)],
    width: u32,
    height: u32,
    nms_iou_threshold: f32,
    max_detections: usize,
) -> Vec<YoloxBox> {
    let mut candidates = whole;
    for ([x0, y0, x1, y1], boxes) in tiled {
        let (x0, y0, x1, y1) = (*x0 as f32, *y0 as f32, *x1 as f32, *y1 as f32);
        let (mx, my) = ((x1 - x0) * TILE_EDGE_FRACTION, (y1 - y0) * TILE_EDGE_FRACTION);
        for b in boxes {
            let bbox = [b.bbox[0] + x0, b.bbox[1] + y0, b.bbox[2] + x0, b.bbox[3] + y0];
            let cut = (x0 > 0.0 && bbox[0] <= x0 + mx)
                || (y0 > 0.0 && bbox[1] <= y0 + my)
                || (x1 < width as f32 && bbox[2] >= x1 - mx)
                || (y1 < height as f32 && bbox[3] >= y1 - my);
            if !cut {
                candidates.push(YoloxBox { bbox, ..*b });
            }
        }
    }
    candidates.sort_by(|a, b| b.score.total_cmp(&a.score).then(a.class.cmp(&b.class)));
    greedy_suppress(candidates, max_detections, |k, c| {
        k.class == c.class && (iou(&k.bbox, &c.bbox) > nms_iou_threshold || cover(&k.bbox, &c.bbox) >= SLICED_MIN_COVER)
    })
}

/// Intersection of two `[x0, y0, x1, y1]` boxes over the smaller one's area.
pub fn cover(a: &[f32; 4], b: &[f32; 4]) -> f32 {
    let iw = (a[2].min(b[2]) - a[0].max(b[0])).max(0.0);
    let ih = (a[3].min(b[3]) - a[1].max(b[1])).max(0.0);
    let area = |x: &[f32; 4]| (x[2] - x[0]).max(0.0) * (x[3] - x[1]).max(0.0);
    let smaller = area(a).min(area(b));
    if smaller > 0.0 { iw * ih / smaller } else { 0.0 }
}

impl Detector for YoloxDetector {
    fn detect(&mut self, frame: &Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError> {
        out.clear();
        let intr = frame.intrinsics;
        if frame.rgb.len() != intr.pixel_count() * 3 {
            return Err(DetectorError::Frame { seq: frame.seq, reason: "no RGB image of the frame's size".to_owned() });
        }
        let boxes = self
            .detect_sliced(&frame.rgb, intr.width, intr.height)
            .map_err(|e| DetectorError::Backend(e.to_string()))?;
        self.box_masks.begin_frame();
        for b in boxes {
            let Some(label) = self.labels.get(b.class).and_then(Option::as_ref) else { continue };
            let Some(pixel_box) = PixelBox::from_float(b.bbox, intr.width, intr.height) else { continue };
            let Some(mask) = self.box_masks.mask(frame, b.bbox, pixel_box)? else { continue };
            out.push(Detection {
                label: label.clone(),
                kind: NodeKind::Object,
                score: self.config.calibration.apply(b.score),
                mask,
                semantic_feature: None,
            });
        }
        Ok(())
    }

    fn name(&self) -> &str {
        "yolox"
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_class_list_has_80_coco_names() {
        let classes = coco_classes();
        assert_eq!(classes.len(), 80);
        assert_eq!(classes[0], "person");
        assert!(classes.contains(&"diningtable") && classes.contains(&"tvmonitor") && classes.contains(&"pottedplant"));
    }

    #[test]
    fn letterbox_scales_to_the_top_left_and_pads_with_114() {
        // A 8x4 image, all (10, 20, 30), into 8x8: r = 1, rows 4..8 padded.
        let rgb: Vec<u8> = [10u8, 20, 30].repeat(32);
        let mut out = Vec::new();
        let r = letterbox(&rgb, 8, 4, 8, &mut out);
        assert_eq!(r, 1.0);
        assert_eq!(out.len(), 3 * 64);
        assert_eq!(out[0], 30.0, "plane 0 is blue");
        assert_eq!(out[64], 20.0);
        assert_eq!(out[128], 10.0);
        assert_eq!(out[4 * 8], 114.0, "row 4 is padding");
        // 16x8 into 8x8: r = 0.5, 8x4 result.
        let rgb: Vec<u8> = (0..16 * 8).flat_map(|i| [(i % 16) as u8 * 10, 0, 0]).collect();
        let r = letterbox(&rgb, 16, 8, 8, &mut out);
        assert_eq!(r, 0.5);
        // Column 0 samples at x = 0.5: between 0 and 10.
        assert_eq!(out[2 * 64], 5.0);
        assert_eq!(out[2 * 64 + 4 * 8], 114.0);
    }

    #[test]
    fn decoding_and_class_aware_nms() {
        let size = 32u32; // grids 4x4, 2x2, 1x1 = 21 anchors
        let classes = 2;
        let mut raw = vec![0.0f32; 21 * (5 + classes)];
        let set = |raw: &mut Vec<f32>, row: usize, v: [f32; 7]| {
            raw[row * 7..row * 7 + 7].copy_from_slice(&v);
        };
        // Anchor (1, 2) of stride 8: centre (1.5 + 1) * 8 = 20, (0.5 + 2) * 8 = 20, w = h = 8.
        set(&mut raw, 2 * 4 + 1, [1.5, 0.5, 0.0, 0.0, 0.9, 0.9, 0.1]);
        // Its neighbour, overlapping heavily: class 0 (0.72) is suppressed, class 1 (0.56) is
        // kept (NMS is per class).
        set(&mut raw, 2 * 4 + 2, [0.6, 0.5, 0.0, 0.0, 0.8, 0.9, 0.7]);
        let out = postprocess(&raw, size, classes, 0.5, 0.3, 0.45, 10);
        assert_eq!(out.len(), 2, "{out:?}");
        assert_eq!(out[0].class, 0);
        assert!((out[0].score - 0.81).abs() < 1e-6);
        assert_eq!(out[0].bbox, [32.0, 32.0, 48.0, 48.0]);
        assert_eq!(out[1].class, 1);
        assert!((out[1].score - 0.56).abs() < 1e-6);
    }

    #[test]
    fn tiles_cover_the_frame_with_the_requested_overlap() {
        assert_eq!(tile_rects(640, 480, [1, 1], 0.25), vec![[0, 0, 640, 480]]);
        // Side = L / (2 - 0.25): 366 x 275; the second tile ends at the frame's edge.
        let rects = tile_rects(640, 480, [2, 2], 0.25);
        assert_eq!(rects, vec![[0, 0, 366, 275], [274, 0, 640, 275], [0, 205, 366, 480], [274, 205, 640, 480]]);
        let overlap = 366 - 274;
        assert!((overlap as f32 / 366.0 - 0.25).abs() < 0.01);
        // Three columns, no overlap: plain thirds.
        let rects = tile_rects(600, 100, [3, 1], 0.0);
        assert_eq!(rects, vec![[0, 0, 200, 100], [200, 0, 400, 100], [400, 0, 600, 100]]);
    }

    #[test]
    fn sliced_merge_shifts_tile_boxes_drops_cut_ones_and_suppresses_across_passes() {
        let b = |bbox: [f32; 4], score: f32, class: usize| YoloxBox { bbox, score, class };
        let whole = vec![b([100.0, 100.0, 200.0, 200.0], 0.5, 0)];
        let tiles = vec![
            (
                [300u32, 0u32, 640u32, 240u32],
                vec![
                    // Small object inside the tile, at the frame's top edge: kept, shifted.
                    b([250.0, 0.0, 300.0, 40.0], 0.6, 1),
                    // Touches the tile's left edge, which lies inside the frame: cut, dropped.
                    b([0.0, 50.0, 40.0, 90.0], 0.9, 2),
                    // Touches the tile's bottom edge (240 < 480): dropped.
                    b([100.0, 200.0, 150.0, 239.5], 0.9, 2),
                    // Touches the frame's right edge (the tile's right edge is the frame's): kept.
                    b([300.0, 100.0, 340.0, 150.0], 0.4, 3),
                ],
            ),
            // The whole-frame object seen again, better, in another tile: one box survives.
            ([0u32, 0u32, 340u32, 240u32], vec![b([101.0, 100.0, 199.0, 200.0], 0.7, 0)]),
        ];
        let merged = merge_sliced(whole, &tiles, 640, 480, 0.45, 100);
        assert_eq!(
            merged,
            vec![
                b([101.0, 100.0, 199.0, 200.0], 0.7, 0),
                b([550.0, 0.0, 600.0, 40.0], 0.6, 1),
                b([600.0, 100.0, 640.0, 150.0], 0.4, 3),
            ]
        );
    }

    #[test]
    fn config_validation_names_the_field() {
        let mut c = YoloxConfig::default();
        c.validate("detector.yolox").unwrap();
        c.class_map.insert("sofa".into(), "couch".into());
        c.validate("detector.yolox").unwrap();
        // This export spells the classes the VOC way (`sofa`, `tvmonitor`), not `couch`, `tv`.
        c.class_map.insert("couch".into(), "couch".into());
        assert_eq!(
            c.validate("detector.yolox").unwrap_err(),
            "detector.yolox.class_map.couch: not a COCO class of the model"
        );
        let c = YoloxConfig { score_threshold: 1.5, ..YoloxConfig::default() };
        assert!(c.validate("detector.yolox").unwrap_err().starts_with("detector.yolox.score_threshold"));
    }
}
