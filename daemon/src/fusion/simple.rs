//! The foundation's association: box overlap within the same node kind, label by vote.
//!
//! Each detection's mask is back-projected through its depth and the keyframe pose into world
//! points (every `pixel_stride`-th pixel, depth within range and within a band around the mask's
//! median depth), voxel-downsampled, and joined to the node of the same kind whose box (grown by
//! one voxel) contains the largest fraction of its points, if that fraction reaches
//! `min_overlap`; otherwise it starts a node. Parts attach to the object whose grown box contains
//! their centre, preferring an object whose label is contained in the part's label ("cabinet
//! handle" → cabinet), then the nearest.

use std::collections::{HashMap, HashSet};

use glam::Vec3;
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind};

use super::{Fusion, FusionConfig, FusionReport};
use crate::graph::{GraphEdge, GraphNode, SceneGraph};
use crate::perception::Detection;

#[derive(Debug, Clone)]
struct MapNode {
    id: u32,
    kind: NodeKind,
    points: Vec<Vec3>,
    voxels: HashSet<(i32, i32, i32)>,
    box_min: Vec3,
    box_max: Vec3,
    centre: Vec3,
    votes: HashMap<String, u32>,
    score_sum: f32,
    observation_count: u32,
    last_seen_stamp_ns: u64,
}

impl MapNode {
    fn label(&self) -> (&str, u32) {
        // Highest count, ties broken by the lexically smallest label for determinism.
        self.votes
            .iter()
            .max_by(|a, b| a.1.cmp(b.1).then_with(|| b.0.cmp(a.0)))
            .map(|(l, c)| (l.as_str(), *c))
            .unwrap_or(("", 0))
    }

    fn refresh_geometry(&mut self) {
        let (min, max, sum) = self
            .points
            .iter()
            .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY), Vec3::ZERO), |(lo, hi, s), p| {
                (lo.min(*p), hi.max(*p), s + *p)
            });
        if !self.points.is_empty() {
            self.box_min = min;
            self.box_max = max;
            self.centre = sum / self.points.len() as f32;
        }
    }
}

/// Box-overlap fusion (see the module docs).
#[derive(Debug)]
pub struct SimpleFusion {
    config: FusionConfig,
    nodes: Vec<MapNode>,
    next_id: u32,
    scratch_points: Vec<Vec3>,
    scratch_depths: Vec<f32>,
    scratch_sorted: Vec<f32>,
    scratch_voxels: HashSet<(i32, i32, i32)>,
    scratch_kept: Vec<Vec3>,
}

impl SimpleFusion {
    /// An empty map.
    pub fn new(config: FusionConfig) -> Self {
        Self {
            config,
            nodes: Vec::new(),
            next_id: 1,
            scratch_points: Vec::new(),
            scratch_depths: Vec::new(),
            scratch_sorted: Vec::new(),
            scratch_voxels: HashSet::new(),
            scratch_kept: Vec::new(),
        }
    }

    fn voxel_of(p: Vec3, voxel_m: f32) -> (i32, i32, i32) {
        let v = (p / voxel_m).floor();
        (v.x as i32, v.y as i32, v.z as i32)
    }

    /// Back-projects the detection into `scratch_points` (world frame).
    fn back_project(&mut self, frame: &Frame, world_from_camera: &glam::Mat4, det: &Detection) {
        let c = &self.config;
        let k = &frame.intrinsics;
        let stride = c.pixel_stride.max(1);
        self.scratch_depths.clear();
        self.scratch_points.clear();
        let m = &det.mask;
        for row in (0..m.height).step_by(stride as usize) {
            for col in (0..m.width).step_by(stride as usize) {
                if m.data[(row * m.width + col) as usize] == 0 {
                    continue;
                }
                let (x, y) = (m.x0 + col, m.y0 + row);
                let depth_m = frame.depth_m((y * k.width + x) as usize);
                if depth_m < c.min_depth_m || depth_m > c.max_depth_m {
                    continue;
                }
                self.scratch_depths.push(depth_m);
                let p = k.point_in_camera(x as f32, y as f32, depth_m);
                self.scratch_points.push(world_from_camera.transform_point3(p));
            }
        }
        if self.scratch_depths.is_empty() {
            return;
        }
        self.scratch_sorted.clear();
        self.scratch_sorted.extend_from_slice(&self.scratch_depths);
        let mid = self.scratch_sorted.len() / 2;
        let median = *self.scratch_sorted.select_nth_unstable_by(mid, f32::total_cmp).1;
        let band = if det.kind == NodeKind::Part { c.part_depth_band_m } else { c.object_depth_band_m };
        let mut keep = 0;
        for i in 0..self.scratch_points.len() {
            if (self.scratch_depths[i] - median).abs() <= band {
                self.scratch_points[keep] = self.scratch_points[i];
                keep += 1;
            }
        }
        self.scratch_points.truncate(keep);
    }

    fn best_match(&self, kind: NodeKind, points: &[Vec3], lo: Vec3, hi: Vec3, grow: f32) -> Option<(usize, f32)> {
        let mut best: Option<(usize, f32)> = None;
        for (i, node) in self.nodes.iter().enumerate() {
            if node.kind != kind {
                continue;
            }
            let (nmin, nmax) = (node.box_min - Vec3::splat(grow), node.box_max + Vec3::splat(grow));
            if hi.cmplt(nmin).any() || lo.cmpgt(nmax).any() {
                continue;
            }
            let inside = points.iter().filter(|p| p.cmpge(nmin).all() && p.cmple(nmax).all()).count();
            let fraction = inside as f32 / points.len() as f32;
            if best.is_none_or(|(_, f)| fraction > f) {
                best = Some((i, fraction));
            }
        }
        best
    }
}

impl Fusion for SimpleFusion {
    fn integrate(&mut self, frame: &Frame, world_from_camera: &Isometry, detections: &[Detection]) -> FusionReport {
        let mut report = FusionReport::default();
        let pose = world_from_camera.to_mat4();
        for det in detections {
            self.back_project(frame, &pose, det);
            let voxel_m =
                if det.kind == NodeKind::Part { self.config.part_voxel_m } else { self.config.object_voxel_m };
            // Voxel-downsample the detection into reused scratch buffers.
            let mut points = std::mem::take(&mut self.scratch_kept);
            points.clear();
            self.scratch_voxels.clear();
            let seen = &mut self.scratch_voxels;
            points.extend(self.scratch_points.iter().copied().filter(|p| seen.insert(Self::voxel_of(*p, voxel_m))));
            if points.len() < self.config.min_points {
                report.ignored += 1;
                self.scratch_kept = points;
                continue;
            }
            let (lo, hi) = points
                .iter()
                .fold((Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)), |(a, b), p| (a.min(*p), b.max(*p)));
            let target = match self.best_match(det.kind, &points, lo, hi, voxel_m) {
                Some((i, fraction)) if fraction >= self.config.min_overlap => {
                    report.merged += 1;
                    i
                }
                _ => {
                    report.created += 1;
                    self.nodes.push(MapNode {
                        id: self.next_id,
                        kind: det.kind,
                        points: Vec::new(),
                        voxels: HashSet::new(),
                        box_min: lo,
                        box_max: hi,
                        centre: (lo + hi) * 0.5,
                        votes: HashMap::new(),
                        score_sum: 0.0,
                        observation_count: 0,
                        last_seen_stamp_ns: 0,
                    });
                    self.next_id += 1;
                    self.nodes.len() - 1
                }
            };
            let cap = self.config.max_points_per_node;
            let node = &mut self.nodes[target];
            for &p in &points {
                if node.points.len() >= cap {
                    break;
                }
                if node.voxels.insert(Self::voxel_of(p, voxel_m)) {
                    node.points.push(p);
                }
            }
            self.scratch_kept = points;
            *node.votes.entry(det.label.clone()).or_insert(0) += 1;
            node.score_sum += det.score;
            node.observation_count += 1;
            node.last_seen_stamp_ns = frame.stamp_ns;
            node.refresh_geometry();
        }
        report
    }

    fn build_graph(&self, out: &mut SceneGraph) {
        out.nodes.clear();
        out.edges.clear();
        let confirmed = self.nodes.iter().filter(|n| n.observation_count >= self.config.min_observations);
        for node in confirmed {
            let (label, votes) = node.label();
            let confidence =
                (votes as f32 / node.observation_count as f32) * (node.score_sum / node.observation_count as f32);
            out.nodes.push(GraphNode {
                id: node.id,
                kind: node.kind,
                parent_id: None,
                label: label.to_owned(),
                confidence: confidence.clamp(0.0, 1.0),
                centre_m: node.centre.to_array(),
                box_min_m: node.box_min.to_array(),
                box_max_m: node.box_max.to_array(),
                observation_count: node.observation_count,
                affordance_bits: 0,
                last_seen_stamp_ns: node.last_seen_stamp_ns,
            });
        }
        attach_parts(out, self.config.part_attach_margin_m);
    }

    fn node_count(&self) -> usize {
        self.nodes.len()
    }
}

/// Sets each part's parent and adds its `part of` edge (see the module docs for the rule).
fn attach_parts(graph: &mut SceneGraph, margin_m: f32) {
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
            let candidate = (lexical, gap, *id);
            let better = match best {
                None => true,
                Some((bl, bg, _)) => (lexical && !bl) || (lexical == bl && gap < bg),
            };
            if better {
                best = Some(candidate);
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
    use crate::perception::Mask;
    use op3dsg_drivers::frame::Intrinsics;

    fn config() -> FusionConfig {
        crate::config::load(None, &[]).unwrap().profile.fusion
    }

    /// A frame looking at a flat wall 2 m away, and a detection covering a square of it.
    fn wall_frame(depth_mm: u16) -> Frame {
        let k = Intrinsics { width: 64, height: 48, fx: 60.0, fy: 60.0, cx: 32.0, cy: 24.0 };
        let mut frame = Frame::new(k, false);
        frame.depth.fill(depth_mm);
        frame
    }

    fn square(label: &str, kind: NodeKind, x0: u32, y0: u32, size: u32) -> Detection {
        Detection {
            label: label.into(),
            kind,
            score: 0.9,
            mask: Mask { x0, y0, width: size, height: size, data: vec![1; (size * size) as usize] },
            semantic_feature: None,
            ground_truth_instance: None,
        }
    }

    #[test]
    fn repeated_views_fuse_and_distinct_places_do_not() {
        let mut fusion = SimpleFusion::new(FusionConfig { pixel_stride: 1, object_voxel_m: 0.01, ..config() });
        let frame = wall_frame(2000);
        let pose = Isometry::IDENTITY;
        fusion.integrate(&frame, &pose, &[square("cabinet", NodeKind::Object, 10, 10, 12)]);
        let r = fusion.integrate(&frame, &pose, &[square("cupboard", NodeKind::Object, 11, 10, 12)]);
        assert_eq!((r.merged, r.created), (1, 0));
        let r = fusion.integrate(&frame, &pose, &[square("cabinet", NodeKind::Object, 40, 10, 12)]);
        assert_eq!((r.merged, r.created), (0, 1));
        assert_eq!(fusion.node_count(), 2);
        let mut graph = SceneGraph::default();
        fusion.build_graph(&mut graph);
        // Only the node seen twice is confirmed (min_observations = 2 in the base profile).
        assert_eq!(graph.nodes.len(), 1);
        assert_eq!(graph.nodes[0].label, "cabinet");
        assert_eq!(graph.nodes[0].observation_count, 2);
        // Points of a wall at z = 2 m.
        assert!((graph.nodes[0].centre_m[2] - 2.0).abs() < 1e-3);
    }

    #[test]
    fn parts_attach_by_label_then_distance() {
        let mut graph = SceneGraph::default();
        let node = |id, kind, label: &str, lo: [f32; 3], hi: [f32; 3]| GraphNode {
            id,
            kind,
            parent_id: None,
            label: label.into(),
            confidence: 1.0,
            centre_m: ((Vec3::from(lo) + Vec3::from(hi)) * 0.5).to_array(),
            box_min_m: lo,
            box_max_m: hi,
            observation_count: 3,
            affordance_bits: 0,
            last_seen_stamp_ns: 0,
        };
        graph.nodes.push(node(1, NodeKind::Object, "cabinet", [0.0; 3], [1.0, 0.5, 0.9]));
        graph.nodes.push(node(2, NodeKind::Object, "stove", [1.0, 0.0, 0.0], [1.6, 0.6, 0.9]));
        // On the boundary between both; the label picks the cabinet.
        graph.nodes.push(node(3, NodeKind::Part, "cabinet handle", [0.98, 0.1, 0.5], [1.01, 0.12, 0.6]));
        // No lexical match: nearest object (the stove contains it).
        graph.nodes.push(node(4, NodeKind::Part, "knob", [1.3, 0.6, 0.8], [1.32, 0.62, 0.82]));
        // Too far from everything.
        graph.nodes.push(node(5, NodeKind::Part, "handle", [3.0, 3.0, 3.0], [3.1, 3.1, 3.1]));
        attach_parts(&mut graph, 0.05);
        assert_eq!(graph.nodes[2].parent_id, Some(1));
        assert_eq!(graph.nodes[3].parent_id, Some(2));
        assert_eq!(graph.nodes[4].parent_id, None);
        assert_eq!(graph.edges.len(), 2);
    }
}
