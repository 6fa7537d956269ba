//! The fusion thread, sole owner of the map: applies detection results in ticket order through
//! the keyframe path, builds each graph version (prior graph and reasoner included) and hands
//! map snapshots to their writer (`crate::service::snapshot`) when they are due.

use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use super::Fusion;
use crate::keyframe_path::{self, Refinement};
use crate::pipeline::PipelineStats;
use crate::pipeline::items::{DetectionBatch, GraphItem, POLL};
use crate::queue::{Popped, QueueReceiver, QueueSender};
use crate::reasoner::GraphEnricher;
use crate::record::RecordSender;
use crate::service::notify::WatchedStage;
use crate::service::snapshot::{self, Snapshot, SnapshotSink};

/// Test-only fault hook: when this variable names a file and that file exists, the fusion
/// thread stops answering (it sleeps without polling its input or beating), as a thread stuck in
/// a bug would. The sd_notify test uses it to see the watchdog pings stop. Never set it in
/// production.
pub const TEST_STALL_FILE_ENV: &str = "OP3DSG_TEST_STALL_FUSION_FILE";

/// Where the map starts: the version and stamp of a restored snapshot.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Resume {
    pub(crate) graph_version: u64,
    pub(crate) stamp_ns: u64,
    /// A map was restored: publish it at once.
    pub(crate) restored: bool,
}

fn take_snapshot(fusion: &dyn Fusion, version: u64, stamp_ns: u64) -> Option<Snapshot> {
    fusion.export_state().map(|map| Snapshot {
        graph_version: version,
        stamp_ns,
        taken_unix_ms: snapshot::now_unix_ms(),
        map,
    })
}

#[allow(clippy::too_many_arguments)]
pub(crate) fn fusion_loop(
    mut fusion: Box<dyn Fusion>,
    mut enricher: Option<GraphEnricher>,
    det_rx: QueueReceiver<DetectionBatch>,
    graph_tx: QueueSender<GraphItem>,
    stats: &PipelineStats,
    min_interval: Duration,
    mut snapshots: Option<SnapshotSink>,
    resume: Resume,
    mut recorder: Option<RecordSender>,
) {
    let stage = stats.stage("fusion");
    let prior_stage = stats.stage("prior");
    let stall_file = std::env::var_os(TEST_STALL_FILE_ENV).map(std::path::PathBuf::from);
    if let Some(file) = &stall_file {
        tracing::warn!(file = %file.display(), "test fault hook {TEST_STALL_FILE_ENV} set: fusion stalls once the file exists");
    }
    let mut newest_capture: Option<Instant> = None;
    let mut pending: BTreeMap<u64, DetectionBatch> = BTreeMap::new();
    let mut next_ticket = 0u64;
    let mut fused_keyframes = 0u64;
    let mut version = resume.graph_version;
    let mut stamp_ns = resume.stamp_ns;
    // A restored map is published at once: planners see it again before the first keyframe.
    let mut dirty = resume.restored;
    let mut last_publish: Option<Instant> = None;
    // The nodes' points of published versions (rate-limited by the recorder's channel).
    let mut points_recorder = recorder.clone();
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
        if let Some(recorder) = points_recorder.as_mut() {
            recorder.offer_node_points(stamp_ns, |max_per_node, out| fusion.node_points(max_per_node, out));
        }
        graph_tx.push(GraphItem { graph, newest_capture });
    };
    loop {
        stats.liveness.beat(WatchedStage::Fusion);
        if stall_file.as_ref().is_some_and(|f| f.exists()) {
            tracing::warn!("test fault hook: the fusion thread stalls now");
            loop {
                std::thread::sleep(Duration::from_secs(1));
            }
        }
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
            fused_keyframes += 1;
            let started = Instant::now();
            let fused = keyframe_path::fuse(fusion.as_mut(), &batch.frame, &batch.world_from_camera, &batch.detections);
            let report = fused.report;
            if let Some(recorder) = recorder.as_mut() {
                recorder.offer_detections(batch.frame.stamp_ns, &batch.detections);
            }
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
        if let Some(sink) = snapshots.as_mut()
            && !finished
            && sink.due(fused_keyframes)
        {
            let started = Instant::now();
            if let Some(snapshot) = take_snapshot(fusion.as_ref(), version, stamp_ns) {
                sink.offer(snapshot, fused_keyframes, stats);
                stats.snapshot.copy.record(started);
            }
        }
        if finished {
            if version == 0 {
                // Publish an empty graph so clients see the daemon served.
                publish(fusion.as_ref(), &mut version, stamp_ns, newest_capture);
            }
            if let Some(sink) = snapshots.take()
                && let Some(snapshot) = take_snapshot(fusion.as_ref(), version, stamp_ns)
            {
                sink.finish(snapshot, Duration::from_secs(2));
            }
            break;
        }
    }
    stats.liveness.ended(WatchedStage::Fusion);
}
