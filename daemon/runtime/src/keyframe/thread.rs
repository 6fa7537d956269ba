//! The keyframe gate's thread: poses in, frames in, keyframes (with their pose) out.
//!
//! Frames are resolved in arrival order. With `pose.source = "ipc"` a frame stamped after the
//! newest pose waits (here, up to `pose.max_wait_ms`) for the pose after it; the frames behind it
//! wait with it, so keyframes leave in order. While [`MAX_PENDING_FRAMES`] wait, no more frames
//! are taken: the frames queue's policy applies to the rest (`latest_wins` drops the oldest and
//! counts it, `block` holds the capture thread).

use std::collections::VecDeque;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::Receiver;
use op3dsg_drivers::pose::{Isometry, PoseAt, PoseMiss};
use op3dsg_ipc_types::PoseStamped;

use super::log_limit::{LOG_PERIOD, LogLimit};
use super::{
    GateDecision, KeyframeCounters, KeyframeGate, MAX_PENDING_FRAMES, PoseRefusal, PoseSourceKind, count_gate,
};
use crate::flow::{CapturedFrame, KeyframeItem, LiveFeed, POLL};
use crate::occupancy::OccupancyFeed;
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

/// The recorder's end for the gate: every frame it receives (with the source's side channels),
/// every received pose, every keyframe's pose.
pub type KeyframeRecorder = (RecordSender, Vec<Box<dyn SideChannelTap>>);

/// The keyframe gate's thread, built by the composition; [`KeyframeThread::run`] is its body.
pub struct KeyframeThread {
    /// The gate (made from `[keyframe]` and `[pose]`, with the source's stamp clock set).
    pub gate: KeyframeGate,
    /// From capture.
    pub frames_rx: QueueReceiver<CapturedFrame>,
    /// To the detection workers.
    pub kf_tx: QueueSender<KeyframeItem>,
    /// Received (or replayed) poses.
    pub pose_rx: Receiver<PoseStamped>,
    /// This stage's counters.
    pub counters: Arc<KeyframeCounters>,
    /// The daemon's stop flag.
    pub stop: Arc<AtomicBool>,
    /// The MCAP recorder, when on.
    pub recorder: Option<KeyframeRecorder>,
    /// The occupancy map's scan queue, when on.
    pub occupancy: Option<OccupancyFeed>,
    /// The live view's newest pose and images, when `[live_view] enabled`.
    pub live: Option<LiveFeed>,
}

impl std::fmt::Debug for KeyframeThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("KeyframeThread").field("gate", &self.gate).finish_non_exhaustive()
    }
}

impl KeyframeThread {
    /// Resolves frames in arrival order until capture has closed the frames queue (or the stop
    /// flag is set) and no frame waits.
    pub fn run(mut self) {
        let mut logs = GateLogs { refusals: LogLimit::new(LOG_PERIOD), misses: LogLimit::new(LOG_PERIOD) };
        let mut pending: VecDeque<Pending> = VecDeque::with_capacity(MAX_PENDING_FRAMES + 1);
        let mut upstream_done = false;
        loop {
            let stopping = self.stop.load(Ordering::Relaxed);
            if upstream_done || stopping || pending.len() >= MAX_PENDING_FRAMES {
                if pending.is_empty() {
                    break;
                }
                // Let the waiting frames' poses come (or their wait end).
                std::thread::sleep(WAIT_POLL);
            } else {
                match self.frames_rx.pop_timeout(if pending.is_empty() { POLL } else { WAIT_POLL }) {
                    Popped::Item(captured) => self.take_frame(captured, &mut pending),
                    Popped::Empty => {}
                    Popped::Finished => upstream_done = true,
                }
            }
            self.take_poses(&mut logs);
            self.resolve(&mut pending, stopping, &mut logs);
            self.gate.set_oldest_waiting(pending.front().map(|p| p.captured.frame.stamp_ns));
        }
    }

    fn take_frame(&mut self, captured: CapturedFrame, pending: &mut VecDeque<Pending>) {
        // Every frame the gate receives is the pipeline's input: recorded for replay (a copy into
        // the recorder's pool, or a counted drop; never a wait).
        if let Some((sender, taps)) = self.recorder.as_mut() {
            sender.offer_frame(&captured.frame, taps);
        }
        // The live view's downscaled copy, only while a viewer watches an image (never waits).
        if let Some(live) = self.live.as_mut() {
            live.offer_frame(&captured.frame);
        }
        self.gate.note_frame(captured.frame.stamp_ns);
        pending.push_back(Pending { captured, arrived: Instant::now() });
    }

    fn take_poses(&mut self, logs: &mut GateLogs) {
        for pose in self.pose_rx.try_iter() {
            // Recorded as received, in order with the frames: a replay gives the gate the same.
            if let Some((sender, _)) = self.recorder.as_mut() {
                sender.offer_input_pose(&pose);
            }
            let outcome = self.gate.add_pose(&pose);
            count_gate(&self.counters.pose, outcome);
            if let Err(reason) = outcome {
                logs.refused(&pose, reason);
            }
        }
    }

    /// Resolves waiting frames in order; the oldest goes without waiting once too many wait.
    fn resolve(&mut self, pending: &mut VecDeque<Pending>, stopping: bool, logs: &mut GateLogs) {
        while let Some(front) = pending.front() {
            let may_wait = front.arrived.elapsed() < self.gate.max_wait() && !stopping;
            let answer = self.gate.pose_for(&front.captured.frame, may_wait);
            if answer == PoseAt::WaitForLater {
                break;
            }
            let Some(Pending { captured, .. }) = pending.pop_front() else { break };
            let started = Instant::now();
            match answer.pose() {
                None => {
                    self.counters.frames_without_pose.fetch_add(1, Ordering::Relaxed);
                    let miss = match answer {
                        PoseAt::Missing(miss) => miss,
                        _ => PoseMiss::Empty,
                    };
                    logs.missed(captured.frame.seq, captured.frame.stamp_ns, miss, self.gate.pose_source());
                }
                Some(world_from_camera) => self.judge(captured, world_from_camera, started),
            }
        }
    }

    fn judge(&mut self, captured: CapturedFrame, world_from_camera: Isometry, started: Instant) {
        let CapturedFrame { frame, captured_at } = captured;
        match self.gate.judge(&frame, world_from_camera) {
            GateDecision::Keyframe(world_from_camera) => {
                self.counters.stage.record(started);
                self.counters.keyframes.fetch_add(1, Ordering::Relaxed);
                if let Some((sender, _)) = self.recorder.as_mut() {
                    sender.offer_keyframe(frame.stamp_ns, &world_from_camera);
                }
                if let Some(live) = &self.live {
                    live.offer_keyframe(frame.stamp_ns, &world_from_camera);
                }
                // The occupancy map's copy of the subsampled depth (never waits).
                if let Some(feed) = &self.occupancy {
                    feed.offer(&frame, &world_from_camera);
                }
                self.kf_tx.push(KeyframeItem { frame, captured_at, world_from_camera });
            }
            GateDecision::Skip | GateDecision::NoPose => self.counters.stage.record(started),
        }
    }
}
