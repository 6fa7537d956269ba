//! The change script of `[source.synthetic]` (`[[source.synthetic.changes]]`, [`SceneChange`]):
//! from a given frame or lap on, the world is different. An object is removed, moved onto
//! another or added (on top of an object, or on the floor in front of one as an occluder), or
//! the sensor stops reading depth on an instance or reads garbage beyond a range (controls).
//!
//! The script is checked and applied once, when the source is made ([`apply`]): every change
//! in frame order (entries at the same frame in the order they are written), giving the scene
//! of each epoch. The renderer draws frame `k` from the scene of the last epoch that starts at
//! or before `k`, so colour, depth and the instance-id side channel agree; the camera path is
//! the one planned on the generated room.
//!
//! Identity: instance ids never change. A removed instance keeps its entry in
//! [`Scene::instances`] (without primitives; [`Scene::is_present`] is false); an added object
//! gets the next id (the largest so far plus one). Removing an object removes its parts too;
//! removing a part (a knob that came off, a wall plate) removes only the part. A part cannot be
//! moved (its object is), nor can an object that has another object on it be moved or removed
//! (move or remove that one first).

use glam::Vec3;
use serde::{Deserialize, Serialize};

use op3dsg_drivers::source::SourceError;

use crate::path::CameraPath;
use crate::scene::{Axis, CEILING_HEIGHT_M, GtEdge, Material, Primitive, Scene, Shape};
use crate::{InstanceInfo, InstanceKind};

/// One entry of the change script, `[[source.synthetic.changes]]`: when (exactly one of
/// `at_frame` / `at_lap`) and one action (`remove`, `move` with `onto`, `add` with `onto` or
/// `in_front_of`, `hide_depth` or `degrade_depth_beyond_m`). Instance ids are those
/// `op3dsg gt --room R --seed S` lists. Checked by [`crate::SyntheticSource::new`]; a flat
/// struct so that a mistake is refused naming its key.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SceneChange {
    /// The change holds from this frame on (absolute frame number; an endless source keeps
    /// looping its path).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at_frame: Option<u64>,
    /// The change holds from the start of this lap of the camera path on: frame
    /// `at_lap * period_frames`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub at_lap: Option<u64>,
    /// Remove this instance: an object vanishes with its parts, a part alone.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub remove: Option<u16>,
    /// Move this object (not a part) and its parts `onto` another object.
    #[serde(rename = "move", skip_serializing_if = "Option::is_none")]
    pub move_instance: Option<u16>,
    /// The object whose top a moved or added object is put on: a free spot of its top face,
    /// inside its footprint, clear of every other instance's box.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub onto: Option<u16>,
    /// Add a new object with this label (new id: the largest so far plus one), `onto` an object
    /// or `in_front_of` an instance.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub add: Option<String>,
    /// The added object is an occluder standing on the floor in front of this instance (between
    /// it and the room's centre, 0.3–0.5 m from its front), by default as wide as it and a
    /// little taller.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub in_front_of: Option<u16>,
    /// Size of an added object, metres: `[width, depth, height]`; with `onto` width is along
    /// world x and depth along world y, with `in_front_of` width is along the instance's front
    /// and depth away from it. A cylinder label (`mug`, `bowl`, `plant`) takes the smaller of
    /// width and depth as its diameter. Default: the label's ([`ADDED_KINDS`], else a 0.25 m
    /// cube) with `onto`, sized to hide the instance with `in_front_of`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub size_m: Option<[f32; 3]>,
    /// From then on the sensor reads no depth (0) on this instance's pixels; colour and
    /// instance ids are unchanged (a control: the object itself does not change).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hide_depth: Option<u16>,
    /// From then on depth beyond this range (metres) is garbage: an error of sigma
    /// [`crate::noise::FAR_SIGMA_M`] and a share of pixels reading 0.3–1.0 m too far (a control:
    /// a revisit from beyond the trusted range).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub degrade_depth_beyond_m: Option<f32>,
}

/// What a change did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ChangeKind {
    /// `remove`: the instance (and an object's parts) vanished.
    Removed,
    /// `move` … `onto`: the object and its parts moved onto another object.
    Moved,
    /// `add` … `onto`: a new object on top of another.
    Added,
    /// `add` … `in_front_of`: a new object on the floor hiding [`AppliedChange::target`].
    Occluder,
    /// `hide_depth`: no depth on [`AppliedChange::target`]'s pixels.
    DepthHole,
    /// `degrade_depth_beyond_m`: depth beyond [`AppliedChange::range_m`] is garbage.
    FarDepth,
}

/// One change of the script as applied, for evaluation.
#[derive(Debug, Clone, PartialEq)]
pub struct AppliedChange {
    /// Index of the entry in the script (`changes[index]`).
    pub index: usize,
    /// First frame that shows the change.
    pub frame: u64,
    /// What happened.
    pub kind: ChangeKind,
    /// The removed, moved or added instance (the occluder for [`ChangeKind::Occluder`], the
    /// depthless instance for [`ChangeKind::DepthHole`]); 0 for [`ChangeKind::FarDepth`].
    pub instance: u16,
    /// Its label (empty for [`ChangeKind::FarDepth`]).
    pub label: String,
    /// Its world box (min, max) before the change (removed and moved instances).
    pub from: Option<(Vec3, Vec3)>,
    /// Its world box (min, max) after the change (moved and added instances).
    pub to: Option<(Vec3, Vec3)>,
    /// The ids of the object's parts that went with it (removed and moved objects).
    pub parts: Vec<u16>,
    /// The instance an occluder hides or whose depth is hidden.
    pub target: Option<u16>,
    /// The object a moved or added object was put on.
    pub onto: Option<u16>,
    /// The range beyond which depth is garbage ([`ChangeKind::FarDepth`]).
    pub range_m: Option<f32>,
}

/// An object `add` knows by label: default size `[width, depth, height]` (metres), shape and
/// material.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AddedKind {
    /// Label.
    pub label: &'static str,
    /// Default `[width, depth, height]`, metres.
    pub size_m: [f32; 3],
    /// A vertical cylinder (diameter: the smaller of width and depth) rather than a box.
    pub cylinder: bool,
    /// Its material.
    pub material: Material,
}

/// The labels `add` knows; any other label is a [`GENERIC_ADDED`] 0.25 m cube.
pub const ADDED_KINDS: [AddedKind; 5] = [
    AddedKind {
        label: "box",
        size_m: [0.3, 0.25, 0.2],
        cylinder: false,
        material: Material::new("cardboard", [0.62, 0.47, 0.3], 0.05, 4.0),
    },
    AddedKind {
        label: "mug",
        size_m: [0.08, 0.08, 0.1],
        cylinder: true,
        material: Material::new("blue glazed ceramic", [0.2, 0.38, 0.68], 0.5, 40.0),
    },
    AddedKind {
        label: "bowl",
        size_m: [0.16, 0.16, 0.07],
        cylinder: true,
        material: Material::new("cream ceramic", [0.9, 0.85, 0.72], 0.4, 30.0),
    },
    AddedKind {
        label: "book",
        size_m: [0.16, 0.24, 0.04],
        cylinder: false,
        material: Material::new("red book cloth", [0.58, 0.12, 0.1], 0.05, 4.0),
    },
    AddedKind {
        label: "plant",
        size_m: [0.2, 0.2, 0.4],
        cylinder: true,
        material: Material::new("leaf green", [0.2, 0.48, 0.18], 0.1, 8.0),
    },
];

/// What `add` makes of a label it does not know.
pub const GENERIC_ADDED: AddedKind = AddedKind {
    label: "",
    size_m: [0.25, 0.25, 0.25],
    cylinder: false,
    material: Material::new("grey plastic", [0.5, 0.5, 0.52], 0.3, 20.0),
};

/// Gap between an occluder and the front of what it hides, metres, in order of preference.
const OCCLUDER_GAPS_M: [f32; 5] = [0.4, 0.35, 0.45, 0.3, 0.5];
/// Sideways shifts of an occluder tried when the centred place is taken, metres.
const OCCLUDER_SHIFTS_M: [f32; 5] = [0.0, 0.1, -0.1, 0.2, -0.2];
/// How close the camera (the robot under it) may pass an occluder's footprint, metres.
const OCCLUDER_CAMERA_CLEARANCE_M: f32 = 0.2;
/// Grid of the free-spot search on a top face, metres.
const SPOT_STEP_M: f32 = 0.02;
/// Boxes may touch; they overlap when they share more than this along every axis, metres.
const OVERLAP_TOLERANCE_M: f32 = 1e-3;

fn err(index: usize, key: &str, message: impl std::fmt::Display) -> SourceError {
    if key.is_empty() {
        SourceError::Config(format!("changes[{index}]: {message}"))
    } else {
        SourceError::Config(format!("changes[{index}].{key}: {message}"))
    }
}

/// A checked action.
#[derive(Debug, Clone, PartialEq)]
enum Action {
    Remove(u16),
    Move { id: u16, onto: u16 },
    AddOnto { label: String, onto: u16, size: Option<[f32; 3]> },
    AddInFront { label: String, target: u16, size: Option<[f32; 3]> },
    HideDepth(u16),
    FarDepth(f32),
}

impl SceneChange {
    /// The first frame showing change `index` of the script.
    fn start_frame(&self, index: usize, period: u64, frame_count: Option<u64>) -> Result<u64, SourceError> {
        let (key, frame) = match (self.at_frame, self.at_lap) {
            (None, None) => {
                return Err(err(
                    index,
                    "at_frame",
                    format!(
                        "a change needs when: at_frame = N or at_lap = L (lap L starts at frame L * {period}, one lap of \
                         the camera path)"
                    ),
                ));
            }
            (Some(_), Some(_)) => return Err(err(index, "at_lap", "give at_frame or at_lap, not both")),
            (Some(frame), None) => ("at_frame", frame),
            (None, Some(lap)) => {
                let frame = lap.checked_mul(period).ok_or_else(|| {
                    err(index, "at_lap", format!("lap {lap} is beyond any run (a lap is {period} frames)"))
                })?;
                ("at_lap", frame)
            }
        };
        if let Some(count) = frame_count.filter(|count| frame >= *count) {
            let what = if key == "at_lap" {
                format!("lap {} starts at frame {frame}", frame / period)
            } else {
                format!("frame {frame}")
            };
            let last = match count.checked_sub(1) {
                Some(last) => format!("the last frame is {last}"),
                None => "the run has no frame".to_owned(),
            };
            return Err(err(
                index,
                key,
                format!(
                    "{what}, past the end of the run (frame_count = {count}: {last}; lap L starts at frame L * \
                     {period}): choose an earlier one or raise frame_count"
                ),
            ));
        }
        Ok(frame)
    }

    /// The action of change `index`, with its companion keys checked.
    fn action(&self, index: usize) -> Result<Action, SourceError> {
        let actions: Vec<&str> = [
            ("remove", self.remove.is_some()),
            ("move", self.move_instance.is_some()),
            ("add", self.add.is_some()),
            ("hide_depth", self.hide_depth.is_some()),
            ("degrade_depth_beyond_m", self.degrade_depth_beyond_m.is_some()),
        ]
        .into_iter()
        .filter_map(|(key, set)| set.then_some(key))
        .collect();
        let action = match actions.as_slice() {
            [] => {
                return Err(err(
                    index,
                    "",
                    "no action: set one of remove, move (with onto), add (with onto or in_front_of), hide_depth or \
                     degrade_depth_beyond_m",
                ));
            }
            [one] => *one,
            [first, second, ..] => {
                return Err(err(
                    index,
                    second,
                    format!(
                        "one action per change, and this one also has {first}: write each in its own \
                         [[source.synthetic.changes]] entry"
                    ),
                ));
            }
        };
        self.check_companions(index, action)?;
        Ok(match action {
            "remove" => Action::Remove(self.remove.unwrap_or_default()),
            "move" => {
                let onto = self.onto.ok_or_else(|| {
                    err(index, "move", "needs onto = <instance id>: the object whose top it is put on")
                })?;
                Action::Move { id: self.move_instance.unwrap_or_default(), onto }
            }
            "add" => self.add_action(index)?,
            "hide_depth" => Action::HideDepth(self.hide_depth.unwrap_or_default()),
            _ => {
                let range = self.degrade_depth_beyond_m.unwrap_or_default();
                if !(range.is_finite() && range > 0.0) {
                    return Err(err(
                        index,
                        "degrade_depth_beyond_m",
                        format!("expected a positive range in metres, found {range}"),
                    ));
                }
                Action::FarDepth(range)
            }
        })
    }

    /// Refuses `onto`, `in_front_of` and `size_m` beside an action they do not go with, and a
    /// bad size.
    fn check_companions(&self, index: usize, action: &str) -> Result<(), SourceError> {
        if self.onto.is_some() && !matches!(action, "move" | "add") {
            return Err(err(index, "onto", format!("goes with move or add (where the object is put), not {action}")));
        }
        if self.in_front_of.is_some() && action != "add" {
            return Err(err(
                index,
                "in_front_of",
                format!("goes with add (a new occluder), not {action}; a moved object goes onto = <instance id>"),
            ));
        }
        if let Some(size) = self.size_m {
            if action != "add" {
                return Err(err(index, "size_m", format!("goes with add (the new object's size), not {action}")));
            }
            if let Some(bad) = size.iter().find(|v| !(v.is_finite() && **v > 0.0 && **v <= 5.0)) {
                return Err(err(
                    index,
                    "size_m",
                    format!("expected [width, depth, height] in metres, each above 0 and at most 5, found {bad}"),
                ));
            }
        }
        Ok(())
    }

    fn add_action(&self, index: usize) -> Result<Action, SourceError> {
        let label = self.add.as_deref().unwrap_or_default().trim().to_lowercase();
        if label.is_empty() {
            return Err(err(index, "add", "expected the new object's label, such as \"box\", found an empty string"));
        }
        let size = self.size_m;
        match (self.onto, self.in_front_of) {
            (Some(onto), None) => Ok(Action::AddOnto { label, onto, size }),
            (None, Some(target)) => Ok(Action::AddInFront { label, target, size }),
            _ => Err(err(
                index,
                "add",
                "needs exactly one of onto = <id> (on top of that object) or in_front_of = <id> (on the floor in front \
                 of that instance, hiding it)",
            )),
        }
    }
}

/// The scenes of a change script: `(first frame, scene)` in frame order, the first being the
/// generated room from frame 0, and what each change did.
#[derive(Debug, Clone)]
pub(crate) struct Script {
    pub(crate) epochs: Vec<(u64, Scene)>,
    pub(crate) applied: Vec<AppliedChange>,
}

/// Checks `changes` against the room `initial` (its camera path `path`, the run's
/// `frame_count`) and applies them in frame order. Errors start with `changes[i].<key>`.
pub(crate) fn apply(
    initial: &Scene,
    changes: &[SceneChange],
    path: &CameraPath,
    frame_count: Option<u64>,
) -> Result<Script, SourceError> {
    let period = path.period_frames();
    let mut order = Vec::with_capacity(changes.len());
    for (index, change) in changes.iter().enumerate() {
        let frame = change.start_frame(index, period, frame_count)?;
        order.push((frame, index, change.action(index)?));
    }
    // Stable: entries of the same frame keep their order.
    order.sort_by_key(|(frame, _, _)| *frame);
    let mut applier = Applier { scene: initial.clone(), path, frame_count, applied: Vec::new() };
    let mut epochs = vec![(0, initial.clone())];
    for (frame, index, action) in order {
        applier.apply(index, frame, action)?;
        // The first epoch stays the generated room; changes of one frame make one epoch.
        let later = epochs.len() > 1;
        match epochs.last_mut() {
            Some((start, scene)) if later && *start == frame => *scene = applier.scene.clone(),
            _ => epochs.push((frame, applier.scene.clone())),
        }
    }
    Ok(Script { epochs, applied: applier.applied })
}

/// The scene as the changes so far left it.
struct Applier<'a> {
    scene: Scene,
    path: &'a CameraPath,
    frame_count: Option<u64>,
    applied: Vec<AppliedChange>,
}

impl Applier<'_> {
    fn apply(&mut self, index: usize, frame: u64, action: Action) -> Result<(), SourceError> {
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

/// The known kind of `label`, else the generic cube.
pub fn added_kind(label: &str) -> AddedKind {
    ADDED_KINDS.iter().find(|k| k.label == label).copied().unwrap_or(GENERIC_ADDED)
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
