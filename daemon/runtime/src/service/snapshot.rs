//! Map snapshots: the map survives a crash, a kill -9 or a reboot.
//!
//! # When
//! Every `snapshot.period_s` the fusion thread, if it fused anything since the last snapshot,
//! copies the map's saved form ([`MapState`]: points, features, votes, ids; a memory copy, no
//! encoding) and hands it to the thread `op3dsg-snapshot` with a non-blocking send (a write still
//! in progress makes it skip that period, counted). That thread encodes, checksums and writes;
//! the fusion thread never waits on the disk. At the end of the shutdown ladder the final map is
//! written too, and `op3dsg map save` asks for one now (a request file, see [`SAVE_REQUEST`]).
//!
//! # How (atomic)
//! `map.snapshot.tmp` is written in full and fsynced, renamed over `map.snapshot`, and the
//! directory is fsynced, so `map.snapshot` is always either the previous complete snapshot or
//! the new complete one, whatever moment the process or the machine dies.
//!
//! # The file (format 1, little-endian)
//! | bytes | what |
//! |---|---|
//! | 8 | magic `OP3DSGMP` |
//! | 4 | format version, u32 ([`FORMAT_VERSION`]) |
//! | 8 | payload length, u64 |
//! | 4 | CRC-32 (IEEE) of the payload, u32 |
//! | n | payload: [`Snapshot`] in postcard's encoding |
//!
//! # At start
//! The daemon locks the directory (`map.lock`, so two daemons never share one, and
//! `op3dsg map reset` refuses while a daemon runs), removes a leftover `map.snapshot.tmp` (an
//! interrupted write, never a snapshot), and restores `map.snapshot` into the fusion before any
//! stage runs: the first graph it publishes holds the snapshot's nodes, with their ids. A file
//! that is not a snapshot, is truncated, fails its checksum, has another format version or does
//! not fit the profile's fusion parameters is **moved aside** to `map.snapshot.<reason>-<unix ms>`
//! (never deleted), a warning names it and the reason, and the daemon starts with an empty map.
//!
//! # Versions across a restart
//! The restored map keeps the snapshot's graph version: the first graph published after a
//! restart is that version + 1, and node ids are the snapshot's. Versions published between the
//! last snapshot and a crash are not known to the next daemon, so a planner may see a version
//! again; the header's `instance_id` (new on every start) is what says "restarted"
//! (see `op3dsg_ipc_types::GraphHeader`).

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU64, Ordering};
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use crossbeam_channel::{Receiver, Sender, TrySendError};
use serde::{Deserialize, Serialize};
use tracing::{debug, info, warn};

use crate::fusion::Fusion;
use crate::fusion::multiview::MapState;
use crate::pipeline::PipelineStats;

/// The snapshot's file name in its directory.
pub const SNAPSHOT_FILE: &str = "map.snapshot";
/// Where a snapshot is written before it is renamed into place.
pub const TEMP_FILE: &str = "map.snapshot.tmp";
/// The directory lock a running daemon holds.
pub const LOCK_FILE: &str = "map.lock";
/// Created by `op3dsg map save`: the running daemon writes a snapshot and removes it.
pub const SAVE_REQUEST: &str = "save-request";
/// The format this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;
const MAGIC: &[u8; 8] = b"OP3DSGMP";
const HEADER_BYTES: usize = 8 + 4 + 8 + 4;
/// Test-only fault hook: milliseconds to pause in the middle of writing the temporary file, so
/// a test can kill the daemon during a write. Never set it in production.
pub const TEST_WRITE_DELAY_ENV: &str = "OP3DSG_TEST_SNAPSHOT_WRITE_DELAY_MS";

/// `[snapshot]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct SnapshotConfig {
    /// Save the map and restore it at start.
    pub enabled: bool,
    /// Directory of `map.snapshot`; relative to the profile file that sets it. Empty: under
    /// systemd `$STATE_DIRECTORY/snapshots` (`StateDirectory=op3dsg`: /var/lib/op3dsg), else no
    /// snapshots (a daemon started by hand writes nothing unless told where).
    pub dir: String,
    /// Seconds between snapshots of a changing map (0 = only at shutdown and on request).
    pub period_s: f64,
}

impl Default for SnapshotConfig {
    fn default() -> Self {
        Self { enabled: true, dir: String::new(), period_s: 30.0 }
    }
}

impl SnapshotConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(self.period_s.is_finite() && (0.0..=86_400.0).contains(&self.period_s)) {
            return Err(format!("{path}.period_s: must be within [0, 86400] seconds, got {}", self.period_s));
        }
        Ok(())
    }

    /// The directory snapshots go to, `None` when they are off (see [`Self::dir`]).
    pub fn resolve_dir(&self) -> Option<PathBuf> {
        self.resolve_dir_with(std::env::var_os("STATE_DIRECTORY").map(PathBuf::from))
    }

    /// [`Self::resolve_dir`] with `$STATE_DIRECTORY` given (systemd may list several, `:`-separated:
    /// the first is ours).
    pub fn resolve_dir_with(&self, state_directory: Option<PathBuf>) -> Option<PathBuf> {
        if !self.enabled {
            return None;
        }
        if !self.dir.is_empty() {
            return Some(PathBuf::from(&self.dir));
        }
        let state = state_directory?;
        let first = state.to_string_lossy().split(':').next().unwrap_or("").to_owned();
        (!first.is_empty()).then(|| Path::new(&first).join("snapshots"))
    }
}

/// What a snapshot file holds.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Snapshot {
    /// The graph version last published from this map.
    pub graph_version: u64,
    /// Stamp of the newest keyframe fused, nanoseconds.
    pub stamp_ns: u64,
    /// When it was taken, milliseconds since the Unix epoch.
    pub taken_unix_ms: u64,
    /// The map.
    pub map: MapState,
}

/// Why a snapshot could not be read or written.
#[derive(Debug, thiserror::Error)]
pub enum SnapshotError {
    /// A file operation failed.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// The file does not start with the magic bytes.
    #[error("{}: not an op3dsg map snapshot (no OP3DSGMP header)", path.display())]
    NotASnapshot {
        /// The file.
        path: PathBuf,
    },
    /// Written by a build with another format.
    #[error("{}: snapshot format {found}, this op3dsgd reads format {FORMAT_VERSION}", path.display())]
    UnsupportedFormat {
        /// The file.
        path: PathBuf,
        /// The format version in the file.
        found: u32,
    },
    /// Shorter or longer than its header says.
    #[error("{}: truncated: header promises {expected} payload bytes, the file has {found}", path.display())]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Payload bytes the header gives.
        expected: u64,
        /// Payload bytes present.
        found: u64,
    },
    /// The payload's checksum does not match.
    #[error("{}: checksum mismatch: saved {saved:#010x}, calculated {calculated:#010x}", path.display())]
    BadChecksum {
        /// The file.
        path: PathBuf,
        /// CRC-32 in the header.
        saved: u32,
        /// CRC-32 of the payload read.
        calculated: u32,
    },
    /// The payload does not decode.
    #[error("{}: cannot decode the payload: {reason}", path.display())]
    Decode {
        /// The file.
        path: PathBuf,
        /// The decoder's message.
        reason: String,
    },
    /// The map does not fit this daemon's profile.
    #[error("{}: does not fit this profile: {reason}", path.display())]
    Incompatible {
        /// The file.
        path: PathBuf,
        /// What does not fit.
        reason: String,
    },
    /// Another process holds the directory's lock.
    #[error("{}: locked by a running op3dsgd{pid}; stop it first (systemctl stop op3dsgd)", path.display())]
    Locked {
        /// The lock file.
        path: PathBuf,
        /// " (pid N)" when the lock file names it.
        pid: String,
    },
}

impl SnapshotError {
    /// The short reason used in the name of a file moved aside (`map.snapshot.<reason>-<ms>`).
    pub fn aside_reason(&self) -> &'static str {
        match self {
            Self::Io { .. } | Self::Locked { .. } => "unreadable",
            Self::NotASnapshot { .. } | Self::Truncated { .. } | Self::BadChecksum { .. } | Self::Decode { .. } => {
                "corrupt"
            }
            Self::UnsupportedFormat { .. } | Self::Incompatible { .. } => "incompatible",
        }
    }
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> SnapshotError + '_ {
    move |source| SnapshotError::Io { path: path.to_owned(), source }
}

fn unix_ms() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_millis() as u64)
}

/// The file's bytes: header and payload.
pub fn encode(snapshot: &Snapshot) -> Result<Vec<u8>, String> {
    let payload = postcard::to_stdvec(snapshot).map_err(|e| e.to_string())?;
    let mut bytes = Vec::with_capacity(HEADER_BYTES + payload.len());
    bytes.extend_from_slice(MAGIC);
    bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
    bytes.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    bytes.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
    bytes.extend_from_slice(&payload);
    Ok(bytes)
}

/// Checks the header and checksum of `bytes` (read from `path`) and decodes the snapshot.
pub fn decode(bytes: &[u8], path: &Path) -> Result<Snapshot, SnapshotError> {
    let path = path.to_owned();
    if bytes.len() < 8 || &bytes[..8] != MAGIC {
        return Err(SnapshotError::NotASnapshot { path });
    }
    if bytes.len() < HEADER_BYTES {
        return Err(SnapshotError::Truncated { path, expected: 0, found: 0 });
    }
    let u32_at = |at: usize| u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    let format = u32_at(8);
    if format != FORMAT_VERSION {
        return Err(SnapshotError::UnsupportedFormat { path, found: format });
    }
    let mut len = [0u8; 8];
    len.copy_from_slice(&bytes[12..20]);
    let expected = u64::from_le_bytes(len);
    let payload = &bytes[HEADER_BYTES..];
    if payload.len() as u64 != expected {
        return Err(SnapshotError::Truncated { path, expected, found: payload.len() as u64 });
    }
    let saved = u32_at(20);
    let calculated = crc32fast::hash(payload);
    if saved != calculated {
        return Err(SnapshotError::BadChecksum { path, saved, calculated });
    }
    postcard::from_bytes(payload).map_err(|e| SnapshotError::Decode { path, reason: e.to_string() })
}

/// Reads and checks `path`.
pub fn read(path: &Path) -> Result<Snapshot, SnapshotError> {
    let bytes = std::fs::read(path).map_err(io(path))?;
    decode(&bytes, path)
}

/// Writes `bytes` as `dir/map.snapshot` atomically (temporary file, fsync, rename, fsync of
/// the directory). `pause_midway`: the test hook of [`TEST_WRITE_DELAY_ENV`].
pub fn write_atomic(dir: &Path, bytes: &[u8], pause_midway: Option<Duration>) -> Result<(), SnapshotError> {
    let temp = dir.join(TEMP_FILE);
    let target = dir.join(SNAPSHOT_FILE);
    {
        let mut file = OpenOptions::new().write(true).create(true).truncate(true).open(&temp).map_err(io(&temp))?;
        match pause_midway {
            Some(pause) => {
                let (first, rest) = bytes.split_at(bytes.len() / 2);
                file.write_all(first).map_err(io(&temp))?;
                file.sync_data().map_err(io(&temp))?;
                std::thread::sleep(pause);
                file.write_all(rest).map_err(io(&temp))?;
            }
            None => file.write_all(bytes).map_err(io(&temp))?,
        }
        file.sync_all().map_err(io(&temp))?;
    }
    std::fs::rename(&temp, &target).map_err(io(&target))?;
    File::open(dir).and_then(|d| d.sync_all()).map_err(io(dir))?;
    Ok(())
}

/// Moves `path` aside to `path.<reason>-<unix ms>` (never deletes it); the new path.
pub fn move_aside(path: &Path, reason: &str) -> std::io::Result<PathBuf> {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".{reason}-{}", unix_ms()));
    let aside = path.with_file_name(name);
    std::fs::rename(path, &aside)?;
    if let Some(dir) = path.parent() {
        File::open(dir).and_then(|d| d.sync_all())?;
    }
    Ok(aside)
}

/// A snapshot directory, locked for this process while the value lives.
#[derive(Debug)]
pub struct SnapshotStore {
    dir: PathBuf,
    _lock: File,
}

impl SnapshotStore {
    /// Creates `dir` if needed and takes its lock (a second daemon, or `op3dsg map reset`, is
    /// refused while this one runs); removes a leftover temporary file.
    pub fn open(dir: &Path) -> Result<Self, SnapshotError> {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let lock = lock_dir(dir)?;
        let temp = dir.join(TEMP_FILE);
        if temp.exists() {
            warn!(file = %temp.display(), "removing an interrupted snapshot write (the snapshot itself is untouched)");
            std::fs::remove_file(&temp).map_err(io(&temp))?;
        }
        Ok(Self { dir: dir.to_owned(), _lock: lock })
    }

    /// The directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Restores `map.snapshot` into `fusion` and records the outcome in `stats` (state,
    /// restored version). `None`: there is none, or it cannot be used: then it is moved aside with
    /// a warning and the daemon starts empty.
    pub fn restore(&self, fusion: &mut dyn Fusion, stats: &SnapshotStats) -> Option<Snapshot> {
        let restored = self.restore_map(fusion);
        match &restored {
            Ok(snapshot) => {
                stats.state.store(STATE_RESTORED, Ordering::Relaxed);
                stats.restored_version.store(snapshot.graph_version, Ordering::Relaxed);
                stats.version.store(snapshot.graph_version, Ordering::Relaxed);
            }
            Err(moved_aside) => {
                stats.state.store(if *moved_aside { STATE_MOVED_ASIDE } else { STATE_STARTED_EMPTY }, Ordering::Relaxed)
            }
        }
        restored.ok()
    }

    /// `Err(true)`: a snapshot was there and moved aside; `Err(false)`: there was none.
    fn restore_map(&self, fusion: &mut dyn Fusion) -> Result<Snapshot, bool> {
        let path = self.dir.join(SNAPSHOT_FILE);
        if !path.exists() {
            info!(dir = %self.dir.display(), "no map snapshot: starting with an empty map");
            return Err(false);
        }
        let snapshot = read(&path).and_then(|snapshot| {
            fusion
                .restore_state(&snapshot.map)
                .map(|()| snapshot)
                .map_err(|reason| SnapshotError::Incompatible { path: path.clone(), reason })
        });
        match snapshot {
            Ok(snapshot) => {
                let (objects, parts) = snapshot.map.kind_counts();
                info!(
                    file = %path.display(),
                    graph_version = snapshot.graph_version,
                    objects,
                    parts,
                    age_s = unix_ms().saturating_sub(snapshot.taken_unix_ms) / 1000,
                    "map restored from snapshot"
                );
                Ok(snapshot)
            }
            Err(e) => {
                // A half-restored map is discarded with the fusion's own reset in restore_state.
                match move_aside(&path, e.aside_reason()) {
                    Ok(aside) => {
                        warn!(error = %e, moved_to = %aside.display(), "map snapshot unusable: moved aside, starting with an empty map")
                    }
                    Err(move_error) => {
                        warn!(error = %e, move_error = %move_error, "map snapshot unusable and could not be moved aside; starting with an empty map")
                    }
                }
                Err(true)
            }
        }
    }
}

fn lock_dir(dir: &Path) -> Result<File, SnapshotError> {
    let path = dir.join(LOCK_FILE);
    let mut file =
        OpenOptions::new().read(true).write(true).create(true).truncate(false).open(&path).map_err(io(&path))?;
    match file.try_lock() {
        Ok(()) => {
            file.set_len(0).map_err(io(&path))?;
            writeln!(file, "{}", std::process::id()).map_err(io(&path))?;
            Ok(file)
        }
        Err(std::fs::TryLockError::WouldBlock) => {
            let pid = std::fs::read_to_string(&path).ok().map(|t| t.trim().to_owned()).filter(|t| !t.is_empty());
            Err(SnapshotError::Locked { path, pid: pid.map(|p| format!(" (pid {p})")).unwrap_or_default() })
        }
        Err(std::fs::TryLockError::Error(source)) => Err(SnapshotError::Io { path, source }),
    }
}

/// Whether a daemon holds `dir`'s lock now (for `op3dsg map reset`); `Err(Locked)` when it does.
pub fn ensure_unlocked(dir: &Path) -> Result<(), SnapshotError> {
    lock_dir(dir).map(drop)
}

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
}

impl SnapshotSink {
    /// Whether a snapshot is due now, with `fused` keyframes fused so far.
    pub fn due(&self, fused: u64) -> bool {
        let requested = self.requested.load(Ordering::Relaxed);
        let periodic = self.period.is_some_and(|p| self.last_at.elapsed() >= p) && fused != self.fused_at_last;
        requested || periodic
    }

    /// Hands `map` over (never blocks; a write in progress makes this one be skipped, counted).
    pub fn offer(&mut self, snapshot: Snapshot, fused: u64, stats: &PipelineStats) {
        self.requested.store(false, Ordering::Relaxed);
        self.last_at = Instant::now();
        self.fused_at_last = fused;
        match self.tx.try_send(SnapshotJob { snapshot, last: false }) {
            Ok(()) => {}
            Err(TrySendError::Full(_)) => {
                stats.snapshot.skipped.fetch_add(1, Ordering::Relaxed);
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
}

/// A connected sink (for the fusion thread) and writer (for the thread `op3dsg-snapshot`).
pub fn channel(store: SnapshotStore, period_s: f64) -> (SnapshotSink, SnapshotWriter) {
    let (tx, rx) = crossbeam_channel::bounded(1);
    let requested = Arc::new(AtomicBool::new(false));
    let pause_midway =
        std::env::var(TEST_WRITE_DELAY_ENV).ok().and_then(|v| v.parse::<u64>().ok()).map(Duration::from_millis);
    if let Some(pause) = pause_midway {
        warn!(
            pause_ms = pause.as_millis() as u64,
            "test fault hook {TEST_WRITE_DELAY_ENV} set: snapshot writes pause midway"
        );
    }
    let sink = SnapshotSink {
        tx,
        period: (period_s > 0.0).then(|| Duration::from_secs_f64(period_s)),
        last_at: Instant::now(),
        fused_at_last: 0,
        requested: requested.clone(),
    };
    (sink, SnapshotWriter { store, rx, requested, pause_midway })
}

/// How often the writer looks for `op3dsg map save`'s request file.
const REQUEST_POLL: Duration = Duration::from_millis(200);

impl SnapshotWriter {
    /// The thread body: writes each snapshot handed over until the sink is gone.
    pub fn run(self, stats: &PipelineStats) {
        let request = self.store.dir.join(SAVE_REQUEST);
        loop {
            match self.rx.recv_timeout(REQUEST_POLL) {
                Ok(job) => {
                    self.write(&job.snapshot, stats);
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

    fn write(&self, snapshot: &Snapshot, stats: &PipelineStats) {
        let started = Instant::now();
        let result = encode(snapshot)
            .map_err(|reason| SnapshotError::Decode { path: self.store.dir.join(SNAPSHOT_FILE), reason })
            .and_then(|bytes| write_atomic(&self.store.dir, &bytes, self.pause_midway).map(|()| bytes.len()));
        match result {
            Ok(bytes) => {
                stats.snapshot.write.record(started);
                stats.snapshot.version.store(snapshot.graph_version, Ordering::Relaxed);
                stats.snapshot.written.fetch_add(1, Ordering::Relaxed);
                stats.snapshot.last_bytes.store(bytes as u64, Ordering::Relaxed);
                stats.snapshot.last_written_unix_ms.store(unix_ms(), Ordering::Relaxed);
                debug!(
                    graph_version = snapshot.graph_version,
                    nodes = snapshot.map.nodes.len(),
                    bytes,
                    write_ms = started.elapsed().as_secs_f64() * 1e3,
                    "map snapshot written"
                );
            }
            Err(e) => {
                stats.snapshot.failures.fetch_add(1, Ordering::Relaxed);
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
    pub write: crate::stats::StageStats,
    /// Time per periodic copy of the map on the fusion thread (the part of a snapshot the hot
    /// path pays; between keyframes, so it is not in the fusion stage's own latency).
    pub copy: crate::stats::StageStats,
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
            write: crate::stats::StageStats::new("snapshot"),
            copy: crate::stats::StageStats::new("snapshot_copy"),
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

/// Milliseconds since the Unix epoch (snapshot stamps).
pub fn now_unix_ms() -> u64 {
    unix_ms()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fusion::multiview::{MapGeometry, NodeState};

    fn snapshot(nodes: u32) -> Snapshot {
        let node = |id: u32| NodeState {
            id,
            kind: 0,
            points: vec![[id as f32, 0.0, 1.0]; 1],
            voxel_scale: 1,
            checked_points: 0,
            semantic: Vec::new(),
            colour: (vec![0.0; 11], vec![0.0; 64], vec![0.0; 64], 0),
            votes: vec![(0, 1)],
            score_sum: 0.9,
            observation_count: 1,
            last_keyframe: 1,
            last_seen_stamp_ns: 5,
        };
        Snapshot {
            graph_version: 7,
            stamp_ns: 5,
            taken_unix_ms: 1,
            map: MapState {
                geometry: MapGeometry {
                    object_voxel_m: 0.02,
                    part_voxel_m: 0.005,
                    object_nnr_radius_m: 0.03,
                    part_nnr_radius_m: 0.01,
                },
                labels: vec!["cabinet".to_owned()],
                next_id: nodes + 1,
                keyframes: 3,
                nodes: (1..=nodes).map(node).collect(),
            },
        }
    }

    #[test]
    fn round_trip_and_every_kind_of_damage_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let bytes = encode(&snapshot(3)).unwrap();
        write_atomic(dir.path(), &bytes, None).unwrap();
        let path = dir.path().join(SNAPSHOT_FILE);
        assert_eq!(read(&path).unwrap(), snapshot(3));
        assert!(!dir.path().join(TEMP_FILE).exists());

        let check = |bytes: &[u8]| decode(bytes, &path).unwrap_err();
        assert!(matches!(check(&b"hello world, not a snapshot"[..]), SnapshotError::NotASnapshot { .. }));
        assert!(matches!(check(&bytes[..bytes.len() - 3]), SnapshotError::Truncated { .. }));
        let mut flipped = bytes.clone();
        let last = flipped.len() - 1;
        flipped[last] ^= 0x40;
        let err = check(&flipped);
        assert!(matches!(err, SnapshotError::BadChecksum { .. }), "{err}");
        assert!(err.to_string().starts_with(&format!("{}: checksum mismatch", path.display())), "{err}");
        let mut other_format = bytes.clone();
        other_format[8] = 9;
        assert!(matches!(check(&other_format), SnapshotError::UnsupportedFormat { found: 9, .. }));
        assert_eq!(check(&other_format).aside_reason(), "incompatible");
    }

    #[test]
    fn moved_aside_never_deleted() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(SNAPSHOT_FILE);
        std::fs::write(&path, b"garbage").unwrap();
        let aside = move_aside(&path, "corrupt").unwrap();
        assert!(!path.exists());
        assert_eq!(std::fs::read(&aside).unwrap(), b"garbage");
        assert!(aside.file_name().unwrap().to_string_lossy().starts_with("map.snapshot.corrupt-"));
    }

    #[test]
    fn one_daemon_per_directory_and_a_leftover_temp_file_goes() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(TEMP_FILE), b"half a write").unwrap();
        let store = SnapshotStore::open(dir.path()).unwrap();
        assert!(!dir.path().join(TEMP_FILE).exists());
        let err = SnapshotStore::open(dir.path()).unwrap_err();
        assert!(matches!(err, SnapshotError::Locked { .. }), "{err}");
        assert!(err.to_string().contains(&format!("(pid {})", std::process::id())), "{err}");
        assert!(ensure_unlocked(dir.path()).is_err());
        drop(store);
        ensure_unlocked(dir.path()).unwrap();
    }

    #[test]
    fn the_directory_defaults_to_the_systemd_state_directory() {
        let config = SnapshotConfig::default();
        assert_eq!(config.resolve_dir_with(None), None);
        assert_eq!(
            config.resolve_dir_with(Some("/var/lib/op3dsg:/var/lib/other".into())),
            Some(PathBuf::from("/var/lib/op3dsg/snapshots"))
        );
        let set = SnapshotConfig { dir: "/data/maps".to_owned(), ..SnapshotConfig::default() };
        assert_eq!(set.resolve_dir_with(Some("/var/lib/op3dsg".into())), Some(PathBuf::from("/data/maps")));
        let off = SnapshotConfig { enabled: false, ..set };
        assert_eq!(off.resolve_dir_with(Some("/var/lib/op3dsg".into())), None);
        assert!(SnapshotConfig { period_s: -1.0, ..SnapshotConfig::default() }.validate("snapshot").is_err());
    }
}
