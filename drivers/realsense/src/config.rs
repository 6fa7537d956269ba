//! `[source.realsense]`: which camera (or `.bag` file), its streams and options, the rotation.
//! Every key is documented in `profiles/stretch3-d435i.toml`.

use serde::{Deserialize, Serialize};

use crate::rotate::Rotation;

/// One video stream's mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StreamMode {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Frames per second.
    pub fps: u32,
}

/// The D400 visual presets (`RS2_OPTION_VISUAL_PRESET`, values of `rs2_rs400_visual_preset`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VisualPreset {
    /// Leave the camera's current preset.
    Unchanged,
    /// `custom` (0).
    Custom,
    /// `default` (1).
    Default,
    /// `hand` (2).
    Hand,
    /// `high_accuracy` (3): fewer, surer depth pixels.
    HighAccuracy,
    /// `high_density` (4): more depth pixels, more outliers.
    HighDensity,
    /// `medium_density` (5).
    MediumDensity,
}

impl VisualPreset {
    /// The option value, `None` for [`VisualPreset::Unchanged`].
    pub fn option_value(self) -> Option<f32> {
        match self {
            Self::Unchanged => None,
            Self::Custom => Some(0.0),
            Self::Default => Some(1.0),
            Self::Hand => Some(2.0),
            Self::HighAccuracy => Some(3.0),
            Self::HighDensity => Some(4.0),
            Self::MediumDensity => Some(5.0),
        }
    }
}

/// The IR projector (`RS2_OPTION_EMITTER_ENABLED`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Emitter {
    /// Leave it as it is.
    Unchanged,
    /// Off (0): passive stereo only.
    Off,
    /// On (1).
    On,
    /// Auto (2): the camera decides.
    Auto,
}

impl Emitter {
    /// The option value, `None` for [`Emitter::Unchanged`].
    pub fn option_value(self) -> Option<f32> {
        match self {
            Self::Unchanged => None,
            Self::Off => Some(0.0),
            Self::On => Some(1.0),
            Self::Auto => Some(2.0),
        }
    }
}

/// Who aligns depth to colour (`align`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum AlignMode {
    /// [`crate::align::DepthToColour`]: rays precomputed from the device's intrinsics,
    /// extrinsics and depth scale, written straight into the pooled frame (rotated on the way).
    #[default]
    Op3dsg,
    /// librealsense's align block (`rs2_create_align`), then the rotate-and-copy.
    Librealsense,
}

/// Reconnect backoff after the camera is lost.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Backoff {
    /// First retry after this many milliseconds.
    pub initial_ms: u64,
    /// Retries never wait longer than this (the wait doubles up to it).
    pub max_ms: u64,
}

impl Default for Backoff {
    fn default() -> Self {
        Self { initial_ms: 250, max_ms: 4000 }
    }
}

/// A fixed `world_from_camera` (a camera that does not move).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FixedPose {
    /// Translation, metres.
    pub translation_m: [f64; 3],
    /// Unit quaternion `[x, y, z, w]`.
    pub rotation_xyzw: [f64; 4],
}

/// `[source.realsense]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RealsenseConfig {
    /// Serial number of the camera to open; wins over `product`. Empty: chosen by `product`.
    /// Ignored when playing a `bag` (a serial names one unit; recordings move between robots).
    pub serial: String,
    /// The camera model to open when `serial` is empty: a word of the name librealsense reports
    /// (`D435I` for `Intel RealSense D435I`) or the whole name, in any case
    /// (`op3dsg_realsense::select`). Empty: any camera. With a `bag`, the recording's camera must
    /// match it too, so a profile made for one camera does not play another's recording.
    pub product: String,
    /// A librealsense recording (`.bag`) to play instead of a camera; empty: a live camera.
    /// Relative paths are resolved against the folder of the profile that sets it.
    pub bag: String,
    /// Playback of `bag` paced by its recorded timestamps (`true`) or as fast as the pipeline
    /// takes frames (`false`: `rs2_playback_device_set_real_time(0)`).
    pub bag_real_time: bool,
    /// Depth stream (aligned to colour, see `align`, before anything else).
    pub depth: StreamMode,
    /// Colour stream (RGB8); frames have its size and intrinsics (rotated).
    pub colour: StreamMode,
    /// Clockwise rotation applied to colour, depth and intrinsics: 0, 90, 180 or 270.
    pub rotate: Rotation,
    /// Depth to colour alignment: `op3dsg` (our own, from the device's calibration; the same
    /// result as librealsense's, see `op3dsg_realsense::align`) or `librealsense` (its align block).
    pub align: AlignMode,
    /// Depth sensor visual preset.
    pub visual_preset: VisualPreset,
    /// IR emitter.
    pub emitter: Emitter,
    /// Laser power in milliwatts when set (D435i: 0..360).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub laser_power_mw: Option<f32>,
    /// On a USB 2 link (too slow for the configured streams) use `usb2_mode` for both streams
    /// instead, with a warning; `false` tries the configured modes anyway.
    pub usb2_fallback: bool,
    /// Both streams' mode on a USB 2 link with `usb2_fallback`.
    pub usb2_mode: StreamMode,
    /// A frame set not arriving within this many milliseconds is a timeout (after the first
    /// frame; start-up allows 10 s). Consecutive timeouts of a live camera check whether it is
    /// still connected.
    pub frame_timeout_ms: u64,
    /// Reconnect backoff.
    pub reconnect: Backoff,
    /// Also stream the D435i's gyro and accelerometer (a recording's motion streams in
    /// playback): samples stamped on the frames' clock go to the source's IMU buffer
    /// (`op3dsg_realsense::imu`).
    pub imu: bool,
    /// A fixed `world_from_camera` for every frame (a camera on a stand, tests): frames then
    /// carry their pose and `pose.source = "frame"` works; leave unset on a robot (poses come
    /// from the navigation stack). With `rotate` it is the pose of the upright image's camera.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub world_from_camera: Option<FixedPose>,
}

impl Default for RealsenseConfig {
    fn default() -> Self {
        Self {
            serial: String::new(),
            product: String::new(),
            bag: String::new(),
            bag_real_time: true,
            depth: StreamMode { width: 848, height: 480, fps: 30 },
            colour: StreamMode { width: 1280, height: 720, fps: 30 },
            rotate: Rotation::None,
            align: AlignMode::default(),
            visual_preset: VisualPreset::Unchanged,
            emitter: Emitter::Unchanged,
            laser_power_mw: None,
            usb2_fallback: true,
            usb2_mode: StreamMode { width: 640, height: 480, fps: 15 },
            frame_timeout_ms: 1000,
            reconnect: Backoff::default(),
            imu: false,
            world_from_camera: None,
        }
    }
}

/// The stream modes the D435i delivers that this source accepts.
const DEPTH_MODES: [(u32, u32); 2] = [(848, 480), (640, 480)];
const COLOUR_MODES: [(u32, u32); 3] = [(1280, 720), (848, 480), (640, 480)];
const RATES: [u32; 4] = [6, 15, 30, 60];

impl RealsenseConfig {
    /// Checks the section: `Err((field, message))`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        let err = |field: &str, message: String| Err((field.to_owned(), message));
        for (name, mode, modes) in [
            ("depth", self.depth, &DEPTH_MODES[..]),
            ("colour", self.colour, &COLOUR_MODES[..]),
            ("usb2_mode", self.usb2_mode, &DEPTH_MODES[1..]),
        ] {
            if !modes.contains(&(mode.width, mode.height)) {
                let list: Vec<String> = modes.iter().map(|(w, h)| format!("{w}x{h}")).collect();
                return err(name, format!("must be one of {}, got {}x{}", list.join(", "), mode.width, mode.height));
            }
            if !RATES.contains(&mode.fps) {
                return err(&format!("{name}.fps"), format!("must be one of 6, 15, 30, 60, got {}", mode.fps));
            }
        }
        if self.depth.fps != self.colour.fps {
            return err(
                "colour.fps",
                format!(
                    "must equal depth.fps ({}) so that every depth frame has its colour frame, got {}",
                    self.depth.fps, self.colour.fps
                ),
            );
        }
        if let Some(p) = self.laser_power_mw
            && !(0.0..=360.0).contains(&p)
        {
            return err("laser_power_mw", format!("must be within [0, 360], got {p}"));
        }
        if !(10..=60_000).contains(&self.frame_timeout_ms) {
            return err("frame_timeout_ms", format!("must be within [10, 60000], got {}", self.frame_timeout_ms));
        }
        let b = self.reconnect;
        if b.initial_ms == 0 || b.max_ms < b.initial_ms || b.max_ms > 600_000 {
            return err(
                "reconnect.max_ms",
                format!("need 0 < initial_ms <= max_ms <= 600000, got initial_ms {} max_ms {}", b.initial_ms, b.max_ms),
            );
        }
        if let Some(pose) = &self.world_from_camera {
            let [x, y, z, w] = pose.rotation_xyzw;
            let norm = (x * x + y * y + z * z + w * w).sqrt();
            if !pose.translation_m.iter().chain(&pose.rotation_xyzw).all(|v| v.is_finite()) || (norm - 1.0).abs() > 1e-3
            {
                return err(
                    "world_from_camera.rotation_xyzw",
                    format!("must be a finite unit quaternion, got norm {norm}"),
                );
            }
        }
        Ok(())
    }

    /// Whether this plays a recording.
    pub fn is_playback(&self) -> bool {
        !self.bag.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> RealsenseConfig {
        toml::from_str(text).unwrap()
    }

    #[test]
    fn defaults_are_the_d435i_and_valid() {
        let c = RealsenseConfig::default();
        assert_eq!((c.depth.width, c.colour.width, c.depth.fps), (848, 1280, 30));
        c.validate().unwrap();
        assert_eq!(parse(""), c);
    }

    #[test]
    fn bad_values_name_their_field() {
        let e = parse("depth = { width = 1024, height = 768, fps = 30 }").validate().unwrap_err();
        assert_eq!(e.0, "depth");
        assert!(e.1.contains("848x480, 640x480") && e.1.contains("got 1024x768"), "{e:?}");
        let e = parse("colour = { width = 1280, height = 720, fps = 15 }").validate().unwrap_err();
        assert_eq!(e.0, "colour.fps");
        assert!(toml::from_str::<RealsenseConfig>("rotate = 45").unwrap_err().to_string().contains("got 45"));
        assert!(toml::from_str::<RealsenseConfig>("visual_preset = \"best\"").is_err());
        assert!(toml::from_str::<RealsenseConfig>("serial_number = \"1\"").is_err());
        let e = parse("world_from_camera = { translation_m = [0, 0, 0], rotation_xyzw = [0, 0, 0, 2] }")
            .validate()
            .unwrap_err();
        assert_eq!(e.0, "world_from_camera.rotation_xyzw");
    }

    #[test]
    fn rotation_parses_from_degrees() {
        assert_eq!(parse("rotate = 90").rotate, Rotation::Cw90);
        assert_eq!(serde_json::to_value(parse("rotate = 270")).unwrap()["rotate"], 270);
    }

    #[test]
    fn align_is_ours_unless_librealsense_is_asked_for() {
        assert_eq!(parse("").align, AlignMode::Op3dsg);
        assert_eq!(parse("align = \"librealsense\"").align, AlignMode::Librealsense);
        let e = toml::from_str::<RealsenseConfig>("align = \"gpu\"").unwrap_err().to_string();
        assert!(e.contains("op3dsg") && e.contains("librealsense"), "{e}");
    }
}
