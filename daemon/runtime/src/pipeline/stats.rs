//! The counters every stage shares and the health record made from them.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Instant;

use op3dsg_ipc_types::{Health, write_fixed_str};

use crate::queue::QueueStats;
use crate::reasoner::llm::RefinerStats;
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

    pub(crate) fn stage(&self, name: &str) -> Arc<StageStats> {
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
