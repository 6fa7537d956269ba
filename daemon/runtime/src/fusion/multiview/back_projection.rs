//! Back-projection of a detection's mask into world points (step 1 of the module docs).

use glam::{Mat4, Vec3};
use op3dsg_drivers::frame::Frame;
use op3dsg_ipc_types::NodeKind;

use super::MultiViewFusion;
use super::cloud::{cell_of, key};
use crate::flow::{Detection, Mask};

impl MultiViewFusion {
    /// Back-projects `det` into `scratch.points` (appended, downsampled); its bounds.
    pub(super) fn back_project(
        &mut self,
        frame: &Frame,
        pose: &Mat4,
        det: &Detection,
    ) -> Option<(usize, usize, Vec3, Vec3)> {
        let c = &self.config;
        let s = &mut self.scratch;
        let k = &frame.intrinsics;
        let (erode, band) = if det.kind == NodeKind::Part {
            (c.part_mask_erode_px, c.part_depth_band_m)
        } else {
            (c.object_mask_erode_px, c.object_depth_band_m)
        };
        let m = &det.mask;
        if m.x0 + m.width > k.width || m.y0 + m.height > k.height || m.data.len() != (m.width * m.height) as usize {
            return None;
        }
        let voxel_m = if det.kind == NodeKind::Part { c.part_voxel_m } else { c.object_voxel_m };
        // Median depth of a coarse grid over the eroded mask (about 8 x 8 samples).
        let coarse = (m.width.min(m.height) / 8).max(1) as usize;
        s.sorted.clear();
        for row in (0..m.height).step_by(coarse) {
            for col in (0..m.width).step_by(coarse) {
                if inside_eroded(m, col, row, erode) {
                    let depth_m = frame.depth_m(((m.y0 + row) * k.width + m.x0 + col) as usize);
                    if depth_m >= c.min_depth_m && depth_m <= c.max_depth_m {
                        s.sorted.push(depth_m);
                    }
                }
            }
        }
        if s.sorted.is_empty() {
            return None;
        }
        let mid = s.sorted.len() / 2;
        let median = *s.sorted.select_nth_unstable_by(mid, f32::total_cmp).1;
        // Pixel stride: about `samples_per_voxel` samples per voxel edge at the median depth.
        let stride = if c.samples_per_voxel > 0 {
            let per_voxel_px = voxel_m * k.fx / median;
            ((per_voxel_px / c.samples_per_voxel as f32) as u32).clamp(c.pixel_stride.max(1), 16)
        } else {
            c.pixel_stride.max(1)
        } as usize;
        s.raw.clear();
        for row in (0..m.height).step_by(stride) {
            for col in (0..m.width).step_by(stride) {
                if !inside_eroded(m, col, row, erode) {
                    continue;
                }
                let (x, y) = (m.x0 + col, m.y0 + row);
                let depth_m = frame.depth_m((y * k.width + x) as usize);
                if !(depth_m >= c.min_depth_m && depth_m <= c.max_depth_m) || (depth_m - median).abs() > band {
                    continue;
                }
                s.raw.push(pose.transform_point3(k.point_in_camera(x as f32, y as f32, depth_m)));
            }
        }
        s.voxels.clear();
        let start = s.points.len();
        let (mut lo, mut hi) = (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY));
        let mut last = u64::MAX;
        for p in &s.raw {
            // Neighbouring pixels mostly fall in the voxel of the previous one.
            let k = key(cell_of(*p, voxel_m));
            if k == last {
                continue;
            }
            last = k;
            if s.voxels.insert(k) {
                s.points.push(*p);
                lo = lo.min(*p);
                hi = hi.max(*p);
            }
        }
        let end = s.points.len();
        if end - start < c.min_points {
            s.points.truncate(start);
            return None;
        }
        Some((start, end, lo, hi))
    }
}

/// Whether mask pixel `(col, row)` is inside and so are the 8 pixels `r` away (x, y, diagonals).
#[inline]
pub(super) fn inside_eroded(m: &Mask, col: u32, row: u32, r: u32) -> bool {
    let at = |c: i64, r_: i64| -> bool {
        c >= 0
            && r_ >= 0
            && c < i64::from(m.width)
            && r_ < i64::from(m.height)
            && m.data[(r_ as u32 * m.width + c as u32) as usize] != 0
    };
    if r > 0 && col >= r && row >= r && col + r < m.width && row + r < m.height {
        // Fully inside the box: no bounds checks needed beyond the slice's own.
        let w = m.width as usize;
        let (c, rw, r) = (col as usize, row as usize, r as usize);
        let d = &m.data;
        return d[rw * w + c] != 0
            && d[rw * w + c - r] != 0
            && d[rw * w + c + r] != 0
            && d[(rw - r) * w + c] != 0
            && d[(rw + r) * w + c] != 0
            && d[(rw - r) * w + c - r] != 0
            && d[(rw - r) * w + c + r] != 0
            && d[(rw + r) * w + c - r] != 0
            && d[(rw + r) * w + c + r] != 0;
    }
    let (c, rw, r) = (i64::from(col), i64::from(row), i64::from(r));
    if !at(c, rw) {
        return false;
    }
    if r == 0 {
        return true;
    }
    at(c - r, rw)
        && at(c + r, rw)
        && at(c, rw - r)
        && at(c, rw + r)
        && at(c - r, rw - r)
        && at(c + r, rw - r)
        && at(c - r, rw + r)
        && at(c + r, rw + r)
}
