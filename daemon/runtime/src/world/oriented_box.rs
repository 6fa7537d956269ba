//! Gravity-aligned oriented boxes for nodes: one axis is the world's up axis
//! (`world.up_axis`), the other two turn about it by a yaw taken from the node points'
//! horizontal covariance.
//!
//! The horizontal frame per up axis is [`super::horizontal_frame`]'s.
//!
//! The box's first axis is `cos(yaw) * first + sin(yaw) * second`, its second axis `up × first
//! box axis`, its third the up axis; `size_m` is the box's extent along these three, `centre_m`
//! its centre in the world. Yaw lies in `(-pi/2, pi/2]` (a box turned by pi is the same box).
//!
//! The yaw is the direction of the major eigenvector of the 2x2 covariance of the points'
//! horizontal coordinates (`nalgebra`'s `SymmetricEigen`). When the axis-aligned footprint is no
//! larger (within 0.1 %) than the one at that yaw (a square table, whose covariance is isotropic, or a
//! wall-aligned cabinet whose eigenvector wobbles by a few degrees with the noise), the box keeps
//! yaw 0, so such nodes do not get a noisy angle.

use glam::Vec3;
use nalgebra::{Matrix2, SymmetricEigen};

use super::{UpAxis, horizontal_frame};

/// A gravity-aligned oriented box (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct OrientedBox {
    /// Centre of the box, world, metres.
    pub centre_m: [f32; 3],
    /// Extent along the box's first and second (horizontal) axes and along up, metres.
    pub size_m: [f32; 3],
    /// Turn of the box's first axis from the first horizontal axis towards the second, about
    /// up, radians in `(-pi/2, pi/2]`.
    pub yaw_rad: f32,
}

impl OrientedBox {
    /// The box of an axis-aligned `min`..`max` (yaw 0).
    pub fn axis_aligned(min: [f32; 3], max: [f32; 3], up_axis: UpAxis) -> Self {
        let [first, second, up] = horizontal_frame(up_axis);
        let (min, max) = (Vec3::from_array(min), Vec3::from_array(max));
        let size = (max - min).abs();
        Self {
            centre_m: ((min + max) * 0.5).to_array(),
            size_m: [first.abs().dot(size), second.abs().dot(size), up.abs().dot(size)],
            yaw_rad: 0.0,
        }
    }

    /// The rotation taking a unit cube's x, y and z to the box's first axis, second axis and up
    /// (world), and the up direction: how viewers (Foxglove, RViz) place the box.
    pub fn rotation(&self, up_axis: UpAxis) -> (glam::DQuat, glam::DVec3) {
        let [first, second, up] = horizontal_frame(up_axis).map(|v| v.as_dvec3());
        let (sin, cos) = f64::from(self.yaw_rad).sin_cos();
        let axis_a = first * cos + second * sin;
        let axis_b = up.cross(axis_a);
        (glam::DQuat::from_mat3(&glam::DMat3::from_cols(axis_a, axis_b, up)).normalize(), up)
    }

    /// The box of `points` (module docs); `None` without points or with a non-finite one.
    pub fn fit(points: &[Vec3], up_axis: UpAxis) -> Option<Self> {
        if points.is_empty() || points.iter().any(|p| !p.is_finite()) {
            return None;
        }
        let [first, second, up] = horizontal_frame(up_axis);
        let n = points.len() as f64;
        let (mut su, mut sv) = (0.0f64, 0.0f64);
        for p in points {
            su += f64::from(p.dot(first));
            sv += f64::from(p.dot(second));
        }
        let (mu, mv) = (su / n, sv / n);
        let (mut cuu, mut cuv, mut cvv) = (0.0f64, 0.0f64, 0.0f64);
        for p in points {
            let (du, dv) = (f64::from(p.dot(first)) - mu, f64::from(p.dot(second)) - mv);
            cuu += du * du;
            cuv += du * dv;
            cvv += dv * dv;
        }
        let eigen = SymmetricEigen::new(Matrix2::new(cuu / n, cuv / n, cuv / n, cvv / n));
        let major = if eigen.eigenvalues[0] >= eigen.eigenvalues[1] { 0 } else { 1 };
        let axis = eigen.eigenvectors.column(major);
        let yaw = wrap_half_turn(axis[1].atan2(axis[0]));
        let fitted = Self::at_yaw(points, yaw as f32, [first, second, up]);
        let aligned = Self::at_yaw(points, 0.0, [first, second, up]);
        let area = |b: &Self| b.size_m[0] * b.size_m[1];
        // Within 0.1 %: equal footprints (a box long along the second axis) keep yaw 0.
        Some(if area(&aligned) <= area(&fitted) * 1.001 { aligned } else { fitted })
    }

    /// The tightest box of `points` with its first axis at `yaw`.
    fn at_yaw(points: &[Vec3], yaw: f32, [first, second, up]: [Vec3; 3]) -> Self {
        let (sin, cos) = yaw.sin_cos();
        let axis_a = first * cos + second * sin;
        let axis_b = up.cross(axis_a);
        let mut lo = Vec3::splat(f32::INFINITY);
        let mut hi = Vec3::splat(f32::NEG_INFINITY);
        for p in points {
            let q = Vec3::new(p.dot(axis_a), p.dot(axis_b), p.dot(up));
            lo = lo.min(q);
            hi = hi.max(q);
        }
        let mid = (lo + hi) * 0.5;
        let centre = axis_a * mid.x + axis_b * mid.y + up * mid.z;
        Self { centre_m: centre.to_array(), size_m: (hi - lo).to_array(), yaw_rad: yaw }
    }

    /// The eight corners, world, metres (bottom four first, counter-clockwise about up).
    pub fn corners(&self, up_axis: UpAxis) -> [[f32; 3]; 8] {
        let [first, second, up] = horizontal_frame(up_axis);
        let (sin, cos) = self.yaw_rad.sin_cos();
        let axis_a = first * cos + second * sin;
        let axis_b = up.cross(axis_a);
        let half = Vec3::from_array(self.size_m) * 0.5;
        let centre = Vec3::from_array(self.centre_m);
        let mut out = [[0.0; 3]; 8];
        let signs = [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)];
        for (level, z) in [-1.0f32, 1.0].into_iter().enumerate() {
            for (i, (a, b)) in signs.iter().enumerate() {
                out[level * 4 + i] =
                    (centre + axis_a * (a * half.x) + axis_b * (b * half.y) + up * (z * half.z)).to_array();
            }
        }
        out
    }
}

/// `angle` folded into `(-pi/2, pi/2]`.
fn wrap_half_turn(angle: f64) -> f64 {
    use std::f64::consts::{FRAC_PI_2, PI};
    let mut a = angle.rem_euclid(PI);
    if a > FRAC_PI_2 {
        a -= PI;
    }
    a
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A filled rectangle `length` x `width` (horizontal) x `height`, turned by `yaw` about up,
    /// centred at `centre`, on a 1 cm grid.
    fn slab(centre: Vec3, length: f32, width: f32, height: f32, yaw: f32, up_axis: UpAxis) -> Vec<Vec3> {
        let [first, second, up] = horizontal_frame(up_axis);
        let (sin, cos) = yaw.sin_cos();
        let a = first * cos + second * sin;
        let b = up.cross(a);
        let steps = |extent: f32| (extent / 0.01).round() as i32;
        let mut points = Vec::new();
        for i in 0..=steps(length) {
            for j in 0..=steps(width) {
                for k in 0..=steps(height).max(1) {
                    let (u, v, w) = (i as f32 * 0.01 - length / 2.0, j as f32 * 0.01 - width / 2.0, k as f32 * 0.01);
                    points.push(centre + a * u + b * v + up * (w - height / 2.0));
                }
            }
        }
        points
    }

    #[test]
    fn a_turned_counter_gets_its_yaw_and_size() {
        for yaw_deg in [-60.0f32, -30.0, 20.0, 35.0, 80.0] {
            let yaw = yaw_deg.to_radians();
            let points = slab(Vec3::new(2.0, 1.0, 0.45), 1.2, 0.4, 0.9, yaw, UpAxis::Z);
            let fitted = OrientedBox::fit(&points, UpAxis::Z).expect("points");
            assert!((fitted.yaw_rad - yaw).abs() < 0.01, "{yaw_deg}: {fitted:?}");
            for (found, expected) in fitted.size_m.iter().zip([1.2, 0.4, 0.9]) {
                assert!((found - expected).abs() < 0.02, "{yaw_deg}: {fitted:?}");
            }
            assert!(Vec3::from_array(fitted.centre_m).distance(Vec3::new(2.0, 1.0, 0.45)) < 0.01, "{fitted:?}");
        }
    }

    #[test]
    fn the_major_axis_may_be_either_horizontal_axis_and_yaw_stays_within_a_half_turn() {
        // Long along the second horizontal axis: the box's first axis follows the long side.
        let points = slab(Vec3::ZERO, 0.3, 1.5, 0.5, 0.0, UpAxis::Z);
        let fitted = OrientedBox::fit(&points, UpAxis::Z).expect("points");
        // Axis-aligned either way, so yaw 0 is kept with the sizes along x and y.
        assert_eq!(fitted.yaw_rad, 0.0);
        assert!((fitted.size_m[0] - 0.3).abs() < 0.02 && (fitted.size_m[1] - 1.5).abs() < 0.02, "{fitted:?}");
        assert!((wrap_half_turn(std::f64::consts::PI) - 0.0).abs() < 1e-12);
        assert!((wrap_half_turn(-std::f64::consts::FRAC_PI_2) - std::f64::consts::FRAC_PI_2).abs() < 1e-12);
        assert!((wrap_half_turn(2.0) - (2.0 - std::f64::consts::PI)).abs() < 1e-12);
    }

    #[test]
    fn a_square_table_keeps_yaw_zero_instead_of_an_arbitrary_angle() {
        let points = slab(Vec3::new(1.0, 1.0, 0.7), 0.8, 0.8, 0.04, 0.0, UpAxis::Z);
        let fitted = OrientedBox::fit(&points, UpAxis::Z).expect("points");
        assert_eq!(fitted.yaw_rad, 0.0);
        let aligned = OrientedBox::axis_aligned([0.6, 0.6, 0.68], [1.4, 1.4, 0.72], UpAxis::Z);
        for (a, b) in fitted.size_m.iter().zip(aligned.size_m) {
            assert!((a - b).abs() < 1e-4, "{fitted:?} vs {aligned:?}");
        }
    }

    #[test]
    fn the_up_axis_decides_which_plane_the_yaw_turns_in() {
        for up_axis in [UpAxis::Y, UpAxis::NegY] {
            let yaw = 0.5f32;
            let points = slab(Vec3::new(0.5, 0.2, -1.0), 1.0, 0.3, 0.6, yaw, up_axis);
            let fitted = OrientedBox::fit(&points, up_axis).expect("points");
            assert!((fitted.yaw_rad - yaw).abs() < 0.01, "{up_axis:?}: {fitted:?}");
            assert!((fitted.size_m[2] - 0.6).abs() < 0.02, "{up_axis:?}: {fitted:?}");
            // Every point lies inside the box's corners' span along up.
            let corners = fitted.corners(up_axis);
            let [_, _, up] = horizontal_frame(up_axis);
            let heights: Vec<f32> = corners.iter().map(|c| Vec3::from_array(*c).dot(up)).collect();
            let (lo, hi) = (heights[0], heights[4]);
            assert!(points.iter().all(|p| (lo - 1e-4..=hi + 1e-4).contains(&p.dot(up))), "{up_axis:?}");
        }
        assert_eq!(OrientedBox::fit(&[], UpAxis::Z), None);
        assert_eq!(OrientedBox::fit(&[Vec3::new(f32::NAN, 0.0, 0.0)], UpAxis::Z), None);
    }
}
