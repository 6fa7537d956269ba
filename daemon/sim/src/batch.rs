//! The deterministic batch runner: source → keyframe gate → detector → fusion, synchronously on
//! the calling thread, with no queues, no threads and no iceoryx2. For evaluation and tuning
//! (`op3dsg fusion-eval`, `daemon/sim/tests/it/fusion_quality.rs`), not for serving.
//!
//! It opens the source and the detector with the backends the pipeline uses
//! ([`crate::backends()`]), selects keyframes with the pipeline's [`KeyframeGate`], makes its
//! map with the same backends (or takes a fusion the caller passes), and takes every keyframe
//! through the stage functions the pipeline's threads call ([`perception::detect`],
//! [`fusion::fuse`], [`fusion::map_graph`], [`reasoner::enrich`]) in order, so its final graph
//! is the one the threaded pipeline
//! publishes last when no frame is dropped (`block` queues, as in `profiles/sim-batch.toml`);
//! `daemon/sim/tests/it/batch_determinism.rs` checks this.
//!
//! Besides the graph it counts, per ground-truth instance (synthetic sources only, read from
//! the ground-truth side channel):
//! - **visibility**: in how many keyframes the instance covers at least
//!   [`VisibilityThresholds`] pixels of the instance-id image (what an ideal detector could see);
//! - **detections**: in how many keyframes the oracle detector reported it (its
//!   [`InstanceLog`]; several detections in one keyframe count once).
//!
//! ```no_run
//! let mut profile = op3dsg_sim::load_profile(None, &[]).unwrap().profile;
//! let mut synthetic = op3dsg_sim::backends::synthetic_config(&profile).unwrap();
//! synthetic.frame_count = Some(300);
//! op3dsg_sim::backends::set_synthetic_config(&mut profile, &synthetic);
//! let run = op3dsg_sim::batch::run(&profile, &Default::default()).unwrap();
//! println!("{} keyframes, {} nodes", run.keyframes, run.graph.nodes.len());
//! ```

use std::time::{Duration, Instant};

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::pose::Isometry;
use op3dsg_drivers::source::{FrameSource, SourceError, SourceStatus};
use op3dsg_runtime::backend::OpenedSource;
use op3dsg_runtime::backend::StartError;
use op3dsg_runtime::capture::REPLAY_SOURCE;
use op3dsg_runtime::config::Profile;
use op3dsg_runtime::fusion::{self, Fusion};
use op3dsg_runtime::keyframe::{GateDecision, KeyframeGate, PoseSourceKind};
use op3dsg_runtime::occupancy::{DepthScan, OccupancyGrid};
use op3dsg_runtime::perception::{self, Detection, Detector};
use op3dsg_runtime::pipeline::make_enricher;
use op3dsg_runtime::reasoner::{self, GraphEnricher, Refinement};
use op3dsg_synthetic::{GroundTruth, InstanceKind, Scene};
use tracing::warn;

use crate::backends::{ORACLE_DETECTOR, OracleSetup, SYNTHETIC_SOURCE, ground_truth, synthetic_config};
use crate::oracle::{InstanceLog, PoseNoise};

/// How many pixels of `Frame::instance_ids` make a ground-truth instance count as visible in a
/// keyframe.
///
/// The defaults: 30 px for parts is the oracle detector's own floor (`min_visible_px`), about a
/// 3 cm knob seen from 3 m; 200 px for objects (a 14 x 14 px patch) leaves out slivers at the
/// image border and through gaps, which no detector would report.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct VisibilityThresholds {
    /// Minimum pixels of an object, pixels.
    pub object_min_px: u32,
    /// Minimum pixels of a part, pixels.
    pub part_min_px: u32,
}

impl Default for VisibilityThresholds {
    fn default() -> Self {
        Self { object_min_px: 200, part_min_px: 30 }
    }
}

/// Where the time of a batch run went (wall clock on the calling thread). With several fusions
/// ([`run_with_fusions`]) `fusion` and `build_graph` are each run's own, the rest is shared.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct BatchTiming {
    /// Reading frames from the source (rendering, for the synthetic source).
    pub source: Duration,
    /// The keyframe gate.
    pub gate: Duration,
    /// Detection on keyframes.
    pub detect: Duration,
    /// `Fusion::integrate` on keyframes.
    pub fusion: Duration,
    /// The final `Fusion::build_graph`, with the prior graph and reasoner (`[reasoner]`).
    pub build_graph: Duration,
    /// Counting ground-truth pixels and detections.
    pub ground_truth: Duration,
    /// The whole run, opening the source included.
    pub total: Duration,
}

/// What a batch run produced.
#[derive(Debug, Clone)]
pub struct BatchRun {
    /// The final graph. `version` is the number of keyframes that changed the map (at least 1,
    /// like the pipeline, which publishes an empty graph rather than none); `stamp_ns` is the
    /// newest keyframe's stamp.
    pub graph: op3dsg_runtime::graph::SceneGraph,
    /// The synthetic scene (ground truth), when the source has one.
    pub scene: Option<Scene>,
    /// Frames the source delivered.
    pub frames: u64,
    /// Keyframes fused.
    pub keyframes: u64,
    /// Frames dropped for lack of a pose.
    pub frames_without_pose: u64,
    /// Detections given to fusion (false positives included).
    pub detections: u64,
    /// Keyframes whose detection failed (fused empty, as the pipeline does).
    pub detector_errors: u64,
    /// Indexed by instance id (index 0 unused): keyframes in which the instance was visible
    /// with at least the [`VisibilityThresholds`] pixels. Empty without ground truth.
    pub visible_keyframes: Vec<u32>,
    /// Indexed by instance id: keyframes in which the detector reported the instance. Empty
    /// without ground truth.
    pub detected_keyframes: Vec<u32>,
    /// Nodes in the map at the end, confirmed or not (the graph holds the confirmed ones).
    pub map_nodes: usize,
    /// Heap bytes of the map at the end.
    pub map_memory_bytes: usize,
    /// Where the time went.
    pub timing: BatchTiming,
    /// The occupancy map integrated from every keyframe (`occupancy.enabled`), as the daemon's
    /// occupancy thread builds it ([`op3dsg_runtime::occupancy`]).
    pub occupancy: Option<op3dsg_runtime::occupancy::OccupancyGrid>,
    /// Per keyframe: the cost of subsampling its depth and integrating it into the map,
    /// microseconds (empty without the map).
    pub occupancy_integrate_us: Vec<u32>,
    /// Per keyframe in order (fusion's keyframe counter `i + 1`): its frame's sequence number
    /// and its true camera pose (before any oracle pose noise).
    pub keyframe_poses: Vec<(u64, Isometry)>,
    /// The changes this run's fusion found (`[fusion.change]`), oldest first.
    pub changes: Vec<fusion::change::ChangeEvent>,
}

impl BatchRun {
    /// Keyframes per second over the whole run.
    pub fn keyframes_per_s(&self) -> f64 {
        self.keyframes as f64 / self.timing.total.as_secs_f64().max(1e-9)
    }
}

/// Errors of a batch run.
#[derive(Debug, thiserror::Error)]
pub enum BatchError {
    /// The source or detector could not be opened, or the profile cannot run in batch.
    #[error(transparent)]
    Start(#[from] StartError),
    /// The source never ends.
    #[error(
        "the batch runner needs a finite source: set source.synthetic.frame_count (or run.max_frames) above 0, or \
         turn source.replay.loop off"
    )]
    Unbounded,
    /// The source failed mid-run. The pipeline retries; a batch run stops, because skipping a
    /// frame would make the result depend on the failure.
    #[error("source failed after {frames} frames: {error}")]
    Source {
        /// Frames delivered before the failure.
        frames: u64,
        /// What failed.
        error: SourceError,
    },
}

/// Runs `profile` with the fusion the pipeline would make (`fusion.method`).
pub fn run(profile: &Profile, visibility: &VisibilityThresholds) -> Result<BatchRun, BatchError> {
    run_with_fusion(profile, visibility, crate::backends().fusion(profile)?)
}

/// Runs `profile` with `fusion` instead of the profile's (ablations, alternative fusions).
pub fn run_with_fusion(
    profile: &Profile,
    visibility: &VisibilityThresholds,
    fusion: Box<dyn Fusion>,
) -> Result<BatchRun, BatchError> {
    let [run] = run_with_fusions(profile, visibility, [fusion])?;
    Ok(run)
}

/// Runs `profile` once and feeds every keyframe with its detections to each of `fusions` in
/// turn: one run per fusion, in order, identical but for `graph` and the fusion timings. An
/// ablation costs one rendering and detection pass instead of one per variant, and every
/// variant sees exactly the same input.
pub fn run_with_fusions<const N: usize>(
    profile: &Profile,
    visibility: &VisibilityThresholds,
    fusions: [Box<dyn Fusion>; N],
) -> Result<[BatchRun; N], BatchError> {
    let lane = Lane { detector: None, fusions: fusions.into() };
    let runs = run_lanes(profile, visibility, vec![lane])?.pop().unwrap_or_default();
    runs.try_into().map_err(|runs: Vec<BatchRun>| {
        BatchError::Start(StartError::Incompatible {
            field: "batch",
            reason: format!("{} runs came back for {N} fusions", runs.len()),
        })
    })
}

/// One detector and the fusions its detections feed, for [`run_lanes`].
pub struct Lane {
    /// The profile whose `[detector]` this lane runs; `None`: the run's own.
    pub detector: Option<Profile>,
    /// Fusions fed with this detector's detections, in order.
    pub fusions: Vec<Box<dyn Fusion>>,
}

impl std::fmt::Debug for Lane {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Lane")
            .field("detector", &self.detector.as_ref().map(|p| p.detector.kind.clone()))
            .field("fusions", &self.fusions.len())
            .finish()
    }
}

/// The detector `profile` makes for worker 0 over `source`, and, for the oracle, the log of the
/// ground-truth instance behind each detection.
fn make_detector(
    profile: &Profile,
    source: &OpenedSource,
    truth: Option<&GroundTruth>,
) -> Result<(Box<dyn Detector>, Option<InstanceLog>), BatchError> {
    if profile.detector.kind == ORACLE_DETECTOR && truth.is_some() {
        // The oracle the backend would make, with a log of where each detection came from.
        let log = InstanceLog::new();
        let detector = OracleSetup::new(profile, truth)?.detector(0).with_instance_log(log.clone());
        return Ok((Box::new(detector), Some(log)));
    }
    let factory = crate::backends().detector(&profile.detector.kind)?.prepare(profile, source)?;
    Ok((factory(0), None))
}

/// The oracle's pose drift and jitter for a lane of `profile` (`detector.oracle.pose_*`), `None`
/// without them or with another detector.
fn lane_pose_noise(profile: &Profile) -> Result<Option<PoseNoise>, BatchError> {
    if profile.detector.kind != ORACLE_DETECTOR {
        return Ok(None);
    }
    Ok(PoseNoise::new(&crate::backends::oracle_config(profile)?))
}

/// Runs `profile`'s source and keyframe gate once and feeds every keyframe to each lane: the
/// lane's detector, then each of its fusions. One [`BatchRun`] per fusion, grouped by lane:
/// variants that differ in detector or fusion see exactly the same keyframes, rendered once.
///
/// Sources that can preview a frame's pose
/// ([`op3dsg_drivers::source::FrameSource::peek_pose`], the synthetic one)
/// only produce the pixels of keyframes; the result is the same as producing every frame.
pub fn run_lanes(
    profile: &Profile,
    visibility: &VisibilityThresholds,
    mut lanes: Vec<Lane>,
) -> Result<Vec<Vec<BatchRun>>, BatchError> {
    let started = Instant::now();
    refuse_unbounded(profile)?;
    let backends = crate::backends();
    let mut opened = backends.source(&profile.source.kind)?.open(profile)?;
    let truth = ground_truth(&opened);
    let scene = truth.as_ref().map(|t| t.scene.clone());
    let mut enricher = make_enricher(profile)?;
    if let Some(enricher) = enricher.as_mut() {
        enricher.set_synchronous(true);
    }
    let llm_wait = llm_refresh_wait(profile);
    refuse_without_poses(profile, &opened)?;
    let mut instances = InstanceCounts::new(scene.as_ref(), visibility);
    let mut lane_runs = Vec::with_capacity(lanes.len());
    for lane in &mut lanes {
        lane_runs.push(LaneRun::new(profile, lane, &opened, truth.as_deref(), instances.id_count())?);
    }
    let source = opened.source.as_mut();
    let mut occupancy = OccupancyRun::new(profile, &source.intrinsics());
    let mut frame = Frame::new(source.intrinsics());
    let mut keyframes = KeyframeReader::new(source, profile);
    let mut timing = BatchTiming::default();
    let mut detections = Vec::new();
    let mut keyframe_poses = Vec::new();
    while let Some(world_from_camera) = keyframes.next_keyframe(&mut frame, &mut timing)? {
        keyframe_poses.push((frame.seq, world_from_camera));
        occupancy.integrate(&frame, &world_from_camera);
        if instances.id_count() > 0 {
            let t = Instant::now();
            instances.count_visible(truth.as_deref(), &frame);
            timing.ground_truth += t.elapsed();
        }
        for (lane, lane_run) in lanes.iter_mut().zip(&mut lane_runs) {
            lane_run.keyframe(lane, &frame, &world_from_camera, &mut detections);
            if instances.id_count() > 0
                && let Some(log) = &lane_run.instance_log
            {
                let t = Instant::now();
                instances.count_detected(log, &mut lane_run.detected_keyframes);
                timing.ground_truth += t.elapsed();
            }
        }
    }

    let totals = RunTotals {
        started,
        scene,
        counts: keyframes.counts,
        visible_keyframes: instances.visible_keyframes,
        occupancy,
        timing,
        keyframe_poses,
    };
    let mut out = Vec::with_capacity(lanes.len());
    for (lane, lane_run) in lanes.iter_mut().zip(&lane_runs) {
        out.push(totals.lane_results(lane, lane_run, enricher.as_mut(), llm_wait));
    }
    Ok(out)
}

/// [`BatchError::Unbounded`] unless the source ends or `run.max_frames` stops it.
fn refuse_unbounded(profile: &Profile) -> Result<(), BatchError> {
    let unbounded = match profile.source.kind.as_str() {
        SYNTHETIC_SOURCE => synthetic_config(profile)?.frame_count.is_none_or(|n| n == 0),
        // A recording ends unless it loops.
        REPLAY_SOURCE => profile.source.replay.as_ref().is_some_and(|r| r.looping),
        _ => true,
    };
    if profile.run.max_frames == 0 && unbounded {
        return Err(BatchError::Unbounded);
    }
    Ok(())
}

/// Batch runs await the LLM refiner (when configured): the longest one refresh can take.
fn llm_refresh_wait(profile: &Profile) -> Duration {
    let llm = &profile.reasoner.llm;
    Duration::from_secs_f64((llm.request_timeout_s + llm.backoff_max_s) * f64::from(llm.max_retries + 1) + 1.0)
}

/// The batch runner takes poses from the frames only: the profile must say so and the source
/// must carry them.
fn refuse_without_poses(profile: &Profile, opened: &OpenedSource) -> Result<(), BatchError> {
    if profile.pose.source != PoseSourceKind::Frame {
        return Err(StartError::Incompatible {
            field: "pose.source",
            reason: "the batch runner has no pose input; use \"frame\" with a source that carries poses".to_owned(),
        }
        .into());
    }
    if !opened.source.has_poses() {
        return Err(StartError::Incompatible {
            field: "pose.source",
            reason: format!("{} carries no poses", opened.source.describe()),
        }
        .into());
    }
    Ok(())
}

/// Frames the source delivered and what the gate made of them.
#[derive(Debug, Clone, Copy, Default)]
struct FrameCounts {
    frames: u64,
    keyframes: u64,
    frames_without_pose: u64,
    /// The newest keyframe's stamp.
    stamp_ns: u64,
}

/// The source behind the keyframe gate: hands out keyframes only, and counts frames.
struct KeyframeReader<'a> {
    source: &'a mut dyn FrameSource,
    gate: KeyframeGate,
    /// `run.max_frames` (0: until the source ends).
    max_frames: u64,
    counts: FrameCounts,
}

impl<'a> KeyframeReader<'a> {
    fn new(source: &'a mut dyn FrameSource, profile: &Profile) -> Self {
        Self {
            source,
            gate: KeyframeGate::new(&profile.keyframe, &profile.pose),
            max_frames: profile.run.max_frames,
            counts: FrameCounts::default(),
        }
    }

    /// Reads frames into `frame` until the gate takes one: its `world_from_camera`, or `None`
    /// at the end of the source or after `max_frames` frames.
    fn next_keyframe(&mut self, frame: &mut Frame, timing: &mut BatchTiming) -> Result<Option<Isometry>, BatchError> {
        loop {
            if self.max_frames > 0 && self.counts.frames >= self.max_frames {
                return Ok(None);
            }
            let t = Instant::now();
            // Preview the pose first where the source can: only keyframes are rendered.
            let previewed = self.source.peek_pose(frame);
            let status = match previewed {
                Some(status) => status,
                None => self.next_frame(frame)?,
            };
            timing.source += t.elapsed();
            match status {
                SourceStatus::Frame => self.counts.frames += 1,
                SourceStatus::Pending => {
                    std::thread::sleep(Duration::from_millis(1));
                    continue;
                }
                SourceStatus::EndOfStream => return Ok(None),
            }

            let t = Instant::now();
            let decision = self.gate.decide(frame);
            timing.gate += t.elapsed();
            let world_from_camera = match decision {
                GateDecision::NoPose => {
                    self.counts.frames_without_pose += 1;
                    if previewed.is_some() {
                        self.source.skip_frame();
                    }
                    continue;
                }
                GateDecision::Skip => {
                    if previewed.is_some() {
                        self.source.skip_frame();
                    }
                    continue;
                }
                GateDecision::Keyframe(world_from_camera) => world_from_camera,
            };
            if previewed.is_some() {
                let t = Instant::now();
                let status = self.next_frame(frame)?;
                timing.source += t.elapsed();
                if status != SourceStatus::Frame {
                    return Err(BatchError::Source {
                        frames: self.counts.frames,
                        error: SourceError::Frame { seq: frame.seq, reason: "previewed but not delivered".to_owned() },
                    });
                }
            }
            self.counts.keyframes += 1;
            self.counts.stamp_ns = self.counts.stamp_ns.max(frame.stamp_ns);
            return Ok(Some(world_from_camera));
        }
    }

    fn next_frame(&mut self, frame: &mut Frame) -> Result<SourceStatus, BatchError> {
        let frames = self.counts.frames;
        self.source.next_frame(frame).map_err(|error| BatchError::Source { frames, error })
    }
}

/// The occupancy map integrated from every keyframe, as the daemon's occupancy thread builds it,
/// and what each integration cost.
struct OccupancyRun {
    grid: Option<OccupancyGrid>,
    depth_scan: DepthScan,
    integrate_us: Vec<u32>,
}

impl OccupancyRun {
    fn new(profile: &Profile, intrinsics: &Intrinsics) -> Self {
        let occ = &profile.occupancy;
        let grid = occ
            .enabled
            .then(|| OccupancyGrid::new(occ, profile.world.up_axis, profile.navigation.robot_radius_m, intrinsics));
        Self { grid, depth_scan: DepthScan::with_capacity(intrinsics, occ.pixel_stride), integrate_us: Vec::new() }
    }

    fn integrate(&mut self, frame: &Frame, world_from_camera: &Isometry) {
        let Some(grid) = self.grid.as_mut() else { return };
        let t = Instant::now();
        self.depth_scan.fill(
            &frame.depth,
            &frame.intrinsics,
            frame.depth_units_per_m,
            world_from_camera,
            frame.stamp_ns,
        );
        grid.integrate(&self.depth_scan);
        self.integrate_us.push(t.elapsed().as_micros().min(u128::from(u32::MAX)) as u32);
    }
}

/// Ground-truth bookkeeping, indexed by instance id (none without ground truth).
struct InstanceCounts {
    /// Per instance, its kind's pixel threshold.
    min_px: Vec<u32>,
    /// Scratch: the current keyframe's pixels per instance.
    pixels: Vec<u32>,
    /// Scratch: whether the current keyframe's detections hold the instance.
    detected_now: Vec<bool>,
    /// Keyframes in which the instance was visible.
    visible_keyframes: Vec<u32>,
}

impl InstanceCounts {
    fn new(scene: Option<&Scene>, visibility: &VisibilityThresholds) -> Self {
        let id_count = scene.map_or(0, |s| s.instances().iter().map(|i| usize::from(i.id)).max().unwrap_or(0) + 1);
        let mut min_px = vec![u32::MAX; id_count];
        if let Some(scene) = scene {
            for info in scene.instances() {
                min_px[usize::from(info.id)] = match info.kind {
                    InstanceKind::Object => visibility.object_min_px,
                    InstanceKind::Part => visibility.part_min_px,
                };
            }
        }
        Self {
            min_px,
            pixels: vec![0; id_count],
            detected_now: vec![false; id_count],
            visible_keyframes: vec![0; id_count],
        }
    }

    /// Instance ids counted, 0 without ground truth.
    fn id_count(&self) -> usize {
        self.min_px.len()
    }

    /// Counts the instances `frame`'s instance-id image shows with enough pixels.
    fn count_visible(&mut self, truth: Option<&GroundTruth>, frame: &Frame) {
        let pixels = &mut self.pixels;
        let counted = truth.and_then(|truth| {
            truth.instance_ids.with_ids(frame, |ids| {
                pixels.fill(0);
                for &id in ids {
                    if let Some(count) = pixels.get_mut(usize::from(id)) {
                        *count += 1;
                    }
                }
            })
        });
        if counted.is_some() {
            for ((visible, count), min) in self.visible_keyframes.iter_mut().zip(&self.pixels).zip(&self.min_px) {
                *visible += u32::from(*count >= *min);
            }
        }
    }

    /// Adds one to `detected_keyframes` for each instance the keyframe's detections (`log`) hold.
    fn count_detected(&mut self, log: &InstanceLog, detected_keyframes: &mut [u32]) {
        let detected_now = &mut self.detected_now;
        detected_now.fill(false);
        log.with(|instances| {
            for id in instances.iter().flatten() {
                if let Some(flag) = detected_now.get_mut(usize::from(*id)) {
                    *flag = true;
                }
            }
        });
        for (count, now) in detected_keyframes.iter_mut().zip(&self.detected_now) {
            *count += u32::from(*now);
        }
    }
}

/// A lane's detector, and what the lane and each of its fusions counted.
struct LaneRun {
    detector: Box<dyn Detector>,
    /// The oracle's log of the instance behind each detection.
    instance_log: Option<InstanceLog>,
    /// The oracle's pose drift and jitter.
    pose_noise: Option<PoseNoise>,
    detections: u64,
    detector_errors: u64,
    detect_time: Duration,
    /// Indexed by instance id.
    detected_keyframes: Vec<u32>,
    /// Per fusion: keyframes that changed its map.
    changed_keyframes: Vec<u64>,
    /// Per fusion.
    fusion_time: Vec<Duration>,
}

impl LaneRun {
    /// Takes the lane's detector profile (`None`: `profile`) and makes its detector.
    fn new(
        profile: &Profile,
        lane: &mut Lane,
        source: &OpenedSource,
        truth: Option<&GroundTruth>,
        id_count: usize,
    ) -> Result<Self, BatchError> {
        let lane_profile = lane.detector.take();
        let lane_profile = lane_profile.as_ref().unwrap_or(profile);
        let (detector, instance_log) = make_detector(lane_profile, source, truth)?;
        Ok(Self {
            detector,
            instance_log,
            pose_noise: lane_pose_noise(lane_profile)?,
            detections: 0,
            detector_errors: 0,
            detect_time: Duration::ZERO,
            detected_keyframes: vec![0; id_count],
            changed_keyframes: vec![0; lane.fusions.len()],
            fusion_time: vec![Duration::ZERO; lane.fusions.len()],
        })
    }

    /// Detects on the keyframe (into `detections`) and fuses the detections into each of the
    /// lane's fusions.
    fn keyframe(
        &mut self,
        lane: &mut Lane,
        frame: &Frame,
        world_from_camera: &Isometry,
        detections: &mut Vec<Detection>,
    ) {
        let t = Instant::now();
        if let Err(e) = perception::detect(self.detector.as_mut(), frame, detections) {
            // As the pipeline does: the keyframe is fused empty.
            warn!(frame_seq = frame.seq, error = %e, "detection failed; keyframe fused empty");
            self.detector_errors += 1;
        }
        self.detect_time += t.elapsed();
        // The pose this lane's fusions are given: the true one, or with the oracle's pose noise.
        let lane_pose = self.pose_noise.as_mut().map_or(*world_from_camera, |n| n.apply(world_from_camera));
        for ((fusion, changed), time) in
            lane.fusions.iter_mut().zip(&mut self.changed_keyframes).zip(&mut self.fusion_time)
        {
            let t = Instant::now();
            let fused = fusion::fuse(fusion.as_mut(), frame, &lane_pose, detections);
            *time += t.elapsed();
            *changed += u64::from(fused.changed());
        }
        self.detections += detections.len() as u64;
    }
}

/// What every lane's runs share once the source has ended.
struct RunTotals {
    started: Instant,
    scene: Option<Scene>,
    counts: FrameCounts,
    visible_keyframes: Vec<u32>,
    occupancy: OccupancyRun,
    /// Source, gate and ground-truth times; the lanes add their own.
    timing: BatchTiming,
    keyframe_poses: Vec<(u64, Isometry)>,
}

impl RunTotals {
    /// One [`BatchRun`] per fusion of `lane`: its final graph, enriched as the pipeline does.
    fn lane_results(
        &self,
        lane: &mut Lane,
        lane_run: &LaneRun,
        mut enricher: Option<&mut GraphEnricher>,
        llm_wait: Duration,
    ) -> Vec<BatchRun> {
        let mut runs = Vec::with_capacity(lane.fusions.len());
        for (i, fusion) in lane.fusions.iter_mut().enumerate() {
            let t = Instant::now();
            let mut graph =
                fusion::map_graph(fusion.as_ref(), lane_run.changed_keyframes[i].max(1), self.counts.stamp_ns);
            if let Some(enricher) = enricher.as_deref_mut() {
                reasoner::enrich(enricher, &mut graph, Refinement::Await(llm_wait));
            }
            let mut changes = Vec::new();
            fusion.take_changes(&mut changes);
            let timing = BatchTiming {
                detect: lane_run.detect_time,
                fusion: lane_run.fusion_time[i],
                build_graph: t.elapsed(),
                total: self.started.elapsed(),
                ..self.timing
            };
            runs.push(BatchRun {
                graph,
                scene: self.scene.clone(),
                frames: self.counts.frames,
                keyframes: self.counts.keyframes,
                frames_without_pose: self.counts.frames_without_pose,
                detections: lane_run.detections,
                detector_errors: lane_run.detector_errors,
                visible_keyframes: self.visible_keyframes.clone(),
                detected_keyframes: lane_run.detected_keyframes.clone(),
                map_nodes: fusion.node_count(),
                map_memory_bytes: fusion.memory_bytes(),
                timing,
                occupancy: self.occupancy.grid.clone(),
                occupancy_integrate_us: self.occupancy.integrate_us.clone(),
                keyframe_poses: self.keyframe_poses.clone(),
                changes,
            });
        }
        runs
    }
}

#[cfg(test)]
mod tests;
