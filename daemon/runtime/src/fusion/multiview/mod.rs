//! [`MultiViewFusion`]: part-aware multi-view fusion as in the OP3DSG paper ("Feature Extraction" and "Multi-view 3D
//! Fusion"), built for one core at keyframe rate.
//!
//! # Per keyframe ([`MultiViewFusion::integrate`](crate::fusion::Fusion::integrate))
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
//! `cargo bench -p op3dsg-sim --bench fusion` measures a step and counts allocations.
//!
//! Files: `cloud.rs` (node point clouds), `node.rs` (one node), `index.rs` (the node index),
//! `back_projection.rs` (step 1), `maintenance.rs`, `attach.rs` (part → object in the graph),
//! `state.rs` (the map's saved form for snapshots).

use glam::{IVec3, Vec3};
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::NodeKind;
use rustc_hash::{FxHashMap, FxHashSet};

use super::change::{ChangeEvent, RemovedHistory, RemovedNode};
use super::colour::{self, ColourFeature};
use super::{Fusion, FusionConfig, FusionReport};
use crate::embedding::{dot, normalise};
use crate::flow::Detection;
use crate::graph::{GraphNode, SceneGraph};
use crate::world::OrientedBox;
use crate::world::UpAxis;

mod attach;
mod back_projection;
mod cloud;
mod evidence;
#[cfg(test)]
mod evidence_tests;
mod index;
mod maintenance;
mod node;
mod state;
#[cfg(test)]
mod tests;

pub use attach::attach_parts;
use back_projection::inside_eroded;
use cloud::{KindGeometry, NONE};
use index::NodeIndex;
use node::Node;
pub use state::{MapGeometry, MapLife, MapState, NodeState};

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

/// Part-aware multi-view fusion: detections of every keyframe associated into 3D nodes by
/// geometric, semantic and colour similarity (see the module docs).
#[derive(Debug)]
pub struct MultiViewFusion {
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
    /// Up axis of the nodes' gravity-aligned boxes.
    up_axis: UpAxis,
    /// Removed nodes (`[fusion.change] history`).
    history: RemovedHistory,
    /// Changes not yet taken ([`Fusion::take_changes`]).
    events: Vec<ChangeEvent>,
    /// Past keyframes' views, thinned (for appearances).
    views: std::collections::VecDeque<evidence::View>,
}

impl MultiViewFusion {
    /// An empty map.
    pub fn new(config: FusionConfig) -> Self {
        let object = KindGeometry::new(config.object_voxel_m, config.object_nnr_radius_m);
        let part = KindGeometry::new(config.part_voxel_m, config.part_nnr_radius_m);
        let index = NodeIndex { cell_m: config.index_cell_m, ..NodeIndex::default() };
        let history = RemovedHistory::new(config.change.history as usize);
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
            up_axis: UpAxis::Z,
            history,
            events: Vec::new(),
            views: Default::default(),
        }
    }

    /// The same map with its nodes' oriented boxes turning about `up_axis` (`world.up_axis`;
    /// +z unless set).
    pub fn with_up_axis(mut self, up_axis: UpAxis) -> Self {
        self.up_axis = up_axis;
        self
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
            node.first_seen_stamp_ns = stamp_ns;
            node.first_keyframe = keyframe;
            node.published = false;
            node.appeared = false;
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
        node.misses.count = 0;
        node.dirty = true;
        self.reindex(slot);
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

impl MultiViewFusion {
    /// Step 1: each detection back-projected into an observation (points, bounds, label; colour
    /// features of parts); detections without enough depth are ignored, counted in `report`.
    fn observe(&mut self, frame: &Frame, pose: &glam::Mat4, detections: &[Detection], report: &mut FusionReport) {
        let colour_on = self.config.colour_features;
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
            let Some((start, end, min, max)) = self.back_project(frame, pose, det) else {
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
    }

    /// Steps 2–4: the candidate nodes of each observation through the spatial index, and the
    /// pairs whose score reaches the kind's threshold.
    fn score_candidates(&mut self, detections: &[Detection]) {
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
        self.scratch.pairs = pairs;
        self.scratch.candidates = candidates;
    }

    /// Step 5: greedy one-to-one assignment, best score first (ties: lower observation, lower
    /// slot).
    fn assign_greedily(&mut self) {
        let scratch = &mut self.scratch;
        scratch.pairs.sort_unstable_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        let taken = &mut scratch.node_taken;
        taken.clear();
        taken.resize(self.nodes.len(), false);
        for &(_, o, slot) in &scratch.pairs {
            let obs = &mut scratch.observations[o as usize];
            if obs.assigned == NONE && !taken[slot as usize] {
                obs.assigned = slot;
                taken[slot as usize] = true;
            }
        }
    }

    /// Step 6: updates of the assigned nodes, then new nodes for the rest.
    fn update_and_create(&mut self, frame: &Frame, detections: &[Detection], report: &mut FusionReport) {
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
    }
}

impl Fusion for MultiViewFusion {
    fn integrate(&mut self, frame: &Frame, world_from_camera: &Isometry, detections: &[Detection]) -> FusionReport {
        let mut report = FusionReport::default();
        self.keyframe += 1;
        self.observe(frame, &world_from_camera.to_mat4(), detections, &mut report);
        self.score_candidates(detections);
        self.assign_greedily();
        self.update_and_create(frame, detections, &mut report);
        let started = std::time::Instant::now();
        self.evidence(frame, world_from_camera, detections, &mut report);
        report.evidence_ns = started.elapsed().as_nanos().min(u128::from(u64::MAX)) as u64;
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
                obb: OrientedBox::fit(&node.cloud.points, self.up_axis).unwrap_or_else(|| {
                    OrientedBox::axis_aligned(node.cloud.min.to_array(), node.cloud.max.to_array(), self.up_axis)
                }),
                observation_count: node.observation_count,
                affordance_bits: 0,
                last_seen_stamp_ns: node.last_seen_stamp_ns,
                first_seen_stamp_ns: node.first_seen_stamp_ns,
                missing: node.misses.count > 0,
                ..Default::default()
            });
        }
        out.nodes.sort_unstable_by_key(|n| n.id);
        attach_parts(out, self.config.part_attach_margin_m);
    }

    fn node_points(&self, max_per_node: usize, out: &mut Vec<super::NodePoint>) {
        for node in self.nodes.iter().filter(|n| n.alive && self.confirmed(n)) {
            let points = &node.cloud.points;
            let step = points.len().div_ceil(max_per_node.max(1)).max(1);
            out.extend(
                points.iter().step_by(step).map(|p| super::NodePoint { node_id: node.id, position_m: p.to_array() }),
            );
        }
    }

    fn node_count(&self) -> usize {
        self.alive
    }

    fn export_state(&self) -> Option<MapState> {
        Some(self.export())
    }

    fn restore_state(&mut self, state: &MapState) -> Result<(), String> {
        self.restore(state)
    }

    fn set_change_handling(&mut self, on: bool) {
        self.config.change.enabled = on;
    }

    fn take_changes(&mut self, out: &mut Vec<ChangeEvent>) {
        out.append(&mut self.events);
    }

    fn removed_nodes(&self) -> Vec<RemovedNode> {
        self.history.iter().cloned().collect()
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
