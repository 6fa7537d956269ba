//! [`HealthReport`]: a [`Health`] record in owned, serialisable form with its stages, queues and
//! LLM refiner ([`StageReport`], [`QueueReport`], [`RefinerReport`]), as `op3dsg health --json`
//! prints it.

use op3dsg_ipc_types::Health;
use serde::{Deserialize, Serialize};

/// A [`Health`] record in owned, serialisable form (`op3dsg health --json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HealthReport {
    /// Wire-contract version of the record.
    pub schema_version: u32,
    /// Wall-clock time of the record, nanoseconds since the Unix epoch.
    pub stamp_ns: u64,
    /// Seconds since the daemon started.
    pub uptime_s: f64,
    /// Frames delivered by the source since start.
    pub frames_captured: u64,
    /// Frames accepted by the keyframe gate.
    pub keyframes: u64,
    /// Frames dropped for lack of a pose.
    pub frames_without_pose: u64,
    /// Detections fused since start.
    pub detections_fused: u64,
    /// Current graph version.
    pub graph_version: u64,
    /// Nodes in the map (confirmed and pending).
    pub map_node_count: u32,
    /// Heap bytes the fusion map holds.
    #[serde(default)]
    pub map_memory_bytes: u64,
    /// Whether the frame source delivers.
    pub source_connected: bool,
    /// What the daemon reads: `live_camera`, `replay`, `synthetic` or `unknown`
    /// (`op3dsg_ipc_types::SOURCE_KINDS`).
    #[serde(default)]
    pub source_kind: String,
    /// The frame the graph's coordinates are in (`world.frame_id`).
    #[serde(default)]
    pub world_frame: String,
    /// Planners (graph subscribers) connected now.
    #[serde(default)]
    pub graph_subscribers: u16,
    /// iceoryx2 nodes of dead processes whose resources the daemon removed since start.
    #[serde(default)]
    pub dead_nodes_cleaned: u32,
    /// Per-stage figures.
    pub stages: Vec<StageReport>,
    /// Per-queue figures.
    pub queues: Vec<QueueReport>,
    /// The LLM refiner.
    #[serde(default)]
    pub refiner: RefinerReport,
    /// The pose input by outcome (`accepted`, `unknown_kind`, `non_finite`,
    /// `non_unit_quaternion`, `no_base_from_camera`, `out_of_order`, `stale`, `future`,
    /// `queue_full`; see `op3dsg_ipc_types::PoseHealth`).
    pub poses: std::collections::BTreeMap<String, u64>,
    /// Where the keyframe gate takes poses from (the profile's `pose.source`: `frame`, `ipc`,
    /// `ros2`; `unknown` from a daemon that does not say). With `frame` the daemon does not read
    /// `<prefix>/pose`, so `poses` stays zero whatever is sent there.
    #[serde(default)]
    pub pose_source: String,
    /// The execution provider each model's sessions run on.
    pub models: Vec<ModelReport>,
    /// The MCAP recorder (see `op3dsg_ipc_types::RecorderHealth`).
    #[serde(default)]
    pub recorder: RecorderReport,
    /// The map snapshots (see `op3dsg_ipc_types::SnapshotHealth`).
    #[serde(default)]
    pub snapshot: SnapshotReport,
    /// The tf input (`pose.source = "ros2"`; see `op3dsg_ipc_types::TfHealth`); absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tf: Option<TfReport>,
    /// Remote detection (see `op3dsg_ipc_types::RemoteHealth`); absent without it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub remote: Option<RemoteReport>,
}

/// Remote detection in a [`HealthReport`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RemoteReport {
    /// Whether keyframes go to the fallback now (no worker answers).
    pub fallback_active: bool,
    /// Keyframes the fallback took (or skipped).
    pub fallback_keyframes: u64,
    /// Times the fallback took over.
    pub fallback_switches: u64,
    /// Workers seen beyond the record's room (`<prefix>/detect_status` lists them).
    pub workers_not_reported: u32,
    /// Per worker, in the order first seen.
    pub workers: Vec<RemoteWorkerReport>,
}

/// One remote detection worker in a [`RemoteReport`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RemoteWorkerReport {
    /// The worker's Zenoh key.
    pub key: String,
    /// Whether its liveliness token is present.
    pub alive: bool,
    /// Requests sent.
    pub requests: u64,
    /// Replies accepted.
    pub replies: u64,
    /// Requests without a reply within `timeout_ms`.
    pub timeouts: u64,
    /// Replies after their timeout (dropped).
    pub late: u64,
    /// Requests that found no worker at the key.
    pub unreachable: u64,
    /// Replies rejected, by reason (`op3dsg_ipc_types::REMOTE_REJECTIONS`).
    pub rejections: std::collections::BTreeMap<String, u64>,
    /// Requests outstanding at the record.
    pub in_flight: u32,
    /// Round trip of accepted replies, median, milliseconds.
    pub round_trip_p50_ms: f64,
    /// Round trip of accepted replies, 99th percentile, milliseconds.
    pub round_trip_p99_ms: f64,
    /// Request bytes sent.
    pub bytes_out: u64,
    /// Reply bytes received.
    pub bytes_in: u64,
    /// Bytes both ways per request.
    pub bytes_per_keyframe: u64,
}

impl RemoteReport {
    fn from_health(h: &Health) -> Option<Self> {
        let r = &h.remote;
        (r.active != 0).then(|| Self {
            fallback_active: r.fallback_active != 0,
            fallback_keyframes: r.fallback_keyframes,
            fallback_switches: r.fallback_switches,
            workers_not_reported: r.workers_not_reported,
            workers: r
                .valid_workers()
                .iter()
                .map(|w| RemoteWorkerReport {
                    key: w.key_str().to_owned(),
                    alive: w.alive != 0,
                    requests: w.requests,
                    replies: w.replies,
                    timeouts: w.timeouts,
                    late: w.late,
                    unreachable: w.unreachable,
                    rejections: op3dsg_ipc_types::REMOTE_REJECTIONS
                        .iter()
                        .zip(w.rejections)
                        .map(|(name, n)| ((*name).to_owned(), n))
                        .collect(),
                    in_flight: w.in_flight,
                    round_trip_p50_ms: f64::from(w.round_trip_p50_us) / 1e3,
                    round_trip_p99_ms: f64::from(w.round_trip_p99_us) / 1e3,
                    bytes_out: w.bytes_out,
                    bytes_in: w.bytes_in,
                    bytes_per_keyframe: w.bytes_per_keyframe(),
                })
                .collect(),
        })
    }
}

/// The tf input of a [`HealthReport`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TfReport {
    /// The chain of the last lookup, world frame first (empty before the first).
    pub path: String,
    /// The stamp of that lookup, ns since the epoch (0: none yet).
    pub lookup_stamp_ns: u64,
    /// The oldest of the newest `/tf` samples of that chain, ns since the epoch (0: every link
    /// static).
    pub newest_data_ns: u64,
    /// The record's `stamp_ns` minus `newest_data_ns`, seconds: how old the chain's data was
    /// when the record was made (tf and the daemon on one clock); `None` before the first lookup
    /// or with a static chain.
    pub data_age_s: Option<f64>,
    /// `/tf` messages received.
    pub dynamic_messages: u64,
    /// `/tf_static` messages received.
    pub static_messages: u64,
    /// Transforms refused by the buffer (besides non-finite values and quaternions).
    pub transforms_refused: u64,
    /// Jumps back in time that cleared the dynamic transforms.
    pub time_jumps: u64,
}

impl TfReport {
    fn from_health(h: &Health) -> Option<Self> {
        let tf = &h.tf;
        (tf.active != 0).then(|| Self {
            path: tf.path_str().to_owned(),
            lookup_stamp_ns: tf.lookup_stamp_ns,
            newest_data_ns: tf.newest_data_ns,
            data_age_s: (tf.newest_data_ns != 0).then_some((h.stamp_ns as f64 - tf.newest_data_ns as f64) * 1e-9),
            dynamic_messages: tf.dynamic_messages,
            static_messages: tf.static_messages,
            transforms_refused: tf.transforms_refused,
            time_jumps: tf.time_jumps,
        })
    }
}

/// The map snapshots of a [`HealthReport`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SnapshotReport {
    /// `off`, `started_empty`, `restored` or `moved_aside` (how the daemon started).
    pub state: String,
    /// Graph version restored at start (0: none).
    pub restored_version: u64,
    /// Graph version of the last snapshot written (or restored).
    pub version: u64,
    /// When the last snapshot was written, ms since the Unix epoch (0: none yet).
    pub last_written_unix_ms: u64,
    /// Size of the last snapshot written, bytes.
    pub last_bytes: u64,
    /// Snapshots written.
    pub written: u64,
    /// Writes that failed.
    pub failures: u64,
    /// Periods skipped while a write was still going on.
    pub skipped: u64,
    /// Write time p99 over the last health period, microseconds (0: no write).
    pub write_p99_us: u32,
}

impl From<&op3dsg_ipc_types::SnapshotHealth> for SnapshotReport {
    fn from(s: &op3dsg_ipc_types::SnapshotHealth) -> Self {
        Self {
            state: op3dsg_ipc_types::SNAPSHOT_STATES.get(s.state as usize).copied().unwrap_or("unknown").to_owned(),
            restored_version: s.restored_version,
            version: s.version,
            last_written_unix_ms: s.last_written_unix_ms,
            last_bytes: s.last_bytes,
            written: s.written,
            failures: s.failures,
            skipped: s.skipped,
            write_p99_us: s.write_p99_us,
        }
    }
}

/// The recorder of a [`HealthReport`].
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RecorderReport {
    /// `off`, `recording`, `failed` or `finished`.
    pub state: String,
    /// Files started.
    pub files: u32,
    /// Messages written.
    pub messages_written: u64,
    /// Messages dropped (queue full, no free frame buffer, or after a failure).
    pub messages_dropped: u64,
    /// Bytes on disk.
    pub bytes_written: u64,
    /// CPU time of the recorder thread, nanoseconds.
    pub cpu_ns: u64,
}

impl From<&op3dsg_ipc_types::RecorderHealth> for RecorderReport {
    fn from(r: &op3dsg_ipc_types::RecorderHealth) -> Self {
        Self {
            state: op3dsg_ipc_types::RECORDER_STATES.get(r.state as usize).copied().unwrap_or("unknown").to_owned(),
            files: r.files,
            messages_written: r.messages_written,
            messages_dropped: r.messages_dropped,
            bytes_written: r.bytes_written,
            cpu_ns: r.cpu_ns,
        }
    }
}

/// One model of a [`HealthReport`] (see `op3dsg_ipc_types::ModelHealth`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelReport {
    /// The model (`YOLOX model`, `text encoder`, ...).
    pub name: String,
    /// Sessions opened on `provider`.
    pub sessions: u32,
    /// The provider they really run on (`cpu`, `cuda`, `openvino`).
    pub provider: String,
    /// The provider the profile asked for.
    pub requested_provider: String,
}

/// The names and values of a [`PoseHealth`](op3dsg_ipc_types::PoseHealth), in its field order.
pub fn pose_counters(p: &op3dsg_ipc_types::PoseHealth) -> [(&'static str, u64); 12] {
    [
        ("accepted", p.accepted),
        ("unknown_kind", p.unknown_kind),
        ("non_finite", p.non_finite),
        ("non_unit_quaternion", p.non_unit_quaternion),
        ("no_base_from_camera", p.no_base_from_camera),
        ("out_of_order", p.out_of_order),
        ("stale", p.stale),
        ("future", p.future),
        ("queue_full", p.queue_full),
        ("no_transform_path", p.no_transform_path),
        ("frame_not_found", p.frame_not_found),
        ("extrapolation", p.extrapolation),
    ]
}

fn provider_name(index: u8) -> String {
    op3dsg_ipc_types::EXECUTION_PROVIDERS.get(index as usize).copied().unwrap_or("unknown").to_owned()
}

/// The LLM refiner in a [`HealthReport`] (see `op3dsg_ipc_types::RefinerHealth`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RefinerReport {
    /// State (`off`, `idle`, `calling`, `backoff`, `breaker_open`, `budget_exhausted`).
    pub state: String,
    /// Whether the circuit breaker is open.
    pub breaker_open: bool,
    /// Refreshes started.
    pub refreshes: u64,
    /// HTTP requests sent, retries included.
    pub calls: u64,
    /// Requests that failed.
    pub failures: u64,
    /// Of `failures`: timeouts.
    pub timeouts: u64,
    /// Of `failures`: 429 answers.
    pub rate_limited: u64,
    /// Items that passed the verification gate.
    pub accepted: u64,
    /// Rejections by reason (`malformed`, `unknown_node`, `wrong_kind`, `non_canonical`, `stale`,
    /// `implausible_geometry`, `implausible_relation`, `implausible_affordance`; see
    /// `op3dsg_ipc_types::REFINER_REJECTIONS`).
    pub rejections: std::collections::BTreeMap<String, u64>,
    /// What the last failed call failed of (`none`, `timeout`, `refused`, `dns`, `tls`,
    /// `connect`, `transport`, `http_status`, `rate_limited`, `not_chat`; see
    /// `op3dsg_ipc_types::REFINER_ERRORS`).
    #[serde(default)]
    pub last_error: String,
    /// The `response_format` sent now (`json_schema`, `json_object`, `json_object_fallback`: the
    /// server refused `json_schema`; see `op3dsg_ipc_types::REFINER_FORMATS`).
    #[serde(default)]
    pub response_format: String,
    /// Latency of the last call, microseconds.
    pub last_latency_us: u32,
    /// Graph version of the last verified result.
    pub last_graph_version: u64,
}

impl From<&op3dsg_ipc_types::RefinerHealth> for RefinerReport {
    fn from(r: &op3dsg_ipc_types::RefinerHealth) -> Self {
        Self {
            state: op3dsg_ipc_types::REFINER_STATES.get(r.state as usize).copied().unwrap_or("unknown").to_owned(),
            breaker_open: r.breaker_open != 0,
            refreshes: r.refreshes,
            calls: r.calls,
            failures: r.failures,
            timeouts: r.timeouts,
            rate_limited: r.rate_limited,
            accepted: r.accepted,
            rejections: op3dsg_ipc_types::REFINER_REJECTIONS
                .iter()
                .zip(r.rejections)
                .map(|(name, n)| ((*name).to_owned(), n))
                .collect(),
            last_error: op3dsg_ipc_types::REFINER_ERRORS
                .get(r.last_error as usize)
                .copied()
                .unwrap_or("unknown")
                .to_owned(),
            response_format: op3dsg_ipc_types::REFINER_FORMATS
                .get(r.response_format as usize)
                .copied()
                .unwrap_or("unknown")
                .to_owned(),
            last_latency_us: r.last_latency_us,
            last_graph_version: r.last_graph_version,
        }
    }
}

/// One stage of a [`HealthReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageReport {
    /// Stage name.
    pub name: String,
    /// Items processed since start.
    pub processed: u64,
    /// Items per second over the last period.
    pub rate_hz: f32,
    /// Median latency, microseconds.
    pub latency_p50_us: f32,
    /// 99th percentile latency, microseconds.
    pub latency_p99_us: f32,
    /// Errors since start.
    pub errors: u32,
}

/// One queue of a [`HealthReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QueueReport {
    /// Queue name.
    pub name: String,
    /// Items waiting now.
    pub depth: u32,
    /// Capacity.
    pub capacity: u32,
    /// Items dropped since start.
    pub dropped: u64,
    /// Items pushed since start.
    pub pushed: u64,
}

impl From<&Health> for HealthReport {
    fn from(h: &Health) -> Self {
        Self {
            schema_version: h.schema_version,
            stamp_ns: h.stamp_ns,
            uptime_s: h.uptime_ns as f64 * 1e-9,
            frames_captured: h.frames_captured,
            keyframes: h.keyframes,
            frames_without_pose: h.frames_without_pose,
            detections_fused: h.detections_fused,
            graph_version: h.graph_version,
            map_node_count: h.map_node_count,
            map_memory_bytes: h.map_memory_bytes,
            source_connected: h.source_connected != 0,
            source_kind: h.source_kind().as_str().to_owned(),
            world_frame: h.world_frame_str().to_owned(),
            graph_subscribers: h.graph_subscribers,
            dead_nodes_cleaned: h.dead_nodes_cleaned,
            stages: h
                .valid_stages()
                .iter()
                .map(|s| StageReport {
                    name: op3dsg_ipc_types::fixed_str(&s.name).to_owned(),
                    processed: s.processed,
                    rate_hz: s.rate_hz,
                    latency_p50_us: s.latency_p50_us,
                    latency_p99_us: s.latency_p99_us,
                    errors: s.errors,
                })
                .collect(),
            queues: h
                .valid_queues()
                .iter()
                .map(|q| QueueReport {
                    name: op3dsg_ipc_types::fixed_str(&q.name).to_owned(),
                    depth: q.depth,
                    capacity: q.capacity,
                    dropped: q.dropped,
                    pushed: q.pushed,
                })
                .collect(),
            refiner: RefinerReport::from(&h.refiner),
            recorder: RecorderReport::from(&h.recorder),
            snapshot: SnapshotReport::from(&h.snapshot),
            tf: TfReport::from_health(h),
            remote: RemoteReport::from_health(h),
            poses: pose_counters(&h.pose).iter().map(|(name, n)| ((*name).to_owned(), *n)).collect(),
            pose_source: h.pose_source_name().to_owned(),
            models: h
                .valid_models()
                .iter()
                .map(|m| ModelReport {
                    name: op3dsg_ipc_types::fixed_str(&m.name).to_owned(),
                    sessions: m.sessions,
                    provider: provider_name(m.provider),
                    requested_provider: provider_name(m.requested_provider),
                })
                .collect(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn report_names_stages_queues_and_refiner_fields_and_round_trips() {
        let mut health =
            Health { schema_version: op3dsg_ipc_types::SCHEMA_VERSION, uptime_ns: 2_500_000_000, ..Health::default() };
        health.stage_count = 1;
        op3dsg_ipc_types::write_fixed_str(&mut health.stages[0].name, "fusion");
        health.stages[0].processed = 4;
        health.queue_count = 1;
        op3dsg_ipc_types::write_fixed_str(&mut health.queues[0].name, "frames");
        health.queues[0].dropped = 3;
        health.refiner.rejections[1] = 2;
        health.pose.future = 3;
        health.model_count = 1;
        op3dsg_ipc_types::write_fixed_str(&mut health.models[0].name, "YOLOX model");
        (health.models[0].sessions, health.models[0].provider, health.models[0].requested_provider) = (2, 1, 2);
        let report = HealthReport::from(&health);
        assert_eq!((report.poses.get("future"), report.poses.len()), (Some(&3), 12));
        assert_eq!(
            report.models,
            [ModelReport {
                name: "YOLOX model".into(),
                sessions: 2,
                provider: "cpu".into(),
                requested_provider: "cuda".into()
            }]
        );
        assert_eq!(report.uptime_s, 2.5);
        assert_eq!((report.stages[0].name.as_str(), report.stages[0].processed), ("fusion", 4));
        assert_eq!((report.queues[0].name.as_str(), report.queues[0].dropped), ("frames", 3));
        assert_eq!(report.refiner.state, "off");
        assert_eq!(report.refiner.rejections.get("unknown_node"), Some(&2));
        let json = serde_json::to_string(&report).expect("serialise");
        let back: HealthReport = serde_json::from_str(&json).expect("parse");
        assert_eq!(back, report);
    }
}
