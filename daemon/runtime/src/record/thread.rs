//! The recorder's thread and its start: queues and a frame-buffer pool made at start-up, then
//! the writer until every producer has gone. [`Recorder`] runs the same for tools.

use std::path::PathBuf;
use std::sync::Arc;

use crossbeam_channel::{Receiver, Sender};
use op3dsg_drivers::frame::Intrinsics;
use op3dsg_ipc_types::RecorderHealth;

use super::sender::{Limiter, RecordSender};
use super::{Event, RawFrame, RawInput, RecordConfig, RecorderState, RecorderStats};
use crate::queue::QueueStats;
use crate::world::{UpAxis, WorldConfig};

/// The recorder thread `op3dsg-record`, made with its producers' sender by
/// [`RecordThread::prepare`]; [`RecordThread::run`] is its body.
pub struct RecordThread {
    pub(super) config: RecordConfig,
    pub(super) up_axis: UpAxis,
    /// `world.frame_id`: the parent of `/tf`, the frame of the scene and the node points.
    pub(super) world_frame: String,
    pub(super) profile_toml: String,
    pub(super) side_topics: Vec<String>,
    pub(super) frames_rx: Receiver<RawInput>,
    pub(super) events_rx: Receiver<Event>,
    pub(super) pool_tx: Sender<Box<RawFrame>>,
    pub(super) stats: Arc<RecorderStats>,
    /// The pipeline's queues after the keyframe gate (keyframes, detections): what they drop
    /// while a file is open is written into its metadata ([`RecordThread::noting_pipeline_drops`]).
    pub(super) pipeline_queues: Vec<Arc<QueueStats>>,
}

impl RecordThread {
    /// Notes in each file's `op3dsg.recorder` metadata what `queues` dropped while it was open
    /// (`pipeline_dropped.<queue>`, `pipeline_dropped_total`): the pipeline's queues after the
    /// keyframe gate, whose drops a replay does not repeat, so `op3dsg record info` can tell
    /// whether the recorded graph is one a replay reproduces.
    pub fn noting_pipeline_drops(mut self, queues: Vec<Arc<QueueStats>>) -> Self {
        self.pipeline_queues = queues;
        self
    }
}

impl std::fmt::Debug for RecordThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RecordThread").field("dir", &self.config.dir).finish_non_exhaustive()
    }
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

impl RecordThread {
    /// Makes the queues and the frame-buffer pool (buffers sized for `intrinsics` now, so the hot
    /// path does not allocate) and checks that the folder can be created. Returns the producers'
    /// sender and the thread. `world` is the profile's `[world]`: its up axis turns the scene's
    /// oriented boxes, its frame id names the world frame in `/tf`, the scene and the node points
    /// (so a recording and the graph header agree); `side_topics` are the source's side channels
    /// recorded with each frame.
    pub fn prepare(
        config: &RecordConfig,
        profile_toml: String,
        intrinsics: Intrinsics,
        world: &WorldConfig,
        side_topics: Vec<String>,
        stats: Arc<RecorderStats>,
    ) -> Result<(RecordSender, Self), RecordStartError> {
        let dir = config.resolve_dir();
        std::fs::create_dir_all(&dir)
            .map_err(|e| RecordStartError { dir: dir.clone(), reason: format!("cannot create: {e}") })?;
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
        let thread = RecordThread {
            config: RecordConfig { dir, ..config.clone() },
            up_axis: world.up_axis,
            world_frame: world.frame_id.clone(),
            profile_toml,
            side_topics,
            frames_rx,
            events_rx,
            pool_tx,
            stats,
            pipeline_queues: Vec::new(),
        };
        Ok((sender, thread))
    }

    /// The thread's body: writes until every [`RecordSender`] is gone, then finishes.
    pub fn run(self) {
        super::writer::recorder_loop(self);
    }
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
    /// Starts thread `op3dsg-record` writing into `config.dir` ([`RecordConfig::resolve_dir`]);
    /// `world` is the profile's `[world]` (see [`RecordThread::prepare`]).
    pub fn start(
        config: &RecordConfig,
        profile_toml: String,
        intrinsics: Intrinsics,
        world: &WorldConfig,
    ) -> Result<Self, RecordStartError> {
        let stats = Arc::new(RecorderStats::default());
        let (sender, thread) =
            RecordThread::prepare(config, profile_toml, intrinsics, world, Vec::new(), stats.clone())?;
        let thread = std::thread::Builder::new()
            .name("op3dsg-record".to_owned())
            .spawn(move || thread.run())
            .map_err(|e| RecordStartError { dir: config.resolve_dir(), reason: format!("thread: {e}") })?;
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
