//! The messages of the daemon's Zenoh keys (`<prefix>/graph`, `<prefix>/graph/delta`,
//! `<prefix>/health`, `<prefix>/occupancy`): a fixed envelope, then a full graph (the graph
//! sample's [`GraphHeader`] and records, unchanged), a delta against an earlier version, the
//! health record as JSON, or the occupancy map (the iceoryx2 sample's [`OccupancyHeader`] and
//! cells, unchanged).
//! Little-endian throughout; the daemon's `docs/remote.md` lays it out field by field.
//!
//! `client::RemoteFollower` keeps a graph up to date from these messages, whatever carried them;
//! with the cargo feature `zenoh`, `client::RemoteGraphSubscriber` receives them over Zenoh.

use crate::{GraphHeader, NAME_CAPACITY_BYTES, NODE_BYTES, OccupancyHeader};

/// First four bytes of every message.
pub const MAGIC: [u8; 4] = *b"O3DZ";
/// The envelope's format version; a reader refuses other values.
pub const FORMAT_VERSION: u16 = 1;
/// Bytes of the envelope.
pub const ENVELOPE_BYTES: usize = 40;
/// Bytes of a graph header in a message ([`GraphHeader`]'s layout).
pub const HEADER_BYTES: usize = 112;
/// Bytes of an occupancy header in a message ([`OccupancyHeader`]'s layout).
pub const OCCUPANCY_HEADER_BYTES: usize = 112;
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
    /// The occupancy map: header and cells.
    Occupancy = 4,
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
    /// A message of another kind than this reader takes (an occupancy map given to a graph
    /// follower, ...).
    WrongKind {
        /// The kind read.
        found: MessageKind,
        /// What the reader takes.
        expected: &'static str,
    },
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
            Self::WrongKind { found, expected } => write!(f, "a message of kind {found:?}, expected {expected}"),
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
            4 => MessageKind::Occupancy,
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

/// Appends `h` in its [`OCCUPANCY_HEADER_BYTES`] wire layout (the `#[repr(C)]` struct's offsets).
pub fn append_occupancy_header(h: &OccupancyHeader, out: &mut Vec<u8>) {
    for v in [h.schema_version, h.width_cells, h.height_cells] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    let plane = [h.cell_size_m, h.origin_x_m, h.origin_y_m, h.floor_height_m];
    for v in plane.into_iter().chain([h.obstacle_min_height_m, h.obstacle_max_height_m]) {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&[h.up_axis, h.robot_pose_valid]);
    out.extend_from_slice(&h.reserved);
    for v in [h.instance_id, h.stamp_ns, h.publish_time_ns, h.keyframes_integrated, h.keyframes_dropped] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in [h.robot_x_m, h.robot_y_m, h.robot_yaw_rad] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    for v in [h.integrate_p50_us, h.integrate_p99_us, h.free_cells, h.occupied_cells, h.reserved2] {
        out.extend_from_slice(&v.to_le_bytes());
    }
}

/// Reads a header written by [`append_occupancy_header`].
pub fn read_occupancy_header(b: &[u8; OCCUPANCY_HEADER_BYTES]) -> OccupancyHeader {
    let f32_at = |o: usize| f32::from_bits(u32_at(b, o));
    OccupancyHeader {
        schema_version: u32_at(b, 0),
        width_cells: u32_at(b, 4),
        height_cells: u32_at(b, 8),
        cell_size_m: f32_at(12),
        origin_x_m: f32_at(16),
        origin_y_m: f32_at(20),
        floor_height_m: f32_at(24),
        obstacle_min_height_m: f32_at(28),
        obstacle_max_height_m: f32_at(32),
        up_axis: b[36],
        robot_pose_valid: b[37],
        reserved: [b[38], b[39]],
        instance_id: u64_at(b, 40),
        stamp_ns: u64_at(b, 48),
        publish_time_ns: u64_at(b, 56),
        keyframes_integrated: u64_at(b, 64),
        keyframes_dropped: u64_at(b, 72),
        robot_x_m: f32_at(80),
        robot_y_m: f32_at(84),
        robot_yaw_rad: f32_at(88),
        integrate_p50_us: u32_at(b, 92),
        integrate_p99_us: u32_at(b, 96),
        free_cells: u32_at(b, 100),
        occupied_cells: u32_at(b, 104),
        reserved2: u32_at(b, 108),
    }
}

/// An occupancy message: envelope, header, then `width_cells * height_cells` cells (as
/// [`OccupancyHeader`] documents them), into `out` (cleared first). `version` counts the maps the
/// daemon published.
pub fn encode_occupancy(header: &OccupancyHeader, cells: &[i8], version: u64, publish_time_ns: u64, out: &mut Vec<u8>) {
    out.clear();
    out.reserve(ENVELOPE_BYTES + OCCUPANCY_HEADER_BYTES + cells.len());
    Envelope {
        kind: MessageKind::Occupancy,
        instance_id: header.instance_id,
        version,
        base_version: 0,
        publish_time_ns,
    }
    .append_to(out);
    append_occupancy_header(header, out);
    out.extend(cells.iter().map(|&c| c as u8));
}

/// The parts of an occupancy message: envelope, header, and the cells (row-major, `width_cells`
/// per row, values as [`OccupancyHeader`] documents them).
pub fn read_occupancy(message: &[u8]) -> Result<(Envelope, OccupancyHeader, &[i8]), RemoteError> {
    let envelope = Envelope::read(message)?;
    if envelope.kind != MessageKind::Occupancy {
        return Err(RemoteError::WrongKind { found: envelope.kind, expected: "an occupancy map" });
    }
    let end = ENVELOPE_BYTES + OCCUPANCY_HEADER_BYTES;
    let header_bytes: &[u8; OCCUPANCY_HEADER_BYTES] = message
        .get(ENVELOPE_BYTES..end)
        .and_then(|b| b.try_into().ok())
        .ok_or(RemoteError::Length { len: message.len(), described: end })?;
    let header = read_occupancy_header(header_bytes);
    let described = end + header.cell_count();
    if message.len() != described {
        return Err(RemoteError::Length { len: message.len(), described });
    }
    Ok((envelope, header, bytemuck::cast_slice(&message[end..])))
}

/// The id of a node record (its first four bytes).
pub fn node_id(record: &[u8; NODE_BYTES]) -> u32 {
    u32_at(record, 0)
}
