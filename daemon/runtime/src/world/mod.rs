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
    /// Name of the world frame: the frame the graph's coordinates (and the poses the daemon is
    /// sent) are in. Every graph header and health record carries it, and recordings use it as
    /// the parent of `/tf` and the frame of the scene. `world` by default; a robot sets its
    /// navigation stack's frame (`map` on the Stretch 3). Checked by [`WorldConfig::validate`].
    #[serde(default = "default_frame_id")]
    pub frame_id: String,
}

/// The world frame's name when the profile sets none.
pub const DEFAULT_WORLD_FRAME: &str = "world";

/// Longest world frame name, bytes of UTF-8: what the graph header's field holds.
pub const MAX_WORLD_FRAME_BYTES: usize = op3dsg_ipc_types::NAME_CAPACITY_BYTES;

fn default_frame_id() -> String {
    DEFAULT_WORLD_FRAME.to_owned()
}

impl Default for WorldConfig {
    /// `+z` up, frame `world`.
    fn default() -> Self {
        Self { up_axis: UpAxis::Z, frame_id: default_frame_id() }
    }
}

impl WorldConfig {
    /// Checks `frame_id` as a ROS frame id (what tf, a navigation stack and Foxglove name frames
    /// with): not empty, at most [`MAX_WORLD_FRAME_BYTES`] bytes (the graph header's field), a
    /// letter first, then letters, digits, `_` and `/` (namespaces: `robot_1/map`), no `//` and
    /// no `/` at the end (tf2 refuses a leading one). The message starts with `path.frame_id`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let id = &self.frame_id;
        let key = format!("{path}.frame_id");
        if id.is_empty() {
            return Err(format!("{key}: must not be empty (the frame the graph's coordinates are in, e.g. \"map\")"));
        }
        if id.len() > MAX_WORLD_FRAME_BYTES {
            return Err(format!(
                "{key}: {id:?} is {} bytes, longer than the {MAX_WORLD_FRAME_BYTES} the graph header holds",
                id.len()
            ));
        }
        let rule = "a ROS frame id is a letter, then letters, digits, '_' and '/'";
        if let Some(c) = id.chars().find(|c| !(c.is_ascii_alphanumeric() || *c == '_' || *c == '/')) {
            return Err(format!("{key}: {id:?} contains {c:?}; {rule}"));
        }
        if !id.starts_with(|c: char| c.is_ascii_alphabetic()) {
            return Err(format!("{key}: {id:?} does not start with a letter; {rule} (tf2 refuses a leading '/')"));
        }
        if id.ends_with('/') || id.contains("//") {
            return Err(format!("{key}: {id:?} has an empty name between '/'; {rule}"));
        }
        Ok(())
    }
}

/// The horizontal axes and the up axis of the world (the table above).
pub fn horizontal_frame(up_axis: UpAxis) -> [Vec3; 3] {
    match up_axis {
        UpAxis::Z => [Vec3::X, Vec3::Y, Vec3::Z],
        UpAxis::Y => [Vec3::Z, Vec3::X, Vec3::Y],
        UpAxis::NegY => [Vec3::X, Vec3::Z, Vec3::NEG_Y],
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn world(frame_id: &str) -> WorldConfig {
        WorldConfig { frame_id: frame_id.to_owned(), ..WorldConfig::default() }
    }

    #[test]
    fn the_frame_id_defaults_to_world_and_is_checked() {
        let parsed: WorldConfig = toml::from_str("up_axis = \"y\"").expect("frame_id has a default");
        assert_eq!((parsed.up_axis, parsed.frame_id.as_str()), (UpAxis::Y, "world"));
        for ok in ["world", "map", "odom", "robot_1/map", "Map2", &"m".repeat(MAX_WORLD_FRAME_BYTES)] {
            assert_eq!(world(ok).validate("world"), Ok(()), "{ok}");
        }
        let err = |id: &str| world(id).validate("world").expect_err(id);
        assert!(err("").starts_with("world.frame_id: must not be empty"), "{}", err(""));
        let long = "m".repeat(MAX_WORLD_FRAME_BYTES + 1);
        assert_eq!(
            err(&long),
            format!("world.frame_id: {long:?} is 33 bytes, longer than the 32 the graph header holds")
        );
        // Multi-byte characters count in bytes: 17 'ä' are 34 bytes; fewer are refused by character.
        assert!(err(&"ä".repeat(17)).contains("is 34 bytes"));
        assert_eq!(
            err("my map"),
            "world.frame_id: \"my map\" contains ' '; a ROS frame id is a letter, then letters, digits, '_' and '/'"
        );
        for bad in ["Welt-1", "map.0", "kärte", "map\n", "map\u{0}"] {
            assert!(err(bad).starts_with(&format!("world.frame_id: {bad:?} contains ")), "{}", err(bad));
        }
        assert!(err("/map").contains("does not start with a letter"), "{}", err("/map"));
        assert!(err("1map").contains("does not start with a letter"), "{}", err("1map"));
        assert!(err("robot//map").contains("empty name"), "{}", err("robot//map"));
        assert!(err("map/").contains("empty name"), "{}", err("map/"));
        assert!(toml::from_str::<WorldConfig>("up_axis = \"z\"\nframe = \"map\"").is_err(), "unknown keys are refused");
    }
}
