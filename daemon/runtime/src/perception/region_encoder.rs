//! A region encoder (`[detector.region_encoder]`): a CLIP image encoder run on each detection's
//! crop, whose L2-normalised embedding becomes the detection's semantic feature. Fusion compares
//! those features (`s^s`, [`crate::fusion`]) and keeps their running mean per node, as
//! ConceptGraphs and the paper do with CLIP crops; without a region encoder a detection carries
//! the feature its detector gives (the open-vocabulary detector's region embeddings, or none:
//! then fusion compares labels).
//!
//! It works with every detector (`yolox`, `open_vocab`, the oracle): the backend wraps each
//! worker's detector ([`WithRegionEncoder`]), so every worker has its own session.
//!
//! # Contract (CLIP image encoder exports)
//!
//! - in `input.name` (`pixel_values`) float32 `[B, 3, H, W]`, `B` 1 or dynamic (one crop per
//!   run either way), `H x W` `input.height x input.width` (224 x 224 for ViT-B/32 and B/16,
//!   336 for L/14-336). Each crop is fitted with `input.resize`, then `(v * scale - mean) / std`
//!   per channel, CLIP's mean `[0.48145466, 0.4578275, 0.40821073]` and std `[0.26862954,
//!   0.26130258, 0.27577711]` on 0..1 values (the defaults). CLIP's own preprocessing scales the
//!   short side and cuts the centre square; the default here is `letterbox` so that the whole
//!   region is seen (a thin crop such as a handle would lose most of itself to a centre cut),
//!   padded with CLIP's mean grey.
//! - out `output` (`image_embeds`) float32 `[B, D]` (or `[D]`): the projected image embedding
//!   (D = 512 for ViT-B, 768 for ViT-L). The daemon normalises it.
//!
//! Exports: Hugging Face's `CLIPVisionModelWithProjection` through `torch.onnx.export` with
//! `input_names=["pixel_values"]`, `output_names=["image_embeds"]` (its `image_embeds` output),
//! or open_clip's `model.encode_image` exported the same way. (`optimum-cli export onnx
//! --task feature-extraction` writes CLIP's joint text + vision model, which needs text inputs
//! too: not this layout.)
//!
//! # Crops
//!
//! The crop is the detection mask's box grown by `padding_px` on each side (ConceptGraphs uses
//! 20 pixels), cut to the image. `background = "keep"` leaves the pixels around the mask as they
//! are (ConceptGraphs' crops); `"grey"` paints the crop's pixels outside the mask with
//! `input.pad_value`, so that only the region itself is encoded. Crops smaller than
//! `min_crop_px` on a side are not encoded (their detection keeps its detector's feature).

use std::path::PathBuf;

use op3dsg_drivers::frame::Frame;
use ort::session::Session;
use serde::{Deserialize, Serialize};

use super::image_input::{ImageInput, Resize, prepare, run_on_image};
use super::{Detection, Detector, DetectorError, Mask};
use crate::embedding::normalise;
use crate::onnx::contract::{self, Dim, FLOAT, TensorSpec};
use crate::onnx::{OnnxError, OnnxRuntime};

/// CLIP's per-channel mean on 0..1 values.
pub const CLIP_MEAN: [f32; 3] = [0.481_454_66, 0.457_827_5, 0.408_210_73];
/// CLIP's per-channel standard deviation on 0..1 values.
pub const CLIP_STD: [f32; 3] = [0.268_629_54, 0.261_302_6, 0.275_777_1];

/// What the crop shows around the mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CropBackground {
    /// The image as it is (ConceptGraphs' crops).
    #[default]
    Keep,
    /// `input.pad_value` outside the mask.
    Grey,
}

/// `[detector.region_encoder]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RegionEncoderConfig {
    /// The image encoder (ONNX). Relative paths in a profile file are relative to that file.
    pub path: PathBuf,
    /// Optional sha256 of `path`, checked at start.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub sha256: Option<String>,
    /// The image input (name, size, resize, normalisation, pad value).
    pub input: ImageInput,
    /// The embedding output's name.
    pub output: String,
    /// Pixels added around the mask's box on each side.
    pub padding_px: u32,
    /// What the crop shows around the mask.
    pub background: CropBackground,
    /// Crops narrower or lower than this (pixels, after padding) are not encoded.
    pub min_crop_px: u32,
    /// ONNX Runtime intra-op threads of the session.
    pub intra_op_threads: usize,
}

impl Default for RegionEncoderConfig {
    fn default() -> Self {
        Self {
            path: PathBuf::from("clip_vitb32_image.onnx"),
            sha256: None,
            input: ImageInput {
                name: "pixel_values".to_owned(),
                width: 224,
                height: 224,
                resize: Resize::Letterbox,
                scale: 1.0 / 255.0,
                mean: CLIP_MEAN,
                std: CLIP_STD,
                // CLIP's mean grey (0.4815 * 255 ≈ 123, about 0 after normalising).
                pad_value: 123.0,
                ..ImageInput::default()
            },
            output: "image_embeds".to_owned(),
            padding_px: 20,
            background: CropBackground::Keep,
            min_crop_px: 4,
            intra_op_threads: 1,
        }
    }
}

impl RegionEncoderConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if self.path.as_os_str().is_empty() {
            return Err(format!("{path}.path: must not be empty"));
        }
        contract::validate_sha256(&format!("{path}.sha256"), self.sha256.as_deref())?;
        self.input.validate(&format!("{path}.input"))?;
        if self.output.trim().is_empty() {
            return Err(format!("{path}.output: must not be empty"));
        }
        if self.padding_px > 1024 {
            return Err(format!("{path}.padding_px: must be at most 1024, got {}", self.padding_px));
        }
        if !(1..=4096).contains(&self.min_crop_px) {
            return Err(format!("{path}.min_crop_px: must be within [1, 4096], got {}", self.min_crop_px));
        }
        if !(1..=64).contains(&self.intra_op_threads) {
            return Err(format!("{path}.intra_op_threads: must be within [1, 64], got {}", self.intra_op_threads));
        }
        Ok(())
    }
}

/// The crop of a detection: image pixels `[x0, x1) x [y0, y1)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Crop {
    /// Left column (inclusive).
    pub x0: u32,
    /// Top row (inclusive).
    pub y0: u32,
    /// Right column (exclusive).
    pub x1: u32,
    /// Bottom row (exclusive).
    pub y1: u32,
}

impl Crop {
    /// The mask's box grown by `padding` on each side, cut to a `width x height` image.
    pub fn around(mask: &Mask, padding: u32, width: u32, height: u32) -> Self {
        Self {
            x0: mask.x0.saturating_sub(padding),
            y0: mask.y0.saturating_sub(padding),
            x1: (mask.x0 + mask.width).saturating_add(padding).min(width),
            y1: (mask.y0 + mask.height).saturating_add(padding).min(height),
        }
    }

    fn width(&self) -> u32 {
        self.x1.saturating_sub(self.x0)
    }

    fn height(&self) -> u32 {
        self.y1.saturating_sub(self.y0)
    }
}

/// One worker's CLIP image encoder session and its buffers.
pub struct RegionEncoder {
    session: Session,
    config: RegionEncoderConfig,
    path: PathBuf,
    /// The current crop, RGB8.
    crop: Vec<u8>,
    /// The crop as the model's input tensor.
    input: Vec<f32>,
}

impl std::fmt::Debug for RegionEncoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RegionEncoder").field("path", &self.path).finish_non_exhaustive()
    }
}

impl RegionEncoder {
    /// Loads `config`'s model (section `key`), checking its sha256 and tensors.
    pub fn new(runtime: &OnnxRuntime, config: &RegionEncoderConfig, key: &str) -> Result<Self, OnnxError> {
        config.validate(key).map_err(OnnxError::InvalidConfig)?;
        let (session, path) = contract::open_user_model(
            runtime,
            &config.path,
            config.sha256.as_deref(),
            "CLIP image encoder",
            (&format!("{key}.path"), &format!("{key}.sha256")),
            config.intra_op_threads,
        )?;
        let image = Some(vec![
            Dim::Any("B"),
            Dim::Is(3),
            Dim::Is(config.input.height.into()),
            Dim::Is(config.input.width.into()),
        ]);
        contract::check(
            &session,
            &path,
            &format!("the CLIP image encoder layout ({key})"),
            &[TensorSpec::new(&config.input.name, &format!("{key}.input.name"), FLOAT, image)],
            &[TensorSpec::new(&config.output, &format!("{key}.output"), FLOAT, None)],
        )?;
        Ok(Self { session, config: config.clone(), path, crop: Vec::new(), input: Vec::new() })
    }

    /// The crop `encode` would use for `mask` in a `width x height` image, if it is large enough.
    pub fn crop_of(&self, mask: &Mask, width: u32, height: u32) -> Option<Crop> {
        let crop = Crop::around(mask, self.config.padding_px, width, height);
        let min = self.config.min_crop_px;
        (crop.width() >= min && crop.height() >= min).then_some(crop)
    }

    /// The L2-normalised embedding of `mask`'s crop of `frame`; `None` when the crop is too small
    /// or the embedding is zero.
    pub fn encode(&mut self, frame: &Frame, mask: &Mask) -> Result<Option<Vec<f32>>, String> {
        let (w, h) = (frame.intrinsics.width, frame.intrinsics.height);
        let Some(crop) = self.crop_of(mask, w, h) else { return Ok(None) };
        let (cw, ch) = (crop.width(), crop.height());
        self.crop.clear();
        self.crop.reserve((cw * ch * 3) as usize);
        let grey = self.config.input.pad_value.round().clamp(0.0, 255.0) as u8;
        for y in crop.y0..crop.y1 {
            let row = ((y * w + crop.x0) * 3) as usize..((y * w + crop.x1) * 3) as usize;
            let pixels = frame.rgb.get(row).ok_or_else(|| {
                format!("frame {}: colour holds {} bytes, fewer than {w}x{h} RGB", frame.seq, frame.rgb.len())
            })?;
            match self.config.background {
                CropBackground::Keep => self.crop.extend_from_slice(pixels),
                CropBackground::Grey => {
                    for (x, px) in (crop.x0..crop.x1).zip(pixels.chunks_exact(3)) {
                        if mask.contains(x, y) {
                            self.crop.extend_from_slice(px);
                        } else {
                            self.crop.extend_from_slice(&[grey; 3]);
                        }
                    }
                }
            }
        }
        let spec = &self.config.input;
        prepare(&self.crop, cw, ch, spec, &mut self.input);
        let output = self.config.output.as_str();
        let mut embedding = Vec::new();
        let shape = run_on_image(
            &mut self.session,
            spec,
            &self.input,
            (output, &mut embedding),
            "CLIP image encoder",
            &self.path,
        )?;
        let path = self.path.display();
        let one_row = match shape[..] {
            [d] | [1, d] => d > 0,
            _ => false,
        };
        if !one_row {
            return Err(format!(
                "CLIP image encoder ({path}): output \"{}\" has shape {shape:?}, expected [1, D] for one crop",
                self.config.output
            ));
        }
        if embedding.iter().any(|v| !v.is_finite()) {
            return Err(format!("CLIP image encoder ({path}): output \"{}\" is not finite", self.config.output));
        }
        if embedding.iter().all(|v| *v == 0.0) {
            return Ok(None);
        }
        normalise(&mut embedding);
        Ok(Some(embedding))
    }
}

/// A detector whose detections get their semantic features from a [`RegionEncoder`].
pub struct WithRegionEncoder {
    inner: Box<dyn Detector>,
    encoder: RegionEncoder,
}

impl std::fmt::Debug for WithRegionEncoder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("WithRegionEncoder")
            .field("detector", &self.inner.name())
            .field("encoder", &self.encoder)
            .finish()
    }
}

impl WithRegionEncoder {
    /// `inner`'s detections, each encoded by `encoder`.
    pub fn new(inner: Box<dyn Detector>, encoder: RegionEncoder) -> Self {
        Self { inner, encoder }
    }
}

impl Detector for WithRegionEncoder {
    fn detect(&mut self, frame: &Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError> {
        self.inner.detect(frame, out)?;
        for detection in out.iter_mut() {
            if let Some(feature) = self.encoder.encode(frame, &detection.mask).map_err(DetectorError::Backend)? {
                detection.semantic_feature = Some(feature);
            }
        }
        Ok(())
    }

    fn name(&self) -> &str {
        self.inner.name()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn mask(x0: u32, y0: u32, width: u32, height: u32) -> Mask {
        Mask { x0, y0, width, height, data: vec![1; (width * height) as usize] }
    }

    #[test]
    fn crops_grow_by_the_padding_and_stay_in_the_image() {
        let m = mask(5, 40, 10, 8);
        assert_eq!(Crop::around(&m, 20, 64, 48), Crop { x0: 0, y0: 20, x1: 35, y1: 48 });
        assert_eq!(Crop::around(&m, 0, 64, 48), Crop { x0: 5, y0: 40, x1: 15, y1: 48 });
    }

    #[test]
    fn bad_settings_are_refused_naming_the_field() {
        let check = |c: RegionEncoderConfig| c.validate("detector.region_encoder").unwrap_err();
        let base = RegionEncoderConfig::default();
        assert!(
            check(RegionEncoderConfig { path: PathBuf::new(), ..base.clone() })
                .starts_with("detector.region_encoder.path")
        );
        assert!(check(RegionEncoderConfig { output: " ".into(), ..base.clone() }).contains(".output"));
        assert!(check(RegionEncoderConfig { min_crop_px: 0, ..base.clone() }).contains(".min_crop_px"));
        assert!(check(RegionEncoderConfig { intra_op_threads: 0, ..base.clone() }).contains(".intra_op_threads"));
        assert!(check(RegionEncoderConfig { sha256: Some("abc".into()), ..base }).contains(".sha256"));
    }
}
