//! The geometry of the alignment: the rays through the depth image's pixel corners, made once
//! per stream start ([`Rays`]), and per frame the projection of a chunk's corners onto the
//! colour image ([`Projection::corners`]) with the test that passes over chunks that cannot land
//! on it ([`Projection::misses`]).

use super::CHUNK;
use super::calibration::{Distortion, Extrinsics, Lens};

/// Rays through the pixel corners of the depth image, in the colour camera's orientation
/// (`R * (x_n, y_n, 1)`): the ray through corner `(u - 0.5, v - 0.5)` is `column(u) + row(v)`.
///
/// A rectilinear depth lens needs only a table per corner column (`width + 1`) and per corner
/// row (`height + 1`), since `R * (x_n, y_n, 1) = x_n R e_x + (y_n R e_y + R e_z)`; the bottom-right
/// corner of pixel `(u, v)` is the top-left corner of `(u + 1, v + 1)`. A lens with inverse
/// Brown-Conrady coefficients gets a full table per corner (rows of zeros then).
#[derive(Debug, Clone)]
pub(super) struct Rays {
    /// Per corner column (`width + 1`), or per corner (`(width + 1) * (height + 1)`) for a
    /// distorted lens: x, y, z.
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    /// Per corner row (`height + 1`): x, y, z (zeros with a full table).
    pub(super) row: Vec<[f32; 3]>,
    /// Corners per table row: `width + 1` with a full table, 0 when separable.
    pub(super) full_stride: usize,
    /// Per depth row, then per chunk of [`CHUNK`] pixels: the range of the rays through the
    /// corners of its pixels (both corners of each), for [`Projection::misses`].
    boxes: Vec<RayBox>,
    /// Chunks per depth row.
    chunks: usize,
}

/// The smallest and the largest of each component (x, y, z) of a set of rays, as the
/// projection sums them (`f32`).
#[derive(Debug, Clone, Copy)]
pub(super) struct RayBox {
    lo: [f32; 3],
    hi: [f32; 3],
}

impl Rays {
    pub(super) fn new(depth: &Lens, extrinsics: &Extrinsics) -> Self {
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
    pub(super) fn row_start(&self, v: usize) -> usize {
        v * self.full_stride
    }

    /// The range of the corner rays of depth row `v`'s chunk starting at column `start`.
    pub(super) fn chunk_box(&self, v: usize, start: usize) -> &RayBox {
        &self.boxes[v * self.chunks + start / CHUNK]
    }
}

/// A corner that does not land in front of the colour camera.
pub(super) const NOWHERE: i32 = i32::MIN;
/// Projections further out than this many pixels are nowhere (and stay exact in the rounding).
const FAR_PX: f32 = 1.0e6;
/// 1.5 * 2^23: adding and subtracting it rounds an `f32` below 2^22 to an integer, ties to even
/// (the default rounding mode; librealsense's `_mm_cvtps_epi32` rounds the same way).
const ROUND_MAGIC: f32 = 12_582_912.0;

/// `x` rounded to the nearest integer, ties to even, for `|x| < 2^22`: adding 1.5 * 2^23 leaves
/// the rounded value in the low mantissa bits.
#[inline(always)]
pub(super) fn round_to_i32(x: f32) -> i32 {
    ((x + ROUND_MAGIC).to_bits() as i32).wrapping_sub(ROUND_MAGIC.to_bits() as i32)
}

/// What the projection of one corner needs.
#[derive(Debug, Clone, Copy)]
pub(super) struct Projection {
    pub(super) metres_per_unit: f32,
    pub(super) t: [f32; 3],
    pub(super) fx: f32,
    pub(super) fy: f32,
    pub(super) ppx: f32,
    pub(super) ppy: f32,
    pub(super) coeffs: [f32; 5],
}

impl Projection {
    /// Colour pixel indices of one corner for each depth value of a chunk: the corner rays are
    /// `rays.{x,y,z}[at + i] + row`.
    #[inline(always)]
    pub(super) fn corners<const DISTORT: bool>(
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
    pub(super) fn misses(&self, b: &RayBox, near: f32, far: f32, cw: u32, ch: u32) -> bool {
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
