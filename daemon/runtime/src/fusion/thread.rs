//! The fusion thread `op3dsg-fusion`, sole owner of the map: applies detection results in ticket
//! order, builds each graph version (prior graph and reasoner included) and hands map snapshots
//! to their writer when they are due.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use super::snapshot::{Snapshot, SnapshotSink};
use super::{Fusion, FusionCounters, fuse, map_graph};
use crate::flow::{DetectionBatch, GraphItem, POLL};
use crate::queue::{Popped, QueueReceiver, QueueSender};
use crate::reasoner::{GraphEnricher, Refinement, enrich};
use crate::record::RecordSender;
use crate::stats::{Liveness, WatchedStage};
use crate::world::clock::unix_ms;

/// Test-only fault hook (builds with the `fault-hooks` feature, which the test command enables):
/// when this variable names a file and that file exists, the fusion thread stops answering (it
/// sleeps without polling its input or beating), as a thread stuck in a bug would. The sd_notify
/// test uses it to see the watchdog pings stop.
#[cfg(feature = "fault-hooks")]
pub const TEST_STALL_FILE_ENV: &str = "OP3DSG_TEST_STALL_FUSION_FILE";

/// Test-only fault hook (`fault-hooks` feature): milliseconds the fusion thread sleeps after
/// each keyframe it fuses, as on a slower computer, so that a test can load the pipeline until
/// its queues' policies matter (the replay test: latest-wins queues drop, a lossless replay waits).
#[cfg(feature = "fault-hooks")]
pub const TEST_FUSION_DELAY_ENV: &str = "OP3DSG_TEST_FUSION_DELAY_MS";

/// Where the map starts: the version and stamp of a restored snapshot.
#[derive(Debug, Clone, Copy, Default)]
pub struct Resume {
    /// The restored snapshot's graph version (0 without one).
    pub graph_version: u64,
    /// The restored snapshot's newest keyframe stamp, nanoseconds.
    pub stamp_ns: u64,
    /// A map was restored: publish it at once.
    pub restored: bool,
}

/// The fusion thread, built by the composition; [`FusionThread::run`] is its body.
pub struct FusionThread {
    /// The map (restored from the last snapshot, if any).
    pub fusion: Box<dyn Fusion>,
    /// The prior graph and reasoner run on each published version (`None`: `reasoner.kind =
    /// "none"`).
    pub enricher: Option<GraphEnricher>,
    /// From the detection workers.
    pub det_rx: QueueReceiver<DetectionBatch>,
    /// To the publisher.
    pub graph_tx: QueueSender<GraphItem>,
    /// This stage's counters.
    pub counters: Arc<FusionCounters>,
    /// The watchdog's heartbeats.
    pub liveness: Arc<Liveness>,
    /// Minimum time between two published versions (`run.min_publish_interval_ms`).
    pub min_interval: Duration,
    /// Where snapshots go (`None`: snapshots off).
    pub snapshots: Option<SnapshotSink>,
    /// Where the map starts.
    pub resume: Resume,
    /// The MCAP recorder (detections, node points), when on.
    pub recorder: Option<RecordSender>,
}

impl std::fmt::Debug for FusionThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FusionThread").field("resume", &self.resume).finish_non_exhaustive()
    }
}

/// Where the map stands.
struct Progress {
    newest_capture: Option<Instant>,
    pending: BTreeMap<u64, DetectionBatch>,
    next_ticket: u64,
    fused_keyframes: u64,
    version: u64,
    stamp_ns: u64,
    /// Changed since the last published version.
    dirty: bool,
    last_publish: Option<Instant>,
    /// The sleep after each keyframe of the `OP3DSG_TEST_FUSION_DELAY_MS` fault hook (zero: none).
    test_delay: Duration,
}

impl FusionThread {
    /// Fuses until the workers close the detections queue, then publishes the final graph and
    /// hands the final snapshot over.
    pub fn run(mut self) {
        let stall_file = test_stall_file();
        let mut progress = Progress {
            newest_capture: None,
            pending: BTreeMap::new(),
            next_ticket: 0,
            fused_keyframes: 0,
            version: self.resume.graph_version,
            stamp_ns: self.resume.stamp_ns,
            // A restored map is published at once: planners see it again before the first keyframe.
            dirty: self.resume.restored,
            last_publish: None,
            test_delay: test_fusion_delay(),
        };
        loop {
            self.liveness.beat(WatchedStage::Fusion);
            if stall_file.as_ref().is_some_and(|f| f.exists()) {
                tracing::warn!("test fault hook: the fusion thread stalls now");
                loop {
                    std::thread::sleep(Duration::from_secs(1));
                }
            }
            let finished = match self.det_rx.pop_timeout(POLL) {
                Popped::Item(batch) => {
                    progress.pending.insert(batch.ticket, batch);
                    false
                }
                Popped::Empty => false,
                Popped::Finished => true,
            };
            self.apply_in_order(&mut progress, finished);
            if progress.dirty && (self.publish_due(&progress) || finished) {
                self.publish(&mut progress);
            }
            if !finished {
                self.offer_snapshot(&progress);
                continue;
            }
            if progress.version == 0 {
                // Publish an empty graph so clients see the daemon served.
                self.publish(&mut progress);
            }
            if let Some(sink) = self.snapshots.take()
                && let Some(snapshot) = take_snapshot(self.fusion.as_ref(), progress.version, progress.stamp_ns)
            {
                sink.finish(snapshot, Duration::from_secs(2));
            }
            break;
        }
        self.liveness.ended(WatchedStage::Fusion);
    }

    /// Whether `run.min_publish_interval_ms` has passed since the last published version.
    fn publish_due(&self, progress: &Progress) -> bool {
        progress.last_publish.is_none_or(|t| t.elapsed() >= self.min_interval)
    }

    /// Applies results in ticket order; at the end, what is left in order (a gap can only come
    /// from a worker that gave up during shutdown). A version is published after each result
    /// that changed the map once one is due, not once per call: with
    /// `run.min_publish_interval_ms = 0` the versions then follow the keyframes, however many
    /// results arrived together (several workers finish out of order), so a replay numbers them
    /// as the recorded run did.
    fn apply_in_order(&mut self, progress: &mut Progress, finished: bool) {
        while let Some(batch) = progress
            .pending
            .remove(&progress.next_ticket)
            .or_else(|| if finished { progress.pending.pop_first().map(|(_, b)| b) } else { None })
        {
            progress.next_ticket = batch.ticket + 1;
            progress.fused_keyframes += 1;
            let started = Instant::now();
            let fused = fuse(self.fusion.as_mut(), &batch.frame, &batch.world_from_camera, &batch.detections);
            let report = fused.report;
            if let Some(recorder) = self.recorder.as_mut() {
                recorder.offer_detections(batch.frame.stamp_ns, &batch.detections);
            }
            self.counters.detections_fused.fetch_add(batch.detections.len() as u64, Ordering::Relaxed);
            progress.stamp_ns = progress.stamp_ns.max(batch.frame.stamp_ns);
            progress.newest_capture = progress.newest_capture.max(Some(batch.captured_at));
            self.counters.stage.record(started);
            if !progress.test_delay.is_zero() {
                std::thread::sleep(progress.test_delay);
            }
            tracing::trace!(
                frame_seq = batch.frame.seq,
                merged = report.merged,
                created = report.created,
                ignored = report.ignored,
                "fused"
            );
            progress.dirty |= fused.changed();
            if progress.dirty && self.publish_due(progress) {
                self.publish(progress);
            }
        }
    }

    /// Builds, enriches and hands over the next graph version.
    fn publish(&mut self, progress: &mut Progress) {
        progress.version += 1;
        let mut graph = map_graph(self.fusion.as_ref(), progress.version, progress.stamp_ns);
        if let Some(enricher) = self.enricher.as_mut() {
            let started = Instant::now();
            enrich(enricher, &mut graph, Refinement::Asynchronous);
            self.counters.prior.record(started);
        }
        let counters = &self.counters;
        counters.graph_version.store(progress.version, Ordering::Relaxed);
        counters.map_node_count.store(self.fusion.node_count() as u64, Ordering::Relaxed);
        counters.map_memory_bytes.store(self.fusion.memory_bytes() as u64, Ordering::Relaxed);
        if let Some(recorder) = self.recorder.as_mut() {
            let fusion = self.fusion.as_ref();
            recorder.offer_node_points(progress.stamp_ns, |max_per_node, out| fusion.node_points(max_per_node, out));
        }
        self.graph_tx.push(GraphItem { graph, newest_capture: progress.newest_capture });
        progress.last_publish = Some(Instant::now());
        progress.dirty = false;
    }

    /// Hands a copy of the map to the snapshot writer when one is due (never waits).
    fn offer_snapshot(&mut self, progress: &Progress) {
        let Some(sink) = self.snapshots.as_mut() else { return };
        if !sink.due(progress.fused_keyframes) {
            return;
        }
        let started = Instant::now();
        if let Some(snapshot) = take_snapshot(self.fusion.as_ref(), progress.version, progress.stamp_ns) {
            sink.offer(snapshot, progress.fused_keyframes);
            self.counters.snapshot.copy.record(started);
        }
    }
}

fn take_snapshot(fusion: &dyn Fusion, version: u64, stamp_ns: u64) -> Option<Snapshot> {
    fusion.export_state().map(|map| Snapshot { graph_version: version, stamp_ns, taken_unix_ms: unix_ms(), map })
}

/// The delay of [`TEST_FUSION_DELAY_ENV`]; always zero without the `fault-hooks` feature.
fn test_fusion_delay() -> Duration {
    #[cfg(feature = "fault-hooks")]
    if let Some(ms) = std::env::var(TEST_FUSION_DELAY_ENV).ok().and_then(|v| v.parse::<u64>().ok()) {
        tracing::warn!(ms, "test fault hook {TEST_FUSION_DELAY_ENV} set: fusion sleeps after each keyframe");
        return Duration::from_millis(ms);
    }
    Duration::ZERO
}

/// The file of [`TEST_STALL_FILE_ENV`]; always `None` without the `fault-hooks` feature.
fn test_stall_file() -> Option<std::path::PathBuf> {
    #[cfg(feature = "fault-hooks")]
    {
        let file = std::env::var_os(TEST_STALL_FILE_ENV).map(std::path::PathBuf::from);
        if let Some(file) = &file {
            tracing::warn!(file = %file.display(), "test fault hook {TEST_STALL_FILE_ENV} set: fusion stalls once the file exists");
        }
        file
    }
    #[cfg(not(feature = "fault-hooks"))]
    None
}
