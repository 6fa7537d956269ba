//! The pose input's wire type: [`PoseStamped`] as the navigation stack sends it on
//! `<prefix>/pose`, and the checks both sides apply to it.

// The derive macros emit `unsafe impl ZeroCopySend`; that is the only unsafe code here.
#![allow(unsafe_code)]

use iceoryx2::prelude::{PlacementDefault, ZeroCopySend};

use crate::NAME_CAPACITY_BYTES;

/// What a [`PoseStamped`] describes.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PoseKind {
    /// `world_from_camera`: the optical frame of the colour camera (x right, y down, z forward)
    /// in the world. On a Stretch the head pans and tilts, so the navigation stack composes the
    /// base pose with the head joints and sends this.
    #[default]
    WorldFromCamera = 0,
    /// `world_from_base`: the robot base in the world; the daemon composes it with the fixed
    /// `base_from_camera` of the profile (rigid mounts only).
    WorldFromBase = 1,
}

impl PoseKind {
    /// Decodes the wire value of [`PoseStamped::kind`].
    pub fn from_u8(value: u8) -> Option<Self> {
        match value {
            0 => Some(Self::WorldFromCamera),
            1 => Some(Self::WorldFromBase),
            _ => None,
        }
    }
}

/// A pose sent to the daemon on `<prefix>/pose` (size 104 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::PoseStamped")]
pub struct PoseStamped {
    /// Time the pose is valid at, nanoseconds, on the same clock as the camera frames: the host
    /// clock (librealsense global time, ns since the Unix epoch) for the camera, the recording's
    /// stamps for a replay, scene time from 0 for the synthetic source. The daemon interpolates
    /// between the poses around each frame's stamp (its keyframe gate's docs give the rules).
    pub stamp_ns: u64,
    /// [`PoseKind`] as `u8`.
    pub kind: u8,
    /// Reserved, zero.
    pub reserved: [u8; 7],
    /// Translation, metres, world frame.
    pub translation_m: [f64; 3],
    /// Rotation as a unit quaternion `[x, y, z, w]`.
    pub rotation_xyzw: [f64; 4],
    /// Name of the child frame (for example `camera_color_optical_frame` or `base_link`),
    /// UTF-8, NUL padded. For the reader's benefit (the recorder keeps it): the daemon compares
    /// it with nothing; `kind` says which frame the pose is of.
    pub frame_id: [u8; NAME_CAPACITY_BYTES],
}

impl PoseStamped {
    /// A pose of `kind` valid at `stamp_ns`, checked with [`check_pose`]; `frame_id` names the
    /// child frame and must fit [`NAME_CAPACITY_BYTES`].
    pub fn new(
        stamp_ns: u64,
        kind: PoseKind,
        translation_m: [f64; 3],
        rotation_xyzw: [f64; 4],
        frame_id: &str,
    ) -> Result<Self, PoseError> {
        let mut pose =
            PoseStamped { stamp_ns, kind: kind as u8, translation_m, rotation_xyzw, ..PoseStamped::default() };
        if !crate::write_fixed_str(&mut pose.frame_id, frame_id) {
            return Err(PoseError::FrameIdTooLong { len: frame_id.len() });
        }
        check_pose(&pose)?;
        Ok(pose)
    }

    /// The decoded kind (an unknown wire value reads as `None`).
    pub fn pose_kind(&self) -> Option<PoseKind> {
        PoseKind::from_u8(self.kind)
    }

    /// The child frame name as text.
    pub fn frame_id_str(&self) -> &str {
        crate::fixed_str(&self.frame_id)
    }
}

/// Why a pose cannot go on the wire (sender side) or is dropped (daemon side).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum PoseError {
    /// `kind` is not a [`PoseKind`] value.
    UnknownKind {
        /// The wire value found.
        value: u8,
    },
    /// A translation component is NaN or infinite.
    NonFiniteTranslation {
        /// The translation given, metres.
        translation_m: [f64; 3],
    },
    /// A quaternion component is NaN or infinite.
    NonFiniteRotation {
        /// The quaternion given, `[x, y, z, w]`.
        rotation_xyzw: [f64; 4],
    },
    /// The quaternion's norm is off 1 by more than
    /// [`QUATERNION_NORM_TOLERANCE`](crate::services::QUATERNION_NORM_TOLERANCE).
    NonUnitQuaternion {
        /// The norm found.
        norm: f64,
    },
    /// The frame id does not fit [`NAME_CAPACITY_BYTES`].
    FrameIdTooLong {
        /// Its length, bytes.
        len: usize,
    },
}

impl core::fmt::Display for PoseError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::UnknownKind { value } => write!(f, "unknown kind {value} (0 world_from_camera, 1 world_from_base)"),
            Self::NonFiniteTranslation { translation_m } => write!(f, "non-finite translation {translation_m:?} m"),
            Self::NonFiniteRotation { rotation_xyzw } => write!(f, "non-finite quaternion {rotation_xyzw:?} (xyzw)"),
            Self::NonUnitQuaternion { norm } => {
                write!(f, "quaternion norm {norm} is not 1 (tolerance {})", crate::services::QUATERNION_NORM_TOLERANCE)
            }
            Self::FrameIdTooLong { len } => {
                write!(f, "frame_id is {len} bytes, longer than {NAME_CAPACITY_BYTES}")
            }
        }
    }
}

impl std::error::Error for PoseError {}

/// The checks the daemon applies to every received pose (it drops and counts those that fail)
/// and [`PosePublisher`](crate::client::PosePublisher) applies before sending: a known kind, a
/// finite translation and a finite unit quaternion (norm within
/// [`QUATERNION_NORM_TOLERANCE`](crate::services::QUATERNION_NORM_TOLERANCE) of 1).
pub fn check_pose(pose: &PoseStamped) -> Result<(), PoseError> {
    if PoseKind::from_u8(pose.kind).is_none() {
        return Err(PoseError::UnknownKind { value: pose.kind });
    }
    if !pose.translation_m.iter().all(|v| v.is_finite()) {
        return Err(PoseError::NonFiniteTranslation { translation_m: pose.translation_m });
    }
    if !pose.rotation_xyzw.iter().all(|v| v.is_finite()) {
        return Err(PoseError::NonFiniteRotation { rotation_xyzw: pose.rotation_xyzw });
    }
    let norm = pose.rotation_xyzw.iter().map(|v| v * v).sum::<f64>().sqrt();
    if (norm - 1.0).abs() > crate::services::QUATERNION_NORM_TOLERANCE {
        return Err(PoseError::NonUnitQuaternion { norm });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pose_checks_name_what_is_wrong() {
        let identity = [0.0, 0.0, 0.0, 1.0];
        let mut pose =
            PoseStamped::new(5, PoseKind::WorldFromBase, [1.0, 2.0, 0.0], identity, "base_link").expect("valid pose");
        assert_eq!(pose.frame_id_str(), "base_link");
        assert_eq!(pose.pose_kind(), Some(PoseKind::WorldFromBase));
        pose.kind = 4;
        assert_eq!(check_pose(&pose), Err(PoseError::UnknownKind { value: 4 }));
        pose.kind = 0;
        pose.rotation_xyzw = [0.0, 0.0, 0.0, 0.9];
        let err = check_pose(&pose).expect_err("norm 0.9");
        assert!(matches!(err, PoseError::NonUnitQuaternion { norm } if (norm - 0.9).abs() < 1e-12));
        assert_eq!(err.to_string(), "quaternion norm 0.9 is not 1 (tolerance 0.001)");
        // Within the tolerance.
        pose.rotation_xyzw = [0.0, 0.0, 0.0, 1.0005];
        assert_eq!(check_pose(&pose), Ok(()));
        pose.rotation_xyzw = [f64::NAN, 0.0, 0.0, 1.0];
        assert!(matches!(check_pose(&pose), Err(PoseError::NonFiniteRotation { .. })));
        pose.rotation_xyzw = identity;
        pose.translation_m[2] = f64::INFINITY;
        assert!(matches!(check_pose(&pose), Err(PoseError::NonFiniteTranslation { .. })));
        let long = "x".repeat(NAME_CAPACITY_BYTES + 1);
        let err = PoseStamped::new(0, PoseKind::WorldFromCamera, [0.0; 3], identity, &long).expect_err("too long");
        assert_eq!(err, PoseError::FrameIdTooLong { len: NAME_CAPACITY_BYTES + 1 });
    }
}
