//! The pipeline's counters: each stage's own, held together for the health record, the service's
//! status line and the run summary. The publisher reads them only through [`HealthSource`].

use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::Instant;

use op3dsg_ipc_types::{Health, write_fixed_str};

use crate::capture::CaptureCounters;
use crate::fusion::FusionCounters;
use crate::keyframe::KeyframeCounters;
use crate::live_view::LiveViewCounters;
use crate::perception::remote::RemoteCounters;
use crate::publish::PublishCounters;
use crate::queue::QueueStats;
use crate::reasoner::llm::RefinerStats;
use crate::record::RecorderStats;
use crate::ros2::{Ros2OutputCounters, TfInputCounters};
use crate::stats::{HealthSource, Liveness, ReportHealth, StageStats};
use crate::zenoh::ZenohCounters;

/// Every stage's counters of one pipeline.
#[derive(Debug)]
pub struct Counters {
    started: Instant,
    /// Capture: frames, the source's state.
    pub capture: Arc<CaptureCounters>,
    /// The keyframe gate: keyframes, frames without a pose, the pose input.
    pub keyframe: Arc<KeyframeCounters>,
    /// One stage entry per detection worker (`detect/<i>`).
    pub detect: Vec<Arc<StageStats>>,
    /// Fusion: the map, its versions, snapshots.
    pub fusion: Arc<FusionCounters>,
    /// The publisher and the end-to-end latency.
    pub publish: Arc<PublishCounters>,
    /// The queues between stages, in pipeline order.
    pub queues: Vec<Arc<QueueStats>>,
    /// The LLM refiner (state `off` without `reasoner.kind = "llm"`).
    pub refiner: Arc<RefinerStats>,
    /// The MCAP recorder (state `off` without `[record] enabled`).
    pub recorder: Arc<RecorderStats>,
    /// Heartbeats of the stages the systemd watchdog watches (`crate::service::notify`).
    pub liveness: Arc<Liveness>,
    /// The Zenoh stage (`None` without `[zenoh] enabled`).
    pub zenoh: Option<Arc<ZenohCounters>>,
    /// The tf input (`None` unless `pose.source = "ros2"`).
    pub ros2_tf: Option<Arc<TfInputCounters>>,
    /// The ROS output (`None` unless a topic of `[ros2.out]` is on).
    pub ros2_out: Option<Arc<Ros2OutputCounters>>,
    /// The Foxglove live view (`None` without `[live_view] enabled`).
    pub live_view: Option<Arc<LiveViewCounters>>,
    /// Remote detection (`None` unless the detectors send keyframes to remote workers).
    pub remote: Option<Arc<RemoteCounters>>,
}

impl Counters {
    /// Zeroed counters for a pipeline with `workers` detection workers, the queues' `queues` and
    /// the LLM refiner's `refiner`.
    pub fn new(workers: usize, queues: Vec<Arc<QueueStats>>, refiner: Arc<RefinerStats>) -> Self {
        Self {
            started: Instant::now(),
            capture: Arc::default(),
            keyframe: Arc::default(),
            detect: (0..workers).map(|i| Arc::new(StageStats::new(format!("detect/{i}")))).collect(),
            fusion: Arc::default(),
            publish: Arc::default(),
            queues,
            refiner,
            recorder: Arc::default(),
            liveness: Arc::default(),
            zenoh: None,
            ros2_tf: None,
            ros2_out: None,
            live_view: None,
            remote: None,
        }
    }

    /// One entry per stage, in pipeline order: `capture`, `keyframe`, `detect/0..N-1`, `fusion`,
    /// `prior` (prior graph + reasoner, on the fusion thread), `publish`, and `end_to_end` (not a
    /// thread: from a keyframe's capture to the send of the first graph holding it), then
    /// `zenoh`, `ros2_tf`, `ros2_out` and `live_view` when those stages are on.
    pub fn stages(&self) -> Vec<Arc<StageStats>> {
        let mut stages = vec![self.capture.stage.clone(), self.keyframe.stage.clone()];
        stages.extend(self.detect.iter().cloned());
        stages.extend([
            self.fusion.stage.clone(),
            self.fusion.prior.clone(),
            self.publish.stage.clone(),
            self.publish.end_to_end.clone(),
        ]);
        stages.extend(self.zenoh.as_ref().map(|z| z.stage.clone()));
        stages.extend(self.ros2_tf.as_ref().map(|t| t.stage.clone()));
        stages.extend(self.ros2_out.as_ref().map(|o| o.stage.clone()));
        stages.extend(self.live_view.as_ref().map(|l| l.stage.clone()));
        stages
    }

    /// Seconds since the pipeline started.
    pub fn uptime_s(&self) -> f64 {
        self.started.elapsed().as_secs_f64()
    }
}

impl HealthSource for Counters {
    fn health(&self) -> Health {
        let mut h = Health { stamp_ns: crate::world::clock::wall_clock_ns(), ..Health::default() };
        h.uptime_ns = self.started.elapsed().as_nanos() as u64;
        let reporters: [&dyn ReportHealth; 3] = [&*self.capture, &*self.keyframe, &*self.fusion];
        for reporter in reporters {
            reporter.report(&mut h);
        }
        let stages = self.stages();
        for (slot, stage) in h.stages.iter_mut().zip(&stages) {
            let f = stage.take_figures();
            write_fixed_str(&mut slot.name, &stage.name);
            slot.processed = f.processed;
            slot.rate_hz = f.rate_hz;
            slot.latency_p50_us = f.p50_us;
            slot.latency_p99_us = f.p99_us;
            slot.errors = f.errors.min(u32::MAX as u64) as u32;
        }
        h.stage_count = stages.len().min(h.stages.len()) as u32;
        for (slot, q) in h.queues.iter_mut().zip(&self.queues) {
            write_fixed_str(&mut slot.name, q.name);
            slot.depth = q.depth() as u32;
            slot.capacity = q.capacity as u32;
            slot.dropped = q.dropped.load(Ordering::Relaxed);
            slot.pushed = q.pushed.load(Ordering::Relaxed);
        }
        h.queue_count = self.queues.len().min(h.queues.len()) as u32;
        h.refiner = self.refiner.health();
        h.recorder = self.recorder.health();
        h.model_count = crate::onnx::fill_model_health(&mut h.models) as u32;
        if let Some(tf) = &self.ros2_tf {
            h.tf = tf.health();
        }
        if let Some(remote) = &self.remote {
            h.remote = remote.health();
        }
        h
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
    /// The summary of `counters` now.
    pub fn of(counters: &Counters) -> Self {
        let load = |c: &std::sync::atomic::AtomicU64| c.load(Ordering::Relaxed);
        Self {
            frames: load(&counters.capture.frames_captured),
            keyframes: load(&counters.keyframe.keyframes),
            graph_version: load(&counters.fusion.graph_version),
            map_nodes: load(&counters.fusion.map_node_count),
            map_memory_bytes: load(&counters.fusion.map_memory_bytes),
            elapsed_s: counters.uptime_s(),
            bad_data_skipped: load(&counters.capture.source_bad_data_skipped),
            source_failed: counters.capture.source_failed.load(Ordering::Relaxed),
        }
    }

    /// Keyframes per second over the run.
    pub fn keyframes_per_s(&self) -> f64 {
        self.keyframes as f64 / self.elapsed_s.max(1e-9)
    }
}

#[cfg(test)]
mod tests {
    use op3dsg_ipc_types::PoseHealth;

    use super::*;
    use crate::ipc::PoseCheckCounts;
    use crate::keyframe::{PoseRefusal, count_gate};
    use crate::publish::add_wire_checks;

    fn counters_with_workers(workers: usize) -> Counters {
        Counters::new(workers, Vec::new(), Arc::default())
    }

    #[test]
    fn every_stage_of_the_largest_profile_is_reported() {
        let workers = op3dsg_ipc_types::MAX_WORKERS;
        let health = counters_with_workers(workers).health();
        assert_eq!(health.stage_count as usize, workers + 6);
        let names: Vec<&str> = health.valid_stages().iter().map(|s| op3dsg_ipc_types::fixed_str(&s.name)).collect();
        assert_eq!(names[2 + workers - 1], "detect/63");
        assert_eq!(names.last(), Some(&"end_to_end"));
    }

    #[test]
    fn pose_outcomes_land_in_their_own_counters() {
        let counters = counters_with_workers(1);
        let pose = &counters.keyframe.pose;
        let mut reported = PoseCheckCounts::default();
        add_wire_checks(
            pose,
            &PoseCheckCounts { unknown_kind: 1, non_finite: 2, non_unit_quaternion: 0 },
            &mut reported,
        );
        // Cumulative counts: only what is new since the last call is added.
        add_wire_checks(
            pose,
            &PoseCheckCounts { unknown_kind: 1, non_finite: 3, non_unit_quaternion: 1 },
            &mut reported,
        );
        count_gate(pose, Ok(()));
        count_gate(pose, Err(PoseRefusal::Future));
        count_gate(pose, Err(PoseRefusal::UnknownKind));
        assert_eq!(
            counters.health().pose,
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
