//! The snapshot file (format 1; the layout is in the module docs above).

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::fusion::multiview::MapState;
use crate::persist::{PersistError, io};

/// The format this build writes; it reads this one and format 1 (before [`MapState::life`]).
pub const FORMAT_VERSION: u32 = 2;
const MAGIC: &[u8; 8] = b"OP3DSGMP";
const HEADER_BYTES: usize = 8 + 4 + 8 + 4;

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
    /// A file operation failed, or another daemon holds the directory.
    #[error(transparent)]
    Persist(#[from] PersistError),
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
}

impl SnapshotError {
    /// The short reason used in the name of a file moved aside (`map.snapshot.<reason>-<ms>`).
    pub fn aside_reason(&self) -> &'static str {
        match self {
            Self::Persist(_) => "unreadable",
            Self::NotASnapshot { .. } | Self::Truncated { .. } | Self::BadChecksum { .. } | Self::Decode { .. } => {
                "corrupt"
            }
            Self::UnsupportedFormat { .. } | Self::Incompatible { .. } => "incompatible",
        }
    }
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
    if format != FORMAT_VERSION && format != 1 {
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
    if format == 1 {
        // Format 1 ends where format 2 appends `MapState::life`, an `Option`: a `None` byte
        // makes it a format-2 payload.
        let mut padded = Vec::with_capacity(payload.len() + 1);
        padded.extend_from_slice(payload);
        padded.push(0);
        return postcard::from_bytes(&padded).map_err(|e| SnapshotError::Decode { path, reason: e.to_string() });
    }
    postcard::from_bytes(payload).map_err(|e| SnapshotError::Decode { path, reason: e.to_string() })
}

/// Reads and checks `path`.
pub fn read(path: &Path) -> Result<Snapshot, SnapshotError> {
    let bytes = std::fs::read(path).map_err(io(path))?;
    decode(&bytes, path)
}
