//! Snapshots off the hot path: the fusion thread's sink decides when one is due and hands a copy
//! of the map over without waiting; the writer thread `op3dsg-snapshot` encodes and writes it.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, TrySendError};
use tracing::{debug, info, warn};

use super::format::{Snapshot, SnapshotError, encode};
use super::store::SnapshotStore;
use super::{SAVE_REQUEST, SNAPSHOT_FILE};
use crate::persist::write_atomic;
use crate::stats::StageStats;
use crate::world::clock::unix_ms;

/// A map handed from the fusion thread to the writer.
#[derive(Debug)]
pub struct SnapshotJob {
    /// What to write.
    pub snapshot: Snapshot,
    /// Whether it is the final one of the shutdown ladder.
    pub last: bool,
}

/// The fusion thread's side: decides when a snapshot is due and hands it over without waiting.
#[derive(Debug)]
pub struct SnapshotSink {
    tx: Sender<SnapshotJob>,
    period: Option<Duration>,
    last_at: Instant,
    fused_at_last: u64,
    requested: Arc<AtomicBool>,
    stats: Arc<SnapshotStats>,
}

impl SnapshotSink {
    /// Whether a snapshot is due now, with `fused` keyframes fused so far.
    pub fn due(&self, fused: u64) -> bool {
        let requested = self.requested.load(Ordering::Relaxed);
        let periodic = self.period.is_some_and(|p| self.last_at.elapsed() >= p) && fused != self.fused_at_last;
        requested || periodic
    }

    /// Hands `map` over (never blocks; a write in progress makes this one be skipped, counted).
    pub fn offer(&mut self, snapshot: Snapshot, fused: u64) {
        self.requested.store(false, Ordering::Relaxed);
        self.last_at = Instant::now();
        self.fused_at_last = fused;
        match self.tx.try_send(SnapshotJob { snapshot, last: false }) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                self.stats.skipped.fetch_add(1, Ordering::Relaxed);
                debug!("snapshot skipped: the previous one is still being written");
            }
            Err(TrySendError::Disconnected(_)) => {}
        }
    }

    /// The final snapshot at shutdown: waits up to `timeout` for the writer to take it.
    pub fn finish(self, snapshot: Snapshot, timeout: Duration) {
        if self.tx.send_timeout(SnapshotJob { snapshot, last: true }, timeout).is_err() {
            warn!("the final map snapshot was not taken by the writer in time; the previous one stays");
        }
    }
}

/// The writer's side.
#[derive(Debug)]
pub struct SnapshotWriter {
    store: SnapshotStore,
    rx: Receiver<SnapshotJob>,
    requested: Arc<AtomicBool>,
    pause_midway: Option<Duration>,
    stats: Arc<SnapshotStats>,
}

/// A connected sink (for the fusion thread) and writer (for the thread `op3dsg-snapshot`), both
/// counting in `stats`.
pub fn channel(store: SnapshotStore, period_s: f64, stats: Arc<SnapshotStats>) -> (SnapshotSink, SnapshotWriter) {
    let (tx, rx) = crossbeam_channel::bounded(1);
    let requested = Arc::new(AtomicBool::new(false));
    let pause_midway = super::test_write_pause();
    let sink = SnapshotSink {
        tx,
        period: (period_s > 0.0).then(|| Duration::from_secs_f64(period_s)),
        last_at: Instant::now(),
        fused_at_last: 0,
        requested: requested.clone(),
        stats: stats.clone(),
    };
    (sink, SnapshotWriter { store, rx, requested, pause_midway, stats })
}

/// How often the writer looks for `op3dsg map save`'s request file.
const REQUEST_POLL: Duration = Duration::from_millis(200);

impl SnapshotWriter {
    /// The thread body: writes each snapshot handed over until the sink is gone.
    pub fn run(self) {
        let request = self.store.dir().join(SAVE_REQUEST);
        loop {
            match self.rx.recv_timeout(REQUEST_POLL) {
                Ok(job) => {
                    self.write(&job.snapshot);
                    if request.exists() {
                        let _ = std::fs::remove_file(&request);
                    }
                    if job.last {
                        break;
                    }
                }
                Err(crossbeam_channel::RecvTimeoutError::Timeout) => {
                    if request.exists() && !self.requested.swap(true, Ordering::Relaxed) {
                        info!("snapshot requested (op3dsg map save)");
                    }
                }
                Err(crossbeam_channel::RecvTimeoutError::Disconnected) => break,
            }
        }
    }

    fn write(&self, snapshot: &Snapshot) {
        let started = Instant::now();
        let result = encode(snapshot)
            .map_err(|reason| SnapshotError::Decode { path: self.store.dir().join(SNAPSHOT_FILE), reason })
            .and_then(|bytes| {
                write_atomic(self.store.dir(), SNAPSHOT_FILE, &bytes, self.pause_midway)
                    .map(|()| bytes.len())
                    .map_err(SnapshotError::from)
            });
        match result {
            Ok(bytes) => {
                self.stats.write.record(started);
                self.stats.version.store(snapshot.graph_version, Ordering::Relaxed);
                self.stats.written.fetch_add(1, Ordering::Relaxed);
                self.stats.last_bytes.store(bytes as u64, Ordering::Relaxed);
                self.stats.last_written_unix_ms.store(unix_ms(), Ordering::Relaxed);
                debug!(
                    graph_version = snapshot.graph_version,
                    nodes = snapshot.map.nodes.len(),
                    bytes,
                    write_ms = started.elapsed().as_secs_f64() * 1e3,
                    "map snapshot written"
                );
            }
            Err(e) => {
                self.stats.failures.fetch_add(1, Ordering::Relaxed);
                warn!(error = %e, "map snapshot failed; the previous one stays");
            }
        }
    }
}

/// [`SnapshotStats::state`] values: the index into `op3dsg_ipc_types::SNAPSHOT_STATES`.
pub const STATE_OFF: u8 = 0;
/// On; there was no snapshot at start.
pub const STATE_STARTED_EMPTY: u8 = 1;
/// On; the map was restored at start.
pub const STATE_RESTORED: u8 = 2;
/// On; the snapshot at start could not be used and was moved aside.
pub const STATE_MOVED_ASIDE: u8 = 3;

/// Counters of the snapshot writer.
#[derive(Debug)]
pub struct SnapshotStats {
    /// One of the `STATE_*` values.
    pub state: AtomicU8,
    /// Graph version restored at start (0 = none).
    pub restored_version: AtomicU64,
    /// Graph version of the last snapshot written or restored (0 = none).
    pub version: AtomicU64,
    /// When the last snapshot was written, ms since the Unix epoch (0 = none).
    pub last_written_unix_ms: AtomicU64,
    /// Snapshots written.
    pub written: AtomicU64,
    /// Snapshots that failed to write.
    pub failures: AtomicU64,
    /// Periods skipped because the previous write was still going on.
    pub skipped: AtomicU64,
    /// Size of the last snapshot written, bytes.
    pub last_bytes: AtomicU64,
    /// Time per write (encode, checksum, write, fsync, rename, fsync of the directory).
    pub write: StageStats,
    /// Time per periodic copy of the map on the fusion thread (the part of a snapshot the hot
    /// path pays; between keyframes, so it is not in the fusion stage's own latency).
    pub copy: StageStats,
}

impl Default for SnapshotStats {
    fn default() -> Self {
        Self {
            state: AtomicU8::new(STATE_OFF),
            restored_version: AtomicU64::new(0),
            version: AtomicU64::new(0),
            last_written_unix_ms: AtomicU64::new(0),
            written: AtomicU64::new(0),
            failures: AtomicU64::new(0),
            skipped: AtomicU64::new(0),
            last_bytes: AtomicU64::new(0),
            write: StageStats::new("snapshot"),
            copy: StageStats::new("snapshot_copy"),
        }
    }
}

impl SnapshotStats {
    /// The health record (starts a new write-time period).
    pub fn health(&self) -> op3dsg_ipc_types::SnapshotHealth {
        op3dsg_ipc_types::SnapshotHealth {
            state: self.state.load(Ordering::Relaxed),
            write_p99_us: self.write.take_figures().p99_us as u32,
            restored_version: self.restored_version.load(Ordering::Relaxed),
            version: self.version.load(Ordering::Relaxed),
            last_written_unix_ms: self.last_written_unix_ms.load(Ordering::Relaxed),
            last_bytes: self.last_bytes.load(Ordering::Relaxed),
            written: self.written.load(Ordering::Relaxed),
            failures: self.failures.load(Ordering::Relaxed),
            skipped: self.skipped.load(Ordering::Relaxed),
            ..Default::default()
        }
    }
}
