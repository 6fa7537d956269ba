//! The keyframe gate's thread: poses in, frames in, keyframes (with their pose) out.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use crossbeam_channel::Receiver;
use op3dsg_ipc_types::PoseStamped;

use super::{GateDecision, KeyframeGate};
use crate::pipeline::PipelineStats;
use crate::pipeline::items::{CapturedFrame, KeyframeItem, POLL};
use crate::queue::{Popped, QueueReceiver, QueueSender};
use crate::record::{RecordSender, SideChannelTap};

#[allow(clippy::too_many_arguments)]
pub(crate) fn keyframe_loop(
    config: &crate::config::KeyframeConfig,
    pose_config: &crate::config::PoseConfig,
    frames_rx: QueueReceiver<CapturedFrame>,
    kf_tx: QueueSender<KeyframeItem>,
    pose_rx: Receiver<PoseStamped>,
    stats: &PipelineStats,
    stop: &AtomicBool,
    mut recorder: Option<(RecordSender, Vec<Box<dyn SideChannelTap>>)>,
) {
    let stage = stats.stage("keyframe");
    let mut gate = KeyframeGate::new(config, pose_config);
    loop {
        let CapturedFrame { frame, captured_at } = match frames_rx.pop_timeout(POLL) {
            Popped::Item(captured) => captured,
            Popped::Empty if stop.load(Ordering::Relaxed) => break,
            Popped::Empty => continue,
            Popped::Finished => break,
        };
        let started = Instant::now();
        for pose in pose_rx.try_iter() {
            let outcome = gate.add_pose(&pose);
            stats.pose.count_gate(outcome);
            if let Err(reason) = outcome {
                tracing::debug!(stamp_ns = pose.stamp_ns, ?reason, "pose not adopted");
            }
        }
        // Every frame the gate receives is the pipeline's input: recorded for replay (a copy into
        // the recorder's pool, or a counted drop; never a wait).
        if let Some((sender, taps)) = recorder.as_mut() {
            sender.offer_frame(&frame, taps);
        }
        match gate.decide(&frame) {
            GateDecision::NoPose => {
                stats.frames_without_pose.fetch_add(1, Ordering::Relaxed);
                tracing::trace!(frame_seq = frame.seq, "no pose within tolerance; frame dropped");
            }
            GateDecision::Skip => stage.record(started),
            GateDecision::Keyframe(world_from_camera) => {
                stage.record(started);
                stats.keyframes.fetch_add(1, Ordering::Relaxed);
                if let Some((sender, _)) = recorder.as_mut() {
                    sender.offer_keyframe(frame.stamp_ns, &world_from_camera);
                }
                kf_tx.push(KeyframeItem { frame, captured_at, world_from_camera });
            }
        }
    }
}
