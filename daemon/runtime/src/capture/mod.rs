//! Capture: the thread that reads the frame source into pooled frames and hands them to the
//! keyframe gate (latest-wins), pacing the source at `source.rate_hz`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;
use op3dsg_drivers::frame::FramePool;
use op3dsg_drivers::mcap::messages::{InputPose, InputPoseKind};
use op3dsg_drivers::source::{FrameSource, SourceStatus};
use op3dsg_ipc_types::{PoseKind, PoseStamped, write_fixed_str};
use tracing::{error, info, warn};

use crate::pipeline::PipelineStats;
use crate::pipeline::items::CapturedFrame;
use crate::queue::QueueSender;
use crate::service::notify::WatchedStage;

/// Hands the poses of the pose input a recording holds before a frame, or after its last one
/// (MCAP replay, see [`FrameSource::take_input_poses`]), to the keyframe gate, as the publisher
/// hands it live ones.
fn replay_input_poses(
    source: &mut dyn FrameSource,
    pose_tx: &Sender<PoseStamped>,
    buf: &mut Vec<InputPose>,
    stats: &PipelineStats,
) {
    source.take_input_poses(buf);
    for recorded in buf.drain(..) {
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
        if pose_tx.try_send(pose).is_err() {
            let dropped = stats.pose.queue_full.fetch_add(1, Ordering::Relaxed) + 1;
            if dropped.is_power_of_two() {
                warn!(dropped, "pose hand-over queue to the keyframe gate full; recorded pose dropped");
            }
        }
    }
}

/// `pose_tx`: where recorded input poses go (`pose.source = "ipc"`), `None` otherwise.
#[allow(clippy::too_many_arguments)]
pub(crate) fn capture_loop(
    source: &mut dyn FrameSource,
    pool: &FramePool,
    frames_tx: QueueSender<CapturedFrame>,
    pose_tx: Option<Sender<PoseStamped>>,
    rate_hz: f64,
    max_frames: u64,
    stats: &PipelineStats,
    stop: &AtomicBool,
) {
    let mut input_poses = Vec::new();
    let stage = stats.stage("capture");
    let period = (rate_hz > 0.0).then(|| Duration::from_secs_f64(1.0 / rate_hz));
    let mut next_due = Instant::now();
    let mut delivered = 0u64;
    let mut consecutive_errors = 0u32;
    // Bad data a replay skipped (it logged each): counted as capture errors for health.
    let mut skipped_seen = 0u64;
    let mut count_skipped = |source: &dyn FrameSource| {
        let skipped = source.bad_data_skipped();
        if skipped > skipped_seen {
            stage.errors.fetch_add(skipped - skipped_seen, Ordering::Relaxed);
            stats.source_bad_data_skipped.store(skipped, Ordering::Relaxed);
            skipped_seen = skipped;
        }
    };
    count_skipped(source);
    while !stop.load(Ordering::Relaxed) {
        // Every way round this loop comes back within a pool wait (100 ms), an error backoff
        // (at most 1 s), the pacing period or one `next_frame` (which waits for the camera
        // with a timeout): the systemd watchdog takes a missing beat for a stalled capture.
        stats.liveness.beat(WatchedStage::Capture);
        if max_frames > 0 && delivered >= max_frames {
            info!(frames = delivered, "run.max_frames reached");
            stats.source_finished.store(true, Ordering::Relaxed);
            break;
        }
        if let Some(period) = period {
            let now = Instant::now();
            if next_due > now {
                std::thread::sleep(next_due - now);
            }
            next_due = next_due.max(now - period) + period;
        }
        let Some(mut frame) = pool.take_timeout(Duration::from_millis(100)) else {
            stats.frames_pool_exhausted.fetch_add(1, Ordering::Relaxed);
            continue;
        };
        let started = Instant::now();
        let status = source.next_frame(&mut frame);
        count_skipped(source);
        stats.source_connected.store(source.connected(), Ordering::Relaxed);
        match status {
            Ok(SourceStatus::Frame) => {
                consecutive_errors = 0;
                delivered += 1;
                stats.frames_captured.fetch_add(1, Ordering::Relaxed);
                stage.record(started);
                tracing::trace!(frame_seq = frame.seq, "captured");
                if let Some(pose_tx) = &pose_tx {
                    replay_input_poses(source, pose_tx, &mut input_poses, stats);
                }
                frames_tx.push(CapturedFrame { frame, captured_at: Instant::now() });
            }
            Ok(SourceStatus::Pending) => {}
            Ok(SourceStatus::EndOfStream) => {
                if let Some(pose_tx) = &pose_tx {
                    replay_input_poses(source, pose_tx, &mut input_poses, stats);
                }
                info!(frames = delivered, source = %source.describe(), "source ended");
                stats.source_finished.store(true, Ordering::Relaxed);
                break;
            }
            Err(e) if source.stops_on_error() => {
                stage.record_error();
                error!(error = %e, source = %source.describe(), frames = delivered, "frame source stopped on bad data");
                stats.source_failed.store(true, Ordering::Relaxed);
                stats.source_finished.store(true, Ordering::Relaxed);
                break;
            }
            Err(e) => {
                stage.record_error();
                consecutive_errors += 1;
                if consecutive_errors == 1 || consecutive_errors.is_power_of_two() {
                    warn!(error = %e, consecutive_errors, "frame source error");
                }
                std::thread::sleep(Duration::from_millis(10 * u64::from(consecutive_errors.min(100))));
            }
        }
    }
    stats.source_connected.store(false, Ordering::Relaxed);
    stats.liveness.ended(WatchedStage::Capture);
}
