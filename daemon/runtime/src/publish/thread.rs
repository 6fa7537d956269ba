//! The publisher thread `op3dsg-publish`: sends each graph version and the periodic health record
//! over iceoryx2, takes poses in from `<prefix>/pose` for the keyframe gate, and keeps serving
//! until the stop.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;
use op3dsg_ipc_types::{Health, PoseStamped};
use tracing::{debug, info, warn};

use crate::flow::{GraphItem, LatestGraph, POLL, RemoteFeed, hand_over_pose};
use crate::ipc::{GraphOrigin, GraphServer, IpcConfig, PoseCheckCounts};
use crate::queue::{Popped, QueueReceiver};
use crate::record::RecordSender;
use crate::stats::{HealthSource, PoseStats, StageStats};

/// The publisher's stage figures.
#[derive(Debug)]
pub struct PublishCounters {
    /// The `publish` stage: one graph version encoded and sent.
    pub stage: Arc<StageStats>,
    /// `end_to_end`: from the moment the source delivered a keyframe to the send of the first
    /// graph version holding it (queueing included).
    pub end_to_end: Arc<StageStats>,
}

impl Default for PublishCounters {
    fn default() -> Self {
        Self { stage: Arc::new(StageStats::new("publish")), end_to_end: Arc::new(StageStats::new("end_to_end")) }
    }
}

/// The publisher thread, built by the composition; [`PublishThread::run`] is its body. It opens
/// the iceoryx2 services itself (they belong to its thread) and says on `ready` whether it could.
pub struct PublishThread {
    /// `[ipc]`.
    pub ipc: IpcConfig,
    /// The opened source's kind and the world frame's name, in every graph header and health
    /// record.
    pub origin: GraphOrigin,
    /// Where the keyframe gate takes poses from (`pose.source`), as health's `pose_source`
    /// ([`op3dsg_ipc_types::POSE_SOURCES`]).
    pub pose_source: u8,
    /// Told once the services exist, or why they could not be made.
    pub ready: Sender<Result<(), String>>,
    /// From fusion.
    pub graph_rx: QueueReceiver<GraphItem>,
    /// Received poses go to the keyframe gate (`pose.source = "ipc"`), else they are only
    /// checked and counted.
    pub pose_tx: Option<Sender<PoseStamped>>,
    /// The record the health service sends.
    pub health: Arc<dyn HealthSource>,
    /// The pose input's counters (wire checks, hand-over drops).
    pub pose_stats: Arc<PoseStats>,
    /// This stage's figures.
    pub counters: Arc<PublishCounters>,
    /// The daemon's stop flag.
    pub stop: Arc<AtomicBool>,
    /// `health.period_ms`.
    pub health_period: Duration,
    /// `health.log_every_periods`.
    pub log_every: u32,
    /// `run.exit_at_end`: end once the pipeline drained instead of serving until the stop.
    pub exit_at_end: bool,
    /// The MCAP recorder (graphs, health), when on.
    pub recorder: Option<RecordSender>,
    /// The query service's copy of the newest graph, when queries are on.
    pub query_graph: Option<Arc<LatestGraph>>,
    /// The off-robot stage's hand-over (`[zenoh] enabled`).
    pub remote: Option<RemoteFeed>,
}

impl std::fmt::Debug for PublishThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PublishThread").field("prefix", &self.ipc.prefix).finish_non_exhaustive()
    }
}

impl PublishThread {
    /// Opens the services, then publishes until the pipeline drained and the stop flag is set
    /// (or, with `exit_at_end`, once it drained).
    pub fn run(mut self) {
        let mut server = match GraphServer::open(&self.ipc, "op3dsgd") {
            Ok(mut server) => {
                server.set_origin(self.origin);
                let _ = self.ready.send(Ok(()));
                server
            }
            Err(e) => {
                let _ = self.ready.send(Err(e.to_string()));
                return;
            }
        };
        let mut next_health = Instant::now();
        let mut periods = 0u32;
        let mut upstream_done = false;
        let mut poses = Vec::new();
        let mut publish_errors = 0u64;
        let mut reported_pose_checks = PoseCheckCounts::default();
        loop {
            match self.graph_rx.pop_timeout(if upstream_done { Duration::from_millis(100) } else { POLL }) {
                Popped::Item(item) => self.publish(&mut server, item, &mut publish_errors),
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
            self.take_poses(&mut server, &mut poses, &mut reported_pose_checks);
            let stopping = self.stop.load(Ordering::Relaxed);
            if Instant::now() >= next_health || upstream_done && stopping {
                self.send_health(&mut server, &mut periods);
                next_health = Instant::now() + self.health_period;
            }
            if upstream_done && (stopping || self.exit_at_end) {
                // One last health record so watchers see the final counters.
                let health = self.health_record(&mut server);
                let _ = server.publish_health(&health);
                if let Some(latest) = self.query_graph.as_ref() {
                    latest.close();
                }
                break;
            }
        }
    }

    fn publish(&mut self, server: &mut GraphServer, item: GraphItem, publish_errors: &mut u64) {
        let GraphItem { graph, newest_capture } = item;
        let started = Instant::now();
        match server.publish_graph(&graph) {
            Ok(report) => {
                self.counters.stage.record(started);
                if let Some(captured_at) = newest_capture {
                    self.counters.end_to_end.record(captured_at);
                }
                if report.truncated {
                    warn!(
                        version = graph.version,
                        "graph exceeds the sample capacity (ipc.max_nodes / ipc.max_edges); truncated"
                    );
                }
                // The query worker and the off-robot stage read one copy, taken here, off the
                // fusion thread; neither can hold the publisher (a slot, a latest-wins queue).
                if self.query_graph.is_some() || self.remote.is_some() {
                    let copy = (Arc::new(graph.clone()), server.instance_id());
                    if let Some(remote) = self.remote.as_ref() {
                        for graphs in &remote.graphs {
                            graphs.push(copy.clone());
                        }
                    }
                    if let Some(latest) = self.query_graph.as_ref() {
                        latest.set(copy);
                    }
                }
                // Sent already: the recorder takes the graph itself, no copy.
                if let Some(recorder) = self.recorder.as_mut() {
                    recorder.offer_graph(graph);
                }
            }
            Err(e) => {
                self.counters.stage.record_error();
                *publish_errors += 1;
                if publish_errors.is_power_of_two() {
                    warn!(error = %e, publish_errors = *publish_errors, "graph publish failed");
                }
            }
        }
    }

    /// Checks and counts the poses received since the last tick, and hands them to the gate.
    fn take_poses(&self, server: &mut GraphServer, poses: &mut Vec<PoseStamped>, reported: &mut PoseCheckCounts) {
        poses.clear();
        if let Err(e) = server.poll_poses(poses) {
            debug!(error = %e, "pose receive failed");
        }
        add_wire_checks(&self.pose_stats, server.pose_checks(), reported);
        if let Some(pose_tx) = &self.pose_tx {
            for pose in poses.drain(..) {
                let _ = hand_over_pose(pose_tx, pose, &self.pose_stats, "pose");
            }
        }
    }

    /// The health record now: the stages' counters, the planners' part, the origin.
    fn health_record(&self, server: &mut GraphServer) -> Health {
        let mut health = self.health.health();
        server.planner_health(&mut health);
        self.origin.stamp_health(&mut health);
        health.pose_source = self.pose_source;
        health
    }

    fn send_health(&mut self, server: &mut GraphServer, periods: &mut u32) {
        let health = self.health_record(server);
        if let Err(e) = server.publish_health(&health) {
            warn!(error = %e, "health publish failed");
        }
        if let Some(recorder) = self.recorder.as_mut() {
            recorder.offer_health(&health);
        }
        if let Some(remote) = self.remote.as_ref() {
            remote.health.set((health, server.instance_id()));
        }
        *periods += 1;
        if self.log_every > 0 && periods.is_multiple_of(self.log_every) {
            log_summary(&health);
        }
    }
}

fn log_summary(health: &Health) {
    info!(
        frames = health.frames_captured,
        keyframes = health.keyframes,
        graph_version = health.graph_version,
        map_nodes = health.map_node_count,
        map_mib = format_args!("{:.1}", crate::stats::mib(health.map_memory_bytes)),
        "running"
    );
}

/// Adds the receiver's wire-check counts that are new since `reported` to `stats`, and remembers
/// them there.
pub fn add_wire_checks(stats: &PoseStats, checks: &PoseCheckCounts, reported: &mut PoseCheckCounts) {
    let add = |counter: &std::sync::atomic::AtomicU64, now: u64, before: &mut u64| {
        counter.fetch_add(now.saturating_sub(*before), Ordering::Relaxed);
        *before = now;
    };
    add(&stats.unknown_kind, checks.unknown_kind, &mut reported.unknown_kind);
    add(&stats.non_finite, checks.non_finite, &mut reported.non_finite);
    add(&stats.non_unit_quaternion, checks.non_unit_quaternion, &mut reported.non_unit_quaternion);
}
