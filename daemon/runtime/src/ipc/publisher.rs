//! The publisher thread: sends each graph version and the periodic health record over
//! iceoryx2, takes poses in from `<prefix>/pose`, and keeps serving until the stop.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;
use op3dsg_ipc_types::PoseStamped;
use tracing::{debug, info, warn};

use super::GraphServer;
use crate::config::PoseSourceKind;
use crate::pipeline::PipelineStats;
use crate::pipeline::items::{GraphItem, POLL};
use crate::queue::{Popped, QueueReceiver};
use crate::record::RecordSender;

#[allow(clippy::too_many_arguments)]
pub(crate) fn publisher_loop(
    mut server: GraphServer,
    graph_rx: QueueReceiver<GraphItem>,
    pose_tx: Sender<PoseStamped>,
    pose_source: PoseSourceKind,
    stats: &PipelineStats,
    stop: &AtomicBool,
    health_period: Duration,
    log_every: u32,
    exit_at_end: bool,
    mut recorder: Option<RecordSender>,
    query_graph: Option<std::sync::Arc<crate::query::service::LatestGraph>>,
) {
    let stage = stats.stage("publish");
    let end_to_end = stats.stage("end_to_end");
    let mut next_health = Instant::now();
    let mut periods = 0u32;
    let mut upstream_done = false;
    let mut poses = Vec::new();
    let mut publish_errors = 0u64;
    let mut reported_pose_checks = super::PoseCheckCounts::default();
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
                            warn!(
                                version = graph.version,
                                "graph exceeds the sample capacity (ipc.max_nodes / ipc.max_edges); truncated"
                            );
                        }
                        // The query worker reads its own copy, taken here, off the fusion thread.
                        if let Some(latest) = query_graph.as_ref() {
                            latest.set(std::sync::Arc::new(graph.clone()), server.instance_id());
                        }
                        // Sent already: the recorder takes the graph itself, no copy.
                        if let Some(recorder) = recorder.as_mut() {
                            recorder.offer_graph(graph);
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
        stats.pose.add_checks(server.pose_checks(), &mut reported_pose_checks);
        if pose_source == PoseSourceKind::Ipc {
            for pose in poses.drain(..) {
                // The gate drains this channel every frame; if it is full the oldest poses are
                // the least useful, but losing the newest is acceptable too: count and go on.
                if pose_tx.try_send(pose).is_err() {
                    let dropped = stats.pose.queue_full.fetch_add(1, Ordering::Relaxed) + 1;
                    if dropped.is_power_of_two() {
                        warn!(dropped, "pose hand-over queue to the keyframe gate full; pose dropped");
                    }
                }
            }
        }
        if Instant::now() >= next_health || upstream_done && stop.load(Ordering::Relaxed) {
            let mut health = stats.health();
            server.planner_health(&mut health);
            if let Err(e) = server.publish_health(&health) {
                warn!(error = %e, "health publish failed");
            }
            if let Some(recorder) = recorder.as_mut() {
                recorder.offer_health(&health);
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
            let mut health = stats.health();
            server.planner_health(&mut health);
            let _ = server.publish_health(&health);
            if let Some(latest) = query_graph.as_ref() {
                latest.close();
            }
            break;
        }
    }
}
