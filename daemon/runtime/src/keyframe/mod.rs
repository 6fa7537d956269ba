//! The keyframe gate: gives each frame its `world_from_camera` and decides whether it is a
//! keyframe. Shared by the threaded [`crate::pipeline`] (on its `op3dsg-keyframe` thread,
//! `thread.rs`) and the synchronous batch runner of `op3dsg-sim`, so both select exactly the same
//! keyframes.
//!
//! A frame's pose comes from the frame itself (`pose.source = "frame"`) or from the pose buffer
//! filled from `<prefix>/pose` (`"ipc"`), as a navigation stack sends it: at its own rate
//! (10 Hz is common), a little late, now and then out of order or broken.
//!
//! ## Looking up a frame's pose (`pose.source = "ipc"`)
//!
//! - Two buffered poses that bracket the frame's stamp and are at most
//!   `pose.max_interpolation_gap_ms` apart: the pose is interpolated between them (linear in
//!   translation, SLERP in rotation; [`PoseBuffer`]).
//! - A frame stamped after the newest pose waits (on its thread, frames kept in order, at most
//!   [`MAX_PENDING_FRAMES`] at once) up to `pose.max_wait_ms` of host time for the pose after it.
//!   The wait adds latency, not loss: at 30 Hz the 200 ms default holds 6 frames.
//! - Otherwise, or once the wait is over, the nearest pose is held if it is at most
//!   `pose.tolerance_ms` from the stamp. Nothing is extrapolated beyond that: the frame is
//!   dropped and counted (`frames_without_pose` in health, a rate-limited warning per reason).
//!
//! ## Which received poses are adopted
//!
//! Each received pose is counted once in health (`PoseHealth`), under the first check it fails,
//! and every refusal is logged at warn, rate-limited per reason:
//!
//! | reason | when | where |
//! |---|---|---|
//! | `unknown_kind` | `kind` is neither 0 (`world_from_camera`) nor 1 (`world_from_base`) | wire check |
//! | `non_finite` | a translation or quaternion component is NaN or infinite | wire check |
//! | `non_unit_quaternion` | the quaternion's norm is off 1 by more than 1e-3 | wire check |
//! | `no_base_from_camera` | `world_from_base` while the profile sets no `pose.base_from_camera` | gate |
//! | `out_of_order` | stamped before the newest adopted pose | gate |
//! | `stale` | stamped more than `max(pose.max_interpolation_gap_ms, pose.tolerance_ms)` before the oldest frame still waiting for a pose (the newest frame when none waits): no frame can use it | gate |
//! | `future` | stamped more than `pose.future_tolerance_ms` after the newest frame; **not** adopted, so it cannot make the poses that follow out of order | gate |
//!
//! The wire checks run on the publisher thread (`GraphServer::poll_poses`), the gate's here.
//! `world_from_base` poses become `world_from_base * base_from_camera` (the profile's fixed mount).
//!
//! The buffer recovers by itself: a refused pose changes nothing; poses adopted before the first
//! frame that turn out to lie beyond `pose.future_tolerance_ms` are discarded when that frame
//! comes; frame stamps that jump back by more than that (a replay that loops, a restarted camera)
//! empty the buffer. An adopted pose at most `pose.future_tolerance_ms` ahead can hold back
//! earlier poses as out of order for at most that long.
//!
//! ## Clocks
//!
//! Poses are looked up by the frame's stamp, so the navigation stack must stamp them on the
//! clock of the frame source ([`StampClock`]):
//!
//! | `source.kind` | frames are stamped on |
//! |---|---|
//! | `realsense` | the host clock, through librealsense's global time (hardware timestamps mapped to the host's system clock, ns since the Unix epoch) |
//! | `replay` | the recording's own stamps (its poses, or poses on its clock) |
//! | `synthetic` | scene time: 0 at the first frame, frame `k` at `k / source.synthetic.frame_rate_hz`, whatever the delivery rate |
//!
//! When poses keep arriving but their stamps stay more than `pose.future_tolerance_ms` ahead of
//! the frames, or more than `max(pose.max_interpolation_gap_ms, pose.tolerance_ms)` behind, for
//! `pose.clock_warning_after_s`, the gate warns that the clocks differ (then at most once per
//! that period while it lasts).
//!
//! ## Keyframes
//!
//! A frame with a pose is a keyframe when it is the first one, or when since the last keyframe
//! the camera moved `keyframe.min_translation_m`, turned `keyframe.min_rotation_deg`, or
//! `keyframe.max_interval_s` passed.
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

pub(crate) mod log_limit;
pub(crate) mod thread;

use std::time::{Duration, Instant};

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::{Isometry, PoseAt, PoseBuffer, PoseBufferConfig, PoseMiss, StampedPose};
use op3dsg_drivers::source::StampClock;
use op3dsg_ipc_types::{PoseKind, PoseStamped};

use crate::config::{KeyframeConfig, PoseConfig, PoseSourceKind};

/// Frames the keyframe thread keeps while they wait for a later pose (`pose.max_wait_ms`); while
/// this many wait it takes no more frames, and the frames queue's policy applies (`latest_wins`
/// drops the oldest queued frame and counts it, `block` holds the capture thread). The frame pool
/// is sized with this headroom when `pose.source = "ipc"`.
pub const MAX_PENDING_FRAMES: usize = 8;

/// A pose received this long ago (host time) or longer no longer counts for the clock check:
/// poses that stopped are a missing stream, not a different clock.
const CLOCK_CHECK_RECENT: Duration = Duration::from_secs(1);

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
    /// Stamped too long before the frames still waiting for a pose.
    Stale,
    /// Stamped more than `pose.future_tolerance_ms` after the newest frame.
    Future,
}

impl PoseRefusal {
    /// Every reason, in a fixed order (index for per-reason logs).
    pub const ALL: [PoseRefusal; 5] =
        [Self::UnknownKind, Self::NoBaseFromCamera, Self::OutOfOrder, Self::Stale, Self::Future];

    /// The health counter's name.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::UnknownKind => "unknown_kind",
            Self::NoBaseFromCamera => "no_base_from_camera",
            Self::OutOfOrder => "out_of_order",
            Self::Stale => "stale",
            Self::Future => "future",
        }
    }

    /// Position in [`Self::ALL`].
    pub fn index(self) -> usize {
        Self::ALL.iter().position(|r| *r == self).unwrap_or(0)
    }
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
    /// A pose this much older than the oldest frame waiting for one is stale.
    stale_after_ns: u64,
    future_tolerance_ns: u64,
    max_wait: Duration,
    /// Stamp of the newest frame seen (`pose.source = "ipc"`).
    newest_frame_ns: Option<u64>,
    /// Stamp of the oldest frame still waiting for its pose (set by the keyframe thread).
    oldest_waiting_ns: Option<u64>,
    clock: ClockCheck,
}

impl KeyframeGate {
    /// A gate that has seen no frame yet.
    pub fn new(config: &KeyframeConfig, pose_config: &PoseConfig) -> Self {
        let ms_to_ns = |ms: f64| (ms * 1e6).max(0.0) as u64;
        let tolerance_ns = ms_to_ns(pose_config.tolerance_ms);
        let max_gap_ns = ms_to_ns(pose_config.max_interpolation_gap_ms);
        let future_tolerance_ns = ms_to_ns(pose_config.future_tolerance_ms);
        let stale_after_ns = max_gap_ns.max(tolerance_ns);
        Self {
            pose_source: pose_config.source,
            poses: PoseBuffer::new(PoseBufferConfig {
                capacity: pose_config.buffer_len,
                max_interpolation_gap_ns: max_gap_ns,
                hold_tolerance_ns: tolerance_ns,
            }),
            base_from_camera: pose_config.base_from_camera.map(|t| t.to_isometry()),
            last: None,
            min_translation_m: config.min_translation_m,
            min_rotation_rad: config.min_rotation_deg.to_radians(),
            max_interval_ns: (config.max_interval_s * 1e9) as u64,
            stale_after_ns,
            future_tolerance_ns,
            max_wait: Duration::from_secs_f64(pose_config.max_wait_ms.max(0.0) / 1e3),
            newest_frame_ns: None,
            oldest_waiting_ns: None,
            clock: ClockCheck::new(
                Duration::from_secs_f64(pose_config.clock_warning_after_s.max(0.0)),
                future_tolerance_ns,
                stale_after_ns,
            ),
        }
    }

    /// Where frames' poses come from.
    pub fn pose_source(&self) -> PoseSourceKind {
        self.pose_source
    }

    /// How long a frame stamped after the newest pose may wait for the next one.
    pub fn max_wait(&self) -> Duration {
        self.max_wait
    }

    /// Names the frames' clock in the clock warning.
    pub fn set_frame_clock(&mut self, clock: StampClock) {
        self.clock.frame_clock = clock;
    }

    /// Adds a pose received on the pose service (already through
    /// [`check_pose`](op3dsg_ipc_types::check_pose)), or says why it is not adopted.
    pub fn add_pose(&mut self, pose: &PoseStamped) -> Result<(), PoseRefusal> {
        self.clock.pose_received(pose.stamp_ns, Instant::now());
        let world_from_x =
            Isometry::new(glam::DQuat::from_array(pose.rotation_xyzw), glam::DVec3::from_array(pose.translation_m));
        let world_from_camera = match (PoseKind::from_u8(pose.kind), self.base_from_camera) {
            (Some(PoseKind::WorldFromCamera), _) => world_from_x,
            (Some(PoseKind::WorldFromBase), Some(base_from_camera)) => world_from_x * base_from_camera,
            (Some(PoseKind::WorldFromBase), None) => return Err(PoseRefusal::NoBaseFromCamera),
            (None, _) => return Err(PoseRefusal::UnknownKind),
        };
        if let Some(frame_ns) = self.newest_frame_ns {
            let oldest_use_ns = self.oldest_waiting_ns.unwrap_or(frame_ns).min(frame_ns);
            if pose.stamp_ns.saturating_add(self.stale_after_ns) < oldest_use_ns {
                return Err(PoseRefusal::Stale);
            }
            if pose.stamp_ns > frame_ns.saturating_add(self.future_tolerance_ns) {
                return Err(PoseRefusal::Future);
            }
        }
        self.poses.push(StampedPose { stamp_ns: pose.stamp_ns, world_from_camera }).map_err(|_| PoseRefusal::OutOfOrder)
    }

    /// Tells the gate a frame stamped `stamp_ns` arrived (`pose.source = "ipc"`; [`Self::decide`]
    /// calls it). Discards poses that this frame shows to lie beyond the future tolerance, and
    /// empties the buffer when frame stamps jump back by more than it.
    pub fn note_frame(&mut self, stamp_ns: u64) {
        if self.pose_source != PoseSourceKind::Ipc {
            return;
        }
        if let Some(newest_ns) = self.newest_frame_ns
            && stamp_ns.saturating_add(self.future_tolerance_ns) < newest_ns
        {
            tracing::warn!(
                frame_stamp_ns = stamp_ns,
                previous_stamp_ns = newest_ns,
                poses_discarded = self.poses.len(),
                "frame stamps jumped back (source restarted or looped); pose buffer emptied"
            );
            self.poses.clear();
            self.newest_frame_ns = None;
            self.last = None;
        }
        let newest_ns = self.newest_frame_ns.map_or(stamp_ns, |n| n.max(stamp_ns));
        self.newest_frame_ns = Some(newest_ns);
        let discarded = self.poses.discard_after(newest_ns.saturating_add(self.future_tolerance_ns));
        if discarded > 0 {
            tracing::warn!(
                discarded,
                frame_stamp_ns = newest_ns,
                future_tolerance_ms = self.future_tolerance_ns as f64 / 1e6,
                "poses adopted before this frame lie beyond the future tolerance; discarded"
            );
        }
        self.clock.frame_seen(newest_ns, Instant::now());
    }

    /// Records the stamp of the oldest frame still waiting for its pose (`None`: none waits); a
    /// pose is stale only when even that frame cannot use it.
    pub fn set_oldest_waiting(&mut self, stamp_ns: Option<u64>) {
        self.oldest_waiting_ns = stamp_ns;
    }

    /// The frame's pose: its own (`pose.source = "frame"`), or from the buffer. With `may_wait`,
    /// a frame stamped after the newest pose answers [`PoseAt::WaitForLater`].
    pub fn pose_for(&self, frame: &Frame, may_wait: bool) -> PoseAt {
        match self.pose_source {
            PoseSourceKind::Frame => {
                frame.world_from_camera.map_or(PoseAt::Missing(PoseMiss::Empty), PoseAt::Interpolated)
            }
            PoseSourceKind::Ipc => self.poses.pose_at(frame.stamp_ns, may_wait),
        }
    }

    /// Applies the motion test to a frame at `world_from_camera`; a keyframe becomes the
    /// reference for the next test.
    pub fn judge(&mut self, frame: &Frame, world_from_camera: Isometry) -> GateDecision {
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

    /// Looks up the frame's pose without waiting and applies the motion test (the batch runner;
    /// the pipeline's thread waits for later poses, see the module docs).
    pub fn decide(&mut self, frame: &Frame) -> GateDecision {
        self.note_frame(frame.stamp_ns);
        match self.pose_for(frame, false).pose() {
            Some(world_from_camera) => self.judge(frame, world_from_camera),
            None => GateDecision::NoPose,
        }
    }
}

/// Watches whether pose stamps and frame stamps stay on one clock (module docs, "Clocks").
#[derive(Debug)]
struct ClockCheck {
    after: Duration,
    ahead_limit_ns: u64,
    behind_limit_ns: u64,
    frame_clock: StampClock,
    /// Stamp of the newest received pose and when it came.
    last_pose: Option<(u64, Instant)>,
    disagree_since: Option<Instant>,
    last_warning: Option<Instant>,
}

impl ClockCheck {
    fn new(after: Duration, ahead_limit_ns: u64, behind_limit_ns: u64) -> Self {
        Self {
            after,
            ahead_limit_ns,
            behind_limit_ns,
            frame_clock: StampClock::Unspecified,
            last_pose: None,
            disagree_since: None,
            last_warning: None,
        }
    }

    fn pose_received(&mut self, stamp_ns: u64, now: Instant) {
        let newest = self.last_pose.map_or(stamp_ns, |(s, _)| s.max(stamp_ns));
        // A pose stream that restarted on another clock replaces the old figure.
        let newest = if stamp_ns < newest && self.last_pose.is_some_and(|(_, at)| now - at > CLOCK_CHECK_RECENT) {
            stamp_ns
        } else {
            newest
        };
        self.last_pose = Some((newest, now));
    }

    /// Checks the newest frame stamp against the newest pose stamp; returns the offset (pose
    /// minus frame, nanoseconds) when it warned.
    fn frame_seen(&mut self, frame_ns: u64, now: Instant) -> Option<i128> {
        let recent = |(_, at): &(u64, Instant)| now.saturating_duration_since(*at) <= CLOCK_CHECK_RECENT;
        let Some((pose_ns, _)) = self.last_pose.filter(recent) else {
            self.disagree_since = None;
            return None;
        };
        let offset_ns = i128::from(pose_ns) - i128::from(frame_ns);
        let disagree = offset_ns > i128::from(self.ahead_limit_ns) || -offset_ns > i128::from(self.behind_limit_ns);
        if !disagree {
            self.disagree_since = None;
            return None;
        }
        let since = *self.disagree_since.get_or_insert(now);
        let lasting = now.saturating_duration_since(since);
        let due = self.last_warning.is_none_or(|at| now.saturating_duration_since(at) >= self.after);
        if lasting < self.after || !due {
            return None;
        }
        self.last_warning = Some(now);
        let (amount_s, side) =
            if offset_ns > 0 { (offset_ns as f64 / 1e9, "ahead of") } else { (-offset_ns as f64 / 1e9, "behind") };
        tracing::warn!(
            offset_s = format_args!("{:.3}", offset_ns as f64 / 1e9),
            for_s = format_args!("{:.1}", lasting.as_secs_f64()),
            "pose stamps are {amount_s:.3} s {side} frame stamps: stamp poses on the frames' clock, {}",
            self.frame_clock.describe()
        );
        Some(offset_ns)
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
            Some(crate::config::TransformConfig { translation_m: [0.1, 0.0, 1.3], rotation_xyzw: q });
        let mut gate = ipc_gate(&p);
        // The base at (2, 0, 0), turned 90 degrees left.
        let yaw = glam::DQuat::from_rotation_z(std::f64::consts::FRAC_PI_2).to_array();
        let base = PoseStamped { kind: PoseKind::WorldFromBase as u8, rotation_xyzw: yaw, ..camera_pose(0, 2.0) };
        assert_eq!(gate.add_pose(&base), Ok(()));
        let GateDecision::Keyframe(world_from_camera) = gate.decide(&bare_frame(0)) else {
            panic!("expected a keyframe");
        };
        // Camera at base + yaw * (0.1, 0, 1.3) = (2, 0.1, 1.3), looking along world +y.
        assert!(
            world_from_camera.translation.distance(glam::DVec3::new(2.0, 0.1, 1.3)) < 1e-9,
            "{world_from_camera:?}"
        );
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
}
