//! Applying a checked change script to the scene, one change at a time ([`Applier`]).

use super::*;

/// The scene as the changes so far left it.
pub(super) struct Applier<'a> {
    pub(super) scene: Scene,
    pub(super) path: &'a CameraPath,
    pub(super) frame_count: Option<u64>,
    pub(super) applied: Vec<AppliedChange>,
}

impl Applier<'_> {
    pub(super) fn apply(&mut self, index: usize, frame: u64, action: Action) -> Result<(), SourceError> {
        let change = match action {
            Action::Remove(id) => self.remove(index, id)?,
            Action::Move { id, onto } => self.move_onto(index, id, onto)?,
            Action::AddOnto { label, onto, size } => self.add_onto(index, &label, onto, size)?,
            Action::AddInFront { label, target, size } => self.add_in_front(index, frame, &label, target, size)?,
            Action::HideDepth(id) => {
                let info = self.lookup(index, "hide_depth", id)?;
                let label = info.label.clone();
                if !self.scene.depthless.contains(&id) {
                    self.scene.depthless.push(id);
                }
                AppliedChange { target: Some(id), ..blank(ChangeKind::DepthHole, id, label) }
            }
            Action::FarDepth(range) => {
                self.scene.unreliable_beyond_m = Some(range);
                AppliedChange { range_m: Some(range), ..blank(ChangeKind::FarDepth, 0, String::new()) }
            }
        };
        self.applied.push(AppliedChange { index, frame, ..change });
        Ok(())
    }

    /// The present instance `id` named by `key` of change `index`.
    fn lookup(&self, index: usize, key: &str, id: u16) -> Result<&InstanceInfo, SourceError> {
        let scene = &self.scene;
        let Some(info) = scene.instance(id) else {
            let (room, seed) = (scene.room().as_str(), scene.seed());
            let generated = self.applied.iter().filter(|c| matches!(c.kind, ChangeKind::Added | ChangeKind::Occluder));
            let added = generated.count();
            let max = scene.instances().len();
            let note = if added > 0 { format!("; the last {added} added by earlier changes") } else { String::new() };
            return Err(err(
                index,
                key,
                format!(
                    "no instance {id} in {room} seed {seed}: the ids are 1 to {max}{note} (`op3dsg gt --room {room} \
                     --seed {seed}` lists them)"
                ),
            ));
        };
        if !scene.is_present(id) {
            let by = self
                .applied
                .iter()
                .find(|c| c.kind == ChangeKind::Removed && (c.instance == id || c.parts.contains(&id)));
            let by = by.map_or(String::new(), |c| format!(" by changes[{}] at frame {}", c.index, c.frame));
            return Err(err(index, key, format!("instance {id} ({}) was removed{by}", info.label)));
        }
        Ok(info)
    }

    /// The present parts of object `id`.
    fn parts_of(&self, id: u16) -> Vec<u16> {
        self.scene.present_instances().filter(|i| i.parent == Some(id)).map(|i| i.id).collect()
    }

    /// Refuses to take away or move `info` while an object stands on it.
    fn refuse_carried(&self, index: usize, key: &str, info: &InstanceInfo) -> Result<(), SourceError> {
        let carried: Vec<String> = self
            .scene
            .edges
            .iter()
            .filter(|e| e.relation == "on" && e.target == info.id && self.scene.is_present(e.source))
            .filter_map(|e| self.scene.instance(e.source))
            .map(|i| format!("{} ({})", i.id, i.label))
            .collect();
        if carried.is_empty() {
            return Ok(());
        }
        Err(err(
            index,
            key,
            format!(
                "instance {} ({}) has {} on it: move or remove that first (at an earlier frame, or listed before this \
                 entry at the same frame)",
                info.id,
                info.label,
                carried.join(", ")
            ),
        ))
    }

    fn remove(&mut self, index: usize, id: u16) -> Result<AppliedChange, SourceError> {
        let info = self.lookup(index, "remove", id)?.clone();
        self.refuse_carried(index, "remove", &info)?;
        let parts = self.parts_of(id);
        let mut gone = parts.clone();
        gone.push(id);
        let scene = &mut self.scene;
        scene.primitives.retain(|p| !gone.contains(&p.instance));
        scene.edges.retain(|e| !gone.contains(&e.source) && !gone.contains(&e.target));
        scene.removed.extend(&gone);
        Ok(AppliedChange {
            from: Some((info.box_min_m, info.box_max_m)),
            parts,
            ..blank(ChangeKind::Removed, id, info.label)
        })
    }

    /// The object named by `onto` for `moving` (none: an added object).
    fn surface(&self, index: usize, onto: u16, moving: Option<&InstanceInfo>) -> Result<InstanceInfo, SourceError> {
        let surface = self.lookup(index, "onto", onto)?;
        if let Some(moving) = moving {
            if onto == moving.id {
                return Err(err(index, "onto", format!("instance {onto} ({}) cannot go onto itself", moving.label)));
            }
            if surface.parent == Some(moving.id) {
                return Err(err(
                    index,
                    "onto",
                    format!(
                        "instance {onto} ({}) is a part of {} ({}), the object being moved",
                        surface.label, moving.id, moving.label
                    ),
                ));
            }
        }
        if surface.kind == InstanceKind::Part {
            let of = surface.parent.and_then(|p| self.scene.instance(p)).map_or(String::new(), |p| {
                format!(" of {} ({}); name an object with a top face, such as {}", p.id, p.label, p.id)
            });
            return Err(err(index, "onto", format!("instance {onto} ({}) is a part{of}", surface.label)));
        }
        Ok(surface.clone())
    }

    fn move_onto(&mut self, index: usize, id: u16, onto: u16) -> Result<AppliedChange, SourceError> {
        let info = self.lookup(index, "move", id)?.clone();
        if info.kind == InstanceKind::Part {
            let message = match info.parent.and_then(|p| self.scene.instance(p)) {
                Some(p) => format!(
                    "instance {id} ({}) is a part of {} ({}): move its object, move = {}",
                    info.label, p.id, p.label, p.id
                ),
                None => format!(
                    "instance {id} ({}) is a part fixed to the wall, not an object: it cannot be moved",
                    info.label
                ),
            };
            return Err(err(index, "move", message));
        }
        self.refuse_carried(index, "move", &info)?;
        let surface = self.surface(index, onto, Some(&info))?;
        let parts = self.parts_of(id);
        let mut moving = vec![id];
        moving.extend(&parts);
        let (lo, hi) = moving
            .iter()
            .filter_map(|m| self.scene.instance(*m))
            .fold((Vec3::INFINITY, Vec3::NEG_INFINITY), |(lo, hi), i| (lo.min(i.box_min_m), hi.max(i.box_max_m)));
        let at = self.free_spot_on(&surface, hi - lo, &moving).map_err(|reason| {
            err(
                index,
                "onto",
                format!("no room for {id} ({}) on top of {onto} ({}): {reason}", info.label, surface.label),
            )
        })?;
        let offset = at - lo;
        translate(&mut self.scene, &moving, offset);
        self.scene
            .edges
            .retain(|e| !(e.kind == "spatial" && e.relation != "part of" && (e.source == id || e.target == id)));
        self.scene.edges.push(GtEdge { source: id, target: onto, kind: "spatial", relation: "on" });
        Ok(AppliedChange {
            from: Some((info.box_min_m, info.box_max_m)),
            to: Some((info.box_min_m + offset, info.box_max_m + offset)),
            parts,
            onto: Some(onto),
            ..blank(ChangeKind::Moved, id, info.label)
        })
    }

    /// Min corner of a free spot of `size` on the top face of `surface`, inside its footprint,
    /// overlapping no present instance but those in `exclude`; the nearest to the top's centre.
    fn free_spot_on(&self, surface: &InstanceInfo, size: Vec3, exclude: &[u16]) -> Result<Vec3, String> {
        let (smin, smax) = (surface.box_min_m, surface.box_max_m);
        let top = smax - smin;
        if size.x > top.x + 1e-4 || size.y > top.y + 1e-4 {
            return Err(format!(
                "its top, {:.2} x {:.2} m, is smaller than the {:.2} x {:.2} m footprint",
                top.x, top.y, size.x, size.y
            ));
        }
        if smax.z + size.z > CEILING_HEIGHT_M {
            return Err(format!("{:.2} m high on a top at {:.2} m, it would go through the ceiling", size.z, smax.z));
        }
        // Keep a centimetre from the edges where the top allows it.
        let margin = ((top - size) * 0.5).min(Vec3::splat(0.01)).max(Vec3::ZERO);
        let lo = smin + margin;
        let hi = (smax - margin - size).max(lo);
        let steps = |a: f32, b: f32| ((b - a) / SPOT_STEP_M).floor() as usize + 1;
        let (nx, ny) = (steps(lo.x, hi.x), steps(lo.y, hi.y));
        let centre = (lo + hi) * 0.5;
        let mut candidates: Vec<Vec3> = (0..nx)
            .flat_map(|ix| (0..ny).map(move |iy| (ix, iy)))
            .map(|(ix, iy)| {
                let x = (lo.x + ix as f32 * SPOT_STEP_M).min(hi.x);
                let y = (lo.y + iy as f32 * SPOT_STEP_M).min(hi.y);
                Vec3::new(x, y, smax.z)
            })
            .collect();
        candidates.push(Vec3::new(centre.x, centre.y, smax.z));
        candidates.sort_by(|a, b| (*a - centre).length_squared().total_cmp(&(*b - centre).length_squared()));
        if let Some(at) = candidates.iter().find(|at| self.blockers(**at, **at + size, exclude).is_empty()) {
            return Ok(*at);
        }
        let slab =
            self.blockers(Vec3::new(smin.x, smin.y, smax.z), Vec3::new(smax.x, smax.y, smax.z + size.z), exclude);
        Err(format!("its top is taken by {}", describe(&self.scene, &slab)))
    }

    /// Present instances whose boxes overlap `[min, max]`, but those in `exclude`.
    fn blockers(&self, min: Vec3, max: Vec3, exclude: &[u16]) -> Vec<u16> {
        self.scene
            .present_instances()
            .filter(|i| !exclude.contains(&i.id))
            .filter(|i| overlaps(min, max, i.box_min_m, i.box_max_m))
            .map(|i| i.id)
            .collect()
    }

    fn add_onto(
        &mut self,
        index: usize,
        label: &str,
        onto: u16,
        size: Option<[f32; 3]>,
    ) -> Result<AppliedChange, SourceError> {
        let surface = self.surface(index, onto, None)?;
        let kind = added_kind(label);
        let [w, d, h] = size.unwrap_or(kind.size_m);
        let extent = if kind.cylinder { Vec3::new(w.min(d), w.min(d), h) } else { Vec3::new(w, d, h) };
        let at = self.free_spot_on(&surface, extent, &[]).map_err(|reason| {
            err(index, "onto", format!("no room for a new {label} on top of {onto} ({}): {reason}", surface.label))
        })?;
        let id = self.new_object(index, label, kind, at, at + extent)?;
        self.scene.edges.push(GtEdge { source: id, target: onto, kind: "spatial", relation: "on" });
        Ok(AppliedChange {
            to: Some((at, at + extent)),
            onto: Some(onto),
            ..blank(ChangeKind::Added, id, label.to_owned())
        })
    }

    fn add_in_front(
        &mut self,
        index: usize,
        frame: u64,
        label: &str,
        target: u16,
        size: Option<[f32; 3]>,
    ) -> Result<AppliedChange, SourceError> {
        let info = self.lookup(index, "in_front_of", target)?.clone();
        let (axis, sign) = front_of(&self.scene, &info);
        let side = 1 - axis;
        let (tmin, tmax) = (info.box_min_m, info.box_max_m);
        let [w, d, h] = size.unwrap_or([
            (tmax[side] - tmin[side] + 0.1).clamp(0.3, 2.0),
            0.2,
            (tmax.z + 0.1).clamp(0.3, CEILING_HEIGHT_M - 0.3),
        ]);
        let room = self.scene.size;
        let front = if sign > 0.0 { tmax[axis] } else { tmin[axis] };
        let middle = (tmin[side] + tmax[side]) * 0.5;
        let mut reason = String::from("no place tried");
        for gap in OCCLUDER_GAPS_M {
            for shift in OCCLUDER_SHIFTS_M {
                let (near, far) = (front + sign * gap, front + sign * (gap + d));
                let mut min = Vec3::ZERO;
                let mut max = Vec3::new(0.0, 0.0, h);
                min[axis] = near.min(far);
                max[axis] = near.max(far);
                min[side] = (middle + shift - w * 0.5).clamp(0.0, (room[side] - w).max(0.0));
                max[side] = min[side] + w;
                if min.cmplt(Vec3::splat(-OVERLAP_TOLERANCE_M)).any() || max.cmpgt(room + OVERLAP_TOLERANCE_M).any() {
                    reason = "it would stand outside the room".to_owned();
                    continue;
                }
                let blocking = self.blockers(min, max, &[]);
                if !blocking.is_empty() {
                    reason = format!("{} in the way", describe(&self.scene, &blocking));
                    continue;
                }
                if let Some(k) = self.camera_passes(frame, min, max) {
                    reason = format!("the camera path passes there (frame {k})");
                    continue;
                }
                let kind = AddedKind { cylinder: false, ..added_kind(label) };
                let id = self.new_object(index, label, kind, min, max)?;
                return Ok(AppliedChange {
                    to: Some((min, max)),
                    target: Some(target),
                    ..blank(ChangeKind::Occluder, id, label.to_owned())
                });
            }
        }
        Err(err(
            index,
            "in_front_of",
            format!(
                "no floor for a {w:.2} x {d:.2} x {h:.2} m {label} 0.3-0.5 m in front of {target} ({}): {reason}; try a \
                 smaller size_m or another instance",
                info.label
            ),
        ))
    }

    /// A frame from `frame` on (one lap, or to the end of the run) at which the camera (the
    /// robot under it) comes within [`OCCLUDER_CAMERA_CLEARANCE_M`] of the footprint `[min, max]`.
    fn camera_passes(&self, frame: u64, min: Vec3, max: Vec3) -> Option<u64> {
        let period = self.path.period_frames();
        let end = self.frame_count.map_or(frame + period, |count| count.min(frame + period));
        let (lo, hi) = ((min - OCCLUDER_CAMERA_CLEARANCE_M).truncate(), (max + OCCLUDER_CAMERA_CLEARANCE_M).truncate());
        (frame..end).step_by(3).find(|k| {
            let at = self.path.pose_at(*k).translation.as_vec3().truncate();
            lo.cmple(at).all() && at.cmple(hi).all()
        })
    }

    /// A new object instance `[min, max]` of one primitive (a box, or a vertical cylinder).
    fn new_object(
        &mut self,
        index: usize,
        label: &str,
        kind: AddedKind,
        min: Vec3,
        max: Vec3,
    ) -> Result<u16, SourceError> {
        let scene = &mut self.scene;
        let id = u16::try_from(scene.instances.len() + 1)
            .map_err(|_| err(index, "add", "the scene has no instance id left for another object"))?;
        let material = match scene.materials.iter().position(|m| *m == kind.material) {
            Some(i) => i,
            None => {
                scene.materials.push(kind.material);
                scene.materials.len() - 1
            }
        };
        let material = u16::try_from(material).map_err(|_| err(index, "add", "the scene has too many materials"))?;
        scene.instances.push(InstanceInfo {
            id,
            label: label.to_owned(),
            kind: InstanceKind::Object,
            parent: None,
            box_min_m: min,
            box_max_m: max,
            synonyms: Vec::new(),
            material: kind.material.name.to_owned(),
        });
        scene.affordances.push(Vec::new());
        let shape = if kind.cylinder {
            Shape::Cylinder {
                axis: Axis::Z,
                centre: (min + max) * 0.5,
                radius: (max.x - min.x).min(max.y - min.y) * 0.5,
                half_length: (max.z - min.z) * 0.5,
            }
        } else {
            Shape::Cuboid { min, max }
        };
        scene.primitives.push(Primitive { shape, instance: id, material });
        Ok(id)
    }
}

fn blank(kind: ChangeKind, instance: u16, label: String) -> AppliedChange {
    AppliedChange {
        index: 0,
        frame: 0,
        kind,
        instance,
        label,
        from: None,
        to: None,
        parts: Vec::new(),
        target: None,
        onto: None,
        range_m: None,
    }
}

/// The world axis (0: x, 1: y) and direction (±1) of the front of `info`: away from a wall it
/// stands against (within 15 cm; of several, the one facing the room's centre most), else
/// towards the room's centre.
fn front_of(scene: &Scene, info: &InstanceInfo) -> (usize, f32) {
    let room = scene.size;
    let to_centre = (room * 0.5 - (info.box_min_m + info.box_max_m) * 0.5).truncate();
    let walls = [
        (info.box_min_m.x, 0usize, 1.0f32),
        (room.x - info.box_max_m.x, 0, -1.0),
        (info.box_min_m.y, 1, 1.0),
        (room.y - info.box_max_m.y, 1, -1.0),
    ];
    let against = walls
        .iter()
        .filter(|(distance, _, _)| *distance <= 0.15)
        .max_by(|a, b| (a.2 * to_centre[a.1]).total_cmp(&(b.2 * to_centre[b.1])));
    match against {
        Some(&(_, axis, sign)) => (axis, sign),
        None => {
            let axis = if to_centre.x.abs() >= to_centre.y.abs() { 0 } else { 1 };
            (axis, if to_centre[axis] < 0.0 { -1.0 } else { 1.0 })
        }
    }
}

/// Moves the primitives and boxes of `ids` by `offset`.
fn translate(scene: &mut Scene, ids: &[u16], offset: Vec3) {
    for prim in scene.primitives.iter_mut().filter(|p| ids.contains(&p.instance)) {
        prim.shape = match prim.shape {
            Shape::Cuboid { min, max } => Shape::Cuboid { min: min + offset, max: max + offset },
            Shape::Cylinder { axis, centre, radius, half_length } => {
                Shape::Cylinder { axis, centre: centre + offset, radius, half_length }
            }
        };
    }
    for info in scene.instances.iter_mut().filter(|i| ids.contains(&i.id)) {
        info.box_min_m += offset;
        info.box_max_m += offset;
    }
}

/// Whether two boxes overlap by more than [`OVERLAP_TOLERANCE_M`] along every axis.
fn overlaps(a_min: Vec3, a_max: Vec3, b_min: Vec3, b_max: Vec3) -> bool {
    (a_max.min(b_max) - a_min.max(b_min)).cmpgt(Vec3::splat(OVERLAP_TOLERANCE_M)).all()
}

/// `12 (kettle), 14 (toaster)`.
fn describe(scene: &Scene, ids: &[u16]) -> String {
    let names: Vec<String> =
        ids.iter().filter_map(|id| scene.instance(*id)).map(|i| format!("{} ({})", i.id, i.label)).collect();
    if names.is_empty() { "other instances".to_owned() } else { names.join(", ") }
}
