//! Node point clouds: voxel-downsampled points in a hash grid for nearest-neighbour queries,
//! and the cell arithmetic they share with the node index.

use glam::{IVec3, Vec3};
use rustc_hash::{FxHashMap, FxHashSet};

pub(super) const NONE: u32 = u32::MAX;

/// Packs a cell coordinate (each within ±2^20) into one hash key.
#[inline]
pub(super) fn key(c: IVec3) -> u64 {
    const OFFSET: i32 = 1 << 20;
    const MASK: u64 = (1 << 21) - 1;
    let x = ((c.x + OFFSET) as u64) & MASK;
    let y = ((c.y + OFFSET) as u64) & MASK;
    let z = ((c.z + OFFSET) as u64) & MASK;
    x | (y << 21) | (z << 42)
}

#[inline]
pub(super) fn cell_of(p: Vec3, size: f32) -> IVec3 {
    let q = p / size;
    IVec3::new(floor_i32(q.x), floor_i32(q.y), floor_i32(q.z))
}

/// `floor` to `i32` without the libm call `f32::floor` becomes on baseline x86-64.
#[inline]
pub(super) fn floor_i32(x: f32) -> i32 {
    let i = x as i32;
    i - i32::from(x < i as f32)
}

/// Geometry parameters of one node kind.
#[derive(Debug, Clone, Copy)]
pub(super) struct KindGeometry {
    pub(super) voxel_m: f32,
    pub(super) radius_m: f32,
    /// Hash-grid cell: the smallest multiple of the voxel at least `2 δ` wide, so that voxels
    /// never straddle cells and a radius query visits at most 2 × 2 × 2 cells.
    pub(super) cell_m: f32,
}

impl KindGeometry {
    pub(super) fn new(voxel_m: f32, radius_m: f32) -> Self {
        let cell_m = voxel_m * (2.0 * radius_m / voxel_m).ceil().max(1.0);
        Self { voxel_m, radius_m, cell_m }
    }
}

/// A voxel-downsampled point cloud in a hash grid (per cell, a chain through `next`).
#[derive(Debug, Default, Clone)]
pub(super) struct PointCloud {
    pub(super) points: Vec<Vec3>,
    /// Occupied voxels (one point per voxel).
    pub(super) voxels: FxHashSet<u64>,
    pub(super) next: Vec<u32>,
    /// Points before this index passed the last outlier test.
    pub(super) checked: usize,
    pub(super) heads: FxHashMap<u64, u32>,
    pub(super) min: Vec3,
    pub(super) max: Vec3,
    pub(super) sum: Vec3,
    /// Voxel multiplier (1, 2, 4, ...): doubles whenever the cloud reaches its point cap.
    pub(super) scale: u32,
}

impl PointCloud {
    /// Empties the cloud (keeping capacity), back at the kind's own voxel size.
    pub(super) fn clear(&mut self) {
        self.scale = 1;
        self.clear_points();
    }

    /// This cloud's geometry: the kind's, with the voxel scaled.
    pub(super) fn geometry(&self, g: &KindGeometry) -> KindGeometry {
        if self.scale <= 1 { *g } else { KindGeometry::new(g.voxel_m * self.scale as f32, g.radius_m) }
    }

    pub(super) fn clear_points(&mut self) {
        self.points.clear();
        self.voxels.clear();
        self.next.clear();
        self.heads.clear();
        self.checked = 0;
        self.min = Vec3::splat(f32::INFINITY);
        self.max = Vec3::splat(f32::NEG_INFINITY);
        self.sum = Vec3::ZERO;
    }

    pub(super) fn len(&self) -> usize {
        self.points.len()
    }

    pub(super) fn centre(&self) -> Vec3 {
        if self.points.is_empty() { Vec3::ZERO } else { self.sum / self.points.len() as f32 }
    }

    /// Adds `p` unless its voxel is taken; whether it was added. A cloud that reaches `cap`
    /// points doubles its voxel and re-downsamples (so a large object keeps growing in extent at
    /// a coarser resolution instead of freezing what it has seen first).
    pub(super) fn insert(&mut self, p: Vec3, g: &KindGeometry, cap: usize) -> bool {
        while self.points.len() >= cap && self.scale < 1 << 12 {
            self.coarsen(g);
        }
        if self.points.len() >= cap {
            return false;
        }
        let g = &self.geometry(g);
        if !self.voxels.insert(key(cell_of(p, g.voxel_m))) {
            return false;
        }
        let index = self.points.len() as u32;
        let head = self.heads.entry(key(cell_of(p, g.cell_m))).or_insert(NONE);
        self.next.push(*head);
        *head = index;
        self.points.push(p);
        self.min = self.min.min(p);
        self.max = self.max.max(p);
        self.sum += p;
        true
    }

    /// Whether some point lies within `g.radius_m` of `p` (`skip`: a point index to ignore).
    pub(super) fn has_neighbour(&self, p: Vec3, g: &KindGeometry) -> bool {
        self.count_neighbours(p, g, NONE, 1) >= 1
    }

    /// Doubles the voxel and keeps one point per new voxel.
    pub(super) fn coarsen(&mut self, g: &KindGeometry) {
        let points = std::mem::take(&mut self.points);
        self.scale *= 2;
        self.clear_points();
        for &p in &points {
            self.insert(p, g, usize::MAX);
        }
        self.checked = self.points.len();
    }

    /// Points within `g.radius_m` of `p`, other than index `skip`, counting up to `limit`.
    pub(super) fn count_neighbours(&self, p: Vec3, g: &KindGeometry, skip: u32, limit: u32) -> u32 {
        let cell_m = if self.scale <= 1 { g.cell_m } else { self.geometry(g).cell_m };
        self.count_within(p, g.radius_m, cell_m, skip, limit)
    }

    /// Points within `radius` of `p` (grid cells of `cell_m`), other than index `skip`,
    /// counting up to `limit`. With `radius <= cell_m / 2` it visits at most 2 x 2 x 2 cells.
    pub(super) fn count_within(&self, p: Vec3, radius: f32, cell_m: f32, skip: u32, limit: u32) -> u32 {
        let r2 = radius * radius;
        let lo = cell_of(p - Vec3::splat(radius), cell_m);
        let hi = cell_of(p + Vec3::splat(radius), cell_m);
        // The point's own cell first: most hits are there.
        let own = cell_of(p, cell_m);
        let mut found = self.count_in_cell(own, p, r2, skip, limit);
        if found >= limit {
            return found;
        }
        for x in lo.x..=hi.x {
            for y in lo.y..=hi.y {
                for z in lo.z..=hi.z {
                    let c = IVec3::new(x, y, z);
                    if c != own {
                        found += self.count_in_cell(c, p, r2, skip, limit - found);
                        if found >= limit {
                            return found;
                        }
                    }
                }
            }
        }
        found
    }

    pub(super) fn count_in_cell(&self, cell: IVec3, p: Vec3, r2: f32, skip: u32, limit: u32) -> u32 {
        let Some(&head) = self.heads.get(&key(cell)) else { return 0 };
        let mut found = 0;
        let mut i = head;
        while i != NONE {
            if i != skip && self.points[i as usize].distance_squared(p) <= r2 {
                found += 1;
                if found >= limit {
                    break;
                }
            }
            i = self.next[i as usize];
        }
        found
    }

    /// Fraction of `points` (at most `max_points`, evenly spread) with a neighbour here.
    pub(super) fn nnr(&self, points: &[Vec3], g: &KindGeometry, max_points: usize) -> f32 {
        if points.is_empty() || self.points.is_empty() {
            return 0.0;
        }
        let step = points.len().div_ceil(max_points.max(1));
        let mut tested = 0u32;
        let mut hits = 0u32;
        for p in points.iter().step_by(step) {
            tested += 1;
            if self.has_neighbour(*p, g) {
                hits += 1;
            }
        }
        hits as f32 / tested as f32
    }

    /// Rebuilds the grid and bounds from `self.points` after points were removed.
    pub(super) fn rebuild(&mut self, g: &KindGeometry, scratch: &mut Vec<Vec3>) {
        scratch.clear();
        scratch.extend_from_slice(&self.points);
        self.clear_points();
        for &p in scratch.iter() {
            self.insert(p, g, usize::MAX);
        }
        self.checked = self.points.len();
    }

    pub(super) fn heap_bytes(&self) -> usize {
        self.points.capacity() * size_of::<Vec3>()
            + self.voxels.capacity() * (size_of::<u64>() + 1)
            + self.next.capacity() * size_of::<u32>()
            + self.heads.capacity() * (size_of::<(u64, u32)>() + 1)
    }
}
