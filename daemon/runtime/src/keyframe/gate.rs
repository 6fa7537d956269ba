//! The keyframe gate (the rules are in the module docs of [`crate::keyframe`]).

use std::time::{Duration, Instant};

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::pose::{Isometry, PoseAt, PoseBuffer, PoseBufferConfig, PoseMiss, StampedPose};
use op3dsg_drivers::source::StampClock;
use op3dsg_ipc_types::{PoseKind, PoseStamped};

use super::config::{KeyframeConfig, PoseConfig, PoseSourceKind};

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
        if !self.pose_source.is_received() {
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
            PoseSourceKind::Ipc | PoseSourceKind::Ros2 => self.poses.pose_at(frame.stamp_ns, may_wait),
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
pub(super) struct ClockCheck {
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
    pub(super) fn new(after: Duration, ahead_limit_ns: u64, behind_limit_ns: u64) -> Self {
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

    pub(super) fn pose_received(&mut self, stamp_ns: u64, now: Instant) {
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
    pub(super) fn frame_seen(&mut self, frame_ns: u64, now: Instant) -> Option<i128> {
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
