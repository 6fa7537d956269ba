//! Negative evidence from each keyframe's depth, removals, moves and appearances (the rules
//! are in [`crate::fusion::change`]).

use glam::{Mat4, Quat, Vec3};
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::NodeKind;

use super::MultiViewFusion;
use super::node::Node;
use crate::embedding::dot;
use crate::flow::Detection;
use crate::fusion::FusionReport;
use crate::fusion::change::{ChangeEvent, ChangeKind, RemovedNode};

/// The view of a past keyframe, for "has the camera looked here before".
#[derive(Debug, Clone, Copy)]
pub(super) struct View {
    stamp_ns: u64,
    position: Vec3,
    rotation: Quat,
    /// tan of half the field of view in x and y.
    tan_half: (f32, f32),
}

/// Views kept at most (thinned: a new one only after the camera moved or turned).
const MAX_VIEWS: usize = 4096;
const VIEW_STEP_M: f32 = 0.5;
const VIEW_STEP_DEG: f32 = 20.0;

/// A miss in progress: where and when the first of the current run of misses was.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Misses {
    pub(super) count: u32,
    first_stamp_ns: u64,
    first_position: Vec3,
    first_forward: Vec3,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Reading {
    Seen,
    Occluded,
    Free,
    Unknown,
}

/// This keyframe's camera.
struct Camera {
    camera_from_world: Mat4,
    position: Vec3,
    forward: Vec3,
    stamp_ns: u64,
}

impl MultiViewFusion {
    /// The evidence step of one keyframe (after its detections are fused).
    pub(super) fn evidence(
        &mut self,
        frame: &Frame,
        world_from_camera: &Isometry,
        detections: &[Detection],
        report: &mut FusionReport,
    ) {
        let now = frame.stamp_ns;
        self.publish_newly_confirmed(now);
        if !self.config.change.enabled {
            return;
        }
        let rotation = world_from_camera.rotation.as_quat();
        let camera = Camera {
            camera_from_world: world_from_camera.to_mat4().inverse(),
            position: world_from_camera.translation.as_vec3(),
            forward: rotation * Vec3::Z,
            stamp_ns: now,
        };
        self.remember_view(&camera, rotation, frame);
        let mut remove = std::mem::take(&mut self.scratch.order);
        remove.clear();
        for slot in 0..self.nodes.len() as u32 {
            let n = &self.nodes[slot as usize];
            if !n.alive || !n.published || n.last_keyframe == self.keyframe {
                continue;
            }
            let mut reading = self.judge(n, frame, &camera, detections);
            if reading == Some(Reading::Free)
                && n.kind == NodeKind::Part
                && !self.holder_seen(slot, frame, &camera, detections)
            {
                reading = Some(Reading::Unknown);
            }
            match reading {
                Some(Reading::Free) => {
                    let c = &self.config.change;
                    let n = &mut self.nodes[slot as usize];
                    if n.misses.count == 0 {
                        report.state_changes += 1;
                        n.misses = Misses {
                            count: 0,
                            first_stamp_ns: now,
                            first_position: camera.position,
                            first_forward: camera.forward,
                        };
                    }
                    n.misses.count += 1;
                    let m = n.misses;
                    let apart_s = now.saturating_sub(m.first_stamp_ns) as f32 * 1e-9;
                    let moved = (camera.position - m.first_position).length() >= c.min_viewpoint_change_m
                        || m.first_forward.angle_between(camera.forward).to_degrees() >= c.min_viewpoint_change_deg;
                    if m.count >= c.misses_to_remove && apart_s >= c.min_miss_separation_s && moved {
                        remove.push(slot);
                    }
                }
                Some(Reading::Seen) if self.nodes[slot as usize].misses.count > 0 => {
                    self.nodes[slot as usize].misses.count = 0;
                    report.state_changes += 1;
                }
                _ => {}
            }
        }
        for &slot in &remove {
            if self.nodes[slot as usize].alive {
                // Parts near it go with it unless this keyframe's depth sees them where they
                // were (a wall outlet behind a kettle stays).
                let parts: Vec<u32> = if self.nodes[slot as usize].kind == NodeKind::Object {
                    let near = self.parts_of(slot);
                    near.into_iter()
                        .filter(|&p| {
                            self.judge(&self.nodes[p as usize], frame, &camera, detections) != Some(Reading::Seen)
                        })
                        .collect()
                } else {
                    Vec::new()
                };
                let id = self.nodes[slot as usize].id;
                self.remove_changed(slot, now, None, report);
                for part in parts {
                    if self.nodes[part as usize].alive {
                        self.remove_changed(part, now, Some(id), report);
                    }
                }
            }
        }
        remove.clear();
        self.scratch.order = remove;
    }

    /// What this keyframe's depth says about node `n`: `Free` (a miss), `Seen` (clears misses),
    /// `Occluded`/`Unknown` (nothing), `None` (not in view).
    fn judge(&self, n: &Node, frame: &Frame, camera: &Camera, detections: &[Detection]) -> Option<Reading> {
        let c = &self.config.change;
        let k = &frame.intrinsics;
        let (w, h) = (k.width as i32, k.height as i32);
        if frame.depth.len() != (w * h) as usize || w == 0 {
            return None;
        }
        // Coarse: the box's centre and radius against the range and the image.
        let centre = camera.camera_from_world.transform_point3(n.cloud.centre());
        let radius = (n.cloud.max - n.cloud.min).length() * 0.5;
        if centre.z + radius < c.min_range_m || centre.z - radius > c.max_range_m || centre.z <= 1e-3 {
            return None;
        }
        let reach_px = radius * k.fx / centre.z.max(0.05);
        let (cu, cv) = (k.fx * centre.x / centre.z + k.cx, k.fy * centre.y / centre.z + k.cy);
        if cu < -reach_px || cv < -reach_px || cu > w as f32 + reach_px || cv > h as f32 + reach_px {
            return None;
        }
        let points = &n.cloud.points;
        let samples = (c.samples_per_node as usize).min(points.len()).max(1);
        let step = (points.len() / samples).max(1);
        let (mut seen, mut occluded, mut free) = (0u32, 0u32, 0u32);
        let r = c.window_px as i32;
        let offsets = [(0, 0), (-r, 0), (r, 0), (0, -r), (0, r), (-r, -r), (r, -r), (-r, r), (r, r)];
        let window = if r == 0 { &offsets[..1] } else { &offsets[..] };
        for p in points.iter().step_by(step).take(samples) {
            let q = camera.camera_from_world.transform_point3(*p);
            let z = q.z;
            if z < c.min_range_m || z > c.max_range_m {
                continue;
            }
            let (u, v) = (k.fx * q.x / z + k.cx, k.fy * q.y / z + k.cy);
            let (ui, vi) = (u.floor() as i32, v.floor() as i32);
            if ui < 0 || vi < 0 || ui >= w || vi >= h {
                continue;
            }
            let agree = c.agree_m + c.agree_per_m2 * z * z;
            let margin = c.free_margin_m + c.free_margin_per_m2 * z * z;
            let (mut valid, mut near, mut behind, mut agrees) = (0u32, 0u32, 0u32, false);
            for &(dx, dy) in window {
                let (x, y) = (ui + dx, vi + dy);
                if x < 0 || y < 0 || x >= w || y >= h {
                    continue;
                }
                let d = frame.depth_m((y * w + x) as usize);
                if !(d >= c.min_range_m && d.is_finite()) {
                    continue;
                }
                valid += 1;
                if (d - z).abs() <= agree {
                    agrees = true;
                } else if d < z - agree {
                    near += 1;
                } else if d > z + margin {
                    behind += 1;
                }
            }
            // Free needs most of the window read, and all of what was read behind.
            let quorum = (window.len() as u32).div_ceil(2);
            match classify(agrees, valid, near, behind, quorum) {
                Reading::Seen => seen += 1,
                Reading::Occluded => occluded += 1,
                Reading::Free => free += 1,
                Reading::Unknown => {}
            }
        }
        // Occluded points are not visible: the evidence is the visible ones, seen or free.
        let visible = seen + free;
        if visible < c.min_visible_points {
            return Some(if occluded >= c.min_visible_points { Reading::Occluded } else { Reading::Unknown });
        }
        if seen as f32 >= c.seen_fraction * visible as f32 {
            return Some(Reading::Seen);
        }
        let fraction = if n.kind == NodeKind::Part { c.part_free_fraction } else { c.free_fraction };
        if (free as f32) < fraction * visible as f32 {
            return Some(Reading::Unknown);
        }
        // A detection of its label where its box projects, at about its range: it is in view,
        // the pose or depth is off. (A point was read in front of the camera, so a corner of the
        // box is too, and the box projects.)
        let Some((lo, hi)) = projected_box(n, &camera.camera_from_world, k) else { return Some(Reading::Free) };
        let grow = c.detection_veto_grow;
        let vetoed = detections.iter().any(|d| {
            let Some(&label) = self.label_ids.get(&d.label) else { return false };
            if !n.has_label(label) {
                return false;
            }
            let m = &d.mask;
            let (gx, gy) = (m.width as f32 * grow, m.height as f32 * grow);
            let (x0, y0) = (m.x0 as f32 - gx, m.y0 as f32 - gy);
            let (x1, y1) = ((m.x0 + m.width) as f32 + gx, (m.y0 + m.height) as f32 + gy);
            let overlaps = !(hi.0 < x0 || lo.0 > x1 || hi.1 < y0 || lo.1 > y1);
            overlaps
                && mask_depth(frame, m).is_none_or(|depth| (depth - centre.z).abs() <= radius + c.free_margin_m * 2.0)
        });
        Some(if vetoed { Reading::Unknown } else { Reading::Free })
    }

    /// Removes node `slot` on change evidence, logs it, and links an object to a node that
    /// appeared elsewhere as a move. `with_object`: the object a part goes with.
    fn remove_changed(&mut self, slot: u32, now: u64, with_object: Option<u32>, report: &mut FusionReport) {
        let removed = self.removed_record(slot, now);
        let (kind, id) = (self.nodes[slot as usize].kind, self.nodes[slot as usize].id);
        self.remove_node(slot);
        report.removed += 1;
        // Parts are alike everywhere (every handle looks like every other): only objects move.
        let moved_to = if kind == NodeKind::Object { self.move_target(&removed, now, None) } else { None };
        match moved_to {
            Some(target) => self.link_move(target, removed, now),
            None => {
                self.events.push(ChangeEvent {
                    kind: ChangeKind::Removed,
                    node_id: id,
                    node_kind: kind,
                    label: removed.label.clone(),
                    from_m: Some(removed.centre_m),
                    to_m: None,
                    retired_id: None,
                    with_object,
                    stamp_ns: now,
                    keyframe: self.keyframe,
                    graph_version: 0,
                });
                self.history.push(removed);
            }
        }
    }

    fn removed_record(&self, slot: u32, now: u64) -> RemovedNode {
        let n = &self.nodes[slot as usize];
        RemovedNode {
            id: n.id,
            kind: n.kind as u8,
            label: self.label_of(n).0.to_owned(),
            centre_m: n.cloud.centre().to_array(),
            box_min_m: n.cloud.min.to_array(),
            box_max_m: n.cloud.max.to_array(),
            first_seen_stamp_ns: n.first_seen_stamp_ns,
            last_seen_stamp_ns: n.last_seen_stamp_ns,
            first_keyframe: n.first_keyframe,
            last_keyframe: n.last_keyframe,
            removed_stamp_ns: now,
            semantic: n.semantic.clone(),
        }
    }

    /// Whether an object around part `slot` (its box grown by the attach margin holds the part's
    /// centre) is seen where it was in this keyframe: the map and the view line up there, so
    /// the part's free space is not a pose error. A part with no object around it (a wall
    /// switch) is never removed on its own evidence.
    fn holder_seen(&mut self, slot: u32, frame: &Frame, camera: &Camera, detections: &[Detection]) -> bool {
        let centre = self.nodes[slot as usize].cloud.centre();
        let margin = Vec3::splat(self.config.part_attach_margin_m);
        let mut candidates = std::mem::take(&mut self.scratch.candidates);
        self.index.query(centre - margin, centre + margin, &mut candidates);
        let seen = candidates.iter().any(|&s| {
            let o = &self.nodes[s as usize];
            o.alive
                && o.kind == NodeKind::Object
                && o.published
                && centre.cmpge(o.cloud.min - margin).all()
                && centre.cmple(o.cloud.max + margin).all()
                && self.judge(o, frame, camera, detections) == Some(Reading::Seen)
        });
        self.scratch.candidates = candidates;
        seen
    }

    /// Parts attached to object `slot` (centre inside its box grown by the attach margin).
    fn parts_of(&mut self, slot: u32) -> Vec<u32> {
        let (min, max) = (self.nodes[slot as usize].cloud.min, self.nodes[slot as usize].cloud.max);
        let margin = Vec3::splat(self.config.part_attach_margin_m);
        let mut candidates = std::mem::take(&mut self.scratch.candidates);
        self.index.query(min - margin, max + margin, &mut candidates);
        let parts = candidates
            .iter()
            .copied()
            .filter(|&s| {
                let p = &self.nodes[s as usize];
                p.alive && p.kind == NodeKind::Part && {
                    let c = p.cloud.centre();
                    c.cmpge(min - margin).all() && c.cmple(max + margin).all()
                }
            })
            .collect();
        self.scratch.candidates = candidates;
        parts
    }

    /// A node that is `removed` moved: same kind, label and appearance, first seen after it
    /// was last seen, far enough away; the most similar, then the nearest.
    fn move_target(&self, removed: &RemovedNode, now: u64, only: Option<u32>) -> Option<u32> {
        let c = &self.config.change;
        if c.move_window_s <= 0.0 {
            return None;
        }
        let centre = Vec3::from_array(removed.centre_m);
        let mut best: Option<(f32, f32, u32)> = None;
        for slot in 0..self.nodes.len() as u32 {
            if only.is_some_and(|o| o != slot) {
                continue;
            }
            let n = &self.nodes[slot as usize];
            if !n.alive || !n.published || n.kind as u8 != removed.kind || n.first_keyframe <= removed.last_keyframe {
                continue;
            }
            // A node found while mapping new ground is not a move: it must have appeared.
            if only.is_none() && !n.appeared {
                continue;
            }
            if now.saturating_sub(n.first_seen_stamp_ns) as f32 * 1e-9 > c.move_window_s {
                continue;
            }
            let distance = (n.cloud.centre() - centre).length();
            if distance < c.move_min_distance_m {
                continue;
            }
            // With semantic features on both, they decide (synonyms share them, as in fusion);
            // without, the labels must be the same.
            let similarity = if !n.semantic.is_empty() && n.semantic.len() == removed.semantic.len() {
                (dot(&n.semantic, &removed.semantic) + 1.0) * 0.5
            } else if self.label_of(n).0 == removed.label {
                1.0
            } else {
                0.0
            };
            if similarity < c.move_min_semantic {
                continue;
            }
            let better = best.is_none_or(|(s, d, _)| similarity > s + 1e-3 || (similarity >= s - 1e-3 && distance < d));
            if better {
                best = Some((similarity, distance, slot));
            }
        }
        best.map(|(_, _, slot)| slot)
    }

    /// Node `target` is `removed` moved: it takes the old id; logged as a move.
    fn link_move(&mut self, target: u32, removed: RemovedNode, now: u64) {
        let n = &mut self.nodes[target as usize];
        let retired = n.id;
        n.id = removed.id;
        n.first_seen_stamp_ns = n.first_seen_stamp_ns.min(removed.first_seen_stamp_ns);
        let to = n.cloud.centre().to_array();
        let kind = n.kind;
        self.events.push(ChangeEvent {
            kind: ChangeKind::Moved,
            node_id: removed.id,
            node_kind: kind,
            label: removed.label,
            from_m: Some(removed.centre_m),
            to_m: Some(to),
            retired_id: Some(retired),
            with_object: None,
            stamp_ns: now,
            keyframe: self.keyframe,
            graph_version: 0,
        });
    }

    /// Nodes confirmed for the first time: a move of a recently removed node, a new thing in a
    /// known place, or a node found while mapping.
    fn publish_newly_confirmed(&mut self, now: u64) {
        for slot in 0..self.nodes.len() as u32 {
            let n = &self.nodes[slot as usize];
            if !n.alive || n.published || !self.confirmed(n) {
                continue;
            }
            self.nodes[slot as usize].published = true;
            if !self.config.change.enabled {
                continue;
            }
            // Only a node where the camera had looked before is new in the home.
            let n = &self.nodes[slot as usize];
            if !self.looked_before(n.cloud.centre(), n.first_seen_stamp_ns) {
                continue;
            }
            let window_s = self.config.change.move_window_s;
            let link = self
                .history
                .iter()
                .rev()
                .filter(|r| r.kind == NodeKind::Object as u8)
                .filter(|r| now.saturating_sub(r.removed_stamp_ns) as f32 * 1e-9 <= window_s)
                .find(|r| self.move_target(r, now, Some(slot)).is_some())
                .map(|r| r.id);
            if let Some(id) = link
                && let Some(removed) = self.history.take(id)
            {
                self.link_move(slot, removed, now);
                continue;
            }
            let n = &self.nodes[slot as usize];
            let (label, kind, id, to) = (self.label_of(n).0.to_owned(), n.kind, n.id, n.cloud.centre().to_array());
            self.nodes[slot as usize].appeared = true;
            self.events.push(ChangeEvent {
                kind: ChangeKind::Appeared,
                node_id: id,
                node_kind: kind,
                label,
                from_m: None,
                to_m: Some(to),
                retired_id: None,
                with_object: None,
                stamp_ns: now,
                keyframe: self.keyframe,
                graph_version: 0,
            });
        }
    }

    /// Whether a keyframe at least `appeared_after_s` before `first_seen` had `p` in view,
    /// within the trusted range.
    fn looked_before(&self, p: Vec3, first_seen: u64) -> bool {
        let c = &self.config.change;
        let age_ns = (c.appeared_after_s as f64 * 1e9) as u64;
        self.views.iter().filter(|v| v.stamp_ns.saturating_add(age_ns) <= first_seen).any(|v| {
            let q = v.rotation.inverse() * (p - v.position);
            q.z >= c.min_range_m
                && q.z <= c.max_range_m
                && q.x.abs() <= v.tan_half.0 * 0.9 * q.z
                && q.y.abs() <= v.tan_half.1 * 0.9 * q.z
        })
    }

    fn remember_view(&mut self, camera: &Camera, rotation: Quat, frame: &Frame) {
        if let Some(last) = self.views.back() {
            let turned = (last.rotation * Vec3::Z).angle_between(camera.forward).to_degrees();
            if (last.position - camera.position).length() < VIEW_STEP_M && turned < VIEW_STEP_DEG {
                return;
            }
        }
        if self.views.len() >= MAX_VIEWS {
            self.views.pop_front();
        }
        let k = &frame.intrinsics;
        let tan_half = (k.width as f32 * 0.5 / k.fx, k.height as f32 * 0.5 / k.fy);
        self.views.push_back(View { stamp_ns: camera.stamp_ns, position: camera.position, rotation, tan_half });
    }
}

/// The image rectangle of the corners of `n`'s box that lie in front of the camera, pixels.
fn projected_box(
    n: &Node,
    camera_from_world: &Mat4,
    k: &op3dsg_drivers::frame::Intrinsics,
) -> Option<((f32, f32), (f32, f32))> {
    let (min, max) = (n.cloud.min, n.cloud.max);
    let mut lo = (f32::INFINITY, f32::INFINITY);
    let mut hi = (f32::NEG_INFINITY, f32::NEG_INFINITY);
    for corner in 0..8u32 {
        let p = Vec3::new(
            if corner & 1 == 0 { min.x } else { max.x },
            if corner & 2 == 0 { min.y } else { max.y },
            if corner & 4 == 0 { min.z } else { max.z },
        );
        let q = camera_from_world.transform_point3(p);
        if q.z <= 0.05 {
            continue;
        }
        let (u, v) = (k.fx * q.x / q.z + k.cx, k.fy * q.y / q.z + k.cy);
        lo = (lo.0.min(u), lo.1.min(v));
        hi = (hi.0.max(u), hi.1.max(v));
    }
    lo.0.is_finite().then_some((lo, hi))
}

/// The median depth of the mask's pixels on a grid over its box (every `width / 8`-th column
/// and `height / 8`-th row), metres; `None` without depth there.
fn mask_depth(frame: &Frame, mask: &crate::flow::Mask) -> Option<f32> {
    let w = frame.intrinsics.width;
    let step_x = (mask.width / 8).max(1);
    let step_y = (mask.height / 8).max(1);
    let mut depths = Vec::with_capacity(64);
    for y in (0..mask.height).step_by(step_y as usize) {
        for x in (0..mask.width).step_by(step_x as usize) {
            if mask.data.get((y * mask.width + x) as usize) != Some(&1) {
                continue;
            }
            let (u, v) = (mask.x0 + x, mask.y0 + y);
            if u >= w || v >= frame.intrinsics.height {
                continue;
            }
            let d = frame.depth_m((v * w + u) as usize);
            if d > 0.0 && d.is_finite() {
                depths.push(d);
            }
        }
    }
    if depths.is_empty() {
        return None;
    }
    let mid = depths.len() / 2;
    Some(*depths.select_nth_unstable_by(mid, f32::total_cmp).1)
}

fn classify(agrees: bool, valid: u32, near: u32, behind: u32, quorum: u32) -> Reading {
    if agrees {
        Reading::Seen
    } else if valid >= quorum && behind == valid {
        Reading::Free
    } else if valid >= quorum && near == valid {
        Reading::Occluded
    } else {
        Reading::Unknown
    }
}
