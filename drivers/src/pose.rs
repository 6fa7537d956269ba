//! Rigid transforms, the interpolating [`PoseBuffer`], and the poses of the daemon's pose input as
//! a recording keeps them ([`InputPose`]).
//!
//! Naming: `a_from_b` maps points expressed in frame `b` into frame `a`, so
//! `world_from_camera * point_in_camera = point_in_world`.

use glam::{DQuat, DVec3, Vec3};
use serde::{Deserialize, Serialize};

/// A rigid transform (rotation then translation), double precision.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Isometry {
    /// Unit quaternion.
    pub rotation: DQuat,
    /// Translation, metres.
    pub translation: DVec3,
}

impl Default for Isometry {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl Isometry {
    /// The identity transform.
    pub const IDENTITY: Self = Self { rotation: DQuat::IDENTITY, translation: DVec3::ZERO };

    /// From a rotation and a translation.
    pub fn new(rotation: DQuat, translation: DVec3) -> Self {
        Self { rotation: rotation.normalize(), translation }
    }

    /// Applies the transform to a point.
    #[inline]
    pub fn transform_point(&self, point: DVec3) -> DVec3 {
        self.rotation * point + self.translation
    }

    /// Applies the transform to a single-precision point (computed in double precision).
    #[inline]
    pub fn transform_point_f32(&self, point: Vec3) -> Vec3 {
        self.transform_point(point.as_dvec3()).as_vec3()
    }

    /// Rotates a direction (no translation).
    #[inline]
    pub fn transform_vector(&self, vector: DVec3) -> DVec3 {
        self.rotation * vector
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.inverse();
        Self { rotation, translation: -(rotation * self.translation) }
    }

    /// Composition `self * rhs` (apply `rhs` first).
    pub fn compose(&self, rhs: &Self) -> Self {
        Self {
            rotation: (self.rotation * rhs.rotation).normalize(),
            translation: self.rotation * rhs.translation + self.translation,
        }
    }

    /// Interpolates between two poses: linear in translation, spherical in rotation.
    pub fn interpolate(&self, other: &Self, t: f64) -> Self {
        Self {
            rotation: self.rotation.slerp(other.rotation, t).normalize(),
            translation: self.translation.lerp(other.translation, t),
        }
    }

    /// Single-precision 4x4 matrix (for hot loops over many points).
    pub fn to_mat4(&self) -> glam::Mat4 {
        glam::DMat4::from_rotation_translation(self.rotation, self.translation).as_mat4()
    }
}

impl std::ops::Mul for Isometry {
    type Output = Isometry;
    fn mul(self, rhs: Isometry) -> Isometry {
        self.compose(&rhs)
    }
}

/// A pose valid at a stamp.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StampedPose {
    /// Time, nanoseconds (on the frames' clock, see [`PoseBuffer`]).
    pub stamp_ns: u64,
    /// `world_from_camera`.
    pub world_from_camera: Isometry,
}

/// What an [`InputPose`] describes (the pose input's `PoseKind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum InputPoseKind {
    /// The colour camera's optical frame in the world.
    WorldFromCamera,
    /// The robot base in the world (composed with the profile's `pose.base_from_camera`).
    WorldFromBase,
}

/// `op3dsg.InputPose`: a pose the daemon received on its pose input (`<prefix>/pose`, with
/// `pose.source = "ipc"`), as the navigation stack sent it. A replay hands these to the keyframe
/// gate again, in the order the gate received them among the frames.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InputPose {
    /// Time the pose is valid at, nanoseconds, on the frames' clock.
    pub stamp_ns: u64,
    /// What the pose describes.
    pub kind: InputPoseKind,
    /// The child frame the sender named ("" when none).
    pub frame_id: String,
    /// Translation, metres, world frame.
    pub translation_m: [f64; 3],
    /// Unit quaternion `[x, y, z, w]`, as sent.
    pub rotation_xyzw: [f64; 4],
}

/// How a [`PoseBuffer`] answers a lookup.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PoseBufferConfig {
    /// Poses kept (the oldest goes when a new one arrives at capacity); at least 2.
    pub capacity: usize,
    /// Two poses at most this far apart (nanoseconds) are interpolated to a stamp between them.
    pub max_interpolation_gap_ns: u64,
    /// Without two such poses around a stamp, the nearest pose is held when it is at most this far
    /// (nanoseconds) from the stamp; never further (no extrapolation).
    pub hold_tolerance_ns: u64,
}

/// Where a looked-up pose came from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PoseAt {
    /// A pose stamped exactly at the stamp, or interpolated (linear translation, SLERP rotation)
    /// between the two poses that bracket it.
    Interpolated(Isometry),
    /// The nearest pose, within the hold tolerance (no pose on the other side of the stamp, or
    /// the two bracketing poses are too far apart to interpolate).
    Held(Isometry),
    /// No pose is stamped at or after the stamp yet, and the caller may wait for one.
    WaitForLater,
    /// No pose can be given (the reason).
    Missing(PoseMiss),
}

impl PoseAt {
    /// The pose, if one was found.
    pub fn pose(&self) -> Option<Isometry> {
        match self {
            Self::Interpolated(pose) | Self::Held(pose) => Some(*pose),
            Self::WaitForLater | Self::Missing(_) => None,
        }
    }
}

/// Why a [`PoseBuffer`] has no pose for a stamp.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PoseMiss {
    /// No pose has been buffered.
    Empty,
    /// The stamp is after the newest pose by more than the hold tolerance (and no later pose
    /// came in time): holding the last pose would be extrapolating.
    AfterNewest,
    /// The stamp is before the oldest buffered pose by more than the hold tolerance.
    BeforeOldest,
    /// The poses around the stamp are further apart than the interpolation gap, and neither is
    /// within the hold tolerance.
    Gap,
}

impl PoseMiss {
    /// Every reason, in a fixed order (for per-reason counters and logs).
    pub const ALL: [PoseMiss; 4] = [Self::Empty, Self::AfterNewest, Self::BeforeOldest, Self::Gap];

    /// A short name for logs.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Empty => "no pose received yet",
            Self::AfterNewest => "no pose at or after the frame in time, and the last one is too old to hold",
            Self::BeforeOldest => "frame is older than every buffered pose",
            Self::Gap => "the poses around the frame are too far apart to interpolate",
        }
    }
}

/// The pose was not added: it is stamped before the newest pose (the buffer only grows
/// forwards, so a late pose cannot reorder what lookups already used).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutOfOrder {
    /// The refused pose's stamp.
    pub stamp_ns: u64,
    /// The newest buffered stamp.
    pub newest_ns: u64,
}

/// Keeps the newest poses of a stream and answers "where was the camera at time t".
///
/// A stamp between two buffered poses at most
/// [`max_interpolation_gap_ns`](PoseBufferConfig::max_interpolation_gap_ns) apart gets the pose
/// interpolated between them (linear in translation, spherical in rotation). Otherwise the nearest
/// pose is held if it is within [`hold_tolerance_ns`](PoseBufferConfig::hold_tolerance_ns) of the
/// stamp; nothing is ever extrapolated further. A stamp after the newest pose can be looked up
/// with `may_wait`, which answers [`PoseAt::WaitForLater`] so that the caller waits (a bounded
/// time) for the pose that brackets it instead of holding the last one at once.
///
/// Stamps must be on the same clock as the frames looked up (see the keyframe gate's docs for the
/// clock of each source).
#[derive(Debug, Clone)]
pub struct PoseBuffer {
    poses: std::collections::VecDeque<StampedPose>,
    config: PoseBufferConfig,
}

impl PoseBuffer {
    /// An empty buffer (`capacity` is raised to 2 when smaller).
    pub fn new(config: PoseBufferConfig) -> Self {
        let config = PoseBufferConfig { capacity: config.capacity.max(2), ..config };
        Self { poses: std::collections::VecDeque::with_capacity(config.capacity), config }
    }

    /// The configuration in use.
    pub fn config(&self) -> &PoseBufferConfig {
        &self.config
    }

    /// Adds a pose stamped at or after the newest one; an older one is refused and the buffer is
    /// left as it was.
    pub fn push(&mut self, pose: StampedPose) -> Result<(), OutOfOrder> {
        if let Some(newest) = self.poses.back()
            && pose.stamp_ns < newest.stamp_ns
        {
            return Err(OutOfOrder { stamp_ns: pose.stamp_ns, newest_ns: newest.stamp_ns });
        }
        if self.poses.len() == self.config.capacity {
            self.poses.pop_front();
        }
        self.poses.push_back(pose);
        Ok(())
    }

    /// Removes the poses stamped after `stamp_ns` (poses adopted before any frame showed they
    /// were in the future); returns how many.
    pub fn discard_after(&mut self, stamp_ns: u64) -> usize {
        let keep = self.poses.partition_point(|p| p.stamp_ns <= stamp_ns);
        let removed = self.poses.len() - keep;
        self.poses.truncate(keep);
        removed
    }

    /// Removes every pose.
    pub fn clear(&mut self) {
        self.poses.clear();
    }

    /// The pose at `stamp_ns` (see the type's docs). With `may_wait`, a stamp after the newest
    /// pose (or any stamp while the buffer is empty) answers [`PoseAt::WaitForLater`].
    pub fn pose_at(&self, stamp_ns: u64, may_wait: bool) -> PoseAt {
        let after = self.poses.partition_point(|p| p.stamp_ns < stamp_ns);
        let next = self.poses.get(after);
        let prev = after.checked_sub(1).and_then(|i| self.poses.get(i));
        let hold = self.config.hold_tolerance_ns;
        match (prev, next) {
            (None, None) if may_wait => PoseAt::WaitForLater,
            (None, None) => PoseAt::Missing(PoseMiss::Empty),
            (_, Some(n)) if n.stamp_ns == stamp_ns => PoseAt::Interpolated(n.world_from_camera),
            (Some(p), Some(n)) => {
                if n.stamp_ns - p.stamp_ns <= self.config.max_interpolation_gap_ns {
                    let t = (stamp_ns - p.stamp_ns) as f64 / (n.stamp_ns - p.stamp_ns) as f64;
                    PoseAt::Interpolated(p.world_from_camera.interpolate(&n.world_from_camera, t))
                } else {
                    let (to_prev, to_next) = (stamp_ns - p.stamp_ns, n.stamp_ns - stamp_ns);
                    let (nearest, distance) = if to_prev <= to_next { (p, to_prev) } else { (n, to_next) };
                    if distance <= hold {
                        PoseAt::Held(nearest.world_from_camera)
                    } else {
                        PoseAt::Missing(PoseMiss::Gap)
                    }
                }
            }
            (Some(_), None) if may_wait => PoseAt::WaitForLater,
            (Some(p), None) if stamp_ns - p.stamp_ns <= hold => PoseAt::Held(p.world_from_camera),
            (Some(_), None) => PoseAt::Missing(PoseMiss::AfterNewest),
            (None, Some(n)) if n.stamp_ns - stamp_ns <= hold => PoseAt::Held(n.world_from_camera),
            (None, Some(_)) => PoseAt::Missing(PoseMiss::BeforeOldest),
        }
    }

    /// The pose at `stamp_ns` without waiting ([`Self::pose_at`]), `None` when there is none.
    pub fn lookup(&self, stamp_ns: u64) -> Option<Isometry> {
        self.pose_at(stamp_ns, false).pose()
    }

    /// Stamp of the newest pose.
    pub fn newest_stamp_ns(&self) -> Option<u64> {
        self.poses.back().map(|p| p.stamp_ns)
    }

    /// Number of buffered poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// `true` when no pose is buffered.
    pub fn is_empty(&self) -> bool {
        self.poses.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_composes_to_identity() {
        let a = Isometry::new(DQuat::from_rotation_z(0.7) * DQuat::from_rotation_x(-0.3), DVec3::new(1.0, -2.0, 0.5));
        let id = a * a.inverse();
        assert!(id.translation.length() < 1e-12);
        assert!(id.rotation.angle_between(DQuat::IDENTITY) < 1e-9);
        let p = DVec3::new(0.3, 0.2, 0.1);
        assert!((a.inverse().transform_point(a.transform_point(p)) - p).length() < 1e-12);
    }

    fn buffer(max_gap_ns: u64, hold_ns: u64) -> PoseBuffer {
        PoseBuffer::new(PoseBufferConfig {
            capacity: 8,
            max_interpolation_gap_ns: max_gap_ns,
            hold_tolerance_ns: hold_ns,
        })
    }

    fn at_x(stamp_ns: u64, x: f64) -> StampedPose {
        StampedPose { stamp_ns, world_from_camera: Isometry::new(DQuat::IDENTITY, DVec3::new(x, 0.0, 0.0)) }
    }

    #[test]
    fn buffer_interpolates_holds_within_tolerance_and_never_extrapolates() {
        let mut buf = buffer(150, 100);
        buf.push(at_x(1000, 0.0)).expect("first");
        buf.push(at_x(1100, 1.0)).expect("in order");
        buf.push(at_x(2000, 5.0)).expect("in order");
        let x = |answer: PoseAt| answer.pose().map(|p| p.translation.x);
        assert!(matches!(buf.pose_at(1050, false), PoseAt::Interpolated(p) if (p.translation.x - 0.5).abs() < 1e-12));
        assert_eq!(buf.pose_at(1100, false), PoseAt::Interpolated(at_x(1100, 1.0).world_from_camera));
        // Inside the 900 ns gap (wider than 150): held only near either end.
        assert_eq!(buf.pose_at(1500, false), PoseAt::Missing(PoseMiss::Gap));
        assert_eq!(x(buf.pose_at(1150, false)), Some(1.0));
        assert!(matches!(buf.pose_at(1950, false), PoseAt::Held(_)));
        assert_eq!(x(buf.pose_at(1950, false)), Some(5.0));
        // After the newest pose: held within 100 ns, then nothing; waiting is offered.
        assert_eq!(x(buf.pose_at(2100, false)), Some(5.0));
        assert_eq!(buf.pose_at(2101, false), PoseAt::Missing(PoseMiss::AfterNewest));
        assert_eq!(buf.pose_at(2050, true), PoseAt::WaitForLater);
        // Before the oldest.
        assert_eq!(x(buf.pose_at(900, false)), Some(0.0));
        assert_eq!(buf.pose_at(899, false), PoseAt::Missing(PoseMiss::BeforeOldest));
        // Out of order: refused, buffer unchanged.
        assert_eq!(buf.push(at_x(10, 0.0)), Err(OutOfOrder { stamp_ns: 10, newest_ns: 2000 }));
        assert_eq!(buf.len(), 3);
        // Recovery from poses found to be in the future.
        assert_eq!(buf.discard_after(1100), 1);
        assert_eq!(buf.newest_stamp_ns(), Some(1100));
        buf.push(at_x(1200, 2.0)).expect("in order again");
        let empty = buffer(150, 100);
        assert_eq!(empty.pose_at(5, false), PoseAt::Missing(PoseMiss::Empty));
        assert_eq!(empty.pose_at(5, true), PoseAt::WaitForLater);
    }

    /// A Stretch-like head camera: the base drives a 1.5 m circle at 0.3 m/s (turning with it),
    /// the head pans +-0.5 rad with a 6.3 s period and tilts +-0.2 rad with a 12.6 s period, and
    /// the camera sits 1.2 m high, bobbing 1 cm.
    fn known_trajectory(t_s: f64) -> Isometry {
        let (radius_m, speed_mps) = (1.5, 0.3);
        let heading = t_s * speed_mps / radius_m;
        let base = DVec3::new(radius_m * heading.cos(), radius_m * heading.sin(), 1.2 + 0.01 * (2.0 * t_s).sin());
        let yaw = heading + std::f64::consts::FRAC_PI_2 + 0.5 * t_s.sin();
        let tilt = 0.2 * (0.5 * t_s).sin();
        // Optical frame: z forward, x right, y down, looking along `yaw` and `tilt`.
        let optical = DQuat::from_mat3(&glam::DMat3::from_cols(DVec3::NEG_Y, DVec3::NEG_Z, DVec3::X));
        let rotation = DQuat::from_rotation_z(yaw) * DQuat::from_rotation_y(-tilt) * optical;
        Isometry::new(rotation, base)
    }

    /// Largest translation (m) and rotation (degrees) error of the buffer's poses at 30 Hz frame
    /// stamps over 30 s, against the trajectory, from a pose stream at `rate_hz` whose stamps are
    /// offset from the frames'.
    fn interpolation_error(rate_hz: f64) -> (f64, f64) {
        let period_ns = (1e9 / rate_hz) as u64;
        let mut buf = PoseBuffer::new(PoseBufferConfig {
            capacity: 4096,
            max_interpolation_gap_ns: period_ns + period_ns / 2,
            hold_tolerance_ns: 0,
        });
        let offset_ns = 7_000_000;
        let end_ns = 31_000_000_000u64;
        let mut stamp_ns = offset_ns;
        while stamp_ns <= end_ns {
            let pose = known_trajectory(stamp_ns as f64 * 1e-9);
            buf.push(StampedPose { stamp_ns, world_from_camera: pose }).expect("in order");
            stamp_ns += period_ns;
        }
        let (mut worst_m, mut worst_deg) = (0.0f64, 0.0f64);
        for k in 1..900u64 {
            let frame_ns = k * 33_333_333;
            let exact = known_trajectory(frame_ns as f64 * 1e-9);
            let PoseAt::Interpolated(found) = buf.pose_at(frame_ns, false) else {
                panic!("frame {k} at {frame_ns} ns not interpolated at {rate_hz} Hz");
            };
            worst_m = worst_m.max(found.translation.distance(exact.translation));
            worst_deg = worst_deg.max(found.rotation.angle_between(exact.rotation).to_degrees());
        }
        (worst_m, worst_deg)
    }

    #[test]
    fn interpolation_follows_a_known_trajectory_at_10_30_and_100_hz() {
        for rate_hz in [10.0, 30.0, 100.0] {
            let (error_m, error_deg) = interpolation_error(rate_hz);
            eprintln!("{rate_hz} Hz poses: largest error {:.4} mm, {:.5} degrees", error_m * 1e3, error_deg);
            assert!(error_m <= 1e-3, "{rate_hz} Hz: translation error {error_m} m");
            assert!(error_deg <= 0.05, "{rate_hz} Hz: rotation error {error_deg} degrees");
        }
        // Sanity of the measure: holding the previous pose instead (no interpolation) at 10 Hz is
        // far off, so the figures above are not vacuous.
        let held = known_trajectory(0.1).translation.distance(known_trajectory(0.0).translation);
        assert!(held > 0.02, "{held}");
    }
}
