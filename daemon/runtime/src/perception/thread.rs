//! A detection worker's thread `op3dsg-detect-<i>`: takes keyframes under a ticket lock
//! (gapless tickets, so fusion applies results in order) and runs its own detector.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use tracing::warn;

use super::{Detector, detect};
use crate::flow::{DetectionBatch, KeyframeItem, POLL};
use crate::queue::{Popped, QueueReceiver, QueueSender};
use crate::stats::StageStats;

/// The keyframes queue's receiving end and the next ticket, shared by the workers: whoever takes
/// a keyframe takes the next ticket under the same lock.
pub type Tickets = Arc<Mutex<(QueueReceiver<KeyframeItem>, u64)>>;

/// One detection worker, built by the composition; [`DetectThread::run`] is its body.
pub struct DetectThread {
    /// Worker index (thread `op3dsg-detect-<worker>`, stage `detect/<worker>`).
    pub worker: usize,
    /// This worker's detector.
    pub detector: Box<dyn Detector>,
    /// Keyframes with their tickets.
    pub tickets: Tickets,
    /// To fusion.
    pub det_tx: QueueSender<DetectionBatch>,
    /// This worker's stage figures (`detect/<worker>`).
    pub stage: Arc<StageStats>,
}

impl std::fmt::Debug for DetectThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("DetectThread").field("worker", &self.worker).field("detector", &self.detector.name()).finish()
    }
}

impl DetectThread {
    /// Detects on keyframes until the gate closes the keyframes queue (on stop it keeps
    /// draining: the ladder is ordered).
    pub fn run(mut self) {
        let mut failures = 0u64;
        loop {
            let (ticket, item) = match self.take() {
                Taken::Keyframe(ticket, item) => (ticket, item),
                Taken::Nothing => continue,
                Taken::Finished => break,
            };
            let started = Instant::now();
            let mut detections = Vec::new();
            if let Err(e) = detect(self.detector.as_mut(), &item.frame, &mut detections) {
                self.stage.record_error();
                failures += 1;
                if failures <= 3 || failures.is_power_of_two() {
                    warn!(worker = self.worker, frame_seq = item.frame.seq, failures, error = %e, "detection failed; keyframe fused empty");
                }
            } else {
                self.stage.record(started);
            }
            // Always send, even empty, so fusion's ticket sequence has no gaps.
            self.det_tx.push(DetectionBatch {
                ticket,
                frame: item.frame,
                captured_at: item.captured_at,
                world_from_camera: item.world_from_camera,
                detections,
            });
        }
    }

    /// The next keyframe and its ticket.
    fn take(&self) -> Taken {
        let Ok(mut guard) = self.tickets.lock() else { return Taken::Finished };
        match guard.0.pop_timeout(POLL) {
            Popped::Item(item) => {
                let ticket = guard.1;
                guard.1 += 1;
                Taken::Keyframe(ticket, item)
            }
            Popped::Empty => Taken::Nothing,
            Popped::Finished => Taken::Finished,
        }
    }
}

/// What one look at the keyframes queue gave.
enum Taken {
    Keyframe(u64, KeyframeItem),
    /// Nothing within the poll.
    Nothing,
    /// The gate closed the queue (or a worker panicked holding the lock).
    Finished,
}
