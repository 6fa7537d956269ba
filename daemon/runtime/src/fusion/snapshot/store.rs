//! The snapshot directory: locked while the daemon runs, and the map restored from it at start.

use std::path::{Path, PathBuf};
use std::sync::atomic::Ordering;

use tracing::{info, warn};

use super::format::{Snapshot, SnapshotError, read};
use super::writer::{STATE_MOVED_ASIDE, STATE_RESTORED, STATE_STARTED_EMPTY, SnapshotStats};
use super::{LOCK_FILE, SNAPSHOT_FILE, TEMP_FILE};
use crate::fusion::Fusion;
use crate::persist::{DirLock, io, move_aside};
use crate::world::clock::unix_ms;

/// A snapshot directory, locked for this process while the value lives.
#[derive(Debug)]
pub struct SnapshotStore {
    dir: PathBuf,
    _lock: DirLock,
}

impl SnapshotStore {
    /// Creates `dir` if needed and takes its lock (a second daemon, or `op3dsg map reset`, is
    /// refused while this one runs); removes a leftover temporary file.
    pub fn open(dir: &Path) -> Result<Self, SnapshotError> {
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let lock = DirLock::acquire(dir, LOCK_FILE)?;
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

/// Whether a daemon holds `dir`'s lock now (for `op3dsg map reset`); `Err(Locked)` when it does.
pub fn ensure_unlocked(dir: &Path) -> Result<(), SnapshotError> {
    DirLock::acquire(dir, LOCK_FILE).map(drop).map_err(SnapshotError::from)
}
