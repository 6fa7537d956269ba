//! Each stage's thread built from the profile, and the spawner that names and tracks them.

use std::sync::{Arc, Mutex};
use std::time::Duration;

use crossbeam_channel::{Receiver, Sender};
use op3dsg_drivers::frame::{FramePool, Intrinsics};
use op3dsg_drivers::source::{FrameSource, SourceKind};
use op3dsg_ipc_types::PoseStamped;
use tracing::{info, warn};

use super::Counters;
use crate::backend::{Backends, StartError};
use crate::capture::CaptureThread;
use crate::config::{Profile, effective_toml};
use crate::flow::{
    CapturedFrame, DetectionBatch, GraphItem, KeyframeItem, LatestGraph, LiveFeed, RemoteFeed, RemoteQueries, live_feed,
};
use crate::fusion::snapshot::{SnapshotSink, SnapshotStore, SnapshotWriter};
use crate::fusion::{Fusion, FusionThread, Resume};
use crate::graph::SceneGraph;
use crate::ipc::GraphOrigin;
use crate::keyframe::{KeyframeGate, KeyframeRecorder, KeyframeThread, PoseSourceKind};
use crate::live_view::LiveViewThread;
use crate::occupancy::persist::OccupancyStore;
use crate::occupancy::{
    LatestOccupancy, OccupancyFeed, OccupancyGrid, OccupancyPublisher, OccupancyThread, scan_queue,
};
use crate::perception::{DetectThread, Tickets};
use crate::publish::PublishThread;
use crate::query::{EncoderSetup, NavigationSetup, QueryCounters, query_threads};
use crate::queue::{Latest, OverflowPolicy, QueueConfig, QueueReceiver, QueueSender, QueueStats, queue};
use crate::reasoner::GraphEnricher;
use crate::record::{RecordSender, RecordThread, SideChannelTap};
use crate::stats::StageStats;

/// The stage threads of one pipeline: each spawned by name, each reporting its end.
pub(super) struct Stages {
    finished_tx: Sender<&'static str>,
    pub(super) finished_rx: Receiver<&'static str>,
    pub(super) running: Vec<&'static str>,
    pub(super) handles: Vec<std::thread::JoinHandle<()>>,
}

impl Stages {
    pub(super) fn new() -> Self {
        let (finished_tx, finished_rx) = crossbeam_channel::unbounded::<&'static str>();
        Self { finished_tx, finished_rx, running: Vec::new(), handles: Vec::new() }
    }

    /// Starts thread `op3dsg-<name>` running `body`.
    pub(super) fn spawn(&mut self, name: &'static str, body: impl FnOnce() + Send + 'static) -> Result<(), StartError> {
        let finished = self.finished_tx.clone();
        let handle = std::thread::Builder::new()
            .name(format!("op3dsg-{name}"))
            .spawn(move || {
                body();
                let _ = finished.send(name);
            })
            .map_err(|e| StartError::Thread { name: name.to_owned(), reason: e.to_string() })?;
        self.handles.push(handle);
        self.running.push(name);
        Ok(())
    }

    /// Starts a thread that creates its iceoryx2 services itself, and returns once it says they
    /// exist (or why they could not be made).
    pub(super) fn spawn_serving(
        &mut self,
        name: &'static str,
        ready: &Receiver<Result<(), String>>,
        body: impl FnOnce() + Send + 'static,
    ) -> Result<(), StartError> {
        self.spawn(name, body)?;
        match ready.recv() {
            Ok(Ok(())) => Ok(()),
            Ok(Err(reason)) => Err(StartError::Ipc(reason)),
            Err(_) => Err(StartError::Ipc(format!("{name} thread ended during start-up"))),
        }
    }
}

/// The queues between the stages, each with its profile's capacity and policy.
pub(super) struct Queues {
    pub(super) frames: (QueueSender<CapturedFrame>, QueueReceiver<CapturedFrame>),
    pub(super) keyframes: (QueueSender<KeyframeItem>, QueueReceiver<KeyframeItem>),
    pub(super) detections: (QueueSender<DetectionBatch>, QueueReceiver<DetectionBatch>),
    pub(super) graph: (QueueSender<GraphItem>, QueueReceiver<GraphItem>),
    /// Received and replayed poses for the keyframe gate.
    pub(super) poses: (Sender<PoseStamped>, Receiver<PoseStamped>),
    /// Publisher → Zenoh stage, latest wins (`[zenoh] enabled`).
    pub(super) remote: Option<RemoteQueue>,
    /// Publisher → ROS output, latest wins (a topic of `[ros2.out]` on).
    pub(super) ros2_out: Option<RemoteQueue>,
    /// Publisher → live view, latest wins (`[live_view] enabled`).
    pub(super) live_view: Option<RemoteQueue>,
    pub(super) stats: Vec<Arc<QueueStats>>,
}

/// Graph versions waiting for the ROS output (it sends the newest anyway).
const ROS2_OUT_QUEUE: usize = 2;

/// Graph versions waiting for the live view (it sends the newest anyway).
const LIVE_VIEW_QUEUE: usize = 2;

/// The publisher → Zenoh stage queue.
pub(super) type RemoteQueue = (QueueSender<(Arc<SceneGraph>, u64)>, QueueReceiver<(Arc<SceneGraph>, u64)>);

impl Queues {
    /// The queues of `profile`; with a `lossless` source ([`FrameSource::lossless`]: a replay
    /// that reproduces its recording) the four up to the publisher block whatever their policy,
    /// so no frame, keyframe, result or graph version is dropped for lack of time.
    pub(super) fn new(profile: &Profile, stop: &Arc<std::sync::atomic::AtomicBool>, lossless: bool) -> Self {
        let mut q = profile.queues.clone();
        if lossless {
            let mut changed = Vec::new();
            let queues = [
                ("frames", &mut q.frames),
                ("keyframes", &mut q.keyframes),
                ("detections", &mut q.detections),
                ("graph", &mut q.graph),
            ];
            for (name, queue) in queues {
                if queue.policy != OverflowPolicy::Block {
                    queue.policy = OverflowPolicy::Block;
                    changed.push(name);
                }
            }
            if !changed.is_empty() {
                info!(
                    queues = %changed.join(", "),
                    "a lossless replay (source.mcap.lossless): these queues block instead of dropping, so every \
                     recorded frame is processed and the replay makes the recorded graph"
                );
            }
        }
        let (frames_tx, frames_rx, frames) = queue::<CapturedFrame>("frames", q.frames, stop.clone());
        let (kf_tx, kf_rx, keyframes) = queue::<KeyframeItem>("keyframes", q.keyframes, stop.clone());
        let (det_tx, det_rx, detections) = queue::<DetectionBatch>("detections", q.detections, stop.clone());
        let (graph_tx, graph_rx, graph) = queue::<GraphItem>("graph", q.graph, stop.clone());
        let mut stats = vec![frames, keyframes, detections, graph];
        let remote = profile.zenoh.enabled.then(|| {
            let config = QueueConfig { capacity: profile.zenoh.queue_capacity, policy: OverflowPolicy::LatestWins };
            let (tx, rx, remote) = queue("zenoh", config, stop.clone());
            stats.push(remote);
            (tx, rx)
        });
        let ros2_out = profile.ros2.out.any().then(|| {
            let config = QueueConfig { capacity: ROS2_OUT_QUEUE, policy: OverflowPolicy::LatestWins };
            let (tx, rx, ros2_out) = queue("ros2_out", config, stop.clone());
            stats.push(ros2_out);
            (tx, rx)
        });
        let live_view = profile.live_view.enabled.then(|| {
            let config = QueueConfig { capacity: LIVE_VIEW_QUEUE, policy: OverflowPolicy::LatestWins };
            let (tx, rx, live_view) = queue("live_view", config, stop.clone());
            stats.push(live_view);
            (tx, rx)
        });
        Self {
            frames: (frames_tx, frames_rx),
            keyframes: (kf_tx, kf_rx),
            detections: (det_tx, det_rx),
            graph: (graph_tx, graph_rx),
            poses: crossbeam_channel::bounded(profile.pose.buffer_len),
            remote,
            ros2_out,
            live_view,
            stats,
        }
    }
}

/// The map at start, and the snapshot writer's two ends when snapshots are on.
pub(super) struct RestoredMap {
    pub(super) fusion: Box<dyn Fusion>,
    pub(super) resume: Resume,
    pub(super) snapshots: Option<(SnapshotSink, SnapshotWriter)>,
}

/// The map the profile asks for, restored from the last snapshot before anything runs (so the
/// first graph published holds it).
pub(super) fn restored_map(
    profile: &Profile,
    backends: &Backends,
    counters: &Counters,
) -> Result<RestoredMap, StartError> {
    let mut fusion = backends.fusion(profile)?;
    let mut resume = Resume::default();
    let snapshots = match profile.snapshot.resolve_dir() {
        None => {
            info!("map snapshots off (snapshot.dir unset outside systemd, or snapshot.enabled = false)");
            None
        }
        Some(dir) if fusion.export_state().is_none() => {
            // A map without a saved form (a peer fusion): neither restore (which would move a
            // saved map of the other fusion aside) nor write.
            warn!(dir = %dir.display(), method = %profile.fusion.method, "map snapshots off: this fusion cannot save or restore its map (a snapshot there is left as it is)");
            None
        }
        Some(dir) => {
            let store = SnapshotStore::open(&dir)?;
            let stats = counters.fusion.snapshot.clone();
            if let Some(restored) = store.restore(fusion.as_mut(), &stats) {
                resume = Resume { graph_version: restored.graph_version, stamp_ns: restored.stamp_ns, restored: true };
            }
            info!(dir = %store.dir().display(), period_s = profile.snapshot.period_s, "map snapshots on");
            Some(crate::fusion::snapshot::channel(store, profile.snapshot.period_s, stats))
        }
    };
    Ok(RestoredMap { fusion, resume, snapshots })
}

/// The recorder's thread and its sender, when `[record] enabled`.
pub(super) fn recorder(
    profile: &Profile,
    intrinsics: Intrinsics,
    side_taps: &[Box<dyn SideChannelTap>],
    counters: &Counters,
) -> Result<Option<(RecordSender, RecordThread)>, StartError> {
    if !profile.record.enabled {
        return Ok(None);
    }
    let side_topics = side_taps.iter().map(|t| t.topic().to_owned()).collect();
    RecordThread::prepare(
        &profile.record,
        effective_toml(profile),
        intrinsics,
        &profile.world,
        side_topics,
        counters.recorder.clone(),
    )
    .map(|(sender, thread)| {
        let after_gate =
            counters.queues.iter().filter(|q| matches!(q.name, "keyframes" | "detections")).cloned().collect();
        Some((sender, thread.noting_pipeline_drops(after_gate)))
    })
    .map_err(|e| StartError::Incompatible { field: "record.dir", reason: e.to_string() })
}

/// The publisher: it owns the iceoryx2 services; `source_kind` is what the opened source reads;
/// it takes graphs from fusion and hands received poses to the keyframe gate (`queues`).
pub(super) fn publisher(
    profile: &Profile,
    source_kind: SourceKind,
    queues: (QueueReceiver<GraphItem>, Sender<PoseStamped>),
    counters: &Arc<Counters>,
    stop: &Arc<std::sync::atomic::AtomicBool>,
    recorder: Option<RecordSender>,
    feeds: (Option<Arc<LatestGraph>>, Option<RemoteFeed>),
) -> (PublishThread, Receiver<Result<(), String>>) {
    let (query_graph, remote) = feeds;
    let (ready, ready_rx) = crossbeam_channel::bounded(1);
    let (graph_rx, pose_tx) = queues;
    let thread = PublishThread {
        ipc: profile.ipc.clone(),
        origin: GraphOrigin::new(source_kind, &profile.world.frame_id),
        pose_source: profile.pose.source.wire(),
        ready,
        graph_rx,
        pose_tx: (profile.pose.source == PoseSourceKind::Ipc).then_some(pose_tx),
        health: counters.clone(),
        pose_stats: counters.keyframe.pose.clone(),
        counters: counters.publish.clone(),
        stop: stop.clone(),
        health_period: Duration::from_millis(profile.health.period_ms),
        log_every: profile.health.log_every_periods,
        exit_at_end: profile.run.exit_at_end,
        recorder,
        query_graph,
        remote,
    };
    (thread, ready_rx)
}

/// The live view (`[live_view] enabled`), started once its server listens: its graph hand-over
/// joins the publisher's `remote` feed (made if the off-robot stages made none), whose health
/// it reads too; returns the keyframe gate's end of its pose and images.
pub(super) fn live_view(
    stages: &mut Stages,
    profile: &Profile,
    (queue, remote): (Option<RemoteQueue>, &mut Option<RemoteFeed>),
    (intrinsics, occupancy): (Intrinsics, Option<Arc<LatestOccupancy>>),
    counters: &Counters,
    stop: &Arc<std::sync::atomic::AtomicBool>,
) -> Result<Option<LiveFeed>, StartError> {
    let (Some((graphs_tx, graphs_rx)), Some(live_counters)) = (queue, counters.live_view.clone()) else {
        return Ok(None);
    };
    let feed = remote.get_or_insert_with(|| RemoteFeed { graphs: Vec::new(), health: Arc::new(Latest::new()) });
    let c = &profile.live_view;
    let rate = c.images.then_some(c.image_rate_hz);
    let (live, intake) = live_feed(intrinsics.width, intrinsics.height, c.image_scale, rate);
    let (ready, ready_rx) = crossbeam_channel::bounded(1);
    let thread = LiveViewThread {
        config: c.clone(),
        world_frame: profile.world.frame_id.clone(),
        up_axis: profile.world.up_axis,
        graphs: graphs_rx,
        health: feed.health.clone(),
        occupancy,
        frames: intake,
        counters: live_counters,
        stop: stop.clone(),
        ready,
    };
    stages.spawn("live-view", move || thread.run())?;
    match ready_rx.recv() {
        Ok(Ok(())) => {
            feed.graphs.push(graphs_tx);
            Ok(Some(live))
        }
        Ok(Err(reason)) => Err(StartError::Incompatible { field: "live_view.bind", reason }),
        Err(_) => Err(StartError::Incompatible {
            field: "live_view",
            reason: "the live view's thread ended during start-up".to_owned(),
        }),
    }
}

/// The occupancy map (allocated now, restored beside the map snapshot), its publisher, and the
/// keyframe gate's end of its queue.
pub(super) fn occupancy(
    profile: &Profile,
    intrinsics: &Intrinsics,
    latest: Option<Arc<LatestOccupancy>>,
    stop: &Arc<std::sync::atomic::AtomicBool>,
) -> Result<(OccupancyThread, OccupancyFeed), StartError> {
    let config = &profile.occupancy;
    let mut grid = OccupancyGrid::new(config, profile.world.up_axis, profile.navigation.robot_radius_m, intrinsics);
    // A file that does not fit is moved aside, named in the log (crate::occupancy::persist).
    let store = profile.snapshot.resolve_dir().map(|dir| OccupancyStore::new(&dir));
    if let Some(store) = &store {
        let _ = store.restore(&mut grid);
    }
    let publisher = OccupancyPublisher::open(&profile.ipc, grid.geometry().cell_count())
        .map_err(|e| StartError::Ipc(e.to_string()))?;
    info!(
        cells = grid.geometry().cell_count(),
        cell_size_m = config.cell_size_m,
        memory_bytes = grid.memory_bytes(),
        "occupancy map on"
    );
    let (feed, intake) = scan_queue(config.queue_capacity, intrinsics, config.pixel_stride);
    let thread = OccupancyThread {
        grid,
        intake,
        publisher,
        latest,
        period: Duration::from_millis(config.publish_period_ms),
        exit_at_end: profile.run.exit_at_end,
        cost: Arc::new(StageStats::new("occupancy")),
        store,
        save_period: (profile.snapshot.period_s > 0.0).then(|| Duration::from_secs_f64(profile.snapshot.period_s)),
        stop: stop.clone(),
    };
    Ok((thread, feed))
}

/// The language query service's two threads (text queries need the text encoder; node queries
/// and approach poses do not) and their counters.
pub(super) fn query(
    stages: &mut Stages,
    profile: &Profile,
    latest: Arc<LatestGraph>,
    occupancy: Option<Arc<LatestOccupancy>>,
    stop: &Arc<std::sync::atomic::AtomicBool>,
    remote: &RemoteQueries,
) -> Result<Arc<QueryCounters>, StartError> {
    let encoder = profile
        .text_encoder
        .enabled
        .then(|| EncoderSetup { onnx: profile.onnx.clone(), text_encoder: profile.text_encoder.clone() });
    let navigation = NavigationSetup { occupancy, config: profile.navigation.clone(), up_axis: profile.world.up_axis };
    let (receiver, worker, ready) =
        query_threads(&profile.ipc, &profile.query, encoder, navigation, latest, stop.clone());
    let counters = worker.counters().clone();
    // Queries over Zenoh go through the same checks and queue to the same worker.
    let _ = remote.set(receiver.remote_intake());
    stages.spawn_serving("query-rx", &ready, move || receiver.run())?;
    stages.spawn("query", move || worker.run())?;
    Ok(counters)
}

/// The fusion thread, with the LLM refiner's calls recorded when both are on.
pub(super) fn fusion(
    profile: &Profile,
    map: (Box<dyn Fusion>, Resume, Option<SnapshotSink>),
    enricher: Option<GraphEnricher>,
    queues: (QueueReceiver<DetectionBatch>, QueueSender<GraphItem>),
    counters: &Counters,
    recorder: Option<RecordSender>,
) -> FusionThread {
    let (fusion, resume, snapshots) = map;
    if let (Some(enricher), Some(recorder)) = (&enricher, &recorder) {
        enricher.record_llm_to(recorder);
    }
    FusionThread {
        fusion,
        enricher,
        det_rx: queues.0,
        graph_tx: queues.1,
        counters: counters.fusion.clone(),
        liveness: counters.liveness.clone(),
        min_interval: Duration::from_millis(profile.run.min_publish_interval_ms),
        snapshots,
        resume,
        recorder,
    }
}

/// The detection workers: one of `detectors` each, one ticketed receiver shared.
pub(super) fn detectors(
    stages: &mut Stages,
    detectors: Vec<Box<dyn crate::perception::Detector>>,
    keyframes: QueueReceiver<KeyframeItem>,
    det_tx: &QueueSender<DetectionBatch>,
    counters: &Counters,
) -> Result<(), StartError> {
    let tickets: Tickets = Arc::new(Mutex::new((keyframes, 0u64)));
    for (worker, (stage, detector)) in counters.detect.iter().zip(detectors).enumerate() {
        let thread =
            DetectThread { worker, detector, tickets: tickets.clone(), det_tx: det_tx.clone(), stage: stage.clone() };
        let name: &'static str = Box::leak(format!("detect-{worker}").into_boxed_str());
        stages.spawn(name, move || thread.run())?;
    }
    Ok(())
}

/// The keyframe gate, with the source's stamp clock.
pub(super) fn keyframe(
    profile: &Profile,
    source: &dyn FrameSource,
    queues: (QueueReceiver<CapturedFrame>, QueueSender<KeyframeItem>, Receiver<PoseStamped>),
    counters: &Counters,
    stop: &Arc<std::sync::atomic::AtomicBool>,
    recorder: Option<KeyframeRecorder>,
    (occupancy, live): (Option<OccupancyFeed>, Option<LiveFeed>),
) -> KeyframeThread {
    let mut gate = KeyframeGate::new(&profile.keyframe, &profile.pose);
    gate.set_frame_clock(source.stamp_clock());
    KeyframeThread {
        gate,
        frames_rx: queues.0,
        kf_tx: queues.1,
        pose_rx: queues.2,
        counters: counters.keyframe.clone(),
        stop: stop.clone(),
        recorder,
        occupancy,
        live,
    }
}

/// The capture thread; a replayed recording's input poses go where the pose input's go.
pub(super) fn capture(
    profile: &Profile,
    source: Box<dyn FrameSource>,
    frames_tx: QueueSender<CapturedFrame>,
    pose_tx: Sender<PoseStamped>,
    counters: &Counters,
    stop: &Arc<std::sync::atomic::AtomicBool>,
) -> CaptureThread {
    let pool = FramePool::new(profile.frame_pool_capacity(), source.intrinsics());
    CaptureThread {
        source,
        pool,
        frames_tx,
        pose_tx: (profile.pose.source == PoseSourceKind::Ipc).then_some(pose_tx),
        rate_hz: profile.source.rate_hz,
        max_frames: profile.run.max_frames,
        counters: counters.capture.clone(),
        pose_stats: counters.keyframe.pose.clone(),
        liveness: counters.liveness.clone(),
        stop: stop.clone(),
    }
}
