//! The world the map lives in: which way is up, the horizontal frame that goes with it, the
//! gravity-aligned boxes of nodes, and the clocks stamps are read from. A leaf: it imports
//! nothing of the stages.
//!
//! The horizontal frame per up axis (right-handed, `first × second = up`):
//!
//! | `world.up_axis` | first horizontal axis | second horizontal axis | up |
//! |---|---|---|---|
//! | `z` | +x | +y | +z |
//! | `y` | +z | +x | +y |
//! | `neg_y` | +x | +z | -y |
//!

use glam::Vec3;
use serde::{Deserialize, Serialize};

pub mod clock;
pub mod oriented_box;

pub use oriented_box::OrientedBox;

/// Up axis of the world frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UpAxis {
    /// +z up (robotics convention; the synthetic world).
    Z,
    /// +y up.
    Y,
    /// -y up (OpenCV camera-like worlds).
    NegY,
}

/// `[world]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldConfig {
    /// Which axis is up (gravity is opposite).
    pub up_axis: UpAxis,
}

/// The horizontal axes and the up axis of the world (the table above).
pub fn horizontal_frame(up_axis: UpAxis) -> [Vec3; 3] {
    match up_axis {
        UpAxis::Z => [Vec3::X, Vec3::Y, Vec3::Z],
        UpAxis::Y => [Vec3::Z, Vec3::X, Vec3::Y],
        UpAxis::NegY => [Vec3::X, Vec3::Z, Vec3::NEG_Y],
    }
}
