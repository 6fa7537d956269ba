//! Remote detection (`detector.kind = "remote"`, `[detector.remote]`): each detection worker
//! thread sends its keyframe to an `op3dsg-detectd` worker over Zenoh and waits at most
//! `timeout_ms` for the detections; the pipeline's tickets keep the results in keyframe order.
//! A keyframe no worker answers in time — none alive, all busy, a timeout, a refusal, a reply
//! that does not match its request — goes to the local fallback (`fallback`: a detector kind,
//! or `skip`: fused empty), so a missing GPU box never stalls the robot.
//!
//! Keys under the robot's prefix (`zenoh.key_prefix`):
//!
//! | key | what |
//! |---|---|
//! | `<prefix>/detect/<worker>` | the worker's liveliness token (`workers = ["auto"]` follows these) |
//! | `<prefix>/detect/<worker>/request` | queryable: a request ([`wire`]) in, its reply out |
//! | `<prefix>/detect/<worker>/status` | queryable: the worker's models, execution provider and load (JSON) |
//! | `<prefix>/detect_status` | queryable on the robot: the per-worker figures of [`RemoteCounters`] (JSON) |
//!
//! | file | what |
//! |---|---|
//! | `wire.rs` | the request and reply bytes, checked field by field |
//! | `config.rs` | `[detector.remote]` ([`RemoteConfig`]) |
//! | `counters.rs` | per-worker figures ([`RemoteCounters`]) |
//! | `client.rs` | [`RemoteClient`] (the session, the workers) and [`RemoteDetector`] (feature `zenoh`) |

#[cfg(feature = "zenoh")]
mod client;
mod config;
mod counters;
pub mod wire;

#[cfg(feature = "zenoh")]
pub use client::{RemoteClient, RemoteDetector, announce};
pub use config::{AUTO_WORKERS, RemoteConfig, SKIP_FALLBACK};
pub use counters::{Rejection, RemoteCounters, WorkerCounters};

/// `detector.kind` of remote detection.
pub const REMOTE_DETECTOR: &str = "remote";

/// The key a worker serves requests on, below its key (`<prefix>/detect/<id>`).
pub fn request_key(worker_key: &str) -> String {
    format!("{worker_key}/request")
}

/// The key of worker `id` under `prefix` (its liveliness token; requests and status below it).
pub fn worker_key(prefix: &str, id: &str) -> String {
    format!("{prefix}/detect/{id}")
}
