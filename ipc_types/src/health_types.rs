//! The health record's wire types: [`Health`] with its per-stage, per-queue, pose-input, model
//! and LLM refiner figures, as the daemon publishes them on `<prefix>/health`.
//!
//! Every stage is reported: [`MAX_STAGES`] is [`MAX_WORKERS`] (the profile's limit on
//! `detector.workers`, one `detect/<i>` entry each) plus [`FIXED_STAGES`] (`capture`,
//! `keyframe`, `fusion`, `prior`, `publish`, `end_to_end` and room for two more), so no profile
//! can make the daemon cut entries off.

// The derive macros emit `unsafe impl ZeroCopySend`; that is the only unsafe code here.
#![allow(unsafe_code)]

use iceoryx2::prelude::{PlacementDefault, ZeroCopySend};

use crate::{NAME_CAPACITY_BYTES, SCHEMA_VERSION};

/// The most detection workers a profile may ask for (`detector.workers`), each with a
/// `detect/<i>` stage entry.
pub const MAX_WORKERS: usize = 64;
/// Stage entries that are not detection workers: `capture`, `keyframe`, `fusion`, `prior`,
/// `publish`, `end_to_end`, `zenoh` (with the daemon's `[zenoh]` stage on), and one spare.
pub const FIXED_STAGES: usize = 8;
/// The most pipeline stages reported in one [`Health`] record: every worker plus the fixed
/// stages, so every stage of any valid profile has an entry.
pub const MAX_STAGES: usize = MAX_WORKERS + FIXED_STAGES;
/// The most model entries ([`ModelHealth`]) in one [`Health`] record.
pub const MAX_MODELS: usize = 8;
/// Execution providers ([`ModelHealth::provider`] and [`ModelHealth::requested_provider`]
/// index this): `unknown` (0, never set by the daemon), `cpu`, `cuda`, `openvino`.
pub const EXECUTION_PROVIDERS: [&str; 4] = ["unknown", "cpu", "cuda", "openvino"];
/// The most queues reported in one [`Health`] record.
pub const MAX_QUEUES: usize = 16;

/// Health of one pipeline stage (size 64 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::StageHealth")]
pub struct StageHealth {
    /// Stage name (`capture`, `keyframe`, `detect/0`, `fusion`, `prior`, `publish`, `end_to_end`, ...), NUL padded.
    pub name: [u8; NAME_CAPACITY_BYTES],
    /// Items processed since start.
    pub processed: u64,
    /// Items per second over the last health period.
    pub rate_hz: f32,
    /// Median latency of one item over the last health period, microseconds.
    pub latency_p50_us: f32,
    /// 99th percentile latency over the last health period, microseconds.
    pub latency_p99_us: f32,
    /// Errors since start (items that failed and were skipped).
    pub errors: u32,
    /// Reserved, zero.
    pub reserved: [u8; 8],
}

/// Health of one bounded queue (size 56 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::QueueHealth")]
pub struct QueueHealth {
    /// Queue name (`frames`, `keyframes`, `detections`, `graph`, ...), NUL padded.
    pub name: [u8; NAME_CAPACITY_BYTES],
    /// Items waiting now.
    pub depth: u32,
    /// Capacity from the profile.
    pub capacity: u32,
    /// Items dropped since start (overwritten by latest-wins, or refused).
    pub dropped: u64,
    /// Items pushed since start.
    pub pushed: u64,
}

/// States of the LLM refiner ([`RefinerHealth::state`] indexes this).
pub const REFINER_STATES: [&str; 6] = ["off", "idle", "calling", "backoff", "breaker_open", "budget_exhausted"];

/// Why the LLM refiner's verification gate rejected an answer or one of its items
/// ([`RefinerHealth::rejections`] index `i` counts `REFINER_REJECTIONS[i]`):
/// `malformed` (an answer that fails strict parsing, or an item with a bad confidence),
/// `unknown_node` (an id not in that graph version), `wrong_kind` (a local relation off a
/// part-of pair, a remote one between nodes the knowledge base does not allow),
/// `non_canonical` (a relation or affordance label that maps onto no canonical one),
/// `stale` (accepted, but when the result was applied to a later graph its nodes were gone, had
/// changed kind, or the part had left its object), and the plausibility rules for canonical
/// items that make no sense for their nodes: `implausible_geometry` (a part off the object it
/// is said to act on, a remote pair too far apart for its relation, a part too large for the
/// affordance), `implausible_relation` (a relation the knowledge base gives none of the
/// categories involved), `implausible_affordance` (likewise for an affordance).
pub const REFINER_REJECTIONS: [&str; 8] = [
    "malformed",
    "unknown_node",
    "wrong_kind",
    "non_canonical",
    "stale",
    "implausible_geometry",
    "implausible_relation",
    "implausible_affordance",
];

/// Kinds of failed LLM calls ([`RefinerHealth::last_error`] indexes this): `none` (no call
/// failed yet), `timeout`, transport errors by cause (`refused`: nothing listens there, `dns`:
/// the host did not resolve, `tls`: handshake or certificate, `connect`: other connect failures,
/// `transport`: the connection broke later), `http_status` (an error status other than 429),
/// `rate_limited` (429), `not_chat` (a 2xx that is not a chat completion: an HTML page, no
/// choices, null content).
pub const REFINER_ERRORS: [&str; 10] =
    ["none", "timeout", "refused", "dns", "tls", "connect", "transport", "http_status", "rate_limited", "not_chat"];

/// The `response_format` the LLM refiner sends ([`RefinerHealth::response_format`] indexes
/// this): `json_schema` (a strict schema per agent, as configured), `json_object` (as
/// configured), `json_object_fallback` (configured `json_schema`, but the server answered 400
/// to it, so `json_object` is sent instead).
pub const REFINER_FORMATS: [&str; 3] = ["json_schema", "json_object", "json_object_fallback"];

/// The LLM refiner (size 128 bytes); all zero (state `off`) when no LLM is configured.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::RefinerHealth")]
pub struct RefinerHealth {
    /// Index into [`REFINER_STATES`].
    pub state: u8,
    /// 1 while the circuit breaker is open (no calls until its cool-down ends).
    pub breaker_open: u8,
    /// Index into [`REFINER_ERRORS`]: what the last failed call failed of (kept after later
    /// successes; `none` until a call fails).
    pub last_error: u8,
    /// Index into [`REFINER_FORMATS`]: the `response_format` sent now (0 from a daemon older
    /// than this field, where the byte was reserved).
    pub response_format: u8,
    /// Latency of the last completed call (success or failure), microseconds.
    pub last_latency_us: u32,
    /// Refreshes started (each sends one prompt per agent).
    pub refreshes: u64,
    /// HTTP requests sent, retries included (each counts against the hourly budget).
    pub calls: u64,
    /// Requests that failed (timeout, transport error, HTTP error status, a 2xx that is not a
    /// chat completion).
    pub failures: u64,
    /// Of `failures`: timeouts.
    pub timeouts: u64,
    /// Of `failures`: HTTP 429 answers.
    pub rate_limited: u64,
    /// Items that passed the verification gate.
    pub accepted: u64,
    /// Graph version of the last result sent to the fusion thread.
    pub last_graph_version: u64,
    /// Rejections by reason ([`REFINER_REJECTIONS`] order).
    pub rejections: [u64; 8],
}

/// What became of the poses received on `<prefix>/pose` (size 96 bytes), each pose counted once,
/// under the first check it fails, in this order: the wire checks of
/// [`check_pose`](crate::check_pose) (`unknown_kind`, `non_finite`, `non_unit_quaternion`), then
/// the keyframe gate's (`no_base_from_camera`, `out_of_order`, `stale`, `future`). All zero with
/// `pose.source = "frame"` except the wire checks (poses are still received and checked).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::PoseHealth")]
pub struct PoseHealth {
    /// Poses the keyframe gate adopted (they may give frames their pose).
    pub accepted: u64,
    /// `kind` is not a [`PoseKind`](crate::PoseKind) value.
    pub unknown_kind: u64,
    /// A translation or quaternion component is NaN or infinite.
    pub non_finite: u64,
    /// The quaternion's norm is off 1 by more than
    /// [`QUATERNION_NORM_TOLERANCE`](crate::services::QUATERNION_NORM_TOLERANCE).
    pub non_unit_quaternion: u64,
    /// A `world_from_base` pose while the profile sets no `pose.base_from_camera`.
    pub no_base_from_camera: u64,
    /// Stamped before the newest adopted pose (the buffer only grows forwards).
    pub out_of_order: u64,
    /// Stamped more than `max(pose.max_interpolation_gap_ms, pose.tolerance_ms)` before the
    /// oldest frame still waiting for a pose (the newest frame the gate has seen when none
    /// waits): no frame can use it.
    pub stale: u64,
    /// Stamped more than `pose.future_tolerance_ms` (default [`FUTURE_POSE_LIMIT_NS`]) after the
    /// newest frame the gate has seen; not adopted, so it cannot hold back the poses that follow.
    pub future: u64,
    /// Dropped between the receiving thread and the gate because the hand-over queue (capacity
    /// `pose.buffer_len`) was full.
    pub queue_full: u64,
    /// `pose.source = "ros2"`: no chain of transforms joins the world and camera frames (a link
    /// of the tf tree is missing; the daemon's log names it).
    pub no_transform_path: u64,
    /// `pose.source = "ros2"`: no transform names the world or camera frame.
    pub frame_not_found: u64,
    /// `pose.source = "ros2"`: a link of the chain has no transforms around the stamp (before
    /// its oldest, after its newest, or too far apart to interpolate).
    pub extrapolation: u64,
}

/// The default of the profile's `pose.future_tolerance_ms`, nanoseconds: a pose stamped further
/// after the newest frame the keyframe gate has seen is counted as [`PoseHealth::future`] and not
/// adopted (1 s: far beyond any camera latency).
pub const FUTURE_POSE_LIMIT_NS: u64 = 1_000_000_000;

/// One model's ONNX Runtime sessions on one execution provider (size 40 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::ModelHealth")]
pub struct ModelHealth {
    /// The model (`YOLOX model`, `text encoder`, ...), NUL padded.
    pub name: [u8; NAME_CAPACITY_BYTES],
    /// Sessions of this model opened on `provider` since start (one per detection worker).
    pub sessions: u32,
    /// Index into [`EXECUTION_PROVIDERS`]: the provider the sessions really run on.
    pub provider: u8,
    /// Index into [`EXECUTION_PROVIDERS`]: the provider the profile asked for (differs from
    /// `provider` when it could not start and the session fell back to the CPU).
    pub requested_provider: u8,
    /// Reserved, zero.
    pub reserved: [u8; 2],
}

/// Daemon health, published on `<prefix>/health` every health period (profile).
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::Health")]
pub struct Health {
    /// [`SCHEMA_VERSION`] of the publisher.
    pub schema_version: u32,
    /// Number of valid entries in `stages` (every stage: at most [`MAX_STAGES`]).
    pub stage_count: u32,
    /// Wall-clock time of this record, nanoseconds since the Unix epoch.
    pub stamp_ns: u64,
    /// Seconds since the daemon started, as nanoseconds.
    pub uptime_ns: u64,
    /// Frames delivered by the source since start.
    pub frames_captured: u64,
    /// Frames accepted by the keyframe gate.
    pub keyframes: u64,
    /// Frames dropped because no pose was available within `pose.tolerance_ms`.
    pub frames_without_pose: u64,
    /// Detections fused since start.
    pub detections_fused: u64,
    /// Current graph version.
    pub graph_version: u64,
    /// Heap bytes the fusion map holds (capacity: what the process really uses for it).
    pub map_memory_bytes: u64,
    /// Nodes in the map now (confirmed and pending).
    pub map_node_count: u32,
    /// Number of valid entries in `queues`.
    pub queue_count: u32,
    /// 1 while the frame source delivers, 0 when it is lost or finished.
    pub source_connected: u8,
    /// What the daemon reads its frames from, as in the graph header: a
    /// [`SourceKind`](crate::SourceKind) value (0 unknown or other, 1 live camera, 2 replay,
    /// 3 synthetic; names in [`SOURCE_KINDS`](crate::SOURCE_KINDS)).
    pub source_kind: u8,
    /// Planners (graph subscribers) connected now, as iceoryx2 counts them: a planner killed
    /// without closing stays counted until its node is cleaned up (see `dead_nodes_cleaned`).
    pub graph_subscribers: u16,
    /// iceoryx2 nodes of dead processes (planners killed mid-read, a previous daemon) whose
    /// shared-memory resources the daemon removed since start, at start and once per health
    /// period: their subscriber slots come back.
    pub dead_nodes_cleaned: u32,
    /// Per-stage figures.
    pub stages: [StageHealth; MAX_STAGES],
    /// Per-queue figures.
    pub queues: [QueueHealth; MAX_QUEUES],
    /// The LLM refiner.
    pub refiner: RefinerHealth,
    /// The pose input, by outcome.
    pub pose: PoseHealth,
    /// Number of valid entries in `models`.
    pub model_count: u32,
    /// Where the keyframe gate takes poses from, the profile's `pose.source`: a
    /// [`POSE_SOURCES`] index (0 unknown, 1 `frame`: the frames carry their poses and
    /// `<prefix>/pose` is not read, 2 `ipc`, 3 `ros2`).
    pub pose_source: u8,
    /// Reserved, zero.
    pub reserved_models: [u8; 3],
    /// The execution provider each model's sessions run on.
    pub models: [ModelHealth; MAX_MODELS],
    /// The MCAP recorder (`[record]`).
    pub recorder: RecorderHealth,
    /// The map snapshots (`[snapshot]`).
    pub snapshot: SnapshotHealth,
    /// Name of the frame the graph's coordinates are in (the profile's `world.frame_id`), as in
    /// the graph header, UTF-8, NUL padded; so a monitor that reads health alone sees it.
    pub world_frame: [u8; NAME_CAPACITY_BYTES],
    /// The tf input (`pose.source = "ros2"`); all zero otherwise.
    pub tf: TfHealth,
    /// Remote detection (`detector.kind = "remote"`, or a local kind whose fallback it is); all
    /// zero otherwise.
    pub remote: RemoteHealth,
}

/// Bytes of [`TfHealth::path`].
pub const TF_PATH_CAPACITY_BYTES: usize = 192;

/// The tf input's state (`pose.source = "ros2"`, the thread `op3dsg-ros2-tf`; size 256 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::TfHealth")]
pub struct TfHealth {
    /// The chain of the last successful lookup, world frame first, frames joined by ` -> `,
    /// UTF-8, NUL padded (a chain longer than the field ends in `...`); empty before the first.
    pub path: [u8; TF_PATH_CAPACITY_BYTES],
    /// The stamp that lookup was for, ns since the epoch on the frames' clock (0: none yet).
    pub lookup_stamp_ns: u64,
    /// The oldest of the newest samples of the chain's `/tf` links at that lookup, ns since the
    /// epoch (0: every link is static). The health record's `stamp_ns` minus this is the age of
    /// the chain's data when tf and the daemon share a clock.
    pub newest_data_ns: u64,
    /// `/tf` messages received.
    pub dynamic_messages: u64,
    /// `/tf_static` messages received (including those fetched from the publishers' caches).
    pub static_messages: u64,
    /// Transforms refused by the buffer for other reasons than non-finite values or
    /// quaternions (an empty frame id, a frame its own parent, a repeated or too old stamp, too
    /// many frames).
    pub transforms_refused: u64,
    /// `/tf` messages stamped wholly before the kept window: tf's time went back and the dynamic
    /// transforms were cleared.
    pub time_jumps: u64,
    /// 1 when the tf input runs.
    pub active: u8,
    /// Reserved, zero.
    pub reserved: [u8; 15],
}

impl Default for TfHealth {
    fn default() -> Self {
        Self {
            path: [0; TF_PATH_CAPACITY_BYTES],
            lookup_stamp_ns: 0,
            newest_data_ns: 0,
            dynamic_messages: 0,
            static_messages: 0,
            transforms_refused: 0,
            time_jumps: 0,
            active: 0,
            reserved: [0; 15],
        }
    }
}

impl TfHealth {
    /// [`Self::path`] as text.
    pub fn path_str(&self) -> &str {
        crate::fixed_str(&self.path)
    }
}

impl Default for Health {
    fn default() -> Self {
        Self {
            schema_version: SCHEMA_VERSION,
            stage_count: 0,
            stamp_ns: 0,
            uptime_ns: 0,
            frames_captured: 0,
            keyframes: 0,
            frames_without_pose: 0,
            detections_fused: 0,
            graph_version: 0,
            map_memory_bytes: 0,
            map_node_count: 0,
            queue_count: 0,
            source_connected: 0,
            source_kind: 0,
            graph_subscribers: 0,
            dead_nodes_cleaned: 0,
            stages: [StageHealth::default(); MAX_STAGES],
            queues: [QueueHealth::default(); MAX_QUEUES],
            refiner: RefinerHealth::default(),
            pose: PoseHealth::default(),
            model_count: 0,
            pose_source: 0,
            reserved_models: [0; 3],
            models: [ModelHealth::default(); MAX_MODELS],
            recorder: RecorderHealth::default(),
            snapshot: SnapshotHealth::default(),
            world_frame: [0; NAME_CAPACITY_BYTES],
            tf: TfHealth::default(),
            remote: RemoteHealth::default(),
        }
    }
}

impl Health {
    /// The valid stage entries.
    pub fn valid_stages(&self) -> &[StageHealth] {
        &self.stages[..(self.stage_count as usize).min(MAX_STAGES)]
    }
    /// The valid model entries.
    pub fn valid_models(&self) -> &[ModelHealth] {
        &self.models[..(self.model_count as usize).min(MAX_MODELS)]
    }
    /// The valid queue entries.
    pub fn valid_queues(&self) -> &[QueueHealth] {
        &self.queues[..(self.queue_count as usize).min(MAX_QUEUES)]
    }
    /// [`Self::source_kind`] decoded; a value this build does not know reads as
    /// [`SourceKind::Unknown`](crate::SourceKind::Unknown).
    pub fn source_kind(&self) -> crate::SourceKind {
        crate::SourceKind::from_u8(self.source_kind).unwrap_or_default()
    }
    /// [`Self::world_frame`] as text.
    pub fn world_frame_str(&self) -> &str {
        crate::fixed_str(&self.world_frame)
    }
    /// [`Self::pose_source`] by name ([`POSE_SOURCES`]); a value this build does not know reads
    /// as `unknown`.
    pub fn pose_source_name(&self) -> &'static str {
        POSE_SOURCES.get(self.pose_source as usize).copied().unwrap_or(POSE_SOURCES[0])
    }
}

/// [`Health::pose_source`] values by index: where the keyframe gate takes poses from.
pub const POSE_SOURCES: [&str; 4] = ["unknown", "frame", "ipc", "ros2"];

/// The most detection workers [`RemoteHealth`] reports (the first seen; `<prefix>/detect_status`
/// over Zenoh lists every one).
pub const MAX_REMOTE_WORKERS: usize = 8;
/// Bytes of [`RemoteWorkerHealth::key`].
pub const REMOTE_KEY_CAPACITY_BYTES: usize = 96;
/// Why a worker's reply was not used ([`RemoteWorkerHealth::rejections`] index `i` counts
/// `REMOTE_REJECTIONS[i]`): `garbage` (not a reply of this wire version), `wrong_id` (it answers
/// another request or keyframe), `mask_size` (a mask leaves the image or its runs do not cover
/// its box), `embedding_dim` (a region embedding of another dimension), `refused` (the worker
/// cannot serve the model contract), `failed` (the worker's detector failed).
pub const REMOTE_REJECTIONS: [&str; 6] = ["garbage", "wrong_id", "mask_size", "embedding_dim", "refused", "failed"];

/// One remote detection worker as the robot sees it (size 216 bytes). Counters are since the
/// daemon started; the round trip's quantiles are over every accepted reply since then.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::RemoteWorkerHealth")]
pub struct RemoteWorkerHealth {
    /// The worker's Zenoh key (`<prefix>/detect/<id>`), UTF-8, NUL padded (a longer key ends in
    /// `...`).
    pub key: [u8; REMOTE_KEY_CAPACITY_BYTES],
    /// Requests sent.
    pub requests: u64,
    /// Replies accepted.
    pub replies: u64,
    /// Requests that got no reply within `timeout_ms`.
    pub timeouts: u64,
    /// Replies that came after their request's timeout (dropped).
    pub late: u64,
    /// Requests that found no worker at the key (it was gone).
    pub unreachable: u64,
    /// Replies rejected, by reason ([`REMOTE_REJECTIONS`] order).
    pub rejections: [u64; 6],
    /// Request bytes sent (the encoded keyframes).
    pub bytes_out: u64,
    /// Reply bytes received.
    pub bytes_in: u64,
    /// Round trip of accepted replies, median, microseconds (0: none yet).
    pub round_trip_p50_us: f32,
    /// Round trip of accepted replies, 99th percentile, microseconds (0: none yet).
    pub round_trip_p99_us: f32,
    /// Requests outstanding now.
    pub in_flight: u32,
    /// 1 while the worker's liveliness token is present (`detector.remote.workers = "auto"`;
    /// configured keys always read 1).
    pub alive: u8,
    /// Reserved, zero.
    pub reserved: [u8; 3],
}

impl Default for RemoteWorkerHealth {
    fn default() -> Self {
        Self {
            key: [0; REMOTE_KEY_CAPACITY_BYTES],
            requests: 0,
            replies: 0,
            timeouts: 0,
            late: 0,
            unreachable: 0,
            rejections: [0; 6],
            bytes_out: 0,
            bytes_in: 0,
            round_trip_p50_us: 0.0,
            round_trip_p99_us: 0.0,
            in_flight: 0,
            alive: 0,
            reserved: [0; 3],
        }
    }
}

impl RemoteWorkerHealth {
    /// [`Self::key`] as text.
    pub fn key_str(&self) -> &str {
        crate::fixed_str(&self.key)
    }
    /// Rejections of every reason.
    pub fn rejected(&self) -> u64 {
        self.rejections.iter().sum()
    }
    /// Bytes both ways per request sent (0 before the first).
    pub fn bytes_per_keyframe(&self) -> u64 {
        (self.bytes_out + self.bytes_in).checked_div(self.requests).unwrap_or(0)
    }
}

/// Remote detection's state (size 1,752 bytes): the fallback's and the first
/// [`MAX_REMOTE_WORKERS`] workers'.
#[repr(C)]
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::RemoteHealth")]
pub struct RemoteHealth {
    /// 1 when the daemon detects through remote workers.
    pub active: u8,
    /// 1 while keyframes go to the fallback (`detector.remote.fallback`) because no worker
    /// answers.
    pub fallback_active: u8,
    /// Number of valid entries in `workers`.
    pub worker_count: u16,
    /// Workers seen beyond [`MAX_REMOTE_WORKERS`] (not reported here).
    pub workers_not_reported: u32,
    /// Keyframes the fallback took (or skipped, with `fallback = "skip"`).
    pub fallback_keyframes: u64,
    /// Times the fallback took over from the workers.
    pub fallback_switches: u64,
    /// Per worker, in the order first seen.
    pub workers: [RemoteWorkerHealth; MAX_REMOTE_WORKERS],
}

impl Default for RemoteHealth {
    fn default() -> Self {
        Self {
            active: 0,
            fallback_active: 0,
            worker_count: 0,
            workers_not_reported: 0,
            fallback_keyframes: 0,
            fallback_switches: 0,
            workers: [RemoteWorkerHealth::default(); MAX_REMOTE_WORKERS],
        }
    }
}

impl RemoteHealth {
    /// The valid worker entries.
    pub fn valid_workers(&self) -> &[RemoteWorkerHealth] {
        &self.workers[..(self.worker_count as usize).min(MAX_REMOTE_WORKERS)]
    }
}

/// Names of [`RecorderHealth::state`], by value.
pub const RECORDER_STATES: [&str; 4] = ["off", "recording", "failed", "finished"];

/// Map snapshot states, as [`SnapshotHealth::state`].
pub const SNAPSHOT_STATES: [&str; 4] = ["off", "started_empty", "restored", "moved_aside"];

/// The map snapshots' state and counters (`[snapshot]`, `daemon/runtime/src/service/snapshot.rs`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::SnapshotHealth")]
pub struct SnapshotHealth {
    /// Index into [`SNAPSHOT_STATES`]: 0 off (no snapshot directory), 1 on and started with an
    /// empty map (no snapshot there), 2 on and the map was restored from the snapshot at start,
    /// 3 on, the snapshot found at start could not be used (moved aside; started empty).
    pub state: u8,
    /// Reserved, zero.
    pub reserved: [u8; 3],
    /// Write time of the snapshots written in the last health period, p99, microseconds (0: none).
    pub write_p99_us: u32,
    /// Graph version of the map restored at start (0: none).
    pub restored_version: u64,
    /// Graph version of the last snapshot written, or restored when none was written yet (0: none).
    pub version: u64,
    /// Wall-clock time of the last snapshot written, milliseconds since the Unix epoch (0: none).
    pub last_written_unix_ms: u64,
    /// Size of the last snapshot written, bytes.
    pub last_bytes: u64,
    /// Snapshots written.
    pub written: u64,
    /// Snapshot writes that failed (the previous snapshot is kept).
    pub failures: u64,
    /// Periods skipped because the previous write was still going on.
    pub skipped: u64,
}

/// The MCAP recorder's state and counters (`[record]`, `daemon/runtime/src/record/`).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::RecorderHealth")]
pub struct RecorderHealth {
    /// Index into [`RECORDER_STATES`]: 0 off (not configured), 1 recording, 2 failed (a write
    /// failed, e.g. the disk is full: recording stopped, the pipeline goes on), 3 finished.
    pub state: u8,
    /// Reserved, zero.
    pub reserved: [u8; 3],
    /// Files started so far (rotation starts a new one).
    pub files: u32,
    /// Messages written, all channels.
    pub messages_written: u64,
    /// Messages dropped, all channels: queue full or no free frame buffer (the disk is slower
    /// than the input), or given up after a failure.
    pub messages_dropped: u64,
    /// Bytes on disk in the files written so far (compressed; updated at each flush).
    pub bytes_written: u64,
    /// CPU time of the recorder thread so far, nanoseconds (Linux; 0 elsewhere).
    pub cpu_ns: u64,
}
