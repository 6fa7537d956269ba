//! `[record]`: what the recorder writes, where, and how files rotate.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

/// Chunk compression.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum RecordCompression {
    /// zstd (default level): smaller files, more CPU.
    #[default]
    Zstd,
    /// lz4: less CPU, larger files.
    Lz4,
    /// Uncompressed chunks.
    None,
}

/// How `/camera/colour` is written.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ColourEncoding {
    /// `foxglove.RawImage` rgb8: lossless, largest, no encoding CPU.
    #[default]
    Raw,
    /// `foxglove.CompressedImage` jpeg at `record.jpeg_quality`: smallest, **lossy** (a replay's
    /// detections and graph are close to, not identical with, the recorded run's).
    Jpeg,
    /// `foxglove.CompressedImage` png: lossless (replays bit for bit), more CPU than jpeg.
    Png,
}

impl ColourEncoding {
    /// The profile's name.
    pub fn name(self) -> &'static str {
        match self {
            ColourEncoding::Raw => "raw",
            ColourEncoding::Jpeg => "jpeg",
            ColourEncoding::Png => "png",
        }
    }
}

/// One channel's switch and rate limit.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ChannelConfig {
    /// Whether the channel is written.
    pub enabled: bool,
    /// At most this many messages per second (wall clock; the rest are skipped, not counted as
    /// drops); 0 = every message.
    #[serde(default)]
    pub max_rate_hz: f64,
}

impl ChannelConfig {
    const fn on() -> Self {
        Self { enabled: true, max_rate_hz: 0.0 }
    }

    const fn once_a_second() -> Self {
        Self { enabled: true, max_rate_hz: 1.0 }
    }
}

impl Default for ChannelConfig {
    fn default() -> Self {
        Self::on()
    }
}

/// `[record.channels]`: one entry per channel (topics in `op3dsg_drivers::mcap`).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordChannels {
    /// `/op3dsg/graph`: the graph JSON of every published version.
    #[serde(default)]
    pub graph: ChannelConfig,
    /// `/op3dsg/scene`: `foxglove.SceneUpdate` of every published version.
    #[serde(default)]
    pub scene: ChannelConfig,
    /// `/tf`: `foxglove.FrameTransform` world → camera per keyframe.
    #[serde(default)]
    pub transforms: ChannelConfig,
    /// `/camera/calibration`: `foxglove.CameraCalibration` (first frame of a file and changes;
    /// the rate limit does not apply). Replay needs it.
    #[serde(default)]
    pub calibration: ChannelConfig,
    /// `/op3dsg/health`: every health record.
    #[serde(default)]
    pub health: ChannelConfig,
    /// `/camera/colour`: `foxglove.RawImage` rgb8 (or `foxglove.CompressedImage`, as
    /// `record.colour` says) of every frame the keyframe gate received.
    #[serde(default)]
    pub colour: ChannelConfig,
    /// `/camera/depth`: `foxglove.RawImage` 16UC1 of every such frame.
    #[serde(default)]
    pub depth: ChannelConfig,
    /// `/op3dsg/frame`: seq, stamp, depth scale and pose of every such frame. Replay needs
    /// colour, depth and frame of every frame (no rate limit on them).
    #[serde(default)]
    pub frame: ChannelConfig,
    /// Side channels the source offers (the simulator's `/sim/instance_ids`), with the frames.
    #[serde(default)]
    pub side_channels: ChannelConfig,
    /// `/op3dsg/input_pose`: every pose the keyframe gate received from the pose input
    /// (`pose.source = "ipc"`). Replay of such a recording needs it (no rate limit then).
    #[serde(default)]
    pub input_poses: ChannelConfig,
    /// `/op3dsg/detections`: `foxglove.ImageAnnotations` of every keyframe's detections (box,
    /// label, score), drawn over `/camera/colour`.
    #[serde(default)]
    pub detections: ChannelConfig,
    /// `/op3dsg/node_points`: `foxglove.PointCloud` of the published nodes' points (at most
    /// `node_points_per_node` each), on graph versions at most `max_rate_hz` (default 1).
    #[serde(default = "ChannelConfig::once_a_second")]
    pub node_points: ChannelConfig,
    /// `/op3dsg/llm`: `op3dsg.LlmExchange` of every call of the LLM refiner's agents
    /// (`reasoner.kind = "llm"`): prompt, answer, the gate's verdict, latency, error; never the
    /// API key or a header.
    #[serde(default)]
    pub llm: ChannelConfig,
}

impl Default for RecordChannels {
    fn default() -> Self {
        let on = ChannelConfig::on();
        Self {
            graph: on,
            scene: on,
            transforms: on,
            calibration: on,
            health: on,
            colour: on,
            depth: on,
            frame: on,
            side_channels: on,
            input_poses: on,
            detections: on,
            node_points: ChannelConfig::once_a_second(),
            llm: on,
        }
    }
}

impl RecordChannels {
    /// `(name, config)` of every channel, in profile order.
    pub fn entries(&self) -> [(&'static str, ChannelConfig); 13] {
        [
            ("graph", self.graph),
            ("scene", self.scene),
            ("transforms", self.transforms),
            ("calibration", self.calibration),
            ("health", self.health),
            ("colour", self.colour),
            ("depth", self.depth),
            ("frame", self.frame),
            ("side_channels", self.side_channels),
            ("input_poses", self.input_poses),
            ("detections", self.detections),
            ("node_points", self.node_points),
            ("llm", self.llm),
        ]
    }
}

/// `[record]`: the MCAP recorder (`crate::record`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecordConfig {
    /// Whether the daemon records (`op3dsgd --record DIR` sets it and `dir`).
    pub enabled: bool,
    /// Folder for the files (created if missing). Relative: to the profile file that sets it
    /// (to the working directory with `--set` or `--record`). Empty (the default): under systemd
    /// `$LOGS_DIRECTORY` (`LogsDirectory=op3dsg`: /var/log/op3dsg), else `recordings` in the
    /// working directory ([`Self::resolve_dir`]).
    pub dir: PathBuf,
    /// Chunk compression: `zstd`, `lz4` or `none`.
    pub compression: RecordCompression,
    /// `/camera/colour` as `raw` (`foxglove.RawImage` rgb8), `jpeg` or `png`
    /// (`foxglove.CompressedImage`). `jpeg` is lossy: its replay is not bit-exact.
    #[serde(default)]
    pub colour: ColourEncoding,
    /// JPEG quality, 1..=100, with `colour = "jpeg"`.
    #[serde(default = "default_jpeg_quality")]
    pub jpeg_quality: u8,
    /// Uncompressed chunk size, KiB: a chunk is compressed and written when it reaches this.
    pub chunk_size_kib: u64,
    /// Finish the current chunk and flush the file at least this often, milliseconds: after a
    /// kill -9 or a power cut, at most this much is lost.
    pub flush_interval_ms: u64,
    /// Start a new file when the current one reaches this size, MiB.
    pub max_file_mib: u64,
    /// Start a new file when the current one is this old, seconds.
    pub max_file_s: f64,
    /// Raw frames waiting for the recorder; their buffers are allocated at start-up. A frame
    /// that finds none free is dropped and counted.
    pub frame_queue: usize,
    /// Graph versions, keyframe poses and health records waiting; when full, dropped and counted.
    pub event_queue: usize,
    /// `/op3dsg/node_points` keeps at most this many points of each node (evenly spaced through
    /// its cloud).
    pub node_points_per_node: usize,
    /// Per-channel switches and rate limits.
    #[serde(default)]
    pub channels: RecordChannels,
}

impl Default for RecordConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            dir: PathBuf::new(),
            compression: RecordCompression::Zstd,
            colour: ColourEncoding::Raw,
            jpeg_quality: default_jpeg_quality(),
            chunk_size_kib: 4096,
            flush_interval_ms: 1000,
            max_file_mib: 2048,
            max_file_s: 600.0,
            frame_queue: 4,
            event_queue: 64,
            node_points_per_node: 256,
            channels: RecordChannels::default(),
        }
    }
}

fn default_jpeg_quality() -> u8 {
    90
}

/// Where recordings go when `record.dir` is empty and systemd gave no logs directory.
pub const DEFAULT_RECORD_DIR: &str = "recordings";

impl RecordConfig {
    /// The folder recordings go to (see [`Self::dir`]).
    pub fn resolve_dir(&self) -> PathBuf {
        self.resolve_dir_with(std::env::var_os("LOGS_DIRECTORY").map(PathBuf::from))
    }

    /// [`Self::resolve_dir`] with `$LOGS_DIRECTORY` given (systemd may list several,
    /// `:`-separated: the first is ours).
    pub fn resolve_dir_with(&self, logs_directory: Option<PathBuf>) -> PathBuf {
        if !self.dir.as_os_str().is_empty() {
            return self.dir.clone();
        }
        let first = logs_directory.map(|d| d.to_string_lossy().split(':').next().unwrap_or("").to_owned());
        match first {
            Some(first) if !first.is_empty() => PathBuf::from(first),
            _ => PathBuf::from(DEFAULT_RECORD_DIR),
        }
    }

    /// Checks ranges; errors name the field prefixed with `path` (`record.max_file_mib: ...`).
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(16..=1 << 20).contains(&self.chunk_size_kib) {
            return Err(format!("{path}.chunk_size_kib: must be within [16, 1048576], got {}", self.chunk_size_kib));
        }
        if !(10..=600_000).contains(&self.flush_interval_ms) {
            return Err(format!(
                "{path}.flush_interval_ms: must be within [10, 600000], got {}",
                self.flush_interval_ms
            ));
        }
        if !(1..=1 << 24).contains(&self.max_file_mib) {
            return Err(format!("{path}.max_file_mib: must be within [1, 16777216], got {}", self.max_file_mib));
        }
        if !(self.max_file_s >= 1.0 && self.max_file_s <= 86_400.0 * 7.0) {
            return Err(format!("{path}.max_file_s: must be within [1, 604800], got {}", self.max_file_s));
        }
        if !(1..=100).contains(&self.jpeg_quality) {
            return Err(format!("{path}.jpeg_quality: must be within [1, 100], got {}", self.jpeg_quality));
        }
        if !(1..=256).contains(&self.frame_queue) {
            return Err(format!("{path}.frame_queue: must be within [1, 256], got {}", self.frame_queue));
        }
        if !(1..=65_536).contains(&self.event_queue) {
            return Err(format!("{path}.event_queue: must be within [1, 65536], got {}", self.event_queue));
        }
        if !(1..=1 << 20).contains(&self.node_points_per_node) {
            return Err(format!(
                "{path}.node_points_per_node: must be within [1, 1048576], got {}",
                self.node_points_per_node
            ));
        }
        for (name, channel) in self.channels.entries() {
            let rate = channel.max_rate_hz;
            if !(rate.is_finite() && (0.0..=1000.0).contains(&rate)) {
                return Err(format!(
                    "{path}.channels.{name}.max_rate_hz: must be within [0, 1000] (0 = every message), got {rate}"
                ));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn validation_names_the_key() {
        let mut config = RecordConfig::default();
        assert_eq!(config.validate("record"), Ok(()));
        config.channels.colour.max_rate_hz = -1.0;
        assert_eq!(
            config.validate("record").unwrap_err(),
            "record.channels.colour.max_rate_hz: must be within [0, 1000] (0 = every message), got -1"
        );
        let config = RecordConfig { max_file_mib: 0, ..RecordConfig::default() };
        assert!(config.validate("record").unwrap_err().starts_with("record.max_file_mib: "));
        let config = RecordConfig { enabled: true, dir: PathBuf::new(), ..RecordConfig::default() };
        assert_eq!(config.validate("record"), Ok(()), "an empty dir has a meaning");
    }

    #[test]
    fn an_empty_dir_is_the_logs_directory_under_systemd() {
        let unset = RecordConfig::default();
        assert_eq!(unset.resolve_dir_with(None), PathBuf::from("recordings"), "by hand: the working directory's");
        assert_eq!(unset.resolve_dir_with(Some("/var/log/op3dsg".into())), PathBuf::from("/var/log/op3dsg"));
        assert_eq!(
            unset.resolve_dir_with(Some("/var/log/op3dsg:/var/log/other".into())),
            PathBuf::from("/var/log/op3dsg")
        );
        assert_eq!(unset.resolve_dir_with(Some("".into())), PathBuf::from("recordings"));
        let set = RecordConfig { dir: PathBuf::from("/data/runs"), ..RecordConfig::default() };
        assert_eq!(set.resolve_dir_with(Some("/var/log/op3dsg".into())), PathBuf::from("/data/runs"));
    }
}
