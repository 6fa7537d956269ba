//! The daemon's pipeline: named threads connected by bounded queues.
//!
//! ```text
//! capture ──[frames]──► keyframe gate ──[keyframes]──► detect/0..N-1 ──[detections]──► fusion ──[graph]──► publisher
//!  source,                pose lookup,                  one Detector                    sole owner     iceoryx2: graph,
//!  frame pool             motion gate                   per worker                      of the map     event, health;
//!                           ▲                                                                          pose input
//!                           └──────────────────────────── poses (from <prefix>/pose) ◄──────────────────┘
//! ```
//!
//! Health reports one latency entry per stage: `capture`, `keyframe`, `detect/0..N-1`, `fusion`
//! (one keyframe's integration), `prior` (prior graph + reasoner, once per published version, on
//! the fusion thread), `publish`, and `end_to_end`: from the moment the source delivered a
//! keyframe to the send of the first graph version holding it (queueing included).
//!
//! Workers take keyframes under a ticket lock, so every keyframe they take gets a gapless ticket;
//! fusion applies results strictly in ticket order (a small reorder buffer), which keeps the map
//! deterministic whatever the number of workers.
//!
//! With `reasoner.kind = "llm"` the fusion thread also owns the LLM refiner (thread `op3dsg-llm`,
//! `crate::reasoner::llm`): it hands each prior graph over (latest wins) and picks up verified
//! results without ever waiting; the refiner's counters are part of the health record.
//!
//! ## Shutdown ladder (SIGINT / SIGTERM, `run.max_frames`, or the end of a finite source)
//! 1. The stop flag is set (or the source ends): capture stops reading, returns its frames to the
//!    pool and closes the `frames` queue.
//! 2. The keyframe gate drains `frames`, then closes `keyframes`.
//! 3. Each worker finishes the keyframe it holds and exits; the last one closes `detections`.
//! 4. Fusion applies every result it received, publishes the final graph into `graph`, hands the
//!    final map snapshot to the snapshot writer (which writes it and exits) and exits (stopping
//!    the LLM refiner, which abandons any request in flight).
//! 5. The publisher sends that final graph and a last health record, then releases its iceoryx2
//!    services. At the end of a finite source without `run.exit_at_end` it keeps serving instead
//!    until a signal arrives.
//!
//! 6. `query-rx` and `query` (the language query service, `crate::query::service`) end with the
//!    stop flag, or once the publisher has ended; requests still queued get a `shutting_down`
//!    reply.
//! 7. `occupancy` (the occupancy map, `crate::occupancy::service`) integrates what the gate
//!    queued and ends with the stop flag, or once the gate has ended with `run.exit_at_end`,
//!    after a last publish of the map.
//!
//! A stage that has not finished `run.shutdown_timeout_s` after the stop is named in the log and
//! the daemon exits with an error; a second signal exits at once (see the `op3dsgd` binary).

//!
//! This module wires the stages; each stage's thread loop lives with its stage (`capture/`,
//! `keyframe/thread.rs`, `perception/worker.rs`, `fusion/thread.rs`, `ipc/publisher.rs`), the
//! queue items in `items.rs`, the counters behind `health` in `stats.rs`; what a keyframe goes
//! through between the gate and a published graph is [`crate::keyframe_path`].

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender};
use op3dsg_drivers::frame::FramePool;
use op3dsg_drivers::source::{SourceError, StepControl};
use op3dsg_ipc_types::PoseStamped;
use tracing::{debug, error, info, warn};

use crate::backend::{Backends, OpenedSource};
use crate::config::{PoseSourceKind, Profile};
use crate::fusion::Fusion;
use crate::ipc::GraphServer;
use crate::queue::queue;
use crate::reasoner::{EnricherError, GraphEnricher};

pub(crate) mod items;
mod stats;

use items::{CapturedFrame, DetectionBatch, GraphItem, KeyframeItem};
pub use stats::{PipelineStats, PoseStats, RunSummary};

/// Errors that stop the pipeline from starting.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    /// The frame source could not be opened.
    #[error("source: {0}")]
    Source(#[from] SourceError),
    /// The profile combines things that cannot work together.
    #[error("{field}: {reason}")]
    Incompatible {
        /// Profile field.
        field: &'static str,
        /// Why.
        reason: String,
    },
    /// The iceoryx2 services could not be created.
    #[error("iceoryx2: {0}")]
    Ipc(String),
    /// A model or the ONNX Runtime could not be loaded (the message says what to run).
    #[error("detector: {0}")]
    Model(#[from] crate::onnx::OnnxError),
    /// The snapshot directory could not be used (or another daemon holds it).
    #[error("snapshot.dir: {0}")]
    Snapshot(#[from] crate::service::snapshot::SnapshotError),
    /// A thread could not be started.
    #[error("thread {name}: {reason}")]
    Thread {
        /// Thread name.
        name: String,
        /// OS error.
        reason: String,
    },
}

/// A running pipeline.
pub struct Pipeline {
    stop: Arc<AtomicBool>,
    query_counters: Option<Arc<crate::query::service::QueryCounters>>,
    step_control: Option<StepControl>,
    stats: Arc<PipelineStats>,
    finished_rx: Receiver<&'static str>,
    running: Vec<&'static str>,
    handles: Vec<std::thread::JoinHandle<()>>,
    shutdown_timeout: Duration,
}

impl std::fmt::Debug for Pipeline {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Pipeline").field("running", &self.running).finish_non_exhaustive()
    }
}

fn spawn_stage(
    name: &'static str,
    finished: &Sender<&'static str>,
    body: impl FnOnce() + Send + 'static,
) -> Result<std::thread::JoinHandle<()>, StartError> {
    let finished = finished.clone();
    std::thread::Builder::new()
        .name(format!("op3dsg-{name}"))
        .spawn(move || {
            body();
            let _ = finished.send(name);
        })
        .map_err(|e| StartError::Thread { name: name.to_owned(), reason: e.to_string() })
}

/// The map the profile asks for. The pipeline and the batch runner both construct their fusion
/// here, so swapping the fusion implementation is this one line.
pub fn make_fusion(profile: &Profile) -> Box<dyn Fusion> {
    crate::fusion::build(&profile.fusion, profile.world.up_axis)
}

/// The prior graph + reasoner the profile asks for (`[reasoner]`), shared by the pipeline and
/// the batch runner.
pub fn make_enricher(profile: &Profile) -> Result<Option<GraphEnricher>, StartError> {
    GraphEnricher::from_profile(profile).map_err(|e| match e {
        EnricherError::Knowledge(e) => {
            StartError::Incompatible { field: "reasoner.knowledge_dir", reason: e.to_string() }
        }
        EnricherError::Llm { field, reason } => StartError::Incompatible { field, reason },
        EnricherError::TextEncoder(reason) => StartError::Incompatible { field: "text_encoder", reason },
    })
}

/// Creates `<prefix>/occupancy` and the map (allocated now), starts `occupancy`, and returns
/// the keyframe gate's end of its queue.
fn start_occupancy_thread(
    profile: &Profile,
    intrinsics: &op3dsg_drivers::frame::Intrinsics,
    latest: Option<Arc<crate::occupancy::service::LatestOccupancy>>,
    stop: &Arc<AtomicBool>,
    finished_tx: &Sender<&'static str>,
    handles: &mut Vec<std::thread::JoinHandle<()>>,
    running: &mut Vec<&'static str>,
) -> Result<crate::occupancy::service::OccupancyFeed, StartError> {
    use crate::occupancy::OccupancyGrid;
    use crate::occupancy::service::{OccupancyPublisher, OccupancyThread, occupancy_loop, scan_queue};
    let config = &profile.occupancy;
    let mut grid = OccupancyGrid::new(config, profile.world.up_axis, profile.navigation.robot_radius_m, intrinsics);
    // Beside the map snapshot: restored now (a file that does not fit is moved aside, named in
    // the log), saved by the thread (crate::occupancy::persist).
    let store = profile.snapshot.resolve_dir().map(|dir| crate::occupancy::persist::OccupancyStore::new(&dir));
    if let Some(store) = &store {
        let _ = store.restore(&mut grid);
    }
    let publisher = OccupancyPublisher::open(&profile.ipc.prefix, grid.geometry().cell_count())
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
        cost: Arc::new(crate::stats::StageStats::new("occupancy")),
        store,
        save_period: (profile.snapshot.period_s > 0.0).then(|| Duration::from_secs_f64(profile.snapshot.period_s)),
    };
    let stop = stop.clone();
    handles.push(spawn_stage("occupancy", finished_tx, move || occupancy_loop(thread, &stop))?);
    running.push("occupancy");
    Ok(feed)
}

/// Starts `query-rx` (it creates `<prefix>/query`; returns once it exists) and the `query`
/// worker (text queries need the text encoder; node queries and approach poses do not).
fn start_query_threads(
    profile: &Profile,
    latest: Arc<crate::query::service::LatestGraph>,
    occupancy: Option<Arc<crate::occupancy::service::LatestOccupancy>>,
    stop: &Arc<AtomicBool>,
    finished_tx: &Sender<&'static str>,
    handles: &mut Vec<std::thread::JoinHandle<()>>,
    running: &mut Vec<&'static str>,
) -> Result<Arc<crate::query::service::QueryCounters>, StartError> {
    use crate::query::service::{
        EncoderSetup, NavigationSetup, QueryCounters, QueryReceiver, receive_loop, worker_loop,
    };
    let counters = Arc::new(QueryCounters::default());
    let config = profile.query.clone();
    let setup = profile
        .text_encoder
        .enabled
        .then(|| EncoderSetup { onnx: profile.onnx.clone(), text_encoder: profile.text_encoder.clone() });
    let encoder_on = setup.is_some();
    let (jobs_tx, jobs_rx) = crossbeam_channel::bounded(config.queue_capacity);
    let (ready_tx, ready_rx) = crossbeam_channel::bounded::<Result<(), String>>(1);
    {
        let (prefix, config, counters, latest, stop) =
            (profile.ipc.prefix.clone(), config.clone(), counters.clone(), latest.clone(), stop.clone());
        handles.push(spawn_stage("query-rx", finished_tx, move || {
            let receiver = match QueryReceiver::open(&prefix) {
                Ok(receiver) => {
                    let _ = ready_tx.send(Ok(()));
                    receiver
                }
                Err(e) => {
                    let _ = ready_tx.send(Err(e.to_string()));
                    return;
                }
            };
            receive_loop(receiver, jobs_tx, encoder_on, &config, &counters, &latest, &stop);
        })?);
        running.push("query-rx");
    }
    match ready_rx.recv() {
        Ok(Ok(())) => {}
        Ok(Err(reason)) => return Err(StartError::Ipc(reason)),
        Err(_) => return Err(StartError::Ipc("query receiver thread ended during start-up".to_owned())),
    }
    let navigation = NavigationSetup { occupancy, config: profile.navigation.clone(), up_axis: profile.world.up_axis };
    {
        let (counters, latest, stop) = (counters.clone(), latest.clone(), stop.clone());
        handles.push(spawn_stage("query", finished_tx, move || {
            worker_loop(setup.as_ref(), navigation, &jobs_rx, &config, &counters, &latest, &stop);
        })?);
        running.push("query");
    }
    Ok(counters)
}

impl Pipeline {
    /// Opens the source and the iceoryx2 services and starts every stage, with the source and
    /// detector `backends` the profile names. Returns once the services exist (the daemon may
    /// then report ready).
    pub fn start(profile: &Profile, backends: &Backends, stop: Arc<AtomicBool>) -> Result<Self, StartError> {
        let (opened, detector_factory) = backends.open(profile)?;
        let side_taps = backends.source(&profile.source.kind)?.side_channel_taps(&opened);
        let OpenedSource { mut source, .. } = opened;
        if profile.pose.source == PoseSourceKind::Frame && !source.has_poses() {
            return Err(StartError::Incompatible {
                field: "pose.source",
                reason: format!("{} carries no poses; use pose.source = \"ipc\"", source.describe()),
            });
        }
        info!(source = %source.describe(), workers = profile.detector.workers, "starting pipeline");
        let step_control = source.step_control();

        let q = &profile.queues;
        let (frames_tx, frames_rx, frames_stats) = queue::<CapturedFrame>("frames", q.frames, stop.clone());
        let (kf_tx, kf_rx, kf_stats) = queue::<KeyframeItem>("keyframes", q.keyframes, stop.clone());
        let (det_tx, det_rx, det_stats) = queue::<DetectionBatch>("detections", q.detections, stop.clone());
        let (graph_tx, graph_rx, graph_stats) = queue::<GraphItem>("graph", q.graph, stop.clone());
        let (pose_tx, pose_rx) = crossbeam_channel::bounded::<PoseStamped>(profile.pose.buffer_len);
        let replay_pose_tx = pose_tx.clone();

        // Before the counters: the LLM refiner (if any) owns its own.
        let enricher = make_enricher(profile)?;
        let stats = Arc::new(PipelineStats::new(
            profile.detector.workers,
            vec![frames_stats, kf_stats, det_stats, graph_stats],
            enricher.as_ref().and_then(GraphEnricher::refiner_stats).unwrap_or_default(),
        ));

        // The map: restored from the last snapshot before anything runs, so the first graph
        // published holds it (crate::service::snapshot).
        let mut fusion = make_fusion(profile);
        let mut resume = crate::fusion::thread::Resume::default();
        let snapshots = match profile.snapshot.resolve_dir() {
            None => {
                info!("map snapshots off (snapshot.dir unset outside systemd, or snapshot.enabled = false)");
                None
            }
            Some(dir) if fusion.export_state().is_none() => {
                // A map without a saved form (fusion.method = "conceptgraphs"): neither restore
                // (which would move a saved map of the other fusion aside) nor write.
                warn!(dir = %dir.display(), method = ?profile.fusion.method, "map snapshots off: this fusion cannot save or restore its map (a snapshot there is left as it is)");
                None
            }
            Some(dir) => {
                let store = crate::service::snapshot::SnapshotStore::open(&dir)?;
                if let Some(restored) = store.restore(fusion.as_mut(), &stats.snapshot) {
                    resume = crate::fusion::thread::Resume {
                        graph_version: restored.graph_version,
                        stamp_ns: restored.stamp_ns,
                        restored: true,
                    };
                }
                info!(dir = %store.dir().display(), period_s = profile.snapshot.period_s, "map snapshots on");
                Some(crate::service::snapshot::channel(store, profile.snapshot.period_s))
            }
        };
        let (snapshot_sink, snapshot_writer) = snapshots.unzip();

        let (finished_tx, finished_rx) = crossbeam_channel::unbounded::<&'static str>();
        let mut handles = Vec::new();
        let mut running = Vec::new();

        // The recorder first among the threads, so it is there before anything is produced; it
        // ends after the last producer (publisher) has dropped its sender.
        let recorder = if profile.record.enabled {
            let side_topics = side_taps.iter().map(|t| t.topic().to_owned()).collect();
            let (sender, parts) = crate::record::prepare(
                &profile.record,
                crate::record::effective_toml(profile),
                source.intrinsics(),
                profile.world.up_axis,
                side_topics,
                stats.recorder.clone(),
            )
            .map_err(|e| StartError::Incompatible { field: "record.dir", reason: e.to_string() })?;
            handles.push(spawn_stage("record", &finished_tx, move || crate::record::run(parts))?);
            running.push("record");
            Some(sender)
        } else {
            None
        };

        // The query service's view of the graph: the publisher fills it (crate::query).
        let query_graph = profile.query.enabled.then(|| Arc::new(crate::query::service::LatestGraph::new()));

        // Publisher first: it owns the iceoryx2 services and must be up before anything runs.
        let (ready_tx, ready_rx) = crossbeam_channel::bounded::<Result<(), String>>(1);
        {
            let ipc = profile.ipc.clone();
            let stats = stats.clone();
            let stop = stop.clone();
            let health_period = Duration::from_millis(profile.health.period_ms);
            let log_every = profile.health.log_every_periods;
            let exit_at_end = profile.run.exit_at_end;
            let pose_source = profile.pose.source;
            let publisher_recorder = recorder.clone();
            let query_graph = query_graph.clone();
            handles.push(spawn_stage("publish", &finished_tx, move || {
                let server = match GraphServer::open(&ipc, "op3dsgd") {
                    Ok(server) => {
                        let _ = ready_tx.send(Ok(()));
                        server
                    }
                    Err(e) => {
                        let _ = ready_tx.send(Err(e.to_string()));
                        return;
                    }
                };
                crate::ipc::publisher::publisher_loop(
                    server,
                    graph_rx,
                    pose_tx,
                    pose_source,
                    &stats,
                    &stop,
                    health_period,
                    log_every,
                    exit_at_end,
                    publisher_recorder,
                    query_graph,
                );
            })?);
            running.push("publish");
        }
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(reason)) => return Err(StartError::Ipc(reason)),
            Err(_) => return Err(StartError::Ipc("publisher thread ended during start-up".to_owned())),
        }

        // The occupancy map: its own thread, fed by the keyframe gate through a bounded queue.
        let (occupancy_feed, latest_occupancy) = if profile.occupancy.enabled {
            let latest = Arc::new(crate::occupancy::service::LatestOccupancy::new());
            let feed = start_occupancy_thread(
                profile,
                &source.intrinsics(),
                query_graph.is_some().then(|| latest.clone()),
                &stop,
                &finished_tx,
                &mut handles,
                &mut running,
            )?;
            (Some(feed), query_graph.is_some().then_some(latest))
        } else {
            (None, None)
        };

        // Language queries: a receiver and one worker of their own, never the fusion thread.
        let query_counters = match query_graph {
            Some(latest) => Some(start_query_threads(
                profile,
                latest,
                latest_occupancy,
                &stop,
                &finished_tx,
                &mut handles,
                &mut running,
            )?),
            None => None,
        };

        // Snapshot writer: off the hot path, ends after the final snapshot of the ladder.
        if let Some(writer) = snapshot_writer {
            let stats = stats.clone();
            handles.push(spawn_stage("snapshot", &finished_tx, move || writer.run(&stats))?);
            running.push("snapshot");
        }

        // Fusion.
        {
            let stats = stats.clone();
            let min_interval = Duration::from_millis(profile.run.min_publish_interval_ms);
            let fusion_recorder = recorder.clone();
            if let (Some(enricher), Some(recorder)) = (&enricher, &recorder) {
                enricher.record_llm_to(recorder);
            }
            handles.push(spawn_stage("fusion", &finished_tx, move || {
                crate::fusion::thread::fusion_loop(
                    fusion,
                    enricher,
                    det_rx,
                    graph_tx,
                    &stats,
                    min_interval,
                    snapshot_sink,
                    resume,
                    fusion_recorder,
                );
            })?);
            running.push("fusion");
        }

        // Detection workers share one ticketed receiver.
        let tickets = Arc::new(Mutex::new((kf_rx, 0u64)));
        for worker in 0..profile.detector.workers {
            let detector = detector_factory(worker as u32);
            let tickets = tickets.clone();
            let det_tx = det_tx.clone();
            let stats = stats.clone();
            let name: &'static str = Box::leak(format!("detect-{worker}").into_boxed_str());
            handles.push(spawn_stage(name, &finished_tx, move || {
                crate::perception::worker::detect_loop(worker, detector, &tickets, &det_tx, &stats);
            })?);
            running.push(name);
        }
        drop(det_tx);

        // Keyframe gate.
        {
            let stats = stats.clone();
            let stop = stop.clone();
            let config = profile.keyframe.clone();
            let pose_config = profile.pose.clone();
            let recorder = recorder.map(|sender| (sender, side_taps));
            let frame_clock = source.stamp_clock();
            handles.push(spawn_stage("keyframe", &finished_tx, move || {
                crate::keyframe::thread::keyframe_loop(
                    &config,
                    &pose_config,
                    frame_clock,
                    frames_rx,
                    kf_tx,
                    pose_rx,
                    &stats,
                    &stop,
                    recorder,
                    occupancy_feed,
                );
            })?);
            running.push("keyframe");
        }

        // Capture last, so every consumer is ready.
        {
            let stats = stats.clone();
            let stop = stop.clone();
            let pool = FramePool::new(profile.frame_pool_capacity(), source.intrinsics());
            let rate_hz = profile.source.rate_hz;
            let max_frames = profile.run.max_frames;
            // A replayed recording's input poses go where the pose input's go.
            let replay_poses = (profile.pose.source == PoseSourceKind::Ipc).then(|| replay_pose_tx.clone());
            handles.push(spawn_stage("capture", &finished_tx, move || {
                crate::capture::capture_loop(
                    source.as_mut(),
                    &pool,
                    frames_tx,
                    replay_poses,
                    rate_hz,
                    max_frames,
                    &stats,
                    &stop,
                );
            })?);
            running.push("capture");
        }

        Ok(Self {
            stop,
            query_counters,
            step_control,
            stats,
            finished_rx,
            running,
            handles,
            shutdown_timeout: Duration::from_secs_f64(profile.run.shutdown_timeout_s),
        })
    }

    /// The handle that releases frames of a stepped source (`[source.replay] mode = "stepped"`):
    /// each `step(n)` lets `n` more frames into the pipeline. `None` for other sources and modes.
    pub fn step_control(&self) -> Option<&StepControl> {
        self.step_control.as_ref()
    }

    /// The query service's counters (`None` with `query.enabled = false`).
    pub fn query_counters(&self) -> Option<&Arc<crate::query::service::QueryCounters>> {
        self.query_counters.as_ref()
    }

    /// Shared counters (for tests and the binary's summary).
    pub fn stats(&self) -> &Arc<PipelineStats> {
        &self.stats
    }

    /// Waits until every stage has ended: after the stop flag is set (signal), or by itself
    /// when the source ended with `run.exit_at_end` / `run.max_frames`. Fails naming the stuck
    /// stages when they do not end within the shutdown timeout after a stop.
    pub fn wait(mut self) -> Result<RunSummary, Vec<&'static str>> {
        let mut stop_seen_at: Option<Instant> = None;
        while !self.running.is_empty() {
            if let Ok(name) = self.finished_rx.recv_timeout(Duration::from_millis(50)) {
                self.running.retain(|n| *n != name);
                debug!(stage = name, "stage ended");
                continue;
            }
            if self.stop.load(Ordering::Relaxed) {
                let since = *stop_seen_at.get_or_insert_with(Instant::now);
                if since.elapsed() > self.shutdown_timeout {
                    error!(stages = ?self.running, "stages did not end within the shutdown timeout");
                    return Err(self.running.clone());
                }
            }
        }
        for handle in self.handles.drain(..) {
            let _ = handle.join();
        }
        let s = &self.stats;
        Ok(RunSummary {
            frames: s.frames_captured.load(Ordering::Relaxed),
            keyframes: s.keyframes.load(Ordering::Relaxed),
            graph_version: s.graph_version.load(Ordering::Relaxed),
            map_nodes: s.map_node_count.load(Ordering::Relaxed),
            map_memory_bytes: s.map_memory_bytes.load(Ordering::Relaxed),
            elapsed_s: s.started.elapsed().as_secs_f64(),
            bad_data_skipped: s.source_bad_data_skipped.load(Ordering::Relaxed),
            source_failed: s.source_failed.load(Ordering::Relaxed),
        })
    }
}
