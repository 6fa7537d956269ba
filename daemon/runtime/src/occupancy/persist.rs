//! The occupancy map beside the map snapshot: `occupancy.snapshot` in the snapshot directory
//! (`[snapshot]`, `crate::fusion::snapshot`), so a restarted daemon keeps its floor map as it
//! keeps its scene graph.
//!
//! Written by the occupancy thread (never the fusion thread) every `snapshot.period_s` while the
//! map changes and at the end of the shutdown ladder; atomically like the map snapshot
//! (`crate::persist::write_atomic`: `occupancy.snapshot.tmp`, fsync, rename, fsync of the directory). `op3dsg map save` asks the
//! fusion map only; the occupancy map follows at its own period.
//!
//! # The file (format 1, little-endian)
//! | bytes | what |
//! |---|---|
//! | 8 | magic `OP3DSGOC` |
//! | 4 | format version, u32 ([`FORMAT_VERSION`]) |
//! | 4 | CRC-32 (IEEE) of the rest, u32 |
//! | n | [`OccupancyGrid::encode_into`]: cells a side, cell size, origin, keyframes, stamp, robot, log-odds, observed bits |
//!
//! At start a file that is not one, fails its checksum, has another format or does not fit the
//! profile's grid (`occupancy.size_m`, `cell_size_m`, `centre_m`) is **moved aside**
//! (`occupancy.snapshot.<reason>-<unix ms>`, never deleted), a warning names it and why, and the
//! map starts empty.

use std::path::{Path, PathBuf};

use tracing::{info, warn};

use super::OccupancyGrid;
use crate::persist::{PersistError, move_aside, write_atomic};

/// The file's name in the snapshot directory.
pub const OCCUPANCY_FILE: &str = "occupancy.snapshot";
/// The format this build writes and reads.
pub const FORMAT_VERSION: u32 = 1;
const MAGIC: &[u8; 8] = b"OP3DSGOC";
const HEADER_BYTES: usize = 8 + 4 + 4;

/// Saves and restores the occupancy map in one directory.
#[derive(Debug)]
pub struct OccupancyStore {
    dir: PathBuf,
    bytes: Vec<u8>,
}

impl OccupancyStore {
    /// A store in `dir` (the snapshot directory, already created and locked by the daemon).
    pub fn new(dir: &Path) -> Self {
        Self { dir: dir.to_owned(), bytes: Vec::new() }
    }

    /// The file's path.
    pub fn path(&self) -> PathBuf {
        self.dir.join(OCCUPANCY_FILE)
    }

    /// Writes `grid` atomically.
    pub fn save(&mut self, grid: &OccupancyGrid) -> Result<(), PersistError> {
        self.bytes.clear();
        self.bytes.extend_from_slice(MAGIC);
        self.bytes.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        self.bytes.extend_from_slice(&[0; 4]);
        grid.encode_into(&mut self.bytes);
        let crc = crc32fast::hash(&self.bytes[HEADER_BYTES..]);
        self.bytes[12..16].copy_from_slice(&crc.to_le_bytes());
        write_atomic(&self.dir, OCCUPANCY_FILE, &self.bytes, None)
    }

    /// Restores the saved map into `grid` (fresh from [`OccupancyGrid::new`]). `Ok(true)`:
    /// restored; `Ok(false)`: no file; `Err`: the file was moved aside (the message says where
    /// and why) and `grid` is unchanged.
    pub fn restore(&self, grid: &mut OccupancyGrid) -> Result<bool, String> {
        let path = self.path();
        let bytes = match std::fs::read(&path) {
            Ok(bytes) => bytes,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
            Err(e) => return Err(format!("{}: {e}", path.display())),
        };
        let checked = check(&bytes).and_then(|payload| grid.restore_from(payload).map_err(|e| ("other-grid", e)));
        match checked {
            Ok(()) => {
                info!(path = %path.display(), keyframes = grid.keyframes(), "occupancy map restored");
                Ok(true)
            }
            Err((reason, why)) => {
                let moved = move_aside(&path, reason)
                    .map_or_else(|e| format!("could not be moved aside: {e}"), |p| format!("moved to {}", p.display()));
                let message = format!("{}: {why}; {moved}; the occupancy map starts empty", path.display());
                warn!("{message}");
                Err(message)
            }
        }
    }
}

/// The payload of a well-formed file, or the reason (a file-name word) and what is wrong.
fn check(bytes: &[u8]) -> Result<&[u8], (&'static str, String)> {
    if bytes.len() < HEADER_BYTES || &bytes[..8] != MAGIC {
        return Err(("not-a-snapshot", "not an occupancy snapshot (magic OP3DSGOC)".to_owned()));
    }
    let u32_at = |at: usize| u32::from_le_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    let format = u32_at(8);
    if format != FORMAT_VERSION {
        return Err(("unsupported-format", format!("format {format}, this build reads {FORMAT_VERSION}")));
    }
    let (saved, calculated) = (u32_at(12), crc32fast::hash(&bytes[HEADER_BYTES..]));
    if saved != calculated {
        return Err(("bad-checksum", format!("checksum {saved:#010x} saved, {calculated:#010x} calculated")));
    }
    Ok(&bytes[HEADER_BYTES..])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::occupancy::{DepthScan, OccupancyConfig};
    use crate::world::UpAxis;
    use glam::{DQuat, DVec3};
    use op3dsg_drivers::frame::Intrinsics;
    use op3dsg_drivers::pose::Isometry;

    fn mapped_grid(config: &OccupancyConfig) -> OccupancyGrid {
        let k = Intrinsics { width: 32, height: 24, fx: 20.0, fy: 20.0, cx: 16.0, cy: 12.0 };
        let rotation = DQuat::from_mat3(&glam::DMat3::from_cols(DVec3::NEG_Y, DVec3::NEG_Z, DVec3::X));
        let pose = Isometry::new(rotation, DVec3::new(0.3, 0.2, 1.0));
        let mut grid = OccupancyGrid::new(config, UpAxis::Z, 0.2, &k);
        let mut scan = DepthScan::with_capacity(&k, 2);
        scan.fill(&vec![1500; 32 * 24], &k, 1000.0, &pose, 7);
        grid.integrate(&scan);
        grid
    }

    #[test]
    fn round_trip_and_damage_is_moved_aside() {
        let dir = tempfile::tempdir().expect("temp dir");
        let config = OccupancyConfig { size_m: 4.0, ..Default::default() };
        let grid = mapped_grid(&config);
        let mut store = OccupancyStore::new(dir.path());
        store.save(&grid).expect("save");
        let k = Intrinsics { width: 32, height: 24, fx: 20.0, fy: 20.0, cx: 16.0, cy: 12.0 };
        let mut restored = OccupancyGrid::new(&config, UpAxis::Z, 0.2, &k);
        assert_eq!(store.restore(&mut restored), Ok(true));
        assert_eq!(restored.geometry(), grid.geometry());
        assert_eq!((restored.keyframes(), restored.stamp_ns(), restored.robot()), (1, 7, grid.robot()));
        let n = grid.geometry().cell_count();
        assert!((0..n).all(|i| restored.cell_percent(i) == grid.cell_percent(i)));
        assert!((0..n).any(|i| grid.cell_percent(i) >= 65), "the test map has obstacles");

        // Another grid size: moved aside, the map stays empty.
        let other = OccupancyConfig { size_m: 5.0, ..Default::default() };
        let mut fresh = OccupancyGrid::new(&other, UpAxis::Z, 0.2, &k);
        let error = store.restore(&mut fresh).unwrap_err();
        assert!(error.contains("occupancy.size_m") && error.contains("moved to"), "{error}");
        assert_eq!(fresh.keyframes(), 0);
        assert_eq!(store.restore(&mut fresh), Ok(false), "the file is gone, not deleted");
        assert!(
            std::fs::read_dir(dir.path())
                .unwrap()
                .any(|e| { e.unwrap().file_name().to_string_lossy().starts_with("occupancy.snapshot.other-grid-") })
        );

        // A flipped byte: bad checksum.
        store.save(&grid).expect("save");
        let mut bytes = std::fs::read(store.path()).unwrap();
        let last = bytes.len() - 1;
        bytes[last] ^= 0xff;
        std::fs::write(store.path(), &bytes).unwrap();
        let error = store.restore(&mut fresh).unwrap_err();
        assert!(error.contains("checksum"), "{error}");
    }
}
