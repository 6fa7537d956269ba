//! Heartbeats of the stages the systemd watchdog watches: each records when its thread last went
//! round its loop, and the service layer decides from them whether to ping the watchdog.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

/// Heartbeats of the stages the watchdog watches: each records when its thread last went round
/// its loop (milliseconds since the pipeline started; 0 = not yet).
#[derive(Debug)]
pub struct Liveness {
    started: Instant,
    capture_beat_ms: AtomicU64,
    fusion_beat_ms: AtomicU64,
    capture_ended: AtomicBool,
    fusion_ended: AtomicBool,
}

impl Default for Liveness {
    fn default() -> Self {
        Self {
            started: Instant::now(),
            capture_beat_ms: AtomicU64::new(0),
            fusion_beat_ms: AtomicU64::new(0),
            capture_ended: AtomicBool::new(false),
            fusion_ended: AtomicBool::new(false),
        }
    }
}

/// The stages [`Liveness`] watches.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WatchedStage {
    /// The capture thread.
    Capture,
    /// The fusion thread.
    Fusion,
}

impl Liveness {
    fn now_ms(&self) -> u64 {
        // +1 so that a beat in the first millisecond is not "never".
        self.started.elapsed().as_millis() as u64 + 1
    }

    fn slots(&self, stage: WatchedStage) -> (&AtomicU64, &AtomicBool) {
        match stage {
            WatchedStage::Capture => (&self.capture_beat_ms, &self.capture_ended),
            WatchedStage::Fusion => (&self.fusion_beat_ms, &self.fusion_ended),
        }
    }

    /// The stage's thread went round its loop.
    pub fn beat(&self, stage: WatchedStage) {
        self.slots(stage).0.store(self.now_ms(), Ordering::Relaxed);
    }

    /// The stage's thread ended normally (end of a finite source, the shutdown ladder): it is
    /// no longer expected to beat.
    pub fn ended(&self, stage: WatchedStage) {
        self.slots(stage).1.store(true, Ordering::Relaxed);
    }

    /// `Ok` when every watched stage beat within `max_age` (or ended normally); otherwise what
    /// is stalled, e.g. `fusion thread silent for 12.3 s`. A stage that never beat counts from
    /// the pipeline's start.
    pub fn check(&self, max_age: Duration) -> Result<(), String> {
        let now = self.now_ms();
        let mut stalled = Vec::new();
        for (stage, name) in [(WatchedStage::Capture, "capture"), (WatchedStage::Fusion, "fusion")] {
            let (beat, ended) = self.slots(stage);
            if ended.load(Ordering::Relaxed) {
                continue;
            }
            let age_ms = now.saturating_sub(beat.load(Ordering::Relaxed));
            if age_ms > max_age.as_millis() as u64 {
                stalled.push(format!("{name} thread silent for {:.1} s", age_ms as f64 / 1000.0));
            }
        }
        if stalled.is_empty() { Ok(()) } else { Err(stalled.join(", ")) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_silent_stage_is_named_and_an_ended_one_is_not() {
        let liveness = Liveness::default();
        liveness.beat(WatchedStage::Capture);
        liveness.beat(WatchedStage::Fusion);
        assert_eq!(liveness.check(Duration::from_secs(5)), Ok(()));
        std::thread::sleep(Duration::from_millis(30));
        liveness.beat(WatchedStage::Capture);
        let err = liveness.check(Duration::from_millis(10)).unwrap_err();
        assert!(err.starts_with("fusion thread silent for"), "{err}");
        liveness.ended(WatchedStage::Fusion);
        assert_eq!(liveness.check(Duration::from_millis(10)), Ok(()));
    }
}
