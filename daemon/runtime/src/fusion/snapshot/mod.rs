//! Map snapshots: fusion saves and restores its own map, so it survives a crash, a kill -9 or
//! a reboot.
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
//!
//! | file | what |
//! |---|---|
//! | `config.rs` | `[snapshot]` ([`SnapshotConfig`]) |
//! | `format.rs` | the file: [`Snapshot`], [`encode`], [`decode`], [`read`], [`SnapshotError`] |
//! | `store.rs` | the locked directory and the restoration at start ([`SnapshotStore`]) |
//! | `writer.rs` | the fusion thread's [`SnapshotSink`], the writer thread ([`SnapshotWriter`]) and their [`SnapshotStats`] |

mod config;
mod format;
mod store;
mod writer;

#[cfg(test)]
mod tests;

pub use config::SnapshotConfig;
pub use format::{FORMAT_VERSION, Snapshot, SnapshotError, decode, encode, read};
pub use store::{SnapshotStore, ensure_unlocked};
pub use writer::{
    STATE_MOVED_ASIDE, STATE_OFF, STATE_RESTORED, STATE_STARTED_EMPTY, SnapshotJob, SnapshotSink, SnapshotStats,
    SnapshotWriter, channel,
};

/// The snapshot's file name in its directory.
pub const SNAPSHOT_FILE: &str = "map.snapshot";
/// Where a snapshot is written before it is renamed into place (`crate::persist::temp_name`).
pub const TEMP_FILE: &str = "map.snapshot.tmp";
/// The directory lock a running daemon holds.
pub const LOCK_FILE: &str = "map.lock";
/// Created by `op3dsg map save`: the running daemon writes a snapshot and removes it.
pub const SAVE_REQUEST: &str = "save-request";
#[cfg(feature = "fault-hooks")]
/// Test-only fault hook (builds with the `fault-hooks` feature, which the test command enables):
/// milliseconds to pause in the middle of writing the temporary file, so a test can kill the
/// daemon during a write.
pub const TEST_WRITE_DELAY_ENV: &str = "OP3DSG_TEST_SNAPSHOT_WRITE_DELAY_MS";

/// The pause [`TEST_WRITE_DELAY_ENV`] asks for; always `None` without the `fault-hooks` feature.
fn test_write_pause() -> Option<std::time::Duration> {
    #[cfg(feature = "fault-hooks")]
    {
        let pause = std::env::var(TEST_WRITE_DELAY_ENV)
            .ok()
            .and_then(|v| v.parse::<u64>().ok())
            .map(std::time::Duration::from_millis);
        if let Some(pause) = pause {
            tracing::warn!(
                pause_ms = pause.as_millis() as u64,
                "test fault hook {TEST_WRITE_DELAY_ENV} set: snapshot writes pause midway"
            );
        }
        pause
    }
    #[cfg(not(feature = "fault-hooks"))]
    None
}
