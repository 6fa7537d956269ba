//! The keyframe gate's thread: poses in, frames in, keyframes (with their pose) out.
//!
//! Frames are resolved in arrival order. With `pose.source = "ipc"` a frame stamped after the
//! newest pose waits (here, up to `pose.max_wait_ms`) for the pose after it; the frames behind it
//! wait with it, so keyframes leave in order. While [`MAX_PENDING_FRAMES`] wait, no more frames
//! are taken: the frames queue's policy applies to the rest (`latest_wins` drops the oldest and
//! counts it, `block` holds the capture thread).

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::Receiver;
use op3dsg_drivers::pose::{PoseAt, PoseMiss};
use op3dsg_drivers::source::StampClock;
use op3dsg_ipc_types::PoseStamped;

use super::log_limit::{LOG_PERIOD, LogLimit};
use super::{GateDecision, KeyframeGate, MAX_PENDING_FRAMES, PoseRefusal};
use crate::config::PoseSourceKind;
use crate::pipeline::PipelineStats;
use crate::pipeline::items::{CapturedFrame, KeyframeItem, POLL};
use crate::queue::{Popped, QueueReceiver, QueueSender};
use crate::record::{RecordSender, SideChannelTap};

/// How often a waiting frame checks for its pose.
const WAIT_POLL: Duration = Duration::from_millis(2);

/// A frame waiting for its pose, and when it reached the gate.
struct Pending {
    captured: CapturedFrame,
    arrived: Instant,
}

/// The gate's per-reason warnings (refused poses, frames without a pose).
struct GateLogs {
    refusals: LogLimit<{ PoseRefusal::ALL.len() }>,
    misses: LogLimit<{ PoseMiss::ALL.len() }>,
}

impl GateLogs {
    fn refused(&mut self, pose: &PoseStamped, reason: PoseRefusal) {
        if let Some(suppressed) = self.refusals.allow(reason.index(), Instant::now()) {
            tracing::warn!(
                stamp_ns = pose.stamp_ns,
                reason = reason.as_str(),
                not_logged_since_last = suppressed,
                "pose not adopted ({}); counted in health",
                reason.as_str()
            );
        }
    }

    fn missed(&mut self, frame_seq: u64, stamp_ns: u64, miss: PoseMiss, source: PoseSourceKind) {
        let index = PoseMiss::ALL.iter().position(|m| *m == miss).unwrap_or(0);
        if let Some(suppressed) = self.misses.allow(index, Instant::now()) {
            let why = if source == PoseSourceKind::Frame { "the frame carries no pose" } else { miss.as_str() };
            tracing::warn!(
                frame_seq,
                frame_stamp_ns = stamp_ns,
                not_logged_since_last = suppressed,
                "frame dropped without a pose: {why}"
            );
        }
    }
}

#[allow(clippy::too_many_arguments)]
pub(crate) fn keyframe_loop(
    config: &crate::config::KeyframeConfig,
    pose_config: &crate::config::PoseConfig,
    frame_clock: StampClock,
    frames_rx: QueueReceiver<CapturedFrame>,
    kf_tx: QueueSender<KeyframeItem>,
    pose_rx: Receiver<PoseStamped>,
    stats: &PipelineStats,
    stop: &AtomicBool,
    mut recorder: Option<(RecordSender, Vec<Box<dyn SideChannelTap>>)>,
    occupancy: Option<crate::occupancy::service::OccupancyFeed>,
) {
    let stage = stats.stage("keyframe");
    let mut gate = KeyframeGate::new(config, pose_config);
    gate.set_frame_clock(frame_clock);
    let mut logs = GateLogs { refusals: LogLimit::new(LOG_PERIOD), misses: LogLimit::new(LOG_PERIOD) };
    let mut pending: VecDeque<Pending> = VecDeque::with_capacity(MAX_PENDING_FRAMES + 1);
    let mut upstream_done = false;
    loop {
        let stopping = stop.load(Ordering::Relaxed);
        if upstream_done || stopping || pending.len() >= MAX_PENDING_FRAMES {
            if pending.is_empty() {
                break;
            }
            // Let the waiting frames' poses come (or their wait end).
            std::thread::sleep(WAIT_POLL);
        } else {
            match frames_rx.pop_timeout(if pending.is_empty() { POLL } else { WAIT_POLL }) {
                Popped::Item(captured) => {
                    // Every frame the gate receives is the pipeline's input: recorded for replay
                    // (a copy into the recorder's pool, or a counted drop; never a wait).
                    if let Some((sender, taps)) = recorder.as_mut() {
                        sender.offer_frame(&captured.frame, taps);
                    }
                    gate.note_frame(captured.frame.stamp_ns);
                    pending.push_back(Pending { captured, arrived: Instant::now() });
                }
                Popped::Empty => {}
                Popped::Finished => upstream_done = true,
            }
        }
        for pose in pose_rx.try_iter() {
            // Recorded as received, in order with the frames: a replay gives the gate the same.
            if let Some((sender, _)) = recorder.as_mut() {
                sender.offer_input_pose(&pose);
            }
            let outcome = gate.add_pose(&pose);
            stats.pose.count_gate(outcome);
            if let Err(reason) = outcome {
                logs.refused(&pose, reason);
            }
        }
        // Resolve waiting frames in order; the oldest goes without waiting once too many wait.
        while let Some(front) = pending.front() {
            let may_wait = front.arrived.elapsed() < gate.max_wait() && !stopping;
            let answer = gate.pose_for(&front.captured.frame, may_wait);
            if answer == PoseAt::WaitForLater {
                break;
            }
            let Some(Pending { captured: CapturedFrame { frame, captured_at }, .. }) = pending.pop_front() else {
                break;
            };
            let started = Instant::now();
            match answer.pose() {
                None => {
                    stats.frames_without_pose.fetch_add(1, Ordering::Relaxed);
                    let miss = match answer {
                        PoseAt::Missing(miss) => miss,
                        _ => PoseMiss::Empty,
                    };
                    logs.missed(frame.seq, frame.stamp_ns, miss, gate.pose_source());
                }
                Some(world_from_camera) => match gate.judge(&frame, world_from_camera) {
                    GateDecision::Keyframe(world_from_camera) => {
                        stage.record(started);
                        stats.keyframes.fetch_add(1, Ordering::Relaxed);
                        if let Some((sender, _)) = recorder.as_mut() {
                            sender.offer_keyframe(frame.stamp_ns, &world_from_camera);
                        }
                        // The occupancy map's copy of the subsampled depth (never waits).
                        if let Some(feed) = &occupancy {
                            feed.offer(&frame, &world_from_camera);
                        }
                        kf_tx.push(KeyframeItem { frame, captured_at, world_from_camera });
                    }
                    GateDecision::Skip | GateDecision::NoPose => stage.record(started),
                },
            }
        }
        gate.set_oldest_waiting(pending.front().map(|p| p.captured.frame.stamp_ns));
    }
}
