//! Depth aligned to colour from the streams' calibration (`source.realsense.align = "op3dsg"`):
//! the same result as librealsense's align block, computed with rays made once at start.
//!
//! For each depth pixel `(x, y)` with a reading, the two corners of its footprint,
//! `(x - 0.5, y - 0.5)` and `(x + 0.5, y + 0.5)`, are deprojected with the depth stream's
//! intrinsics at the pixel's depth, moved into the colour camera by the depth → colour
//! extrinsics and projected with the colour intrinsics. Each corner lands on colour pixel
//! `round(p + 0.5)` (ties to even), as in librealsense's align. Every colour pixel of the
//! rectangle between the two corners gets the depth pixel's raw value, the nearest (smallest
//! non-zero) value winning where several land (a z-buffer: a near object hides what is behind
//! it). Colour pixels that no depth pixel reaches stay 0 (no depth), as do those whose depth
//! pixel had none. The value written is the depth sensor's own reading (its `z`, in depth
//! units), not the distance along the colour camera's axis: librealsense does the same.
//!
//! When the depth stream has at least as many pixels per degree as the colour stream (in both
//! directions, fields of view as `rs2_fov` computes them), only the top-left corner is mapped and
//! each depth pixel fills that one colour pixel, again as librealsense decides; the Stretch's
//! 848x480 depth to 1280x720 colour maps rectangles.
//!
//! **What is precomputed** ([`DepthToColour::new`], once per stream start): the ray through
//! each corner, undistorted and rotated into the colour camera (`R * (x_n, y_n, 1)`; for a
//! rectilinear depth lens as a table per corner column plus one per corner row, a few KiB), so
//! a frame costs per corner a few multiply-adds, the division and the projection, vectorised
//! over chunks of 128 depth pixels before the z-buffer writes. No buffer is allocated
//! per frame: [`DepthToColour::align`] writes into the pooled frame's depth buffer, rotating on the
//! way (align first, then rotate, in one pass: the z-buffer works on the rotated index of the
//! same colour pixel). The per-frame loop is compiled twice, for baseline x86-64 and for AVX2
//! (chosen once at run time from the CPU; no FMA, which would round differently from
//! librealsense). Where the colour stream has at least 1.25 times the depth's pixels per degree
//! (the D435i's 848x480 depth to 848x480 or 1280x720 colour) rectangles are written as fixed
//! blocks, without a branch on each rectangle's size: 3 or 4 lines of 4 values along colour y,
//! planned for 128 depth pixels at a time. Turned 90° or 270° (the Stretch's mount) colour y runs
//! along the output's rows; unturned and 180° frames are aligned turned 90° into a buffer kept
//! from frame to frame and turned the rest of the way. Below that ratio, with a loop sized per
//! pixel.
//!
//! **Lens models**, as librealsense's align block (its SSE build, what the PyPI library and
//! Intel's x86 packages run) applies them: depth rays through the inverse Brown-Conrady formula
//! when the depth stream has that model; projection through the modified Brown-Conrady formula
//! when the colour stream has that model (the tangential terms as `rs2_project_point_to_pixel`
//! writes them; librealsense's SSE align uses the x term for y, so the two differ where those
//! coefficients are not zero); the coefficients of other models are not applied (nor are they
//! by librealsense's align): [`DepthToColour::ignored_coefficients`] says which.
//!
//! ```
//! use op3dsg_realsense::align::{DepthToColour, Extrinsics, Lens};
//! use op3dsg_realsense::rotate::{Rotation, SourceLayout};
//!
//! let lens = Lens::pinhole(4, 2, 2.0, 2.0, 1.5, 0.5);
//! let mut align = DepthToColour::new(lens, lens, Extrinsics::IDENTITY, 0.001).unwrap();
//! let depth: Vec<u8> = [1000u16, 0, 1200, 1300, 900, 950, 0, 1000].iter().flat_map(|d| d.to_le_bytes()).collect();
//! let mut aligned = vec![0u16; 8];
//! align.align(&depth, SourceLayout { width: 4, height: 2, stride_bytes: 8 }, Rotation::None, &mut aligned).unwrap();
//! assert_eq!(aligned, [1000, 0, 1200, 1300, 900, 950, 0, 1000]); // same camera: unchanged
//! ```

use crate::rotate::{CopyError, Rotation, SourceLayout};

/// A stream's lens model, as librealsense names it (`rs2_distortion`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Distortion {
    /// Rectilinear.
    None,
    /// Brown-Conrady with tangential terms applied to radially distorted points (projection).
    ModifiedBrownConrady,
    /// Coefficients that undistort (deprojection).
    InverseBrownConrady,
    /// Brown-Conrady.
    BrownConrady,
    /// Any other model librealsense knows (F-theta, Kannala-Brandt): `rs2_distortion` value.
    Other(i32),
}

/// A stream's intrinsics with its lens model (`rs2_intrinsics`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lens {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub ppx: f32,
    /// Principal point y, pixels.
    pub ppy: f32,
    /// Lens model.
    pub model: Distortion,
    /// The model's coefficients (k1, k2, p1, p2, k3).
    pub coeffs: [f32; 5],
}

impl Lens {
    /// A rectilinear lens.
    pub fn pinhole(width: u32, height: u32, fx: f32, fy: f32, ppx: f32, ppy: f32) -> Self {
        Self { width, height, fx, fy, ppx, ppy, model: Distortion::None, coeffs: [0.0; 5] }
    }

    /// Horizontal and vertical field of view in degrees, as librealsense's `rs2_fov`.
    pub fn fov_deg(&self) -> [f32; 2] {
        let (w, h) = (self.width as f32, self.height as f32);
        let x = (self.ppx + 0.5).atan2(self.fx) + (w - (self.ppx + 0.5)).atan2(self.fx);
        let y = (self.ppy + 0.5).atan2(self.fy) + (h - (self.ppy + 0.5)).atan2(self.fy);
        [x.to_degrees(), y.to_degrees()]
    }

    fn has_coefficients(&self) -> bool {
        self.coeffs.iter().any(|c| *c != 0.0)
    }

    fn check(&self, stream: &'static str) -> Result<(), AlignError> {
        let bad = |field: &'static str, value: f32| AlignError::Calibration { stream, field, value };
        // (Output indices are i32 in the projection.)
        if self.width == 0 || self.height == 0 || u64::from(self.width) * u64::from(self.height) > 1 << 30 {
            return Err(bad("size", self.width.min(self.height) as f32));
        }
        for (field, value) in [("fx", self.fx), ("fy", self.fy)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(bad(field, value));
            }
        }
        for (field, value) in [("ppx", self.ppx), ("ppy", self.ppy)] {
            if !value.is_finite() {
                return Err(bad(field, value));
            }
        }
        if let Some(c) = self.coeffs.iter().find(|c| !c.is_finite()) {
            return Err(bad("coeffs", *c));
        }
        Ok(())
    }
}

/// The depth → colour extrinsics (`rs2_extrinsics`): `p_colour = R * p_depth + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Extrinsics {
    /// `R`, column-major as librealsense stores it.
    pub rotation: [f32; 9],
    /// `t`, metres.
    pub translation_m: [f32; 3],
}

impl Extrinsics {
    /// The same camera.
    pub const IDENTITY: Self =
        Self { rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], translation_m: [0.0; 3] };

    fn apply_rotation(&self, p: [f64; 3]) -> [f64; 3] {
        let r = self.rotation.map(f64::from);
        [
            r[0] * p[0] + r[3] * p[1] + r[6] * p[2],
            r[1] * p[0] + r[4] * p[1] + r[7] * p[2],
            r[2] * p[0] + r[5] * p[1] + r[8] * p[2],
        ]
    }
}

/// Calibration that cannot align.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignError {
    /// A value of a stream's intrinsics is out of range.
    #[error("{stream} intrinsics: {field} = {value} (need a finite value, focal lengths and sizes above 0)")]
    Calibration {
        /// `depth` or `colour`.
        stream: &'static str,
        /// The field.
        field: &'static str,
        /// What it was.
        value: f32,
    },
    /// The extrinsics' rotation is not a rotation, or the translation is not finite.
    #[error("depth to colour extrinsics: {0}")]
    Extrinsics(String),
    /// The depth scale is not a positive number.
    #[error("depth units: {0} metres per unit (need a finite value above 0)")]
    DepthScale(f32),
}

/// Rays through the pixel corners of the depth image, in the colour camera's orientation
/// (`R * (x_n, y_n, 1)`): the ray through corner `(u - 0.5, v - 0.5)` is `column(u) + row(v)`.
///
/// A rectilinear depth lens needs only a table per corner column (`width + 1`) and per corner
/// row (`height + 1`), since `R * (x_n, y_n, 1) = x_n R e_x + (y_n R e_y + R e_z)`; the bottom-right
/// corner of pixel `(u, v)` is the top-left corner of `(u + 1, v + 1)`. A lens with inverse
/// Brown-Conrady coefficients gets a full table per corner (rows of zeros then).
#[derive(Debug, Clone)]
struct Rays {
    /// Per corner column (`width + 1`), or per corner (`(width + 1) * (height + 1)`) for a
    /// distorted lens: x, y, z.
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    /// Per corner row (`height + 1`): x, y, z (zeros with a full table).
    row: Vec<[f32; 3]>,
    /// Corners per table row: `width + 1` with a full table, 0 when separable.
    full_stride: usize,
    /// Per depth row, then per chunk of [`CHUNK`] pixels: the range of the rays through the
    /// corners of its pixels (both corners of each), for [`Projection::misses`].
    boxes: Vec<RayBox>,
    /// Chunks per depth row.
    chunks: usize,
}

/// The smallest and the largest of each component (x, y, z) of a set of rays, as the
/// projection sums them (`f32`).
#[derive(Debug, Clone, Copy)]
struct RayBox {
    lo: [f32; 3],
    hi: [f32; 3],
}

impl Rays {
    fn new(depth: &Lens, extrinsics: &Extrinsics) -> Self {
        let (w, h) = (depth.width as usize, depth.height as usize);
        // f32 as librealsense computes the normalised coordinates.
        let x_n = |u: usize| (u as f32 - 0.5 - depth.ppx) / depth.fx;
        let y_n = |v: usize| (v as f32 - 0.5 - depth.ppy) / depth.fy;
        let c = depth.coeffs;
        let full = depth.model == Distortion::InverseBrownConrady && depth.has_coefficients();
        let mut rays = Self {
            x: Vec::new(),
            y: Vec::new(),
            z: Vec::new(),
            row: Vec::new(),
            full_stride: 0,
            boxes: Vec::new(),
            chunks: w.div_ceil(CHUNK),
        };
        let mut push = |r: [f64; 3]| {
            rays.x.push(r[0] as f32);
            rays.y.push(r[1] as f32);
            rays.z.push(r[2] as f32);
        };
        if full {
            for v in 0..=h {
                for u in 0..=w {
                    let (x, y) = (x_n(u), y_n(v));
                    let r2 = x * x + y * y;
                    let f = 1.0 + c[0] * r2 + c[1] * r2 * r2 + c[4] * r2 * r2 * r2;
                    let ux = x * f + 2.0 * c[2] * x * y + c[3] * (r2 + 2.0 * x * x);
                    let uy = y * f + 2.0 * c[3] * x * y + c[2] * (r2 + 2.0 * y * y);
                    push(extrinsics.apply_rotation([f64::from(ux), f64::from(uy), 1.0]));
                }
            }
            rays.row = vec![[0.0; 3]; h + 1];
            rays.full_stride = w + 1;
        } else {
            for u in 0..=w {
                push(extrinsics.apply_rotation([f64::from(x_n(u)), 0.0, 0.0]));
            }
            rays.row =
                (0..=h).map(|v| extrinsics.apply_rotation([0.0, f64::from(y_n(v)), 1.0]).map(|c| c as f32)).collect();
        }
        // Pixel u of a chunk starting at `start` has its corners on columns u and u + 1, rows v
        // and v + 1.
        for v in 0..h {
            for start in (0..w).step_by(CHUNK) {
                let columns = start..=(start + CHUNK).min(w);
                let mut b = RayBox { lo: [f32::INFINITY; 3], hi: [f32::NEG_INFINITY; 3] };
                for r in [v, v + 1] {
                    for at in columns.clone().map(|u| rays.row_start(r) + u) {
                        let ray =
                            [rays.x[at] + rays.row[r][0], rays.y[at] + rays.row[r][1], rays.z[at] + rays.row[r][2]];
                        for (c, r) in ray.into_iter().enumerate() {
                            b.lo[c] = b.lo[c].min(r);
                            b.hi[c] = b.hi[c].max(r);
                        }
                    }
                }
                rays.boxes.push(b);
            }
        }
        rays
    }

    /// Where row `v`'s corners start in the column tables.
    fn row_start(&self, v: usize) -> usize {
        v * self.full_stride
    }

    /// The range of the corner rays of depth row `v`'s chunk starting at column `start`.
    fn chunk_box(&self, v: usize, start: usize) -> &RayBox {
        &self.boxes[v * self.chunks + start / CHUNK]
    }
}

/// Depth pixels handled per pass (projection into stack arrays, then the z-buffer writes).
/// (Timed on the `frame_handling` benchmark's synthetic room, one core, runs alternating: turned
/// 90° about 8 % faster than 64, as fast as 256; unturned the same as 64.)
const CHUNK: usize = 128;
/// Colour pixels per depth pixel (in both directions) from which rectangles are written as
/// fixed blocks ([`LinePlan`]). A rectangle spans the projections of a depth pixel's corners,
/// rounded: at 1.25 or more it is 2 or 3 pixels a side, and the fixed block (no branch on its
/// size) wins; nearer 1 most rectangles are 1 or 2 a side and a block would write most cells
/// several times. Measured by the `frame_handling` benchmark (synthetic room, one core), with
/// 3x3 blocks written cell by cell: 848x480 depth to 848x480 colour (1.3 and 1.4 colour pixels
/// per depth pixel) 2.03-2.15 ms with blocks against 2.26-2.36 ms with the sized loop; to
/// 1280x720 colour (1.9 and 2.1) blocks were already the faster.
const BLOCK_RATIO: f32 = 1.25;
/// How each depth pixel is written: one colour pixel ...
const PIXELS: u8 = 0;
/// ... the rectangle between its corners, loop sized per pixel ...
const RECTANGLES: u8 = 1;
/// ... or, with colour y along the output's rows (turned 90° or 270°), as up to 3 or 4 lines of
/// [`LANES`] values, planned for a whole chunk at once ([`LinePlan`]). Unturned and 180° frames
/// are aligned turned 90° and turned the rest of the way ([`DepthToColour::align`]).
const LINES_3: u8 = 3;
const LINES_4: u8 = 4;
/// A corner that does not land in front of the colour camera.
const NOWHERE: i32 = i32::MIN;
/// Projections further out than this many pixels are nowhere (and stay exact in the rounding).
const FAR_PX: f32 = 1.0e6;
/// 1.5 * 2^23: adding and subtracting it rounds an `f32` below 2^22 to an integer, ties to even
/// (the default rounding mode; librealsense's `_mm_cvtps_epi32` rounds the same way).
const ROUND_MAGIC: f32 = 12_582_912.0;

/// `x` rounded to the nearest integer, ties to even, for `|x| < 2^22`: adding 1.5 * 2^23 leaves
/// the rounded value in the low mantissa bits.
#[inline(always)]
fn round_to_i32(x: f32) -> i32 {
    ((x + ROUND_MAGIC).to_bits() as i32).wrapping_sub(ROUND_MAGIC.to_bits() as i32)
}

/// What the projection of one corner needs.
#[derive(Debug, Clone, Copy)]
struct Projection {
    metres_per_unit: f32,
    t: [f32; 3],
    fx: f32,
    fy: f32,
    ppx: f32,
    ppy: f32,
    coeffs: [f32; 5],
}

impl Projection {
    /// Colour pixel indices of one corner for each depth value of a chunk: the corner rays are
    /// `rays.{x,y,z}[at + i] + row`.
    #[inline(always)]
    #[allow(clippy::too_many_arguments)]
    fn corners<const DISTORT: bool>(
        &self,
        rays: &Rays,
        at: usize,
        row: [f32; 3],
        raw: &[u16],
        us: &mut [i32; CHUNK],
        vs: &mut [i32; CHUNK],
    ) {
        let n = raw.len();
        let (rx, ry, rz) = (&rays.x[at..at + n], &rays.y[at..at + n], &rays.z[at..at + n]);
        let (us, vs) = (&mut us[..n], &mut vs[..n]);
        let [tx, ty, tz] = self.t;
        let c = self.coeffs;
        for i in 0..n {
            let d = f32::from(raw[i]) * self.metres_per_unit;
            let px = d * (rx[i] + row[0]) + tx;
            let py = d * (ry[i] + row[1]) + ty;
            let pz = d * (rz[i] + row[2]) + tz;
            let (mut x, mut y) = (px / pz, py / pz); // two divisions as librealsense (rounding)
            if DISTORT {
                let r2 = x * x + y * y;
                let f = 1.0 + c[0] * r2 + c[1] * r2 * r2 + c[4] * r2 * r2 * r2;
                let (xf, yf) = (x * f, y * f);
                x = xf + 2.0 * c[2] * xf * yf + c[3] * (r2 + 2.0 * xf * xf);
                y = yf + 2.0 * c[3] * xf * yf + c[2] * (r2 + 2.0 * yf * yf);
            }
            let u = x * self.fx + self.ppx + 0.5;
            let v = y * self.fy + self.ppy + 0.5;
            // NaN (no depth, zero z) fails these comparisons too. `&`, not `&&`, and integer
            // arithmetic on the bits instead of a saturating `as i32`: the loop stays vectorised.
            let inside = (pz > 0.0) & (u.abs() < FAR_PX) & (v.abs() < FAR_PX);
            us[i] = if inside { round_to_i32(u) } else { NOWHERE };
            vs[i] = if inside { round_to_i32(v) } else { NOWHERE };
        }
    }
}

impl Projection {
    /// Whether no corner on the rays of `b` at a depth from `near` to `far` metres (above 0)
    /// lands on a `cw` x `ch` colour image, with a pixel to spare: every such corner is in front
    /// of the camera and left, right, above or below the image by more than a pixel, or behind it
    /// (projected nowhere). A rectilinear colour lens only (the test is on the pinhole
    /// projection).
    ///
    /// A corner at `p = d * r + t` (`p_z > 0`) lands left of colour column `c` when
    /// `(p_x / p_z) * fx + ppx + 0.5 < c`, that is when `g = fx * p_x + (ppx + 0.5 - c) * p_z < 0`.
    /// `g` is linear in each of `r_x`, `r_z` and `d` with the others held, so over the box of
    /// rays and the depth range it is largest at a corner of the box: the ray component of the
    /// larger `g` (`r_x` high, `r_z` by the sign of its factor) at either end of the depth
    /// range. The same holds for the other three sides. Computed in `f64`, with a slack for the
    /// rounding of the projection's `f32`.
    fn misses(&self, b: &RayBox, near: f32, far: f32, cw: u32, ch: u32) -> bool {
        let t = self.t.map(f64::from);
        let (lo, hi) = (b.lo.map(f64::from), b.hi.map(f64::from));
        let depths = [f64::from(near), f64::from(far)];
        // The projection's f32 error on `g`, bounded well above: a few roundings of each term's
        // magnitude. (It matters only for corners nearly at the colour camera's centre, where
        // the spare pixel, scaled by `p_z`, vanishes.)
        let size = lo.iter().chain(&hi).fold(0.0f64, |m, r| m.max(r.abs())) * f64::from(far)
            + t.iter().fold(0.0f64, |m, t| m.max(t.abs()));
        let slack = |f: f64, k: f64| 1e-5 * (f.abs() + k.abs()) * size;
        // The largest and the smallest of `f * p_a + k * p_z` over the box (`a`: 0 for x, 1 for
        // y), the slack added or taken away.
        let largest = |a: usize, f: f64, k: f64| {
            let rz = if k > 0.0 { hi[2] } else { lo[2] };
            let g = depths.map(|d| f * (d * hi[a] + t[a]) + k * (d * rz + t[2]));
            g[0].max(g[1]) + slack(f, k)
        };
        let smallest = |a: usize, f: f64, k: f64| {
            let rz = if k > 0.0 { lo[2] } else { hi[2] };
            let g = depths.map(|d| f * (d * lo[a] + t[a]) + k * (d * rz + t[2]));
            g[0].min(g[1]) - slack(f, k)
        };
        let (fx, fy) = (f64::from(self.fx), f64::from(self.fy));
        let (cx, cy) = (f64::from(self.ppx) + 0.5, f64::from(self.ppy) + 0.5);
        // Left of column -1.5 (rounded, -2 or less), right of cw + 0.5 (cw + 1 or more).
        let (left, right) = (-1.5, f64::from(cw) + 0.5);
        let (above, below) = (-1.5, f64::from(ch) + 0.5);
        largest(0, fx, cx - left) < 0.0
            || smallest(0, fx, cx - right) > 0.0
            || largest(1, fy, cy - above) < 0.0
            || smallest(1, fy, cy - below) > 0.0
    }
}

/// Where colour pixel `(x, y)` goes in the rotated output: `origin + x * step_x + y * step_y`.
#[derive(Debug, Clone, Copy)]
struct Placement {
    origin: isize,
    step_x: isize,
    step_y: isize,
    /// Whether colour x runs along the output's rows (no rotation or 180°), else colour y.
    along_x: bool,
    /// The step along the output's rows of that axis (1 or -1) ...
    along_step: isize,
    /// ... and of the other axis.
    across_step: isize,
    /// Where a block's line of [`LANES`] values starts, from its first cell: 0 forwards, back
    /// `LANES - 1` values backwards.
    lane_offset: isize,
}

impl Placement {
    fn new(rotation: Rotation, w: usize, h: usize) -> Self {
        let (w, h) = (w as isize, h as isize);
        let (origin, step_x, step_y) = match rotation {
            Rotation::None => (0, 1, w),
            // (x, y) -> (h-1-y, x), output width h.
            Rotation::Cw90 => (h - 1, h, -1),
            // (x, y) -> (w-1-x, h-1-y), output width w.
            Rotation::Cw180 => (h * w - 1, -1, -w),
            // (x, y) -> (y, w-1-x), output width h.
            Rotation::Cw270 => ((w - 1) * h, -h, 1),
        };
        let along_x = step_x.abs() == 1;
        let (along_step, across_step) = if along_x { (step_x, step_y) } else { (step_y, step_x) };
        let lane_offset = if along_step > 0 { 0 } else { -(LANES as isize - 1) };
        Self { origin, step_x, step_y, along_x, along_step, across_step, lane_offset }
    }
}

/// Depth → colour alignment for one pair of streams (made at stream start, used per frame).
#[derive(Debug, Clone)]
pub struct DepthToColour {
    depth: Lens,
    colour: Lens,
    extrinsics: Extrinsics,
    rays: Rays,
    /// Whether each depth pixel fills the rectangle between its corners (else one pixel).
    rectangles: bool,
    /// Whether rectangles are written as fixed blocks, lines of [`LANES`] values (colour pixels
    /// per depth pixel at least [`BLOCK_RATIO`] in both directions) rather than loops sized per
    /// pixel.
    blocks: bool,
    /// Whether rectangles are up to 4 colour pixels wide (at least 2 colour pixels per depth
    /// pixel along x), else 3: turned, blocks are written as that many lines.
    wide: bool,
    projection: Projection,
    distort: bool,
    /// Whether chunks of depth whose corners cannot land on the colour image are passed over
    /// before the projection (always, but for the tests that compare with the full projection).
    skips: bool,
    /// Unturned and 180° frames written as blocks: the aligned depth turned 90°, before it is
    /// turned the rest of the way into the frame (made at the first such frame).
    turned: Scratch,
}

/// A buffer reused from frame to frame (its values are not worth a `Debug` line).
#[derive(Clone, Default)]
struct Scratch(Vec<u16>);

impl std::fmt::Debug for Scratch {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Scratch({} values)", self.0.len())
    }
}

impl DepthToColour {
    /// Precomputes the rays for `depth` → `colour` with the device's extrinsics and depth scale
    /// (metres per depth unit, librealsense's `depth_units`).
    pub fn new(
        depth: Lens,
        colour: Lens,
        depth_to_colour: Extrinsics,
        metres_per_unit: f32,
    ) -> Result<Self, AlignError> {
        depth.check("depth")?;
        colour.check("colour")?;
        if !(metres_per_unit.is_finite() && metres_per_unit > 0.0) {
            return Err(AlignError::DepthScale(metres_per_unit));
        }
        check_extrinsics(&depth_to_colour)?;
        let [depth_fov, colour_fov] = [depth.fov_deg(), colour.fov_deg()];
        let depth_per_deg = [depth.width as f32 / depth_fov[0], depth.height as f32 / depth_fov[1]];
        let colour_per_deg = [colour.width as f32 / colour_fov[0], colour.height as f32 / colour_fov[1]];
        // librealsense also maps rectangles for two resolution pairs it names.
        let special = matches!(
            ((depth.width, depth.height), (colour.width, colour.height)),
            ((640, 240), (320, 180)) | ((640, 480), (640, 360))
        );
        let rectangles = depth_per_deg[0] < colour_per_deg[0] || depth_per_deg[1] < colour_per_deg[1] || special;
        let blocks = rectangles
            && colour_per_deg[0] >= BLOCK_RATIO * depth_per_deg[0]
            && colour_per_deg[1] >= BLOCK_RATIO * depth_per_deg[1];
        // Colour pixels per depth pixel along x, where the images meet: the focal lengths' ratio.
        let wide = colour.fx >= 2.0 * depth.fx;
        let distort = colour.model == Distortion::ModifiedBrownConrady && colour.has_coefficients();
        Ok(Self {
            depth,
            colour,
            extrinsics: depth_to_colour,
            rays: Rays::new(&depth, &depth_to_colour),
            rectangles,
            blocks,
            wide,
            projection: Projection {
                metres_per_unit,
                t: depth_to_colour.translation_m,
                fx: colour.fx,
                fy: colour.fy,
                ppx: colour.ppx,
                ppy: colour.ppy,
                coeffs: colour.coeffs,
            },
            distort,
            skips: true,
            turned: Scratch::default(),
        })
    }

    /// The depth stream's lens.
    pub fn depth(&self) -> &Lens {
        &self.depth
    }

    /// The colour stream's lens (the aligned depth has its size).
    pub fn colour(&self) -> &Lens {
        &self.colour
    }

    /// The extrinsics it was made with.
    pub fn extrinsics(&self) -> &Extrinsics {
        &self.extrinsics
    }

    /// Whether each depth pixel fills the rectangle between its corners (`false`: one pixel).
    pub fn maps_rectangles(&self) -> bool {
        self.rectangles
    }

    /// Metres per depth unit.
    pub fn metres_per_unit(&self) -> f32 {
        self.projection.metres_per_unit
    }

    /// Replaces the depth scale (the first frame's own depth units, when the sensor's option
    /// disagreed); ignored unless finite and above 0.
    pub fn set_metres_per_unit(&mut self, metres_per_unit: f32) {
        if metres_per_unit.is_finite() && metres_per_unit > 0.0 {
            self.projection.metres_per_unit = metres_per_unit;
        }
    }

    /// The streams whose lens coefficients are not applied (non-zero, of a model the align does
    /// not use for that stream), for a warning at start.
    pub fn ignored_coefficients(&self) -> Vec<(&'static str, Distortion)> {
        let mut ignored = Vec::new();
        if self.depth.has_coefficients() && self.depth.model != Distortion::InverseBrownConrady {
            ignored.push(("depth", self.depth.model));
        }
        if self.colour.has_coefficients() && self.colour.model != Distortion::ModifiedBrownConrady {
            ignored.push(("colour", self.colour.model));
        }
        ignored
    }

    /// Aligns one Z16 depth image (little-endian `u16` per pixel, rows `layout.stride_bytes`
    /// apart) to the colour stream and writes it, turned by `rotation`, into `out` (the pooled
    /// frame's depth: colour width x height values). Every value of `out` is written (0 where
    /// no depth lands).
    ///
    /// Where rectangles are written as blocks, an unturned or 180° frame is aligned turned 90°
    /// into a buffer kept for the next frame (allocated at the first), then turned into `out`:
    /// the blocks' lines run along colour y ([`LinePlan`]).
    pub fn align(
        &mut self,
        depth: &[u8],
        layout: SourceLayout,
        rotation: Rotation,
        out: &mut [u16],
    ) -> Result<(), CopyError> {
        let (dw, dh) = (self.depth.width as usize, self.depth.height as usize);
        let (cw, ch) = (self.colour.width as usize, self.colour.height as usize);
        let SourceLayout { width, height, stride_bytes } = layout;
        let needed = if dh == 0 { 0 } else { stride_bytes * (dh - 1) + dw * 2 };
        if (width, height) != (dw, dh) || stride_bytes < dw * 2 || depth.len() < needed {
            return Err(CopyError::ShortSource {
                stream: "depth",
                got: depth.len(),
                needed: needed.max(dw * dh * 2),
                width: dw,
                height: dh,
                stride: stride_bytes,
            });
        }
        if out.len() != cw * ch {
            return Err(CopyError::Destination {
                stream: "aligned depth",
                got: out.len(),
                needed: cw * ch,
                width: cw,
                height: ch,
            });
        }
        let mode = match (self.rectangles, self.blocks) {
            (false, _) => PIXELS,
            // (A line needs LANES values of the output.)
            (true, true) if out.len() >= LANES => {
                if self.wide {
                    LINES_4
                } else {
                    LINES_3
                }
            }
            (true, _) => RECTANGLES,
        };
        let place = Placement::new(rotation, cw, ch);
        if place.along_x && (mode == LINES_3 || mode == LINES_4) {
            // Lines along colour y: aligned turned 90° (ch wide, cw tall), then turned back 90°
            // (unturned) or on by 90° (180°).
            let mut turned = std::mem::take(&mut self.turned.0);
            turned.clear();
            turned.resize(out.len(), 0);
            self.align_rows(mode, depth, stride_bytes, Placement::new(Rotation::Cw90, cw, ch), &mut turned);
            let rest = if rotation == Rotation::None { Rotation::Cw270 } else { Rotation::Cw90 };
            crate::rotate::turn_u16(&turned, ch, cw, rest, out);
            self.turned.0 = turned;
        } else {
            out.fill(0);
            self.align_rows(mode, depth, stride_bytes, place, out);
        }
        Ok(())
    }

    /// The per-frame loop for `mode`, written into `out` (zeroed) as `place` turns it.
    fn align_rows(&self, mode: u8, depth: &[u8], stride_bytes: usize, place: Placement, out: &mut [u16]) {
        match (self.distort, mode) {
            (false, PIXELS) => align_rows::<false, PIXELS>(self, depth, stride_bytes, place, out),
            (false, RECTANGLES) => align_rows::<false, RECTANGLES>(self, depth, stride_bytes, place, out),
            (false, LINES_3) => align_rows::<false, LINES_3>(self, depth, stride_bytes, place, out),
            (false, _) => align_rows::<false, LINES_4>(self, depth, stride_bytes, place, out),
            (true, PIXELS) => align_rows::<true, PIXELS>(self, depth, stride_bytes, place, out),
            (true, RECTANGLES) => align_rows::<true, RECTANGLES>(self, depth, stride_bytes, place, out),
            (true, LINES_3) => align_rows::<true, LINES_3>(self, depth, stride_bytes, place, out),
            (true, _) => align_rows::<true, LINES_4>(self, depth, stride_bytes, place, out),
        }
    }

    #[inline(always)]
    fn align_chunks<const DISTORT: bool, const MODE: u8>(
        &self,
        depth: &[u8],
        stride_bytes: usize,
        place: Placement,
        out: &mut [u16],
    ) {
        let (dw, dh) = (self.depth.width as usize, self.depth.height as usize);
        let (cw, ch) = (self.colour.width, self.colour.height);
        let rays = &self.rays;
        let mut raw = [0u16; CHUNK];
        let (mut x0, mut y0, mut x1, mut y1) = ([0i32; CHUNK], [0i32; CHUNK], [0i32; CHUNK], [0i32; CHUNK]);
        let (mut lines_3, mut lines_4) = (LinePlan::<3>::new(), LinePlan::<4>::new());
        for v in 0..dh {
            let row = &depth[v * stride_bytes..v * stride_bytes + dw * 2];
            let (top, bottom) = (rays.row_start(v), rays.row_start(v + 1));
            let mut start = 0;
            while start < dw {
                let n = CHUNK.min(dw - start);
                let raw = &mut raw[..n];
                for (r, px) in raw.iter_mut().zip(row[start * 2..(start + n) * 2].chunks_exact(2)) {
                    *r = u16::from_le_bytes([px[0], px[1]]);
                }
                // The chunk's nearest and farthest depth (0, no depth, as the farthest: it
                // writes nothing). With none, or when no corner at those depths can land on the
                // colour image, the chunk writes nothing and is passed over before the
                // projection: the D435i's depth sees wider and taller than its colour, by about
                // a third of its rows and a quarter of its columns.
                let nearest_raw = raw.iter().fold(u16::MAX, |m, &z| m.min(z.wrapping_sub(1))).wrapping_add(1);
                if nearest_raw == 0 {
                    start += n;
                    continue;
                }
                if !DISTORT && self.skips {
                    let farthest_raw = raw.iter().fold(0, |m, &z| m.max(z));
                    let mpu = self.projection.metres_per_unit;
                    let (near, far) = (f32::from(nearest_raw) * mpu, f32::from(farthest_raw) * mpu);
                    if self.projection.misses(rays.chunk_box(v, start), near, far, cw, ch) {
                        start += n;
                        continue;
                    }
                }
                self.projection.corners::<DISTORT>(rays, top + start, rays.row[v], raw, &mut x0, &mut y0);
                if MODE != PIXELS {
                    // Bottom-right of pixel (u, v): the corner of column u + 1 on row v + 1.
                    self.projection.corners::<DISTORT>(
                        rays,
                        bottom + start + 1,
                        rays.row[v + 1],
                        raw,
                        &mut x1,
                        &mut y1,
                    );
                }
                if MODE == PIXELS {
                    // One colour pixel each: its output index, worked out for the whole chunk
                    // (vectorised; NOWHERE is out of bounds as u32 too), -1 for none.
                    let (idxs, xs, ys) = (&mut x1[..n], &x0[..n], &y0[..n]);
                    for i in 0..n {
                        let (x, y) = (xs[i], ys[i]);
                        let inside = ((x as u32) < cw) & ((y as u32) < ch) & (raw[i] != 0);
                        let at = place.origin as i32
                            + x.wrapping_mul(place.step_x as i32)
                            + y.wrapping_mul(place.step_y as i32);
                        idxs[i] = if inside { at } else { -1 };
                    }
                    for (&idx, &z) in idxs.iter().zip(raw.iter()) {
                        if idx >= 0 {
                            // Nearest wins; 0 (nothing yet) counts as farthest:
                            // min(out - 1, z - 1) + 1 in wrapping u16 arithmetic.
                            let at = idx as usize;
                            out[at] = out[at].wrapping_sub(1).min(z - 1) + 1;
                        }
                    }
                    start += n;
                    continue;
                }
                if MODE == LINES_3 || MODE == LINES_4 {
                    let corners = Corners { raw, x0: &x0[..n], y0: &y0[..n], x1: &x1[..n], y1: &y1[..n] };
                    if MODE == LINES_3 {
                        lines_3.write(corners, place, cw, ch, out);
                    } else {
                        lines_4.write(corners, place, cw, ch, out);
                    }
                    start += n;
                    continue;
                }
                for i in 0..n {
                    let z = raw[i];
                    if z == 0 {
                        continue;
                    }
                    // Nearest wins; 0 (nothing yet) counts as farthest: min(out - 1, z - 1) + 1
                    // in wrapping u16 arithmetic.
                    let z1 = z - 1;
                    let (xa, ya) = (x0[i], y0[i]);
                    let (xb, yb) = (x1[i], y1[i]);
                    if xa == NOWHERE || xb == NOWHERE {
                        continue;
                    }
                    // Pixels of the rectangle outside the colour image are skipped, as by
                    // librealsense; the part inside is written.
                    let (xa, xb) = (xa.max(0), xb.min(cw as i32 - 1));
                    let (ya, yb) = (ya.max(0), yb.min(ch as i32 - 1));
                    if xa > xb || ya > yb {
                        continue;
                    }
                    write_rectangle(out, place, z1, [xa, ya, xb, yb]);
                }
                start += n;
            }
        }
    }
}

/// Writes depth `z1 + 1` into the colour pixels `xa..=xb` x `ya..=yb` (inside the colour image)
/// of the rotated `out`, the nearest winning, with a loop sized to the rectangle.
///
/// Blocks go through [`LinePlan`], with colour y along the output's rows. Along colour x,
/// 4-value lines of neighbouring depth pixels would overlap shifted by a cell or two, and each
/// load would wait on partly overlapping stores (`frame_handling` benchmark, 848x480 to 848x480
/// unturned: 2.38 ms cell by cell, 2.49 ms with such lines): unturned frames are aligned turned.
#[inline(always)]
fn write_rectangle(out: &mut [u16], place: Placement, z1: u16, [xa, ya, xb, yb]: [i32; 4]) {
    let base = place.origin + xa as isize * place.step_x + ya as isize * place.step_y;
    let mut row_at = base;
    for _ in ya..=yb {
        let mut at = row_at;
        for _ in xa..=xb {
            nearest(out, at as usize, z1);
            at += place.step_x;
        }
        row_at += place.step_y;
    }
}

/// One chunk's depths and the colour pixels of their footprints' corners.
#[derive(Clone, Copy)]
struct Corners<'a> {
    raw: &'a [u16],
    x0: &'a [i32],
    y0: &'a [i32],
    x1: &'a [i32],
    y1: &'a [i32],
}

/// The block writes of one chunk, turned 90° or 270°: per depth pixel the output index of each
/// of its `L` lines (a line: [`LANES`] values of one output row, colour y running along it, at
/// one colour x of the rectangle) and the depth in the lanes the rectangle covers.
///
/// Worked out for the whole chunk in passes without branches (vectorised), then written: each
/// pixel's lines are `L` load-min-store of [`LANES`] values, with no test on the rectangle's
/// size. A pixel with nothing to write (no depth, off the colour image) is passed over; one
/// whose rectangle does not fit the lines (wider than `L`, taller than [`LANES`], or lines past
/// the ends of the output) is written afterwards by [`write_rectangle`]. The nearest-wins
/// minimum does not depend on the order of the writes, so the image is the same.
///
/// Neighbouring depth pixels of a row differ in colour x: the lines two of them share are the
/// same output values, and each load finds the previous store whole (store-to-load
/// forwarding); unturned they would overlap shifted by a value or two.
struct LinePlan<const L: usize> {
    /// Output index of each line's first value, per line then per pixel.
    at: [[i32; CHUNK]; L],
    /// The rectangle's width - 1 (0 ..= L - 1).
    width: [i32; CHUNK],
    /// The depth written (`z - 1`; `u16::MAX` writes nothing).
    z1: [i32; CHUNK],
    /// The rectangle's height - 1 (0..=3): which lanes it covers.
    height: [i32; CHUNK],
    /// Whether the pixel is left to [`write_rectangle`] (non-zero).
    apart: [i32; CHUNK],
}

impl<const L: usize> LinePlan<L> {
    fn new() -> Self {
        Self { at: [[0; CHUNK]; L], width: [0; CHUNK], z1: [0; CHUNK], height: [0; CHUNK], apart: [0; CHUNK] }
    }

    /// Writes one chunk's rectangles into `out` (at least [`LANES`] values, as
    /// [`DepthToColour::align`] checks before choosing lines).
    #[inline(always)]
    fn write(&mut self, c: Corners, place: Placement, cw: u32, ch: u32, out: &mut [u16]) {
        let n = c.raw.len();
        // (Lets the compiler drop the bounds checks on the chunk's arrays.)
        assert!(n <= CHUNK, "chunk of {n} depth pixels");
        let (cw, ch) = (cw as i32, ch as i32);
        // Output indices fit i32: the colour image has at most 2^30 pixels (`Lens::check`).
        let (origin, step_x, step_y) = (place.origin as i32, place.step_x as i32, place.step_y as i32);
        let (across, lane_offset) = (place.across_step as i32, place.lane_offset as i32);
        let last_low = (out.len() - LANES) as u32;
        // Every slice n long, so that the loops have no bounds checks and are vectorised.
        let (raws, x0, y0, x1, y1) = (c.raw, &c.x0[..n], &c.y0[..n], &c.x1[..n], &c.y1[..n]);
        // A chunk none of whose rectangles can reach into the colour image writes nothing: the
        // D435i's depth sees wider and taller than its colour, so the depth rows above and below
        // the colour image and the columns beside it are passed over after the projection.
        // (Counted rather than `any`: a count is vectorised, the early exit of `any` is not.)
        let reaching: i32 = (raws.iter().zip(x0).zip(x1).zip(y0).zip(y1))
            .map(|((((&raw, &xa), &xb), &ya), &yb)| {
                i32::from((raw != 0) & (xb >= 0) & (xa < cw) & (yb >= 0) & (ya < ch))
            })
            .sum();
        if reaching == 0 {
            return;
        }
        let (first, widths) = (&mut self.at[0][..n], &mut self.width[..n]);
        let (z1s, heights, aparts) = (&mut self.z1[..n], &mut self.height[..n], &mut self.apart[..n]);
        for i in 0..n {
            let raw = raws[i];
            let (xa, xb) = (x0[i], x1[i]);
            let reach = (raw != 0) & (xa != NOWHERE) & (xb != NOWHERE);
            // Pixels of the rectangle outside the colour image are skipped, as by librealsense;
            // the part inside is written.
            let (xa, xb) = (xa.max(0), xb.min(cw - 1));
            let (ya, yb) = (y0[i].max(0), y1[i].min(ch - 1));
            let (dx, dy) = (xb.wrapping_sub(xa), yb.wrapping_sub(ya));
            let some = reach & (dx >= 0) & (dy >= 0);
            let fits = ((dx as u32) < L as u32) & ((dy as u32) < LANES as u32);
            let low = origin
                .wrapping_add(xa.wrapping_mul(step_x))
                .wrapping_add(ya.wrapping_mul(step_y))
                .wrapping_add(lane_offset);
            // The lines lie between the first and the last (`across` apart).
            let last = low.wrapping_add(dx.wrapping_mul(across));
            let inside = ((low as u32) <= last_low) & ((last as u32) <= last_low);
            let lined = some & fits & inside;
            z1s[i] = if lined { i32::from(raw) - 1 } else { i32::from(u16::MAX) };
            heights[i] = dy & 3;
            first[i] = if lined { low } else { 0 };
            widths[i] = if lined { dx } else { 0 };
            aparts[i] = i32::from(some & !lined);
        }
        // Line j at colour x `xa + min(j, width - 1)`: the last repeats where the rectangle is
        // narrower than L (writing the same depth twice changes nothing).
        let widths = &self.width[..n];
        let (head, tail) = self.at.split_at_mut(1);
        let first = &head[0][..n];
        for (j, line) in (1..).zip(tail) {
            let line = &mut line[..n];
            for i in 0..n {
                line[i] = first[i].wrapping_add(widths[i].min(j).wrapping_mul(across));
            }
        }
        // Lanes covered (0) per rectangle height, with the line running forwards from the
        // rectangle's first cell or backwards to it.
        const FORWARD: [[u16; LANES]; LANES] = [[0, !0, !0, !0], [0, 0, !0, !0], [0, 0, 0, !0], [0; LANES]];
        const BACKWARD: [[u16; LANES]; LANES] = [[!0, !0, !0, 0], [!0, !0, 0, 0], [!0, 0, 0, 0], [0; LANES]];
        let masks = if place.along_step > 0 { &FORWARD } else { &BACKWARD };
        for i in 0..n {
            let z1 = self.z1[i] as u16;
            if z1 == u16::MAX {
                continue;
            }
            let z = masks[(self.height[i] & 3) as usize].map(|m| z1 | m);
            for at in &self.at {
                // 0 <= at[i] <= out.len() - LANES: checked above (or 0).
                nearest_lanes(out, at[i] as usize, z);
            }
        }
        // Most chunks leave nothing to the sized loop: one vectorised test instead of a scan.
        if self.apart[..n].iter().fold(0, |any, &apart| any | apart) == 0 {
            return;
        }
        for i in 0..n {
            if self.apart[i] != 0 {
                let clamp = |lo: i32, hi: i32, max: i32| (lo.max(0), hi.min(max - 1));
                let (xa, xb) = clamp(c.x0[i], c.x1[i], cw);
                let (ya, yb) = clamp(c.y0[i], c.y1[i], ch);
                write_rectangle(out, place, c.raw[i] - 1, [xa, ya, xb, yb]);
            }
        }
    }
}

/// Values per lane-wise write of [`nearest_lanes`]: a block's line, up to 4 colour pixels along
/// colour y, one 8-byte load and store.
const LANES: usize = 4;

/// [`nearest`] on the `LANES` consecutive values from `low`, each with its own depth (a lane
/// with `u16::MAX` keeps its value: `min(out - 1, MAX) + 1 = out`). Vectorised by the compiler.
///
/// The caller checks `low + LANES <= out.len()`.
#[inline(always)]
#[allow(unsafe_code)] // One unchecked slice on the hot path, checked by the caller.
fn nearest_lanes(out: &mut [u16], low: usize, z1: [u16; LANES]) {
    debug_assert!(low + LANES <= out.len(), "aligned depth values {low}.. outside {} values", out.len());
    // SAFETY: `low + LANES <= out.len()`, checked by the caller (and here in debug builds).
    let cells = unsafe { out.get_unchecked_mut(low..low + LANES) };
    for (cell, z) in cells.iter_mut().zip(z1) {
        *cell = cell.wrapping_sub(1).min(z).wrapping_add(1);
    }
}

/// Keeps the nearer of `out[at]` and depth `z1 + 1`; 0 (nothing yet) counts as farthest:
/// `min(out - 1, z1) + 1` in wrapping `u16` arithmetic.
///
/// `at` lies inside `out` by construction: the callers clamp every rectangle to the colour
/// image (`0 <= x < width`, `0 <= y < height`) before placing it, and [`Placement`] maps that
/// image onto `out`, which [`DepthToColour::align`] checked to be width x height long. The
/// check is compiled out of release builds: on this hot path (about six writes per depth pixel)
/// the bounds checks cost a measurable share of the alignment (the `frame_handling` benchmark).
#[inline(always)]
#[allow(unsafe_code)] // One unchecked index on the hot path, argued above.
fn nearest(out: &mut [u16], at: usize, z1: u16) {
    debug_assert!(at < out.len(), "aligned depth index {at} outside {} values", out.len());
    // SAFETY: `at < out.len()` as argued above (and checked in debug builds).
    let cell = unsafe { out.get_unchecked_mut(at) };
    *cell = cell.wrapping_sub(1).min(z1) + 1;
}

/// [`DepthToColour::align_chunks`], compiled for the baseline and for AVX2 (picked once at run
/// time from the CPU's features). No FMA: the result must stay bit-identical to librealsense's
/// separate multiplies and adds.
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn align_rows<const DISTORT: bool, const MODE: u8>(
    align: &DepthToColour,
    depth: &[u8],
    stride_bytes: usize,
    place: Placement,
    out: &mut [u16],
) {
    align.align_chunks::<DISTORT, MODE>(depth, stride_bytes, place, out);
}

fn check_extrinsics(e: &Extrinsics) -> Result<(), AlignError> {
    if !e.rotation.iter().chain(&e.translation_m).all(|v| v.is_finite()) {
        return Err(AlignError::Extrinsics(format!("not finite: {e:?}")));
    }
    // R^T R = I within float noise of a calibration (columns of unit length, orthogonal).
    let r = e.rotation.map(f64::from);
    let col = |j: usize| [r[3 * j], r[3 * j + 1], r[3 * j + 2]];
    for i in 0..3 {
        for j in 0..3 {
            let (a, b) = (col(i), col(j));
            let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            let want = if i == j { 1.0 } else { 0.0 };
            if (dot - want).abs() > 1e-3 {
                return Err(AlignError::Extrinsics(format!(
                    "rotation is not orthonormal (column {i} . column {j} = {dot:.6}): {:?}",
                    e.rotation
                )));
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rotate::copy_depth;

    fn bytes(depth: &[u16]) -> Vec<u8> {
        depth.iter().flat_map(|d| d.to_le_bytes()).collect()
    }

    fn layout(lens: &Lens) -> SourceLayout {
        SourceLayout { width: lens.width as usize, height: lens.height as usize, stride_bytes: lens.width as usize * 2 }
    }

    fn run(align: &DepthToColour, depth: &[u16], rotation: Rotation) -> Vec<u16> {
        let mut out = vec![0xABCDu16; align.colour().width as usize * align.colour().height as usize];
        align.clone().align(&bytes(depth), layout(align.depth()), rotation, &mut out).unwrap();
        out
    }

    fn translation(tx: f32) -> Extrinsics {
        Extrinsics { translation_m: [tx, 0.0, 0.0], ..Extrinsics::IDENTITY }
    }

    /// Units of 1 mm.
    const MM: f32 = 0.001;

    #[test]
    fn the_same_camera_leaves_depth_unchanged_holes_included() {
        let lens = Lens::pinhole(64, 48, 50.0, 51.0, 31.25, 23.75);
        let align = DepthToColour::new(lens, lens, Extrinsics::IDENTITY, MM).unwrap();
        assert!(!align.maps_rectangles(), "equal resolution: one pixel per depth pixel");
        let depth: Vec<u16> = (0..64 * 48).map(|i| if i % 7 == 3 { 0 } else { 500 + (i * 13 % 4000) as u16 }).collect();
        assert_eq!(run(&align, &depth, Rotation::None), depth);
    }

    #[test]
    fn a_plane_seen_from_a_shifted_camera_shifts_by_the_disparity() {
        // Fronto-parallel plane at 2 m, colour camera 5 cm to the right of depth (points move by
        // +5 cm in its frame): every pixel moves by fx * t / z = 400 * 0.05 / 2 = 10 px.
        let lens = Lens::pinhole(80, 40, 400.0, 400.0, 39.3, 19.6);
        let align = DepthToColour::new(lens, lens, translation(0.05), MM).unwrap();
        let depth = vec![2000u16; 80 * 40];
        let out = run(&align, &depth, Rotation::None);
        for v in 0..40 {
            for u in 0..80 {
                let want = if u < 10 { 0 } else { 2000 };
                assert_eq!(out[v * 80 + u], want, "({u}, {v})");
            }
        }
        // A distinct value per depth pixel lands exactly 10 px to the right.
        let depth: Vec<u16> = (0..80 * 40).map(|i| 2000 + (i % 2) as u16).collect();
        let out = run(&align, &depth, Rotation::None);
        for v in 0..40 {
            for u in 10..80 {
                assert_eq!(out[v * 80 + u], depth[v * 80 + u - 10], "({u}, {v})");
            }
        }
    }

    #[test]
    fn a_sharper_colour_camera_gets_every_pixel_of_the_plane() {
        // Colour: twice the resolution and focal length, same field of view: rectangles.
        let depth_lens = Lens::pinhole(60, 40, 50.0, 50.0, 29.5, 19.5);
        let colour_lens = Lens::pinhole(120, 80, 100.0, 100.0, 59.5, 39.5);
        let align = DepthToColour::new(depth_lens, colour_lens, Extrinsics::IDENTITY, MM).unwrap();
        assert!(align.maps_rectangles());
        let out = run(&align, &vec![1500u16; 60 * 40], Rotation::None);
        assert!(out.iter().all(|&z| z == 1500), "no holes on a plane: {:?}", out.iter().filter(|&&z| z == 0).count());
        // A step: the left half nearer; the edge column of the colour image gets the nearer value
        // where both rectangles touch it.
        let depth: Vec<u16> = (0..60 * 40).map(|i| if i % 60 < 30 { 1000 } else { 3000 }).collect();
        let out = run(&align, &depth, Rotation::None);
        for v in 0..80 {
            assert!(out[v * 120..v * 120 + 59].iter().all(|&z| z == 1000), "row {v} left");
            assert!(out[v * 120 + 61..v * 120 + 120].iter().all(|&z| z == 3000), "row {v} right");
        }
    }

    #[test]
    fn a_near_box_hides_the_wall_behind_it_and_leaves_its_shadow_empty() {
        // Wall at 4 m, a box at 1 m over depth columns 40..60; colour 9.6 cm to the right:
        // the wall moves 100 * 0.096 / 4 = 2.4 px (to 2..42 and 62..), the box 9.6 px (to
        // 50..70, hiding the wall that lands on 62..70), and 42..50 is seen by colour only (the
        // box's shadow in depth): no depth there.
        let lens = Lens::pinhole(100, 20, 100.0, 100.0, 49.5, 9.5);
        let align = DepthToColour::new(lens, lens, translation(0.096), MM).unwrap();
        let depth: Vec<u16> = (0..100 * 20).map(|i| if (40..60).contains(&(i % 100)) { 1000 } else { 4000 }).collect();
        let out = run(&align, &depth, Rotation::None);
        for v in 0..20 {
            let row = &out[v * 100..(v + 1) * 100];
            assert!(row[51..69].iter().all(|&z| z == 1000), "box, row {v}: {row:?}");
            assert!(row[44..49].iter().all(|&z| z == 0), "shadow, row {v}: {row:?}");
            assert!(row[4..42].iter().all(|&z| z == 4000), "wall left, row {v}: {row:?}");
            assert!(row[71..].iter().all(|&z| z == 4000), "wall right, row {v}: {row:?}");
        }
    }

    #[test]
    fn rotating_on_the_way_equals_aligning_then_rotating() {
        let depth_lens = Lens::pinhole(48, 36, 40.0, 41.0, 23.0, 18.5);
        let colour_lens = Lens::pinhole(64, 40, 70.0, 70.5, 31.0, 20.5);
        let extrinsics = Extrinsics {
            // 2 degrees about y, then a baseline.
            rotation: {
                let (s, c) = 0.035f32.sin_cos();
                [c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c]
            },
            translation_m: [0.015, 0.001, -0.002],
        };
        let align = DepthToColour::new(depth_lens, colour_lens, extrinsics, 0.00025).unwrap();
        let depth: Vec<u16> =
            (0..48 * 36).map(|i| if i % 11 == 0 { 0 } else { 4000 + (i * 37 % 9000) as u16 }).collect();
        let upright = run(&align, &depth, Rotation::None);
        assert!(upright.iter().filter(|&&z| z != 0).count() > 64 * 40 / 2, "most of the colour image has depth");
        for rotation in [Rotation::Cw90, Rotation::Cw180, Rotation::Cw270] {
            let mut want = vec![0u16; upright.len()];
            copy_depth(
                &bytes(&upright),
                SourceLayout { width: 64, height: 40, stride_bytes: 128 },
                rotation,
                &mut want,
            )
            .unwrap();
            assert_eq!(run(&align, &depth, rotation), want, "{rotation:?}");
        }
    }

    #[test]
    fn strided_rows_and_points_behind_the_colour_camera() {
        let lens = Lens::pinhole(8, 2, 10.0, 10.0, 3.5, 0.5);
        // Colour 1 m in front of depth: points nearer than 1 m are behind it.
        let mut align =
            DepthToColour::new(lens, lens, Extrinsics { translation_m: [0.0, 0.0, -1.0], ..Extrinsics::IDENTITY }, MM)
                .unwrap();
        let mut padded = vec![0xFFu8; 2 * 24];
        for (v, row) in [[500u16; 8], [3000u16; 8]].iter().enumerate() {
            padded[v * 24..v * 24 + 16].copy_from_slice(&bytes(row));
        }
        let mut out = vec![7u16; 16];
        align.align(&padded, SourceLayout { width: 8, height: 2, stride_bytes: 24 }, Rotation::None, &mut out).unwrap();
        // Row 0 (0.5 m) is behind the colour camera: nothing; row 1 (3 m, 2 m from colour) lands
        // nearer the centre, within the image.
        assert!(out.contains(&3000));
        assert!(out.iter().all(|&z| z == 0 || z == 3000), "{out:?}");
    }

    #[test]
    fn bad_calibration_and_buffers_are_refused_naming_what() {
        let lens = Lens::pinhole(8, 2, 10.0, 10.0, 3.5, 0.5);
        let e = DepthToColour::new(Lens { fx: 0.0, ..lens }, lens, Extrinsics::IDENTITY, MM).unwrap_err();
        assert_eq!(e.to_string(), "depth intrinsics: fx = 0 (need a finite value, focal lengths and sizes above 0)");
        let e = DepthToColour::new(lens, Lens { ppy: f32::NAN, ..lens }, Extrinsics::IDENTITY, MM).unwrap_err();
        assert!(e.to_string().starts_with("colour intrinsics: ppy = NaN"), "{e}");
        let skewed = Extrinsics { rotation: [1.0, 0.0, 0.0, 0.5, 1.0, 0.0, 0.0, 0.0, 1.0], ..Extrinsics::IDENTITY };
        let e = DepthToColour::new(lens, lens, skewed, MM).unwrap_err();
        assert!(e.to_string().contains("not orthonormal"), "{e}");
        assert!(matches!(DepthToColour::new(lens, lens, Extrinsics::IDENTITY, 0.0), Err(AlignError::DepthScale(_))));
        let mut align = DepthToColour::new(lens, lens, Extrinsics::IDENTITY, MM).unwrap();
        let mut out = vec![0u16; 16];
        let e = align.align(&[0u8; 31], layout(&lens), Rotation::None, &mut out).unwrap_err();
        assert!(e.to_string().starts_with("depth: driver buffer holds 31 bytes"), "{e}");
        let mut short = vec![0u16; 15];
        let e = align.align(&[0u8; 32], layout(&lens), Rotation::None, &mut short).unwrap_err();
        assert!(e.to_string().contains("aligned depth: frame buffer holds 15 values"), "{e}");
    }

    #[test]
    fn a_depth_lens_with_coefficients_uses_full_ray_tables_indexed_alike() {
        // Inverse Brown-Conrady coefficients too small to move a corner by a pixel: the full
        // per-corner tables must give what the separable ones give.
        let depth_lens = Lens::pinhole(48, 36, 40.0, 41.0, 23.0, 18.5);
        let colour_lens = Lens::pinhole(64, 40, 70.0, 70.5, 31.0, 20.5);
        let distorted =
            Lens { model: Distortion::InverseBrownConrady, coeffs: [1e-9, 0.0, 0.0, 0.0, 0.0], ..depth_lens };
        let e = translation(0.02);
        let plain = DepthToColour::new(depth_lens, colour_lens, e, 0.00025).unwrap();
        let full = DepthToColour::new(distorted, colour_lens, e, 0.00025).unwrap();
        assert!(full.rays.full_stride > 0 && plain.rays.full_stride == 0);
        let depth: Vec<u16> =
            (0..48 * 36).map(|i| if i % 13 == 0 { 0 } else { 6000 + (i * 31 % 5000) as u16 }).collect();
        for rotation in [Rotation::None, Rotation::Cw90] {
            assert_eq!(run(&full, &depth, rotation), run(&plain, &depth, rotation), "{rotation:?}");
        }
    }

    #[test]
    fn field_of_view_and_rounding_follow_librealsense() {
        // rs2_fov of a 848x480 D435i-like depth stream.
        let lens = Lens::pinhole(848, 480, 421.0, 421.0, 423.5, 239.5);
        let [h, v] = lens.fov_deg();
        assert!((h - 90.4).abs() < 0.1 && (v - 59.4).abs() < 0.1, "{h} {v}");
        // Ties round to even, as _mm_cvtps_epi32.
        for (x, want) in
            [(2.5f32, 2), (3.5, 4), (-0.5, 0), (-1.5, -2), (-2.7, -3), (7.49, 7), (7.51, 8), (-999_999.4, -999_999)]
        {
            assert_eq!(round_to_i32(x), want, "{x}");
        }
        // Coefficients of models the align does not apply are reported.
        let colour = Lens { model: Distortion::InverseBrownConrady, coeffs: [0.1, 0.0, 0.0, 0.0, 0.0], ..lens };
        let align = DepthToColour::new(lens, colour, Extrinsics::IDENTITY, MM).unwrap();
        assert_eq!(align.ignored_coefficients(), [("colour", Distortion::InverseBrownConrady)]);
    }

    #[test]
    fn turned_lines_write_what_the_sized_loop_writes() {
        // The D435i's 848x480 depth to 848x480 colour (1.43 colour pixels per depth pixel): 3
        // lines; to 1280x720 (2.16): 4 lines; and 1280x720 held to 3 lines, so that every
        // rectangle 4 wide is left to the sized loop. The depth's field of view is the wider:
        // rectangles reach the colour image's corners, where lines would run past the ends of
        // the output (left to the sized loop too). A near box over a slanted wall, holes, and a
        // yawed, shifted colour camera (parallax, occlusion, shadows).
        let depth_lens = Lens::pinhole(848, 480, 421.0, 421.0, 422.75, 239.75);
        let colour = |w: u32, h: u32| {
            let f = 910.0 * w as f32 / 1280.0;
            Lens::pinhole(w, h, f, f, (w as f32 - 1.0) / 2.0 + 0.4, (h as f32 - 1.0) / 2.0 - 0.3)
        };
        let extrinsics = Extrinsics {
            rotation: {
                let (s, c) = 0.4f32.to_radians().sin_cos();
                [c, 0.0, -s, 0.0, 1.0, 0.0, s, 0.0, c]
            },
            translation_m: [0.015, 0.0003, -0.0002],
        };
        let depth: Vec<u16> = (0..848 * 480)
            .map(|i: usize| {
                let (u, v) = (i % 848, i / 848);
                if (7 * u + 3 * v) % 53 == 0 {
                    0
                } else if (300..510).contains(&u) && (140..340).contains(&v) {
                    3600 + (i * 7919 % 97) as u16
                } else {
                    8000 + (u * 4) as u16 + (i * 104_729 % 31) as u16
                }
            })
            .collect();
        let narrow = DepthToColour::new(depth_lens, colour(848, 480), extrinsics, 0.00025).unwrap();
        let wide = DepthToColour::new(depth_lens, colour(1280, 720), extrinsics, 0.00025).unwrap();
        assert!(narrow.blocks && !narrow.wide && wide.blocks && wide.wide);
        let held = DepthToColour { wide: false, ..wide.clone() };
        for (name, lines) in [("848x480, 3 lines", narrow), ("1280x720, 4 lines", wide), ("1280x720, 3 lines", held)] {
            let loops = DepthToColour { blocks: false, ..lines.clone() };
            // Unturned and 180°: aligned turned 90° and turned the rest of the way.
            for rotation in [Rotation::Cw90, Rotation::Cw270, Rotation::None, Rotation::Cw180] {
                let want = run(&loops, &depth, rotation);
                assert!(want.iter().filter(|&&z| z != 0).count() > want.len() * 9 / 10, "{name} {rotation:?}");
                assert!(want[..4].iter().chain(&want[want.len() - 4..]).all(|&z| z != 0), "corners {name}");
                assert_eq!(run(&lines, &depth, rotation), want, "{name} {rotation:?}");
            }
        }
    }

    #[test]
    fn frames_after_the_first_reuse_the_turned_buffer_and_keep_nothing_of_the_last() {
        // Unturned blocks go through the turned buffer kept from frame to frame: a frame's image
        // must not depend on the frame before (near depth there, holes here), whatever the
        // rotations in between.
        let depth_lens = Lens::pinhole(96, 64, 48.0, 48.0, 47.5, 31.5);
        let colour_lens = Lens::pinhole(160, 100, 96.0, 96.0, 79.5, 49.5);
        let fresh = DepthToColour::new(depth_lens, colour_lens, translation(0.015), MM).unwrap();
        assert!(fresh.blocks);
        let mut align = fresh.clone();
        let near: Vec<u16> = vec![300; 96 * 64];
        let far: Vec<u16> = (0..96 * 64).map(|i| if i % 5 == 0 { 0 } else { 2000 + (i % 96) as u16 }).collect();
        let mut out = vec![0u16; 160 * 100];
        for rotation in [Rotation::None, Rotation::Cw180, Rotation::Cw90, Rotation::None] {
            align.align(&bytes(&near), layout(&depth_lens), Rotation::None, &mut out).unwrap();
            align.align(&bytes(&far), layout(&depth_lens), rotation, &mut out).unwrap();
            assert_eq!(out, run(&fresh, &far, rotation), "{rotation:?} after a near frame");
            assert!(out.contains(&0) && !out.contains(&300), "{rotation:?}");
        }
    }

    #[test]
    fn blocks_and_per_pixel_rectangles_write_the_same_image() {
        // Colour with 2.2 times the depth's pixels per degree: rectangle corners 2 or 3 pixels
        // apart, so both the fixed blocks (3 a side) and the fallback loop (4) are used; a near
        // box over a far wall (parallax, occlusion, shadows) and holes.
        let depth_lens = Lens::pinhole(40, 30, 30.0, 30.0, 19.5, 14.5);
        let colour_lens = Lens::pinhole(88, 66, 66.0, 66.0, 43.5, 32.5);
        let blocks = DepthToColour::new(depth_lens, colour_lens, translation(0.05), MM).unwrap();
        assert!(blocks.maps_rectangles() && blocks.blocks);
        let loops = DepthToColour { blocks: false, ..blocks.clone() };
        let depth: Vec<u16> = (0..40 * 30)
            .map(|i| {
                let (u, v) = (i % 40, i / 40);
                if i % 17 == 0 {
                    0
                } else if (12..26).contains(&u) && (8..20).contains(&v) {
                    400 + (u * 7) as u16
                } else {
                    3000 + (v * 11) as u16
                }
            })
            .collect();
        for rotation in [Rotation::None, Rotation::Cw90, Rotation::Cw180, Rotation::Cw270] {
            let want = run(&loops, &depth, rotation);
            assert!(want.iter().filter(|&&z| z != 0).count() > 70 * 50, "{rotation:?}");
            assert_eq!(run(&blocks, &depth, rotation), want, "{rotation:?}");
        }
        // The D435i's 848x480 depth to 848x480 colour (1.44 colour pixels per depth pixel):
        // blocks; nearer 1 (1.1), rectangles written by the sized loop.
        let d435i = Lens::pinhole(848, 480, 421.0, 421.0, 423.5, 239.5);
        let colour = |f: f32| Lens::pinhole(848, 480, f, f, 423.5, 239.5);
        let same = DepthToColour::new(d435i, colour(605.0), translation(0.015), MM).unwrap();
        assert!(same.maps_rectangles() && same.blocks);
        let near_one = DepthToColour::new(d435i, colour(463.0), translation(0.015), MM).unwrap();
        assert!(near_one.maps_rectangles() && !near_one.blocks);
    }

    /// A rotation by `yaw` about y then `pitch` about x (degrees).
    fn turned(yaw: f32, pitch: f32, translation_m: [f32; 3]) -> Extrinsics {
        let (sy, cy) = yaw.to_radians().sin_cos();
        let (sp, cp) = pitch.to_radians().sin_cos();
        let about_y = [[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]];
        let about_x = [[1.0, 0.0, 0.0], [0.0, cp, -sp], [0.0, sp, cp]];
        let mut rotation = [0.0; 9];
        for i in 0..3 {
            for j in 0..3 {
                rotation[3 * i + j] = (0..3).map(|k| about_x[i][k] * about_y[k][j]).sum();
            }
        }
        Extrinsics { rotation, translation_m }
    }

    /// Depth with holes, rows and whole chunks without any, a near box and a far slanted wall,
    /// from a seeded generator.
    fn scattered_depth(lens: &Lens, near: u16, far: u16, seed: u64) -> Vec<u16> {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let mut next = move || rng.random::<u64>();
        let (w, h) = (lens.width as usize, lens.height as usize);
        (0..w * h)
            .map(|i| {
                let (u, v) = (i % w, i / w);
                let spread = u64::from(far - near) + 1;
                if v % 11 == 5 || (v % 7 == 2 && u < CHUNK) || next() % 10 == 0 {
                    0
                } else if (w / 3..w / 2).contains(&u) && (h / 4..h / 2).contains(&v) {
                    near + (next() % (spread / 8 + 1)) as u16
                } else {
                    near + (spread * u as u64 / w as u64) as u16 / 2 + (next() % (spread / 2)) as u16
                }
            })
            .collect()
    }

    #[test]
    fn passing_over_chunks_that_miss_the_colour_image_changes_nothing() {
        // Calibrations where much of the depth falls outside the colour image, and where little
        // does: the D435i's (depth wider and taller than colour), a colour camera turned 25° and
        // 10° and 30 cm away, one 1 m in front of the depth camera (points behind it), a wider
        // colour camera, and a distorting depth lens (full ray tables). Each aligned with and
        // without the pass-over, all four rotations: the same image.
        let d435i = Lens::pinhole(848, 480, 421.0, 421.0, 422.75, 239.75);
        let small = Lens::pinhole(160, 96, 80.0, 80.0, 79.5, 47.5);
        let colour = |w: u32, h: u32, f: f32| {
            Lens::pinhole(w, h, f, f, (w as f32 - 1.0) / 2.0 + 0.4, (h as f32 - 1.0) / 2.0 - 0.3)
        };
        let distorting =
            Lens { model: Distortion::InverseBrownConrady, coeffs: [0.08, -0.02, 0.001, -0.002, 0.0], ..small };
        let cases = [
            ("D435i 1280x720", d435i, colour(1280, 720, 910.0), turned(0.4, 0.0, [0.015, 0.0003, -0.0002]), 300, 9000),
            ("D435i 848x480", d435i, colour(848, 480, 603.0), turned(0.4, 0.0, [0.015, 0.0003, -0.0002]), 300, 9000),
            ("turned, 30 cm", small, colour(200, 150, 220.0), turned(25.0, 10.0, [0.3, -0.1, 0.05]), 200, 2500),
            ("colour 1 m ahead", small, colour(120, 90, 100.0), turned(0.0, 0.0, [0.0, 0.0, -1.0]), 400, 4000),
            ("wider colour", small, colour(160, 96, 40.0), turned(-3.0, 2.0, [0.05, 0.0, 0.0]), 300, 6000),
            ("distorting depth", distorting, colour(320, 240, 400.0), turned(15.0, -5.0, [-0.1, 0.02, 0.0]), 250, 3000),
        ];
        let mut passed_over = 0;
        for (seed, (name, depth_lens, colour_lens, extrinsics, near, far)) in cases.into_iter().enumerate() {
            let skipping = DepthToColour::new(depth_lens, colour_lens, extrinsics, MM).unwrap();
            assert!(skipping.skips);
            let depth = scattered_depth(&depth_lens, near, far, seed as u64);
            let (w, h) = (depth_lens.width as usize, depth_lens.height as usize);
            for v in 0..h {
                for start in (0..w).step_by(CHUNK) {
                    let raw = &depth[v * w + start..v * w + (start + CHUNK).min(w)];
                    let (nearest, farthest) = (raw.iter().filter(|&&z| z != 0).min(), raw.iter().max());
                    if let (Some(&nearest), Some(&farthest)) = (nearest, farthest) {
                        let b = skipping.rays.chunk_box(v, start);
                        let [cw, ch] = [colour_lens.width, colour_lens.height];
                        let (near_m, far_m) = (f32::from(nearest) * MM, f32::from(farthest) * MM);
                        passed_over += usize::from(skipping.projection.misses(b, near_m, far_m, cw, ch));
                    }
                }
            }
            let full = DepthToColour { skips: false, ..skipping.clone() };
            for rotation in [Rotation::None, Rotation::Cw90, Rotation::Cw180, Rotation::Cw270] {
                let want = run(&full, &depth, rotation);
                assert!(want.iter().any(|&z| z != 0), "{name} {rotation:?}");
                assert_eq!(run(&skipping, &depth, rotation), want, "{name} {rotation:?}");
            }
        }
        // The D435i's rows above and below the colour image, and its chunks left and right.
        assert!(passed_over > 480 * 7 / 4, "{passed_over} chunks passed over");
    }

    #[test]
    fn a_chunk_said_to_miss_has_no_corner_on_the_colour_image() {
        // Every chunk's corner rays at depths across its range (its ends included), projected
        // as the align projects them: none of a chunk that misses lands on the image or the
        // pixel around it. The depth lens sees far wider and taller than the colour one (5
        // chunks a row across 158°); the colour camera, shifted, is turned in small steps so
        // that chunk edges sweep across all four edges of its image and barely miss.
        let depth_lens = Lens::pinhole(640, 48, 60.0, 60.0, 319.5, 23.5);
        let colour_lens = Lens::pinhole(96, 64, 110.0, 110.0, 47.3, 31.8);
        let (cw, ch) = (colour_lens.width, colour_lens.height);
        let mut tried = [0usize; 2];
        let mut sides = [false; 4];
        for step in 0..48 {
            let (yaw, pitch) = (-70.0 + 2.93 * step as f32, -9.0 + 0.41 * step as f32);
            let extrinsics = turned(yaw, pitch, [0.04 - 0.002 * step as f32, 0.01, -0.03]);
            let align = DepthToColour::new(depth_lens, colour_lens, extrinsics, MM).unwrap();
            let (rays, p) = (&align.rays, &align.projection);
            let (mut x, mut y) = ([0i32; CHUNK], [0i32; CHUNK]);
            for v in 0..48 {
                for start in (0..640).step_by(CHUNK) {
                    for (near, far) in [(300u16, 320u16), (500, 4000), (1200, 1200), (120, 9000)] {
                        let b = rays.chunk_box(v, start);
                        let misses = p.misses(b, f32::from(near) * MM, f32::from(far) * MM, cw, ch);
                        tried[usize::from(misses)] += 1;
                        if !misses {
                            continue;
                        }
                        let steps = 9u16.min(far - near + 1);
                        for i in 0..steps {
                            let z =
                                near + ((u32::from(far - near) * u32::from(i)) / u32::from((steps - 1).max(1))) as u16;
                            let raw = [z; CHUNK];
                            for (r, at) in [(v, rays.row_start(v) + start), (v + 1, rays.row_start(v + 1) + start + 1)]
                            {
                                p.corners::<false>(rays, at, rays.row[r], &raw, &mut x, &mut y);
                                for (&x, &y) in x.iter().zip(&y).filter(|&(&x, _)| x != NOWHERE) {
                                    let on = (-1..=cw as i32).contains(&x) && (-1..=ch as i32).contains(&y);
                                    assert!(!on, "turn {step} row {v} chunk {start} depth {z}: corner at ({x}, {y})");
                                    // Within 5 pixels outside a side of the image: a near miss there.
                                    let (w, h) = (cw as i32, ch as i32);
                                    let near_side = [
                                        (-5..0).contains(&x),
                                        (w + 1..=w + 5).contains(&x),
                                        (-5..0).contains(&y),
                                        (h + 1..=h + 5).contains(&y),
                                    ];
                                    for (seen, near_side) in sides.iter_mut().zip(near_side) {
                                        *seen |= near_side;
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        assert!(tried[0] > 1000 && tried[1] > 1000, "hits and misses: {tried:?}");
        assert_eq!(sides, [true; 4], "near misses left, right, above, below");
    }
}
