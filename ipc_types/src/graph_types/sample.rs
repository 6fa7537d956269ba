//! One graph sample: its user header ([`GraphHeader`]) and the borrowed view of header and
//! payload ([`GraphMessage`]) that decodes the records.

// The derive macros emit `unsafe impl ZeroCopySend`; that is the only unsafe code here.
#![allow(unsafe_code)]

use iceoryx2::prelude::{PlacementDefault, ZeroCopySend};

use super::records::{EDGE_BYTES, Edge, NODE_BYTES, Node};
use crate::NAME_CAPACITY_BYTES;

/// The most nodes one graph sample holds when the profile sets no `ipc.max_nodes`. A larger map
/// sets [`GraphHeader::capacity_exceeded`] and publishes the most recently seen nodes that fit.
pub const MAX_NODES: usize = 16_384;
/// The most edges one graph sample holds when the profile sets no `ipc.max_edges` (see
/// [`MAX_NODES`] for what happens beyond).
pub const MAX_EDGES: usize = 32_768;

/// What the daemon reads its frames from, as [`GraphHeader::source_kind`] and
/// [`Health::source_kind`](crate::Health::source_kind) carry it: the source the daemon actually
/// opened, so a planner can tell a live robot from a replay before it acts on the graph.
///
/// | value | name | what |
/// |---|---|---|
/// | 0 | `unknown` | unknown or other: a source of another kind (a backend of another build), a publisher that does not say (a [`GraphBuffer`](crate::publish::GraphBuffer) left at its default), or a value newer than this build |
/// | 1 | `live_camera` | a live camera (the RealSense on the robot): the graph is the world now |
/// | 2 | `replay` | a recording played back: a TUM RGB-D / ICL-NUIM sequence (`source.kind = "replay"`), an MCAP recording of op3dsgd (`"mcap"`), or a librealsense `.bag` (`"realsense"` with `source.realsense.bag`: a replay although the camera's source plays it) |
/// | 3 | `synthetic` | the built-in synthetic rooms (`"synthetic"`): a simulated world |
///
/// The names are [`SOURCE_KINDS`], indexed by the value.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SourceKind {
    /// Unknown or other (see the table).
    #[default]
    Unknown = 0,
    /// A live camera.
    LiveCamera = 1,
    /// A recording played back (TUM/ICL replay, MCAP replay, librealsense `.bag`).
    Replay = 2,
    /// The built-in synthetic rooms.
    Synthetic = 3,
}

/// The names of the [`SourceKind`] values, indexed by the wire value.
pub const SOURCE_KINDS: [&str; 4] = ["unknown", "live_camera", "replay", "synthetic"];

impl SourceKind {
    /// Decodes a wire value; `None` for a value this build does not know.
    pub fn from_u8(value: u8) -> Option<Self> {
        match value {
            0 => Some(Self::Unknown),
            1 => Some(Self::LiveCamera),
            2 => Some(Self::Replay),
            3 => Some(Self::Synthetic),
            _ => None,
        }
    }

    /// The wire value's name ([`SOURCE_KINDS`]): `unknown`, `live_camera`, `replay`, `synthetic`.
    pub fn as_str(self) -> &'static str {
        SOURCE_KINDS[self as usize]
    }
}

/// The user header of every `<prefix>/graph` sample (size 112 bytes, alignment 8).
///
/// A sample is this header and a byte payload of exactly [`GraphHeader::payload_bytes`]:
/// `node_count` nodes of [`NODE_BYTES`] each (sorted by id), then `edge_count` edges of
/// [`EDGE_BYTES`] each, every record in its struct's layout ([`Node`], [`Edge`]), little-endian.
/// A sample costs what the graph holds; nothing beyond the counts is sent or initialised.
///
/// **Detecting a daemon restart**: `instance_id` is drawn anew each time `op3dsgd` starts (never
/// 0) and stays the same for its whole run; it is the epoch of `graph_version`. `graph_version`
/// only grows within one instance. A restarted daemon that restored a map snapshot (see
/// `op3dsg map info`) goes on from the snapshot's version and keeps the snapshot's node ids;
/// without one it starts again at 1. Versions published after the last snapshot and before a
/// crash are unknown to the next instance, so a version may repeat across a restart. A planner
/// that remembers the last `(instance_id, graph_version)` it used must therefore treat a
/// different `instance_id` as a new map: forget the version (and re-check any ids it cached) and
/// take the new graph, whatever its version.
///
/// **What the coordinates mean**: every position in the payload is in the frame named by
/// `world_frame` (the profile's `world.frame_id`, `world` by default; `map` on the Stretch
/// profile, the navigation stack's frame), and `source_kind` says whether the graph comes from a
/// live camera, a replay or the synthetic rooms ([`SourceKind`]). Both are fixed for one daemon
/// instance.
#[repr(C)]
#[derive(
    Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, PlacementDefault, bytemuck::Pod, bytemuck::Zeroable,
)]
#[type_name("op3dsg::GraphHeader")]
pub struct GraphHeader {
    /// [`SCHEMA_VERSION`](crate::SCHEMA_VERSION) of the publisher.
    pub schema_version: u32,
    /// Number of nodes in the payload.
    pub node_count: u32,
    /// Graph version: increases by one with every published change of the graph while one daemon
    /// instance runs; starts at 1 when the daemon starts with an empty map, at the snapshot's
    /// version + 1 when it restored one.
    pub graph_version: u64,
    /// The publishing daemon's instance: a random non-zero value drawn at start, the same for
    /// every sample of one run. A different value than the last one seen means the daemon was
    /// restarted (see the type's docs for what a planner should do).
    pub instance_id: u64,
    /// Stamp of the newest keyframe fused into this version, nanoseconds.
    pub stamp_ns: u64,
    /// Wall-clock time the sample was written, nanoseconds since the Unix epoch (for latency).
    pub publish_time_ns: u64,
    /// Number of edges in the payload (after the nodes).
    pub edge_count: u32,
    /// Number of object nodes among the nodes.
    pub object_count: u32,
    /// Number of part nodes among the nodes.
    pub part_count: u32,
    /// 1 when the map had more nodes or edges than the daemon publishes (`node_capacity`,
    /// `edge_capacity`): the sample then holds the most recently seen nodes and the edges among
    /// them. 0 otherwise.
    pub capacity_exceeded: u8,
    /// What the daemon reads its frames from: a [`SourceKind`] value (0 unknown or other,
    /// 1 live camera, 2 replay, 3 synthetic; names in [`SOURCE_KINDS`]).
    pub source_kind: u8,
    /// Reserved, zero.
    pub reserved: [u8; 2],
    /// Nodes in the map, including those not published because of capacity.
    pub total_node_count: u32,
    /// Edges in the graph, including those not published because of capacity.
    pub total_edge_count: u32,
    /// Most nodes the daemon publishes (its profile's `ipc.max_nodes`).
    pub node_capacity: u32,
    /// Most edges the daemon publishes (its profile's `ipc.max_edges`).
    pub edge_capacity: u32,
    /// Name of the frame every coordinate of the payload is in (the profile's
    /// `world.frame_id`: `world` by default, `map` on the Stretch profile), UTF-8, NUL padded;
    /// read it with [`GraphHeader::world_frame_str`]. Empty from a publisher that does not say.
    pub world_frame: [u8; NAME_CAPACITY_BYTES],
    /// Reserved, zero.
    pub reserved2: u64,
}

impl GraphHeader {
    /// Bytes of the payload this header describes: `node_count * NODE_BYTES + edge_count *
    /// EDGE_BYTES`.
    pub fn payload_bytes(&self) -> usize {
        graph_payload_bytes(self.node_count as usize, self.edge_count as usize)
    }

    /// [`Self::source_kind`] decoded; a value this build does not know reads as
    /// [`SourceKind::Unknown`].
    pub fn source_kind(&self) -> SourceKind {
        SourceKind::from_u8(self.source_kind).unwrap_or_default()
    }

    /// [`Self::world_frame`] as text (`""` when the publisher left it empty).
    pub fn world_frame_str(&self) -> &str {
        crate::fixed_str(&self.world_frame)
    }
}

/// Bytes of the payload of a graph with `nodes` nodes and `edges` edges.
pub const fn graph_payload_bytes(nodes: usize, edges: usize) -> usize {
    nodes * NODE_BYTES + edges * EDGE_BYTES
}

/// One received graph as it lies in a sample: the header and the byte payload, borrowed. Made
/// from an iceoryx2 sample (`GraphMessage::new(sample.user_header(), sample.payload())`) or from a
/// [`GraphBuffer`](crate::publish::GraphBuffer) ([`GraphBuffer::encode`](crate::publish::GraphBuffer::encode)).
///
/// Nothing is checked here; [`check_message`](crate::client::check_message) checks the contract.
#[derive(Debug, Clone, Copy)]
pub struct GraphMessage<'a> {
    /// The header.
    pub header: &'a GraphHeader,
    /// The payload: nodes, then edges.
    pub payload: &'a [u8],
}

impl<'a> GraphMessage<'a> {
    /// A message over a header and its payload.
    pub fn new(header: &'a GraphHeader, payload: &'a [u8]) -> Self {
        Self { header, payload }
    }

    /// The node records (as many as fit in the payload, at most `node_count`).
    pub fn node_records(&self) -> &'a [[u8; NODE_BYTES]] {
        let len = (self.header.node_count as usize * NODE_BYTES).min(self.payload.len());
        self.payload[..len].as_chunks::<NODE_BYTES>().0
    }

    /// The edge records (as many as fit in the payload after the nodes, at most `edge_count`).
    pub fn edge_records(&self) -> &'a [[u8; EDGE_BYTES]] {
        let start = (self.header.node_count as usize * NODE_BYTES).min(self.payload.len());
        let len = (self.header.edge_count as usize * EDGE_BYTES).min(self.payload.len() - start);
        self.payload[start..start + len].as_chunks::<EDGE_BYTES>().0
    }

    /// The nodes, decoded.
    pub fn nodes(&self) -> impl ExactSizeIterator<Item = Node> + 'a {
        self.node_records().iter().map(Node::from_bytes)
    }

    /// The edges, decoded.
    pub fn edges(&self) -> impl ExactSizeIterator<Item = Edge> + 'a {
        self.edge_records().iter().map(Edge::from_bytes)
    }

    /// Replaces `out` with the decoded nodes, reusing its buffer (one block copy on
    /// little-endian machines).
    pub fn copy_nodes_into(&self, out: &mut Vec<Node>) {
        copy_records(self.node_records().as_flattened(), out, Node::from_bytes);
    }

    /// Replaces `out` with the decoded edges, reusing its buffer (one block copy on
    /// little-endian machines).
    pub fn copy_edges_into(&self, out: &mut Vec<Edge>) {
        copy_records(self.edge_records().as_flattened(), out, Edge::from_bytes);
    }
}

/// Decodes the records in `bytes` into `out`: on little-endian machines the wire layout is the
/// struct's layout, so this is one copy into the reused buffer (zero-filling only what it grows).
#[cfg_attr(target_endian = "little", allow(unused_variables))]
fn copy_records<T: bytemuck::Pod, const N: usize>(bytes: &[u8], out: &mut Vec<T>, decode: fn(&[u8; N]) -> T) {
    let count = bytes.len() / N;
    #[cfg(target_endian = "little")]
    {
        out.truncate(count);
        out.resize(count, T::zeroed());
        bytemuck::cast_slice_mut::<T, u8>(out).copy_from_slice(&bytes[..count * N]);
    }
    #[cfg(not(target_endian = "little"))]
    {
        out.clear();
        out.extend(bytes.as_chunks::<N>().0.iter().map(decode));
    }
}
