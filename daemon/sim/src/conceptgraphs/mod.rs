//! [`ConceptGraphsFusion`]: the association and merging of ConceptGraphs (Gu et al., "ConceptGraphs:
//! Open-Vocabulary 3D Scene Graphs for Perception and Planning", ICRA 2024), as their code does
//! it (`conceptgraph/slam/utils.py`, `slam/mapping.py`: `compute_spatial_similarities`,
//! `compute_visual_similarities`, `aggregate_similarities`, `match_detections_to_objects`,
//! `merge_obj_matches`, `denoise_objects`, `filter_objects`, `merge_overlap_objects`; defaults of
//! `hydra_configs/base_mapping.yaml`). It is a peer baseline for the benchmarks: the same
//! keyframes and detections go to it and to [`super::multiview::MultiViewFusion`], and its
//! graph feeds the same reasoner.
//!
//! # What their code does, and this module follows
//!
//! * **Detections** (`gobs_to_detection_list` / `filter_gobs`): a mask is skipped when its area
//!   is under `mask_area_threshold` (25 px), its confidence under `mask_conf_threshold` (0.25),
//!   its 2D box larger than `max_bbox_area_ratio` (0.5) of the image, or (`skip_bg`) its class is
//!   a background class (wall, floor, ceiling). Every mask pixel with depth > 0 is lifted
//!   (`create_object_pcd`; no erosion, no depth band), and a detection with fewer than
//!   `max(min_points_threshold, 4)` (16) points is skipped. The cloud is voxel-downsampled at
//!   `downsample_voxel_size` (2.5 cm; Open3D's `voxel_down_sample`: one point per voxel, the mean
//!   of its points) and denoised by DBSCAN (`pcd_denoise_dbscan`, below). A detection whose box
//!   has no volume (< 1e-6 m³) is skipped (so is a noise-free planar patch facing a world axis,
//!   as theirs would be).
//! * **Spatial similarity** (`compute_overlap_matrix_2set`, `spatial_sim_type = "overlap"`): for
//!   each (object, detection) pair whose 3D boxes have an IoU > 0, the fraction of the
//!   detection's points whose nearest object point is closer than the voxel size (their
//!   `D < downsample_voxel_size²` on faiss' squared distances); 0 otherwise. Nearest neighbours
//!   come from a `kiddo` kd-tree per object (their code builds a flat faiss index each frame;
//!   the result is the same, exact nearest neighbour).
//! * **Visual similarity** (`compute_visual_similarities`): cosine of the detection's CLIP
//!   feature and the object's, in [−1, 1].
//! * **Aggregation** (`aggregate_similarities`, `match_method = "sim_sum"`):
//!   `sim = (1 + phys_bias) · spatial + (1 − phys_bias) · visual`, `phys_bias = 0`; pairs below
//!   `sim_threshold` (1.2) are set to −∞.
//! * **Assignment** (`match_detections_to_objects`): each detection independently takes its
//!   highest-scoring object, or starts a new object when every score is −∞. Several detections
//!   of one keyframe may join one object (their code allows it; ours does not).
//! * **Merge of a detection into an object** (`merge_obj_matches` → `merge_obj2_into_obj1`,
//!   `run_dbscan = False`): point union, voxel-downsampled again; box recomputed; the CLIP
//!   feature becomes the detection-count-weighted mean, L2-normalised; detection count, class
//!   list and confidences appended.
//! * **Periodic post-processing**, counted in keyframes (their frames): `denoise_objects` every
//!   `denoise_interval` (20): each object's cloud is voxel-downsampled and DBSCAN-denoised
//!   (`dbscan_eps` 0.1 m, `dbscan_min_points` 10: the largest cluster is kept, noise dropped,
//!   unless that cluster has fewer than 5 points; a result under 4 points keeps the old cloud).
//!   `merge_overlap_objects` every `merge_interval`: object pairs with box IoU > 0 whose overlap
//!   ratio (fraction of one's points within a voxel of the other's) exceeds
//!   `merge_overlap_thresh` (0.7), in descending overlap order, merge when the visual cosine and
//!   the text cosine both exceed 0.7 (`merge_visual_sim_thresh`, `merge_text_sim_thresh`); the
//!   merge runs DBSCAN. `filter_objects` every `filter_interval` (−1 = never during the run):
//!   objects with fewer than `obj_min_points` (0) points or `obj_min_detections` (3) detections go.
//! * **The final frame** (`run_denoise_final_frame`, `run_filter_final_frame`,
//!   `run_merge_final_frame`, all true): [`Fusion::build_graph`] publishes the map after a
//!   denoise, a filter and a merge, run on a copy (so publishing does not change the map, and a
//!   live daemon gets at every publication what their run gives at its end).
//! * **Label**: the most common class of the object's detections (their `class_name` vote).
//!
//! # Where this differs, and why
//!
//! * **`merge_interval = 20`** where `base_mapping.yaml` has −1 (merge at the end only): the
//!   published algorithm merges periodically, and their real-time configurations do (5 in
//!   `rerun_realtime_mapping.yaml`, 20 in their launch scripts). The final merge runs in any case.
//! * **Semantic feature**: ConceptGraphs uses CLIP image crops for the visual feature and the
//!   CLIP text feature of the class for the text feature. Here both are the detection's own
//!   `semantic_feature`, the one the OP3DSG fusion uses (the detector's; no CLIP image encoder is
//!   available to this project). A detection without one uses its label: cosine 1 when the
//!   object's class votes hold the label, else 0.
//! * **Kinds**: ConceptGraphs has no parts. The same detector gives objects and parts here, and
//!   by default ConceptGraphs' association runs within each kind (an object detection only
//!   joins objects, a part only parts), so it can be scored on parts at all;
//!   `associate_across_kinds = true` runs it class-agnostic over both, as their code does, and
//!   a node then takes its detections' majority kind. Parts attach to objects as in OP3DSG
//!   ([`super::multiview::attach_parts`]).
//! * **IoU gate**: their code uses the IoU of oriented boxes (`compute_3d_iou_accurate_batch`,
//!   falling back to axis-aligned boxes on a degenerate box); here axis-aligned boxes are used
//!   throughout. Only whether the IoU is > 0 matters, and an axis-aligned box contains the
//!   oriented one, so a few more pairs pass the gate; the nearest-neighbour ratio decides.
//!   Published nodes carry the same gravity-aligned oriented box fit as OP3DSG's.
//! * **`obj_pcd_max_points` (5000)**: an object cloud above it keeps an evenly spread subset
//!   (their code downsamples randomly to about that many); deterministic for the benchmarks.
//! * **Confidence** (ConceptGraphs has none per object): the same formula as OP3DSG's, the
//!   share of the winning label's votes times the mean detector score, so the reasoner treats
//!   both alike.
//!
//! # Cost
//!
//! Every mask pixel is lifted and every object is compared with every detection (an
//! axis-aligned box test, then the kd-tree), as in their code; there is no spatial index. The
//! kd-tree of an object is rebuilt when its points change.

use std::sync::Arc;

use glam::Vec3;
use kiddo::SquaredEuclidean;
use kiddo::immutable::float::kdtree::ImmutableKdTree;
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::NodeKind;
use op3dsg_runtime::embedding::{dot, normalise};
use op3dsg_runtime::flow::Detection;
use op3dsg_runtime::fusion::{Fusion, FusionReport, multiview::attach_parts};
use op3dsg_runtime::graph::{GraphNode, NodePoint, SceneGraph};
use op3dsg_runtime::world::{OrientedBox, UpAxis};
use rustc_hash::FxHashMap;

mod backend;
mod config;
#[cfg(test)]
mod tests;

pub use backend::{CONCEPTGRAPHS_FUSION, ConceptGraphsBackend};
pub use config::ConceptGraphsConfig;

/// The kd-tree over an object's points.
type Tree = ImmutableKdTree<f32, u32, 3, 32>;

/// The peer baseline's row: ConceptGraphs' association and merging
/// (this module) in place of OP3DSG's fusion, on the full row's
/// keyframes and detections, reasoned by the same reasoner.
pub const PEER_ROW: &str = "peer: ConceptGraphs fusion";

/// The peer baseline's fusion for `profile`: ConceptGraphs' defaults, with the profile's up axis
/// and part attachment margin (the published graph is built like OP3DSG's).
pub fn peer_fusion(profile: &op3dsg_runtime::config::Profile) -> Box<dyn Fusion> {
    let config = ConceptGraphsConfig {
        part_attach_margin_m: profile.fusion.part_attach_margin_m,
        ..ConceptGraphsConfig::default()
    };
    Box::new(ConceptGraphsFusion::new(config).with_up_axis(profile.world.up_axis))
}

/// Their `bg_classes`.
const BACKGROUND_CLASSES: [&str; 3] = ["wall", "floor", "ceiling"];

/// One map object (their object dict).
#[derive(Debug, Clone)]
struct Object {
    id: u32,
    points: Vec<Vec3>,
    min: Vec3,
    max: Vec3,
    /// L2-normalised mean feature (empty: none seen).
    feature: Vec<f32>,
    num_detections: u32,
    /// Detections of each kind (object, part).
    kinds: [u32; 2],
    /// Class votes.
    labels: Vec<(String, u32)>,
    score_sum: f32,
    last_seen_stamp_ns: u64,
    tree: Option<Arc<Tree>>,
}

impl Object {
    fn kind(&self) -> NodeKind {
        if self.kinds[1] > self.kinds[0] { NodeKind::Part } else { NodeKind::Object }
    }

    fn has_label(&self, label: &str) -> bool {
        self.labels.iter().any(|(l, _)| l == label)
    }

    fn set_points(&mut self, points: Vec<Vec3>) {
        let (min, max) = bounds(&points);
        self.points = points;
        self.min = min;
        self.max = max;
        self.tree = None;
    }

    fn tree(&mut self) -> &Tree {
        if self.tree.is_none() {
            let pts: Vec<[f32; 3]> = self.points.iter().map(|p| p.to_array()).collect();
            self.tree = Some(Arc::new(Tree::new_from_slice(&pts)));
        }
        self.tree.as_deref().expect("tree set just above")
    }

    fn label(&self) -> (&str, u32) {
        let mut best: Option<(&str, u32)> = None;
        for (label, count) in &self.labels {
            if best.is_none_or(|(bl, bc)| *count > bc || (*count == bc && label.as_str() < bl)) {
                best = Some((label, *count));
            }
        }
        best.unwrap_or(("", 0))
    }

    fn heap_bytes(&self) -> usize {
        self.points.capacity() * size_of::<Vec3>()
            + self.feature.capacity() * 4
            + self.labels.iter().map(|(l, _)| l.capacity() + size_of::<(String, u32)>()).sum::<usize>()
            + self.tree.as_ref().map_or(0, |_| self.points.len() * (size_of::<[f32; 3]>() + 4))
    }
}

/// A detection after lifting and processing.
struct Candidate {
    detection: usize,
    kind: NodeKind,
    points: Vec<Vec3>,
    min: Vec3,
    max: Vec3,
}

/// ConceptGraphs' association and merging (see the module docs).
#[derive(Debug, Clone)]
pub struct ConceptGraphsFusion {
    config: ConceptGraphsConfig,
    objects: Vec<Object>,
    next_id: u32,
    keyframe: u64,
    up_axis: UpAxis,
}

impl ConceptGraphsFusion {
    /// An empty map.
    pub fn new(config: ConceptGraphsConfig) -> Self {
        Self { config, objects: Vec::new(), next_id: 1, keyframe: 0, up_axis: UpAxis::Z }
    }

    /// The same map with published boxes turning about `up_axis`.
    pub fn with_up_axis(mut self, up_axis: UpAxis) -> Self {
        self.up_axis = up_axis;
        self
    }

    /// Lifts, downsamples and denoises one detection (`gobs_to_detection_list`); `None` when a
    /// filter drops it.
    fn lift(&self, frame: &Frame, pose: &glam::Mat4, index: usize, det: &Detection) -> Option<Candidate> {
        let c = &self.config;
        let k = &frame.intrinsics;
        let m = &det.mask;
        if m.x0 + m.width > k.width || m.y0 + m.height > k.height || m.data.len() != (m.width * m.height) as usize {
            return None;
        }
        if m.area() < c.mask_area_threshold_px || det.score < c.mask_conf_threshold {
            return None;
        }
        if (m.width * m.height) as f32 > c.max_bbox_area_ratio * (k.width * k.height) as f32 {
            return None;
        }
        if c.skip_bg && BACKGROUND_CLASSES.contains(&det.label.as_str()) {
            return None;
        }
        let mut raw = Vec::new();
        for row in 0..m.height {
            for col in 0..m.width {
                if m.data[(row * m.width + col) as usize] == 0 {
                    continue;
                }
                let (x, y) = (m.x0 + col, m.y0 + row);
                let depth_m = frame.depth_m((y * k.width + x) as usize);
                if depth_m > 0.0 && depth_m.is_finite() {
                    raw.push(pose.transform_point3(k.point_in_camera(x as f32, y as f32, depth_m)));
                }
            }
        }
        if raw.len() < c.min_points_threshold.max(4) {
            return None;
        }
        let points = self.process(voxel_down_sample(&raw, c.voxel_m), true);
        let (min, max) = bounds(&points);
        let extent = max - min;
        if points.is_empty() || extent.x * extent.y * extent.z < 1e-6 {
            return None;
        }
        Some(Candidate { detection: index, kind: det.kind, points, min, max })
    }

    /// Their `process_pcd` after a downsample: the point cap, then DBSCAN when asked.
    fn process(&self, mut points: Vec<Vec3>, run_dbscan: bool) -> Vec<Vec3> {
        let c = &self.config;
        if c.obj_pcd_max_points > 0 && points.len() > c.obj_pcd_max_points {
            let step = points.len().div_ceil(c.obj_pcd_max_points);
            points = points.into_iter().step_by(step).collect();
        }
        if run_dbscan && c.dbscan_remove_noise {
            points = dbscan_largest_cluster(points, c.dbscan_eps_m, c.dbscan_min_points);
        }
        points
    }

    fn visual(&self, det: &Detection, object: &Object) -> f32 {
        match det.semantic_feature.as_deref() {
            Some(f) if !f.is_empty() && f.len() == object.feature.len() => dot(f, &object.feature),
            _ => {
                if object.has_label(&det.label) {
                    1.0
                } else {
                    0.0
                }
            }
        }
    }

    fn same_association(&self, a: NodeKind, b: NodeKind) -> bool {
        self.config.associate_across_kinds || a == b
    }

    /// `merge_obj2_into_obj1` of a detection.
    fn merge_detection(&mut self, slot: usize, cand: Candidate, det: &Detection, stamp_ns: u64) {
        let voxel = self.config.voxel_m;
        let mut points = std::mem::take(&mut self.objects[slot].points);
        points.extend_from_slice(&cand.points);
        let points = self.process(voxel_down_sample(&points, voxel), false);
        let object = &mut self.objects[slot];
        object.set_points(points);
        if let Some(f) = det.semantic_feature.as_deref()
            && !f.is_empty()
        {
            if object.feature.len() == f.len() {
                let n = object.num_detections as f32;
                for (a, b) in object.feature.iter_mut().zip(f) {
                    *a = (*a * n + b) / (n + 1.0);
                }
                normalise(&mut object.feature);
            } else if object.feature.is_empty() {
                object.feature = f.to_vec();
            }
        }
        add_detection(object, det, cand.kind, stamp_ns);
    }

    fn new_object(&mut self, cand: Candidate, det: &Detection, stamp_ns: u64) {
        let mut object = Object {
            id: self.next_id,
            points: Vec::new(),
            min: Vec3::ZERO,
            max: Vec3::ZERO,
            feature: det.semantic_feature.clone().unwrap_or_default(),
            num_detections: 0,
            kinds: [0; 2],
            labels: Vec::new(),
            score_sum: 0.0,
            last_seen_stamp_ns: stamp_ns,
            tree: None,
        };
        self.next_id += 1;
        object.set_points(cand.points);
        add_detection(&mut object, det, cand.kind, stamp_ns);
        self.objects.push(object);
    }

    /// `denoise_objects`.
    fn denoise(&mut self) {
        let voxel = self.config.voxel_m;
        for i in 0..self.objects.len() {
            let points = self.process(voxel_down_sample(&self.objects[i].points, voxel), true);
            if points.len() >= 4 {
                self.objects[i].set_points(points);
            }
        }
    }

    /// `filter_objects`.
    fn filter(&mut self) {
        let (min_points, min_detections) = (self.config.obj_min_points, self.config.obj_min_detections);
        self.objects.retain(|o| o.points.len() >= min_points && o.num_detections >= min_detections);
    }

    /// `merge_overlap_objects`; the number of objects merged away.
    fn merge_overlapping(&mut self) -> u32 {
        let c = self.config.clone();
        if c.merge_overlap_thresh < 0.0 {
            return 0;
        }
        let n = self.objects.len();
        // compute_overlap_matrix: (i, j) = share of i's points within a voxel of j's.
        let mut pairs: Vec<(f32, usize, usize)> = Vec::new();
        for j in 0..n {
            for i in 0..n {
                if i == j
                    || !self.same_association(self.objects[i].kind(), self.objects[j].kind())
                    || !boxes_intersect(&self.objects[i], &self.objects[j])
                {
                    continue;
                }
                let points = std::mem::take(&mut self.objects[i].points);
                let ratio = overlap_ratio(&points, self.objects[j].tree(), c.voxel_m);
                self.objects[i].points = points;
                if ratio > 0.0 {
                    pairs.push((ratio, i, j));
                }
            }
        }
        pairs.sort_by(|a, b| b.0.total_cmp(&a.0).then(a.1.cmp(&b.1)).then(a.2.cmp(&b.2)));
        let mut kept = vec![true; n];
        let mut merged = 0;
        for (ratio, i, j) in pairs {
            if ratio <= c.merge_overlap_thresh {
                break;
            }
            let visual = cosine(&self.objects[i].feature, &self.objects[j].feature);
            // Text features: the same per-detection feature (module docs).
            let text = visual;
            if visual > c.merge_visual_sim_thresh && text > c.merge_text_sim_thresh && kept[j] && kept[i] {
                // Object i into object j.
                let from = self.objects[i].clone();
                let mut points = std::mem::take(&mut self.objects[j].points);
                points.extend_from_slice(&from.points);
                let points = self.process(voxel_down_sample(&points, c.voxel_m), true);
                let into = &mut self.objects[j];
                into.set_points(points);
                let (n1, n2) = (into.num_detections as f32, from.num_detections as f32);
                if into.feature.len() == from.feature.len() && !into.feature.is_empty() {
                    for (a, b) in into.feature.iter_mut().zip(&from.feature) {
                        *a = (*a * n1 + b * n2) / (n1 + n2);
                    }
                    normalise(&mut into.feature);
                } else if into.feature.is_empty() {
                    into.feature.clone_from(&from.feature);
                }
                into.num_detections += from.num_detections;
                into.kinds[0] += from.kinds[0];
                into.kinds[1] += from.kinds[1];
                for (label, count) in &from.labels {
                    match into.labels.iter_mut().find(|(l, _)| l == label) {
                        Some(entry) => entry.1 += count,
                        None => into.labels.push((label.clone(), *count)),
                    }
                }
                into.score_sum += from.score_sum;
                into.last_seen_stamp_ns = into.last_seen_stamp_ns.max(from.last_seen_stamp_ns);
                kept[i] = false;
                merged += 1;
            }
        }
        let mut index = 0;
        self.objects.retain(|_| {
            index += 1;
            kept[index - 1]
        });
        merged
    }

    /// The map as their final frame leaves it: denoise, filter, merge, on a copy.
    fn finalised(&self) -> Self {
        let mut map = self.clone();
        map.denoise();
        map.filter();
        map.merge_overlapping();
        map
    }
}

fn add_detection(object: &mut Object, det: &Detection, kind: NodeKind, stamp_ns: u64) {
    object.num_detections += 1;
    object.kinds[usize::from(kind == NodeKind::Part)] += 1;
    match object.labels.iter_mut().find(|(l, _)| *l == det.label) {
        Some(entry) => entry.1 += 1,
        None => object.labels.push((det.label.clone(), 1)),
    }
    object.score_sum += det.score;
    object.last_seen_stamp_ns = stamp_ns;
}

fn bounds(points: &[Vec3]) -> (Vec3, Vec3) {
    points
        .iter()
        .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(lo, hi), p| (lo.min(*p), hi.max(*p)))
}

/// Axis-aligned 3D IoU > 0 (the boxes share a volume).
fn boxes_intersect(a: &Object, b: &Object) -> bool {
    boxes_share_volume(a.min, a.max, b.min, b.max)
}

fn boxes_share_volume(a_min: Vec3, a_max: Vec3, b_min: Vec3, b_max: Vec3) -> bool {
    let lo = a_min.max(b_min);
    let hi = a_max.min(b_max);
    let d = (hi - lo).max(Vec3::ZERO);
    d.x * d.y * d.z > 0.0
}

/// Share of `points` whose nearest neighbour in `tree` is closer than `voxel_m`.
fn overlap_ratio(points: &[Vec3], tree: &Tree, voxel_m: f32) -> f32 {
    if points.is_empty() || tree.size() == 0 {
        return 0.0;
    }
    let limit = voxel_m * voxel_m;
    let near = points.iter().filter(|p| tree.nearest_one::<SquaredEuclidean>(&p.to_array()).distance < limit).count();
    near as f32 / points.len() as f32
}

fn cosine(a: &[f32], b: &[f32]) -> f32 {
    if a.is_empty() || a.len() != b.len() {
        return 0.0;
    }
    let (na, nb) = (dot(a, a).sqrt(), dot(b, b).sqrt());
    if na == 0.0 || nb == 0.0 { 0.0 } else { dot(a, b) / (na * nb) }
}

/// Open3D's `voxel_down_sample`: the mean of the points of each voxel, in voxel order.
pub fn voxel_down_sample(points: &[Vec3], voxel_m: f32) -> Vec<Vec3> {
    let mut cells: FxHashMap<[i32; 3], (Vec3, u32)> = FxHashMap::default();
    for p in points {
        let key = (*p / voxel_m).floor().as_ivec3().to_array();
        let cell = cells.entry(key).or_insert((Vec3::ZERO, 0));
        cell.0 += *p;
        cell.1 += 1;
    }
    let mut cells: Vec<([i32; 3], (Vec3, u32))> = cells.into_iter().collect();
    cells.sort_unstable_by_key(|(k, _)| *k);
    cells.into_iter().map(|(_, (sum, n))| sum / n as f32).collect()
}

/// Their `pcd_denoise_dbscan`: Open3D's DBSCAN (a point with at least `min_points` points
/// within `eps`, itself included, is a core point), then the largest cluster, unless it has
/// fewer than 5 points (then the cloud is kept as it is).
pub fn dbscan_largest_cluster(points: Vec<Vec3>, eps_m: f32, min_points: usize) -> Vec<Vec3> {
    if points.is_empty() {
        return points;
    }
    let pts: Vec<[f32; 3]> = points.iter().map(|p| p.to_array()).collect();
    let tree = Tree::new_from_slice(&pts);
    let eps2 = eps_m * eps_m;
    let neighbours = |i: usize| -> Vec<usize> {
        tree.within_unsorted::<SquaredEuclidean>(&pts[i], eps2)
            .into_iter()
            .filter(|n| n.distance <= eps2)
            .map(|n| n.item as usize)
            .collect()
    };
    const UNSEEN: i32 = -2;
    const NOISE: i32 = -1;
    let mut label = vec![UNSEEN; pts.len()];
    let mut clusters: Vec<usize> = Vec::new();
    for start in 0..pts.len() {
        if label[start] != UNSEEN {
            continue;
        }
        let first = neighbours(start);
        if first.len() < min_points {
            label[start] = NOISE;
            continue;
        }
        let cluster = clusters.len() as i32;
        clusters.push(0);
        label[start] = cluster;
        clusters[cluster as usize] += 1;
        let mut queue = first;
        while let Some(q) = queue.pop() {
            if label[q] == NOISE {
                label[q] = cluster;
                clusters[cluster as usize] += 1;
            }
            if label[q] != UNSEEN {
                continue;
            }
            label[q] = cluster;
            clusters[cluster as usize] += 1;
            let more = neighbours(q);
            if more.len() >= min_points {
                queue.extend(more.into_iter().filter(|&n| label[n] == UNSEEN || label[n] == NOISE));
            }
        }
    }
    // Largest cluster; ties to the first (Counter.most_common keeps insertion order).
    let Some((best, &size)) = clusters.iter().enumerate().max_by(|a, b| a.1.cmp(b.1).then(b.0.cmp(&a.0))) else {
        return points;
    };
    if size < 5 {
        return points;
    }
    points.into_iter().zip(label).filter(|(_, l)| *l == best as i32).map(|(p, _)| p).collect()
}

impl Fusion for ConceptGraphsFusion {
    fn integrate(&mut self, frame: &Frame, world_from_camera: &Isometry, detections: &[Detection]) -> FusionReport {
        let mut report = FusionReport::default();
        self.keyframe += 1;
        let pose = world_from_camera.to_mat4();
        let mut candidates = Vec::with_capacity(detections.len());
        for (i, det) in detections.iter().enumerate() {
            match self.lift(frame, &pose, i, det) {
                Some(c) => candidates.push(c),
                None => report.ignored += 1,
            }
        }
        // Similarities against the map as it was before this keyframe, then each detection's
        // best object (match_detections_to_objects).
        let c = self.config.clone();
        let mut matches: Vec<Option<usize>> = Vec::with_capacity(candidates.len());
        for cand in &candidates {
            let det = &detections[cand.detection];
            let mut best: Option<(f32, usize)> = None;
            for slot in 0..self.objects.len() {
                let object = &self.objects[slot];
                if !self.same_association(cand.kind, object.kind())
                    || !boxes_share_volume(cand.min, cand.max, object.min, object.max)
                {
                    continue;
                }
                let visual = self.visual(det, object);
                // The kd-tree is cached per object (rebuilt when its points change).
                let spatial = overlap_ratio(&cand.points, self.objects[slot].tree(), c.voxel_m);
                let sim = (1.0 + c.phys_bias) * spatial + (1.0 - c.phys_bias) * visual;
                if sim >= c.sim_threshold && best.is_none_or(|(b, _)| sim > b) {
                    best = Some((sim, slot));
                }
            }
            matches.push(best.map(|(_, slot)| slot));
        }
        for (cand, matched) in candidates.into_iter().zip(matches) {
            let det = &detections[cand.detection];
            match matched {
                Some(slot) => {
                    self.merge_detection(slot, cand, det, frame.stamp_ns);
                    report.merged += 1;
                }
                None => {
                    self.new_object(cand, det, frame.stamp_ns);
                    report.created += 1;
                }
            }
        }
        let keyframe = self.keyframe;
        let due = |every: u32| every > 0 && keyframe.is_multiple_of(u64::from(every));
        if due(c.denoise_interval) {
            self.denoise();
        }
        if due(c.filter_interval) {
            let before = self.objects.len();
            self.filter();
            report.pruned += (before - self.objects.len()) as u32;
        }
        if due(c.merge_interval) {
            report.maintenance_merged += self.merge_overlapping();
        }
        report
    }

    fn build_graph(&self, out: &mut SceneGraph) {
        out.nodes.clear();
        out.edges.clear();
        let map = self.finalised();
        for object in &map.objects {
            let (label, votes) = object.label();
            let n = object.num_detections as f32;
            out.nodes.push(GraphNode {
                id: object.id,
                kind: object.kind(),
                parent_id: None,
                label: label.to_owned(),
                confidence: ((votes as f32 / n) * (object.score_sum / n)).clamp(0.0, 1.0),
                centre_m: ((object.min + object.max) * 0.5).to_array(),
                box_min_m: object.min.to_array(),
                box_max_m: object.max.to_array(),
                obb: OrientedBox::fit(&object.points, self.up_axis).unwrap_or_else(|| {
                    OrientedBox::axis_aligned(object.min.to_array(), object.max.to_array(), self.up_axis)
                }),
                observation_count: object.num_detections,
                affordance_bits: 0,
                last_seen_stamp_ns: object.last_seen_stamp_ns,
                ..Default::default()
            });
        }
        out.nodes.sort_unstable_by_key(|n| n.id);
        attach_parts(out, self.config.part_attach_margin_m);
    }

    fn node_count(&self) -> usize {
        self.objects.len()
    }

    fn memory_bytes(&self) -> usize {
        self.objects.capacity() * size_of::<Object>() + self.objects.iter().map(Object::heap_bytes).sum::<usize>()
    }

    fn node_points(&self, max_per_node: usize, out: &mut Vec<NodePoint>) {
        for object in &self.finalised().objects {
            let step = object.points.len().div_ceil(max_per_node.max(1)).max(1);
            out.extend(
                object.points.iter().step_by(step).map(|p| NodePoint { node_id: object.id, position_m: p.to_array() }),
            );
        }
    }
}
