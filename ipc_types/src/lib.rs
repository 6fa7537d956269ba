//! # op3dsg wire contract
//!
//! Every type a planner, a navigation stack or a tool sees over iceoryx2 shared memory is defined
//! here, once. All types are `#[repr(C)]`, plain data (no pointers, no heap), [`ZeroCopySend`]
//! and carry a stable `#[type_name]`, so a C or Python client can mirror them field by field from
//! this documentation alone (Python: a `ctypes.Structure` whose `type_name()` returns the name
//! given below).
//!
//! Conventions used by every type:
//! - Units are part of field names: `_m` metres, `_ns` nanoseconds, `_us` microseconds, `_hz`.
//! - Coordinates are in the `world` frame of the map (right-handed; which axis is up is the
//!   profile's `world.up_axis`, `+z` by default).
//! - Stamps are nanoseconds on the daemon's clock (`CLOCK_REALTIME` for live cameras, the
//!   recording's clock for replay, scene time for the synthetic source).
//! - Text is UTF-8 in a fixed buffer, padded with NUL bytes; a string that fills the buffer has no
//!   terminating NUL. Use [`fixed_str`] / [`write_fixed_str`] from Rust.
//! - Boolean-like fields are `u8` (0 or 1) so their size is the same in every language.
//!
//! ## Services (names under a configurable prefix, default `op3dsg`)
//!
//! | service                 | pattern           | payload            | QoS                                   |
//! |-------------------------|-------------------|--------------------|---------------------------------------|
//! | `<prefix>/graph`        | publish-subscribe | [`GraphSnapshot`]  | history 1, safe overflow              |
//! | `<prefix>/graph_updated`| event             | event id = graph version modulo 2^16 | notified after each graph sample |
//! | `<prefix>/health`       | publish-subscribe | [`Health`]         | history 1, safe overflow              |
//! | `<prefix>/pose`         | publish-subscribe | [`PoseStamped`]    | input: the navigation stack publishes |
//!
//! ```
//! use op3dsg_ipc_types::{GraphSnapshot, ServiceNames};
//! let names = ServiceNames::new("op3dsg");
//! assert_eq!(names.graph, "op3dsg/graph");
//! // The snapshot is large and must be built in place (in shared memory), never on the stack.
//! assert!(core::mem::size_of::<GraphSnapshot>() > 1 << 20);
//! ```

// The derive macros emit `unsafe impl ZeroCopySend`; that is the only unsafe code here.
#![allow(unsafe_code)]

pub use iceoryx2::prelude::{PlacementDefault, ZeroCopySend};

/// Version of this wire contract. Bumped whenever a type's layout or meaning changes; a client
/// must check [`GraphHeader::schema_version`] and [`Health::schema_version`] before reading.
pub const SCHEMA_VERSION: u32 = 3;

/// Bytes in a node label buffer (UTF-8, NUL padded).
pub const LABEL_CAPACITY_BYTES: usize = 48;
/// Bytes in a relation phrase buffer (UTF-8, NUL padded). The longest canonical phrase,
/// "rotate to adjust the setting or temperature", has 43 bytes.
pub const PHRASE_CAPACITY_BYTES: usize = 48;
/// Bytes in a frame id (`PoseStamped::frame_id`), a stage or a queue name.
pub const NAME_CAPACITY_BYTES: usize = 32;
/// The most nodes one [`GraphSnapshot`] holds. A larger map sets
/// [`GraphHeader::capacity_exceeded`] and publishes the most recently seen nodes that fit.
pub const MAX_NODES: usize = 16_384;
/// The most edges one [`GraphSnapshot`] holds (see [`MAX_NODES`] for what happens beyond).
pub const MAX_EDGES: usize = 32_768;
/// The most pipeline stages reported in one [`Health`] record.
pub const MAX_STAGES: usize = 16;
/// The most queues reported in one [`Health`] record.
pub const MAX_QUEUES: usize = 16;
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

/// Reads a NUL-padded UTF-8 buffer. Invalid UTF-8 is cut at the first invalid byte.
pub fn fixed_str(buffer: &[u8]) -> &str {
    let len = buffer.iter().position(|b| *b == 0).unwrap_or(buffer.len());
    match core::str::from_utf8(&buffer[..len]) {
        Ok(s) => s,
        Err(e) => core::str::from_utf8(&buffer[..e.valid_up_to()]).unwrap_or(""),
    }
}

/// Writes `text` into a NUL-padded buffer, cutting at a character boundary if it does not fit.
/// Returns `true` when the whole text fitted.
pub fn write_fixed_str(buffer: &mut [u8], text: &str) -> bool {
    let mut len = text.len().min(buffer.len());
    while !text.is_char_boundary(len) {
        len -= 1;
    }
    buffer[..len].copy_from_slice(&text.as_bytes()[..len]);
    buffer[len..].fill(0);
    len == text.len()
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
    /// [`SCHEMA_VERSION`] of the publisher.
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

/// What a [`PoseStamped`] describes.
#[repr(u8)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PoseKind {
    /// `world_from_camera`: the optical frame of the colour camera (x right, y down, z forward)
    /// in the world. On a Stretch the head pans and tilts, so the navigation stack composes the
    /// base pose with the head joints and sends this.
    #[default]
    WorldFromCamera = 0,
    /// `world_from_base`: the robot base in the world; the daemon composes it with the fixed
    /// `base_from_camera` of the profile (rigid mounts only).
    WorldFromBase = 1,
}

impl PoseKind {
    /// Decodes the wire value of [`PoseStamped::kind`].
    pub fn from_u8(value: u8) -> Option<Self> {
        match value {
            0 => Some(Self::WorldFromCamera),
            1 => Some(Self::WorldFromBase),
            _ => None,
        }
    }
}

/// A pose sent to the daemon on `<prefix>/pose` (size 104 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::PoseStamped")]
pub struct PoseStamped {
    /// Time the pose is valid at, nanoseconds, on the same clock as the camera frames.
    pub stamp_ns: u64,
    /// [`PoseKind`] as `u8`.
    pub kind: u8,
    /// Reserved, zero.
    pub reserved: [u8; 7],
    /// Translation, metres, world frame.
    pub translation_m: [f64; 3],
    /// Rotation as a unit quaternion `[x, y, z, w]`.
    pub rotation_xyzw: [f64; 4],
    /// Name of the child frame (for example `camera_color_optical_frame` or `base_link`),
    /// UTF-8, NUL padded; checked against the profile when set.
    pub frame_id: [u8; NAME_CAPACITY_BYTES],
}

/// Health of one pipeline stage (size 64 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::StageHealth")]
pub struct StageHealth {
    /// Stage name (`capture`, `keyframe`, `detect/0`, `fusion`, `prior`, `publish`, `end_to_end`, ...), NUL padded.
    pub name: [u8; NAME_CAPACITY_BYTES],
    /// Items processed since start.
    pub processed: u64,
    /// Items per second over the last health period.
    pub rate_hz: f32,
    /// Median latency of one item over the last health period, microseconds.
    pub latency_p50_us: f32,
    /// 99th percentile latency over the last health period, microseconds.
    pub latency_p99_us: f32,
    /// Errors since start (items that failed and were skipped).
    pub errors: u32,
    /// Reserved, zero.
    pub reserved: [u8; 8],
}

/// Health of one bounded queue (size 56 bytes).
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::QueueHealth")]
pub struct QueueHealth {
    /// Queue name (`frames`, `keyframes`, `detections`, `graph`, ...), NUL padded.
    pub name: [u8; NAME_CAPACITY_BYTES],
    /// Items waiting now.
    pub depth: u32,
    /// Capacity from the profile.
    pub capacity: u32,
    /// Items dropped since start (overwritten by latest-wins, or refused).
    pub dropped: u64,
    /// Items pushed since start.
    pub pushed: u64,
}

/// States of the LLM refiner ([`RefinerHealth::state`] indexes this).
pub const REFINER_STATES: [&str; 6] = ["off", "idle", "calling", "backoff", "breaker_open", "budget_exhausted"];

/// Why the LLM refiner's verification gate rejected an answer or one of its items
/// ([`RefinerHealth::rejections`] index `i` counts `REFINER_REJECTIONS[i]`):
/// `malformed` (an answer that fails strict parsing, or an item with a bad confidence),
/// `unknown_node` (an id not in that graph version), `wrong_kind` (a local relation off a
/// part-of pair, a remote one between nodes the knowledge base does not allow),
/// `non_canonical` (a relation or affordance label that maps onto no canonical one),
/// `stale` (accepted, but its nodes were gone when the result reached the graph).
pub const REFINER_REJECTIONS: [&str; 5] = ["malformed", "unknown_node", "wrong_kind", "non_canonical", "stale"];

/// The LLM refiner (size 128 bytes); all zero (state `off`) when no LLM is configured.
#[repr(C)]
#[derive(Debug, Clone, Copy, Default, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::RefinerHealth")]
pub struct RefinerHealth {
    /// Index into [`REFINER_STATES`].
    pub state: u8,
    /// 1 while the circuit breaker is open (no calls until its cool-down ends).
    pub breaker_open: u8,
    /// Reserved, zero.
    pub reserved: [u8; 2],
    /// Latency of the last completed call (success or failure), microseconds.
    pub last_latency_us: u32,
    /// Refreshes started (each sends one prompt per agent).
    pub refreshes: u64,
    /// HTTP requests sent, retries included (each counts against the hourly budget).
    pub calls: u64,
    /// Requests that failed (timeout, transport error, HTTP error status).
    pub failures: u64,
    /// Of `failures`: timeouts.
    pub timeouts: u64,
    /// Of `failures`: HTTP 429 answers.
    pub rate_limited: u64,
    /// Items that passed the verification gate.
    pub accepted: u64,
    /// Graph version of the last result sent to the fusion thread.
    pub last_graph_version: u64,
    /// Rejections by reason ([`REFINER_REJECTIONS`] order; the rest reserved, zero).
    pub rejections: [u64; 8],
}

/// Daemon health, published on `<prefix>/health` every health period (profile).
#[repr(C)]
#[derive(Debug, Clone, Copy, ZeroCopySend, PlacementDefault)]
#[type_name("op3dsg::Health")]
pub struct Health {
    /// [`SCHEMA_VERSION`] of the publisher.
    pub schema_version: u32,
    /// Number of valid entries in `stages`.
    pub stage_count: u32,
    /// Wall-clock time of this record, nanoseconds since the Unix epoch.
    pub stamp_ns: u64,
    /// Seconds since the daemon started, as nanoseconds.
    pub uptime_ns: u64,
    /// Frames delivered by the source since start.
    pub frames_captured: u64,
    /// Frames accepted by the keyframe gate.
    pub keyframes: u64,
    /// Frames dropped because no pose was available within tolerance.
    pub frames_without_pose: u64,
    /// Detections fused since start.
    pub detections_fused: u64,
    /// Current graph version.
    pub graph_version: u64,
    /// Heap bytes the fusion map holds (capacity: what the process really uses for it).
    pub map_memory_bytes: u64,
    /// Nodes in the map now (confirmed and pending).
    pub map_node_count: u32,
    /// Number of valid entries in `queues`.
    pub queue_count: u32,
    /// 1 while the frame source delivers, 0 when it is lost or finished.
    pub source_connected: u8,
    /// Reserved, zero.
    pub reserved: [u8; 7],
    /// Per-stage figures.
    pub stages: [StageHealth; MAX_STAGES],
    /// Per-queue figures.
    pub queues: [QueueHealth; MAX_QUEUES],
    /// The LLM refiner.
    pub refiner: RefinerHealth,
}

impl Default for Health {
    fn default() -> Self {
        Self {
            schema_version: SCHEMA_VERSION,
            stage_count: 0,
            stamp_ns: 0,
            uptime_ns: 0,
            frames_captured: 0,
            keyframes: 0,
            frames_without_pose: 0,
            detections_fused: 0,
            graph_version: 0,
            map_memory_bytes: 0,
            map_node_count: 0,
            queue_count: 0,
            source_connected: 0,
            reserved: [0; 7],
            stages: [StageHealth::default(); MAX_STAGES],
            queues: [QueueHealth::default(); MAX_QUEUES],
            refiner: RefinerHealth::default(),
        }
    }
}

impl Health {
    /// The valid stage entries.
    pub fn valid_stages(&self) -> &[StageHealth] {
        &self.stages[..(self.stage_count as usize).min(MAX_STAGES)]
    }
    /// The valid queue entries.
    pub fn valid_queues(&self) -> &[QueueHealth] {
        &self.queues[..(self.queue_count as usize).min(MAX_QUEUES)]
    }
}

/// The service names for a prefix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    /// `<prefix>/graph`: [`GraphSnapshot`] publish-subscribe.
    pub graph: String,
    /// `<prefix>/graph_updated`: event after each new graph version.
    pub graph_updated: String,
    /// `<prefix>/health`: [`Health`] publish-subscribe.
    pub health: String,
    /// `<prefix>/pose`: [`PoseStamped`] publish-subscribe (input to the daemon).
    pub pose: String,
}

impl ServiceNames {
    /// Names under `prefix` (no trailing slash).
    pub fn new(prefix: &str) -> Self {
        let prefix = prefix.trim_end_matches('/');
        Self {
            graph: format!("{prefix}/graph"),
            graph_updated: format!("{prefix}/graph_updated"),
            health: format!("{prefix}/health"),
            pose: format!("{prefix}/pose"),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{align_of, size_of};

    #[test]
    fn layouts_are_the_documented_ones() {
        assert_eq!(size_of::<Node>(), 120);
        assert_eq!(align_of::<Node>(), 8);
        assert_eq!(size_of::<Edge>(), 64);
        assert_eq!(size_of::<GraphHeader>(), 56);
        assert_eq!(size_of::<PoseStamped>(), 104);
        assert_eq!(size_of::<StageHealth>(), 64);
        assert_eq!(size_of::<QueueHealth>(), 56);
        assert_eq!(size_of::<RefinerHealth>(), 128);
        assert_eq!(size_of::<Health>(), 88 + MAX_STAGES * 64 + MAX_QUEUES * 56 + 128);
        assert_eq!(size_of::<GraphSnapshot>(), 56 + MAX_NODES * size_of::<Node>() + MAX_EDGES * size_of::<Edge>());
    }

    #[test]
    fn type_names_are_stable() {
        // SAFETY: `type_name` is an unsafe trait fn only because implementors must keep it stable.
        unsafe {
            assert_eq!(<Node as ZeroCopySend>::type_name(), "op3dsg::Node");
            assert_eq!(<GraphSnapshot as ZeroCopySend>::type_name(), "op3dsg::GraphSnapshot");
            assert_eq!(<Health as ZeroCopySend>::type_name(), "op3dsg::Health");
            assert_eq!(<RefinerHealth as ZeroCopySend>::type_name(), "op3dsg::RefinerHealth");
            assert_eq!(<PoseStamped as ZeroCopySend>::type_name(), "op3dsg::PoseStamped");
        }
    }

    #[test]
    fn fixed_strings_round_trip_and_cut_at_char_boundaries() {
        let mut buf = [0u8; 8];
        assert!(write_fixed_str(&mut buf, "knob"));
        assert_eq!(fixed_str(&buf), "knob");
        assert!(!write_fixed_str(&mut buf, "drawer handle"));
        assert_eq!(fixed_str(&buf), "drawer h");
        assert!(!write_fixed_str(&mut buf, "ÄÄÄÄÄ")); // 10 bytes, cut to 8 = 4 chars
        assert_eq!(fixed_str(&buf), "ÄÄÄÄ");
        assert!(write_fixed_str(&mut buf, "12345678"));
        assert_eq!(fixed_str(&buf), "12345678");
    }

    #[test]
    fn relation_ids_round_trip() {
        for phrase in SPATIAL_RELATIONS.iter().chain(FUNCTIONAL_RELATIONS.iter()) {
            let (_, id) = relation_id(phrase).unwrap();
            assert_eq!(relation_phrase(id), Some(*phrase));
            assert!(phrase.len() <= PHRASE_CAPACITY_BYTES);
        }
        assert_eq!(relation_id("part of"), Some((EdgeKind::Spatial, 0)));
        assert_eq!(relation_id("remote to control"), Some((EdgeKind::Functional, 105)));
        assert_eq!(relation_id("frobnicate"), None);
    }

    #[test]
    fn affordance_bits_round_trip() {
        let bits = affordance_bits(["hook_pull", "rotate"]).unwrap();
        assert_eq!(bits, 0b1001);
        assert_eq!(affordance_names(bits).collect::<Vec<_>>(), ["rotate", "hook_pull"]);
        assert_eq!(affordance_bits(["fly"]), Err("fly"));
    }
}
