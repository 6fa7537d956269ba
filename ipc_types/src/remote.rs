//! The messages of the daemon's Zenoh keys (`<prefix>/graph`, `<prefix>/graph/delta`,
//! `<prefix>/health`): a fixed envelope, then a full graph (the graph sample's [`GraphHeader`]
//! and records, unchanged), a delta against an earlier version, or the health record as JSON.
//! Little-endian throughout; the daemon's `docs/remote.md` lays it out field by field.
//!
//! `client::RemoteFollower` keeps a graph up to date from these messages, whatever carried them;
//! with the cargo feature `zenoh`, `client::RemoteGraphSubscriber` receives them over Zenoh.

use crate::{GraphHeader, NAME_CAPACITY_BYTES, NODE_BYTES};

/// First four bytes of every message.
pub const MAGIC: [u8; 4] = *b"O3DZ";
/// The envelope's format version; a reader refuses other values.
pub const FORMAT_VERSION: u16 = 1;
/// Bytes of the envelope.
pub const ENVELOPE_BYTES: usize = 40;
/// Bytes of a graph header in a message ([`GraphHeader`]'s layout).
pub const HEADER_BYTES: usize = 112;
/// Bytes of a delta's counts (four `u32`).
pub const DELTA_COUNTS_BYTES: usize = 16;

/// What a message's body is (the envelope's `kind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u16)]
pub enum MessageKind {
    /// A whole graph version: header, nodes, edges.
    Graph = 1,
    /// The changes from `base_version` to `version`.
    Delta = 2,
    /// The health record, JSON.
    Health = 3,
}

/// The envelope in front of every body.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Envelope {
    /// What follows.
    pub kind: MessageKind,
    /// The publishing daemon's instance id (drawn at start; a new one means a restart).
    pub instance_id: u64,
    /// The graph version this message brings the reader to (health: the newest version).
    pub version: u64,
    /// A delta applies to exactly this version; 0 for other kinds.
    pub base_version: u64,
    /// Wall-clock time of the send, nanoseconds since the Unix epoch.
    pub publish_time_ns: u64,
}

/// A message that cannot be read.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RemoteError {
    /// Not an op3dsg message, or of another format version.
    Format {
        /// The first four bytes.
        magic: [u8; 4],
        /// The format version read.
        format: u16,
    },
    /// An unknown `kind`.
    Kind(u16),
    /// Fewer or more bytes than the message's counts describe.
    Length {
        /// Bytes received.
        len: usize,
        /// Bytes the envelope and counts describe.
        described: usize,
    },
    /// A delta that removes what the graph held does not hold, or ends with other counts than
    /// its header's.
    Inconsistent(u64),
}

impl std::fmt::Display for RemoteError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Format { magic, format } => {
                write!(f, "not an op3dsg message of format {FORMAT_VERSION} (magic {magic:?}, format {format})")
            }
            Self::Kind(kind) => write!(f, "unknown message kind {kind}"),
            Self::Length { len, described } => write!(f, "message of {len} bytes, {described} described"),
            Self::Inconsistent(version) => {
                write!(f, "delta to version {version} does not fit the graph it names as its base")
            }
        }
    }
}

impl std::error::Error for RemoteError {}

impl Envelope {
    /// Appends the envelope's [`ENVELOPE_BYTES`] bytes to `out`.
    pub fn append_to(&self, out: &mut Vec<u8>) {
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&FORMAT_VERSION.to_le_bytes());
        out.extend_from_slice(&(self.kind as u16).to_le_bytes());
        for v in [self.instance_id, self.version, self.base_version, self.publish_time_ns] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }

    /// The envelope at the start of `message`.
    pub fn read(message: &[u8]) -> Result<Self, RemoteError> {
        let short = || RemoteError::Length { len: message.len(), described: ENVELOPE_BYTES };
        let b: &[u8; ENVELOPE_BYTES] =
            message.get(..ENVELOPE_BYTES).and_then(|b| b.try_into().ok()).ok_or_else(short)?;
        let magic = [b[0], b[1], b[2], b[3]];
        let format = u16::from_le_bytes([b[4], b[5]]);
        if magic != MAGIC || format != FORMAT_VERSION {
            return Err(RemoteError::Format { magic, format });
        }
        let kind = match u16::from_le_bytes([b[6], b[7]]) {
            1 => MessageKind::Graph,
            2 => MessageKind::Delta,
            3 => MessageKind::Health,
            other => return Err(RemoteError::Kind(other)),
        };
        Ok(Self {
            kind,
            instance_id: u64_at(b, 8),
            version: u64_at(b, 16),
            base_version: u64_at(b, 24),
            publish_time_ns: u64_at(b, 32),
        })
    }
}

pub(crate) fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}

fn u64_at(b: &[u8], o: usize) -> u64 {
    u64::from(u32_at(b, o)) | (u64::from(u32_at(b, o + 4)) << 32)
}

/// Appends `header` in its [`HEADER_BYTES`] wire layout (the `#[repr(C)]` struct's offsets).
pub fn append_header(h: &GraphHeader, out: &mut Vec<u8>) {
    out.extend_from_slice(&h.schema_version.to_le_bytes());
    out.extend_from_slice(&h.node_count.to_le_bytes());
    for v in [h.graph_version, h.instance_id, h.stamp_ns, h.publish_time_ns] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in [h.edge_count, h.object_count, h.part_count] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&[h.capacity_exceeded, h.source_kind]);
    out.extend_from_slice(&h.reserved);
    for v in [h.total_node_count, h.total_edge_count, h.node_capacity, h.edge_capacity] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&h.world_frame);
    out.extend_from_slice(&h.reserved2.to_le_bytes());
}

/// Reads a header written by [`append_header`].
pub fn read_header(b: &[u8; HEADER_BYTES]) -> GraphHeader {
    let mut world_frame = [0u8; NAME_CAPACITY_BYTES];
    world_frame.copy_from_slice(&b[72..72 + NAME_CAPACITY_BYTES]);
    GraphHeader {
        schema_version: u32_at(b, 0),
        node_count: u32_at(b, 4),
        graph_version: u64_at(b, 8),
        instance_id: u64_at(b, 16),
        stamp_ns: u64_at(b, 24),
        publish_time_ns: u64_at(b, 32),
        edge_count: u32_at(b, 40),
        object_count: u32_at(b, 44),
        part_count: u32_at(b, 48),
        capacity_exceeded: b[52],
        source_kind: b[53],
        reserved: [b[54], b[55]],
        total_node_count: u32_at(b, 56),
        total_edge_count: u32_at(b, 60),
        node_capacity: u32_at(b, 64),
        edge_capacity: u32_at(b, 68),
        world_frame,
        reserved2: u64_at(b, 104),
    }
}

/// The id of a node record (its first four bytes).
pub fn node_id(record: &[u8; NODE_BYTES]) -> u32 {
    u32_at(record, 0)
}
