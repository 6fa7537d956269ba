//! The fusion thread, sole owner of the map: applies detection results in ticket order through
//! the keyframe path and builds each graph version (prior graph and reasoner included).

use std::collections::BTreeMap;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use super::Fusion;
use crate::keyframe_path::{self, Refinement};
use crate::pipeline::PipelineStats;
use crate::pipeline::items::{DetectionBatch, GraphItem, POLL};
use crate::queue::{Popped, QueueReceiver, QueueSender};
use crate::reasoner::GraphEnricher;

pub(crate) fn fusion_loop(
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
