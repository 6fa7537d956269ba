//! The capture stage's counters: frames delivered, the source's state, its latency.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use op3dsg_ipc_types::Health;

use crate::stats::{ReportHealth, StageStats};

/// Counters of the capture thread, read by health, the service status line and the run summary.
#[derive(Debug)]
pub struct CaptureCounters {
    /// The `capture` stage: one `next_frame` per delivered frame; skipped bad data and source
    /// errors count as its errors.
    pub stage: Arc<StageStats>,
    /// Frames the source delivered.
    pub frames_captured: AtomicU64,
    /// Frames dropped at capture because every pooled frame was in flight.
    pub frames_pool_exhausted: AtomicU64,
    /// Whether the source is delivering.
    pub source_connected: AtomicBool,
    /// Set once a finite source has ended (or `max_frames` was reached).
    pub source_finished: AtomicBool,
    /// Bad inputs a replay skipped (`on_bad_frame = "skip"`); also counted as capture errors.
    pub source_bad_data_skipped: AtomicU64,
    /// Set when the source stopped on an error (a replay's bad data with `on_bad_frame = "stop"`).
    pub source_failed: AtomicBool,
}

impl Default for CaptureCounters {
    fn default() -> Self {
        Self {
            stage: Arc::new(StageStats::new("capture")),
            frames_captured: AtomicU64::new(0),
            frames_pool_exhausted: AtomicU64::new(0),
            source_connected: AtomicBool::new(true),
            source_finished: AtomicBool::new(false),
            source_bad_data_skipped: AtomicU64::new(0),
            source_failed: AtomicBool::new(false),
        }
    }
}

impl CaptureCounters {
    /// A short word for the source's state: `failed`, `ended`, `delivering` or `disconnected`.
    pub fn source_state(&self) -> &'static str {
        if self.source_failed.load(Ordering::Relaxed) {
            "failed"
        } else if self.source_finished.load(Ordering::Relaxed) {
            "ended"
        } else if self.source_connected.load(Ordering::Relaxed) {
            "delivering"
        } else {
            "disconnected"
        }
    }
}

impl ReportHealth for CaptureCounters {
    fn report(&self, health: &mut Health) {
        health.frames_captured = self.frames_captured.load(Ordering::Relaxed);
        health.source_connected = u8::from(self.source_connected.load(Ordering::Relaxed));
    }
}
