//! The graph's wire types: [`GraphHeader`] and the byte payload of [`Node`] and [`Edge`] records
//! ([`GraphMessage`] borrows one), the node and edge kinds, and
//! the canonical affordance and relation vocabularies they index.

// The derive macros emit `unsafe impl ZeroCopySend`; that is the only unsafe code here.
#![allow(unsafe_code)]

use iceoryx2::prelude::{PlacementDefault, ZeroCopySend};

use crate::text::fixed_str;

/// Bytes in a node label buffer (UTF-8, NUL padded).
pub const LABEL_CAPACITY_BYTES: usize = 48;
/// Bytes in a relation phrase buffer (UTF-8, NUL padded). The longest canonical phrase,
/// "rotate to adjust the setting or temperature", has 43 bytes.
pub const PHRASE_CAPACITY_BYTES: usize = 48;
/// The most nodes one graph sample holds when the profile sets no `ipc.max_nodes`. A larger map
/// sets [`GraphHeader::capacity_exceeded`] and publishes the most recently seen nodes that fit.
pub const MAX_NODES: usize = 16_384;
/// The most edges one graph sample holds when the profile sets no `ipc.max_edges` (see
/// [`MAX_NODES`] for what happens beyond).
pub const MAX_EDGES: usize = 32_768;
/// Node id meaning "no node" (for example the parent of an object node).
pub const NO_NODE: u32 = u32::MAX;

/// The 9 canonical affordances (the SceneFun3D set used by UniGraph3D), in bit order:
/// bit `i` of [`Node::affordance_bits`] is `AFFORDANCES[i]`.
pub const AFFORDANCES: [&str; 9] =
    ["rotate", "key_press", "tip_push", "hook_pull", "pinch_pull", "hook_turn", "foot_push", "plug_in", "unplug"];

/// The 11 canonical functional relations of UniGraph3D. A functional [`Edge`]'s
/// `relation_id` is `FUNCTIONAL_RELATIONS` index + [`FUNCTIONAL_RELATION_BASE`].
pub const FUNCTIONAL_RELATIONS: [&str; 11] = [
    "pull to open or close",
    "control the water flow",
    "rotate to adjust the setting or temperature",
    "press to start and operate",
    "turn on or turn off",
    "remote to control",
    "press to flush",
    "provide power",
    "push or press to open",
    "operate or adjust the flow or setting",
    "rotate to open or close",
];

/// The canonical spatial relations. A spatial [`Edge`]'s `relation_id` is the index here.
pub const SPATIAL_RELATIONS: [&str; 7] = ["part of", "on", "under", "above", "below", "next to", "inside"];

/// Offset of functional relation ids, so that every relation id is unique across kinds.
pub const FUNCTIONAL_RELATION_BASE: u16 = 100;

/// Canonical relation id for a phrase of [`SPATIAL_RELATIONS`] or [`FUNCTIONAL_RELATIONS`].
pub fn relation_id(phrase: &str) -> Option<(EdgeKind, u16)> {
    if let Some(i) = SPATIAL_RELATIONS.iter().position(|p| *p == phrase) {
        return Some((EdgeKind::Spatial, i as u16));
    }
    FUNCTIONAL_RELATIONS
        .iter()
        .position(|p| *p == phrase)
        .map(|i| (EdgeKind::Functional, FUNCTIONAL_RELATION_BASE + i as u16))
}

/// The canonical phrase of a relation id (inverse of [`relation_id`]).
pub fn relation_phrase(id: u16) -> Option<&'static str> {
    if id >= FUNCTIONAL_RELATION_BASE {
        FUNCTIONAL_RELATIONS.get((id - FUNCTIONAL_RELATION_BASE) as usize).copied()
    } else {
        SPATIAL_RELATIONS.get(id as usize).copied()
    }
}

/// Bit set over [`AFFORDANCES`] for the given names; unknown names give `Err(name)`.
pub fn affordance_bits<'a>(names: impl IntoIterator<Item = &'a str>) -> Result<u16, &'a str> {
    let mut bits = 0u16;
    for name in names {
        let i = AFFORDANCES.iter().position(|a| *a == name).ok_or(name)?;
        bits |= 1 << i;
    }
    Ok(bits)
}

/// Names of the affordances set in `bits`, in canonical order.
pub fn affordance_names(bits: u16) -> impl Iterator<Item = &'static str> {
    AFFORDANCES.iter().enumerate().filter(move |(i, _)| bits & (1 << i) != 0).map(|(_, a)| *a)
}

/// Kind of a graph node.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum NodeKind {
    /// A physical object (cabinet, stove, TV, ...).
    #[default]
    Object = 0,
    /// An interactive part of an object (handle, knob, button, switch, ...).
    Part = 1,
}

impl NodeKind {
    /// Decodes the wire value of [`Node::kind`].
    pub fn from_u8(value: u8) -> Option<Self> {
        match value {
            0 => Some(Self::Object),
            1 => Some(Self::Part),
            _ => None,
        }
    }
    /// Lower-case name as used in the JSON form ("object", "part").
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Object => "object",
            Self::Part => "part",
        }
    }
}

/// Kind of a graph edge.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EdgeKind {
    /// Geometric relation ([`SPATIAL_RELATIONS`]), including `part of`.
    #[default]
    Spatial = 0,
    /// Functional relation ([`FUNCTIONAL_RELATIONS`]): the source acts on the target.
    Functional = 1,
}

impl EdgeKind {
    /// Decodes the wire value of [`Edge::kind`].
    pub fn from_u8(value: u8) -> Option<Self> {
        match value {
            0 => Some(Self::Spatial),
            1 => Some(Self::Functional),
            _ => None,
        }
    }
    /// Lower-case name as used in the JSON form ("spatial", "functional").
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Spatial => "spatial",
            Self::Functional => "functional",
        }
    }
}

/// Where an edge came from.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EdgeOrigin {
    /// Derived from fused geometry (spatial rules, part-of attachment).
    #[default]
    Geometry = 0,
    /// The offline knowledge reasoner.
    Knowledge = 1,
    /// An LLM agent, after the verification gate.
    Llm = 2,
    /// The knowledge reasoner and an LLM agent agree.
    KnowledgeAndLlm = 3,
}

impl EdgeOrigin {
    /// Decodes the wire value of [`Edge::origin`].
    pub fn from_u8(value: u8) -> Option<Self> {
        match value {
            0 => Some(Self::Geometry),
            1 => Some(Self::Knowledge),
            2 => Some(Self::Llm),
            3 => Some(Self::KnowledgeAndLlm),
            _ => None,
        }
    }
    /// Lower-case name as used in the JSON form.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::Geometry => "geometry",
            Self::Knowledge => "knowledge",
            Self::Llm => "llm",
            Self::KnowledgeAndLlm => "knowledge+llm",
        }
    }
}

/// One node of the scene graph (size 144 bytes, alignment 8, no implicit padding).
///
/// Byte offsets: `id` 0, `parent_id` 4, `kind` 8, `affordance_knowledge_bits` 10,
/// `observation_count` 12, `label` 16, `confidence` 64, `centre_m` 68, `box_min_m` 80,
/// `box_max_m` 92, `affordance_bits` 104, `affordance_llm_bits` 106, `obb_yaw_rad` 108,
/// `last_seen_stamp_ns` 112, `obb_centre_m` 120, `obb_size_m` 132.
///
/// Each affordance carries an origin like an edge ([`EdgeOrigin`], [`Node::affordance_origin`]):
/// its bit in `affordance_knowledge_bits` only: `knowledge`; in `affordance_llm_bits` only:
/// `llm`; in both: `knowledge+llm`; in neither: `geometry` (this daemon derives no affordance
/// from geometry alone, so it appears only for a publisher that sets `affordance_bits` without
/// the origin masks). Bits of the origin masks outside `affordance_bits` mean nothing.
///
/// Two boxes around the node's points: the axis-aligned `box_min_m`..`box_max_m`, and the
/// gravity-aligned oriented box (`obb_*`, schema 5): its third axis is the world's up axis (the
/// daemon profile's `world.up_axis`, +z on a robot), its first axis is the world's first
/// horizontal axis turned by `obb_yaw_rad` about up towards the second (for +z up: x turned
/// towards y), its second axis is `up × first`. With +z up the world corners are
/// `obb_centre_m + R_z(obb_yaw_rad) * (±sx/2, ±sy/2, ±sz/2)` for `obb_size_m = [sx, sy, sz]`.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend, PlacementDefault, bytemuck::Pod, bytemuck::Zeroable)]
#[type_name("op3dsg::Node")]
pub struct Node {
    /// Node id, stable while one daemon instance runs ([`GraphHeader::instance_id`]) and across
    /// a restart that restored a map snapshot.
    pub id: u32,
    /// Id of the parent object of a part node, [`NO_NODE`] for objects and unattached parts.
    pub parent_id: u32,
    /// [`NodeKind`] as `u8`: 0 object, 1 part.
    pub kind: u8,
    /// Reserved, zero.
    pub reserved: u8,
    /// The bits of `affordance_bits` the offline knowledge reasoner gave (schema 7); with
    /// `affordance_llm_bits` they name each affordance's origin ([`Node::affordance_origin`]).
    pub affordance_knowledge_bits: u16,
    /// Number of keyframe detections fused into this node.
    pub observation_count: u32,
    /// Label (the winner of the node's label vote), UTF-8, NUL padded.
    pub label: [u8; LABEL_CAPACITY_BYTES],
    /// Confidence in [0, 1]: the winning label's share of the vote times the mean detector score.
    pub confidence: f32,
    /// Centre of the node's points, world frame, metres.
    pub centre_m: [f32; 3],
    /// Minimum corner of the axis-aligned box around the node's points, world frame, metres.
    pub box_min_m: [f32; 3],
    /// Maximum corner of the axis-aligned box, world frame, metres.
    pub box_max_m: [f32; 3],
    /// Bit set over [`AFFORDANCES`] (bit `i` = `AFFORDANCES[i]`).
    pub affordance_bits: u16,
    /// The bits of `affordance_bits` an LLM agent gave, after the verification gate (schema 7;
    /// see `affordance_knowledge_bits`).
    pub affordance_llm_bits: u16,
    /// Yaw of the oriented box about the world's up axis, radians in `(-pi/2, pi/2]` (see the
    /// type's docs; 0 when the box is axis-aligned).
    pub obb_yaw_rad: f32,
    /// Stamp of the last keyframe that observed this node, nanoseconds.
    pub last_seen_stamp_ns: u64,
    /// Centre of the oriented box, world frame, metres.
    pub obb_centre_m: [f32; 3],
    /// Extent of the oriented box along its first, second (horizontal) and third (up) axes,
    /// metres.
    pub obb_size_m: [f32; 3],
}

impl Default for Node {
    fn default() -> Self {
        Self {
            id: NO_NODE,
            parent_id: NO_NODE,
            kind: 0,
            reserved: 0,
            affordance_knowledge_bits: 0,
            observation_count: 0,
            label: [0; LABEL_CAPACITY_BYTES],
            confidence: 0.0,
            centre_m: [0.0; 3],
            box_min_m: [0.0; 3],
            box_max_m: [0.0; 3],
            affordance_bits: 0,
            affordance_llm_bits: 0,
            obb_yaw_rad: 0.0,
            last_seen_stamp_ns: 0,
            obb_centre_m: [0.0; 3],
            obb_size_m: [0.0; 3],
        }
    }
}

impl Node {
    /// The label as text.
    pub fn label_str(&self) -> &str {
        fixed_str(&self.label)
    }
    /// The decoded kind (an unknown wire value reads as `None`).
    pub fn node_kind(&self) -> Option<NodeKind> {
        NodeKind::from_u8(self.kind)
    }
    /// Where the affordance `AFFORDANCES[index]` came from; `None` when the node does not have
    /// it (see the type's docs).
    pub fn affordance_origin(&self, index: usize) -> Option<EdgeOrigin> {
        affordance_origin(self.affordance_bits, self.affordance_knowledge_bits, self.affordance_llm_bits, index)
    }
}

/// The origin of affordance `AFFORDANCES[index]` from a node's three masks ([`Node`]'s docs):
/// `None` when `bits` lacks it, else knowledge, llm, knowledge+llm or geometry.
pub fn affordance_origin(bits: u16, knowledge_bits: u16, llm_bits: u16, index: usize) -> Option<EdgeOrigin> {
    if index >= AFFORDANCES.len() {
        return None;
    }
    let bit = 1u16 << index;
    if bits & bit == 0 {
        return None;
    }
    Some(match (knowledge_bits & bit != 0, llm_bits & bit != 0) {
        (true, true) => EdgeOrigin::KnowledgeAndLlm,
        (true, false) => EdgeOrigin::Knowledge,
        (false, true) => EdgeOrigin::Llm,
        (false, false) => EdgeOrigin::Geometry,
    })
}

/// Each affordance in `bits` with its origin (see [`affordance_origin`]), in canonical order.
pub fn affordance_origins(
    bits: u16,
    knowledge_bits: u16,
    llm_bits: u16,
) -> impl Iterator<Item = (&'static str, EdgeOrigin)> {
    AFFORDANCES
        .iter()
        .enumerate()
        .filter_map(move |(i, name)| affordance_origin(bits, knowledge_bits, llm_bits, i).map(|o| (*name, o)))
}

/// One directed edge of the scene graph (size 64 bytes, alignment 4).
///
/// Direction: `source` relates to `target` as the phrase says, e.g. handle `part of` cabinet,
/// remote `remote to control` TV, cup `on` table.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend, PlacementDefault, bytemuck::Pod, bytemuck::Zeroable)]
#[type_name("op3dsg::Edge")]
pub struct Edge {
    /// Source node id.
    pub source_id: u32,
    /// Target node id.
    pub target_id: u32,
    /// [`EdgeKind`] as `u8`: 0 spatial, 1 functional.
    pub kind: u8,
    /// [`EdgeOrigin`] as `u8`: 0 geometry, 1 knowledge, 2 llm, 3 knowledge+llm.
    pub origin: u8,
    /// Canonical relation id: index into [`SPATIAL_RELATIONS`] for spatial edges,
    /// [`FUNCTIONAL_RELATION_BASE`] + index into [`FUNCTIONAL_RELATIONS`] for functional ones.
    pub relation_id: u16,
    /// Confidence in [0, 1].
    pub confidence: f32,
    /// The canonical phrase of `relation_id`, UTF-8, NUL padded (redundant, for readers without
    /// the tables).
    pub phrase: [u8; PHRASE_CAPACITY_BYTES],
}

impl Default for Edge {
    fn default() -> Self {
        Self {
            source_id: NO_NODE,
            target_id: NO_NODE,
            kind: 0,
            origin: 0,
            relation_id: 0,
            confidence: 0.0,
            phrase: [0; PHRASE_CAPACITY_BYTES],
        }
    }
}

impl Edge {
    /// The phrase as text.
    pub fn phrase_str(&self) -> &str {
        fixed_str(&self.phrase)
    }
}

/// Bytes of one node in the graph payload: [`Node`]'s layout, little-endian.
pub const NODE_BYTES: usize = 144;
/// Bytes of one edge in the graph payload: [`Edge`]'s layout, little-endian.
pub const EDGE_BYTES: usize = 64;

impl Node {
    /// Writes this node's [`NODE_BYTES`] bytes (the struct's field offsets, little-endian) into
    /// `b`, every byte of it; the inverse of [`Node::from_bytes`].
    pub fn write_bytes(&self, b: &mut [u8; NODE_BYTES]) {
        #[cfg(target_endian = "little")]
        b.copy_from_slice(bytemuck::bytes_of(self));
        #[cfg(not(target_endian = "little"))]
        self.write_fields(b);
    }

    /// [`Node::write_bytes`] field by field (the portable form, for big-endian machines).
    #[cfg(any(test, not(target_endian = "little")))]
    fn write_fields(&self, b: &mut [u8; NODE_BYTES]) {
        b[0..4].copy_from_slice(&self.id.to_le_bytes());
        b[4..8].copy_from_slice(&self.parent_id.to_le_bytes());
        b[8] = self.kind;
        b[9] = self.reserved;
        b[10..12].copy_from_slice(&self.affordance_knowledge_bits.to_le_bytes());
        b[12..16].copy_from_slice(&self.observation_count.to_le_bytes());
        b[16..64].copy_from_slice(&self.label);
        b[64..68].copy_from_slice(&self.confidence.to_le_bytes());
        for (i, v) in self.centre_m.iter().chain(&self.box_min_m).chain(&self.box_max_m).enumerate() {
            b[68 + 4 * i..72 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
        b[104..106].copy_from_slice(&self.affordance_bits.to_le_bytes());
        b[106..108].copy_from_slice(&self.affordance_llm_bits.to_le_bytes());
        b[108..112].copy_from_slice(&self.obb_yaw_rad.to_le_bytes());
        b[112..120].copy_from_slice(&self.last_seen_stamp_ns.to_le_bytes());
        for (i, v) in self.obb_centre_m.iter().chain(&self.obb_size_m).enumerate() {
            b[120 + 4 * i..124 + 4 * i].copy_from_slice(&v.to_le_bytes());
        }
    }

    /// Appends this node's [`NODE_BYTES`] bytes to `out` (see [`Node::write_bytes`]).
    pub fn append_bytes(&self, out: &mut Vec<u8>) {
        let mut b = [0u8; NODE_BYTES];
        self.write_bytes(&mut b);
        out.extend_from_slice(&b);
    }

    /// The node in `b` (laid out as [`Node::append_bytes`] writes it).
    pub fn from_bytes(b: &[u8; NODE_BYTES]) -> Self {
        #[cfg(target_endian = "little")]
        return bytemuck::pod_read_unaligned(b);
        #[cfg(not(target_endian = "little"))]
        Self::from_fields(b)
    }

    /// [`Node::from_bytes`] field by field (the portable form, for big-endian machines).
    #[cfg(any(test, not(target_endian = "little")))]
    fn from_fields(b: &[u8; NODE_BYTES]) -> Self {
        let u32_at = |o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        let f32_at = |o: usize| f32::from_bits(u32_at(o));
        let vec3_at = |o: usize| [f32_at(o), f32_at(o + 4), f32_at(o + 8)];
        let mut label = [0u8; LABEL_CAPACITY_BYTES];
        label.copy_from_slice(&b[16..64]);
        let mut last_seen = [0u8; 8];
        last_seen.copy_from_slice(&b[112..120]);
        Self {
            id: u32_at(0),
            parent_id: u32_at(4),
            kind: b[8],
            reserved: b[9],
            affordance_knowledge_bits: u16::from_le_bytes([b[10], b[11]]),
            observation_count: u32_at(12),
            label,
            confidence: f32_at(64),
            centre_m: vec3_at(68),
            box_min_m: vec3_at(80),
            box_max_m: vec3_at(92),
            affordance_bits: u16::from_le_bytes([b[104], b[105]]),
            affordance_llm_bits: u16::from_le_bytes([b[106], b[107]]),
            obb_yaw_rad: f32_at(108),
            last_seen_stamp_ns: u64::from_le_bytes(last_seen),
            obb_centre_m: vec3_at(120),
            obb_size_m: vec3_at(132),
        }
    }
}

impl Edge {
    /// Writes this edge's [`EDGE_BYTES`] bytes (the struct's field offsets, little-endian) into
    /// `b`, every byte of it; the inverse of [`Edge::from_bytes`].
    pub fn write_bytes(&self, b: &mut [u8; EDGE_BYTES]) {
        #[cfg(target_endian = "little")]
        b.copy_from_slice(bytemuck::bytes_of(self));
        #[cfg(not(target_endian = "little"))]
        self.write_fields(b);
    }

    /// [`Edge::write_bytes`] field by field (the portable form, for big-endian machines).
    #[cfg(any(test, not(target_endian = "little")))]
    fn write_fields(&self, b: &mut [u8; EDGE_BYTES]) {
        b[0..4].copy_from_slice(&self.source_id.to_le_bytes());
        b[4..8].copy_from_slice(&self.target_id.to_le_bytes());
        b[8] = self.kind;
        b[9] = self.origin;
        b[10..12].copy_from_slice(&self.relation_id.to_le_bytes());
        b[12..16].copy_from_slice(&self.confidence.to_le_bytes());
        b[16..64].copy_from_slice(&self.phrase);
    }

    /// Appends this edge's [`EDGE_BYTES`] bytes to `out` (see [`Edge::write_bytes`]).
    pub fn append_bytes(&self, out: &mut Vec<u8>) {
        let mut b = [0u8; EDGE_BYTES];
        self.write_bytes(&mut b);
        out.extend_from_slice(&b);
    }

    /// The edge in `b` (laid out as [`Edge::append_bytes`] writes it).
    pub fn from_bytes(b: &[u8; EDGE_BYTES]) -> Self {
        #[cfg(target_endian = "little")]
        return bytemuck::pod_read_unaligned(b);
        #[cfg(not(target_endian = "little"))]
        Self::from_fields(b)
    }

    /// [`Edge::from_bytes`] field by field (the portable form, for big-endian machines).
    #[cfg(any(test, not(target_endian = "little")))]
    fn from_fields(b: &[u8; EDGE_BYTES]) -> Self {
        let u32_at = |o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
        let mut phrase = [0u8; PHRASE_CAPACITY_BYTES];
        phrase.copy_from_slice(&b[16..64]);
        Self {
            source_id: u32_at(0),
            target_id: u32_at(4),
            kind: b[8],
            origin: b[9],
            relation_id: u16::from_le_bytes([b[10], b[11]]),
            confidence: f32::from_bits(u32_at(12)),
            phrase,
        }
    }
}

/// The user header of every `<prefix>/graph` sample (size 80 bytes, alignment 8).
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
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, ZeroCopySend, PlacementDefault)]
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
    /// Reserved, zero.
    pub reserved: [u8; 3],
    /// Nodes in the map, including those not published because of capacity.
    pub total_node_count: u32,
    /// Edges in the graph, including those not published because of capacity.
    pub total_edge_count: u32,
    /// Most nodes the daemon publishes (its profile's `ipc.max_nodes`).
    pub node_capacity: u32,
    /// Most edges the daemon publishes (its profile's `ipc.max_edges`).
    pub edge_capacity: u32,
    /// Reserved, zero.
    pub reserved2: u32,
}

impl GraphHeader {
    /// Bytes of the payload this header describes: `node_count * NODE_BYTES + edge_count *
    /// EDGE_BYTES`.
    pub fn payload_bytes(&self) -> usize {
        graph_payload_bytes(self.node_count as usize, self.edge_count as usize)
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

#[cfg(test)]
mod record_tests {
    use super::*;

    fn node(seed: u32) -> Node {
        let f = |k: u32| (seed * 31 + k) as f32 * 0.125 - 3.0;
        let mut label = [0u8; LABEL_CAPACITY_BYTES];
        crate::write_fixed_str(&mut label, "stove knob");
        Node {
            id: seed,
            parent_id: seed.wrapping_add(7),
            kind: (seed % 2) as u8,
            reserved: 1,
            affordance_knowledge_bits: 0x1ff & (seed as u16 * 11),
            observation_count: seed * 3 + 1,
            label,
            confidence: f(1),
            centre_m: [f(2), f(3), f(4)],
            box_min_m: [f(5), f(6), f(7)],
            box_max_m: [f(8), f(9), f(10)],
            affordance_bits: 0x1ff & (seed as u16 * 37),
            affordance_llm_bits: 0x1ff & (seed as u16 * 13),
            obb_yaw_rad: f(11),
            last_seen_stamp_ns: u64::from(seed) * 1_000_000_007 + 0x0102_0304_0506_0708,
            obb_centre_m: [f(12), f(13), f(14)],
            obb_size_m: [f(15), f(16), f(17)],
        }
    }

    fn edge(seed: u32) -> Edge {
        let mut phrase = [0u8; PHRASE_CAPACITY_BYTES];
        crate::write_fixed_str(&mut phrase, "rotate to adjust the setting");
        Edge {
            source_id: seed,
            target_id: seed ^ 0xa5a5,
            kind: (seed % 2) as u8,
            origin: (seed % 4) as u8,
            relation_id: (seed % 300) as u16,
            confidence: seed as f32 / 7.0,
            phrase,
        }
    }

    /// The block copies of little-endian machines and the field-by-field form agree byte for
    /// byte, both ways.
    #[test]
    fn block_and_field_encodings_agree() {
        for seed in [0, 1, 2, 977, 65_537] {
            let n = node(seed);
            let (mut block, mut fields) = ([0u8; NODE_BYTES], [0u8; NODE_BYTES]);
            n.write_bytes(&mut block);
            n.write_fields(&mut fields);
            assert_eq!(block, fields);
            assert_eq!(bytemuck::bytes_of(&Node::from_bytes(&fields)), bytemuck::bytes_of(&Node::from_fields(&block)));
            let e = edge(seed);
            let (mut block, mut fields) = ([0u8; EDGE_BYTES], [0u8; EDGE_BYTES]);
            e.write_bytes(&mut block);
            e.write_fields(&mut fields);
            assert_eq!(block, fields);
            assert_eq!(bytemuck::bytes_of(&Edge::from_bytes(&fields)), bytemuck::bytes_of(&Edge::from_fields(&block)));
        }
    }

    /// `copy_nodes_into` / `copy_edges_into` decode what was written, shrinking and growing the
    /// reused buffer.
    #[test]
    fn bulk_copies_decode_every_record() {
        let nodes: Vec<Node> = (0..50).map(node).collect();
        let edges: Vec<Edge> = (0..90).map(edge).collect();
        let mut payload = Vec::new();
        nodes.iter().for_each(|n| n.append_bytes(&mut payload));
        edges.iter().for_each(|e| e.append_bytes(&mut payload));
        let header = GraphHeader { node_count: 50, edge_count: 90, ..GraphHeader::default() };
        let message = GraphMessage::new(&header, &payload);
        let (mut out_nodes, mut out_edges) = (vec![node(999); 70], Vec::new());
        for _ in 0..2 {
            message.copy_nodes_into(&mut out_nodes);
            message.copy_edges_into(&mut out_edges);
            assert_eq!(bytemuck::cast_slice::<Node, u8>(&out_nodes), bytemuck::cast_slice::<Node, u8>(&nodes));
            assert_eq!(bytemuck::cast_slice::<Edge, u8>(&out_edges), bytemuck::cast_slice::<Edge, u8>(&edges));
            out_nodes.truncate(10);
        }
    }
}
