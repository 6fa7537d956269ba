//! Part-aware multi-view fusion as in the OP3DSG paper ("Feature Extraction" and "Multi-view 3D
//! Fusion"), built for one core at keyframe rate.
//!
//! # Per keyframe ([`PaperFusion::integrate`])
//!
//! 1. **Back-projection.** Pixels of a mask whose `erode_px`-neighbourhood (probed at the 8 pixels
//!    `r` away in x, y and the diagonals) lies inside the mask are lifted through their depth, the
//!    intrinsics and the keyframe pose into the world. The median depth `z̃` of a coarse grid
//!    (about 8 x 8) over the eroded mask sets the sampling stride: about `samples_per_voxel`
//!    samples per voxel edge at `z̃`, i.e. `floor(voxel · f_x / (z̃ · samples_per_voxel))`, at
//!    least `pixel_stride` and at most 16 (a far object needs every pixel, a near wall every 8th).
//!    Depth of 0 or outside `[min_depth_m, max_depth_m]` is dropped, and so is every point further
//!    than the kind's depth band from `z̃` (mask bleed onto the background). The points
//!    are voxel-downsampled (one point per voxel: `object_voxel_m`, `part_voxel_m`). Fewer than
//!    `min_points` points: the detection is ignored.
//! 2. **Candidates.** A uniform grid over node boxes (`index_cell_m`) returns the nodes of the
//!    same kind whose box, grown by `δ`, overlaps the detection's box. The map is never scanned.
//! 3. **Similarities** against each candidate:
//!    * geometric `s^g` = nearest-neighbour ratio: the fraction of the detection's points (at most
//!      `nnr_max_points`, evenly spread) with a node point within `δ` (`object_nnr_radius_m`,
//!      `part_nnr_radius_m`). Node points live in a hash grid of cells at least `2δ` wide, so one
//!      query visits at most 8 cells. Candidates below `min_geometric_similarity` are dropped.
//!    * semantic `s^s = (f_i · f_j + 1) / 2` on L2-normalised features. A detection without a
//!      feature (a closed-vocabulary detector) uses its label instead: `s^s = 1` when the node's
//!      vote table holds that label, else 0.
//!    * colour (parts) `s^c = 1 / (1 + d^c)`, see [`super::colour`]. White balance is gray-world
//!      with gains from the whole keyframe (every 4th pixel), never from the mask alone (which
//!      would grey out a single-coloured part). The colour pixels are the eroded mask at stride 1.
//! 4. **Scores.** Objects `S^o = s^g + s^s`; parts `S^p = w_p (s^g + s^s) + (1 − w_p) s^c`. When
//!    `s^c` is not available (either side has no valid colour pixel, or `colour_features = false`,
//!    the paper's ablation) it is replaced by `(s^g + s^s) / 2`, so `S^p = (1 + w_p)/2 · (s^g + s^s)`
//!    stays on the same scale and the threshold keeps its meaning.
//! 5. **Greedy assignment.** All (detection, node) pairs at or above the kind's threshold are
//!    taken in descending score order, one detection per node and one node per detection per
//!    keyframe (two detections of one view are two things). Unassigned detections start nodes.
//! 6. **Updates.** Semantic feature: running mean, re-normalised. Points: union, voxel
//!    downsampled, at most `max_points_per_node`: a node that reaches it doubles its voxel and
//!    re-downsamples (a bed or a wardrobe keeps growing to its full extent at a coarser
//!    resolution; freezing the first points would split it into fragments).
//!    Colour: EMA with `α` then `L1` renormalised with `ε` (a node without valid colour takes the
//!    first valid observation). Observation count, label vote table, score sum, last seen.
//!
//! # Maintenance, every `maintenance_every_keyframes` keyframes
//!
//! * **Duplicate merge** (nodes changed since the last run against their neighbours): two nodes
//!   of one kind with overlapping boxes whose larger nearest-neighbour ratio (either direction,
//!   on a quarter of `nnr_max_points` samples) reaches `merge_min_overlap`, with
//!   `s^s ≥ merge_min_semantic` and, for parts with valid colour on both sides,
//!   `s^c ≥ merge_min_colour`. The node with more observations survives (ties: the older id);
//!   features are averaged by observation count, votes summed.
//! * **Outlier removal** of the points added since the last run: points with fewer than
//!   `outlier_min_neighbours` other points within `outlier_radius_voxels` voxels go (nodes under
//!   32 points are left alone).
//! * **Pruning**: unconfirmed nodes (fewer than `min_observations` detections, or a mean detector
//!   score below `min_mean_score`: detectors score their false positives low) not seen for
//!   `prune_unconfirmed_after_keyframes` keyframes are removed. Publication ([`Fusion::build_graph`])
//!   holds back unconfirmed nodes in any case.
//!
//! # Cost
//!
//! After warm-up a keyframe allocates nothing: all scratch buffers, node clouds and the index keep
//! their capacity, removed nodes' slots (with their buffers) are reused, and labels are interned.
//! `cargo bench -p op3dsg-daemon --bench fusion` measures a step and counts allocations.

use std::cmp::Ordering;

use glam::{IVec3, Mat4, Vec3};
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind};
use rustc_hash::{FxHashMap, FxHashSet};

use super::colour::{self, ColourFeature};
use super::{Fusion, FusionConfig, FusionReport};
use crate::graph::{GraphEdge, GraphNode, SceneGraph};
use crate::perception::{Detection, Mask, dot, normalise};

const NONE: u32 = u32::MAX;

/// Packs a cell coordinate (each within ±2^20) into one hash key.
#[inline]
fn key(c: IVec3) -> u64 {
    const OFFSET: i32 = 1 << 20;
    const MASK: u64 = (1 << 21) - 1;
    let x = ((c.x + OFFSET) as u64) & MASK;
    let y = ((c.y + OFFSET) as u64) & MASK;
    let z = ((c.z + OFFSET) as u64) & MASK;
    x | (y << 21) | (z << 42)
}

#[inline]
fn cell_of(p: Vec3, size: f32) -> IVec3 {
    let q = p / size;
    IVec3::new(floor_i32(q.x), floor_i32(q.y), floor_i32(q.z))
}

/// `floor` to `i32` without the libm call `f32::floor` becomes on baseline x86-64.
#[inline]
fn floor_i32(x: f32) -> i32 {
    let i = x as i32;
    i - i32::from(x < i as f32)
}

/// Geometry parameters of one node kind.
#[derive(Debug, Clone, Copy)]
struct KindGeometry {
    voxel_m: f32,
    radius_m: f32,
    /// Hash-grid cell: the smallest multiple of the voxel at least `2 δ` wide, so that voxels
    /// never straddle cells and a radius query visits at most 2 × 2 × 2 cells.
    cell_m: f32,
}

impl KindGeometry {
    fn new(voxel_m: f32, radius_m: f32) -> Self {
        let cell_m = voxel_m * (2.0 * radius_m / voxel_m).ceil().max(1.0);
        Self { voxel_m, radius_m, cell_m }
    }
}

/// A voxel-downsampled point cloud in a hash grid (per cell, a chain through `next`).
#[derive(Debug, Default, Clone)]
struct PointCloud {
    points: Vec<Vec3>,
    /// Occupied voxels (one point per voxel).
    voxels: FxHashSet<u64>,
    next: Vec<u32>,
    /// Points before this index passed the last outlier test.
    checked: usize,
    heads: FxHashMap<u64, u32>,
    min: Vec3,
    max: Vec3,
    sum: Vec3,
    /// Voxel multiplier (1, 2, 4, ...): doubles whenever the cloud reaches its point cap.
    scale: u32,
}

impl PointCloud {
    /// Empties the cloud (keeping capacity), back at the kind's own voxel size.
    fn clear(&mut self) {
        self.scale = 1;
        self.clear_points();
    }

    /// This cloud's geometry: the kind's, with the voxel scaled.
    fn geometry(&self, g: &KindGeometry) -> KindGeometry {
        if self.scale <= 1 { *g } else { KindGeometry::new(g.voxel_m * self.scale as f32, g.radius_m) }
    }

    fn clear_points(&mut self) {
        self.points.clear();
        self.voxels.clear();
        self.next.clear();
        self.heads.clear();
        self.checked = 0;
        self.min = Vec3::splat(f32::INFINITY);
        self.max = Vec3::splat(f32::NEG_INFINITY);
        self.sum = Vec3::ZERO;
    }

    fn len(&self) -> usize {
        self.points.len()
    }

    fn centre(&self) -> Vec3 {
        if self.points.is_empty() { Vec3::ZERO } else { self.sum / self.points.len() as f32 }
    }

    /// Adds `p` unless its voxel is taken; whether it was added. A cloud that reaches `cap`
    /// points doubles its voxel and re-downsamples (so a large object keeps growing in extent at
    /// a coarser resolution instead of freezing what it has seen first).
    fn insert(&mut self, p: Vec3, g: &KindGeometry, cap: usize) -> bool {
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
    fn has_neighbour(&self, p: Vec3, g: &KindGeometry) -> bool {
        self.count_neighbours(p, g, NONE, 1) >= 1
    }

    /// Doubles the voxel and keeps one point per new voxel.
    fn coarsen(&mut self, g: &KindGeometry) {
        let points = std::mem::take(&mut self.points);
        self.scale *= 2;
        self.clear_points();
        for &p in &points {
            self.insert(p, g, usize::MAX);
        }
        self.checked = self.points.len();
    }

    /// Points within `g.radius_m` of `p`, other than index `skip`, counting up to `limit`.
    fn count_neighbours(&self, p: Vec3, g: &KindGeometry, skip: u32, limit: u32) -> u32 {
        let cell_m = if self.scale <= 1 { g.cell_m } else { self.geometry(g).cell_m };
        self.count_within(p, g.radius_m, cell_m, skip, limit)
    }

    /// Points within `radius` of `p` (grid cells of `cell_m`), other than index `skip`,
    /// counting up to `limit`. With `radius <= cell_m / 2` it visits at most 2 x 2 x 2 cells.
    fn count_within(&self, p: Vec3, radius: f32, cell_m: f32, skip: u32, limit: u32) -> u32 {
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

    fn count_in_cell(&self, cell: IVec3, p: Vec3, r2: f32, skip: u32, limit: u32) -> u32 {
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
    fn nnr(&self, points: &[Vec3], g: &KindGeometry, max_points: usize) -> f32 {
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
    fn rebuild(&mut self, g: &KindGeometry, scratch: &mut Vec<Vec3>) {
        scratch.clear();
        scratch.extend_from_slice(&self.points);
        self.clear_points();
        for &p in scratch.iter() {
            self.insert(p, g, usize::MAX);
        }
        self.checked = self.points.len();
    }

    fn heap_bytes(&self) -> usize {
        self.points.capacity() * size_of::<Vec3>()
            + self.voxels.capacity() * (size_of::<u64>() + 1)
            + self.next.capacity() * size_of::<u32>()
            + self.heads.capacity() * (size_of::<(u64, u32)>() + 1)
    }
}

/// One node of the map.
#[derive(Debug, Clone)]
struct Node {
    id: u32,
    kind: NodeKind,
    alive: bool,
    cloud: PointCloud,
    /// Running mean of the semantic features, L2-normalised; empty when none was given.
    semantic: Vec<f32>,
    colour: ColourFeature,
    /// (label id, count).
    votes: Vec<(u32, u32)>,
    score_sum: f32,
    observation_count: u32,
    last_keyframe: u64,
    last_seen_stamp_ns: u64,
    /// Index cells the node is registered in (inclusive range).
    cells: (IVec3, IVec3),
    /// Changed since the last maintenance.
    dirty: bool,
}

impl Node {
    fn empty() -> Self {
        Self {
            id: 0,
            kind: NodeKind::Object,
            alive: false,
            cloud: PointCloud::default(),
            semantic: Vec::new(),
            colour: ColourFeature::default(),
            votes: Vec::new(),
            score_sum: 0.0,
            observation_count: 0,
            last_keyframe: 0,
            last_seen_stamp_ns: 0,
            cells: (IVec3::ZERO, IVec3::NEG_ONE),
            dirty: false,
        }
    }

    fn vote(&mut self, label: u32, count: u32) {
        match self.votes.iter_mut().find(|(l, _)| *l == label) {
            Some((_, c)) => *c += count,
            None => self.votes.push((label, count)),
        }
    }

    fn has_label(&self, label: u32) -> bool {
        self.votes.iter().any(|(l, _)| *l == label)
    }

    fn heap_bytes(&self) -> usize {
        self.cloud.heap_bytes()
            + self.semantic.capacity() * size_of::<f32>()
            + self.votes.capacity() * size_of::<(u32, u32)>()
    }
}

/// Uniform grid over node boxes: cell → node slots whose (grown) box touches it.
#[derive(Debug, Default)]
struct NodeIndex {
    cell_m: f32,
    cells: FxHashMap<u64, Vec<u32>>,
    /// Per slot, the query stamp that last returned it (dedupe without a set).
    marks: Vec<u32>,
    stamp: u32,
}

impl NodeIndex {
    fn range(&self, min: Vec3, max: Vec3) -> (IVec3, IVec3) {
        (cell_of(min, self.cell_m), cell_of(max, self.cell_m))
    }

    fn for_cells(range: (IVec3, IVec3), mut f: impl FnMut(IVec3)) {
        for x in range.0.x..=range.1.x {
            for y in range.0.y..=range.1.y {
                for z in range.0.z..=range.1.z {
                    f(IVec3::new(x, y, z));
                }
            }
        }
    }

    fn insert(&mut self, slot: u32, range: (IVec3, IVec3)) {
        Self::for_cells(range, |c| self.cells.entry(key(c)).or_default().push(slot));
    }

    fn remove(&mut self, slot: u32, range: (IVec3, IVec3)) {
        Self::for_cells(range, |c| {
            if let Some(list) = self.cells.get_mut(&key(c))
                && let Some(at) = list.iter().position(|s| *s == slot)
            {
                list.swap_remove(at);
            }
        });
    }

    /// Slots whose cells touch the box `[min, max]`, each once, into `out`.
    fn query(&mut self, min: Vec3, max: Vec3, out: &mut Vec<u32>) {
        out.clear();
        self.stamp = self.stamp.wrapping_add(1);
        if self.stamp == 0 {
            self.marks.fill(0);
            self.stamp = 1;
        }
        let range = self.range(min, max);
        let (cells, marks, stamp) = (&self.cells, &mut self.marks, self.stamp);
        Self::for_cells(range, |c| {
            if let Some(list) = cells.get(&key(c)) {
                for &slot in list {
                    let mark = &mut marks[slot as usize];
                    if *mark != stamp {
                        *mark = stamp;
                        out.push(slot);
                    }
                }
            }
        });
    }

    fn heap_bytes(&self) -> usize {
        self.cells.capacity() * (size_of::<(u64, Vec<u32>)>() + 1)
            + self.cells.values().map(|v| v.capacity() * size_of::<u32>()).sum::<usize>()
            + self.marks.capacity() * size_of::<u32>()
    }
}

/// One detection of the current keyframe after back-projection.
#[derive(Debug, Clone, Copy)]
struct Observation {
    detection: usize,
    kind: NodeKind,
    label: u32,
    /// Range in `scratch.points`.
    start: usize,
    end: usize,
    min: Vec3,
    max: Vec3,
    /// Slot it was assigned to.
    assigned: u32,
}

/// Buffers reused by every keyframe.
#[derive(Debug, Default)]
struct Scratch {
    raw: Vec<Vec3>,
    sorted: Vec<f32>,
    voxels: FxHashSet<u64>,
    points: Vec<Vec3>,
    observations: Vec<Observation>,
    colours: Vec<ColourFeature>,
    candidates: Vec<u32>,
    pairs: Vec<(f32, u32, u32)>,
    node_taken: Vec<bool>,
    rebuild: Vec<Vec3>,
    order: Vec<u32>,
}

/// The paper's fusion (see the module docs).
#[derive(Debug)]
pub struct PaperFusion {
    config: FusionConfig,
    object: KindGeometry,
    part: KindGeometry,
    nodes: Vec<Node>,
    free: Vec<u32>,
    alive: usize,
    index: NodeIndex,
    labels: Vec<String>,
    label_ids: FxHashMap<String, u32>,
    next_id: u32,
    keyframe: u64,
    scratch: Scratch,
}

impl PaperFusion {
    /// An empty map.
    pub fn new(config: FusionConfig) -> Self {
        let object = KindGeometry::new(config.object_voxel_m, config.object_nnr_radius_m);
        let part = KindGeometry::new(config.part_voxel_m, config.part_nnr_radius_m);
        let index = NodeIndex { cell_m: config.index_cell_m, ..NodeIndex::default() };
        Self {
            config,
            object,
            part,
            nodes: Vec::new(),
            free: Vec::new(),
            alive: 0,
            index,
            labels: Vec::new(),
            label_ids: FxHashMap::default(),
            next_id: 1,
            keyframe: 0,
            scratch: Scratch::default(),
        }
    }

    fn geometry(&self, kind: NodeKind) -> KindGeometry {
        if kind == NodeKind::Part { self.part } else { self.object }
    }

    fn label_id(&mut self, label: &str) -> u32 {
        if let Some(&id) = self.label_ids.get(label) {
            return id;
        }
        let id = self.labels.len() as u32;
        self.labels.push(label.to_owned());
        self.label_ids.insert(label.to_owned(), id);
        id
    }

    /// Back-projects `det` into `scratch.points` (appended, downsampled); its bounds.
    fn back_project(&mut self, frame: &Frame, pose: &Mat4, det: &Detection) -> Option<(usize, usize, Vec3, Vec3)> {
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

    /// `s^s` between a detection and a node.
    fn semantic_similarity(&self, det: &Detection, label: u32, node: &Node) -> f32 {
        match det.semantic_feature.as_deref() {
            Some(f) if f.len() == node.semantic.len() && !f.is_empty() => (dot(f, &node.semantic) + 1.0) * 0.5,
            _ => {
                if node.has_label(label) {
                    1.0
                } else {
                    0.0
                }
            }
        }
    }

    /// `S^o` or `S^p`; `None` when the candidate fails the geometric gate.
    fn score(&self, obs: &Observation, det: &Detection, colour_feature: &ColourFeature, node: &Node) -> Option<f32> {
        let g = self.geometry(obs.kind);
        let points = &self.scratch.points[obs.start..obs.end];
        let s_g = node.cloud.nnr(points, &g, self.config.nnr_max_points);
        if s_g <= 0.0 || s_g < self.config.min_geometric_similarity {
            return None;
        }
        let s_s = self.semantic_similarity(det, obs.label, node);
        Some(match obs.kind {
            NodeKind::Part => self.part_score(s_g + s_s, colour_feature, &node.colour),
            _ => s_g + s_s,
        })
    }

    /// `S^p = w_p x + (1 − w_p) s^c` with `x = s^g + s^s` (see the module docs for a missing `s^c`).
    fn part_score(&self, x: f32, a: &ColourFeature, b: &ColourFeature) -> f32 {
        let w = self.config.part_weight;
        let s_c = self
            .config
            .colour_features
            .then(|| colour::colour_similarity(a, b, &self.config.colour))
            .flatten()
            .unwrap_or(x * 0.5);
        w * x + (1.0 - w) * s_c
    }

    fn threshold(&self, kind: NodeKind) -> f32 {
        if kind == NodeKind::Part { self.config.part_match_threshold } else { self.config.object_match_threshold }
    }

    /// A slot for a new node (reusing a removed node's buffers when there is one).
    fn allocate_slot(&mut self) -> u32 {
        if let Some(slot) = self.free.pop() {
            return slot;
        }
        self.nodes.push(Node::empty());
        self.index.marks.push(0);
        (self.nodes.len() - 1) as u32
    }

    /// Re-registers a node in the index when its box moved to other cells.
    fn reindex(&mut self, slot: u32) {
        let node = &self.nodes[slot as usize];
        let grow = Vec3::splat(self.geometry(node.kind).radius_m);
        let range = self.index.range(node.cloud.min - grow, node.cloud.max + grow);
        let old = node.cells;
        if range != old {
            self.index.remove(slot, old);
            self.index.insert(slot, range);
            self.nodes[slot as usize].cells = range;
        }
    }

    fn remove_node(&mut self, slot: u32) {
        let node = &mut self.nodes[slot as usize];
        node.alive = false;
        let cells = node.cells;
        node.cells = (IVec3::ZERO, IVec3::NEG_ONE);
        self.index.remove(slot, cells);
        self.free.push(slot);
        self.alive -= 1;
    }

    /// Applies observation `o` to node `slot` (a new node when `create`).
    fn apply(&mut self, o: usize, slot: u32, create: bool, det: &Detection, stamp_ns: u64) {
        let obs = self.scratch.observations[o];
        let g = self.geometry(obs.kind);
        let cap = self.config.max_points_per_node;
        let alpha_params = self.config.colour;
        let keyframe = self.keyframe;
        let node = &mut self.nodes[slot as usize];
        if create {
            node.id = self.next_id;
            self.next_id += 1;
            node.kind = obs.kind;
            node.alive = true;
            node.cloud.clear();
            node.semantic.clear();
            node.colour = ColourFeature::default();
            node.votes.clear();
            node.score_sum = 0.0;
            node.observation_count = 0;
            node.cells = (IVec3::ZERO, IVec3::NEG_ONE);
            self.alive += 1;
        }
        for &p in &self.scratch.points[obs.start..obs.end] {
            node.cloud.insert(p, &g, cap);
        }
        if let Some(f) = det.semantic_feature.as_deref() {
            if node.semantic.is_empty() && node.observation_count == 0 {
                node.semantic.extend_from_slice(f);
            } else if node.semantic.len() == f.len() {
                let n = node.observation_count as f32;
                for (a, b) in node.semantic.iter_mut().zip(f) {
                    *a = *a * n + b;
                }
                normalise(&mut node.semantic);
            }
        }
        if obs.kind == NodeKind::Part {
            let new = &self.scratch.colours[o];
            if new.is_valid() {
                if node.colour.is_valid() {
                    node.colour.ema_update(new, &alpha_params);
                } else {
                    node.colour.clone_from(new);
                }
            }
        }
        node.vote(obs.label, 1);
        node.score_sum += det.score;
        node.observation_count += 1;
        node.last_keyframe = keyframe;
        node.last_seen_stamp_ns = stamp_ns;
        node.dirty = true;
        self.reindex(slot);
    }

    /// Duplicate merge, outlier removal and pruning (see the module docs).
    fn maintain(&mut self, report: &mut FusionReport) {
        let prune_after = u64::from(self.config.prune_unconfirmed_after_keyframes);
        // Pruning.
        if prune_after > 0 {
            for slot in 0..self.nodes.len() as u32 {
                let n = &self.nodes[slot as usize];
                if n.alive && !self.confirmed(n) && self.keyframe.saturating_sub(n.last_keyframe) >= prune_after {
                    self.remove_node(slot);
                    report.pruned += 1;
                }
            }
        }
        // Outlier removal.
        if self.config.outlier_min_neighbours > 0 {
            let need = self.config.outlier_min_neighbours;
            for slot in 0..self.nodes.len() {
                let n = &self.nodes[slot];
                if !n.alive || n.cloud.len() < 32 || n.cloud.checked == n.cloud.len() {
                    continue;
                }
                let g = self.geometry(n.kind);
                let node = &mut self.nodes[slot];
                let own = node.cloud.geometry(&g);
                let (radius, cell_m) = (own.voxel_m * self.config.outlier_radius_voxels, own.cell_m);
                let keep = &mut self.scratch.rebuild;
                keep.clear();
                // Only points added since the last test: older points only gain neighbours.
                let from = node.cloud.checked;
                let mut removed = false;
                keep.extend_from_slice(&node.cloud.points[..from]);
                for (i, p) in node.cloud.points.iter().enumerate().skip(from) {
                    if node.cloud.count_within(*p, radius, cell_m, i as u32, need) >= need {
                        keep.push(*p);
                    } else {
                        removed = true;
                    }
                }
                if removed && !keep.is_empty() {
                    std::mem::swap(&mut node.cloud.points, keep);
                    node.cloud.rebuild(&g, keep);
                    self.reindex(slot as u32);
                } else {
                    node.cloud.checked = node.cloud.len();
                }
            }
        }
        // Duplicate merge. A pair neither of whose nodes changed since the last run was already
        // checked, so only changed nodes are visited: the cost follows what the robot sees, not
        // the map's size. Most observations first, so small fragments fold into established
        // nodes.
        let mut order = std::mem::take(&mut self.scratch.order);
        order.clear();
        order.extend((0..self.nodes.len() as u32).filter(|&s| {
            let n = &self.nodes[s as usize];
            n.alive && n.dirty
        }));
        order.sort_unstable_by(|&a, &b| {
            let (na, nb) = (&self.nodes[a as usize], &self.nodes[b as usize]);
            nb.observation_count.cmp(&na.observation_count).then(na.id.cmp(&nb.id))
        });
        let mut candidates = std::mem::take(&mut self.scratch.candidates);
        for &a in &order {
            if !self.nodes[a as usize].alive {
                continue;
            }
            let node = &self.nodes[a as usize];
            let g = self.geometry(node.kind);
            let grow = Vec3::splat(g.radius_m);
            self.index.query(node.cloud.min - grow, node.cloud.max + grow, &mut candidates);
            for &b in &candidates {
                if b == a {
                    continue;
                }
                let (na, nb) = (&self.nodes[a as usize], &self.nodes[b as usize]);
                if !nb.alive || nb.kind != na.kind || !boxes_touch(na, nb, g.radius_m) {
                    continue;
                }
                // Survivor: more observations, then the older id.
                let (keep, gone) = if (nb.observation_count, std::cmp::Reverse(nb.id))
                    > (na.observation_count, std::cmp::Reverse(na.id))
                {
                    (b, a)
                } else {
                    (a, b)
                };
                if self.should_merge(keep, gone) {
                    self.merge_nodes(keep, gone);
                    report.maintenance_merged += 1;
                    if gone == a {
                        break;
                    }
                }
            }
        }
        self.scratch.candidates = candidates;
        for &slot in &order {
            self.nodes[slot as usize].dirty = false;
        }
        self.scratch.order = order;
    }

    /// The cheap tests (semantics, colour) first; the nearest-neighbour ratios last.
    fn should_merge(&self, a: u32, b: u32) -> bool {
        let (na, nb) = (&self.nodes[a as usize], &self.nodes[b as usize]);
        let semantic = if !na.semantic.is_empty() && na.semantic.len() == nb.semantic.len() {
            (dot(&na.semantic, &nb.semantic) + 1.0) * 0.5
        } else {
            let (la, _) = top_vote(&na.votes);
            if nb.has_label(la) { 1.0 } else { 0.0 }
        };
        if semantic < self.config.merge_min_semantic {
            return false;
        }
        if na.kind == NodeKind::Part
            && self.config.colour_features
            && let Some(s_c) = colour::colour_similarity(&na.colour, &nb.colour, &self.config.colour)
            && s_c < self.config.merge_min_colour
        {
            return false;
        }
        let g = self.geometry(na.kind);
        // A yes/no decision at a ratio of 0.5 needs far fewer samples than scoring does.
        let max_points = (self.config.nnr_max_points / 4).max(16);
        let overlap = nb.cloud.nnr(&na.cloud.points, &g, max_points);
        overlap >= self.config.merge_min_overlap
            || na.cloud.nnr(&nb.cloud.points, &g, max_points) >= self.config.merge_min_overlap
    }

    /// Folds node `gone` into node `keep`.
    fn merge_nodes(&mut self, keep: u32, gone: u32) {
        let (k, g_) = (keep as usize, gone as usize);
        let mut taken = std::mem::replace(&mut self.nodes[g_], Node::empty());
        let g = self.geometry(taken.kind);
        let cap = self.config.max_points_per_node;
        let node = &mut self.nodes[k];
        for &p in &taken.cloud.points {
            node.cloud.insert(p, &g, cap);
        }
        let (nk, ng) = (node.observation_count as f32, taken.observation_count as f32);
        if node.semantic.len() == taken.semantic.len() && !node.semantic.is_empty() {
            for (a, b) in node.semantic.iter_mut().zip(&taken.semantic) {
                *a = *a * nk + b * ng;
            }
            normalise(&mut node.semantic);
        } else if node.semantic.is_empty() {
            std::mem::swap(&mut node.semantic, &mut taken.semantic);
        }
        if taken.colour.is_valid() {
            if node.colour.is_valid() {
                let w = ng / (nk + ng);
                blend(&mut node.colour, &taken.colour, w, self.config.colour.ema_epsilon);
            } else {
                node.colour.clone_from(&taken.colour);
            }
        }
        for &(label, count) in &taken.votes {
            node.vote(label, count);
        }
        node.score_sum += taken.score_sum;
        node.observation_count += taken.observation_count;
        node.last_keyframe = node.last_keyframe.max(taken.last_keyframe);
        node.last_seen_stamp_ns = node.last_seen_stamp_ns.max(taken.last_seen_stamp_ns);
        node.dirty = true;
        // Put the (dead) node back so its buffers are reused by the next new node.
        taken.alive = true;
        self.nodes[g_] = taken;
        self.remove_node(gone);
        self.reindex(keep);
    }

    /// Published: seen `min_observations` times with a mean score of at least `min_mean_score`.
    fn confirmed(&self, node: &Node) -> bool {
        node.observation_count >= self.config.min_observations
            && node.score_sum >= self.config.min_mean_score * node.observation_count as f32
    }

    fn label_of(&self, node: &Node) -> (&str, u32) {
        // Highest count; ties go to the lexically smallest label (deterministic).
        let mut best: Option<(&str, u32)> = None;
        for &(label, count) in &node.votes {
            let name = self.labels[label as usize].as_str();
            let better = match best {
                None => true,
                Some((bn, bc)) => count > bc || (count == bc && name < bn),
            };
            if better {
                best = Some((name, count));
            }
        }
        best.unwrap_or(("", 0))
    }
}

impl Fusion for PaperFusion {
    fn integrate(&mut self, frame: &Frame, world_from_camera: &Isometry, detections: &[Detection]) -> FusionReport {
        let mut report = FusionReport::default();
        self.keyframe += 1;
        let pose = world_from_camera.to_mat4();
        let colour_on = self.config.colour_features;

        // 1. Back-projection (and colour features of parts).
        let any_part = detections.iter().any(|d| d.kind == NodeKind::Part);
        let gains = if colour_on && any_part {
            let (w, h) = (frame.intrinsics.width as usize, frame.intrinsics.height as usize);
            // Gray-world means from every 4th pixel of every 4th row.
            colour::white_balance_gains(
                &frame.rgb,
                (0..h).step_by(4).flat_map(|y| (0..w).step_by(4).map(move |x| y * w + x)),
            )
        } else {
            [1.0; 3]
        };
        self.scratch.points.clear();
        self.scratch.observations.clear();
        if self.scratch.colours.len() < detections.len() {
            self.scratch.colours.resize(detections.len(), ColourFeature::default());
        }
        for (i, det) in detections.iter().enumerate() {
            let Some((start, end, min, max)) = self.back_project(frame, &pose, det) else {
                report.ignored += 1;
                continue;
            };
            let label = self.label_id(&det.label);
            let o = self.scratch.observations.len();
            if det.kind == NodeKind::Part && colour_on {
                let erode = self.config.part_mask_erode_px;
                let width = frame.intrinsics.width;
                let m = &det.mask;
                let pixels = (0..m.height).flat_map(move |row| {
                    (0..m.width).filter_map(move |col| {
                        inside_eroded(m, col, row, erode).then_some(((m.y0 + row) * width + m.x0 + col) as usize)
                    })
                });
                colour::extract(&frame.rgb, pixels, gains, &self.config.colour, &mut self.scratch.colours[o]);
            } else {
                self.scratch.colours[o].valid_pixels = 0;
            }
            self.scratch.observations.push(Observation {
                detection: i,
                kind: det.kind,
                label,
                start,
                end,
                min,
                max,
                assigned: NONE,
            });
        }

        // 2–4. Candidates and scores.
        let mut pairs = std::mem::take(&mut self.scratch.pairs);
        let mut candidates = std::mem::take(&mut self.scratch.candidates);
        pairs.clear();
        for o in 0..self.scratch.observations.len() {
            let obs = self.scratch.observations[o];
            let grow = Vec3::splat(self.geometry(obs.kind).radius_m);
            self.index.query(obs.min - grow, obs.max + grow, &mut candidates);
            let det = &detections[obs.detection];
            for &slot in &candidates {
                let node = &self.nodes[slot as usize];
                if !node.alive
                    || node.kind != obs.kind
                    || obs.max.cmplt(node.cloud.min - grow).any()
                    || obs.min.cmpgt(node.cloud.max + grow).any()
                {
                    continue;
                }
                if let Some(score) = self.score(&obs, det, &self.scratch.colours[o], node)
                    && score >= self.threshold(obs.kind)
                {
                    pairs.push((score, o as u32, slot));
                }
            }
        }

        // 5. Greedy one-to-one assignment, best score first (ties: lower observation, lower slot).
        pairs.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        let taken = &mut self.scratch.node_taken;
        taken.clear();
        taken.resize(self.nodes.len(), false);
        for &(_, o, slot) in &pairs {
            let obs = &mut self.scratch.observations[o as usize];
            if obs.assigned == NONE && !taken[slot as usize] {
                obs.assigned = slot;
                taken[slot as usize] = true;
            }
        }
        self.scratch.pairs = pairs;
        self.scratch.candidates = candidates;

        // 6. Updates, then new nodes.
        for o in 0..self.scratch.observations.len() {
            let obs = self.scratch.observations[o];
            if obs.assigned != NONE {
                self.apply(o, obs.assigned, false, &detections[obs.detection], frame.stamp_ns);
                report.merged += 1;
            }
        }
        for o in 0..self.scratch.observations.len() {
            let obs = self.scratch.observations[o];
            if obs.assigned == NONE {
                let slot = self.allocate_slot();
                self.apply(o, slot, true, &detections[obs.detection], frame.stamp_ns);
                report.created += 1;
            }
        }

        let every = u64::from(self.config.maintenance_every_keyframes);
        if every > 0 && self.keyframe.is_multiple_of(every) {
            self.maintain(&mut report);
        }
        report
    }

    fn build_graph(&self, out: &mut SceneGraph) {
        out.nodes.clear();
        out.edges.clear();
        for node in self.nodes.iter().filter(|n| n.alive && self.confirmed(n)) {
            let (label, votes) = self.label_of(node);
            let n = node.observation_count as f32;
            let confidence = (votes as f32 / n) * (node.score_sum / n);
            out.nodes.push(GraphNode {
                id: node.id,
                kind: node.kind,
                parent_id: None,
                label: label.to_owned(),
                confidence: confidence.clamp(0.0, 1.0),
                centre_m: node.cloud.centre().to_array(),
                box_min_m: node.cloud.min.to_array(),
                box_max_m: node.cloud.max.to_array(),
                observation_count: node.observation_count,
                affordance_bits: 0,
                last_seen_stamp_ns: node.last_seen_stamp_ns,
            });
        }
        out.nodes.sort_unstable_by_key(|n| n.id);
        attach_parts(out, self.config.part_attach_margin_m);
    }

    fn node_count(&self) -> usize {
        self.alive
    }

    fn memory_bytes(&self) -> usize {
        let nodes: usize = self.nodes.iter().map(Node::heap_bytes).sum();
        nodes
            + self.nodes.capacity() * size_of::<Node>()
            + self.free.capacity() * size_of::<u32>()
            + self.index.heap_bytes()
            + self.labels.iter().map(|l| 2 * l.capacity()).sum::<usize>()
            + self.label_ids.capacity() * (size_of::<(String, u32)>() + 1)
    }
}

/// Whether mask pixel `(col, row)` is inside and so are the 8 pixels `r` away (x, y, diagonals).
#[inline]
fn inside_eroded(m: &Mask, col: u32, row: u32, r: u32) -> bool {
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

fn boxes_touch(a: &Node, b: &Node, grow: f32) -> bool {
    let g = Vec3::splat(grow);
    !(a.cloud.max.cmplt(b.cloud.min - g).any() || a.cloud.min.cmpgt(b.cloud.max + g).any())
}

fn top_vote(votes: &[(u32, u32)]) -> (u32, u32) {
    votes.iter().copied().max_by(|a, b| a.1.cmp(&b.1).then(b.0.cmp(&a.0))).unwrap_or((NONE, 0))
}

/// `a ← (1 − w) a + w b`, each histogram L1-renormalised with `ε`.
fn blend(a: &mut ColourFeature, b: &ColourFeature, w: f32, epsilon: f32) {
    fn mix(x: &mut [f32], y: &[f32], w: f32, epsilon: f32) {
        let mut sum = 0.0;
        for (p, q) in x.iter_mut().zip(y) {
            *p = (1.0 - w) * *p + w * q;
            sum += *p;
        }
        for p in x.iter_mut() {
            *p /= sum + epsilon;
        }
    }
    mix(&mut a.cn, &b.cn, w, epsilon);
    mix(&mut a.ab, &b.ab, w, epsilon);
    mix(&mut a.opp, &b.opp, w, epsilon);
    a.valid_pixels = a.valid_pixels.saturating_add(b.valid_pixels);
}

/// Sets each part's parent and adds its `part of` edge: among objects whose box, grown by
/// `margin_m`, contains the part's centre, one whose label is contained in the part's label
/// ("cabinet handle" → cabinet) wins, then the nearest.
pub fn attach_parts(graph: &mut SceneGraph, margin_m: f32) {
    let objects: Vec<(u32, String, Vec3, Vec3)> = graph
        .nodes
        .iter()
        .filter(|n| n.kind == NodeKind::Object)
        .map(|n| (n.id, n.label.clone(), Vec3::from(n.box_min_m), Vec3::from(n.box_max_m)))
        .collect();
    for part in graph.nodes.iter_mut().filter(|n| n.kind == NodeKind::Part) {
        let centre = Vec3::from(part.centre_m);
        let mut best: Option<(bool, f32, u32)> = None;
        for (id, label, lo, hi) in &objects {
            let gap = (*lo - centre).max(centre - *hi).max(Vec3::ZERO).length();
            if gap > margin_m {
                continue;
            }
            let lexical = !label.is_empty() && part.label.contains(label.as_str());
            let better = match best {
                None => true,
                Some((bl, bg, _)) => (lexical && !bl) || (lexical == bl && gap.total_cmp(&bg) == Ordering::Less),
            };
            if better {
                best = Some((lexical, gap, *id));
            }
        }
        if let Some((_, _, object_id)) = best {
            part.parent_id = Some(object_id);
            graph.edges.push(GraphEdge {
                source_id: part.id,
                target_id: object_id,
                kind: EdgeKind::Spatial,
                relation_id: 0,
                confidence: part.confidence,
                origin: EdgeOrigin::Geometry,
            });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use op3dsg_drivers::frame::Intrinsics;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn config() -> FusionConfig {
        crate::config::load(None, &[]).expect("built-in profile").profile.fusion
    }

    /// A frame looking at a grey wall `depth_mm` away (64 x 48 pixels, f = 60).
    fn wall_frame(depth_mm: u16) -> Frame {
        let k = Intrinsics { width: 64, height: 48, fx: 60.0, fy: 60.0, cx: 32.0, cy: 24.0 };
        let mut frame = Frame::new(k);
        frame.depth.fill(depth_mm);
        frame.rgb.fill(128);
        frame
    }

    fn paint(frame: &mut Frame, x0: u32, y0: u32, size: u32, rgb: [u8; 3]) {
        for y in y0..y0 + size {
            for x in x0..x0 + size {
                let i = ((y * frame.intrinsics.width + x) * 3) as usize;
                frame.rgb[i..i + 3].copy_from_slice(&rgb);
            }
        }
    }

    fn square(label: &str, kind: NodeKind, x0: u32, y0: u32, size: u32) -> Detection {
        Detection {
            label: label.into(),
            kind,
            score: 0.9,
            mask: Mask { x0, y0, width: size, height: size, data: vec![1; (size * size) as usize] },
            semantic_feature: None,
        }
    }

    fn dense() -> FusionConfig {
        FusionConfig {
            pixel_stride: 1,
            object_mask_erode_px: 0,
            part_mask_erode_px: 0,
            object_voxel_m: 0.01,
            object_nnr_radius_m: 0.01,
            part_voxel_m: 0.005,
            part_nnr_radius_m: 0.005,
            maintenance_every_keyframes: 0,
            ..config()
        }
    }

    #[test]
    fn nnr_on_constructed_point_sets() {
        let g = KindGeometry::new(0.01, 0.01);
        assert!((g.cell_m - 0.02).abs() < 1e-6, "cell is the smallest voxel multiple >= 2 delta");
        let mut cloud = PointCloud::default();
        cloud.clear();
        // A 10 x 10 grid of points 1 cm apart (voxel centres) on z = 0.
        for i in 0..10 {
            for j in 0..10 {
                assert!(cloud.insert(Vec3::new(0.005 + 0.01 * i as f32, 0.005 + 0.01 * j as f32, 0.0), &g, 1000));
            }
        }
        assert_eq!(cloud.len(), 100);
        // Same voxel again: refused.
        assert!(!cloud.insert(Vec3::new(0.006, 0.006, 0.0005), &g, 1000));
        // 6 points 5 mm above grid points (neighbours), 3 points 5 cm above, 1 point 1.1 cm beside.
        let mut probe: Vec<Vec3> = (0..6).map(|i| Vec3::new(0.005 + 0.01 * i as f32, 0.025, 0.005)).collect();
        probe.extend((0..3).map(|i| Vec3::new(0.005 + 0.01 * i as f32, 0.025, 0.05)));
        probe.push(Vec3::new(0.095 + 0.011, 0.055, 0.0));
        assert!((cloud.nnr(&probe, &g, 256) - 0.6).abs() < 1e-6);
        // Subsampled to 5 points (every 2nd): indices 0, 2, 4 hit, 6, 8 miss.
        assert!((cloud.nnr(&probe, &g, 5) - 0.6).abs() < 1e-6);
        assert_eq!(cloud.nnr(&[], &g, 256), 0.0);
        // Within delta inclusive.
        assert!(cloud.has_neighbour(Vec3::new(0.005, 0.005, 0.0099), &g));
        assert!(!cloud.has_neighbour(Vec3::new(0.005, 0.005, -0.0101), &g));
    }

    #[test]
    fn grid_neighbour_query_agrees_with_brute_force() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        for (voxel, radius) in [(0.005, 0.01), (0.025, 0.025), (0.01, 0.004), (0.02, 0.05)] {
            let g = KindGeometry::new(voxel, radius);
            let mut cloud = PointCloud::default();
            cloud.clear();
            for _ in 0..2000 {
                let p =
                    Vec3::new(rng.random_range(-0.2..0.2), rng.random_range(-0.2..0.2), rng.random_range(-0.05..0.05));
                cloud.insert(p, &g, usize::MAX);
            }
            for _ in 0..2000 {
                let p = Vec3::new(
                    rng.random_range(-0.25..0.25),
                    rng.random_range(-0.25..0.25),
                    rng.random_range(-0.1..0.1),
                );
                let brute = cloud.points.iter().filter(|q| q.distance_squared(p) <= radius * radius).count() as u32;
                assert_eq!(
                    cloud.count_neighbours(p, &g, NONE, u32::MAX),
                    brute,
                    "voxel {voxel} radius {radius} at {p}"
                );
            }
        }
    }

    #[test]
    fn voxel_downsampling_and_the_point_cap() {
        let g = KindGeometry::new(0.01, 0.01);
        let mut cloud = PointCloud::default();
        cloud.clear();
        for i in 0..100 {
            // 100 points within one voxel.
            cloud.insert(Vec3::new(0.001 + 0.00008 * i as f32, 0.0051, 0.0052), &g, 1000);
        }
        assert_eq!(cloud.len(), 1);
        for i in 0..100 {
            cloud.insert(Vec3::new(0.015 + 0.01 * i as f32, 0.0, 0.0), &g, 10);
        }
        // A 1 m line of 1 cm voxels under a cap of 10: the voxel grows to 16 cm, the extent stays.
        assert!(cloud.len() <= 10, "{}", cloud.len());
        assert_eq!(cloud.scale, 16);
        assert!(cloud.max.x > 0.9 && cloud.min.x < 0.01, "{} {}", cloud.min, cloud.max);
        for i in 0..100 {
            let p = Vec3::new(0.015 + 0.01 * i as f32, 0.0, 0.0);
            assert!(cloud.points.iter().any(|q| q.distance(p) <= 0.16), "coverage at {p}");
        }
    }

    #[test]
    fn repeated_views_fuse_and_distinct_places_do_not() {
        let mut fusion = PaperFusion::new(dense());
        let frame = wall_frame(2000);
        let pose = Isometry::IDENTITY;
        fusion.integrate(&frame, &pose, &[square("cabinet", NodeKind::Object, 10, 10, 12)]);
        let r = fusion.integrate(&frame, &pose, &[square("cabinet", NodeKind::Object, 11, 10, 12)]);
        assert_eq!((r.merged, r.created), (1, 0));
        // A synonym without features: s^s = 0, s^g alone cannot reach 1.1.
        let r = fusion.integrate(&frame, &pose, &[square("cupboard", NodeKind::Object, 10, 10, 12)]);
        assert_eq!((r.merged, r.created), (0, 1));
        let r = fusion.integrate(&frame, &pose, &[square("cabinet", NodeKind::Object, 40, 10, 12)]);
        assert_eq!((r.merged, r.created), (0, 1));
        assert_eq!(fusion.node_count(), 3);
        let mut graph = SceneGraph::default();
        fusion.build_graph(&mut graph);
        // Only the node seen twice is confirmed (min_observations = 2).
        assert_eq!(graph.nodes.len(), 1);
        assert_eq!(graph.nodes[0].label, "cabinet");
        assert_eq!(graph.nodes[0].observation_count, 2);
        assert!((graph.nodes[0].centre_m[2] - 2.0).abs() < 1e-3);
    }

    #[test]
    fn low_scoring_nodes_are_held_back_and_pruned() {
        let mut fusion = PaperFusion::new(FusionConfig {
            maintenance_every_keyframes: 1,
            prune_unconfirmed_after_keyframes: 2,
            ..dense()
        });
        let frame = wall_frame(2000);
        let mut weak = square("kettle", NodeKind::Object, 10, 10, 12);
        weak.score = 0.3;
        for _ in 0..3 {
            fusion.integrate(&frame, &Isometry::IDENTITY, std::slice::from_ref(&weak));
        }
        let mut graph = SceneGraph::default();
        fusion.build_graph(&mut graph);
        assert!(graph.nodes.is_empty(), "seen 3 times, mean score 0.3 < 0.5");
        assert_eq!(fusion.node_count(), 1);
        let pruned: u32 = (0..2).map(|_| fusion.integrate(&frame, &Isometry::IDENTITY, &[]).pruned).sum();
        assert_eq!((pruned, fusion.node_count()), (1, 0));
    }

    #[test]
    fn semantic_features_let_synonyms_fuse() {
        let mut fusion = PaperFusion::new(dense());
        let frame = wall_frame(2000);
        let feature = |v: [f32; 2]| Some(v.to_vec());
        let mut a = square("cabinet", NodeKind::Object, 10, 10, 12);
        a.semantic_feature = feature([1.0, 0.0]);
        let mut b = square("cupboard", NodeKind::Object, 11, 10, 12);
        b.semantic_feature = feature([0.8, 0.6]); // s^s = 0.9
        let mut c = square("stove", NodeKind::Object, 10, 11, 12);
        c.semantic_feature = feature([-1.0, 0.0]); // s^s ≈ 0
        fusion.integrate(&frame, &Isometry::IDENTITY, &[a]);
        let r = fusion.integrate(&frame, &Isometry::IDENTITY, &[b]);
        assert_eq!(r.merged, 1);
        let r = fusion.integrate(&frame, &Isometry::IDENTITY, &[c]);
        assert_eq!(r.created, 1);
        // Running mean, re-normalised: (1, 0) + (0.8, 0.6) → (0.949, 0.316).
        let node = fusion.nodes.iter().find(|n| n.observation_count == 2).unwrap();
        assert!((node.semantic[0] - 0.9487).abs() < 1e-3 && (node.semantic[1] - 0.3162).abs() < 1e-3);
    }

    /// Two knobs with one label, one red and one blue, side by side on a wall; the second view
    /// sees the blue knob where its mask half-overlaps the red knob's points.
    fn two_knobs(colour_features: bool, second: [u8; 3]) -> usize {
        let mut fusion = PaperFusion::new(FusionConfig { colour_features, ..dense() });
        let mut frame = wall_frame(1000);
        paint(&mut frame, 20, 20, 8, [200, 40, 40]);
        fusion.integrate(&frame, &Isometry::IDENTITY, &[square("knob", NodeKind::Part, 20, 20, 8)]);
        let mut frame = wall_frame(1000);
        paint(&mut frame, 24, 20, 8, second);
        fusion.integrate(&frame, &Isometry::IDENTITY, &[square("knob", NodeKind::Part, 24, 20, 8)]);
        fusion.node_count()
    }

    #[test]
    fn colour_keeps_apart_parts_that_geometry_and_semantics_would_merge() {
        let blue = [40, 40, 200];
        let red = [200, 40, 40];
        assert_eq!(two_knobs(true, blue), 2, "different colours stay apart");
        assert_eq!(two_knobs(true, red), 1, "same colour merges");
        assert_eq!(two_knobs(false, blue), 1, "without colour they merge");
    }

    #[test]
    fn part_score_formula() {
        let fusion = PaperFusion::new(config());
        let mut red = ColourFeature::default();
        red.cn[8] = 1.0;
        red.ab[0] = 1.0;
        red.opp[0] = 1.0;
        red.valid_pixels = 10;
        let mut blue = ColourFeature::default();
        blue.cn[1] = 1.0;
        blue.ab[1] = 1.0;
        blue.opp[1] = 1.0;
        blue.valid_pixels = 10;
        // Identical colour: s^c = 1 → 0.4 x + 0.6.
        assert!((fusion.part_score(1.5, &red, &red) - (0.4 * 1.5 + 0.6)).abs() < 1e-6);
        // Disjoint: d^c = 1, s^c = 0.5.
        assert!((fusion.part_score(1.5, &red, &blue) - (0.4 * 1.5 + 0.3)).abs() < 1e-6);
        // No colour on one side: s^c := x / 2.
        assert!((fusion.part_score(1.5, &red, &ColourFeature::default()) - 0.7 * 1.5).abs() < 1e-6);
    }

    #[test]
    fn one_detection_per_node_per_keyframe() {
        let mut fusion = PaperFusion::new(dense());
        let frame = wall_frame(2000);
        fusion.integrate(&frame, &Isometry::IDENTITY, &[square("cabinet", NodeKind::Object, 10, 10, 12)]);
        let both = [square("cabinet", NodeKind::Object, 10, 10, 12), square("cabinet", NodeKind::Object, 12, 10, 12)];
        let r = fusion.integrate(&frame, &Isometry::IDENTITY, &both);
        assert_eq!((r.merged, r.created), (1, 1));
        // Objects never match parts.
        let r = fusion.integrate(&frame, &Isometry::IDENTITY, &[square("cabinet", NodeKind::Part, 10, 10, 12)]);
        assert_eq!((r.merged, r.created), (0, 1));
    }

    #[test]
    fn maintenance_merges_duplicates_and_prunes_stale_candidates() {
        let mut fusion = PaperFusion::new(FusionConfig {
            maintenance_every_keyframes: 1,
            prune_unconfirmed_after_keyframes: 3,
            ..dense()
        });
        let frame = wall_frame(2000);
        // One keyframe sees the same surface twice: two nodes (one detection per node per keyframe).
        let twice = [square("cabinet", NodeKind::Object, 10, 10, 12), square("cabinet", NodeKind::Object, 10, 10, 12)];
        let r = fusion.integrate(&frame, &Isometry::IDENTITY, &twice);
        assert_eq!(r.created, 2);
        assert_eq!(r.maintenance_merged, 1, "maintenance folds the duplicate in");
        assert_eq!(fusion.node_count(), 1);
        assert_eq!(fusion.nodes.iter().find(|n| n.alive).unwrap().observation_count, 2);
        // A stray candidate elsewhere, then three keyframes without it: pruned.
        fusion.integrate(&frame, &Isometry::IDENTITY, &[square("kettle", NodeKind::Object, 40, 30, 10)]);
        assert_eq!(fusion.node_count(), 2);
        let mut pruned = 0;
        for _ in 0..3 {
            pruned += fusion.integrate(&frame, &Isometry::IDENTITY, &[]).pruned;
        }
        assert_eq!(pruned, 1);
        assert_eq!(fusion.node_count(), 1);
        // The freed slot is reused.
        fusion.integrate(&frame, &Isometry::IDENTITY, &[square("kettle", NodeKind::Object, 40, 30, 10)]);
        assert_eq!(fusion.nodes.len(), 2);
    }

    #[test]
    fn outlier_removal_drops_isolated_points() {
        let mut fusion = PaperFusion::new(FusionConfig { maintenance_every_keyframes: 1, ..dense() });
        let mut frame = wall_frame(500);
        // One pixel of the mask sees a surface 20 cm nearer (within the depth band).
        frame.depth[(15 * 64 + 15) as usize] = 300;
        fusion.integrate(&frame, &Isometry::IDENTITY, &[square("cabinet", NodeKind::Object, 10, 10, 12)]);
        let node = fusion.nodes.iter().find(|n| n.alive).unwrap();
        assert!(node.cloud.len() > 50, "{}", node.cloud.len());
        assert!(node.cloud.points.iter().all(|p| (p.z - 0.5).abs() < 0.01), "the stray point is gone");
        assert!((node.cloud.min.z - 0.5).abs() < 0.01);
    }

    #[test]
    fn eroded_masks_lose_their_border() {
        let m = Mask { x0: 0, y0: 0, width: 5, height: 5, data: vec![1; 25] };
        let inside: usize =
            (0..5).flat_map(|r| (0..5).map(move |c| (c, r))).filter(|&(c, r)| inside_eroded(&m, c, r, 1)).count();
        assert_eq!(inside, 9);
        assert!(inside_eroded(&m, 0, 0, 0));
        assert!(!inside_eroded(&m, 2, 2, 3));
    }
}
