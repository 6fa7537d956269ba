//! [`RigidTransform`]: a rotation then a translation, in double precision, named `a_from_b` (it maps
//! points expressed in frame `b` into frame `a`), the convention of `op3dsg_drivers::pose::Isometry`.
//! The two have the same fields, so `Isometry::new(t.rotation, t.translation)` converts.

use glam::{DQuat, DVec3};

/// A rigid transform (rotation then translation), double precision.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RigidTransform {
    /// Unit quaternion.
    pub rotation: DQuat,
    /// Translation, metres.
    pub translation: DVec3,
}

impl Default for RigidTransform {
    fn default() -> Self {
        Self::IDENTITY
    }
}

impl RigidTransform {
    /// The identity transform.
    pub const IDENTITY: Self = Self { rotation: DQuat::IDENTITY, translation: DVec3::ZERO };

    /// From a rotation (normalised here) and a translation.
    pub fn new(rotation: DQuat, translation: DVec3) -> Self {
        Self { rotation: rotation.normalize(), translation }
    }

    /// Applies the transform to a point.
    #[inline]
    pub fn transform_point(&self, point: DVec3) -> DVec3 {
        self.rotation * point + self.translation
    }

    /// The inverse transform (`b_from_a` of an `a_from_b`).
    pub fn inverse(&self) -> Self {
        let rotation = self.rotation.inverse();
        Self { rotation, translation: -(rotation * self.translation) }
    }

    /// Composition `self * rhs` (`a_from_b * b_from_c = a_from_c`).
    pub fn compose(&self, rhs: &Self) -> Self {
        Self {
            rotation: (self.rotation * rhs.rotation).normalize(),
            translation: self.rotation * rhs.translation + self.translation,
        }
    }

    /// Between `self` (`t = 0`) and `other` (`t = 1`): linear in translation, spherical (SLERP,
    /// shortest arc) in rotation.
    pub fn interpolate(&self, other: &Self, t: f64) -> Self {
        Self {
            rotation: self.rotation.slerp(other.rotation, t).normalize(),
            translation: self.translation.lerp(other.translation, t),
        }
    }
}

impl std::ops::Mul for RigidTransform {
    type Output = RigidTransform;
    fn mul(self, rhs: RigidTransform) -> RigidTransform {
        self.compose(&rhs)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn inverse_and_composition_agree() {
        let a =
            RigidTransform::new(DQuat::from_rotation_z(0.7) * DQuat::from_rotation_x(-0.3), DVec3::new(1.0, -2.0, 0.5));
        let b = RigidTransform::new(DQuat::from_rotation_y(1.1), DVec3::new(0.1, 0.2, 0.3));
        let p = DVec3::new(0.3, -0.2, 0.9);
        assert!(((a * b).transform_point(p) - a.transform_point(b.transform_point(p))).length() < 1e-12);
        let id = a * a.inverse();
        assert!(id.translation.length() < 1e-12);
        assert!(id.rotation.angle_between(DQuat::IDENTITY) < 1e-9);
        let half = RigidTransform::IDENTITY.interpolate(&a, 0.5);
        assert!((half.translation - a.translation * 0.5).length() < 1e-12);
        assert!(
            (half.rotation.angle_between(DQuat::IDENTITY) - a.rotation.angle_between(DQuat::IDENTITY) / 2.0).abs()
                < 1e-9
        );
    }
}
