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

mod applier;
use applier::Applier;

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

/// The known kind of `label`, else the generic cube.
pub fn added_kind(label: &str) -> AddedKind {
    ADDED_KINDS.iter().find(|k| k.label == label).copied().unwrap_or(GENERIC_ADDED)
}
