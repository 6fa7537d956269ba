//! The z-buffer writes into the rotated output: where each colour pixel goes ([`Placement`]),
//! one rectangle with a loop sized to it ([`write_rectangle`]), or a chunk's rectangles as fixed
//! lines of [`LANES`] values ([`LinePlan`]); the nearest depth wins in every cell.

use super::CHUNK;
use super::projection::NOWHERE;
use crate::rotate::Rotation;
pub(super) use crate::unchecked::zbuffer::LANES;
use crate::unchecked::zbuffer::{nearest_lines, nearest_rectangle};

/// Where colour pixel `(x, y)` goes in the rotated output: `origin + x * step_x + y * step_y`.
#[derive(Debug, Clone, Copy)]
pub(super) struct Placement {
    pub(super) origin: isize,
    pub(super) step_x: isize,
    pub(super) step_y: isize,
    /// Whether colour x runs along the output's rows (no rotation or 180°), else colour y.
    pub(super) along_x: bool,
    /// The step along the output's rows of that axis (1 or -1) ...
    along_step: isize,
    /// ... and of the other axis.
    across_step: isize,
    /// Where a block's line of [`LANES`] values starts, from its first cell: 0 forwards, back
    /// `LANES - 1` values backwards.
    lane_offset: isize,
}

impl Placement {
    pub(super) fn new(rotation: Rotation, w: usize, h: usize) -> Self {
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

/// Writes depth `z1 + 1` into the colour pixels `xa..=xb` x `ya..=yb` (inside the colour image)
/// of the rotated `out`, the nearest winning, with a loop sized to the rectangle.
///
/// Blocks go through [`LinePlan`], with colour y along the output's rows. Along colour x,
/// 4-value lines of neighbouring depth pixels would overlap shifted by a cell or two, and each
/// load would wait on partly overlapping stores (`frame_handling` benchmark, 848x480 to 848x480
/// unturned: 2.38 ms cell by cell, 2.49 ms with such lines): unturned frames are aligned turned.
#[inline(always)]
pub(super) fn write_rectangle(out: &mut [u16], place: Placement, z1: u16, rectangle: [i32; 4]) {
    nearest_rectangle(out, [place.origin, place.step_x, place.step_y], z1, rectangle);
}

/// One chunk's depths and the colour pixels of their footprints' corners.
#[derive(Clone, Copy)]
pub(super) struct Corners<'a> {
    pub(super) raw: &'a [u16],
    pub(super) x0: &'a [i32],
    pub(super) y0: &'a [i32],
    pub(super) x1: &'a [i32],
    pub(super) y1: &'a [i32],
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
pub(super) struct LinePlan<const L: usize> {
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
    pub(super) fn new() -> Self {
        Self { at: [[0; CHUNK]; L], width: [0; CHUNK], z1: [0; CHUNK], height: [0; CHUNK], apart: [0; CHUNK] }
    }

    /// Writes one chunk's rectangles into `out` (at least [`LANES`] values, as
    /// [`DepthToColour::align`](super::DepthToColour::align) checks before choosing lines).
    #[inline(always)]
    pub(super) fn write(&mut self, c: Corners, place: Placement, cw: u32, ch: u32, out: &mut [u16]) {
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
        // Every line start lies in 0..=last_low (tested when planned, or 0); the writes check
        // the whole plan once more before they skip the test per line.
        let (z1s, heights) = (&self.z1, &self.height);
        nearest_lines(out, &self.at, n, |i| {
            let z1 = z1s[i] as u16;
            (z1 != u16::MAX).then(|| masks[(heights[i] & 3) as usize].map(|m| z1 | m))
        });
        // Most chunks leave nothing to the sized loop: one vectorised test instead of a scan.
        if self.apart[..n].iter().fold(0, |any, &apart| any | apart) == 0 {
            return;
        }
        for i in 0..n {
            if self.apart[i] != 0 {
                let clamp = |lo: i32, hi: i32, max: i32| (lo.max(0), hi.min(max - 1));
                let (xa, xb) = clamp(c.x0[i], c.x1[i], cw);
                let (ya, yb) = clamp(c.y0[i], c.y1[i], ch);
                write_leftover(out, place, c.raw[i] - 1, [xa, ya, xb, yb]);
            }
        }
    }
}

/// [`write_rectangle`] for the few rectangles a [`LinePlan`] leaves: kept out of the plan's
/// loop, whose registers it would otherwise crowd (`frame_handling` benchmark).
#[cold]
#[inline(never)]
fn write_leftover(out: &mut [u16], place: Placement, z1: u16, rectangle: [i32; 4]) {
    write_rectangle(out, place, z1, rectangle);
}
