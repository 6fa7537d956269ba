//! The MCAP recorder: the field log and the raw input for bit-exact replay, written on its own
//! thread (`op3dsg-record`) from bounded queues that the pipeline feeds with `try_send` — the
//! hot path never waits on the disk; what does not fit is dropped and counted.
//!
//! ```text
//! keyframe gate ──(frame buffers from a pool made at start-up)──► [frames]  ─┐
//!   every frame it receives: colour, depth, meta, side channels             ├─► op3dsg-record ──► <dir>/op3dsg_<UTC start>.mcap
//!   every keyframe: world → camera ──────────────────────────────► [events] ─┤      zstd | lz4 chunks, rotation by size and age
//! publisher: every graph version (moved, not copied), health ────► [events] ─┘
//! ```
//!
//! The channels, their schemas and the order of a frame's messages are documented in
//! [`op3dsg_drivers::mcap`]; `[record]` ([`RecordConfig`]) switches each channel and limits its
//! rate. Each file starts with the effective profile as metadata (`op3dsg.profile`), rotates by
//! size (`max_file_mib`) and age (`max_file_s`), and is finished (summary, statistics, and the
//! metadata `op3dsg.recorder` with the drop counts) on rotation and on shutdown: when every
//! producer has gone (SIGTERM → shutdown ladder) the recorder drains its queues, finishes the
//! file and ends. Every `flush_interval_ms` the current chunk is closed and flushed, so after a
//! kill -9 the file reads back (with any MCAP reader that tolerates a missing summary) up to
//! the last flush.
//!
//! **A failing disk is not a failing robot.** When a write fails (disk full, quota, I/O error),
//! the recorder logs one warning naming the file and the error, gives the file up (what was
//! flushed before stays readable), sets its health state to `failed` and takes no more input;
//! producers see the state and stop copying frames. The pipeline goes on publishing.

mod annotations;
mod config;
pub mod scene;
mod sender;
mod thread;
mod writer;

use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::{Health, RecorderHealth};

pub use config::{ChannelConfig, ColourEncoding, RecordChannels, RecordCompression, RecordConfig};
pub use sender::RecordSender;
pub use thread::{RecordStartError, RecordThread, Recorder};
pub(crate) use writer::health_json;

use crate::graph::SceneGraph;

/// A side channel of the source recorded with each frame (the simulator's instance ids): a
/// 16-bit image the size of the frame. Registered by a source backend
/// ([`crate::backend::SourceBackend::side_channel_taps`]); the runtime records it without
/// knowing what it holds.
pub trait SideChannelTap: Send {
    /// The topic (`/sim/instance_ids`).
    fn topic(&self) -> &str;
    /// Copies the frame's side-channel image into `out` (`width * height` values); `false`
    /// when the source has none for this frame.
    fn copy(&mut self, frame: &Frame, out: &mut [u16]) -> bool;
}

/// Recorder states, as [`RecorderHealth::state`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum RecorderState {
    /// Not configured.
    Off = 0,
    /// Writing.
    Recording = 1,
    /// A write failed; recording stopped.
    Failed = 2,
    /// Finished its last file.
    Finished = 3,
}

/// The channels whose drops are counted apart ([`RecorderStats::dropped_by_channel`]); side
/// channels share one count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum Channel {
    Graph,
    Scene,
    Transforms,
    Health,
    Colour,
    Depth,
    Frame,
    SideChannels,
    InputPoses,
    Detections,
    NodePoints,
    LlmExchanges,
}

/// Number of [`Channel`]s.
pub(crate) const CHANNEL_COUNT: usize = 12;

impl Channel {
    const ALL: [Channel; CHANNEL_COUNT] = [
        Channel::Graph,
        Channel::Scene,
        Channel::Transforms,
        Channel::Health,
        Channel::Colour,
        Channel::Depth,
        Channel::Frame,
        Channel::SideChannels,
        Channel::InputPoses,
        Channel::Detections,
        Channel::NodePoints,
        Channel::LlmExchanges,
    ];

    /// The channel's topic (side channels: their own topics, [`None`] here).
    pub(crate) fn topic(self) -> Option<&'static str> {
        use op3dsg_drivers::mcap as t;
        Some(match self {
            Channel::Graph => t::TOPIC_GRAPH,
            Channel::Scene => t::TOPIC_SCENE,
            Channel::Transforms => t::TOPIC_TF,
            Channel::Health => t::TOPIC_HEALTH,
            Channel::Colour => t::TOPIC_COLOUR,
            Channel::Depth => t::TOPIC_DEPTH,
            Channel::Frame => t::TOPIC_FRAME,
            Channel::SideChannels => return None,
            Channel::InputPoses => t::TOPIC_INPUT_POSE,
            Channel::Detections => t::TOPIC_DETECTIONS,
            Channel::NodePoints => t::TOPIC_NODE_POINTS,
            Channel::LlmExchanges => t::TOPIC_LLM,
        })
    }
}

/// The recorder's counters, shared with the health reporter.
#[derive(Debug, Default)]
pub struct RecorderStats {
    state: AtomicU8,
    files: AtomicU64,
    written: AtomicU64,
    dropped: AtomicU64,
    dropped_by: [AtomicU64; CHANNEL_COUNT],
    bytes: AtomicU64,
    cpu_ns: AtomicU64,
}

impl RecorderStats {
    /// The state now.
    pub fn state(&self) -> RecorderState {
        match self.state.load(Ordering::Relaxed) {
            1 => RecorderState::Recording,
            2 => RecorderState::Failed,
            3 => RecorderState::Finished,
            _ => RecorderState::Off,
        }
    }

    fn set_state(&self, state: RecorderState) {
        self.state.store(state as u8, Ordering::Relaxed);
    }

    /// Counts `n` messages of `channel` dropped; returns the total dropped so far.
    fn count_drop(&self, channel: Channel, n: u64) -> u64 {
        self.dropped_by[channel as usize].fetch_add(n, Ordering::Relaxed);
        self.dropped.fetch_add(n, Ordering::Relaxed) + n
    }

    /// Messages dropped so far per channel, in [`Channel`] order.
    pub(crate) fn dropped_by_channel(&self) -> [(Channel, u64); CHANNEL_COUNT] {
        Channel::ALL.map(|c| (c, self.dropped_by[c as usize].load(Ordering::Relaxed)))
    }

    /// For the health record.
    pub fn health(&self) -> RecorderHealth {
        RecorderHealth {
            state: self.state.load(Ordering::Relaxed),
            reserved: [0; 3],
            files: self.files.load(Ordering::Relaxed).min(u64::from(u32::MAX)) as u32,
            messages_written: self.written.load(Ordering::Relaxed),
            messages_dropped: self.dropped.load(Ordering::Relaxed),
            bytes_written: self.bytes.load(Ordering::Relaxed),
            cpu_ns: self.cpu_ns.load(Ordering::Relaxed),
        }
    }
}

/// A raw frame copied for the recorder, in a buffer of the recorder's pool.
pub(crate) struct RawFrame {
    log_time_ns: u64,
    seq: u64,
    stamp_ns: u64,
    intrinsics: Intrinsics,
    depth_units_per_m: f32,
    world_from_camera: Option<Isometry>,
    colour: Option<Vec<u8>>,
    depth: Option<Vec<u16>>,
    has_colour: bool,
    has_depth: bool,
    has_meta: bool,
    /// One buffer per side-channel tap, and whether this frame filled it.
    sides: Vec<(Vec<u16>, bool)>,
}

/// What the keyframe gate hands the recorder, in the order it received it: frames and the poses
/// of the pose input between them (one queue keeps the order, so a replay can restore it).
pub(crate) enum RawInput {
    Frame(Box<RawFrame>),
    Pose { log_time_ns: u64, pose: op3dsg_drivers::mcap::messages::InputPose },
}

/// What the recorder writes besides raw frames.
pub(crate) enum Event {
    Graph { log_time_ns: u64, graph: SceneGraph, json: bool, scene: bool },
    Keyframe { log_time_ns: u64, stamp_ns: u64, world_from_camera: Isometry },
    Health { log_time_ns: u64, health: Box<Health> },
    Detections { log_time_ns: u64, stamp_ns: u64, boxes: Vec<annotations::DetectionBox> },
    NodePoints { log_time_ns: u64, stamp_ns: u64, points: Vec<crate::graph::NodePoint> },
    LlmExchange { log_time_ns: u64, exchange: Box<op3dsg_drivers::mcap::messages::LlmExchange> },
}

/// Wall clock, Unix nanoseconds.
pub(crate) fn now_ns() -> u64 {
    crate::world::clock::wall_clock_ns()
}
