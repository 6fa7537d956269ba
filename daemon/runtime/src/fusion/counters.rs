//! The fusion stage's counters: the map's size, the latest version, the keyframe and prior
//! latencies, the snapshots.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use op3dsg_ipc_types::Health;

use super::snapshot::SnapshotStats;
use crate::stats::{ReportHealth, StageStats};

/// Counters of the fusion thread and its snapshot writer.
#[derive(Debug)]
pub struct FusionCounters {
    /// The `fusion` stage: one keyframe's integration.
    pub stage: Arc<StageStats>,
    /// The `prior` stage: the prior graph and the reasoner, once per published version.
    pub prior: Arc<StageStats>,
    /// Detections given to fusion.
    pub detections_fused: AtomicU64,
    /// Latest graph version.
    pub graph_version: AtomicU64,
    /// Nodes in the map.
    pub map_node_count: AtomicU64,
    /// Heap bytes of the map.
    pub map_memory_bytes: AtomicU64,
    /// Map snapshots.
    pub snapshot: Arc<SnapshotStats>,
}

impl Default for FusionCounters {
    fn default() -> Self {
        Self {
            stage: Arc::new(StageStats::new("fusion")),
            prior: Arc::new(StageStats::new("prior")),
            detections_fused: AtomicU64::new(0),
            graph_version: AtomicU64::new(0),
            map_node_count: AtomicU64::new(0),
            map_memory_bytes: AtomicU64::new(0),
            snapshot: Arc::default(),
        }
    }
}

impl ReportHealth for FusionCounters {
    fn report(&self, health: &mut Health) {
        health.detections_fused = self.detections_fused.load(Ordering::Relaxed);
        health.graph_version = self.graph_version.load(Ordering::Relaxed);
        health.map_node_count = self.map_node_count.load(Ordering::Relaxed) as u32;
        health.map_memory_bytes = self.map_memory_bytes.load(Ordering::Relaxed);
        health.snapshot = self.snapshot.health();
    }
}
