//! Replay of recorded RGB-D sequences in the TUM RGB-D layout, with their poses.
//!
//! # The layout
//!
//! ```text
//! <path>/rgb.txt           "timestamp filename" per line: colour images (8-bit PNG or JPEG)
//! <path>/depth.txt         "timestamp filename" per line: depth images (16-bit grey PNG)
//! <path>/groundtruth.txt   "timestamp tx ty tz qx qy qz qw" per line (optional)
//! <path>/camera.json       {"width", "height", "fx", "fy", "cx", "cy", "depth_scale_per_m", "rate_hz"}
//! <path>/rgb/, depth/      the images the index files name (paths relative to <path>)
//! ```
//!
//! Lines starting with `#` and blank lines are ignored. Timestamps are decimal seconds (any
//! origin: Unix time in TUM, 0 in ICL-NUIM) and are parsed exactly to nanoseconds.
//! `groundtruth.txt` holds `world_from_camera` with OpenCV camera axes (x right, y down,
//! z forward), translation in metres, quaternion `x y z w`: the pose maps points of the camera
//! frame into the world, as [`Frame::world_from_camera`](crate::frame::Frame) expects.
//!
//! # What a frame is
//!
//! - **Association.** Each colour image is paired with the depth image nearest in time, one to
//!   one, greedily by smallest difference (the TUM `associate.py` rule), when they are at most
//!   [`ReplayConfig::association_tolerance_ms`] apart (default 20 ms). Colour images without a
//!   partner are not frames (TUM streams are not synchronised; this is normal, not bad data).
//!   The frame's stamp is the colour image's.
//! - **Pose.** The ground truth at the frame's stamp: an exact stamp, else interpolated
//!   (linear translation, slerp rotation) between the two ground-truth poses around it when they
//!   are at most [`ReplayConfig::max_pose_gap_ms`] apart (default 100 ms), else the nearest pose
//!   within the association tolerance. A frame inside the ground truth's time span that has none
//!   of these is **bad data** (a pose gap). A frame before the first or after the last
//!   ground-truth pose carries no pose (`world_from_camera = None`), which the pipeline drops and
//!   counts like any frame without a pose. Without `groundtruth.txt` no frame carries a pose.
//! - **Images.** Colour is decoded straight into [`Frame::rgb`](crate::frame::Frame) (RGB8; RGBA
//!   and grey are converted), depth into [`Frame::depth`](crate::frame::Frame) (u16) with
//!   `depth_units_per_m` from the profile or `camera.json`. Both must match the intrinsics'
//!   size.
//!   Files are read into a reused buffer and decoded in place; only the codecs' small internal
//!   state is allocated per image.
//! - **Sequence numbers** count delivered frames from 0, one by one, across loops; stamps keep
//!   increasing across loops (each pass is shifted by the recording's length plus one median
//!   frame interval). The same recording and profile give the same frames, seqs and stamps.
//!
//! # Playback ([`PlaybackMode`])
//!
//! - `recorded`: each frame is delivered when its stamp is due, counting from the first
//!   delivered frame (late frames go at once; the source never drops). The source blocks at most
//!   [`MAX_BLOCK`] per call and returns `Pending` when a frame is further away, so a stop is
//!   never held up by a long pause in the recording.
//! - `fast`: as fast as the caller asks (the daemon's capture loop then paces by
//!   `source.rate_hz`, 0 = as fast as the pipeline takes frames, like the synthetic source).
//! - `stepped`: a frame only after [`StepControl::step`](crate::source::StepControl::step) on the
//!   handle from [`FrameSource::step_control`](crate::source::FrameSource::step_control); without
//!   credit `next_frame` waits up to [`MAX_BLOCK`] and returns `Pending`.
//! - `loop = true` starts over after the last frame; otherwise the source ends with
//!   `EndOfStream`.
//!
//! # Bad data ([`OnBadFrame`])
//!
//! Every problem is a [`SourceError`](crate::source::SourceError) naming the file and line or
//! frame: a malformed index line (`SourceError::Line { path: rgb.txt, line, .. }`), a missing,
//! corrupt or wrongly sized image (`SourceError::File { path: the image, .. }` whose reason names
//! the index line and frame), a pose gap (`SourceError::Line { path: groundtruth.txt, line, .. }`
//! with the frame). Index files are read when the source opens, images when their frame is due.
//!
//! - `stop` (default): a malformed index line fails [`ReplaySource::new`]; a bad frame ends the
//!   stream with its error after the frames before it were delivered
//!   ([`FrameSource::stops_on_error`](crate::source::FrameSource::stops_on_error)).
//! - `skip`: the line or frame is left out, logged at warn (the first ten, then at powers of two)
//!   and counted in [`FrameSource::bad_data_skipped`](crate::source::FrameSource::bad_data_skipped),
//!   which the daemon shows as capture errors in `health`. A pass that delivers no frame at all
//!   ends the stream with an error instead of looping forever.
//!
//! ```no_run
//! use std::path::PathBuf;
//! use op3dsg_drivers::frame::Frame;
//! use op3dsg_drivers::replay::{PlaybackMode, ReplayConfig, ReplaySource};
//! use op3dsg_drivers::source::{FrameSource, SourceStatus};
//!
//! let config = ReplayConfig { mode: PlaybackMode::Fast, ..ReplayConfig::new(PathBuf::from("data/icl_livingroom1")) };
//! let mut source = ReplaySource::new(&config)?;
//! let mut frame = Frame::new(source.intrinsics());
//! while source.next_frame(&mut frame)? == SourceStatus::Frame {
//!     let world_from_camera = frame.world_from_camera.expect("ICL frames all have poses");
//!     println!("frame {} at {} ns: camera at {:?}", frame.seq, frame.stamp_ns, world_from_camera.translation);
//! }
//! # Ok::<(), op3dsg_drivers::source::SourceError>(())
//! ```

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::frame::{Intrinsics, check_intrinsics};

mod decode;
mod index;
mod source;
#[cfg(test)]
mod tests;

pub use index::{CameraFile, parse_stamp_ns};
pub use source::ReplaySource;

// The pacing shared with the MCAP replay, defined with the frame-source interface.
pub use crate::source::{MAX_BLOCK, PlaybackMode};

/// What a bad line or frame does.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OnBadFrame {
    /// End with the error.
    #[default]
    Stop,
    /// Warn, count, and go on with the next line or frame.
    Skip,
}

/// `[source.replay]`: a recording in the TUM RGB-D layout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReplayConfig {
    /// Folder of the recording. In a profile, a relative path is relative to the folder of the
    /// profile file that sets it (relative to the working directory with `--set`).
    pub path: PathBuf,
    /// Pacing.
    #[serde(default)]
    pub mode: PlaybackMode,
    /// Start over after the last frame.
    #[serde(default, rename = "loop")]
    pub looping: bool,
    /// Largest time difference between a colour and a depth image of one frame, and between a
    /// frame and a single nearest ground-truth pose, milliseconds.
    #[serde(default = "default_association_tolerance_ms")]
    pub association_tolerance_ms: f64,
    /// Largest gap between the two ground-truth poses a frame's pose is interpolated from,
    /// milliseconds; a wider gap around a frame is bad data.
    #[serde(default = "default_max_pose_gap_ms")]
    pub max_pose_gap_ms: f64,
    /// Depth units per metre (1000 = millimetres; TUM's own recordings use 5000). Overrides
    /// `camera.json`'s `depth_scale_per_m`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub depth_units_per_m: Option<f32>,
    /// Pinhole intrinsics of colour (depth is aligned to it). Overrides `camera.json`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub intrinsics: Option<Intrinsics>,
    /// What a malformed line or a bad frame does.
    #[serde(default)]
    pub on_bad_frame: OnBadFrame,
}

fn default_association_tolerance_ms() -> f64 {
    20.0
}

fn default_max_pose_gap_ms() -> f64 {
    100.0
}

impl ReplayConfig {
    /// The defaults for the recording at `path`: recorded rate, no loop, 20 ms association,
    /// 100 ms pose gaps, stop on bad data, intrinsics and depth scale from `camera.json`.
    pub fn new(path: PathBuf) -> Self {
        Self {
            path,
            mode: PlaybackMode::default(),
            looping: false,
            association_tolerance_ms: default_association_tolerance_ms(),
            max_pose_gap_ms: default_max_pose_gap_ms(),
            depth_units_per_m: None,
            intrinsics: None,
            on_bad_frame: OnBadFrame::default(),
        }
    }

    /// Checks ranges; the error names the offending field prefixed with `path`
    /// (`source.replay.max_pose_gap_ms: must be within (0, 10000], got 0`).
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let field = |name: &str| if path.is_empty() { name.to_owned() } else { format!("{path}.{name}") };
        if self.path.as_os_str().is_empty() {
            return Err(format!("{}: must name the recording's folder", field("path")));
        }
        let tol = self.association_tolerance_ms;
        if !(tol > 0.0 && tol <= 1000.0) {
            return Err(format!("{}: must be within (0, 1000], got {tol}", field("association_tolerance_ms")));
        }
        let gap = self.max_pose_gap_ms;
        if !(gap > 0.0 && gap <= 10_000.0) {
            return Err(format!("{}: must be within (0, 10000], got {gap}", field("max_pose_gap_ms")));
        }
        if let Some(units) = self.depth_units_per_m
            && !(units.is_finite() && units > 0.0)
        {
            return Err(format!("{}: must be > 0, got {units}", field("depth_units_per_m")));
        }
        if let Some(k) = &self.intrinsics {
            check_intrinsics(k).map_err(|e| format!("{}{e}", field("intrinsics")))?;
        }
        Ok(())
    }
}
