//! A SAM-family mask decoder for box detectors (`[detector.open_vocab.mask_decoder]`,
//! `[detector.yolox.mask_decoder]`): the image encoder runs once per frame that has a box, the
//! prompt decoder once per detection box, and its mask replaces the one segmented from depth
//! ([`BoxMasks`] picks one or the other for both detectors).
//!
//! # Contract (SAM and MobileSAM exports)
//!
//! Encoder (e.g. MobileSAM's or SAM's image encoder exported with `torch.onnx.export`):
//! - in `input.name` (`images`) float32 `[1, 3, 1024, 1024]`: RGB, longest side scaled to 1024,
//!   placed top-left and padded, `(v - mean) / std` with SAM's mean `[123.675, 116.28, 103.53]`
//!   and std `[58.395, 57.12, 57.375]` on 0..255 values (SAM pads with 0 after normalising; the
//!   default `pad_value` 117 is the mean's grey, about 0 after normalising);
//! - out `embeddings` (`image_embeddings`) float32 `[1, C, h, w]` (SAM: `[1, 256, 64, 64]`).
//!
//! Decoder, as segment-anything's `scripts/export_onnx_model.py --return-single-mask` writes it
//! (MobileSAM's export script is the same):
//! - in `image_embeddings` (the encoder's output), `point_coords` float32 `[1, K, 2]` (input
//!   pixels: the box corners, then a padding point `(0, 0)`), `point_labels` float32 `[1, K]`
//!   (`2, 3, -1`), `mask_input` float32 `[1, 1, 256, 256]` (zeros), `has_mask_input` float32
//!   `[1]` (0), `orig_im_size` float32 `[2]` (image height, width);
//! - out `masks` float32 `[1, 1, H, W]`: logits at the image size; a pixel is inside when its
//!   logit is above `mask_threshold` (0). The mask is cut to the detection box.
//!
//! # Contract (EfficientSAM exports), `layout = "efficient_sam"`
//!
//! As EfficientSAM's `export_to_onnx.py` (from labelme's) writes them:
//! - encoder: in `input.name` (`batched_images`) float32 `[1, 3, H, W]`, RGB on 0..1 values
//!   without normalisation (the model resizes to 1024 x 1024 and normalises inside; give
//!   `input = { name = "batched_images", width = 1024, height = 1024, resize = "stretch",
//!   scale = 0.00392157, mean = [0, 0, 0], std = [1, 1, 1] }`); out `embeddings`
//!   (`image_embeddings`) float32 `[1, 256, 64, 64]`;
//! - decoder: in `image_embeddings`, `batched_point_coords` float32 `[1, 1, K, 2]` (image
//!   pixels: the model scales them by `orig_im_size` itself), `batched_point_labels` float32
//!   `[1, 1, K]` (box corners `2, 3`), `orig_im_size` int64 `[2]` (image height, width); out
//!   `output_masks` float32 `[1, 1, M, H, W]` (M candidate masks, logits at the image size) and
//!   `iou_predictions` float32 `[1, 1, M]`: the candidate with the highest predicted IoU is
//!   taken, then thresholded and cut to the box as above.

use std::path::PathBuf;

use op3dsg_drivers::frame::Frame;
use ort::session::{Session, SessionInputValue};
use ort::value::TensorRef;
use serde::{Deserialize, Serialize};

use super::depth_mask::{DepthMaskConfig, DepthSegmenter, PixelBox};
use super::image_input::{ImageInput, Placement, prepare, run_on_image};
use super::{DetectorError, Mask};
use crate::onnx::contract::{self, Dim, FLOAT, INT64, TensorSpec};
use crate::onnx::{OnnxError, OnnxRuntime};

/// Which export layout the encoder and decoder have.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum MaskDecoderLayout {
    /// segment-anything's (SAM, MobileSAM): single-mask decoder, prompts in the encoder's input
    /// pixels.
    #[default]
    Sam,
    /// EfficientSAM's: candidate masks with IoU predictions, prompts in image pixels.
    EfficientSam,
}

/// `[detector.open_vocab.mask_decoder]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct MaskDecoderConfig {
    /// The export layout (module docs).
    pub layout: MaskDecoderLayout,
    /// The image encoder (ONNX). Relative paths in a profile file are relative to that file.
    pub encoder_path: PathBuf,
    /// Optional sha256 of `encoder_path`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub encoder_sha256: Option<String>,
    /// The prompt decoder (ONNX).
    pub decoder_path: PathBuf,
    /// Optional sha256 of `decoder_path`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub decoder_sha256: Option<String>,
    /// The encoder's image input.
    pub input: ImageInput,
    /// The encoder's output (and the decoder's input) name.
    pub embeddings: String,
    /// Mask logit above which a pixel is inside.
    pub mask_threshold: f32,
    /// ONNX Runtime intra-op threads of each session.
    pub intra_op_threads: usize,
}

impl Default for MaskDecoderConfig {
    fn default() -> Self {
        Self {
            layout: MaskDecoderLayout::Sam,
            encoder_path: PathBuf::from("sam_encoder.onnx"),
            encoder_sha256: None,
            decoder_path: PathBuf::from("sam_decoder.onnx"),
            decoder_sha256: None,
            input: ImageInput {
                name: "images".to_owned(),
                width: 1024,
                height: 1024,
                scale: 1.0,
                mean: [123.675, 116.28, 103.53],
                std: [58.395, 57.12, 57.375],
                pad_value: 117.0,
                ..ImageInput::default()
            },
            embeddings: "image_embeddings".to_owned(),
            mask_threshold: 0.0,
            intra_op_threads: 1,
        }
    }
}

impl MaskDecoderConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        for (field, value) in [("encoder_path", &self.encoder_path), ("decoder_path", &self.decoder_path)] {
            if value.as_os_str().is_empty() {
                return Err(format!("{path}.{field}: must not be empty"));
            }
        }
        contract::validate_sha256(&format!("{path}.encoder_sha256"), self.encoder_sha256.as_deref())?;
        contract::validate_sha256(&format!("{path}.decoder_sha256"), self.decoder_sha256.as_deref())?;
        self.input.validate(&format!("{path}.input"))?;
        if !self.mask_threshold.is_finite() {
            return Err(format!("{path}.mask_threshold: must be finite"));
        }
        if !(1..=64).contains(&self.intra_op_threads) {
            return Err(format!("{path}.intra_op_threads: must be within [1, 64], got {}", self.intra_op_threads));
        }
        Ok(())
    }
}

const DECODER_INPUTS: [&str; 5] = ["point_coords", "point_labels", "mask_input", "has_mask_input", "orig_im_size"];
const MASKS: &str = "masks";
/// EfficientSAM's decoder inputs (after the embeddings) and outputs.
const EFFICIENT_INPUTS: [&str; 3] = ["batched_point_coords", "batched_point_labels", "orig_im_size"];
const EFFICIENT_OUTPUTS: [&str; 2] = ["output_masks", "iou_predictions"];

/// The encoder and decoder sessions of one worker, and the current frame's embeddings.
pub struct SamMaskDecoder {
    encoder: Session,
    decoder: Session,
    config: MaskDecoderConfig,
    decoder_path: PathBuf,
    encoder_path: PathBuf,
    input: Vec<f32>,
    placement: Placement,
    embeddings: Vec<f32>,
    embedding_shape: Vec<usize>,
    mask_input: Vec<f32>,
}

impl std::fmt::Debug for SamMaskDecoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("SamMaskDecoder").field("decoder_path", &self.decoder_path).finish_non_exhaustive()
    }
}

impl SamMaskDecoder {
    /// Loads both files of `config` (section `key`), checking sha256s and tensors.
    pub fn new(runtime: &OnnxRuntime, config: &MaskDecoderConfig, key: &str) -> Result<Self, OnnxError> {
        config.validate(key).map_err(OnnxError::InvalidConfig)?;
        let open = |path: &PathBuf, sha: &Option<String>, field: &str, what: &'static str| {
            let keys = (format!("{key}.{field}_path"), format!("{key}.{field}_sha256"));
            contract::open_user_model(runtime, path, sha.as_deref(), what, (&keys.0, &keys.1), config.intra_op_threads)
        };
        let (encoder, encoder_path) =
            open(&config.encoder_path, &config.encoder_sha256, "encoder", "SAM image encoder")?;
        let (decoder, decoder_path) =
            open(&config.decoder_path, &config.decoder_sha256, "decoder", "SAM mask decoder")?;
        let image =
            Some(vec![Dim::Is(1), Dim::Is(3), Dim::Is(config.input.height.into()), Dim::Is(config.input.width.into())]);
        let embedding = || Some(vec![Dim::Is(1), Dim::Any("C"), Dim::Any("h"), Dim::Any("w")]);
        contract::check(
            &encoder,
            &encoder_path,
            &format!("the SAM image encoder layout ({key})"),
            &[TensorSpec::new(&config.input.name, &format!("{key}.input.name"), FLOAT, image)],
            &[TensorSpec::new(&config.embeddings, &format!("{key}.embeddings"), FLOAT, embedding())],
        )?;
        let dims = |d: &[Dim]| Some(d.to_vec());
        let (decoder_inputs, decoder_outputs, what) = match config.layout {
            MaskDecoderLayout::Sam => {
                let layout = format!("{key} (segment-anything's export_onnx_model.py)");
                let inputs = vec![
                    TensorSpec::new(&config.embeddings, &format!("{key}.embeddings"), FLOAT, embedding()),
                    TensorSpec::new(DECODER_INPUTS[0], &layout, FLOAT, dims(&[Dim::Is(1), Dim::Any("K"), Dim::Is(2)])),
                    TensorSpec::new(DECODER_INPUTS[1], &layout, FLOAT, dims(&[Dim::Is(1), Dim::Any("K")])),
                    TensorSpec::new(
                        DECODER_INPUTS[2],
                        &layout,
                        FLOAT,
                        dims(&[Dim::Is(1), Dim::Is(1), Dim::Any("m"), Dim::Any("m")]),
                    ),
                    TensorSpec::new(DECODER_INPUTS[3], &layout, FLOAT, dims(&[Dim::Is(1)])),
                    TensorSpec::new(DECODER_INPUTS[4], &layout, FLOAT, dims(&[Dim::Is(2)])),
                ];
                let outputs = vec![TensorSpec::new(
                    MASKS,
                    &layout,
                    FLOAT,
                    dims(&[Dim::Is(1), Dim::Is(1), Dim::Any("H"), Dim::Any("W")]),
                )];
                (inputs, outputs, "the SAM mask decoder layout")
            }
            MaskDecoderLayout::EfficientSam => {
                let layout = format!("{key}.layout = \"efficient_sam\" (EfficientSAM's export_to_onnx.py)");
                let inputs = vec![
                    TensorSpec::new(&config.embeddings, &format!("{key}.embeddings"), FLOAT, embedding()),
                    TensorSpec::new(
                        EFFICIENT_INPUTS[0],
                        &layout,
                        FLOAT,
                        dims(&[Dim::Is(1), Dim::Is(1), Dim::Any("K"), Dim::Is(2)]),
                    ),
                    TensorSpec::new(
                        EFFICIENT_INPUTS[1],
                        &layout,
                        FLOAT,
                        dims(&[Dim::Is(1), Dim::Is(1), Dim::Any("K")]),
                    ),
                    TensorSpec::new(EFFICIENT_INPUTS[2], &layout, INT64, dims(&[Dim::Is(2)])),
                ];
                let outputs = vec![
                    TensorSpec::new(
                        EFFICIENT_OUTPUTS[0],
                        &layout,
                        FLOAT,
                        dims(&[Dim::Is(1), Dim::Is(1), Dim::Any("M"), Dim::Any("H"), Dim::Any("W")]),
                    ),
                    TensorSpec::new(
                        EFFICIENT_OUTPUTS[1],
                        &layout,
                        FLOAT,
                        dims(&[Dim::Is(1), Dim::Is(1), Dim::Any("M")]),
                    ),
                ];
                (inputs, outputs, "the EfficientSAM mask decoder layout")
            }
        };
        contract::check(&decoder, &decoder_path, what, &decoder_inputs, &decoder_outputs)?;
        // The mask prompt's side from the file (256 for SAM), zeros.
        let side = decoder
            .inputs()
            .iter()
            .find(|i| i.name() == DECODER_INPUTS[2])
            .and_then(|i| i.dtype().tensor_shape().and_then(|s| s.get(2).copied()))
            .filter(|d| *d > 0)
            .unwrap_or(256) as usize;
        Ok(Self {
            encoder,
            decoder,
            config: config.clone(),
            decoder_path,
            encoder_path,
            input: Vec::new(),
            placement: Placement { sx: 1.0, sy: 1.0 },
            embeddings: Vec::new(),
            embedding_shape: Vec::new(),
            mask_input: vec![0.0; side * side],
        })
    }

    fn error(&self, context: &str, e: impl std::fmt::Display) -> String {
        format!("SAM {context} ({}): {e}", self.decoder_path.display())
    }

    /// Runs the image encoder on `frame` (once per frame, before [`SamMaskDecoder::mask`]).
    pub fn set_image(&mut self, frame: &Frame) -> Result<(), String> {
        let intr = frame.intrinsics;
        let spec = &self.config.input;
        self.placement = prepare(&frame.rgb, intr.width, intr.height, spec, &mut self.input);
        let shape = run_on_image(
            &mut self.encoder,
            spec,
            &self.input,
            (&self.config.embeddings, &mut self.embeddings),
            "SAM image encoder",
            &self.encoder_path,
        )?;
        self.embedding_shape = shape.iter().map(|d| (*d).max(0) as usize).collect();
        Ok(())
    }

    /// The decoder's mask for the box `bbox` (image pixels) of the frame given to
    /// [`SamMaskDecoder::set_image`], cut to `pixel_box`; `None` when no pixel of the box is in it.
    pub fn mask(
        &mut self,
        bbox: [f32; 4],
        pixel_box: PixelBox,
        width: u32,
        height: u32,
    ) -> Result<Option<Mask>, String> {
        if self.config.layout == MaskDecoderLayout::EfficientSam {
            return self.efficient_sam_mask(bbox, pixel_box, width, height);
        }
        let Placement { sx, sy } = self.placement;
        let coords = [bbox[0] * sx, bbox[1] * sy, bbox[2] * sx, bbox[3] * sy, 0.0, 0.0];
        let labels = [2.0f32, 3.0, -1.0];
        let has_mask = [0.0f32];
        let size = [height as f32, width as f32];
        let side = (self.mask_input.len() as f64).sqrt() as usize;
        let tensor = |e| self.error("prompt tensor", e);
        let inputs: Vec<(&str, SessionInputValue)> = vec![
            (self.config.embeddings.as_str(), embeddings_input(&self.embedding_shape, &self.embeddings)?),
            (DECODER_INPUTS[0], TensorRef::from_array_view(([1usize, 3, 2], &coords[..])).map_err(tensor)?.into()),
            (DECODER_INPUTS[1], TensorRef::from_array_view(([1usize, 3], &labels[..])).map_err(tensor)?.into()),
            (
                DECODER_INPUTS[2],
                TensorRef::from_array_view(([1usize, 1, side, side], self.mask_input.as_slice()))
                    .map_err(tensor)?
                    .into(),
            ),
            (DECODER_INPUTS[3], TensorRef::from_array_view(([1usize], &has_mask[..])).map_err(tensor)?.into()),
            (DECODER_INPUTS[4], TensorRef::from_array_view(([2usize], &size[..])).map_err(tensor)?.into()),
        ];
        let path = self.decoder_path.display().to_string();
        let outputs = self.decoder.run(inputs).map_err(|e| format!("SAM decoder ({path}): {e}"))?;
        let (shape, logits) = outputs
            .get(MASKS)
            .ok_or_else(|| format!("SAM decoder ({path}): no output {MASKS}"))?
            .try_extract_tensor::<f32>()
            .map_err(|e| format!("SAM decoder ({path}): {e}"))?;
        if shape[..] != [1, 1, i64::from(height), i64::from(width)] {
            return Err(format!("SAM decoder ({path}): masks has shape {shape:?}, expected [1, 1, {height}, {width}]"));
        }
        Ok(cut(logits, self.config.mask_threshold, pixel_box, width))
    }

    /// [`SamMaskDecoder::mask`] for EfficientSAM's layout: the box corners in image pixels, the
    /// candidate mask with the highest predicted IoU.
    fn efficient_sam_mask(
        &mut self,
        bbox: [f32; 4],
        pixel_box: PixelBox,
        width: u32,
        height: u32,
    ) -> Result<Option<Mask>, String> {
        let coords = [bbox[0], bbox[1], bbox[2], bbox[3]];
        let labels = [2.0f32, 3.0];
        let size = [i64::from(height), i64::from(width)];
        let tensor = |e| self.error("prompt tensor", e);
        let inputs: Vec<(&str, SessionInputValue)> = vec![
            (self.config.embeddings.as_str(), embeddings_input(&self.embedding_shape, &self.embeddings)?),
            (EFFICIENT_INPUTS[0], TensorRef::from_array_view(([1usize, 1, 2, 2], &coords[..])).map_err(tensor)?.into()),
            (EFFICIENT_INPUTS[1], TensorRef::from_array_view(([1usize, 1, 2], &labels[..])).map_err(tensor)?.into()),
            (EFFICIENT_INPUTS[2], TensorRef::from_array_view(([2usize], &size[..])).map_err(tensor)?.into()),
        ];
        let path = self.decoder_path.display().to_string();
        let outputs = self.decoder.run(inputs).map_err(|e| format!("EfficientSAM decoder ({path}): {e}"))?;
        let output = |name: &str| {
            outputs
                .get(name)
                .ok_or_else(|| format!("EfficientSAM decoder ({path}): no output {name}"))?
                .try_extract_tensor::<f32>()
                .map_err(|e| format!("EfficientSAM decoder ({path}): {name}: {e}"))
        };
        let (shape, logits) = output(EFFICIENT_OUTPUTS[0])?;
        let (iou_shape, ious) = output(EFFICIENT_OUTPUTS[1])?;
        let plane = (width * height) as usize;
        let m = match shape[..] {
            [1, 1, m, h, w] if h == i64::from(height) && w == i64::from(width) && m > 0 => m as usize,
            _ => {
                return Err(format!(
                    "EfficientSAM decoder ({path}): output_masks has shape {shape:?}, expected [1, 1, M, {height}, {width}]"
                ));
            }
        };
        if ious.len() != m || logits.len() != m * plane {
            return Err(format!(
                "EfficientSAM decoder ({path}): iou_predictions has shape {iou_shape:?}, expected [1, 1, {m}]"
            ));
        }
        // The best candidate; ties to the first.
        let best = (0..m).fold(0, |best, i| if ious[i] > ious[best] { i } else { best });
        Ok(cut(&logits[best * plane..(best + 1) * plane], self.config.mask_threshold, pixel_box, width))
    }
}

/// The encoder's embeddings (`shape`, `data`) as the decoder's input.
fn embeddings_input<'a>(shape: &[usize], data: &'a [f32]) -> Result<SessionInputValue<'a>, String> {
    TensorRef::from_array_view((shape.to_vec(), data))
        .map(Into::into)
        .map_err(|e| format!("SAM embeddings tensor: {e}"))
}

/// The pixels of `pixel_box` whose logit in the image-sized plane `logits` is above `threshold`;
/// `None` when there are none.
fn cut(logits: &[f32], threshold: f32, pixel_box: PixelBox, width: u32) -> Option<Mask> {
    let (bw, bh) = (pixel_box.x1 - pixel_box.x0, pixel_box.y1 - pixel_box.y0);
    let mut data = vec![0u8; (bw * bh) as usize];
    for y in 0..bh {
        let row = ((pixel_box.y0 + y) * width + pixel_box.x0) as usize;
        for x in 0..bw {
            if logits[row + x as usize] > threshold {
                data[(y * bw + x) as usize] = 1;
            }
        }
    }
    let mask = Mask { x0: pixel_box.x0, y0: pixel_box.y0, width: bw, height: bh, data };
    (mask.area() > 0).then_some(mask)
}

/// The masks of a box detector: SAM's when a mask decoder is set, else segmented from depth.
#[derive(Debug)]
pub struct BoxMasks {
    segmenter: DepthSegmenter,
    sam: Option<SamMaskDecoder>,
    /// The SAM encoder ran on the current frame.
    encoded: bool,
}

impl BoxMasks {
    /// Depth masks with `depth`, or SAM's with `decoder` (section `key`).
    pub fn new(
        runtime: &OnnxRuntime,
        depth: &DepthMaskConfig,
        decoder: Option<&MaskDecoderConfig>,
        key: &str,
    ) -> Result<Self, OnnxError> {
        let sam = match decoder {
            Some(config) => Some(SamMaskDecoder::new(runtime, config, key)?),
            None => None,
        };
        Ok(Self { segmenter: DepthSegmenter::new(depth.clone()), sam, encoded: false })
    }

    /// Whether masks come from a SAM decoder.
    pub fn has_decoder(&self) -> bool {
        self.sam.is_some()
    }

    /// Call before the first box of each frame.
    pub fn begin_frame(&mut self) {
        self.encoded = false;
    }

    /// The mask of the detection box `bbox` (image pixels; `pixel_box` its pixels) in `frame`.
    pub fn mask(&mut self, frame: &Frame, bbox: [f32; 4], pixel_box: PixelBox) -> Result<Option<Mask>, DetectorError> {
        let intr = frame.intrinsics;
        match self.sam.as_mut() {
            Some(sam) => {
                if !self.encoded {
                    sam.set_image(frame).map_err(DetectorError::Backend)?;
                    self.encoded = true;
                }
                sam.mask(bbox, pixel_box, intr.width, intr.height).map_err(DetectorError::Backend)
            }
            None => {
                let has_depth = frame.depth.len() == intr.pixel_count();
                let depth_m = |i: usize| if has_depth { frame.depth_m(i) } else { 0.0 };
                Ok(self.segmenter.segment(&depth_m, intr.width, pixel_box))
            }
        }
    }
}
