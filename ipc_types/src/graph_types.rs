//! The graph's wire types: [`GraphSnapshot`] (header, nodes, edges), the node and edge kinds, and
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
/// The most nodes one [`GraphSnapshot`] holds. A larger map sets
/// [`GraphHeader::capacity_exceeded`] and publishes the most recently seen nodes that fit.
pub const MAX_NODES: usize = 16_384;
/// The most edges one [`GraphSnapshot`] holds (see [`MAX_NODES`] for what happens beyond).
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

/// One node of the scene graph (size 120 bytes, alignment 8, no implicit padding).
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::Node")]
pub struct Node {
    /// Stable node id within the daemon's lifetime (and across restarts from a map snapshot).
    pub id: u32,
    /// Id of the parent object of a part node, [`NO_NODE`] for objects and unattached parts.
    pub parent_id: u32,
    /// [`NodeKind`] as `u8`: 0 object, 1 part.
    pub kind: u8,
    /// Reserved, zero.
    pub reserved: [u8; 3],
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
    /// Reserved, zero.
    pub reserved2: [u8; 6],
    /// Stamp of the last keyframe that observed this node, nanoseconds.
    pub last_seen_stamp_ns: u64,
}

impl Default for Node {
    fn default() -> Self {
        Self {
            id: NO_NODE,
            parent_id: NO_NODE,
            kind: 0,
            reserved: [0; 3],
            observation_count: 0,
            label: [0; LABEL_CAPACITY_BYTES],
            confidence: 0.0,
            centre_m: [0.0; 3],
            box_min_m: [0.0; 3],
            box_max_m: [0.0; 3],
            affordance_bits: 0,
            reserved2: [0; 6],
            last_seen_stamp_ns: 0,
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
}

/// One directed edge of the scene graph (size 64 bytes, alignment 4).
///
/// Direction: `source` relates to `target` as the phrase says, e.g. handle `part of` cabinet,
/// remote `remote to control` TV, cup `on` table.
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend, PlacementDefault)]
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

/// Header of a [`GraphSnapshot`] (size 56 bytes, alignment 8).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::GraphHeader")]
pub struct GraphHeader {
    /// [`SCHEMA_VERSION`](crate::SCHEMA_VERSION) of the publisher.
    pub schema_version: u32,
    /// Number of valid entries at the start of [`GraphSnapshot::nodes`].
    pub node_count: u32,
    /// Graph version: increases by one with every published change of the graph. Starts at 1
    /// for a fresh map; continues from the restored value after a restart from a map snapshot.
    pub graph_version: u64,
    /// Stamp of the newest keyframe fused into this version, nanoseconds.
    pub stamp_ns: u64,
    /// Wall-clock time the sample was written, nanoseconds since the Unix epoch (for latency).
    pub publish_time_ns: u64,
    /// Number of valid entries at the start of [`GraphSnapshot::edges`].
    pub edge_count: u32,
    /// Number of object nodes among the valid nodes.
    pub object_count: u32,
    /// Number of part nodes among the valid nodes.
    pub part_count: u32,
    /// 1 when the map had more nodes or edges than [`MAX_NODES`] / [`MAX_EDGES`]: the snapshot
    /// then holds the most recently seen nodes and the edges among them. 0 otherwise.
    pub capacity_exceeded: u8,
    /// Reserved, zero.
    pub reserved: [u8; 3],
    /// Nodes in the map, including those not published because of capacity.
    pub total_node_count: u32,
    /// Edges in the graph, including those not published because of capacity.
    pub total_edge_count: u32,
}

/// One consistent version of the scene graph: header, nodes and edges written together.
///
/// Too large for the stack (about 3.9 MiB): loan it from the publisher and fill it in place.
#[repr(C)]
#[derive(Debug, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::GraphSnapshot")]
pub struct GraphSnapshot {
    /// Header: version, stamp, counts, capacity flag.
    pub header: GraphHeader,
    /// `header.node_count` valid nodes, sorted by id; the rest is undefined.
    pub nodes: [Node; MAX_NODES],
    /// `header.edge_count` valid edges; the rest is undefined.
    pub edges: [Edge; MAX_EDGES],
}

impl GraphSnapshot {
    /// The valid nodes.
    pub fn valid_nodes(&self) -> &[Node] {
        &self.nodes[..(self.header.node_count as usize).min(MAX_NODES)]
    }
    /// The valid edges.
    pub fn valid_edges(&self) -> &[Edge] {
        &self.edges[..(self.header.edge_count as usize).min(MAX_EDGES)]
    }
}
