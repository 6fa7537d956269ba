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
mod writer;

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicU8, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, TrySendError};
use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::{Health, RecorderHealth};
use tracing::warn;

pub use config::{ChannelConfig, ColourEncoding, RecordChannels, RecordCompression, RecordConfig};

use crate::config::UpAxis;
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
    NodePoints { log_time_ns: u64, stamp_ns: u64, points: Vec<crate::fusion::NodePoint> },
    LlmExchange { log_time_ns: u64, exchange: Box<op3dsg_drivers::mcap::messages::LlmExchange> },
}

/// Wall clock, Unix nanoseconds.
pub(crate) fn now_ns() -> u64 {
    crate::ipc::wall_clock_ns()
}

/// A per-producer rate limit.
#[derive(Debug, Clone)]
struct Limiter {
    enabled: bool,
    period: Option<Duration>,
    next: Option<Instant>,
}

impl Limiter {
    fn new(config: ChannelConfig) -> Self {
        Self {
            enabled: config.enabled,
            period: (config.max_rate_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / config.max_rate_hz)),
            next: None,
        }
    }

    fn due(&mut self, now: Instant) -> bool {
        if !self.enabled {
            return false;
        }
        let Some(period) = self.period else { return true };
        if self.next.is_some_and(|next| now < next) {
            return false;
        }
        self.next = Some(self.next.map_or(now, |next| next.max(now - period)) + period);
        true
    }
}

/// The producers' side of the recorder; each producing thread owns a clone (its rate limits are
/// its own). Every call returns at once.
#[derive(Clone)]
pub struct RecordSender {
    frames_tx: Sender<RawInput>,
    events_tx: Sender<Event>,
    pool_rx: Receiver<Box<RawFrame>>,
    pool_tx: Sender<Box<RawFrame>>,
    stats: Arc<RecorderStats>,
    graph: Limiter,
    scene: Limiter,
    transforms: Limiter,
    health: Limiter,
    colour: Limiter,
    depth: Limiter,
    frame: Limiter,
    sides: Limiter,
    poses: Limiter,
    detections: Limiter,
    node_points: Limiter,
    llm: Limiter,
    node_points_per_node: usize,
}

impl std::fmt::Debug for RecordSender {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecordSender").field("state", &self.stats.state()).finish_non_exhaustive()
    }
}

impl RecordSender {
    fn accepting(&self) -> bool {
        self.stats.state() == RecorderState::Recording
    }

    fn drop_counted(&self, what: &str, drops: &[(Channel, u64)]) {
        let mut dropped = 0;
        for &(channel, n) in drops.iter().filter(|(_, n)| *n > 0) {
            dropped = self.stats.count_drop(channel, n);
        }
        if dropped > 0 && (dropped.is_power_of_two() || dropped < 4) {
            warn!(dropped, what, "recorder queue full (the disk is slower than the input); message dropped");
        }
    }

    /// Offers a frame the keyframe gate received (colour, depth, meta and side channels, as
    /// enabled and due); `taps` are the source's side channels. Copies into a pooled buffer, or
    /// drops and counts when none is free.
    pub fn offer_frame(&mut self, frame: &Frame, taps: &mut [Box<dyn SideChannelTap>]) {
        if !self.accepting() {
            return;
        }
        let now = Instant::now();
        let colour = self.colour.due(now);
        let depth = self.depth.due(now);
        let meta = self.frame.due(now);
        let sides = !taps.is_empty() && self.sides.due(now);
        if !(colour || depth || meta || sides) {
            return;
        }
        let n = |due: bool| u64::from(due);
        let drops = [
            (Channel::Colour, n(colour)),
            (Channel::Depth, n(depth)),
            (Channel::Frame, n(meta)),
            (Channel::SideChannels, if sides { taps.len() as u64 } else { 0 }),
        ];
        let Ok(mut raw) = self.pool_rx.try_recv() else {
            self.drop_counted("frame", &drops);
            return;
        };
        raw.log_time_ns = now_ns();
        raw.seq = frame.seq;
        raw.stamp_ns = frame.stamp_ns;
        raw.intrinsics = frame.intrinsics;
        raw.depth_units_per_m = frame.depth_units_per_m;
        raw.world_from_camera = frame.world_from_camera;
        raw.has_meta = meta;
        raw.has_colour = colour;
        if colour {
            let buf = raw.colour.get_or_insert_with(Vec::new);
            buf.clear();
            buf.extend_from_slice(&frame.rgb);
        }
        raw.has_depth = depth;
        if depth {
            let buf = raw.depth.get_or_insert_with(Vec::new);
            buf.clear();
            buf.extend_from_slice(&frame.depth);
        }
        raw.sides.resize_with(taps.len(), || (Vec::new(), false));
        for ((buf, filled), tap) in raw.sides.iter_mut().zip(taps.iter_mut()) {
            *filled = false;
            if sides {
                buf.resize(frame.depth.len(), 0);
                *filled = tap.copy(frame, buf);
            }
        }
        if let Err(e) = self.frames_tx.try_send(RawInput::Frame(raw)) {
            if let TrySendError::Full(RawInput::Frame(raw)) | TrySendError::Disconnected(RawInput::Frame(raw)) = e {
                // Back to the pool (it has room: the buffer came from it).
                let _ = self.pool_tx.try_send(raw);
            }
            self.drop_counted("frame", &drops);
        }
    }

    /// Offers a pose the keyframe gate received from the pose input (`/op3dsg/input_pose`), in
    /// order with the frames.
    pub fn offer_input_pose(&mut self, pose: &op3dsg_ipc_types::PoseStamped) {
        if !self.accepting() || !self.poses.due(Instant::now()) {
            return;
        }
        use op3dsg_drivers::mcap::messages::{InputPose, InputPoseKind};
        let kind = match op3dsg_ipc_types::PoseKind::from_u8(pose.kind) {
            Some(op3dsg_ipc_types::PoseKind::WorldFromBase) => InputPoseKind::WorldFromBase,
            // The gate refuses an unknown kind; the replay would refuse it as camera too.
            _ => InputPoseKind::WorldFromCamera,
        };
        let pose = InputPose {
            stamp_ns: pose.stamp_ns,
            kind,
            frame_id: op3dsg_ipc_types::fixed_str(&pose.frame_id).to_owned(),
            translation_m: pose.translation_m,
            rotation_xyzw: pose.rotation_xyzw,
        };
        if self.frames_tx.try_send(RawInput::Pose { log_time_ns: now_ns(), pose }).is_err() {
            self.drop_counted("input pose", &[(Channel::InputPoses, 1)]);
        }
    }

    /// Offers a keyframe's pose (`/tf`).
    pub fn offer_keyframe(&mut self, stamp_ns: u64, world_from_camera: &Isometry) {
        if !self.accepting() || !self.transforms.due(Instant::now()) {
            return;
        }
        let event = Event::Keyframe { log_time_ns: now_ns(), stamp_ns, world_from_camera: *world_from_camera };
        if self.events_tx.try_send(event).is_err() {
            self.drop_counted("keyframe", &[(Channel::Transforms, 1)]);
        }
    }

    /// Offers a published graph version (moved: the publisher has sent it already).
    pub fn offer_graph(&mut self, graph: SceneGraph) {
        if !self.accepting() {
            return;
        }
        let now = Instant::now();
        let json = self.graph.due(now);
        let scene = self.scene.due(now);
        if !(json || scene) {
            return;
        }
        if self.events_tx.try_send(Event::Graph { log_time_ns: now_ns(), graph, json, scene }).is_err() {
            self.drop_counted("graph", &[(Channel::Graph, u64::from(json)), (Channel::Scene, u64::from(scene))]);
        }
    }

    /// Offers a keyframe's detections (`/op3dsg/detections`), fused at `stamp_ns`.
    pub fn offer_detections(&mut self, stamp_ns: u64, detections: &[crate::perception::Detection]) {
        if !self.accepting() || !self.detections.due(Instant::now()) {
            return;
        }
        let boxes = detections
            .iter()
            .map(|d| annotations::DetectionBox {
                label: d.label.clone(),
                kind: d.kind,
                score: d.score,
                x0: d.mask.x0,
                y0: d.mask.y0,
                width: d.mask.width,
                height: d.mask.height,
            })
            .collect();
        if self.events_tx.try_send(Event::Detections { log_time_ns: now_ns(), stamp_ns, boxes }).is_err() {
            self.drop_counted("detections", &[(Channel::Detections, 1)]);
        }
    }

    /// Offers the nodes' points of a published graph version (`/op3dsg/node_points`) when the
    /// channel is due: `collect(max_per_node, out)` fills them (called only then).
    pub fn offer_node_points(
        &mut self,
        stamp_ns: u64,
        collect: impl FnOnce(usize, &mut Vec<crate::fusion::NodePoint>),
    ) {
        if !self.accepting() || !self.node_points.due(Instant::now()) {
            return;
        }
        let mut points = Vec::new();
        collect(self.node_points_per_node, &mut points);
        if self.events_tx.try_send(Event::NodePoints { log_time_ns: now_ns(), stamp_ns, points }).is_err() {
            self.drop_counted("node points", &[(Channel::NodePoints, 1)]);
        }
    }

    /// Offers one call of an LLM agent (`/op3dsg/llm`); the refiner's thread calls it after the
    /// gate checked the answer.
    pub fn offer_llm_exchange(&mut self, exchange: op3dsg_drivers::mcap::messages::LlmExchange) {
        if !self.accepting() || !self.llm.due(Instant::now()) {
            return;
        }
        let event = Event::LlmExchange { log_time_ns: now_ns(), exchange: Box::new(exchange) };
        if self.events_tx.try_send(event).is_err() {
            self.drop_counted("llm exchange", &[(Channel::LlmExchanges, 1)]);
        }
    }

    /// Offers a health record.
    pub fn offer_health(&mut self, health: &Health) {
        if !self.accepting() || !self.health.due(Instant::now()) {
            return;
        }
        let event = Event::Health { log_time_ns: now_ns(), health: Box::new(*health) };
        if self.events_tx.try_send(event).is_err() {
            self.drop_counted("health", &[(Channel::Health, 1)]);
        }
    }
}

/// The effective profile as TOML, the sections of registered backends included (what
/// `--print-config` shows), for the recording's `op3dsg.profile` metadata.
pub fn effective_toml(profile: &crate::config::Profile) -> String {
    let mut table = toml::Table::try_from(profile).unwrap_or_default();
    for (path, section) in &profile.sections {
        if let Some((group, name)) = path.split_once('.')
            && let Some(toml::Value::Table(group)) = table.get_mut(group)
        {
            group.insert(name.to_owned(), toml::Value::Table(section.clone()));
        }
    }
    toml::to_string(&table).unwrap_or_default()
}

/// What the recorder thread needs.
pub(crate) struct RecorderParts {
    pub(crate) config: RecordConfig,
    pub(crate) up_axis: UpAxis,
    pub(crate) profile_toml: String,
    pub(crate) side_topics: Vec<String>,
    pub(crate) frames_rx: Receiver<RawInput>,
    pub(crate) events_rx: Receiver<Event>,
    pub(crate) pool_tx: Sender<Box<RawFrame>>,
    pub(crate) stats: Arc<RecorderStats>,
}

/// Why the recorder could not start.
#[derive(Debug, thiserror::Error)]
#[error("record.dir: {dir}: {reason}")]
pub struct RecordStartError {
    /// The folder.
    pub dir: PathBuf,
    /// What failed.
    pub reason: String,
}

/// Makes the queues and the frame-buffer pool (buffers sized for `intrinsics` now, so the hot
/// path does not allocate) and checks that the folder can be created. Returns the producers'
/// sender and what the thread runs with ([`run`]). `up_axis` is the world's (`world.up_axis`),
/// for the scene's oriented boxes.
pub(crate) fn prepare(
    config: &RecordConfig,
    profile_toml: String,
    intrinsics: Intrinsics,
    up_axis: UpAxis,
    side_topics: Vec<String>,
    stats: Arc<RecorderStats>,
) -> Result<(RecordSender, RecorderParts), RecordStartError> {
    std::fs::create_dir_all(&config.dir)
        .map_err(|e| RecordStartError { dir: config.dir.clone(), reason: format!("cannot create: {e}") })?;
    // Frames are bounded by the pool (`frame_queue` + 1 buffers); the queue also carries the
    // input poses between them, which get the event queue's room.
    let (frames_tx, frames_rx) = crossbeam_channel::bounded(config.frame_queue + config.event_queue);
    let (events_tx, events_rx) = crossbeam_channel::bounded(config.event_queue);
    // One buffer more than the queue holds: the one being written.
    let (pool_tx, pool_rx) = crossbeam_channel::bounded(config.frame_queue + 1);
    let pixels = intrinsics.pixel_count();
    for _ in 0..config.frame_queue + 1 {
        let raw = Box::new(RawFrame {
            log_time_ns: 0,
            seq: 0,
            stamp_ns: 0,
            intrinsics,
            depth_units_per_m: 0.0,
            world_from_camera: None,
            colour: Some(Vec::with_capacity(pixels * 3)),
            depth: Some(Vec::with_capacity(pixels)),
            has_colour: false,
            has_depth: false,
            has_meta: false,
            sides: side_topics.iter().map(|_| (vec![0u16; pixels], false)).collect(),
        });
        let _ = pool_tx.try_send(raw);
    }
    stats.set_state(RecorderState::Recording);
    let c = &config.channels;
    let sender = RecordSender {
        frames_tx,
        events_tx,
        pool_rx,
        pool_tx: pool_tx.clone(),
        stats: stats.clone(),
        graph: Limiter::new(c.graph),
        scene: Limiter::new(c.scene),
        transforms: Limiter::new(c.transforms),
        health: Limiter::new(c.health),
        colour: Limiter::new(c.colour),
        depth: Limiter::new(c.depth),
        frame: Limiter::new(c.frame),
        sides: Limiter::new(c.side_channels),
        poses: Limiter::new(c.input_poses),
        detections: Limiter::new(c.detections),
        node_points: Limiter::new(c.node_points),
        llm: Limiter::new(c.llm),
        node_points_per_node: config.node_points_per_node,
    };
    let parts = RecorderParts {
        config: config.clone(),
        up_axis,
        profile_toml,
        side_topics,
        frames_rx,
        events_rx,
        pool_tx,
        stats,
    };
    Ok((sender, parts))
}

/// The recorder thread's body: writes until every [`RecordSender`] is gone, then finishes.
pub(crate) fn run(parts: RecorderParts) {
    writer::recorder_loop(parts);
}

/// A standalone recorder for tools and benchmarks (`op3dsg bench record`): the same queues and
/// thread as in the daemon, fed by the caller.
pub struct Recorder {
    sender: Option<RecordSender>,
    thread: Option<std::thread::JoinHandle<()>>,
    stats: Arc<RecorderStats>,
}

impl std::fmt::Debug for Recorder {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Recorder").field("stats", &self.stats.health()).finish()
    }
}

impl Recorder {
    /// Starts thread `op3dsg-record` writing into `config.dir`; `up_axis` is the world's.
    pub fn start(
        config: &RecordConfig,
        profile_toml: String,
        intrinsics: Intrinsics,
        up_axis: UpAxis,
    ) -> Result<Self, RecordStartError> {
        let stats = Arc::new(RecorderStats::default());
        let (sender, parts) = prepare(config, profile_toml, intrinsics, up_axis, Vec::new(), stats.clone())?;
        let thread = std::thread::Builder::new()
            .name("op3dsg-record".to_owned())
            .spawn(move || run(parts))
            .map_err(|e| RecordStartError { dir: config.dir.clone(), reason: format!("thread: {e}") })?;
        Ok(Self { sender: Some(sender), thread: Some(thread), stats })
    }

    /// The producers' side.
    pub fn sender(&self) -> Option<RecordSender> {
        self.sender.clone()
    }

    /// The counters.
    pub fn stats(&self) -> &Arc<RecorderStats> {
        &self.stats
    }

    /// Drops this handle's sender and waits until the recorder finished its file (every other
    /// sender must be gone too).
    pub fn finish(mut self) -> RecorderHealth {
        self.sender = None;
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
        self.stats.health()
    }
}
