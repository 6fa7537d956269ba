//! The keyframe stage's counters: keyframes, frames dropped without a pose, the pose input.

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

use op3dsg_ipc_types::Health;

use super::PoseRefusal;
use crate::stats::{PoseStats, ReportHealth, StageStats};

/// Counters of the keyframe gate's thread.
#[derive(Debug)]
pub struct KeyframeCounters {
    /// The `keyframe` stage: one entry per frame judged.
    pub stage: Arc<StageStats>,
    /// Frames accepted as keyframes.
    pub keyframes: AtomicU64,
    /// Frames dropped for lack of a pose within tolerance.
    pub frames_without_pose: AtomicU64,
    /// The pose input by outcome (published as `Health::pose`); the publisher and a replaying
    /// capture thread count into it too.
    pub pose: Arc<PoseStats>,
}

impl Default for KeyframeCounters {
    fn default() -> Self {
        Self {
            stage: Arc::new(StageStats::new("keyframe")),
            keyframes: AtomicU64::new(0),
            frames_without_pose: AtomicU64::new(0),
            pose: Arc::default(),
        }
    }
}

impl ReportHealth for KeyframeCounters {
    fn report(&self, health: &mut Health) {
        health.keyframes = self.keyframes.load(Ordering::Relaxed);
        health.frames_without_pose = self.frames_without_pose.load(Ordering::Relaxed);
        health.pose = self.pose.health();
    }
}

/// Counts one of the gate's outcomes for a received pose in `stats`.
pub fn count_gate(stats: &PoseStats, outcome: Result<(), PoseRefusal>) {
    let counter = match outcome {
        Ok(()) => &stats.accepted,
        Err(PoseRefusal::UnknownKind) => &stats.unknown_kind,
        Err(PoseRefusal::NoBaseFromCamera) => &stats.no_base_from_camera,
        Err(PoseRefusal::OutOfOrder) => &stats.out_of_order,
        Err(PoseRefusal::Stale) => &stats.stale,
        Err(PoseRefusal::Future) => &stats.future,
    };
    counter.fetch_add(1, Ordering::Relaxed);
}
