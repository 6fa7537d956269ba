use std::time::{Duration, Instant};

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::pose::{Isometry, PoseAt, PoseMiss};
use op3dsg_ipc_types::{PoseKind, PoseStamped};

use super::gate::ClockCheck;
use super::*;

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

fn camera_pose(stamp_ns: u64, x: f64) -> PoseStamped {
    PoseStamped {
        stamp_ns,
        translation_m: [x, 0.0, 0.0],
        rotation_xyzw: [0.0, 0.0, 0.0, 1.0],
        kind: PoseKind::WorldFromCamera as u8,
        ..PoseStamped::default()
    }
}

fn ipc_gate(p: &crate::config::Profile) -> KeyframeGate {
    let mut pose = p.pose.clone();
    pose.source = PoseSourceKind::Ipc;
    KeyframeGate::new(&p.keyframe, &pose)
}

fn bare_frame(stamp_ns: u64) -> Frame {
    let mut frame = frame_at(stamp_ns, 0.0, 0.0);
    frame.world_from_camera = None;
    frame
}

#[test]
fn stale_and_future_poses_are_refused_and_do_not_block_later_ones() {
    let p = profile();
    let mut gate = ipc_gate(&p);
    let stale_after_ns = (p.pose.max_interpolation_gap_ms.max(p.pose.tolerance_ms) * 1e6) as u64;
    let future_ns = (p.pose.future_tolerance_ms * 1e6) as u64;
    let at = |stamp_ns: u64| camera_pose(stamp_ns, 0.0);
    let frame_ns = 10_000_000_000u64;
    // Before any frame there is no reference: anything in order is adopted.
    assert_eq!(gate.add_pose(&at(1)), Ok(()));
    assert_eq!(gate.decide(&bare_frame(frame_ns)), GateDecision::NoPose);
    assert_eq!(gate.add_pose(&at(frame_ns - stale_after_ns - 1)), Err(PoseRefusal::Stale));
    assert_eq!(gate.add_pose(&at(frame_ns + future_ns + 1)), Err(PoseRefusal::Future));
    // Not adopted, so the next good pose is not out of order.
    assert_eq!(gate.add_pose(&at(frame_ns + 1_000_000)), Ok(()));
    assert!(matches!(gate.decide(&bare_frame(frame_ns + 1_000_000)), GateDecision::Keyframe(_)));
    // A pose still useful to a frame waiting for its pose is not stale.
    gate.set_oldest_waiting(Some(frame_ns + 1_000_000));
    assert_eq!(gate.add_pose(&at(frame_ns + 2_000_000)), Ok(()));
}

#[test]
fn a_future_pose_adopted_before_the_first_frame_is_discarded_when_frames_come() {
    let p = profile();
    let mut gate = ipc_gate(&p);
    let frame_ns = 5_000_000_000u64;
    // A navigation stack sends one pose 100 s ahead before the camera delivers anything.
    assert_eq!(gate.add_pose(&camera_pose(frame_ns + 100_000_000_000, 9.0)), Ok(()));
    assert_eq!(gate.decide(&bare_frame(frame_ns)), GateDecision::NoPose);
    // The good stream resumes: not out of order, because the future pose is gone.
    assert_eq!(gate.add_pose(&camera_pose(frame_ns - 50_000_000, 0.0)), Ok(()));
    assert_eq!(gate.add_pose(&camera_pose(frame_ns + 50_000_000, 1.0)), Ok(()));
    match gate.decide(&bare_frame(frame_ns)) {
        GateDecision::Keyframe(w) => assert!((w.translation.x - 0.5).abs() < 1e-9, "{w:?}"),
        other => panic!("expected a keyframe, got {other:?}"),
    }
}

#[test]
fn frames_after_the_newest_pose_wait_then_hold_only_within_tolerance() {
    let p = profile();
    let mut gate = ipc_gate(&p);
    let ms = 1_000_000u64;
    gate.add_pose(&camera_pose(1000 * ms, 0.0)).expect("first pose");
    gate.add_pose(&camera_pose(1100 * ms, 1.0)).expect("10 Hz");
    let frame = bare_frame(1130 * ms);
    gate.note_frame(frame.stamp_ns);
    assert_eq!(gate.pose_for(&frame, true), PoseAt::WaitForLater);
    // The wait ends without a later pose: 30 ms from the last pose is within the 50 ms hold.
    assert!(matches!(gate.pose_for(&frame, false), PoseAt::Held(w) if w.translation.x == 1.0));
    // 80 ms is not: no extrapolation.
    assert_eq!(gate.pose_for(&bare_frame(1180 * ms), false), PoseAt::Missing(PoseMiss::AfterNewest));
    // The later pose came: 10 Hz poses are interpolated (100 ms apart, within the 250 ms gap).
    gate.add_pose(&camera_pose(1200 * ms, 2.0)).expect("in order");
    assert!(
        matches!(gate.pose_for(&bare_frame(1180 * ms), true), PoseAt::Interpolated(w) if (w.translation.x - 1.8).abs() < 1e-9)
    );
}

#[test]
fn world_from_base_poses_are_composed_with_the_profiles_base_from_camera() {
    let mut p = profile();
    // The camera 1.3 m above the base, looking along the base's +x (optical z forward).
    let camera_in_base =
        glam::DQuat::from_mat3(&glam::DMat3::from_cols(glam::DVec3::NEG_Y, glam::DVec3::NEG_Z, glam::DVec3::X));
    let q = camera_in_base.to_array();
    p.pose.base_from_camera =
        Some(crate::keyframe::TransformConfig { translation_m: [0.1, 0.0, 1.3], rotation_xyzw: q });
    let mut gate = ipc_gate(&p);
    // The base at (2, 0, 0), turned 90 degrees left.
    let yaw = glam::DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2).to_array();
    let base = PoseStamped { kind: PoseKind::WorldFromBase as u8, rotation_xyzw: yaw, ..camera_pose(0, 2.0) };
    assert_eq!(gate.add_pose(&base), Ok(()));
    let GateDecision::Keyframe(world_from_camera) = gate.decide(&bare_frame(0)) else {
        panic!("expected a keyframe");
    };
    // Camera at base + yaw * (0.1, 0, 1.3) = (2, 0.1, 1.3), looking along world +y.
    assert!(world_from_camera.translation.distance(glam::DVec3::new(2.0, 0.1, 1.3)) < 1e-9, "{world_from_camera:?}");
    let forward = world_from_camera.transform_vector(glam::DVec3::Z);
    assert!(forward.distance(glam::DVec3::Y) < 1e-9, "{forward}");
}

#[test]
fn frame_stamps_jumping_back_empty_the_buffer() {
    let p = profile();
    let mut gate = ipc_gate(&p);
    let s = 1_000_000_000u64;
    gate.add_pose(&camera_pose(20 * s, 0.0)).expect("first");
    assert!(matches!(gate.decide(&bare_frame(20 * s)), GateDecision::Keyframe(_)));
    // The recording loops: frames start again at 0, so do its poses.
    assert_eq!(gate.decide(&bare_frame(0)), GateDecision::NoPose);
    assert_eq!(gate.add_pose(&camera_pose(0, 0.0)), Ok(()), "not out of order after the jump");
    assert!(matches!(gate.decide(&bare_frame(0)), GateDecision::Keyframe(_)));
}

#[test]
fn a_sustained_clock_difference_warns_once_per_period() {
    let second = Duration::from_secs(1);
    let mut check = ClockCheck::new(5 * second, 1_000_000_000, 250_000_000);
    let t0 = Instant::now();
    let wall_ns = 1_764_000_000_000_000_000u64; // poses on the Unix epoch, frames on scene time
    for step in 0..=12u64 {
        let now = t0 + Duration::from_millis(500 * step);
        check.pose_received(wall_ns + step * 500_000_000, now);
        let warned = check.frame_seen(step * 500_000_000, now);
        // Warns once the difference has lasted 5 s (step 10), not before, not twice in 5 s.
        assert_eq!(warned.is_some(), step == 10, "step {step}");
    }
    // In step with the frames: no warning, and the sustained period starts again.
    let mut check = ClockCheck::new(5 * second, 1_000_000_000, 250_000_000);
    for step in 0..20u64 {
        let now = t0 + Duration::from_millis(500 * step);
        check.pose_received(step * 500_000_000 + 40_000_000, now);
        assert_eq!(check.frame_seen(step * 500_000_000, now), None);
    }
    // Poses that stopped arriving are not a clock difference.
    assert_eq!(check.frame_seen(1_000_000_000_000, t0 + 60 * second), None);
}
