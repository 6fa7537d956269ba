//! The transform buffer on a Stretch-like chain, `map -> odom -> base_link -> link_head_tilt ->
//! camera_link -> camera_color_optical_frame` (the first three edges on `/tf`, the last two on
//! `/tf_static`), against a known camera trajectory; every error; a frame that changes parents.

use glam::{DMat3, DQuat, DVec3};
use op3dsg_ros2::msg::builtin_interfaces::Time;
use op3dsg_ros2::msg::geometry_msgs::{Quaternion, TransformStamped};
use op3dsg_ros2::msg::std_msgs::Header;
use op3dsg_ros2::msg::tf2_msgs::TFMessage;
use op3dsg_ros2::{RigidTransform, TfBuffer, TfConfig, TfError, TfInsertError};

const CHAIN: [&str; 6] = ["camera_color_optical_frame", "camera_link", "link_head_tilt", "base_link", "odom", "map"];
const MS: u64 = 1_000_000;
const S: u64 = 1_000_000_000;

fn ts(parent: &str, child: &str, stamp_ns: u64, parent_from_child: RigidTransform) -> TransformStamped {
    TransformStamped {
        header: Header { stamp: Time::from_ns(stamp_ns), frame_id: parent.to_string() },
        child_frame_id: child.to_string(),
        transform: parent_from_child.into(),
    }
}

fn at_x(x: f64) -> RigidTransform {
    RigidTransform::new(DQuat::IDENTITY, DVec3::new(x, 0.0, 0.0))
}

/// The camera of `tests::known_trajectory` in `op3dsg_drivers::pose`: the base drives a 1.5 m
/// circle at 0.3 m/s, the head pans and tilts, the optical frame looks along the head.
fn world_from_camera(t: f64) -> RigidTransform {
    let heading = t * 0.3 / 1.5;
    let base = DVec3::new(1.5 * heading.cos(), 1.5 * heading.sin(), 1.2 + 0.01 * (2.0 * t).sin());
    let yaw = heading + std::f64::consts::FRAC_PI_2 + 0.5 * t.sin();
    let tilt = 0.2 * (0.5 * t).sin();
    RigidTransform::new(DQuat::from_rotation_z(yaw) * DQuat::from_rotation_y(-tilt) * optical(), base)
}

/// `camera_link_from_camera_color_optical_frame`: z forward, x right, y down.
fn optical() -> DQuat {
    DQuat::from_mat3(&DMat3::from_cols(DVec3::NEG_Y, DVec3::NEG_Z, DVec3::X))
}

fn head_tilt_from_camera_link() -> RigidTransform {
    RigidTransform::new(DQuat::from_rotation_y(0.05), DVec3::new(0.03, -0.01, 0.05))
}

fn map_from_odom(t: f64) -> RigidTransform {
    RigidTransform::new(DQuat::from_rotation_z(0.01 * t), DVec3::new(0.05 * t, 0.02 * t.sin(), 0.0))
}

fn base_from_head_tilt(t: f64) -> RigidTransform {
    RigidTransform::new(
        DQuat::from_rotation_z(0.4 * t.sin()) * DQuat::from_rotation_y(0.3 * (0.5 * t).cos()),
        DVec3::new(-0.01, 0.12, 1.1),
    )
}

/// The statics, and the dynamic edges at `stamp_ns` chosen so that the chain's product is
/// [`world_from_camera`] exactly.
fn statics() -> TFMessage {
    let camera_link_from_optical = RigidTransform::new(optical(), DVec3::new(0.0, 0.015, 0.0));
    TFMessage {
        transforms: vec![
            ts(CHAIN[2], CHAIN[1], 0, head_tilt_from_camera_link()),
            ts(CHAIN[1], CHAIN[0], 0, camera_link_from_optical),
        ],
    }
}

fn dynamics(stamp_ns: u64) -> TFMessage {
    let t = stamp_ns as f64 * 1e-9;
    let camera_link_from_optical = RigidTransform::new(optical(), DVec3::new(0.0, 0.015, 0.0));
    let base_from_camera = base_from_head_tilt(t) * head_tilt_from_camera_link() * camera_link_from_optical;
    let odom_from_base = map_from_odom(t).inverse() * world_from_camera(t) * base_from_camera.inverse();
    TFMessage {
        transforms: vec![
            ts(CHAIN[5], CHAIN[4], stamp_ns, map_from_odom(t)),
            ts(CHAIN[4], CHAIN[3], stamp_ns, odom_from_base),
            ts(CHAIN[3], CHAIN[2], stamp_ns, base_from_head_tilt(t)),
        ],
    }
}

fn stretch(rate_hz: f64, end_ns: u64, config: TfConfig) -> TfBuffer {
    let mut buffer = TfBuffer::new(config);
    assert!(buffer.insert_message(&statics(), true).is_empty());
    let period_ns = (1e9 / rate_hz) as u64;
    let mut stamp_ns = 7 * MS;
    while stamp_ns <= end_ns {
        assert_eq!(buffer.insert_message(&dynamics(stamp_ns), false), vec![]);
        stamp_ns += period_ns;
    }
    buffer
}

fn config(window_ns: u64, max_gap_ns: u64, hold_ns: u64) -> TfConfig {
    TfConfig { window_ns, max_interpolation_gap_ns: max_gap_ns, hold_tolerance_ns: hold_ns, ..TfConfig::default() }
}

#[test]
fn the_chain_interpolates_within_1_mm_and_0_05_degrees_at_30_and_100_hz() {
    for rate_hz in [30.0, 100.0] {
        let mut buffer = stretch(rate_hz, 31 * S, config(60 * S, 50 * MS, 0));
        let (mut worst_m, mut worst_deg) = (0.0f64, 0.0f64);
        for k in 1..900u64 {
            let frame_ns = k * 33_333_333;
            let found = buffer.lookup("map", "camera_color_optical_frame", frame_ns).unwrap();
            let exact = world_from_camera(frame_ns as f64 * 1e-9);
            worst_m = worst_m.max(found.translation.distance(exact.translation));
            worst_deg = worst_deg.max(found.rotation.angle_between(exact.rotation).to_degrees());
        }
        eprintln!("{rate_hz} Hz tf: largest error {:.4} mm, {:.5} degrees", worst_m * 1e3, worst_deg);
        assert!(worst_m <= 1e-3 && worst_deg <= 0.05, "{rate_hz} Hz: {worst_m} m, {worst_deg} degrees");
        let path = buffer.last_path().unwrap();
        assert_eq!(path.frames, CHAIN);
        assert_eq!(path.stamp_ns, 899 * 33_333_333);
        // The newest data of every dynamic edge is the last published stamp.
        let period_ns = (1e9 / rate_hz) as u64;
        assert_eq!(path.newest_data_ns, Some(7 * MS + (31 * S - 7 * MS) / period_ns * period_ns));
    }
    // Sanity of the measure: the exact chain at a sample's own stamp is exact, and the camera
    // moves enough between 30 Hz samples that holding one would fail the bound.
    let mut buffer = stretch(30.0, 2 * S, config(60 * S, 50 * MS, 0));
    let stamp = 7 * MS + 33_333_333 * 10;
    let exact = world_from_camera(stamp as f64 * 1e-9);
    assert!(
        buffer.lookup("map", "camera_color_optical_frame", stamp).unwrap().translation.distance(exact.translation)
            < 1e-9
    );
    assert!(world_from_camera(0.0).translation.distance(world_from_camera(1.0 / 30.0).translation) > 5e-3);
}

#[test]
fn lookups_go_both_ways_and_across_branches() {
    let mut buffer = stretch(30.0, 2 * S, config(60 * S, 50 * MS, 0));
    buffer.insert(&ts("base_link", "laser", 0, at_x(0.2)), true).unwrap();
    let stamp = S;
    let map_from_camera = buffer.lookup("map", "camera_color_optical_frame", stamp).unwrap();
    let camera_from_map = buffer.lookup("/camera_color_optical_frame", "/map", stamp).unwrap();
    assert!((map_from_camera * camera_from_map).translation.length() < 1e-9);
    assert_eq!(buffer.last_path().unwrap().frames, CHAIN.iter().rev().copied().collect::<Vec<_>>());
    // laser and camera meet at base_link.
    let laser_from_camera = buffer.lookup("laser", "camera_color_optical_frame", stamp).unwrap();
    let map_from_laser = buffer.lookup("map", "laser", stamp).unwrap();
    assert!((map_from_laser * laser_from_camera).translation.distance(map_from_camera.translation) < 1e-9);
    buffer.lookup("laser", "camera_color_optical_frame", stamp).unwrap();
    assert_eq!(
        buffer.last_path().unwrap().frames,
        ["camera_color_optical_frame", "camera_link", "link_head_tilt", "base_link", "laser"]
    );
    // Static only: no data age; a frame to itself.
    buffer.lookup("link_head_tilt", "camera_color_optical_frame", 10 * S).unwrap();
    assert_eq!(buffer.last_path().unwrap().newest_data_ns, None);
    assert_eq!(buffer.lookup("odom", "odom", stamp).unwrap(), RigidTransform::IDENTITY);
    let frames: Vec<&str> = buffer.frame_names().collect();
    assert_eq!(frames.len(), 7);
}

#[test]
fn each_lookup_error_names_what_is_missing() {
    let mut buffer = TfBuffer::new(config(60 * S, 150 * MS, 20 * MS));
    assert!(buffer.insert_message(&statics(), true).is_empty());
    for stamp in [S, S + 100 * MS, 3 * S] {
        let mut message = dynamics(stamp);
        message.transforms.remove(0); // no map -> odom
        assert!(buffer.insert_message(&message, false).is_empty());
    }
    let err = |buffer: &mut TfBuffer, target: &str, source: &str, stamp: u64| {
        buffer.lookup(target, source, stamp).unwrap_err()
    };
    assert_eq!(err(&mut buffer, "map", "nope", S), TfError::FrameNotFound("nope".into()));
    assert!(buffer.lookup("odom", "camera_color_optical_frame", S + 50 * MS).is_ok());
    buffer.insert(&ts("map", "dock", 0, RigidTransform::IDENTITY), true).unwrap();
    // map exists now, but odom has no parent.
    let no_path = err(&mut buffer, "map", "camera_color_optical_frame", S);
    assert_eq!(
        no_path,
        TfError::NoPath {
            from: "camera_color_optical_frame".into(),
            to: "map".into(),
            missing_link: "odom has no parent".into()
        }
    );
    assert!(no_path.to_string().contains("odom has no parent"), "{no_path}");
    // Two trees, neither frame a root.
    buffer.insert(&ts("a", "b", 0, at_x(1.0)), true).unwrap();
    assert_eq!(
        err(&mut buffer, "b", "camera_link", S),
        TfError::NoPath {
            from: "camera_link".into(),
            to: "b".into(),
            missing_link: "frames camera_link and b are in different trees (roots odom and a)".into()
        }
    );
    // After the newest sample by more than the 20 ms hold: the future; within it: held.
    let future = err(&mut buffer, "odom", "camera_link", 3 * S + 21 * MS);
    assert!(future.is_after_newest(), "{future}");
    assert!(future.to_string().contains("after its samples"), "{future}");
    assert!(buffer.lookup("odom", "camera_link", 3 * S + 20 * MS).is_ok());
    let past = err(&mut buffer, "odom", "camera_link", S - 21 * MS);
    assert_eq!(
        past,
        TfError::Extrapolation {
            edge: "base_link -> link_head_tilt".into(),
            stamp_ns: S - 21 * MS,
            oldest_ns: S,
            newest_ns: 3 * S
        }
    );
    assert!(!past.is_after_newest() && past.to_string().contains("before its samples"), "{past}");
    // Between samples 1.9 s apart (more than the 150 ms gap): held near either, else a gap.
    assert!(buffer.lookup("odom", "camera_link", S + 110 * MS).is_ok());
    assert!(buffer.lookup("odom", "camera_link", 3 * S - 15 * MS).is_ok());
    assert_eq!(
        err(&mut buffer, "odom", "camera_link", 2 * S),
        TfError::Gap {
            edge: "base_link -> link_head_tilt".into(),
            stamp_ns: 2 * S,
            before_ns: S + 100 * MS,
            after_ns: 3 * S
        }
    );
    // A loop of parents.
    buffer.insert(&ts("p", "q", S, at_x(1.0)), false).unwrap();
    buffer.insert(&ts("q", "p", S, at_x(1.0)), false).unwrap();
    let looped = err(&mut buffer, "map", "q", S).to_string();
    assert!(looped.contains("form a loop"), "{looped}");
}

#[test]
fn bad_transforms_are_refused_with_their_reason() {
    let mut buffer = TfBuffer::new(TfConfig { max_frames: 5, ..config(5 * S, 100 * MS, 0) });
    let good = ts("odom", "base_link", 10 * S, at_x(1.0));
    buffer.insert(&good, false).unwrap();
    let mut bad = |f: &dyn Fn(&mut TransformStamped), is_static: bool| {
        let mut t = good.clone();
        f(&mut t);
        buffer.insert(&t, is_static).unwrap_err()
    };
    assert_eq!(bad(&|t| t.header.frame_id.clear(), false), TfInsertError::EmptyFrameId("parent"));
    assert_eq!(bad(&|t| t.child_frame_id = "/".into(), false), TfInsertError::EmptyFrameId("child"));
    assert_eq!(bad(&|t| t.child_frame_id = "/odom".into(), false), TfInsertError::SelfTransform("odom".into()));
    assert!(matches!(bad(&|t| t.transform.translation.y = f64::NAN, false), TfInsertError::NonFinite { .. }));
    let quaternion = bad(&|t| t.transform.rotation = Quaternion { x: 0.0, y: 0.0, z: 0.0, w: 1.01 }, false);
    assert!(quaternion.to_string().contains("base_link: quaternion norm 1.01"), "{quaternion}");
    assert!(matches!(bad(&|t| t.header.stamp.sec = -1, false), TfInsertError::BadStamp { .. }));
    assert_eq!(
        bad(&|_| {}, false),
        TfInsertError::RepeatedStamp { edge: "odom -> base_link".into(), stamp_ns: 10 * S }
    );
    assert_eq!(
        bad(&|t| t.header.stamp = Time::from_ns(4 * S), false),
        TfInsertError::TooOld { edge: "odom -> base_link".into(), stamp_ns: 4 * S, newest_ns: 10 * S }
    );
    let conflict = bad(&|_| {}, true);
    assert_eq!(conflict, TfInsertError::KindConflict { child: "base_link".into(), now_static: true });
    assert_eq!(conflict.to_string(), "frame \"base_link\" comes from /tf; a /tf_static transform for it is refused");
    buffer.insert(&ts("base_link", "laser", 0, at_x(0.1)), true).unwrap();
    let conflict = buffer.insert(&ts("base_link", "laser", 11 * S, at_x(0.1)), false).unwrap_err();
    assert_eq!(conflict.to_string(), "frame \"laser\" comes from /tf_static; a /tf transform for it is refused");
    for (i, child) in ["a", "b", "c"].iter().enumerate() {
        let result = buffer.insert(&ts("odom", child, 10 * S, at_x(i as f64)), false);
        assert_eq!(result.is_ok(), i < 2, "{child}: {result:?}");
    }
    // The good one still answers.
    assert_eq!(buffer.lookup("odom", "base_link", 10 * S).unwrap(), at_x(1.0));
}

#[test]
fn a_frame_that_moves_parents_follows_its_newest_parent() {
    // A cup on the table until 1 s, then in the gripper; tf2 answers each stamp with the parent
    // of the samples there.
    let mut buffer = TfBuffer::new(config(60 * S, 150 * MS, 0));
    buffer.insert(&ts("map", "table", 0, at_x(10.0)), true).unwrap();
    buffer.insert(&ts("map", "gripper", 0, at_x(20.0)), true).unwrap();
    for k in 0..=9 {
        buffer.insert(&ts("table", "cup", k * 100 * MS, at_x(1.0)), false).unwrap();
    }
    for k in 10..=20 {
        buffer.insert(&ts("gripper", "cup", k * 100 * MS, at_x(2.0)), false).unwrap();
    }
    let x = |buffer: &mut TfBuffer, stamp| buffer.lookup("map", "cup", stamp).unwrap().translation.x;
    assert_eq!(x(&mut buffer, 500 * MS), 11.0);
    assert_eq!(buffer.last_path().unwrap().frames, ["cup", "table", "map"]);
    assert_eq!(x(&mut buffer, 1500 * MS), 22.0);
    assert_eq!(buffer.last_path().unwrap().frames, ["cup", "gripper", "map"]);
    // Between the last sample on the table (0.9 s) and the first in the gripper (1.0 s): no
    // interpolation across parents; the earlier one holds until the change.
    assert_eq!(x(&mut buffer, 950 * MS), 11.0);
    assert_eq!(x(&mut buffer, S), 22.0);
    // The newest parent is what the latest common stamp walks through.
    assert_eq!(buffer.latest_common_stamp("map", "cup").unwrap(), Some(2 * S));
    // Static transforms: a newer one for the same child replaces it, parent included.
    buffer.insert(&ts("gripper", "table", 0, at_x(-1.0)), true).unwrap();
    assert_eq!(x(&mut buffer, 500 * MS), 20.0);
}

#[test]
fn windows_latest_stamps_and_clearing() {
    let mut buffer = TfBuffer::new(config(5 * S, 150 * MS, 0));
    for k in 0..=200 {
        buffer.insert(&ts("map", "odom", k * 100 * MS, at_x(k as f64)), false).unwrap();
        buffer.insert(&ts("odom", "base_link", k * 100 * MS + 50 * MS, at_x(0.0)), false).unwrap();
    }
    buffer.insert(&ts("base_link", "camera", 0, at_x(0.0)), true).unwrap();
    // Only the last 5 s are kept.
    let old = buffer.lookup("map", "odom", S).unwrap_err();
    assert!(
        matches!(old, TfError::Extrapolation { oldest_ns, newest_ns, .. } if oldest_ns == 15 * S && newest_ns == 20 * S),
        "{old}"
    );
    assert!((buffer.lookup("map", "odom", 17 * S + 50 * MS).unwrap().translation.x - 170.5).abs() < 1e-9);
    // Latest common stamp: map -> odom ends at 20 s, odom -> base_link at 20.05 s.
    assert_eq!(buffer.latest_common_stamp("map", "camera").unwrap(), Some(20 * S));
    assert_eq!(buffer.latest_common_stamp("base_link", "camera").unwrap(), None);
    assert!(matches!(buffer.latest_common_stamp("map", "nope"), Err(TfError::FrameNotFound(_))));
    buffer.insert(&ts("x", "y", 0, at_x(0.0)), true).unwrap();
    assert!(matches!(buffer.latest_common_stamp("y", "camera"), Err(TfError::NoPath { .. })));
    // A clock jump back: dynamic samples go, statics stay.
    buffer.clear_dynamic();
    assert!(buffer.last_path().is_none());
    assert!(matches!(buffer.lookup("map", "camera", 20 * S), Err(TfError::NoPath { .. })));
    assert!(buffer.lookup("base_link", "camera", 20 * S).is_ok());
    buffer.insert(&ts("map", "odom", S, at_x(3.0)), false).unwrap();
    assert_eq!(buffer.lookup("map", "odom", S).unwrap(), at_x(3.0));
}
