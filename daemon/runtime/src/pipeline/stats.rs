//! The counters every stage shares and the health record made from them.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Instant;

use op3dsg_ipc_types::{Health, PoseHealth, write_fixed_str};

use crate::ipc::PoseCheckCounts;
use crate::keyframe::PoseRefusal;

use crate::queue::QueueStats;
use crate::reasoner::llm::RefinerStats;
use crate::record::RecorderStats;
use crate::stats::StageStats;

/// Counters shared by every stage and read by the health reporter.
#[derive(Debug)]
pub struct PipelineStats {
    pub(super) started: Instant,
    /// Frames the source delivered.
    pub frames_captured: AtomicU64,
    /// Frames dropped at capture because every pooled frame was in flight.
    pub frames_pool_exhausted: AtomicU64,
    /// Frames accepted as keyframes.
    pub keyframes: AtomicU64,
    /// Frames dropped for lack of a pose within tolerance.
    pub frames_without_pose: AtomicU64,
    /// The pose input by outcome (published as [`Health::pose`]).
    pub pose: PoseStats,
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
    /// Heartbeats of the stages the systemd watchdog watches (`crate::service::notify`).
    pub liveness: crate::service::Liveness,
    /// Map snapshots written (`crate::service::snapshot`).
    pub snapshot: crate::service::snapshot::SnapshotStats,
    /// The MCAP recorder (state `off` without `[record] enabled`).
    pub recorder: Arc<RecorderStats>,
}

impl PipelineStats {
    /// Zeroed counters for a pipeline with `workers` detection workers: one stage entry each for
    /// capture, the keyframe gate, every worker (`detect/<i>`), fusion, prior, publish and
    /// `end_to_end` (not a thread: from a keyframe's capture to the send of the first graph
    /// holding it), in pipeline order.
    pub(crate) fn new(workers: usize, queues: Vec<Arc<QueueStats>>, refiner: Arc<RefinerStats>) -> Self {
        let mut stages = vec![Arc::new(StageStats::new("capture")), Arc::new(StageStats::new("keyframe"))];
        stages.extend((0..workers).map(|i| Arc::new(StageStats::new(format!("detect/{i}")))));
        stages.extend(["fusion", "prior", "publish", "end_to_end"].map(|name| Arc::new(StageStats::new(name))));
        Self {
            started: Instant::now(),
            frames_captured: AtomicU64::new(0),
            frames_pool_exhausted: AtomicU64::new(0),
            keyframes: AtomicU64::new(0),
            frames_without_pose: AtomicU64::new(0),
            pose: PoseStats::default(),
            detections_fused: AtomicU64::new(0),
            graph_version: AtomicU64::new(0),
            map_node_count: AtomicU64::new(0),
            map_memory_bytes: AtomicU64::new(0),
            source_connected: AtomicBool::new(true),
            source_finished: AtomicBool::new(false),
            source_bad_data_skipped: AtomicU64::new(0),
            source_failed: AtomicBool::new(false),
            stages,
            queues,
            refiner,
            liveness: crate::service::Liveness::default(),
            snapshot: crate::service::snapshot::SnapshotStats::default(),
            recorder: Arc::new(RecorderStats::default()),
        }
    }

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
        h.pose = self.pose.health();
        h.recorder = self.recorder.health();
        h.snapshot = self.snapshot.health();
        h.model_count = crate::onnx::fill_model_health(&mut h.models) as u32;
        h
    }

    pub(crate) fn stage(&self, name: &str) -> Arc<StageStats> {
        // Stages are created in `start`; a missing name is a programming error caught by tests.
        self.stages.iter().find(|s| s.name == name).cloned().unwrap_or_else(|| Arc::new(StageStats::new(name)))
    }
}

/// The pose input's counters, one per outcome ([`PoseHealth`] documents each). The publisher
/// thread adds the wire-check counts (it checks every received pose), the keyframe thread the
/// gate's outcomes.
#[derive(Debug, Default)]
pub struct PoseStats {
    /// Adopted by the keyframe gate.
    pub accepted: AtomicU64,
    /// Unknown `kind`.
    pub unknown_kind: AtomicU64,
    /// NaN or infinite components.
    pub non_finite: AtomicU64,
    /// Quaternion norm off 1.
    pub non_unit_quaternion: AtomicU64,
    /// `world_from_base` without `pose.base_from_camera`.
    pub no_base_from_camera: AtomicU64,
    /// Older than the newest adopted pose.
    pub out_of_order: AtomicU64,
    /// Older than the newest frame by more than the tolerance.
    pub stale: AtomicU64,
    /// Too far after the newest frame.
    pub future: AtomicU64,
    /// Hand-over queue to the gate full.
    pub queue_full: AtomicU64,
}

impl PoseStats {
    /// Counts one of the gate's outcomes.
    pub fn count_gate(&self, outcome: Result<(), PoseRefusal>) {
        let counter = match outcome {
            Ok(()) => &self.accepted,
            Err(PoseRefusal::UnknownKind) => &self.unknown_kind,
            Err(PoseRefusal::NoBaseFromCamera) => &self.no_base_from_camera,
            Err(PoseRefusal::OutOfOrder) => &self.out_of_order,
            Err(PoseRefusal::Stale) => &self.stale,
            Err(PoseRefusal::Future) => &self.future,
        };
        counter.fetch_add(1, Ordering::Relaxed);
    }

    /// Adds the receiver's wire-check counts that are new since `reported`, and remembers them
    /// there.
    pub fn add_checks(&self, checks: &PoseCheckCounts, reported: &mut PoseCheckCounts) {
        let add = |counter: &AtomicU64, now: u64, before: &mut u64| {
            counter.fetch_add(now.saturating_sub(*before), Ordering::Relaxed);
            *before = now;
        };
        add(&self.unknown_kind, checks.unknown_kind, &mut reported.unknown_kind);
        add(&self.non_finite, checks.non_finite, &mut reported.non_finite);
        add(&self.non_unit_quaternion, checks.non_unit_quaternion, &mut reported.non_unit_quaternion);
    }

    /// The wire form.
    pub fn health(&self) -> PoseHealth {
        let load = |c: &AtomicU64| c.load(Ordering::Relaxed);
        PoseHealth {
            accepted: load(&self.accepted),
            unknown_kind: load(&self.unknown_kind),
            non_finite: load(&self.non_finite),
            non_unit_quaternion: load(&self.non_unit_quaternion),
            no_base_from_camera: load(&self.no_base_from_camera),
            out_of_order: load(&self.out_of_order),
            stale: load(&self.stale),
            future: load(&self.future),
            queue_full: load(&self.queue_full),
            reserved: [0; 3],
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn stats_with_workers(workers: usize) -> PipelineStats {
        PipelineStats::new(workers, Vec::new(), Arc::default())
    }

    #[test]
    fn every_stage_of_the_largest_profile_is_reported() {
        let workers = op3dsg_ipc_types::MAX_WORKERS;
        let health = stats_with_workers(workers).health();
        assert_eq!(health.stage_count as usize, workers + 6);
        let names: Vec<&str> = health.valid_stages().iter().map(|s| op3dsg_ipc_types::fixed_str(&s.name)).collect();
        assert_eq!(names[2 + workers - 1], "detect/63");
        assert_eq!(names.last(), Some(&"end_to_end"));
    }

    #[test]
    fn pose_outcomes_land_in_their_own_counters() {
        let stats = stats_with_workers(1);
        let mut reported = PoseCheckCounts::default();
        stats
            .pose
            .add_checks(&PoseCheckCounts { unknown_kind: 1, non_finite: 2, non_unit_quaternion: 0 }, &mut reported);
        // Cumulative counts: only what is new since the last call is added.
        stats
            .pose
            .add_checks(&PoseCheckCounts { unknown_kind: 1, non_finite: 3, non_unit_quaternion: 1 }, &mut reported);
        stats.pose.count_gate(Ok(()));
        stats.pose.count_gate(Err(PoseRefusal::Future));
        stats.pose.count_gate(Err(PoseRefusal::UnknownKind));
        let pose = stats.health().pose;
        assert_eq!(
            pose,
            PoseHealth {
                accepted: 1,
                unknown_kind: 2,
                non_finite: 3,
                non_unit_quaternion: 1,
                future: 1,
                ..PoseHealth::default()
            }
        );
    }
}
