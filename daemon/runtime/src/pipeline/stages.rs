//! The stage loops: capture, keyframe gate, detection workers, fusion, publisher. Each runs on
//! its own named thread (started by [`super::Pipeline::start`]) between bounded queues.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender};
use op3dsg_drivers::frame::{FramePool, PooledFrame};
use op3dsg_drivers::pose::Isometry;
use op3dsg_drivers::source::{FrameSource, SourceStatus};
use op3dsg_ipc_types::PoseStamped;
use tracing::{debug, error, info, warn};

use super::PipelineStats;
use crate::config::PoseSourceKind;
use crate::fusion::Fusion;
use crate::graph::SceneGraph;
use crate::ipc::GraphServer;
use crate::keyframe::{GateDecision, KeyframeGate};
use crate::keyframe_path::{self, Refinement};
use crate::perception::{Detection, Detector};
use crate::queue::{Popped, QueueReceiver, QueueSender};
use crate::reasoner::GraphEnricher;

/// How long a stage waits on an empty queue before it checks the stop flag again.
const POLL: Duration = Duration::from_millis(20);

/// A frame as the source delivered it, with the moment it was delivered (the start of the
/// `end_to_end` latency).
pub(super) struct CapturedFrame {
    pub(super) frame: PooledFrame,
    pub(super) captured_at: Instant,
}

pub(super) struct KeyframeItem {
    pub(super) frame: PooledFrame,
    pub(super) captured_at: Instant,
    pub(super) world_from_camera: Isometry,
}

pub(super) struct DetectionBatch {
    pub(super) ticket: u64,
    pub(super) frame: PooledFrame,
    pub(super) captured_at: Instant,
    pub(super) world_from_camera: Isometry,
    pub(super) detections: Vec<Detection>,
}

/// A graph version for the publisher, with the capture moment of the newest keyframe fused into
/// it (`None` before the first keyframe).
pub(super) struct GraphItem {
    pub(super) graph: SceneGraph,
    pub(super) newest_capture: Option<Instant>,
}

pub(super) fn capture_loop(
    source: &mut dyn FrameSource,
    pool: &FramePool,
    frames_tx: QueueSender<CapturedFrame>,
    rate_hz: f64,
    max_frames: u64,
    stats: &PipelineStats,
    stop: &AtomicBool,
) {
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
        match status {
            Ok(SourceStatus::Frame) => {
                consecutive_errors = 0;
                delivered += 1;
                stats.frames_captured.fetch_add(1, Ordering::Relaxed);
                stage.record(started);
                tracing::trace!(frame_seq = frame.seq, "captured");
                frames_tx.push(CapturedFrame { frame, captured_at: Instant::now() });
            }
            Ok(SourceStatus::Pending) => {}
            Ok(SourceStatus::EndOfStream) => {
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
}

pub(super) fn keyframe_loop(
    config: &crate::config::KeyframeConfig,
    pose_config: &crate::config::PoseConfig,
    frames_rx: QueueReceiver<CapturedFrame>,
    kf_tx: QueueSender<KeyframeItem>,
    pose_rx: Receiver<PoseStamped>,
    stats: &PipelineStats,
    stop: &AtomicBool,
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
            if !gate.add_pose(&pose) {
                stats.poses_rejected.fetch_add(1, Ordering::Relaxed);
            }
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
                kf_tx.push(KeyframeItem { frame, captured_at, world_from_camera });
            }
        }
    }
}

pub(super) fn detect_loop(
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

pub(super) fn fusion_loop(
    mut fusion: Box<dyn Fusion>,
    mut enricher: Option<GraphEnricher>,
    det_rx: QueueReceiver<DetectionBatch>,
    graph_tx: QueueSender<GraphItem>,
    stats: &PipelineStats,
    min_interval: Duration,
) {
    let stage = stats.stage("fusion");
    let prior_stage = stats.stage("prior");
    let mut newest_capture: Option<Instant> = None;
    let mut pending: BTreeMap<u64, DetectionBatch> = BTreeMap::new();
    let mut next_ticket = 0u64;
    let mut version = 0u64;
    let mut stamp_ns = 0u64;
    let mut dirty = false;
    let mut last_publish: Option<Instant> = None;
    let mut publish = |fusion: &dyn Fusion, version: &mut u64, stamp_ns: u64, newest_capture: Option<Instant>| {
        *version += 1;
        let mut graph = keyframe_path::map_graph(fusion, *version, stamp_ns);
        if let Some(enricher) = enricher.as_mut() {
            let started = Instant::now();
            keyframe_path::enrich(enricher, &mut graph, Refinement::Asynchronous);
            prior_stage.record(started);
        }
        stats.graph_version.store(*version, Ordering::Relaxed);
        stats.map_node_count.store(fusion.node_count() as u64, Ordering::Relaxed);
        stats.map_memory_bytes.store(fusion.memory_bytes() as u64, Ordering::Relaxed);
        graph_tx.push(GraphItem { graph, newest_capture });
    };
    loop {
        let finished = match det_rx.pop_timeout(POLL) {
            Popped::Item(batch) => {
                pending.insert(batch.ticket, batch);
                false
            }
            Popped::Empty => false,
            Popped::Finished => true,
        };
        // Apply results in ticket order; at the end, apply what is left in order (a gap can only
        // come from a worker that gave up during shutdown).
        while let Some(batch) =
            pending.remove(&next_ticket).or_else(|| if finished { pending.pop_first().map(|(_, b)| b) } else { None })
        {
            next_ticket = batch.ticket + 1;
            let started = Instant::now();
            let fused = keyframe_path::fuse(fusion.as_mut(), &batch.frame, &batch.world_from_camera, &batch.detections);
            let report = fused.report;
            stats.detections_fused.fetch_add(batch.detections.len() as u64, Ordering::Relaxed);
            stamp_ns = stamp_ns.max(batch.frame.stamp_ns);
            newest_capture = newest_capture.max(Some(batch.captured_at));
            stage.record(started);
            tracing::trace!(
                frame_seq = batch.frame.seq,
                merged = report.merged,
                created = report.created,
                ignored = report.ignored,
                "fused"
            );
            dirty |= fused.changed();
        }
        let due = last_publish.is_none_or(|t| t.elapsed() >= min_interval);
        if dirty && (due || finished) {
            publish(fusion.as_ref(), &mut version, stamp_ns, newest_capture);
            last_publish = Some(Instant::now());
            dirty = false;
        }
        if finished {
            if version == 0 {
                // Publish an empty graph so clients see the daemon served.
                publish(fusion.as_ref(), &mut version, stamp_ns, newest_capture);
            }
            break;
        }
    }
}

#[allow(clippy::too_many_arguments)]
pub(super) fn publisher_loop(
    mut server: GraphServer,
    graph_rx: QueueReceiver<GraphItem>,
    pose_tx: Sender<PoseStamped>,
    pose_source: PoseSourceKind,
    stats: &PipelineStats,
    stop: &AtomicBool,
    health_period: Duration,
    log_every: u32,
    exit_at_end: bool,
) {
    let stage = stats.stage("publish");
    let end_to_end = stats.stage("end_to_end");
    let mut next_health = Instant::now();
    let mut periods = 0u32;
    let mut upstream_done = false;
    let mut poses = Vec::new();
    let mut publish_errors = 0u64;
    loop {
        match graph_rx.pop_timeout(if upstream_done { Duration::from_millis(100) } else { POLL }) {
            Popped::Item(GraphItem { graph, newest_capture }) => {
                let started = Instant::now();
                match server.publish_graph(&graph) {
                    Ok(report) => {
                        stage.record(started);
                        if let Some(captured_at) = newest_capture {
                            end_to_end.record(captured_at);
                        }
                        if report.truncated {
                            warn!(version = graph.version, "graph exceeds the snapshot capacity; truncated");
                        }
                    }
                    Err(e) => {
                        stage.record_error();
                        publish_errors += 1;
                        if publish_errors.is_power_of_two() {
                            warn!(error = %e, publish_errors, "graph publish failed");
                        }
                    }
                }
            }
            Popped::Empty => {}
            Popped::Finished => {
                if !upstream_done {
                    info!("pipeline drained; final graph published");
                }
                upstream_done = true;
            }
        }
        // Late joiners get the history sample when the publisher updates its connections, so
        // do it on every tick, not only when the graph changes.
        if let Err(e) = server.update_connections() {
            debug!(error = %e, "update connections failed");
        }
        poses.clear();
        if let Err(e) = server.poll_poses(&mut poses) {
            debug!(error = %e, "pose receive failed");
        }
        if pose_source == PoseSourceKind::Ipc {
            for pose in poses.drain(..) {
                // The gate drains this channel every frame; if it is full the oldest poses are
                // the least useful, but losing the newest is acceptable too: count and go on.
                if pose_tx.try_send(pose).is_err() {
                    stats.poses_rejected.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
        if Instant::now() >= next_health || upstream_done && stop.load(Ordering::Relaxed) {
            let health = stats.health();
            if let Err(e) = server.publish_health(&health) {
                warn!(error = %e, "health publish failed");
            }
            periods += 1;
            if log_every > 0 && periods.is_multiple_of(log_every) {
                info!(
                    frames = health.frames_captured,
                    keyframes = health.keyframes,
                    graph_version = health.graph_version,
                    map_nodes = health.map_node_count,
                    map_mib = format_args!("{:.1}", crate::stats::mib(health.map_memory_bytes)),
                    "running"
                );
            }
            next_health = Instant::now() + health_period;
        }
        if upstream_done && (stop.load(Ordering::Relaxed) || exit_at_end) {
            // One last health record so watchers see the final counters.
            let _ = server.publish_health(&stats.health());
            break;
        }
    }
}
