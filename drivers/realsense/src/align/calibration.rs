//! The streams' calibration as the alignment takes it: each stream's lens (intrinsics and lens
//! model), the depth → colour extrinsics, and the checks that refuse values it cannot align with.

/// A stream's lens model, as librealsense names it (`rs2_distortion`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Distortion {
    /// Rectilinear.
    None,
    /// Brown-Conrady with tangential terms applied to radially distorted points (projection).
    ModifiedBrownConrady,
    /// Coefficients that undistort (deprojection).
    InverseBrownConrady,
    /// Brown-Conrady.
    BrownConrady,
    /// Any other model librealsense knows (F-theta, Kannala-Brandt): `rs2_distortion` value.
    Other(i32),
}

/// A stream's intrinsics with its lens model (`rs2_intrinsics`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Lens {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Focal length along x, pixels.
    pub fx: f32,
    /// Focal length along y, pixels.
    pub fy: f32,
    /// Principal point x, pixels.
    pub ppx: f32,
    /// Principal point y, pixels.
    pub ppy: f32,
    /// Lens model.
    pub model: Distortion,
    /// The model's coefficients (k1, k2, p1, p2, k3).
    pub coeffs: [f32; 5],
}

impl Lens {
    /// A rectilinear lens.
    pub fn pinhole(width: u32, height: u32, fx: f32, fy: f32, ppx: f32, ppy: f32) -> Self {
        Self { width, height, fx, fy, ppx, ppy, model: Distortion::None, coeffs: [0.0; 5] }
    }

    /// Horizontal and vertical field of view in degrees, as librealsense's `rs2_fov`.
    pub fn fov_deg(&self) -> [f32; 2] {
        let (w, h) = (self.width as f32, self.height as f32);
        let x = (self.ppx + 0.5).atan2(self.fx) + (w - (self.ppx + 0.5)).atan2(self.fx);
        let y = (self.ppy + 0.5).atan2(self.fy) + (h - (self.ppy + 0.5)).atan2(self.fy);
        [x.to_degrees(), y.to_degrees()]
    }

    pub(super) fn has_coefficients(&self) -> bool {
        self.coeffs.iter().any(|c| *c != 0.0)
    }

    pub(super) fn check(&self, stream: &'static str) -> Result<(), AlignError> {
        let bad = |field: &'static str, value: f32| AlignError::Calibration { stream, field, value };
        // (Output indices are i32 in the projection.)
        if self.width == 0 || self.height == 0 || u64::from(self.width) * u64::from(self.height) > 1 << 30 {
            return Err(bad("size", self.width.min(self.height) as f32));
        }
        for (field, value) in [("fx", self.fx), ("fy", self.fy)] {
            if !(value.is_finite() && value > 0.0) {
                return Err(bad(field, value));
            }
        }
        for (field, value) in [("ppx", self.ppx), ("ppy", self.ppy)] {
            if !value.is_finite() {
                return Err(bad(field, value));
            }
        }
        if let Some(c) = self.coeffs.iter().find(|c| !c.is_finite()) {
            return Err(bad("coeffs", *c));
        }
        Ok(())
    }
}

/// The depth → colour extrinsics (`rs2_extrinsics`): `p_colour = R * p_depth + t`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Extrinsics {
    /// `R`, column-major as librealsense stores it.
    pub rotation: [f32; 9],
    /// `t`, metres.
    pub translation_m: [f32; 3],
}

impl Extrinsics {
    /// The same camera.
    pub const IDENTITY: Self =
        Self { rotation: [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0], translation_m: [0.0; 3] };

    pub(super) fn apply_rotation(&self, p: [f64; 3]) -> [f64; 3] {
        let r = self.rotation.map(f64::from);
        [
            r[0] * p[0] + r[3] * p[1] + r[6] * p[2],
            r[1] * p[0] + r[4] * p[1] + r[7] * p[2],
            r[2] * p[0] + r[5] * p[1] + r[8] * p[2],
        ]
    }
}

/// Calibration that cannot align.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AlignError {
    /// A value of a stream's intrinsics is out of range.
    #[error("{stream} intrinsics: {field} = {value} (need a finite value, focal lengths and sizes above 0)")]
    Calibration {
        /// `depth` or `colour`.
        stream: &'static str,
        /// The field.
        field: &'static str,
        /// What it was.
        value: f32,
    },
    /// The extrinsics' rotation is not a rotation, or the translation is not finite.
    #[error("depth to colour extrinsics: {0}")]
    Extrinsics(String),
    /// The depth scale is not a positive number.
    #[error("depth units: {0} metres per unit (need a finite value above 0)")]
    DepthScale(f32),
}

pub(super) fn check_extrinsics(e: &Extrinsics) -> Result<(), AlignError> {
    if !e.rotation.iter().chain(&e.translation_m).all(|v| v.is_finite()) {
        return Err(AlignError::Extrinsics(format!("not finite: {e:?}")));
    }
    // R^T R = I within float noise of a calibration (columns of unit length, orthogonal).
    let r = e.rotation.map(f64::from);
    let col = |j: usize| [r[3 * j], r[3 * j + 1], r[3 * j + 2]];
    for i in 0..3 {
        for j in 0..3 {
            let (a, b) = (col(i), col(j));
            let dot = a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
            let want = if i == j { 1.0 } else { 0.0 };
            if (dot - want).abs() > 1e-3 {
                return Err(AlignError::Extrinsics(format!(
                    "rotation is not orthonormal (column {i} . column {j} = {dot:.6}): {:?}",
                    e.rotation
                )));
            }
        }
    }
    Ok(())
}
