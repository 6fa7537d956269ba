//! A detection worker's thread: takes keyframes under a ticket lock (gapless tickets, so
//! fusion applies results in order), runs its own detector through the keyframe path.

use std::sync::Mutex;
use std::time::Instant;

use tracing::warn;

use super::Detector;
use crate::keyframe_path;
use crate::pipeline::PipelineStats;
use crate::pipeline::items::{DetectionBatch, KeyframeItem, POLL};
use crate::queue::{Popped, QueueReceiver, QueueSender};

pub(crate) fn detect_loop(
    worker: usize,
    mut detector: Box<dyn Detector>,
    tickets: &Mutex<(QueueReceiver<KeyframeItem>, u64)>,
    det_tx: &QueueSender<DetectionBatch>,
    stats: &PipelineStats,
) {
    let stage = stats.stage(&format!("detect/{worker}"));
    let mut failures = 0u64;
    loop {
        let taken = {
            let Ok(mut guard) = tickets.lock() else { break };
            match guard.0.pop_timeout(POLL) {
                Popped::Item(item) => {
                    let ticket = guard.1;
                    guard.1 += 1;
                    Some((ticket, item))
                }
                Popped::Empty => None,
                Popped::Finished => break,
            }
        };
        // On stop, keep draining until the gate closes the queue: the ladder is ordered.
        let Some((ticket, item)) = taken else { continue };
        let started = Instant::now();
        let mut detections = Vec::new();
        if let Err(e) = keyframe_path::detect(detector.as_mut(), &item.frame, &mut detections) {
            stage.record_error();
            failures += 1;
            if failures <= 3 || failures.is_power_of_two() {
                warn!(worker, frame_seq = item.frame.seq, failures, error = %e, "detection failed; keyframe fused empty");
            }
        } else {
            stage.record(started);
        }
        // Always send, even empty, so fusion's ticket sequence has no gaps.
        det_tx.push(DetectionBatch {
            ticket,
            frame: item.frame,
            captured_at: item.captured_at,
            world_from_camera: item.world_from_camera,
            detections,
        });
    }
}
