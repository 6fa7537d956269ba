//! A model's image input, as a profile states it: tensor name, size, colour order, resize
//! (letterbox or stretch), scale, per-channel mean and standard deviation, pad value. One
//! preprocessing routine ([`prepare`]) serves every image model, YOLOX included.
//!
//! Resampling is bilinear with half-pixel centres and the result rounded to integers, like
//! OpenCV's `INTER_LINEAR` on 8-bit images, so a model exported with OpenCV preprocessing sees
//! the same pixels. Then each channel becomes `(v * scale - mean) / std`, written as planar
//! NCHW float32 `[1, 3, height, width]` in the stated colour order. Letterbox: scaled by
//! `r = min(height / h, width / w)` to `(floor(w r), floor(h r))`, placed at the top-left, the
//! rest `pad_value` (an 8-bit value, normalised like the pixels).

use serde::{Deserialize, Serialize};

/// Channel order of the network input.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ColourOrder {
    /// Red, green, blue planes.
    #[default]
    Rgb,
    /// Blue, green, red planes (OpenCV-trained models such as YOLOX).
    Bgr,
}

/// How the frame is fitted to the input size.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Resize {
    /// Keep the aspect ratio, top-left, pad the rest.
    #[default]
    Letterbox,
    /// Scale each axis to fill the input.
    Stretch,
}

/// `[...input]` of an image model.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ImageInput {
    /// Input tensor name.
    pub name: String,
    /// Input width, pixels.
    pub width: u32,
    /// Input height, pixels.
    pub height: u32,
    /// Channel order.
    pub colour_order: ColourOrder,
    /// Letterbox or stretch.
    pub resize: Resize,
    /// Multiplies 8-bit values first (1/255 for 0..1 models, 1 for 0..255 models).
    pub scale: f32,
    /// Subtracted per channel (in the input's colour order) after scaling.
    pub mean: [f32; 3],
    /// Divides per channel after the mean.
    pub std: [f32; 3],
    /// Letterbox padding, an 8-bit value normalised like the pixels.
    pub pad_value: f32,
}

impl Default for ImageInput {
    fn default() -> Self {
        Self {
            name: "images".to_owned(),
            width: 640,
            height: 640,
            colour_order: ColourOrder::Rgb,
            resize: Resize::Letterbox,
            scale: 1.0 / 255.0,
            mean: [0.0; 3],
            std: [1.0; 3],
            pad_value: 114.0,
        }
    }
}

impl ImageInput {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if self.name.trim().is_empty() {
            return Err(format!("{path}.name: must not be empty"));
        }
        for (field, v) in [("width", self.width), ("height", self.height)] {
            if !(8..=4096).contains(&v) {
                return Err(format!("{path}.{field}: must be within [8, 4096], got {v}"));
            }
        }
        if !(self.scale.is_finite() && self.scale > 0.0) {
            return Err(format!("{path}.scale: must be positive, got {}", self.scale));
        }
        if let Some(s) = self.std.iter().find(|s| !(s.is_finite() && **s > 0.0)) {
            return Err(format!("{path}.std: every entry must be positive, got {s}"));
        }
        if !self.mean.iter().all(|m| m.is_finite()) {
            return Err(format!("{path}.mean: must be finite"));
        }
        if !(0.0..=255.0).contains(&self.pad_value) {
            return Err(format!("{path}.pad_value: must be within [0, 255], got {}", self.pad_value));
        }
        Ok(())
    }
}

/// Where the frame landed in the input: network pixels per image pixel along x and y (equal
/// for a letterbox). Image coordinates are network coordinates divided by these.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Placement {
    /// Network pixels per image pixel, x.
    pub sx: f32,
    /// Network pixels per image pixel, y.
    pub sy: f32,
}

/// Writes the RGB8 `width x height` image into `out` as `spec`'s input tensor (see the module
/// docs) and returns where it landed.
pub fn prepare(rgb: &[u8], width: u32, height: u32, spec: &ImageInput, out: &mut Vec<f32>) -> Placement {
    let (iw, ih) = (spec.width as usize, spec.height as usize);
    let plane = iw * ih;
    let normalise = |v: f32, plane_index: usize| (v * spec.scale - spec.mean[plane_index]) / spec.std[plane_index];
    out.clear();
    out.resize(3 * plane, 0.0);
    for p in 0..3 {
        out[p * plane..(p + 1) * plane].fill(normalise(spec.pad_value, p));
    }
    let (new_w, new_h, placement) = match spec.resize {
        Resize::Letterbox => {
            let r = (spec.height as f32 / height as f32).min(spec.width as f32 / width as f32);
            let new_w = ((width as f32 * r) as usize).clamp(1, iw);
            let new_h = ((height as f32 * r) as usize).clamp(1, ih);
            (new_w, new_h, Placement { sx: r, sy: r })
        }
        Resize::Stretch => {
            (iw, ih, Placement { sx: spec.width as f32 / width as f32, sy: spec.height as f32 / height as f32 })
        }
    };
    let (w, h) = (width as usize, height as usize);
    let sx_scale = width as f32 / new_w as f32;
    let sy_scale = height as f32 / new_h as f32;
    // Horizontal sample positions and weights, computed once per column.
    let cols: Vec<(usize, usize, f32)> = (0..new_w)
        .map(|dx| {
            let sx = ((dx as f32 + 0.5) * sx_scale - 0.5).max(0.0);
            let x0 = (sx.floor() as usize).min(w - 1);
            let fx = sx - x0 as f32;
            (x0, (x0 + 1).min(w - 1), fx)
        })
        .collect();
    // Image channel c (RGB) goes to this plane.
    let plane_of = |c: usize| match spec.colour_order {
        ColourOrder::Rgb => c,
        ColourOrder::Bgr => 2 - c,
    };
    for dy in 0..new_h {
        let sy = ((dy as f32 + 0.5) * sy_scale - 0.5).max(0.0);
        let y0 = (sy.floor() as usize).min(h - 1);
        let fy = sy - y0 as f32;
        let y1 = (y0 + 1).min(h - 1);
        let row0 = &rgb[y0 * w * 3..(y0 + 1) * w * 3];
        let row1 = &rgb[y1 * w * 3..(y1 + 1) * w * 3];
        for (dx, &(x0, x1, fx)) in cols.iter().enumerate() {
            for c in 0..3 {
                let p00 = f32::from(row0[x0 * 3 + c]);
                let p01 = f32::from(row0[x1 * 3 + c]);
                let p10 = f32::from(row1[x0 * 3 + c]);
                let p11 = f32::from(row1[x1 * 3 + c]);
                let top = p00 + (p01 - p00) * fx;
                let bottom = p10 + (p11 - p10) * fx;
                let v = (top + (bottom - top) * fy).round();
                let p = plane_of(c);
                out[p * plane + dy * iw + dx] = normalise(v, p);
            }
        }
    }
    placement
}

/// Runs `session` on an image prepared by [`prepare`] (`input`, tensor `spec.name` of shape
/// `[1, 3, spec.height, spec.width]`), puts the values of its float output `output` into
/// `values` (reused from frame to frame) and returns that output's shape; errors name `what`
/// and the model's `path`.
pub fn run_on_image(
    session: &mut ort::session::Session,
    spec: &ImageInput,
    input: &[f32],
    (output, values): (&str, &mut Vec<f32>),
    what: &str,
    path: &std::path::Path,
) -> Result<Vec<i64>, String> {
    let path = path.display();
    let image = ort::value::TensorRef::from_array_view(([1usize, 3, spec.height as usize, spec.width as usize], input))
        .map_err(|e| format!("{what} ({path}): input tensor: {e}"))?;
    let outputs =
        session.run(ort::inputs![spec.name.as_str() => image]).map_err(|e| format!("{what} ({path}): {e}"))?;
    let (shape, data) = outputs
        .get(output)
        .ok_or_else(|| format!("{what} ({path}): no output \"{output}\""))?
        .try_extract_tensor::<f32>()
        .map_err(|e| format!("{what} ({path}): output \"{output}\": {e}"))?;
    values.clear();
    values.extend_from_slice(data);
    Ok(shape.to_vec())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stretch_rgb_with_mean_and_std() {
        // 2x1 image, red then blue, stretched to 4x2, 0..1 with ImageNet-like normalisation.
        let rgb = [255u8, 0, 0, 0, 0, 255];
        let spec = ImageInput {
            width: 4,
            height: 2,
            resize: Resize::Stretch,
            mean: [0.5, 0.5, 0.5],
            std: [0.5, 0.5, 0.5],
            ..ImageInput::default()
        };
        let mut out = Vec::new();
        let placement = prepare(&rgb, 2, 1, &spec, &mut out);
        assert_eq!(placement, Placement { sx: 2.0, sy: 2.0 });
        assert_eq!(out.len(), 3 * 8);
        // Red plane, first row: 255, 191 (0.25 of the way), 64, 0 → (v/255 - 0.5)/0.5.
        let expect = |v: f32| (v / 255.0 - 0.5) / 0.5;
        assert_eq!(&out[0..4], &[expect(255.0), expect(191.0), expect(64.0), expect(0.0)]);
        // Blue plane (index 2 in RGB order) mirrors it.
        assert_eq!(&out[16..20], &[expect(0.0), expect(64.0), expect(191.0), expect(255.0)]);
        // Second row equals the first (one source row).
        assert_eq!(out[4..8], out[0..4]);
    }

    #[test]
    fn validation_names_the_field() {
        let spec = ImageInput { std: [1.0, 0.0, 1.0], ..ImageInput::default() };
        assert_eq!(spec.validate("m.input").unwrap_err(), "m.input.std: every entry must be positive, got 0");
        let spec = ImageInput { width: 2, ..ImageInput::default() };
        assert!(spec.validate("m.input").unwrap_err().starts_with("m.input.width"));
    }
}
