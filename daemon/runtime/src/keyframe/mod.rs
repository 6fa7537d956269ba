//! The keyframe gate: gives each frame its `world_from_camera` and decides whether it is a
//! keyframe. Shared by the threaded [`crate::pipeline`] (on its `op3dsg-keyframe` thread,
//! `thread.rs`) and the synchronous batch runner of `op3dsg-sim`, so both select exactly the same
//! keyframes.
//!
//! A frame's pose comes from the frame itself (`pose.source = "frame"`) or from the pose buffer
//! filled from `<prefix>/pose` and interpolated to the frame stamp (`"ipc"`). A received pose is
//! not adopted ([`PoseRefusal`], each counted in health) when its kind cannot be used, when it is
//! older than the newest adopted pose, more than `pose.tolerance_ms` older than the newest frame
//! (no later frame could use it), or more than
//! [`FUTURE_POSE_LIMIT_NS`](op3dsg_ipc_types::FUTURE_POSE_LIMIT_NS) newer than the newest frame
//! (adopting it would make every following pose out of order). A frame without a
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

/// Why [`KeyframeGate::add_pose`] did not adopt a pose (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseRefusal {
    /// `kind` is not a known value.
    UnknownKind,
    /// `world_from_base` without `pose.base_from_camera` in the profile.
    NoBaseFromCamera,
    /// Stamped before the newest adopted pose.
    OutOfOrder,
    /// Stamped more than the tolerance before the newest frame.
    Stale,
    /// Stamped more than [`FUTURE_POSE_LIMIT_NS`](op3dsg_ipc_types::FUTURE_POSE_LIMIT_NS) after
    /// the newest frame.
    Future,
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
    tolerance_ns: u64,
    /// Stamp of the newest frame looked up (`pose.source = "ipc"`).
    newest_frame_ns: Option<u64>,
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
            tolerance_ns,
            newest_frame_ns: None,
        }
    }

    /// Adds a pose received on the pose service (already through
    /// [`check_pose`](op3dsg_ipc_types::check_pose)), or says why it is not adopted.
    pub fn add_pose(&mut self, pose: &PoseStamped) -> Result<(), PoseRefusal> {
        let world_from_x =
            Isometry::new(glam::DQuat::from_array(pose.rotation_xyzw), glam::DVec3::from_array(pose.translation_m));
        let world_from_camera = match (PoseKind::from_u8(pose.kind), self.base_from_camera) {
            (Some(PoseKind::WorldFromCamera), _) => world_from_x,
            (Some(PoseKind::WorldFromBase), Some(base_from_camera)) => world_from_x * base_from_camera,
            (Some(PoseKind::WorldFromBase), None) => return Err(PoseRefusal::NoBaseFromCamera),
            (None, _) => return Err(PoseRefusal::UnknownKind),
        };
        if let Some(frame_ns) = self.newest_frame_ns {
            if pose.stamp_ns.saturating_add(self.tolerance_ns) < frame_ns {
                return Err(PoseRefusal::Stale);
            }
            if pose.stamp_ns > frame_ns.saturating_add(op3dsg_ipc_types::FUTURE_POSE_LIMIT_NS) {
                return Err(PoseRefusal::Future);
            }
        }
        if self.poses.push(StampedPose { stamp_ns: pose.stamp_ns, world_from_camera }) {
            Ok(())
        } else {
            Err(PoseRefusal::OutOfOrder)
        }
    }

    /// Looks up the frame's pose and applies the motion test; a keyframe becomes the reference
    /// for the next test.
    pub fn decide(&mut self, frame: &Frame) -> GateDecision {
        let pose = match self.pose_source {
            PoseSourceKind::Frame => frame.world_from_camera,
            PoseSourceKind::Ipc => {
                self.newest_frame_ns = Some(self.newest_frame_ns.map_or(frame.stamp_ns, |n| n.max(frame.stamp_ns)));
                self.poses.lookup(frame.stamp_ns)
            }
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
        assert_eq!(gate.add_pose(&pose(0, 0.0, PoseKind::WorldFromCamera)), Ok(()));
        assert_eq!(gate.add_pose(&pose(20_000_000, 2.0, PoseKind::WorldFromCamera)), Ok(()));
        // No base_from_camera in the base profile: world_from_base poses are refused.
        assert_eq!(gate.add_pose(&pose(30_000_000, 9.0, PoseKind::WorldFromBase)), Err(PoseRefusal::NoBaseFromCamera));
        assert_eq!(gate.add_pose(&pose(15_000_000, 9.0, PoseKind::WorldFromCamera)), Err(PoseRefusal::OutOfOrder));
        let unknown = PoseStamped { kind: 7, ..pose(25_000_000, 0.0, PoseKind::WorldFromCamera) };
        assert_eq!(gate.add_pose(&unknown), Err(PoseRefusal::UnknownKind));
        match gate.decide(&frame) {
            GateDecision::Keyframe(w) => assert!((w.translation.x - 1.0).abs() < 1e-9, "{w:?}"),
            other => panic!("expected a keyframe, got {other:?}"),
        }
    }

    #[test]
    fn stale_and_future_poses_are_refused_and_do_not_block_later_ones() {
        let mut p = profile();
        p.pose.source = PoseSourceKind::Ipc;
        let mut gate = KeyframeGate::new(&p.keyframe, &p.pose);
        let tolerance_ns = (p.pose.tolerance_ms * 1e6) as u64;
        let at =
            |stamp_ns: u64| PoseStamped { stamp_ns, rotation_xyzw: [0.0, 0.0, 0.0, 1.0], ..PoseStamped::default() };
        let frame_ns = 10_000_000_000u64;
        let mut frame = frame_at(frame_ns, 0.0, 0.0);
        frame.world_from_camera = None;
        // Before any frame there is no reference: anything in order is adopted.
        assert_eq!(gate.add_pose(&at(1)), Ok(()));
        assert_eq!(gate.decide(&frame), GateDecision::NoPose);
        assert_eq!(gate.add_pose(&at(frame_ns - tolerance_ns - 1)), Err(PoseRefusal::Stale));
        let future_ns = frame_ns + op3dsg_ipc_types::FUTURE_POSE_LIMIT_NS + 1;
        assert_eq!(gate.add_pose(&at(future_ns)), Err(PoseRefusal::Future));
        // Not adopted, so the next good pose is not out of order.
        assert_eq!(gate.add_pose(&at(frame_ns + 1_000_000)), Ok(()));
        frame.stamp_ns = frame_ns + 1_000_000;
        assert!(matches!(gate.decide(&frame), GateDecision::Keyframe(_)));
    }
}
