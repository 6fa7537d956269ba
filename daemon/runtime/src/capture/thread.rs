//! The capture thread `op3dsg-capture`: reads the frame source into pooled frames and hands them
//! to the keyframe gate (latest-wins), pacing the source at `source.rate_hz`.

use std::ops::ControlFlow;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;
use op3dsg_drivers::frame::FramePool;
use op3dsg_drivers::mcap::messages::{InputPose, InputPoseKind};
use op3dsg_drivers::source::{FrameSource, SourceStatus};
use op3dsg_ipc_types::{PoseKind, PoseStamped, write_fixed_str};
use tracing::{error, info, warn};

use super::CaptureCounters;
use crate::flow::{CapturedFrame, hand_over_pose};
use crate::queue::QueueSender;
use crate::stats::{Liveness, PoseStats, WatchedStage};

/// The capture thread, built by the composition with everything it uses; [`CaptureThread::run`]
/// is the thread's body.
pub struct CaptureThread {
    /// The frame source (opened by its backend).
    pub source: Box<dyn FrameSource>,
    /// Frames to fill (sized for every queue and worker, see `Profile::frame_pool_capacity`).
    pub pool: FramePool,
    /// To the keyframe gate.
    pub frames_tx: QueueSender<CapturedFrame>,
    /// Where a replayed recording's input poses go (`pose.source = "ipc"`), `None` otherwise.
    pub pose_tx: Option<Sender<PoseStamped>>,
    /// Delivery rate, Hz (0 = as fast as the pipeline takes frames).
    pub rate_hz: f64,
    /// Stop after this many frames (0 = no limit).
    pub max_frames: u64,
    /// This stage's counters.
    pub counters: Arc<CaptureCounters>,
    /// The pose input's counters (recorded poses the gate had no room for).
    pub pose_stats: Arc<PoseStats>,
    /// The watchdog's heartbeats.
    pub liveness: Arc<Liveness>,
    /// The daemon's stop flag.
    pub stop: Arc<AtomicBool>,
}

impl std::fmt::Debug for CaptureThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CaptureThread").field("source", &self.source.describe()).finish_non_exhaustive()
    }
}

impl CaptureThread {
    /// Reads frames until the stop flag, the end of a finite source, `max_frames`, or a source
    /// that stops on bad data.
    pub fn run(mut self) {
        let period = (self.rate_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / self.rate_hz));
        let mut next_due = Instant::now();
        let mut progress = Progress::default();
        self.count_skipped(&mut progress);
        while !self.stop.load(Ordering::Relaxed) {
            // Every way round this loop comes back within a pool wait (100 ms), an error backoff
            // (at most 1 s), the pacing period or one `next_frame` (which waits for the camera
            // with a timeout): the systemd watchdog takes a missing beat for a stalled capture.
            self.liveness.beat(WatchedStage::Capture);
            if self.max_frames > 0 && progress.delivered >= self.max_frames {
                info!(frames = progress.delivered, "run.max_frames reached");
                self.counters.source_finished.store(true, Ordering::Relaxed);
                break;
            }
            if let Some(period) = period {
                let now = Instant::now();
                if next_due > now {
                    std::thread::sleep(next_due - now);
                }
                next_due = next_due.max(now - period) + period;
            }
            if self.capture_one(&mut progress).is_break() {
                break;
            }
        }
        self.counters.source_connected.store(false, Ordering::Relaxed);
        self.liveness.ended(WatchedStage::Capture);
    }

    /// Reads one frame into a pooled buffer and hands it on; `Break` when the source ended.
    fn capture_one(&mut self, progress: &mut Progress) -> ControlFlow<()> {
        let Some(mut frame) = self.pool.take_timeout(Duration::from_millis(100)) else {
            self.counters.frames_pool_exhausted.fetch_add(1, Ordering::Relaxed);
            return ControlFlow::Continue(());
        };
        let stage = self.counters.stage.clone();
        let started = Instant::now();
        let status = self.source.next_frame(&mut frame);
        self.count_skipped(progress);
        self.counters.source_connected.store(self.source.connected(), Ordering::Relaxed);
        match status {
            Ok(SourceStatus::Frame) => {
                progress.consecutive_errors = 0;
                progress.delivered += 1;
                self.counters.frames_captured.fetch_add(1, Ordering::Relaxed);
                stage.record(started);
                tracing::trace!(frame_seq = frame.seq, "captured");
                self.replay_input_poses(&mut progress.input_poses);
                self.frames_tx.push(CapturedFrame { frame, captured_at: Instant::now() });
            }
            Ok(SourceStatus::Pending) => {}
            Ok(SourceStatus::EndOfStream) => {
                self.replay_input_poses(&mut progress.input_poses);
                info!(frames = progress.delivered, source = %self.source.describe(), "source ended");
                self.counters.source_finished.store(true, Ordering::Relaxed);
                return ControlFlow::Break(());
            }
            Err(e) if self.source.stops_on_error() => {
                stage.record_error();
                error!(error = %e, source = %self.source.describe(), frames = progress.delivered, "frame source stopped on bad data");
                self.counters.source_failed.store(true, Ordering::Relaxed);
                self.counters.source_finished.store(true, Ordering::Relaxed);
                return ControlFlow::Break(());
            }
            Err(e) => {
                stage.record_error();
                progress.consecutive_errors += 1;
                let consecutive_errors = progress.consecutive_errors;
                if consecutive_errors == 1 || consecutive_errors.is_power_of_two() {
                    warn!(error = %e, consecutive_errors, "frame source error");
                }
                std::thread::sleep(Duration::from_millis(10 * u64::from(consecutive_errors.min(100))));
            }
        }
        ControlFlow::Continue(())
    }

    /// Bad data a replay skipped (it logged each): counted as capture errors for health.
    fn count_skipped(&self, progress: &mut Progress) {
        let skipped = self.source.bad_data_skipped();
        if skipped > progress.skipped_seen {
            self.counters.stage.errors.fetch_add(skipped - progress.skipped_seen, Ordering::Relaxed);
            self.counters.source_bad_data_skipped.store(skipped, Ordering::Relaxed);
            progress.skipped_seen = skipped;
        }
    }

    /// Hands the poses of the pose input a recording holds before a frame, or after its last one
    /// (MCAP replay, see [`FrameSource::take_input_poses`]), to the keyframe gate, as the
    /// publisher hands it live ones. Nothing without `pose.source = "ipc"`.
    fn replay_input_poses(&mut self, buf: &mut Vec<InputPose>) {
        let Some(pose_tx) = &self.pose_tx else { return };
        self.source.take_input_poses(buf);
        for recorded in buf.drain(..) {
            let _ = hand_over_pose(pose_tx, wire_pose(&recorded), &self.pose_stats, "recorded pose");
        }
    }
}

/// What the thread counts as it goes.
#[derive(Default)]
struct Progress {
    delivered: u64,
    consecutive_errors: u32,
    skipped_seen: u64,
    input_poses: Vec<InputPose>,
}

/// A recorded input pose as the pose input receives it.
fn wire_pose(recorded: &InputPose) -> PoseStamped {
    let kind = match recorded.kind {
        InputPoseKind::WorldFromCamera => PoseKind::WorldFromCamera,
        InputPoseKind::WorldFromBase => PoseKind::WorldFromBase,
    };
    let mut pose = PoseStamped {
        stamp_ns: recorded.stamp_ns,
        kind: kind as u8,
        translation_m: recorded.translation_m,
        rotation_xyzw: recorded.rotation_xyzw,
        ..PoseStamped::default()
    };
    // A recorded name fits: it came from a frame id of the same capacity.
    let _ = write_fixed_str(&mut pose.frame_id, &recorded.frame_id);
    pose
}
