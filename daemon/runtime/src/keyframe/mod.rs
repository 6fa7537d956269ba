//! The keyframe gate: gives each frame its `world_from_camera` and decides whether it is a
//! keyframe. Shared by the threaded [`crate::pipeline`] (on its `op3dsg-keyframe` thread,
//! `thread.rs`) and the synchronous batch runner of `op3dsg-sim`, so both select exactly the same
//! keyframes.
//!
//! A frame's pose comes from the frame itself (`pose.source = "frame"`) or from the pose buffer
//! filled from `<prefix>/pose` and interpolated to the frame stamp (`"ipc"`). A frame without a
//! pose within `pose.tolerance_ms` is dropped. A frame with a pose is a keyframe when it is the
//! first one, or when since the last keyframe the camera moved `keyframe.min_translation_m`,
//! turned `keyframe.min_rotation_deg`, or `keyframe.max_interval_s` passed.
//!
//! ```
//! use op3dsg_runtime::keyframe::{GateDecision, KeyframeGate};
//! let profile = op3dsg_runtime::config::load(None, &[]).unwrap().profile;
//! let mut gate = KeyframeGate::new(&profile.keyframe, &profile.pose);
//! let mut frame = op3dsg_drivers::frame::Frame::new(op3dsg_drivers::frame::Intrinsics::d435i_640x480());
//! frame.world_from_camera = Some(op3dsg_drivers::pose::Isometry::IDENTITY);
//! assert!(matches!(gate.decide(&frame), GateDecision::Keyframe(_)));
//! frame.stamp_ns = 1_000_000; // 1 ms later, not moved: not a keyframe
//! assert_eq!(gate.decide(&frame), GateDecision::Skip);
//! ```

pub(crate) mod thread;

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::{Isometry, PoseBuffer, StampedPose};
use op3dsg_ipc_types::{PoseKind, PoseStamped};

use crate::config::{KeyframeConfig, PoseConfig, PoseSourceKind};

/// What the gate decided about one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum GateDecision {
    /// No pose within tolerance: the frame is dropped (and counted by the caller).
    NoPose,
    /// The camera has not moved enough since the last keyframe.
    Skip,
    /// A keyframe, taken at this `world_from_camera`.
    Keyframe(Isometry),
}

/// The keyframe gate's state (see the module docs).
#[derive(Debug)]
pub struct KeyframeGate {
    pose_source: PoseSourceKind,
    poses: PoseBuffer,
    base_from_camera: Option<Isometry>,
    /// Stamp and pose of the last keyframe.
    last: Option<(u64, Isometry)>,
    min_translation_m: f64,
    min_rotation_rad: f64,
    max_interval_ns: u64,
}

impl KeyframeGate {
    /// A gate that has seen no frame yet.
    pub fn new(config: &KeyframeConfig, pose_config: &PoseConfig) -> Self {
        let tolerance_ns = (pose_config.tolerance_ms * 1e6) as u64;
        Self {
            pose_source: pose_config.source,
            poses: PoseBuffer::new(pose_config.buffer_len, tolerance_ns),
            base_from_camera: pose_config.base_from_camera.map(|t| t.to_isometry()),
            last: None,
            min_translation_m: config.min_translation_m,
            min_rotation_rad: config.min_rotation_deg.to_radians(),
            max_interval_ns: (config.max_interval_s * 1e9) as u64,
        }
    }

    /// Adds a pose received on the pose service. Returns `false` when it is rejected: an unknown
    /// kind, or a `world_from_base` pose without `pose.base_from_camera` in the profile.
    pub fn add_pose(&mut self, pose: &PoseStamped) -> bool {
        let world_from_x =
            Isometry::new(glam::DQuat::from_array(pose.rotation_xyzw), glam::DVec3::from_array(pose.translation_m));
        let world_from_camera = match (PoseKind::from_u8(pose.kind), self.base_from_camera) {
            (Some(PoseKind::WorldFromCamera), _) => world_from_x,
            (Some(PoseKind::WorldFromBase), Some(base_from_camera)) => world_from_x * base_from_camera,
            _ => return false,
        };
        self.poses.push(StampedPose { stamp_ns: pose.stamp_ns, world_from_camera });
        true
    }

    /// Looks up the frame's pose and applies the motion test; a keyframe becomes the reference
    /// for the next test.
    pub fn decide(&mut self, frame: &Frame) -> GateDecision {
        let pose = match self.pose_source {
            PoseSourceKind::Frame => frame.world_from_camera,
            PoseSourceKind::Ipc => self.poses.lookup(frame.stamp_ns),
        };
        let Some(world_from_camera) = pose else {
            return GateDecision::NoPose;
        };
        let is_keyframe = match self.last {
            None => true,
            Some((stamp_ns, previous)) => {
                let moved = previous.translation.distance(world_from_camera.translation);
                let turned = previous.rotation.angle_between(world_from_camera.rotation);
                moved >= self.min_translation_m
                    || turned >= self.min_rotation_rad
                    || frame.stamp_ns.saturating_sub(stamp_ns) >= self.max_interval_ns
            }
        };
        if is_keyframe {
            self.last = Some((frame.stamp_ns, world_from_camera));
            GateDecision::Keyframe(world_from_camera)
        } else {
            GateDecision::Skip
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use op3dsg_drivers::frame::Intrinsics;

    fn profile() -> crate::config::Profile {
        crate::config::load(None, &[]).unwrap().profile
    }

    fn frame_at(stamp_ns: u64, x_m: f64, yaw_deg: f64) -> Frame {
        let mut frame = Frame::new(Intrinsics { width: 4, height: 4, fx: 4.0, fy: 4.0, cx: 2.0, cy: 2.0 });
        frame.stamp_ns = stamp_ns;
        frame.world_from_camera =
            Some(Isometry::new(glam::DQuat::from_rotation_z(yaw_deg.to_radians()), glam::DVec3::new(x_m, 0.0, 0.0)));
        frame
    }

    #[test]
    fn motion_rotation_and_interval_each_make_a_keyframe() {
        let p = profile();
        // Base profile: 0.10 m, 8 degrees, 1 s.
        let mut gate = KeyframeGate::new(&p.keyframe, &p.pose);
        let ms = 1_000_000u64;
        assert!(matches!(gate.decide(&frame_at(0, 0.0, 0.0)), GateDecision::Keyframe(_)));
        assert_eq!(gate.decide(&frame_at(33 * ms, 0.05, 4.0)), GateDecision::Skip);
        assert!(matches!(gate.decide(&frame_at(66 * ms, 0.10, 0.0)), GateDecision::Keyframe(_)));
        assert_eq!(gate.decide(&frame_at(100 * ms, 0.12, 5.0)), GateDecision::Skip);
        assert!(matches!(gate.decide(&frame_at(133 * ms, 0.10, 8.5)), GateDecision::Keyframe(_)));
        assert_eq!(gate.decide(&frame_at(1000 * ms, 0.10, 8.5)), GateDecision::Skip);
        assert!(matches!(gate.decide(&frame_at(1133 * ms, 0.10, 8.5)), GateDecision::Keyframe(_)));
    }

    #[test]
    fn ipc_poses_are_interpolated_and_bad_kinds_rejected() {
        let mut p = profile();
        p.pose.source = PoseSourceKind::Ipc;
        let mut gate = KeyframeGate::new(&p.keyframe, &p.pose);
        let mut frame = frame_at(10_000_000, 0.0, 0.0);
        frame.world_from_camera = None;
        assert_eq!(gate.decide(&frame), GateDecision::NoPose);
        let pose = |stamp_ns: u64, x: f64, kind: PoseKind| PoseStamped {
            stamp_ns,
            translation_m: [x, 0.0, 0.0],
            rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
            kind: kind as u8,
            ..PoseStamped::default()
        };
        assert!(gate.add_pose(&pose(0, 0.0, PoseKind::WorldFromCamera)));
        assert!(gate.add_pose(&pose(20_000_000, 2.0, PoseKind::WorldFromCamera)));
        // No base_from_camera in the base profile: world_from_base poses are refused.
        assert!(!gate.add_pose(&pose(30_000_000, 9.0, PoseKind::WorldFromBase)));
        match gate.decide(&frame) {
            GateDecision::Keyframe(w) => assert!((w.translation.x - 1.0).abs() < 1e-9, "{w:?}"),
            other => panic!("expected a keyframe, got {other:?}"),
        }
    }
}
