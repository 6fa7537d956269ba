//! MCAP recordings: the channels the recorder writes (`op3dsg_runtime::record`), their schemas
//! and message encodings, and [`McapSource`], which replays the raw input of a recording as a
//! [`FrameSource`](crate::source::FrameSource) (`source.kind = "mcap"`).
//!
//! # Channels
//!
//! The `foxglove.*` channels are protobuf (`message_encoding` and schema encoding `protobuf`):
//! the messages are the `foxglove` crate's generated types (Foxglove SDK) and each file embeds
//! their descriptors as the schemas ([`schemas`]), so Foxglove and any protobuf reader decode
//! them with what the file holds. The `op3dsg.*` channels are JSON with JSON schemas written
//! here (`message_encoding = "json"`, schema encoding `jsonschema`). Recordings written before
//! the `foxglove.*` channels became protobuf hold them as JSON (base64 image data); the replay
//! reads both ([`messages`]).
//!
//! | topic | schema | what | written |
//! | --- | --- | --- | --- |
//! | `/op3dsg/graph` | `op3dsg.Graph` | the graph in [`crate::graph_json`] form | every published version |
//! | `/op3dsg/scene` | `foxglove.SceneUpdate` | a cube per node (objects blue-grey, parts orange), its label, spatial edges grey, functional edges green | every published version |
//! | `/tf` | `foxglove.FrameTransform` | `world` → `camera` | every keyframe |
//! | `/camera/calibration` | `foxglove.CameraCalibration` | pinhole intrinsics, no distortion | first frame of each file, then when they change |
//! | `/camera/colour` | `foxglove.RawImage`, or `foxglove.CompressedImage` (`png` lossless, `jpeg` lossy) with `record.colour` | `rgb8` | every frame the keyframe gate received |
//! | `/camera/depth` | `foxglove.RawImage` | `16UC1`, little-endian, sensor units | every frame the keyframe gate received |
//! | `/op3dsg/frame` | `op3dsg.Frame` | seq, stamp, depth units per metre, `world_from_camera` | every frame the keyframe gate received |
//! | `/op3dsg/health` | `op3dsg.Health` | counters, queues, stages, recorder state | every health period |
//! | `/op3dsg/detections` | `foxglove.ImageAnnotations` | a box outline per detection of a keyframe (objects blue-grey, parts orange) with label and score, over `/camera/colour` | every keyframe fused |
//! | `/op3dsg/node_points` | `foxglove.PointCloud` | the published nodes' points, world frame, fields x, y, z (float32), node_id (uint32), at most `record.node_points_per_node` per node | graph versions, at most `max_rate_hz` (1 Hz by default) |
//! | `/op3dsg/input_pose` | `op3dsg.InputPose` | a pose from the pose input (`pose.source = "ipc"`): stamp, kind, child frame, translation, rotation | every pose the keyframe gate received |
//! | `/op3dsg/llm` | `op3dsg.LlmExchange` | one call of an LLM agent (`reasoner.kind = "llm"`): agent, model, prompt messages, answer, the gate's verdict (accepted, rejected by reason), attempts, latency, error; never the key or a header | every call |
//! | `/sim/instance_ids` | `foxglove.RawImage` | `16UC1` instance ids of the synthetic renderer (simulation only) | every frame, when the source has them |
//!
//! A raw frame is written as `/camera/colour`, `/camera/depth`, any side channel of the source,
//! then `/op3dsg/frame` (which completes it), the images with the frame's stamp as their
//! `timestamp`; `/camera/calibration` comes before the first frame of each file. Frames and
//! input poses keep the order the keyframe gate received them in (one queue carries both), so
//! the replay hands each pose to the gate before the frame that followed it. Each file also holds metadata `op3dsg.profile` (`toml`: the effective profile)
//! and, when finished cleanly, `op3dsg.recorder` (messages written and dropped per channel).
//! Log times are the recorder's wall clock (Unix nanoseconds, never decreasing within a file);
//! the `timestamp` fields are sensor time.

pub mod messages;
pub mod reader;
pub mod schemas;
mod source;
#[cfg(test)]
mod tests;

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

pub use source::McapSource;

use crate::source::PlaybackMode;

/// The graph in [`crate::graph_json`] form.
pub const TOPIC_GRAPH: &str = "/op3dsg/graph";
/// `foxglove.SceneUpdate` of the graph.
pub const TOPIC_SCENE: &str = "/op3dsg/scene";
/// `foxglove.FrameTransform` world → camera per keyframe.
pub const TOPIC_TF: &str = "/tf";
/// `foxglove.CameraCalibration`.
pub const TOPIC_CALIBRATION: &str = "/camera/calibration";
/// `foxglove.RawImage` rgb8.
pub const TOPIC_COLOUR: &str = "/camera/colour";
/// `foxglove.RawImage` 16UC1.
pub const TOPIC_DEPTH: &str = "/camera/depth";
/// `op3dsg.Frame`: what a frame carries besides pixels.
pub const TOPIC_FRAME: &str = "/op3dsg/frame";
/// `op3dsg.Health`.
pub const TOPIC_HEALTH: &str = "/op3dsg/health";
/// `foxglove.ImageAnnotations`: every keyframe's detections.
pub const TOPIC_DETECTIONS: &str = "/op3dsg/detections";
/// `foxglove.PointCloud`: the published nodes' points.
pub const TOPIC_NODE_POINTS: &str = "/op3dsg/node_points";
/// `op3dsg.InputPose`: every pose the keyframe gate received from the pose input.
pub const TOPIC_INPUT_POSE: &str = "/op3dsg/input_pose";
/// `op3dsg.LlmExchange`: every call of the LLM refiner's agents.
pub const TOPIC_LLM: &str = "/op3dsg/llm";

/// Metadata record with the effective profile (key `toml`).
pub const METADATA_PROFILE: &str = "op3dsg.profile";
/// Metadata record the recorder writes when it finishes a file: per channel `<topic>.written`
/// and `<topic>.dropped` (messages the recorder had no room or no disk for), and
/// `dropped_total`; in the daemon also `pipeline_dropped.<queue>` for the pipeline's queues after
/// the keyframe gate (`keyframes`, `detections`: items their policy dropped while the file was
/// open) and [`PIPELINE_DROPPED_TOTAL`].
pub const METADATA_RECORDER: &str = "op3dsg.recorder";

/// Key of [`METADATA_RECORDER`]: what the pipeline dropped after the keyframe gate while the
/// file was open (absent in files of earlier recorders and of `bench record`).
pub const PIPELINE_DROPPED_TOTAL: &str = "pipeline_dropped_total";

/// Keys of [`METADATA_RECORDER`] that start with this and go on with a queue's name: what that
/// queue dropped while the file was open.
pub const PIPELINE_DROPPED_PREFIX: &str = "pipeline_dropped.";

/// What the pipeline dropped after the gate while the file was open, from the recorder's
/// metadata: the total and `<queue> <count>` for each queue that dropped; `None` when the file
/// does not say (an earlier recorder).
pub fn pipeline_drops(recorder: &std::collections::BTreeMap<String, String>) -> Option<(u64, Vec<String>)> {
    let total = recorder.get(PIPELINE_DROPPED_TOTAL)?.parse().ok()?;
    let queues = recorder
        .iter()
        .filter_map(|(key, n)| {
            key.strip_prefix(PIPELINE_DROPPED_PREFIX).filter(|_| n != "0").map(|queue| format!("{queue} {n}"))
        })
        .collect();
    Some((total, queues))
}

/// The channels of the recorder's metadata ([`METADATA_RECORDER`]) that dropped messages, as
/// `<topic> <count>` in topic order: what `record info` and a replay's warning name.
pub fn dropped_channels(recorder: &std::collections::BTreeMap<String, String>) -> Vec<String> {
    recorder
        .iter()
        .filter_map(|(key, n)| key.strip_suffix(".dropped").filter(|_| n != "0").map(|topic| format!("{topic} {n}")))
        .collect()
}

/// Frame id of the camera (OpenCV axes: x right, y down, z forward).
pub const CAMERA_FRAME: &str = "camera";

/// `[source.mcap]`: replay of a recording the recorder wrote.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct McapReplayConfig {
    /// An `.mcap` file, or a folder whose `*.mcap` files are played in name order (the recorder
    /// names files by their start time, so that is recording order). In a profile, a relative
    /// path is relative to the folder of the profile file that sets it.
    pub path: PathBuf,
    /// Pacing: `recorded` (by the frames' stamps), `fast`, or `stepped`, as the TUM replay.
    #[serde(default)]
    pub mode: PlaybackMode,
    /// The pipeline waits for the replay instead of dropping frames: the queues up to fusion
    /// block, whatever `[queues]` says, so the replay gives the recorded graph bit for bit
    /// ([`crate::source::FrameSource::lossless`]). `false` keeps the profile's policies (to
    /// reproduce an overload: the replay then drops as the robot may have).
    #[serde(default = "lossless_default")]
    pub lossless: bool,
}

fn lossless_default() -> bool {
    true
}

impl McapReplayConfig {
    /// Checks the fields; the error names the field prefixed with `path`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if self.path.as_os_str().is_empty() {
            return Err(format!("{path}.path: must name an .mcap file or a folder of them"));
        }
        Ok(())
    }
}
