//! Rigid transforms and pose sources.
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
    /// Time, nanoseconds.
    pub stamp_ns: u64,
    /// `world_from_camera`.
    pub world_from_camera: Isometry,
}

/// Keeps the newest poses of a stream and answers "where was the camera at time t" by
/// interpolation, refusing to extrapolate or bridge gaps wider than a tolerance.
#[derive(Debug, Clone)]
pub struct PoseBuffer {
    poses: std::collections::VecDeque<StampedPose>,
    capacity: usize,
    tolerance_ns: u64,
}

impl PoseBuffer {
    /// A buffer of `capacity` poses; `tolerance_ns` bounds both the gap between the two poses
    /// used for interpolation and the distance to a single nearest pose.
    pub fn new(capacity: usize, tolerance_ns: u64) -> Self {
        Self { poses: std::collections::VecDeque::with_capacity(capacity), capacity: capacity.max(2), tolerance_ns }
    }

    /// Adds a pose; out-of-order poses older than the newest are ignored (returns `false`).
    pub fn push(&mut self, pose: StampedPose) -> bool {
        if self.poses.back().is_some_and(|last| pose.stamp_ns < last.stamp_ns) {
            return false;
        }
        if self.poses.len() == self.capacity {
            self.poses.pop_front();
        }
        self.poses.push_back(pose);
        true
    }

    /// The pose at `stamp_ns`, interpolated between the poses around it, or the nearest pose
    /// when it is within tolerance; `None` otherwise.
    pub fn lookup(&self, stamp_ns: u64) -> Option<Isometry> {
        let after = self.poses.partition_point(|p| p.stamp_ns < stamp_ns);
        let next = self.poses.get(after);
        let prev = after.checked_sub(1).and_then(|i| self.poses.get(i));
        match (prev, next) {
            (_, Some(n)) if n.stamp_ns == stamp_ns => Some(n.world_from_camera),
            (Some(p), Some(n)) if n.stamp_ns - p.stamp_ns <= self.tolerance_ns => {
                let t = (stamp_ns - p.stamp_ns) as f64 / (n.stamp_ns - p.stamp_ns) as f64;
                Some(p.world_from_camera.interpolate(&n.world_from_camera, t))
            }
            (Some(p), _) if stamp_ns - p.stamp_ns <= self.tolerance_ns => Some(p.world_from_camera),
            (_, Some(n)) if n.stamp_ns - stamp_ns <= self.tolerance_ns => Some(n.world_from_camera),
            _ => None,
        }
    }

    /// Number of buffered poses.
    pub fn len(&self) -> usize {
        self.poses.len()
    }

    /// `true` when no pose has arrived yet.
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

    #[test]
    fn buffer_interpolates_and_refuses_gaps() {
        let mut buf = PoseBuffer::new(8, 100);
        let at = |x: f64| Isometry::new(DQuat::IDENTITY, DVec3::new(x, 0.0, 0.0));
        buf.push(StampedPose { stamp_ns: 1000, world_from_camera: at(0.0) });
        buf.push(StampedPose { stamp_ns: 1100, world_from_camera: at(1.0) });
        buf.push(StampedPose { stamp_ns: 2000, world_from_camera: at(5.0) });
        assert!((buf.lookup(1050).unwrap().translation.x - 0.5).abs() < 1e-12);
        assert_eq!(buf.lookup(1100).unwrap().translation.x, 1.0);
        // Inside the 900 ns gap, too far from either end.
        assert!(buf.lookup(1500).is_none());
        // Near the end of the gap, the nearest pose is close enough.
        assert_eq!(buf.lookup(1950).unwrap().translation.x, 5.0);
        assert!(buf.lookup(5000).is_none());
        assert!(!buf.push(StampedPose { stamp_ns: 10, world_from_camera: at(0.0) }));
    }
}
