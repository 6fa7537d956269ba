//! `[pose]` and `[keyframe]`: where a frame's pose comes from, how received poses are used, and
//! which frames become keyframes (the rules are in the module docs of [`crate::keyframe`]).

use serde::{Deserialize, Serialize};

/// Pose source kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseSourceKind {
    /// The frame source carries `world_from_camera` (synthetic, replay).
    Frame,
    /// The navigation stack publishes [`op3dsg_ipc_types::PoseStamped`] on `<prefix>/pose`.
    Ipc,
    /// The robot's ROS 2 tf tree, through Zenoh (`[ros2]`, `crate::ros2`).
    Ros2,
}

impl PoseSourceKind {
    /// Poses arrive apart from the frames (over iceoryx2 or from tf) and the keyframe gate
    /// matches them to frames by stamp.
    pub fn is_received(self) -> bool {
        matches!(self, Self::Ipc | Self::Ros2)
    }

    /// The health record's `pose_source` value ([`op3dsg_ipc_types::POSE_SOURCES`]).
    pub fn wire(self) -> u8 {
        match self {
            Self::Frame => 1,
            Self::Ipc => 2,
            Self::Ros2 => 3,
        }
    }
}

/// A fixed transform in the profile.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransformConfig {
    /// Translation, metres.
    pub translation_m: [f64; 3],
    /// Unit quaternion `[x, y, z, w]`.
    pub rotation_xyzw: [f64; 4],
}

impl TransformConfig {
    /// As an isometry.
    pub fn to_isometry(&self) -> op3dsg_drivers::pose::Isometry {
        let [x, y, z, w] = self.rotation_xyzw;
        op3dsg_drivers::pose::Isometry::new(
            glam::DQuat::from_xyzw(x, y, z, w),
            glam::DVec3::from_array(self.translation_m),
        )
    }
}

/// `[pose]`: where a frame's `world_from_camera` comes from and how received poses are used
/// (the rules are in [`crate::keyframe`]'s docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseConfig {
    /// Where poses come from.
    pub source: PoseSourceKind,
    /// Hold tolerance, milliseconds: without two poses around a frame close enough to
    /// interpolate, the nearest pose is used when it is at most this far from the frame's stamp
    /// (never further: no extrapolation); otherwise the frame is dropped and counted.
    pub tolerance_ms: f64,
    /// Two poses at most this far apart (milliseconds) are interpolated to the stamp of a frame
    /// between them (a 10 Hz stream is 100 ms apart; the default also bridges one lost pose).
    pub max_interpolation_gap_ms: f64,
    /// A frame stamped after the newest pose waits up to this long (milliseconds, host clock)
    /// for the pose after it before it is held within `tolerance_ms` or dropped (0 = never wait).
    pub max_wait_ms: f64,
    /// A pose stamped more than this (milliseconds) after the newest frame is refused as
    /// `future`, and not adopted, so it cannot block the poses that follow.
    pub future_tolerance_ms: f64,
    /// When frame and pose stamps disagree by more than the tolerances for this long (seconds),
    /// the daemon warns that their clocks differ (then again at most once per this period).
    pub clock_warning_after_s: f64,
    /// Poses kept for interpolation.
    pub buffer_len: usize,
    /// Fixed `base_from_camera` for `world_from_base` poses (rigid mounts only).
    #[serde(default)]
    pub base_from_camera: Option<TransformConfig>,
}

/// `[keyframe]`: a frame becomes a keyframe when the camera moved or turned enough since the
/// last keyframe, or when `max_interval_s` passed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyframeConfig {
    /// Translation since the last keyframe, metres.
    pub min_translation_m: f64,
    /// Rotation since the last keyframe, degrees.
    pub min_rotation_deg: f64,
    /// Longest time without a keyframe, seconds (0 = every frame is a keyframe).
    pub max_interval_s: f64,
}

impl PoseConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(self.tolerance_ms > 0.0 && self.tolerance_ms <= 5000.0) {
            return Err(format!("{path}.tolerance_ms: must be within (0, 5000], got {}", self.tolerance_ms));
        }
        let gap = self.max_interpolation_gap_ms;
        if !(gap > 0.0 && gap <= 10_000.0) {
            return Err(format!("{path}.max_interpolation_gap_ms: must be within (0, 10000] milliseconds, got {gap}"));
        }
        if !(0.0..=5000.0).contains(&self.max_wait_ms) {
            return Err(format!(
                "{path}.max_wait_ms: must be within [0, 5000] milliseconds (0 = never wait), got {}",
                self.max_wait_ms
            ));
        }
        let future = self.future_tolerance_ms;
        if !(future > 0.0 && future <= 3_600_000.0) {
            return Err(format!("{path}.future_tolerance_ms: must be within (0, 3600000] milliseconds, got {future}"));
        }
        let clock = self.clock_warning_after_s;
        if !(clock > 0.0 && clock <= 3600.0) {
            return Err(format!("{path}.clock_warning_after_s: must be within (0, 3600] seconds, got {clock}"));
        }
        if !(2..=100_000).contains(&self.buffer_len) {
            return Err(format!("{path}.buffer_len: must be within [2, 100000], got {}", self.buffer_len));
        }
        if let Some(t) = &self.base_from_camera {
            if !t.translation_m.iter().all(|v| v.is_finite()) {
                return Err(format!(
                    "{path}.base_from_camera.translation_m: must be finite metres, got {:?}",
                    t.translation_m
                ));
            }
            let norm = t.rotation_xyzw.iter().map(|v| v * v).sum::<f64>().sqrt();
            let unit = (norm - 1.0).abs() < 1e-3;
            if !unit {
                return Err(format!(
                    "{path}.base_from_camera.rotation_xyzw: must be a unit quaternion, norm is {norm}"
                ));
            }
        }
        Ok(())
    }
}

impl KeyframeConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let moved = self.min_translation_m >= 0.0;
        if !moved {
            return Err(format!("{path}.min_translation_m: must be >= 0, got {}", self.min_translation_m));
        }
        if !(0.0..=180.0).contains(&self.min_rotation_deg) {
            return Err(format!("{path}.min_rotation_deg: must be within [0, 180], got {}", self.min_rotation_deg));
        }
        let interval = self.max_interval_s >= 0.0;
        if !interval {
            return Err(format!("{path}.max_interval_s: must be >= 0, got {}", self.max_interval_s));
        }
        Ok(())
    }
}
