//! The graph codec: the runtime's [`SceneGraph`] encoded into a wire graph sample (a
//! [`GraphHeader`] and the byte payload of node and edge records, [`GraphEncoder`], capacity rules
//! included), and read back from a received sample or from the client library's owned [`Graph`]
//! ([`message_to_scene_graph`], [`graph_to_scene_graph`]).

use op3dsg_ipc_types::{
    EDGE_BYTES, Edge, EdgeKind, EdgeOrigin, Graph, GraphHeader, GraphMessage, MAX_EDGES, MAX_NODES, NO_NODE,
    NODE_BYTES, Node as WireNode, NodeKind, PHRASE_CAPACITY_BYTES, SCHEMA_VERSION, SnapshotError, check_message,
    graph_payload_bytes, relation_phrase,
};
use std::mem::MaybeUninit;

use rustc_hash::FxHashMap;

use crate::graph::{GraphEdge, GraphNode, SceneGraph};
use crate::ipc::GraphOrigin;
#[cfg(doc)]
use crate::ipc::GraphServer;
use crate::world::OrientedBox;

/// The most nodes and edges one graph sample holds (the profile's `ipc.max_nodes` and
/// `ipc.max_edges`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GraphCapacity {
    /// Most nodes per sample.
    pub max_nodes: usize,
    /// Most edges per sample.
    pub max_edges: usize,
}

impl Default for GraphCapacity {
    fn default() -> Self {
        Self { max_nodes: MAX_NODES, max_edges: MAX_EDGES }
    }
}

impl GraphCapacity {
    /// Bytes of the largest payload: what the publisher reserves per sample.
    pub fn max_payload_bytes(&self) -> usize {
        graph_payload_bytes(self.max_nodes, self.max_edges)
    }
}

/// What one [`GraphEncoder::encode`] / [`GraphServer::publish_graph`] wrote.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PublishReport {
    /// Graph version written.
    pub version: u64,
    /// Nodes written into the sample.
    pub nodes_written: usize,
    /// Edges written into the sample.
    pub edges_written: usize,
    /// Nodes in the graph.
    pub total_nodes: usize,
    /// Edges in the graph.
    pub total_edges: usize,
    /// `true` when nodes or edges were left out for capacity (`capacity_exceeded` was set).
    pub truncated: bool,
    /// Labels cut to fit the label buffer.
    pub labels_cut: usize,
    /// Edges left out because an endpoint is not in the graph at all (a pipeline bug).
    pub dangling_edges: usize,
    /// Bytes of the payload sent (nodes and edges; the header comes on top).
    pub payload_bytes: usize,
}

/// Node id → index, as a table indexed by id while the ids are dense (the runtime hands them out
/// from a counter), else as a hash map; reuses its storage between graphs.
#[derive(Debug, Default)]
struct IdTable {
    dense: Vec<u32>,
    sparse: FxHashMap<u32, u32>,
    use_sparse: bool,
}

impl IdTable {
    const ABSENT: u32 = u32::MAX;

    /// Rebuilds the table over `(id, index)` pairs; `max_id` is the largest id among them.
    fn rebuild(&mut self, len: usize, max_id: Option<u32>, entries: impl Iterator<Item = (u32, u32)>) {
        self.dense.clear();
        self.sparse.clear();
        let dense_len = max_id.map_or(0, |id| id as usize + 1);
        self.use_sparse = dense_len > len * 4 + 1024;
        if self.use_sparse {
            self.sparse.extend(entries);
        } else {
            self.dense.resize(dense_len, Self::ABSENT);
            for (id, index) in entries {
                if let Some(slot) = self.dense.get_mut(id as usize) {
                    *slot = index;
                }
            }
        }
    }

    fn get(&self, id: u32) -> Option<u32> {
        if self.use_sparse {
            self.sparse.get(&id).copied()
        } else {
            self.dense.get(id as usize).copied().filter(|&i| i != Self::ABSENT)
        }
    }
}

/// Encodes [`SceneGraph`]s into the wire form, keeping every buffer between calls: once a graph
/// of a given size has been encoded, encoding another of at most that size allocates nothing.
#[derive(Debug, Default)]
pub struct GraphEncoder {
    capacity: GraphCapacity,
    instance_id: u64,
    /// The source kind and world frame stamped into every header.
    origin: GraphOrigin,
    header: GraphHeader,
    /// The payload of the last graph is `payload[..payload_len]`; the buffer only grows.
    payload: Vec<u8>,
    payload_len: usize,
    /// Indices into `graph.nodes` of the published nodes.
    selected: Vec<usize>,
    /// `(index into graph.edges, source node index, target node index)` of the published edges.
    edges: Vec<(u32, u32, u32)>,
    /// Published node id -> index into `graph.nodes`, for edge filtering.
    published: IdTable,
    /// Every node id, when nodes were left out (to tell capacity from dangling edges).
    all_ids: IdTable,
    /// The wire phrase of each relation id (NUL padded), so edges copy it instead of building it.
    phrases: Vec<[u8; PHRASE_CAPACITY_BYTES]>,
}

impl GraphEncoder {
    /// An encoder for samples of at most `capacity`, stamping `instance_id` into every header.
    pub fn new(capacity: GraphCapacity, instance_id: u64) -> Self {
        let phrases = (0..=RELATION_ID_TABLE_MAX)
            .map(|id| {
                let mut phrase = [0u8; PHRASE_CAPACITY_BYTES];
                op3dsg_ipc_types::write_fixed_str(&mut phrase, relation_phrase(id).unwrap_or(""));
                phrase
            })
            .collect();
        Self { capacity, instance_id, phrases, ..Self::default() }
    }

    /// The instance id stamped into every header.
    pub fn instance_id(&self) -> u64 {
        self.instance_id
    }

    /// Stamps `origin` (source kind, world frame) into every header from now on.
    pub fn set_origin(&mut self, origin: GraphOrigin) {
        self.origin = origin;
    }

    /// The capacity.
    pub fn capacity(&self) -> GraphCapacity {
        self.capacity
    }

    /// The header of the last encoded graph.
    pub fn header(&self) -> &GraphHeader {
        &self.header
    }

    /// Stamps the header's `publish_time_ns` (the publisher does, just before sending).
    pub fn set_publish_time_ns(&mut self, publish_time_ns: u64) {
        self.header.publish_time_ns = publish_time_ns;
    }

    /// The payload of the last encoded graph.
    pub fn payload(&self) -> &[u8] {
        &self.payload[..self.payload_len]
    }

    /// The last encoded graph as a subscriber receives it.
    pub fn message(&self) -> GraphMessage<'_> {
        GraphMessage::new(&self.header, self.payload())
    }

    /// Chooses what of `graph` a sample holds (nodes sorted by id, edges) and writes the header's
    /// counts; [`Self::write_payload`] then writes the records. Pure: no shared memory.
    ///
    /// Beyond `max_nodes` it keeps the most recently seen nodes (highest `last_seen_stamp_ns`,
    /// on ties the lower id) and only the edges between kept nodes; beyond `max_edges` it keeps
    /// the edges whose older endpoint was seen most recently (on ties the earlier edge). Either
    /// sets `capacity_exceeded`. `total_*` are always the graph's real counts. `publish_time_ns`
    /// is set to 0; the publisher stamps it.
    pub fn select(&mut self, graph: &SceneGraph) -> PublishReport {
        let GraphCapacity { max_nodes, max_edges } = self.capacity;
        let mut report = PublishReport {
            version: graph.version,
            total_nodes: graph.nodes.len(),
            total_edges: graph.edges.len(),
            ..PublishReport::default()
        };

        let selected = &mut self.selected;
        selected.clear();
        selected.extend(0..graph.nodes.len());
        if selected.len() > max_nodes {
            let recency = |&a: &usize, &b: &usize| {
                let (na, nb) = (&graph.nodes[a], &graph.nodes[b]);
                nb.last_seen_stamp_ns.cmp(&na.last_seen_stamp_ns).then(na.id.cmp(&nb.id))
            };
            if max_nodes == 0 {
                selected.clear();
            } else {
                selected.select_nth_unstable_by(max_nodes - 1, recency);
                selected.truncate(max_nodes);
            }
            report.truncated = true;
        }
        // The runtime keeps its nodes sorted by id; sort only when they are not.
        if !selected.is_sorted_by_key(|&i| graph.nodes[i].id) {
            selected.sort_unstable_by_key(|&i| graph.nodes[i].id);
        }

        let max_published_id = selected.iter().map(|&i| graph.nodes[i].id).max();
        self.published.rebuild(
            selected.len(),
            max_published_id,
            selected.iter().map(|&i| (graph.nodes[i].id, i as u32)),
        );
        if report.truncated {
            let max_id = graph.nodes.iter().map(|n| n.id).max();
            self.all_ids.rebuild(graph.nodes.len(), max_id, graph.nodes.iter().map(|n| (n.id, 0)));
        }
        let (published, all_ids) = (&self.published, &self.all_ids);
        let exists = |id: u32| if report.truncated { all_ids.get(id).is_some() } else { published.get(id).is_some() };

        let edges = &mut self.edges;
        edges.clear();
        for (i, e) in graph.edges.iter().enumerate() {
            match (published.get(e.source_id), published.get(e.target_id)) {
                (Some(s), Some(t)) => edges.push((i as u32, s, t)),
                _ if !exists(e.source_id) || !exists(e.target_id) => report.dangling_edges += 1,
                _ => {} // endpoint left out for capacity
            }
        }
        if edges.len() > max_edges {
            let recency = |&(_, s, t): &(u32, u32, u32)| {
                graph.nodes[s as usize].last_seen_stamp_ns.min(graph.nodes[t as usize].last_seen_stamp_ns)
            };
            if max_edges == 0 {
                edges.clear();
            } else {
                edges.select_nth_unstable_by(max_edges - 1, |a, b| recency(b).cmp(&recency(a)).then(a.0.cmp(&b.0)));
                edges.truncate(max_edges);
                edges.sort_unstable_by_key(|&(i, _, _)| i);
            }
            report.truncated = true;
        }
        if edges.len() + report.dangling_edges < graph.edges.len() {
            report.truncated = true;
        }

        report.nodes_written = selected.len();
        report.edges_written = edges.len();
        report.payload_bytes = graph_payload_bytes(selected.len(), edges.len());
        self.payload_len = report.payload_bytes;
        self.header = GraphHeader {
            schema_version: SCHEMA_VERSION,
            node_count: selected.len() as u32,
            graph_version: graph.version,
            instance_id: self.instance_id,
            stamp_ns: graph.stamp_ns,
            publish_time_ns: 0,
            edge_count: edges.len() as u32,
            object_count: 0,
            part_count: 0,
            capacity_exceeded: u8::from(report.truncated),
            source_kind: self.origin.source_kind as u8,
            reserved: [0; 2],
            total_node_count: u32::try_from(graph.nodes.len()).unwrap_or(u32::MAX),
            total_edge_count: u32::try_from(graph.edges.len()).unwrap_or(u32::MAX),
            node_capacity: u32::try_from(max_nodes).unwrap_or(u32::MAX),
            edge_capacity: u32::try_from(max_edges).unwrap_or(u32::MAX),
            world_frame: self.origin.world_frame,
            reserved2: 0,
        };
        report
    }

    /// Writes the records of the graph [`Self::select`] chose into `out` (exactly
    /// `report.payload_bytes` long, every byte written: `out` may be a loaned sample's
    /// uninitialised bytes) and completes the header (object and part counts) and `report`
    /// (labels cut).
    ///
    /// # Panics
    /// When `out` is not `report.payload_bytes` long.
    pub fn write_payload<B: OutByte>(&mut self, graph: &SceneGraph, out: &mut [B], report: &mut PublishReport) {
        let counts = write_records(graph, &self.selected, &self.edges, &self.phrases, out);
        (self.header.object_count, self.header.part_count, report.labels_cut) = counts;
    }

    /// [`Self::select`] and [`Self::write_payload`] into the encoder's own buffer: the header and
    /// payload are then [`Self::header`] and [`Self::payload`].
    pub fn encode(&mut self, graph: &SceneGraph) -> PublishReport {
        let mut report = self.select(graph);
        let len = report.payload_bytes;
        // The buffer only grows; every byte of `payload[..len]` is written.
        if self.payload.len() < len {
            self.payload.resize(len, 0);
        }
        let counts = write_records(graph, &self.selected, &self.edges, &self.phrases, &mut self.payload[..len]);
        (self.header.object_count, self.header.part_count, report.labels_cut) = counts;
        report
    }
}

/// A byte of the buffer records are written into: an initialised `u8` (the encoder's own buffer)
/// or a `MaybeUninit<u8>` (a sample loaned without zero-filling it first).
pub trait OutByte: Sized {
    /// Copies `src` into `dst` (the same length).
    fn put(dst: &mut [Self], src: &[u8]);
}

impl OutByte for u8 {
    fn put(dst: &mut [u8], src: &[u8]) {
        dst.copy_from_slice(src);
    }
}

impl OutByte for MaybeUninit<u8> {
    fn put(dst: &mut [MaybeUninit<u8>], src: &[u8]) {
        assert_eq!(dst.len(), src.len(), "record length");
        for (d, &s) in dst.iter_mut().zip(src) {
            d.write(s);
        }
    }
}

/// Writes `wire` into the record `out`.
fn put_node<B: OutByte>(out: &mut [B; NODE_BYTES], wire: &WireNode) {
    #[cfg(target_endian = "little")]
    B::put(out, bytemuck::bytes_of(wire));
    #[cfg(not(target_endian = "little"))]
    {
        let mut bytes = [0u8; NODE_BYTES];
        wire.write_bytes(&mut bytes);
        B::put(out, &bytes);
    }
}

/// Writes `wire` into the record `out`.
fn put_edge<B: OutByte>(out: &mut [B; EDGE_BYTES], wire: &Edge) {
    #[cfg(target_endian = "little")]
    B::put(out, bytemuck::bytes_of(wire));
    #[cfg(not(target_endian = "little"))]
    {
        let mut bytes = [0u8; EDGE_BYTES];
        wire.write_bytes(&mut bytes);
        B::put(out, &bytes);
    }
}

/// Writes the chosen nodes, then edges, as records into `out`, every byte of it; returns the
/// object and part counts and the number of labels cut.
///
/// # Panics
/// When `out` is not exactly the records' length (the publisher relies on every byte of a loaned
/// sample being written).
fn write_records<B: OutByte>(
    graph: &SceneGraph,
    selected: &[usize],
    edges: &[(u32, u32, u32)],
    phrases: &[[u8; PHRASE_CAPACITY_BYTES]],
    out: &mut [B],
) -> (u32, u32, usize) {
    assert_eq!(out.len(), graph_payload_bytes(selected.len(), edges.len()), "graph payload length");
    let split = selected.len() * NODE_BYTES;
    let (node_bytes, edge_bytes) = out.split_at_mut(split);
    let (mut object_count, mut part_count, mut labels_cut) = (0u32, 0u32, 0usize);
    for (record, &i) in node_bytes.as_chunks_mut::<NODE_BYTES>().0.iter_mut().zip(selected) {
        let node = &graph.nodes[i];
        match node.kind {
            NodeKind::Object => object_count += 1,
            NodeKind::Part => part_count += 1,
        }
        let mut wire = WireNode {
            id: node.id,
            parent_id: node.parent_id.unwrap_or(NO_NODE),
            kind: node.kind as u8,
            reserved: 0,
            affordance_knowledge_bits: node.affordance_knowledge_bits & node.affordance_bits,
            observation_count: node.observation_count,
            confidence: node.confidence,
            centre_m: node.centre_m,
            box_min_m: node.box_min_m,
            box_max_m: node.box_max_m,
            affordance_bits: node.affordance_bits,
            affordance_llm_bits: node.affordance_llm_bits & node.affordance_bits,
            obb_yaw_rad: node.obb.yaw_rad,
            last_seen_stamp_ns: node.last_seen_stamp_ns,
            obb_centre_m: node.obb.centre_m,
            obb_size_m: node.obb.size_m,
            ..WireNode::default()
        };
        if !op3dsg_ipc_types::write_fixed_str(&mut wire.label, &node.label) {
            labels_cut += 1;
        }
        put_node(record, &wire);
    }
    for (record, &(i, _, _)) in edge_bytes.as_chunks_mut::<EDGE_BYTES>().0.iter_mut().zip(edges) {
        let edge = &graph.edges[i as usize];
        let phrase = phrases.get(usize::from(edge.relation_id)).copied().unwrap_or_else(|| {
            let mut phrase = [0u8; PHRASE_CAPACITY_BYTES];
            op3dsg_ipc_types::write_fixed_str(&mut phrase, relation_phrase(edge.relation_id).unwrap_or(""));
            phrase
        });
        let wire = Edge {
            source_id: edge.source_id,
            target_id: edge.target_id,
            kind: edge.kind as u8,
            origin: edge.origin as u8,
            relation_id: edge.relation_id,
            confidence: edge.confidence,
            phrase,
        };
        put_edge(record, &wire);
    }
    (object_count, part_count, labels_cut)
}

/// Relation ids up to this one get a prepared phrase (the canonical ones are below 128).
const RELATION_ID_TABLE_MAX: u16 = 127;

/// Reads a received graph back into a [`SceneGraph`], checking it against the wire contract
/// first ([`check_message`]: schema version, counts, payload length, every kind and origin
/// value).
pub fn message_to_scene_graph(message: &GraphMessage<'_>) -> Result<SceneGraph, SnapshotError> {
    check_message(message)?;
    let header = message.header;
    Ok(SceneGraph {
        version: header.graph_version,
        stamp_ns: header.stamp_ns,
        nodes: message.nodes().map(|n| node_from_wire(&n)).collect(),
        edges: message.edges().map(|e| edge_from_wire(&e)).collect(),
    })
}

/// The client library's owned [`Graph`] (what [`op3dsg_ipc_types::GraphSubscriber`] returns) as
/// a [`SceneGraph`], for tools and tests that need the runtime's form (`op3dsg dump --json`
/// writes its [`SceneGraph::to_json`]). The graph was checked when it was copied, so this cannot
/// fail.
pub fn graph_to_scene_graph(graph: &Graph) -> SceneGraph {
    SceneGraph {
        version: graph.version(),
        stamp_ns: graph.stamp_ns(),
        nodes: graph.wire_nodes().iter().map(node_from_wire).collect(),
        edges: graph.wire_edges().iter().map(edge_from_wire).collect(),
    }
}

/// A node of a checked graph sample (its kind is known).
fn node_from_wire(n: &WireNode) -> GraphNode {
    GraphNode {
        id: n.id,
        kind: NodeKind::from_u8(n.kind).unwrap_or_default(),
        parent_id: (n.parent_id != NO_NODE).then_some(n.parent_id),
        label: n.label_str().to_owned(),
        confidence: n.confidence,
        centre_m: n.centre_m,
        box_min_m: n.box_min_m,
        box_max_m: n.box_max_m,
        obb: OrientedBox { centre_m: n.obb_centre_m, size_m: n.obb_size_m, yaw_rad: n.obb_yaw_rad },
        observation_count: n.observation_count,
        affordance_bits: n.affordance_bits,
        affordance_knowledge_bits: n.affordance_knowledge_bits & n.affordance_bits,
        affordance_llm_bits: n.affordance_llm_bits & n.affordance_bits,
        last_seen_stamp_ns: n.last_seen_stamp_ns,
        first_seen_stamp_ns: 0,
        missing: false,
    }
}

/// An edge of a checked graph sample (its kind and origin are known).
fn edge_from_wire(e: &Edge) -> GraphEdge {
    GraphEdge {
        source_id: e.source_id,
        target_id: e.target_id,
        kind: EdgeKind::from_u8(e.kind).unwrap_or_default(),
        relation_id: e.relation_id,
        confidence: e.confidence,
        origin: EdgeOrigin::from_u8(e.origin).unwrap_or_default(),
    }
}

#[cfg(test)]
mod tests;
