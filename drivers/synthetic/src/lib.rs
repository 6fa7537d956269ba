//! # op3dsg synthetic world
//!
//! Seeded procedural rooms with exact ground truth, rendered by a CPU ray caster with a
//! D435i-like depth noise model along a robot-like camera path.
//!
//! - [`SyntheticConfig`] → [`SyntheticSource::new`] → a
//!   [`FrameSource`](op3dsg_drivers::source::FrameSource) whose frames carry RGB, noisy depth
//!   and `world_from_camera`, like any camera with poses.
//! - The ground truth travels beside the frames, never in them: [`SyntheticSource::ground_truth`]
//!   gives the [`Scene`] (instance id `k` is ground-truth node id `k`, [`Scene::instance`];
//!   [`Scene::ground_truth`] gives the graph JSON) and the [`InstanceIdChannel`] that holds the
//!   per-pixel instance ids of each delivered frame. Only simulation and evaluation read it.
//!
//! ```
//! use op3dsg_drivers::frame::Frame;
//! use op3dsg_drivers::source::{FrameSource, SourceStatus};
//! use op3dsg_synthetic::{RoomKind, SyntheticConfig, SyntheticSource};
//!
//! let config = SyntheticConfig { room: RoomKind::Kitchen, seed: 1, frame_count: Some(2), ..Default::default() };
//! let mut source = SyntheticSource::new(&config).unwrap();
//! let truth = source.ground_truth();
//! let mut frame = Frame::new(source.intrinsics());
//! assert_eq!(source.next_frame(&mut frame).unwrap(), SourceStatus::Frame);
//! assert!(frame.world_from_camera.is_some());
//! let visible = truth.instance_ids.with_ids(&frame, |ids| ids.iter().any(|&id| id > 0));
//! assert_eq!(visible, Some(true));
//! assert!(truth.scene.ground_truth().nodes.iter().any(|n| n.kind == "part"));
//! ```

use serde::{Deserialize, Serialize};

use op3dsg_drivers::frame::Intrinsics;

mod catalog;
pub mod change;
#[cfg(test)]
mod change_tests;
pub mod noise;
mod path;
mod render;
mod scene;
mod side_channel;
mod source;
#[cfg(test)]
mod tests;
pub mod truth;

pub use catalog::{FUNCTIONAL_RELATIONS, SPATIAL_RELATIONS};
pub use change::{AppliedChange, ChangeKind, SceneChange};
pub use path::{CameraPath, inside_furniture, look_rotation};
pub use render::{Renderer, render};
pub use scene::{Axis, CEILING_HEIGHT_M, GtEdge, Material, Primitive, Scene, Shape};
pub use side_channel::{GroundTruth, InstanceIdChannel};
pub use source::SyntheticSource;

/// Room types of the synthetic benchmark.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum RoomKind {
    /// Cabinets and drawers with handles and knobs, stove and oven with knobs, sink and faucet,
    /// fridge, microwave, kettle/toaster on outlets, switches and lights.
    #[default]
    Kitchen,
    /// Toilet and flush button, sink and faucet, bathtub and faucet, cabinet, switch and light.
    Bathroom,
    /// Bed, dresser and nightstands with handles/knobs, wardrobe, lamp, switch, outlets.
    Bedroom,
    /// TV and remote, TV stand with drawers, sofa, coffee table, power strip and appliances,
    /// lamps and switches.
    LivingRoom,
    /// A test scene, not a benchmark room: one control panel whose rows of knobs and push
    /// buttons share a label within the row but differ in colour (saturated red, blue, green,
    /// yellow, orange, purple), 0.5–1 cm apart, so that telling neighbours apart needs colour
    /// features. Its camera path looks at the panel from 0.55–2.1 m and ±45°.
    ColourPanel,
}

impl RoomKind {
    /// The benchmark rooms.
    pub const ALL: [RoomKind; 4] = [RoomKind::Kitchen, RoomKind::Bathroom, RoomKind::Bedroom, RoomKind::LivingRoom];

    /// Scenes built to test one ability (not part of the benchmark).
    pub const TEST_SCENES: [RoomKind; 1] = [RoomKind::ColourPanel];

    /// The snake_case name (`kitchen`, `bathroom`, `bedroom`, `living_room`, `colour_panel`).
    pub fn as_str(self) -> &'static str {
        match self {
            RoomKind::Kitchen => "kitchen",
            RoomKind::Bathroom => "bathroom",
            RoomKind::Bedroom => "bedroom",
            RoomKind::LivingRoom => "living_room",
            RoomKind::ColourPanel => "colour_panel",
        }
    }

    /// Parses a snake_case name (benchmark rooms and test scenes).
    pub fn parse(name: &str) -> Option<Self> {
        Self::ALL.into_iter().chain(Self::TEST_SCENES).find(|r| r.as_str() == name)
    }
}

/// Depth noise model parameters (D435i-like). See `noise` for the model.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct DepthNoiseConfig {
    /// Standard deviation of depth error at 1 m, metres; the error grows with distance squared
    /// (sigma(z) = sigma_at_1m_m * z^2).
    pub sigma_at_1m_m: f32,
    /// Pixels closer than this read 0 (no depth), metres.
    pub min_range_m: f32,
    /// Pixels farther than this read 0, metres.
    pub max_range_m: f32,
    /// A pixel whose 4-neighbourhood spans a depth jump larger than this fraction of its depth
    /// is a depth edge.
    pub edge_jump_ratio: f32,
    /// Probability that a depth-edge pixel reads 0 (a hole).
    pub edge_hole_probability: f32,
    /// Probability that any other valid pixel reads 0.
    pub random_hole_probability: f32,
}

impl Default for DepthNoiseConfig {
    fn default() -> Self {
        Self {
            sigma_at_1m_m: 0.002,
            min_range_m: 0.28,
            max_range_m: 6.0,
            edge_jump_ratio: 0.05,
            edge_hole_probability: 0.6,
            random_hole_probability: 0.002,
        }
    }
}

/// Configuration of the synthetic source.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SyntheticConfig {
    /// Room type.
    pub room: RoomKind,
    /// Seed of the room layout, materials, camera path and noise.
    pub seed: u64,
    /// Frames to deliver before end of stream; `None` loops the camera path forever.
    pub frame_count: Option<u64>,
    /// Camera intrinsics (D435i colour at 640x480 by default).
    pub intrinsics: Intrinsics,
    /// Simulated camera rate: frame `k` is stamped `k / frame_rate_hz` seconds.
    pub frame_rate_hz: f64,
    /// Depth noise; `None` renders exact depth.
    pub depth_noise: Option<DepthNoiseConfig>,
    /// The change script (`[[source.synthetic.changes]]`): how the world changes during the
    /// run ([`change`]); empty: the room stays as generated.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub changes: Vec<SceneChange>,
}

impl Default for SyntheticConfig {
    fn default() -> Self {
        Self {
            room: RoomKind::Kitchen,
            seed: 1,
            frame_count: None,
            intrinsics: Intrinsics::d435i_640x480(),
            frame_rate_hz: 30.0,
            depth_noise: Some(DepthNoiseConfig::default()),
            changes: Vec::new(),
        }
    }
}

impl SyntheticConfig {
    /// The room after every change of [`SyntheticConfig::changes`] (the generated room without
    /// changes), without rendering: what [`GroundTruth::scene`] of a source made from this
    /// config holds. Checks the change script as [`SyntheticSource::new`] does.
    pub fn final_scene(&self) -> Result<Scene, op3dsg_drivers::source::SourceError> {
        let scene = Scene::generate(self.room, self.seed);
        if self.changes.is_empty() {
            return Ok(scene);
        }
        let path = CameraPath::new(&scene, self.seed, self.frame_rate_hz);
        let mut script = change::apply(&scene, &self.changes, &path, self.frame_count)?;
        Ok(script.epochs.pop().map_or(scene, |(_, last)| last))
    }
}

/// Kind of a scene instance.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InstanceKind {
    /// A whole object.
    Object,
    /// An interactive part of an object.
    Part,
}

/// What the world knows about one instance (ground-truth node).
#[derive(Debug, Clone, PartialEq)]
pub struct InstanceInfo {
    /// Instance id as it appears in `Frame::instance_ids` (1-based; 0 is background/structure).
    pub id: u16,
    /// Canonical label (`cabinet`, `cabinet handle`, `stove knob`, ...).
    pub label: String,
    /// Object or part.
    pub kind: InstanceKind,
    /// Parent object of a part.
    pub parent: Option<u16>,
    /// Axis-aligned world box, metres.
    pub box_min_m: glam::Vec3,
    /// Axis-aligned world box, metres.
    pub box_max_m: glam::Vec3,
    /// Other names a detector may use for it ("cupboard" for cabinet).
    pub synonyms: Vec<String>,
    /// Name of its material (for tests of colour features).
    pub material: String,
}
