//! The health record's wire types: [`Health`] with its per-stage, per-queue and LLM refiner
//! figures, as the daemon publishes them on `<prefix>/health`.

// The derive macros emit `unsafe impl ZeroCopySend`; that is the only unsafe code here.
#![allow(unsafe_code)]

use iceoryx2::prelude::{PlacementDefault, ZeroCopySend};

use crate::{NAME_CAPACITY_BYTES, SCHEMA_VERSION};

/// The most pipeline stages reported in one [`Health`] record.
pub const MAX_STAGES: usize = 16;
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
/// `stale` (accepted, but its nodes were gone when the result reached the graph).
pub const REFINER_REJECTIONS: [&str; 5] = ["malformed", "unknown_node", "wrong_kind", "non_canonical", "stale"];

/// The LLM refiner (size 128 bytes); all zero (state `off`) when no LLM is configured.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::RefinerHealth")]
pub struct RefinerHealth {
    /// Index into [`REFINER_STATES`].
    pub state: u8,
    /// 1 while the circuit breaker is open (no calls until its cool-down ends).
    pub breaker_open: u8,
    /// Reserved, zero.
    pub reserved: [u8; 2],
    /// Latency of the last completed call (success or failure), microseconds.
    pub last_latency_us: u32,
    /// Refreshes started (each sends one prompt per agent).
    pub refreshes: u64,
    /// HTTP requests sent, retries included (each counts against the hourly budget).
    pub calls: u64,
    /// Requests that failed (timeout, transport error, HTTP error status).
    pub failures: u64,
    /// Of `failures`: timeouts.
    pub timeouts: u64,
    /// Of `failures`: HTTP 429 answers.
    pub rate_limited: u64,
    /// Items that passed the verification gate.
    pub accepted: u64,
    /// Graph version of the last result sent to the fusion thread.
    pub last_graph_version: u64,
    /// Rejections by reason ([`REFINER_REJECTIONS`] order; the rest reserved, zero).
    pub rejections: [u64; 8],
}

/// Daemon health, published on `<prefix>/health` every health period (profile).
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::Health")]
pub struct Health {
    /// [`SCHEMA_VERSION`] of the publisher.
    pub schema_version: u32,
    /// Number of valid entries in `stages`.
    pub stage_count: u32,
    /// Wall-clock time of this record, nanoseconds since the Unix epoch.
    pub stamp_ns: u64,
    /// Seconds since the daemon started, as nanoseconds.
    pub uptime_ns: u64,
    /// Frames delivered by the source since start.
    pub frames_captured: u64,
    /// Frames accepted by the keyframe gate.
    pub keyframes: u64,
    /// Frames dropped because no pose was available within tolerance.
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
    /// Reserved, zero.
    pub reserved: [u8; 7],
    /// Per-stage figures.
    pub stages: [StageHealth; MAX_STAGES],
    /// Per-queue figures.
    pub queues: [QueueHealth; MAX_QUEUES],
    /// The LLM refiner.
    pub refiner: RefinerHealth,
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
            reserved: [0; 7],
            stages: [StageHealth::default(); MAX_STAGES],
            queues: [QueueHealth::default(); MAX_QUEUES],
            refiner: RefinerHealth::default(),
        }
    }
}

impl Health {
    /// The valid stage entries.
    pub fn valid_stages(&self) -> &[StageHealth] {
        &self.stages[..(self.stage_count as usize).min(MAX_STAGES)]
    }
    /// The valid queue entries.
    pub fn valid_queues(&self) -> &[QueueHealth] {
        &self.queues[..(self.queue_count as usize).min(MAX_QUEUES)]
    }
}
