//! The per-frame loop: depth read chunk by chunk, chunks that cannot land on the colour image
//! passed over, corners projected, then each chunk written as the mode says; compiled for the
//! baseline and for AVX2.

use super::projection::NOWHERE;
use super::write::{Corners, LinePlan, Placement, write_rectangle};
use super::{CHUNK, DepthToColour, LINES_3, LINES_4, PIXELS};

impl DepthToColour {
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

/// [`DepthToColour::align_chunks`], compiled for the baseline and for AVX2 (picked once at run
/// time from the CPU's features). No FMA: the result must stay bit-identical to librealsense's
/// separate multiplies and adds.
#[multiversion::multiversion(targets("x86_64+avx2"))]
pub(super) fn align_rows<const DISTORT: bool, const MODE: u8>(
    align: &DepthToColour,
    depth: &[u8],
    stride_bytes: usize,
    place: Placement,
    out: &mut [u16],
) {
    align.align_chunks::<DISTORT, MODE>(depth, stride_bytes, place, out);
}
