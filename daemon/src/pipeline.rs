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
//! 4. Fusion applies every result it received, publishes the final graph into `graph` and exits
//!    (stopping the LLM refiner, which abandons any request in flight).
//! 5. The publisher sends that final graph and a last health record, then releases its iceoryx2
//!    services. At the end of a finite source without `run.exit_at_end` it keeps serving instead
//!    until a signal arrives.
//!
//! A stage that has not finished `run.shutdown_timeout_s` after the stop is named in the log and
//! the daemon exits with an error; a second signal exits at once (see the `op3dsgd` binary).

use std::collections::{BTreeMap, HashMap};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender};
use op3dsg_drivers::frame::{FramePool, PooledFrame};
use op3dsg_drivers::pose::Isometry;
use op3dsg_drivers::replay::ReplaySource;
use op3dsg_drivers::source::{FrameSource, SourceError, SourceStatus, StepControl};
use op3dsg_drivers::synthetic::{Scene, SyntheticSource};
use op3dsg_ipc_types::{Health, PoseStamped, write_fixed_str};
use tracing::{debug, error, info, warn};

use crate::config::{DetectorKind, PoseSourceKind, Profile, SourceKind};
use crate::fusion::Fusion;
use crate::graph::SceneGraph;
use crate::ipc::GraphServer;
use crate::keyframe::{GateDecision, KeyframeGate};
use crate::knowledge::KnowledgeBase;
use crate::perception::candidates::{CandidateMode, PartCandidates};
use crate::perception::open_vocab::OpenVocabDetector;
use crate::perception::oracle::{OracleDetector, SemanticSource};
use crate::perception::yolox::YoloxDetector;
use crate::perception::{Detection, Detector, DetectorError};
use crate::queue::{Popped, QueueReceiver, QueueSender, QueueStats, queue};
use crate::reasoner::llm::RefinerStats;
use crate::reasoner::{EnricherError, GraphEnricher};
use crate::stats::StageStats;

/// How long a stage waits on an empty queue before it checks the stop flag again.
const POLL: Duration = Duration::from_millis(20);

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
    /// A thread could not be started.
    #[error("thread {name}: {reason}")]
    Thread {
        /// Thread name.
        name: String,
        /// OS error.
        reason: String,
    },
}

/// Counters shared by every stage and read by the health reporter.
#[derive(Debug)]
pub struct PipelineStats {
    started: Instant,
    /// Frames the source delivered.
    pub frames_captured: AtomicU64,
    /// Frames dropped at capture because every pooled frame was in flight.
    pub frames_pool_exhausted: AtomicU64,
    /// Frames accepted as keyframes.
    pub keyframes: AtomicU64,
    /// Frames dropped for lack of a pose within tolerance.
    pub frames_without_pose: AtomicU64,
    /// Poses received on the pose service that were rejected (bad kind or quaternion).
    pub poses_rejected: AtomicU64,
    /// Detections given to fusion.
    pub detections_fused: AtomicU64,
    /// Latest graph version.
    pub graph_version: AtomicU64,
    /// Nodes in the map.
    pub map_node_count: AtomicU64,
    /// Heap bytes of the fusion map.
    pub map_memory_bytes: AtomicU64,
    /// Whether the source is delivering.
    pub source_connected: AtomicBool,
    /// Set once a finite source has ended (or `max_frames` was reached).
    pub source_finished: AtomicBool,
    /// Bad inputs a replay skipped (`on_bad_frame = "skip"`); also counted as capture errors.
    pub source_bad_data_skipped: AtomicU64,
    /// Set when the source stopped on an error (a replay's bad data with `on_bad_frame = "stop"`).
    pub source_failed: AtomicBool,
    /// Per-stage figures, in pipeline order.
    pub stages: Vec<Arc<StageStats>>,
    /// Per-queue figures, in pipeline order.
    pub queues: Vec<Arc<QueueStats>>,
    /// The LLM refiner (state `off` without `reasoner.kind = "llm"`).
    pub refiner: Arc<RefinerStats>,
}

impl PipelineStats {
    /// The health record of this moment (starts a new latency period for every stage).
    pub fn health(&self) -> Health {
        let mut h = Health { stamp_ns: crate::ipc::wall_clock_ns(), ..Health::default() };
        h.uptime_ns = self.started.elapsed().as_nanos() as u64;
        h.frames_captured = self.frames_captured.load(Ordering::Relaxed);
        h.keyframes = self.keyframes.load(Ordering::Relaxed);
        h.frames_without_pose = self.frames_without_pose.load(Ordering::Relaxed);
        h.detections_fused = self.detections_fused.load(Ordering::Relaxed);
        h.graph_version = self.graph_version.load(Ordering::Relaxed);
        h.map_node_count = self.map_node_count.load(Ordering::Relaxed) as u32;
        h.map_memory_bytes = self.map_memory_bytes.load(Ordering::Relaxed);
        h.source_connected = u8::from(self.source_connected.load(Ordering::Relaxed));
        for (slot, stage) in h.stages.iter_mut().zip(&self.stages) {
            let f = stage.take_figures();
            write_fixed_str(&mut slot.name, &stage.name);
            slot.processed = f.processed;
            slot.rate_hz = f.rate_hz;
            slot.latency_p50_us = f.p50_us;
            slot.latency_p99_us = f.p99_us;
            slot.errors = f.errors.min(u32::MAX as u64) as u32;
        }
        h.stage_count = self.stages.len().min(h.stages.len()) as u32;
        for (slot, q) in h.queues.iter_mut().zip(&self.queues) {
            write_fixed_str(&mut slot.name, q.name);
            slot.depth = q.depth() as u32;
            slot.capacity = q.capacity as u32;
            slot.dropped = q.dropped.load(Ordering::Relaxed);
            slot.pushed = q.pushed.load(Ordering::Relaxed);
        }
        h.queue_count = self.queues.len().min(h.queues.len()) as u32;
        h.refiner = self.refiner.health();
        h
    }

    fn stage(&self, name: &str) -> Arc<StageStats> {
        // Stages are created in `start`; a missing name is a programming error caught by tests.
        self.stages.iter().find(|s| s.name == name).cloned().unwrap_or_else(|| Arc::new(StageStats::new(name)))
    }
}

/// What a finished run did (printed by `op3dsgd` at exit).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RunSummary {
    /// Frames delivered by the source.
    pub frames: u64,
    /// Keyframes fused.
    pub keyframes: u64,
    /// Final graph version.
    pub graph_version: u64,
    /// Nodes in the map at the end.
    pub map_nodes: u64,
    /// Heap bytes of the fusion map at the end.
    pub map_memory_bytes: u64,
    /// Seconds from start to the end of the last stage.
    pub elapsed_s: f64,
    /// Bad inputs the source skipped.
    pub bad_data_skipped: u64,
    /// The source stopped on an error (the binary exits with a failure).
    pub source_failed: bool,
}

impl RunSummary {
    /// Keyframes per second over the run.
    pub fn keyframes_per_s(&self) -> f64 {
        self.keyframes as f64 / self.elapsed_s.max(1e-9)
    }
}

/// A frame as the source delivered it, with the moment it was delivered (the start of the
/// `end_to_end` latency).
struct CapturedFrame {
    frame: PooledFrame,
    captured_at: Instant,
}

struct KeyframeItem {
    frame: PooledFrame,
    captured_at: Instant,
    world_from_camera: Isometry,
}

struct DetectionBatch {
    ticket: u64,
    frame: PooledFrame,
    captured_at: Instant,
    world_from_camera: Isometry,
    detections: Vec<Detection>,
}

/// A graph version for the publisher, with the capture moment of the newest keyframe fused into
/// it (`None` before the first keyframe).
struct GraphItem {
    graph: SceneGraph,
    newest_capture: Option<Instant>,
}

/// A running pipeline.
pub struct Pipeline {
    stop: Arc<AtomicBool>,
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

/// Makes one detector per worker (the argument is the worker index, for logs only).
pub(crate) type DetectorFactory = Arc<dyn Fn(u32) -> Box<dyn Detector> + Send + Sync>;

/// What the profile's source section opens: the source, a detector factory, and the ground
/// truth when the source has one.
pub(crate) struct BuiltSource {
    pub(crate) source: Box<dyn FrameSource>,
    pub(crate) detector_factory: DetectorFactory,
    /// The synthetic scene (ground truth) when the source is synthetic.
    pub(crate) scene: Option<Scene>,
}

/// Opens the source and prepares the detectors exactly as the pipeline does (the batch runner
/// uses it too, so both see the same frames and detections).
pub(crate) fn build_source(profile: &Profile) -> Result<BuiltSource, StartError> {
    match profile.source.kind {
        SourceKind::Synthetic => {
            let source = SyntheticSource::new(&profile.source.synthetic)?;
            let scene = source.scene().clone();
            let instances = scene.instances().to_vec();
            let oracle = profile.detector.oracle.clone();
            let detector_factory: DetectorFactory = match profile.detector.kind {
                DetectorKind::Oracle => {
                    let candidates = oracle_candidates(profile)?;
                    let vectors = oracle_label_vectors(profile, &instances)?;
                    Arc::new(move |worker| {
                        let mut detector = OracleDetector::new(oracle.clone(), instances.clone(), worker);
                        if let Some(candidates) = &candidates {
                            detector = detector.with_candidates(candidates.clone());
                        }
                        if let Some(vectors) = &vectors {
                            detector = detector.with_label_vectors(vectors);
                        }
                        Box::new(detector) as Box<dyn Detector>
                    })
                }
                DetectorKind::Yolox | DetectorKind::OpenVocab => model_factory(profile)?,
            };
            Ok(BuiltSource { source: Box::new(source), detector_factory, scene: Some(scene) })
        }
        SourceKind::Replay => {
            let Some(config) = &profile.source.replay else {
                return Err(StartError::Incompatible {
                    field: "source.replay",
                    reason: "required with source.kind = \"replay\"".to_owned(),
                });
            };
            let source = ReplaySource::new(config)?;
            let oracle = profile.detector.oracle.clone();
            let factory: DetectorFactory = match profile.detector.kind {
                DetectorKind::Oracle => {
                    warn!(
                        "detector.kind = \"oracle\" reads the synthetic renderer's instance ids, which replayed \
                         frames do not have: every keyframe's detection fails and the map stays empty"
                    );
                    Arc::new(move |worker| {
                        Box::new(OracleDetector::new(oracle.clone(), Vec::new(), worker)) as Box<dyn Detector>
                    })
                }
                DetectorKind::Yolox | DetectorKind::OpenVocab => model_factory(profile)?,
            };
            Ok(BuiltSource { source: Box::new(source), detector_factory: factory, scene: None })
        }
    }
}

/// The knowledge base of `reasoner.knowledge_dir`, else the built-in tables (the detectors' part
/// candidates use the reasoner's tables).
fn knowledge_base(profile: &Profile) -> Result<Arc<KnowledgeBase>, StartError> {
    KnowledgeBase::from_profile_dir(profile.reasoner.knowledge_dir.as_deref())
        .map(Arc::new)
        .map_err(|e| StartError::Incompatible { field: "reasoner.knowledge_dir", reason: e.to_string() })
}

/// The oracle's prompt lists (`detector.oracle.part_prompts`), from the knowledge base the
/// reasoner uses (`reasoner.knowledge_dir`, else the built-in tables); `None` for `all`.
fn oracle_candidates(profile: &Profile) -> Result<Option<Arc<PartCandidates>>, StartError> {
    let mode = profile.detector.oracle.part_prompts;
    if mode == CandidateMode::All {
        return Ok(None);
    }
    Ok(Some(Arc::new(PartCandidates::new(knowledge_base(profile)?, mode))))
}

/// Label → semantic vector, shared by the detection workers.
type LabelVectors = Arc<HashMap<String, Vec<f32>>>;

/// With `detector.oracle.semantic_source = "text_encoder"`, the text encoder's embedding of
/// every label of the scene (loaded once here, so a missing model stops start-up).
fn oracle_label_vectors(
    profile: &Profile,
    instances: &[op3dsg_drivers::synthetic::InstanceInfo],
) -> Result<Option<LabelVectors>, StartError> {
    if profile.detector.oracle.semantic_source != SemanticSource::TextEncoder {
        return Ok(None);
    }
    let runtime = crate::onnx::OnnxRuntime::init(&profile.onnx)?;
    let mut encoder = crate::onnx::text_encoder::TextEncoder::new(&runtime, &profile.text_encoder)?;
    let mut labels: Vec<&str> = instances.iter().map(|i| i.label.as_str()).collect();
    labels.sort_unstable();
    labels.dedup();
    let embeddings = encoder.encode_batch(&labels)?;
    Ok(Some(Arc::new(labels.iter().zip(embeddings).map(|(l, e)| ((*l).to_owned(), e.to_vec())).collect())))
}

/// Loads the ONNX Runtime and one model session per detection worker now (YOLOX or the
/// open-vocabulary detector), so a missing runtime or model stops start-up with the error that
/// says what to run. The factory hands worker `i` its preloaded session; a worker index beyond
/// `detector.workers` (none in the pipeline) loads a fresh one.
fn model_factory(profile: &Profile) -> Result<DetectorFactory, StartError> {
    type Load = dyn Fn() -> Result<Box<dyn Detector>, crate::onnx::OnnxError> + Send + Sync;
    let runtime = crate::onnx::OnnxRuntime::init(&profile.onnx)?;
    let load: Arc<Load> = match profile.detector.kind {
        DetectorKind::OpenVocab => {
            let config = profile.detector.open_vocab.clone();
            let text_encoder = profile.text_encoder.clone();
            let knowledge = knowledge_base(profile)?;
            Arc::new(move || {
                OpenVocabDetector::new(&runtime, &config, knowledge.clone(), &text_encoder)
                    .map(|d| Box::new(d) as Box<dyn Detector>)
            })
        }
        DetectorKind::Yolox | DetectorKind::Oracle => {
            let config = profile.detector.yolox.clone();
            Arc::new(move || YoloxDetector::new(&runtime, &config).map(|d| Box::new(d) as Box<dyn Detector>))
        }
    };
    let mut preloaded = Vec::with_capacity(profile.detector.workers);
    for _ in 0..profile.detector.workers.max(1) {
        preloaded.push(Some(load()?));
    }
    let preloaded = Arc::new(Mutex::new(preloaded));
    Ok(Arc::new(move |worker| {
        let taken = preloaded
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .get_mut(worker as usize)
            .and_then(Option::take);
        match taken.map_or_else(|| load(), Ok) {
            Ok(detector) => detector,
            Err(e) => Box::new(FailedDetector(e.to_string())),
        }
    }))
}

/// A detector whose model could not be loaded: every detection fails with the load error.
struct FailedDetector(String);

impl Detector for FailedDetector {
    fn detect(&mut self, _frame: &op3dsg_drivers::frame::Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError> {
        out.clear();
        Err(DetectorError::Backend(self.0.clone()))
    }

    fn name(&self) -> &str {
        "failed"
    }
}

/// The map the profile asks for. The pipeline and the batch runner both construct their fusion
/// here, so swapping the fusion implementation is this one line.
pub fn make_fusion(profile: &Profile) -> Box<dyn Fusion> {
    crate::fusion::build(&profile.fusion)
}

/// The prior graph + reasoner the profile asks for (`[reasoner]`), shared by the pipeline and
/// the batch runner.
pub fn make_enricher(profile: &Profile) -> Result<Option<GraphEnricher>, StartError> {
    GraphEnricher::from_profile(profile).map_err(|e| match e {
        EnricherError::Knowledge(e) => {
            StartError::Incompatible { field: "reasoner.knowledge_dir", reason: e.to_string() }
        }
        EnricherError::Llm { field, reason } => StartError::Incompatible { field, reason },
    })
}

impl Pipeline {
    /// Opens the source and the iceoryx2 services and starts every stage. Returns once the
    /// services exist (the daemon may then report ready).
    pub fn start(profile: &Profile, stop: Arc<AtomicBool>) -> Result<Self, StartError> {
        let BuiltSource { mut source, detector_factory, scene: _ } = build_source(profile)?;
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

        let mut stages = vec![Arc::new(StageStats::new("capture")), Arc::new(StageStats::new("keyframe"))];
        for i in 0..profile.detector.workers {
            stages.push(Arc::new(StageStats::new(format!("detect/{i}"))));
        }
        stages.push(Arc::new(StageStats::new("fusion")));
        stages.push(Arc::new(StageStats::new("prior")));
        stages.push(Arc::new(StageStats::new("publish")));
        // Not a thread: from a keyframe's capture to the send of the first graph holding it.
        stages.push(Arc::new(StageStats::new("end_to_end")));
        // Before the counters: the LLM refiner (if any) owns its own.
        let enricher = make_enricher(profile)?;
        let stats = Arc::new(PipelineStats {
            started: Instant::now(),
            frames_captured: AtomicU64::new(0),
            frames_pool_exhausted: AtomicU64::new(0),
            keyframes: AtomicU64::new(0),
            frames_without_pose: AtomicU64::new(0),
            poses_rejected: AtomicU64::new(0),
            detections_fused: AtomicU64::new(0),
            graph_version: AtomicU64::new(0),
            map_node_count: AtomicU64::new(0),
            map_memory_bytes: AtomicU64::new(0),
            source_connected: AtomicBool::new(true),
            source_finished: AtomicBool::new(false),
            source_bad_data_skipped: AtomicU64::new(0),
            source_failed: AtomicBool::new(false),
            stages,
            queues: vec![frames_stats, kf_stats, det_stats, graph_stats],
            refiner: enricher.as_ref().and_then(GraphEnricher::refiner_stats).unwrap_or_default(),
        });

        let (finished_tx, finished_rx) = crossbeam_channel::unbounded::<&'static str>();
        let mut handles = Vec::new();
        let mut running = Vec::new();

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
                publisher_loop(
                    server,
                    graph_rx,
                    pose_tx,
                    pose_source,
                    &stats,
                    &stop,
                    health_period,
                    log_every,
                    exit_at_end,
                );
            })?);
            running.push("publish");
        }
        match ready_rx.recv() {
            Ok(Ok(())) => {}
            Ok(Err(reason)) => return Err(StartError::Ipc(reason)),
            Err(_) => return Err(StartError::Ipc("publisher thread ended during start-up".to_owned())),
        }

        // Fusion.
        {
            let stats = stats.clone();
            let fusion = make_fusion(profile);
            let min_interval = Duration::from_millis(profile.run.min_publish_interval_ms);
            handles.push(spawn_stage("fusion", &finished_tx, move || {
                fusion_loop(fusion, enricher, det_rx, graph_tx, &stats, min_interval);
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
                detect_loop(worker, detector, &tickets, &det_tx, &stats);
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
            handles.push(spawn_stage("keyframe", &finished_tx, move || {
                keyframe_loop(&config, &pose_config, frames_rx, kf_tx, pose_rx, &stats, &stop);
            })?);
            running.push("keyframe");
        }

        // Capture last, so every consumer is ready.
        {
            let stats = stats.clone();
            let stop = stop.clone();
            let pool = FramePool::new(profile.frame_pool_capacity(), source.intrinsics(), source.has_instance_ids());
            let rate_hz = profile.source.rate_hz;
            let max_frames = profile.run.max_frames;
            handles.push(spawn_stage("capture", &finished_tx, move || {
                capture_loop(source.as_mut(), &pool, frames_tx, rate_hz, max_frames, &stats, &stop);
            })?);
            running.push("capture");
        }

        Ok(Self {
            stop,
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

fn capture_loop(
    source: &mut dyn FrameSource,
    pool: &FramePool,
    frames_tx: QueueSender<CapturedFrame>,
    rate_hz: f64,
    max_frames: u64,
    stats: &PipelineStats,
    stop: &AtomicBool,
) {
    let stage = stats.stage("capture");
    let period = (rate_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / rate_hz));
    let mut next_due = Instant::now();
    let mut delivered = 0u64;
    let mut consecutive_errors = 0u32;
    // Bad data a replay skipped (it logged each): counted as capture errors for health.
    let mut skipped_seen = 0u64;
    let mut count_skipped = |source: &dyn FrameSource| {
        let skipped = source.bad_data_skipped();
        if skipped > skipped_seen {
            stage.errors.fetch_add(skipped - skipped_seen, Ordering::Relaxed);
            stats.source_bad_data_skipped.store(skipped, Ordering::Relaxed);
            skipped_seen = skipped;
        }
    };
    count_skipped(source);
    while !stop.load(Ordering::Relaxed) {
        if max_frames > 0 && delivered >= max_frames {
            info!(frames = delivered, "run.max_frames reached");
            stats.source_finished.store(true, Ordering::Relaxed);
            break;
        }
        if let Some(period) = period {
            let now = Instant::now();
            if next_due > now {
                std::thread::sleep(next_due - now);
            }
            next_due = next_due.max(now - period) + period;
        }
        let Some(mut frame) = pool.take_timeout(Duration::from_millis(100)) else {
            stats.frames_pool_exhausted.fetch_add(1, Ordering::Relaxed);
            continue;
        };
        let started = Instant::now();
        let status = source.next_frame(&mut frame);
        count_skipped(source);
        match status {
            Ok(SourceStatus::Frame) => {
                consecutive_errors = 0;
                delivered += 1;
                stats.frames_captured.fetch_add(1, Ordering::Relaxed);
                stage.record(started);
                tracing::trace!(frame_seq = frame.seq, "captured");
                frames_tx.push(CapturedFrame { frame, captured_at: Instant::now() });
            }
            Ok(SourceStatus::Pending) => {}
            Ok(SourceStatus::EndOfStream) => {
                info!(frames = delivered, source = %source.describe(), "source ended");
                stats.source_finished.store(true, Ordering::Relaxed);
                break;
            }
            Err(e) if source.stops_on_error() => {
                stage.record_error();
                error!(error = %e, source = %source.describe(), frames = delivered, "frame source stopped on bad data");
                stats.source_failed.store(true, Ordering::Relaxed);
                stats.source_finished.store(true, Ordering::Relaxed);
                break;
            }
            Err(e) => {
                stage.record_error();
                consecutive_errors += 1;
                if consecutive_errors == 1 || consecutive_errors.is_power_of_two() {
                    warn!(error = %e, consecutive_errors, "frame source error");
                }
                std::thread::sleep(Duration::from_millis(10 * u64::from(consecutive_errors.min(100))));
            }
        }
    }
    stats.source_connected.store(false, Ordering::Relaxed);
}

fn keyframe_loop(
    config: &crate::config::KeyframeConfig,
    pose_config: &crate::config::PoseConfig,
    frames_rx: QueueReceiver<CapturedFrame>,
    kf_tx: QueueSender<KeyframeItem>,
    pose_rx: Receiver<PoseStamped>,
    stats: &PipelineStats,
    stop: &AtomicBool,
) {
    let stage = stats.stage("keyframe");
    let mut gate = KeyframeGate::new(config, pose_config);
    loop {
        let CapturedFrame { frame, captured_at } = match frames_rx.pop_timeout(POLL) {
            Popped::Item(captured) => captured,
            Popped::Empty if stop.load(Ordering::Relaxed) => break,
            Popped::Empty => continue,
            Popped::Finished => break,
        };
        let started = Instant::now();
        for pose in pose_rx.try_iter() {
            if !gate.add_pose(&pose) {
                stats.poses_rejected.fetch_add(1, Ordering::Relaxed);
            }
        }
        match gate.decide(&frame) {
            GateDecision::NoPose => {
                stats.frames_without_pose.fetch_add(1, Ordering::Relaxed);
                tracing::trace!(frame_seq = frame.seq, "no pose within tolerance; frame dropped");
            }
            GateDecision::Skip => stage.record(started),
            GateDecision::Keyframe(world_from_camera) => {
                stage.record(started);
                stats.keyframes.fetch_add(1, Ordering::Relaxed);
                kf_tx.push(KeyframeItem { frame, captured_at, world_from_camera });
            }
        }
    }
}

fn detect_loop(
    worker: usize,
    mut detector: Box<dyn Detector>,
    tickets: &Mutex<(QueueReceiver<KeyframeItem>, u64)>,
    det_tx: &QueueSender<DetectionBatch>,
    stats: &PipelineStats,
) {
    let stage = stats.stage(&format!("detect/{worker}"));
    let mut failures = 0u64;
    loop {
        let taken = {
            let Ok(mut guard) = tickets.lock() else { break };
            match guard.0.pop_timeout(POLL) {
                Popped::Item(item) => {
                    let ticket = guard.1;
                    guard.1 += 1;
                    Some((ticket, item))
                }
                Popped::Empty => None,
                Popped::Finished => break,
            }
        };
        // On stop, keep draining until the gate closes the queue: the ladder is ordered.
        let Some((ticket, item)) = taken else { continue };
        let started = Instant::now();
        let mut detections = Vec::new();
        if let Err(e) = detector.detect(&item.frame, &mut detections) {
            stage.record_error();
            failures += 1;
            if failures <= 3 || failures.is_power_of_two() {
                warn!(worker, frame_seq = item.frame.seq, failures, error = %e, "detection failed; keyframe fused empty");
            }
            detections.clear();
        } else {
            stage.record(started);
        }
        // Always send, even empty, so fusion's ticket sequence has no gaps.
        det_tx.push(DetectionBatch {
            ticket,
            frame: item.frame,
            captured_at: item.captured_at,
            world_from_camera: item.world_from_camera,
            detections,
        });
    }
}

fn fusion_loop(
    mut fusion: Box<dyn Fusion>,
    mut enricher: Option<GraphEnricher>,
    det_rx: QueueReceiver<DetectionBatch>,
    graph_tx: QueueSender<GraphItem>,
    stats: &PipelineStats,
    min_interval: Duration,
) {
    let stage = stats.stage("fusion");
    let prior_stage = stats.stage("prior");
    let mut newest_capture: Option<Instant> = None;
    let mut pending: BTreeMap<u64, DetectionBatch> = BTreeMap::new();
    let mut next_ticket = 0u64;
    let mut version = 0u64;
    let mut stamp_ns = 0u64;
    let mut dirty = false;
    let mut last_publish: Option<Instant> = None;
    let mut publish = |fusion: &dyn Fusion, version: &mut u64, stamp_ns: u64, newest_capture: Option<Instant>| {
        let mut graph = SceneGraph::default();
        fusion.build_graph(&mut graph);
        *version += 1;
        graph.version = *version;
        graph.stamp_ns = stamp_ns;
        if let Some(enricher) = enricher.as_mut() {
            let started = Instant::now();
            enricher.enrich(&mut graph);
            prior_stage.record(started);
        }
        stats.graph_version.store(*version, Ordering::Relaxed);
        stats.map_node_count.store(fusion.node_count() as u64, Ordering::Relaxed);
        stats.map_memory_bytes.store(fusion.memory_bytes() as u64, Ordering::Relaxed);
        graph_tx.push(GraphItem { graph, newest_capture });
    };
    loop {
        let finished = match det_rx.pop_timeout(POLL) {
            Popped::Item(batch) => {
                pending.insert(batch.ticket, batch);
                false
            }
            Popped::Empty => false,
            Popped::Finished => true,
        };
        // Apply results in ticket order; at the end, apply what is left in order (a gap can only
        // come from a worker that gave up during shutdown).
        while let Some(batch) =
            pending.remove(&next_ticket).or_else(|| if finished { pending.pop_first().map(|(_, b)| b) } else { None })
        {
            next_ticket = batch.ticket + 1;
            let started = Instant::now();
            let report = fusion.integrate(&batch.frame, &batch.world_from_camera, &batch.detections);
            stats.detections_fused.fetch_add(batch.detections.len() as u64, Ordering::Relaxed);
            stamp_ns = stamp_ns.max(batch.frame.stamp_ns);
            newest_capture = newest_capture.max(Some(batch.captured_at));
            stage.record(started);
            tracing::trace!(
                frame_seq = batch.frame.seq,
                merged = report.merged,
                created = report.created,
                ignored = report.ignored,
                "fused"
            );
            dirty |= report.merged + report.created > 0;
        }
        let due = last_publish.is_none_or(|t| t.elapsed() >= min_interval);
        if dirty && (due || finished) {
            publish(fusion.as_ref(), &mut version, stamp_ns, newest_capture);
            last_publish = Some(Instant::now());
            dirty = false;
        }
        if finished {
            if version == 0 {
                // Publish an empty graph so clients see the daemon served.
                publish(fusion.as_ref(), &mut version, stamp_ns, newest_capture);
            }
            break;
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn publisher_loop(
    mut server: GraphServer,
    graph_rx: QueueReceiver<GraphItem>,
    pose_tx: Sender<PoseStamped>,
    pose_source: PoseSourceKind,
    stats: &PipelineStats,
    stop: &AtomicBool,
    health_period: Duration,
    log_every: u32,
    exit_at_end: bool,
) {
    let stage = stats.stage("publish");
    let end_to_end = stats.stage("end_to_end");
    let mut next_health = Instant::now();
    let mut periods = 0u32;
    let mut upstream_done = false;
    let mut poses = Vec::new();
    let mut publish_errors = 0u64;
    loop {
        match graph_rx.pop_timeout(if upstream_done { Duration::from_millis(100) } else { POLL }) {
            Popped::Item(GraphItem { graph, newest_capture }) => {
                let started = Instant::now();
                match server.publish_graph(&graph) {
                    Ok(report) => {
                        stage.record(started);
                        if let Some(captured_at) = newest_capture {
                            end_to_end.record(captured_at);
                        }
                        if report.truncated {
                            warn!(version = graph.version, "graph exceeds the snapshot capacity; truncated");
                        }
                    }
                    Err(e) => {
                        stage.record_error();
                        publish_errors += 1;
                        if publish_errors.is_power_of_two() {
                            warn!(error = %e, publish_errors, "graph publish failed");
                        }
                    }
                }
            }
            Popped::Empty => {}
            Popped::Finished => {
                if !upstream_done {
                    info!("pipeline drained; final graph published");
                }
                upstream_done = true;
            }
        }
        // Late joiners get the history sample when the publisher updates its connections, so
        // do it on every tick, not only when the graph changes.
        if let Err(e) = server.update_connections() {
            debug!(error = %e, "update connections failed");
        }
        poses.clear();
        if let Err(e) = server.poll_poses(&mut poses) {
            debug!(error = %e, "pose receive failed");
        }
        if pose_source == PoseSourceKind::Ipc {
            for pose in poses.drain(..) {
                // The gate drains this channel every frame; if it is full the oldest poses are
                // the least useful, but losing the newest is acceptable too: count and go on.
                if pose_tx.try_send(pose).is_err() {
                    stats.poses_rejected.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        if Instant::now() >= next_health || upstream_done && stop.load(Ordering::Relaxed) {
            let health = stats.health();
            if let Err(e) = server.publish_health(&health) {
                warn!(error = %e, "health publish failed");
            }
            periods += 1;
            if log_every > 0 && periods.is_multiple_of(log_every) {
                info!(
                    frames = health.frames_captured,
                    keyframes = health.keyframes,
                    graph_version = health.graph_version,
                    map_nodes = health.map_node_count,
                    map_mib = format_args!("{:.1}", crate::stats::mib(health.map_memory_bytes)),
                    "running"
                );
            }
            next_health = Instant::now() + health_period;
        }
        if upstream_done && (stop.load(Ordering::Relaxed) || exit_at_end) {
            // One last health record so watchers see the final counters.
            let _ = server.publish_health(&stats.health());
            break;
        }
    }
}
