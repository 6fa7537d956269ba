//! Masks from depth: when a detector gives only a box, segment the object inside the box from
//! the depth image, so fusion gets a real mask without a segmentation network.
//!
//! # Method
//!
//! 1. **Seed region.** The central part of the box (a `seed_fraction` of its width and height,
//!    centred) is where the object most likely is: a detector's box is tight around the object,
//!    and the background shows mostly at its borders.
//! 2. **Dominant surface depth.** The valid depths of the seed region (non-zero, within
//!    `[min_depth_m, max_depth_m]`) go into a histogram of `bin_m`-wide bins; the fullest bin
//!    (ties: the nearer one, objects stand in front of what they occlude) and its two neighbours
//!    give the dominant depth as the median of the depths in those three bins. Too few valid
//!    depths (`min_seed_pixels`) means no mask (the detection is dropped by the caller).
//! 3. **Depth band.** A pixel of the box can belong to the object only if its depth is within
//!    `band_m + band_fraction * d` of the dominant depth `d` (objects have depth extent, and
//!    depth noise grows with distance).
//! 4. **Connected to the seed, no depth edges.** A 4-neighbour flood fill starts from the seed
//!    pixels that are in the band (those near the dominant depth, within `edge_m`) and crosses from
//!    a pixel to a neighbour only when the neighbour is in the band and the two depths differ by
//!    less than `edge_m + edge_fraction * d` (a depth edge stops it, so a wall behind the object
//!    at the same distance as part of it does not leak in through a silhouette boundary).
//!    Pixels without depth (holes) are not crossed and not included.
//!
//! Cost is linear in the box area; the scratch buffers are reused between calls.

use serde::{Deserialize, Serialize};

use super::Mask;

/// `[detector.yolox.depth_mask]`: knobs of the depth segmentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DepthMaskConfig {
    /// Seed region: this fraction of the box's width and height, centred. (0, 1].
    pub seed_fraction: f32,
    /// Histogram bin width for the dominant depth, metres.
    pub bin_m: f32,
    /// Depth band half-width: fixed part, metres.
    pub band_m: f32,
    /// Depth band half-width: part proportional to the dominant depth. Unitless.
    pub band_fraction: f32,
    /// Largest depth step between 4-neighbours the fill crosses: fixed part, metres.
    pub edge_m: f32,
    /// Largest depth step: part proportional to the dominant depth. Unitless.
    pub edge_fraction: f32,
    /// Depths outside `[min_depth_m, max_depth_m]` count as holes, metres.
    pub min_depth_m: f32,
    /// See `min_depth_m`, metres.
    pub max_depth_m: f32,
    /// Fewest valid depths in the seed region for a mask. At least 1.
    pub min_seed_pixels: u32,
    /// Fewest pixels in the final mask; smaller masks are no mask.
    pub min_mask_pixels: u32,
}

impl Default for DepthMaskConfig {
    fn default() -> Self {
        Self {
            seed_fraction: 0.3,
            bin_m: 0.05,
            band_m: 0.15,
            band_fraction: 0.1,
            edge_m: 0.03,
            edge_fraction: 0.02,
            min_depth_m: 0.1,
            max_depth_m: 10.0,
            min_seed_pixels: 8,
            min_mask_pixels: 16,
        }
    }
}

impl DepthMaskConfig {
    /// Range checks; errors are `path.field: message`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(self.seed_fraction > 0.0 && self.seed_fraction <= 1.0) {
            return Err(format!("{path}.seed_fraction: must be within (0, 1], got {}", self.seed_fraction));
        }
        for (field, v) in [("bin_m", self.bin_m), ("band_m", self.band_m), ("edge_m", self.edge_m)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{path}.{field}: must be > 0, got {v}"));
            }
        }
        for (field, v) in [("band_fraction", self.band_fraction), ("edge_fraction", self.edge_fraction)] {
            if !(v.is_finite() && (0.0..=1.0).contains(&v)) {
                return Err(format!("{path}.{field}: must be within [0, 1], got {v}"));
            }
        }
        if !(self.min_depth_m >= 0.0 && self.max_depth_m > self.min_depth_m && self.max_depth_m.is_finite()) {
            return Err(format!(
                "{path}.max_depth_m: must be > min_depth_m ({}) and finite, got {}",
                self.min_depth_m, self.max_depth_m
            ));
        }
        if self.min_seed_pixels == 0 {
            return Err(format!("{path}.min_seed_pixels: must be at least 1"));
        }
        Ok(())
    }
}

/// A pixel box, `[x0, x1) x [y0, y1)`, inside the image.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PixelBox {
    /// Left column (inclusive).
    pub x0: u32,
    /// Top row (inclusive).
    pub y0: u32,
    /// Right column (exclusive).
    pub x1: u32,
    /// Bottom row (exclusive).
    pub y1: u32,
}

impl PixelBox {
    /// The pixels covered by a float box `[x0, y0, x1, y1]` (image pixels, continuous
    /// coordinates), clipped to a `width x height` image; `None` when empty.
    pub fn from_float(b: [f32; 4], width: u32, height: u32) -> Option<Self> {
        let clamp = |v: f32, hi: u32| (v.max(0.0).min(hi as f32)) as u32;
        let x0 = clamp(b[0].floor(), width);
        let y0 = clamp(b[1].floor(), height);
        let x1 = clamp(b[2].ceil(), width);
        let y1 = clamp(b[3].ceil(), height);
        (x1 > x0 && y1 > y0).then_some(Self { x0, y0, x1, y1 })
    }

    fn width(&self) -> u32 {
        self.x1 - self.x0
    }

    fn height(&self) -> u32 {
        self.y1 - self.y0
    }
}

/// Segments objects in boxes from depth; keeps its scratch buffers between calls.
#[derive(Debug, Clone, Default)]
pub struct DepthSegmenter {
    config: DepthMaskConfig,
    depths: Vec<f32>,
    histogram: Vec<u32>,
    stack: Vec<u32>,
}

impl DepthSegmenter {
    /// A segmenter with these knobs (validated by the profile).
    pub fn new(config: DepthMaskConfig) -> Self {
        Self { config, ..Self::default() }
    }

    /// The knobs.
    pub fn config(&self) -> &DepthMaskConfig {
        &self.config
    }

    /// The dominant depth of the seed region of `bbox` (metres), or `None` with too few valid
    /// depths. `depth_m(i)` gives the depth of image pixel `i` (0 or non-finite = none).
    pub fn dominant_depth(&mut self, depth_m: &dyn Fn(usize) -> f32, width: u32, bbox: PixelBox) -> Option<f32> {
        let c = &self.config;
        let sw = ((bbox.width() as f32 * c.seed_fraction).round() as u32).clamp(1, bbox.width());
        let sh = ((bbox.height() as f32 * c.seed_fraction).round() as u32).clamp(1, bbox.height());
        let sx0 = bbox.x0 + (bbox.width() - sw) / 2;
        let sy0 = bbox.y0 + (bbox.height() - sh) / 2;
        self.depths.clear();
        for y in sy0..sy0 + sh {
            for x in sx0..sx0 + sw {
                let d = depth_m((y * width + x) as usize);
                if d.is_finite() && d >= c.min_depth_m && d <= c.max_depth_m && d > 0.0 {
                    self.depths.push(d);
                }
            }
        }
        if self.depths.len() < c.min_seed_pixels as usize {
            return None;
        }
        let bins = ((c.max_depth_m - c.min_depth_m) / c.bin_m).ceil() as usize + 1;
        self.histogram.clear();
        self.histogram.resize(bins, 0);
        let bin_of = |d: f32| (((d - c.min_depth_m) / c.bin_m) as usize).min(bins - 1);
        for &d in &self.depths {
            self.histogram[bin_of(d)] += 1;
        }
        // Fullest bin; the first (nearest) on ties.
        let mut best = 0;
        for (i, &n) in self.histogram.iter().enumerate() {
            if n > self.histogram[best] {
                best = i;
            }
        }
        let lo = best.saturating_sub(1);
        let hi = (best + 1).min(bins - 1);
        self.depths.retain(|&d| (lo..=hi).contains(&bin_of(d)));
        self.depths.sort_unstable_by(f32::total_cmp);
        Some(self.depths[self.depths.len() / 2])
    }

    /// The object's mask inside `bbox`: pixels in the depth band of the dominant depth,
    /// connected to the seed region without crossing depth edges (module docs). `None` when the
    /// box has too little valid depth or the mask is smaller than `min_mask_pixels`.
    pub fn segment(&mut self, depth_m: &dyn Fn(usize) -> f32, width: u32, bbox: PixelBox) -> Option<Mask> {
        let dominant = self.dominant_depth(depth_m, width, bbox)?;
        let c = self.config.clone();
        let band = c.band_m + c.band_fraction * dominant;
        let edge = c.edge_m + c.edge_fraction * dominant;
        let (bw, bh) = (bbox.width(), bbox.height());
        let mut data = vec![0u8; (bw * bh) as usize];
        let local_depth = |lx: u32, ly: u32| {
            let d = depth_m(((bbox.y0 + ly) * width + bbox.x0 + lx) as usize);
            if d.is_finite() && d > 0.0 && d >= c.min_depth_m && d <= c.max_depth_m { d } else { f32::NAN }
        };
        // Seeds: seed-region pixels near the dominant depth.
        let sw = ((bw as f32 * c.seed_fraction).round() as u32).clamp(1, bw);
        let sh = ((bh as f32 * c.seed_fraction).round() as u32).clamp(1, bh);
        let sx0 = (bw - sw) / 2;
        let sy0 = (bh - sh) / 2;
        self.stack.clear();
        for ly in sy0..sy0 + sh {
            for lx in sx0..sx0 + sw {
                let d = local_depth(lx, ly);
                if (d - dominant).abs() <= edge.max(c.bin_m) {
                    let i = ly * bw + lx;
                    data[i as usize] = 1;
                    self.stack.push(i);
                }
            }
        }
        let mut area = self.stack.len();
        while let Some(i) = self.stack.pop() {
            let (lx, ly) = (i % bw, i / bw);
            let d = local_depth(lx, ly);
            let neighbours = [
                (lx > 0).then(|| (lx - 1, ly)),
                (lx + 1 < bw).then(|| (lx + 1, ly)),
                (ly > 0).then(|| (lx, ly - 1)),
                (ly + 1 < bh).then(|| (lx, ly + 1)),
            ];
            for (nx, ny) in neighbours.into_iter().flatten() {
                let j = ny * bw + nx;
                if data[j as usize] != 0 {
                    continue;
                }
                let dn = local_depth(nx, ny);
                // NaN (holes) fails both comparisons.
                if (dn - dominant).abs() <= band && (dn - d).abs() < edge {
                    data[j as usize] = 1;
                    area += 1;
                    self.stack.push(j);
                }
            }
        }
        if area < c.min_mask_pixels as usize {
            return None;
        }
        Some(Mask { x0: bbox.x0, y0: bbox.y0, width: bw, height: bh, data })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const W: u32 = 64;
    const H: u32 = 48;

    fn image(f: impl Fn(u32, u32) -> f32) -> Vec<f32> {
        (0..H).flat_map(|y| (0..W).map(move |x| (x, y))).map(|(x, y)| f(x, y)).collect()
    }

    fn segment(depth: &[f32], bbox: PixelBox, config: DepthMaskConfig) -> Option<Mask> {
        let lookup = |i: usize| depth[i];
        DepthSegmenter::new(config).segment(&lookup, W, bbox)
    }

    fn full_box() -> PixelBox {
        PixelBox { x0: 10, y0: 8, x1: 50, y1: 40 }
    }

    /// An object (a 20 x 16 block at 1.5 m) in front of a wall at 3 m, boxed loosely.
    #[test]
    fn object_in_front_of_a_wall_is_cut_out() {
        let inside = |x: u32, y: u32| (20..40).contains(&x) && (16..32).contains(&y);
        let depth = image(|x, y| if inside(x, y) { 1.5 } else { 3.0 });
        let mask = segment(&depth, full_box(), DepthMaskConfig::default()).expect("a mask");
        assert_eq!((mask.x0, mask.y0, mask.width, mask.height), (10, 8, 40, 32));
        assert_eq!(mask.area(), 20 * 16);
        for y in 0..H {
            for x in 0..W {
                assert_eq!(mask.contains(x, y), inside(x, y), "pixel ({x}, {y})");
            }
        }
    }

    /// A slanted object surface (depth grows smoothly over it) is kept whole: the band is wide
    /// enough and there is no edge between neighbours.
    #[test]
    fn a_slanted_surface_is_kept_whole() {
        let inside = |x: u32, y: u32| (20..40).contains(&x) && (16..32).contains(&y);
        let depth = image(|x, y| if inside(x, y) { 1.4 + 0.01 * (x - 20) as f32 } else { 3.0 });
        let mask = segment(&depth, full_box(), DepthMaskConfig::default()).unwrap();
        assert_eq!(mask.area(), 20 * 16);
    }

    /// Two depth layers in the box: the one covering the centre wins, the other (nearer but off
    /// centre, at a depth step bigger than the band) is excluded.
    #[test]
    fn two_layers_keep_the_central_one() {
        let depth = image(|x, y| {
            if (10..18).contains(&x) && (8..40).contains(&y) {
                0.8 // an occluder at the left edge of the box
            } else if (18..50).contains(&x) && (8..40).contains(&y) {
                2.0
            } else {
                4.0
            }
        });
        let mask = segment(&depth, full_box(), DepthMaskConfig::default()).unwrap();
        assert_eq!(mask.area(), 32 * 32);
        assert!(!mask.contains(12, 20));
        assert!(mask.contains(30, 20));
    }

    /// A surface at the dominant depth that is not connected to the seed (separated by a gap of
    /// background) stays out.
    #[test]
    fn disconnected_surfaces_at_the_same_depth_stay_out() {
        let depth = image(|x, y| {
            let object = (24..36).contains(&x) && (14..34).contains(&y);
            let other = (42..48).contains(&x) && (10..38).contains(&y);
            if object || other { 1.0 } else { 2.5 }
        });
        let mask = segment(&depth, full_box(), DepthMaskConfig::default()).unwrap();
        assert_eq!(mask.area(), 12 * 20);
        assert!(!mask.contains(44, 20));
    }

    /// Holes (no depth) are not in the mask and do not stop the fill around them; a box that is
    /// all holes has no mask.
    #[test]
    fn holes_are_excluded_and_an_empty_box_has_no_mask() {
        let inside = |x: u32, y: u32| (20..40).contains(&x) && (16..32).contains(&y);
        let hole = |x: u32, y: u32| (28..32).contains(&x) && (22..26).contains(&y);
        let depth = image(|x, y| {
            if hole(x, y) {
                0.0
            } else if inside(x, y) {
                1.5
            } else {
                3.0
            }
        });
        let mask = segment(&depth, full_box(), DepthMaskConfig::default()).unwrap();
        assert_eq!(mask.area(), 20 * 16 - 16);
        assert!(!mask.contains(29, 23));
        assert!(mask.contains(21, 17));

        let nothing = image(|_, _| 0.0);
        assert!(segment(&nothing, full_box(), DepthMaskConfig::default()).is_none());
    }

    /// A depth edge inside the band stops the fill: a step of 10 cm (within the band, above the
    /// edge threshold) separates the object's top from a shelf behind it.
    #[test]
    fn a_depth_edge_within_the_band_stops_the_fill() {
        let depth = image(|x, y| {
            if (20..40).contains(&x) && (20..36).contains(&y) {
                1.5
            } else if (20..40).contains(&x) && (8..20).contains(&y) {
                1.6
            } else {
                3.0
            }
        });
        let mask = segment(&depth, PixelBox { x0: 10, y0: 14, x1: 50, y1: 40 }, DepthMaskConfig::default()).unwrap();
        assert!(mask.contains(30, 25));
        assert!(!mask.contains(30, 16), "the step is an edge");
        assert_eq!(mask.area(), 20 * 16);
    }

    #[test]
    fn float_boxes_are_clipped_to_the_image() {
        assert_eq!(
            PixelBox::from_float([-5.2, 3.7, 70.0, 20.1], W, H),
            Some(PixelBox { x0: 0, y0: 3, x1: 64, y1: 21 })
        );
        assert_eq!(PixelBox::from_float([65.0, 3.0, 70.0, 20.0], W, H), None);
    }

    #[test]
    fn validation_names_the_field() {
        let bad = DepthMaskConfig { seed_fraction: 0.0, ..DepthMaskConfig::default() };
        assert!(
            bad.validate("detector.yolox.depth_mask")
                .unwrap_err()
                .starts_with("detector.yolox.depth_mask.seed_fraction")
        );
        DepthMaskConfig::default().validate("x").unwrap();
    }
}
