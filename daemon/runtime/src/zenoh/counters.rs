//! [`ZenohCounters`]: the Zenoh stage's figures, in every build (health reads them; without the
//! feature `zenoh` the stage never runs and they stay absent from the counters).

use std::sync::Arc;
use std::sync::atomic::AtomicU64;

use crate::stats::StageStats;

/// The Zenoh stage's figures.
#[derive(Debug)]
pub struct ZenohCounters {
    /// The `zenoh` stage: one graph version encoded and put (full and delta); a failed put is an
    /// error.
    pub stage: Arc<StageStats>,
    /// Full graphs put on `<prefix>/graph` (periodic and first of an instance).
    pub fulls: AtomicU64,
    /// Deltas put on `<prefix>/graph/delta`.
    pub deltas: AtomicU64,
    /// Health records put on `<prefix>/health`.
    pub healths: AtomicU64,
    /// Occupancy maps put on `<prefix>/occupancy`.
    pub occupancies: AtomicU64,
    /// Queries on `<prefix>/graph` answered with a graph.
    pub queries: AtomicU64,
    /// Queries on `<prefix>/query` handed to the query service (answered by it, busy included).
    pub language_queries: AtomicU64,
    /// Bytes of the last full graph message.
    pub last_full_bytes: AtomicU64,
    /// Bytes of the last delta message.
    pub last_delta_bytes: AtomicU64,
    /// Bytes of every full graph message put.
    pub full_bytes: AtomicU64,
    /// Bytes of every delta message put.
    pub delta_bytes: AtomicU64,
}

impl Default for ZenohCounters {
    fn default() -> Self {
        Self {
            stage: Arc::new(StageStats::new("zenoh")),
            fulls: AtomicU64::new(0),
            deltas: AtomicU64::new(0),
            healths: AtomicU64::new(0),
            occupancies: AtomicU64::new(0),
            queries: AtomicU64::new(0),
            language_queries: AtomicU64::new(0),
            last_full_bytes: AtomicU64::new(0),
            last_delta_bytes: AtomicU64::new(0),
            full_bytes: AtomicU64::new(0),
            delta_bytes: AtomicU64::new(0),
        }
    }
}
