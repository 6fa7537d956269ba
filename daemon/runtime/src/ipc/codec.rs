//! The graph codec: the runtime's [`SceneGraph`] encoded into a wire graph sample (a
//! [`GraphHeader`] and the byte payload of node and edge records, [`GraphEncoder`], capacity rules
//! included), and read back from a received sample or from the client library's owned [`Graph`]
//! ([`message_to_scene_graph`], [`graph_to_scene_graph`]).

use op3dsg_ipc_types::{
    EDGE_BYTES, Edge, EdgeKind, EdgeOrigin, Graph, GraphHeader, GraphMessage, MAX_EDGES, MAX_NODES, NO_NODE,
    NODE_BYTES, Node as WireNode, NodeKind, PHRASE_CAPACITY_BYTES, SCHEMA_VERSION, SnapshotError, check_message,
    graph_payload_bytes, relation_phrase,
};
use rustc_hash::FxHashMap;

use crate::graph::{GraphEdge, GraphNode, SceneGraph};
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
            reserved: [0; 3],
            total_node_count: u32::try_from(graph.nodes.len()).unwrap_or(u32::MAX),
            total_edge_count: u32::try_from(graph.edges.len()).unwrap_or(u32::MAX),
            node_capacity: u32::try_from(max_nodes).unwrap_or(u32::MAX),
            edge_capacity: u32::try_from(max_edges).unwrap_or(u32::MAX),
            reserved2: 0,
        };
        report
    }

    /// Writes the records of the graph [`Self::select`] chose into `out` (exactly
    /// `report.payload_bytes` long, every byte written) and completes the header (object and part
    /// counts) and `report` (labels cut).
    pub fn write_payload(&mut self, graph: &SceneGraph, out: &mut [u8], report: &mut PublishReport) {
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

/// Writes the chosen nodes, then edges, as records into `out`; returns the object and part
/// counts and the number of labels cut.
fn write_records(
    graph: &SceneGraph,
    selected: &[usize],
    edges: &[(u32, u32, u32)],
    phrases: &[[u8; PHRASE_CAPACITY_BYTES]],
    out: &mut [u8],
) -> (u32, u32, usize) {
    debug_assert_eq!(out.len(), graph_payload_bytes(selected.len(), edges.len()));
    let split = (selected.len() * NODE_BYTES).min(out.len());
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
        wire.write_bytes(record);
    }
    for (record, &(i, _, _)) in edge_bytes.as_chunks_mut::<EDGE_BYTES>().0.iter_mut().zip(edges) {
        let edge = &graph.edges[i as usize];
        let phrase = phrases.get(usize::from(edge.relation_id)).copied().unwrap_or_else(|| {
            let mut phrase = [0u8; PHRASE_CAPACITY_BYTES];
            op3dsg_ipc_types::write_fixed_str(&mut phrase, relation_phrase(edge.relation_id).unwrap_or(""));
            phrase
        });
        Edge {
            source_id: edge.source_id,
            target_id: edge.target_id,
            kind: edge.kind as u8,
            origin: edge.origin as u8,
            relation_id: edge.relation_id,
            confidence: edge.confidence,
            phrase,
        }
        .write_bytes(record);
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
mod tests {
    use super::*;

    fn node(id: u32, kind: NodeKind, last_seen: u64) -> GraphNode {
        GraphNode {
            id,
            kind,
            parent_id: None,
            label: format!("n{id}"),
            confidence: 0.5,
            centre_m: [id as f32, 0.0, 0.0],
            box_min_m: [0.0; 3],
            box_max_m: [1.0; 3],
            obb: Default::default(),
            observation_count: 3,
            affordance_bits: 0,
            last_seen_stamp_ns: last_seen,
            ..Default::default()
        }
    }

    fn edge(s: u32, t: u32) -> GraphEdge {
        GraphEdge {
            source_id: s,
            target_id: t,
            kind: EdgeKind::Spatial,
            relation_id: 5,
            confidence: 0.9,
            origin: EdgeOrigin::Geometry,
        }
    }

    fn encoder() -> GraphEncoder {
        GraphEncoder::new(GraphCapacity::default(), 0x1234)
    }

    fn node_ids(encoder: &GraphEncoder) -> Vec<u32> {
        encoder.message().nodes().map(|n| n.id).collect()
    }

    #[test]
    fn round_trip_small_graph() {
        let mut encoder = encoder();
        let mut part = node(7, NodeKind::Part, 20);
        part.parent_id = Some(3);
        part.affordance_bits = 0b1000;
        part.add_affordances(0b0011, EdgeOrigin::Knowledge);
        part.add_affordances(0b0110, EdgeOrigin::Llm);
        let graph = SceneGraph {
            version: 42,
            stamp_ns: 99,
            nodes: vec![part, node(3, NodeKind::Object, 10)],
            edges: vec![edge(7, 3)],
        };
        let report = encoder.encode(&graph);
        assert!(!report.truncated);
        assert_eq!((report.nodes_written, report.edges_written), (2, 1));
        assert_eq!(report.payload_bytes, 2 * 144 + 64, "the sample holds what the graph holds");
        let header = encoder.header();
        assert_eq!(header.capacity_exceeded, 0);
        assert_eq!((header.object_count, header.part_count), (1, 1));
        assert_eq!((header.instance_id, header.node_capacity, header.edge_capacity), (0x1234, 16_384, 32_768));
        assert_eq!(encoder.message().edges().next().map(|e| e.phrase_str().to_owned()).as_deref(), Some("next to"));
        let back = message_to_scene_graph(&encoder.message()).expect("valid");
        // Sorted by id on the wire.
        assert_eq!(back.nodes.iter().map(|n| n.id).collect::<Vec<_>>(), [3, 7]);
        let mut expected = graph.clone();
        expected.nodes.sort_by_key(|n| n.id);
        assert_eq!(back, expected);
        // Each affordance's origin on the wire: bit 0 knowledge, 1 both, 2 llm, 3 geometry.
        let wire = encoder.message().nodes().find(|n| n.id == 7).expect("the part");
        assert_eq!(
            (wire.affordance_bits, wire.affordance_knowledge_bits, wire.affordance_llm_bits),
            (0b1111, 0b0011, 0b0110)
        );
        let origins: Vec<_> = (0..4).map(|i| wire.affordance_origin(i)).collect();
        assert_eq!(
            origins,
            [EdgeOrigin::Knowledge, EdgeOrigin::KnowledgeAndLlm, EdgeOrigin::Llm, EdgeOrigin::Geometry].map(Some)
        );
        assert_eq!(
            back.to_json("test").node(7).map(|n| n.affordance_origins.clone()),
            Some(
                [
                    ("rotate", "knowledge"),
                    ("key_press", "knowledge+llm"),
                    ("tip_push", "llm"),
                    ("hook_pull", "geometry")
                ]
                .into_iter()
                .map(|(a, o)| (a.to_owned(), o.to_owned()))
                .collect()
            )
        );
    }

    #[test]
    fn truncation_keeps_most_recent_nodes_and_prunes_edges() {
        let mut encoder = encoder();
        let extra = 10;
        let total = MAX_NODES + extra;
        // Node id i seen at stamp i, except the ten lowest ids are the most recent.
        let mut nodes: Vec<GraphNode> =
            (0..total as u32).map(|i| node(i, NodeKind::Object, if i < 10 { 1_000_000 } else { i as u64 })).collect();
        nodes.reverse(); // input order must not matter
        let edges = vec![edge(0, 1), edge(10, 11), edge(total as u32 - 1, 0), edge(5, 9999999)];
        let graph = SceneGraph { version: 1, stamp_ns: 1, nodes, edges };
        let report = encoder.encode(&graph);
        assert!(report.truncated);
        assert_eq!(report.nodes_written, MAX_NODES);
        assert_eq!(report.total_nodes, total);
        let header = *encoder.header();
        assert_eq!(header.capacity_exceeded, 1);
        assert_eq!(header.total_node_count as usize, total);
        assert_eq!(header.total_edge_count, 4);
        // Dropped: ids 10..10+extra (the oldest stamps).
        let ids = node_ids(&encoder);
        assert!(ids.windows(2).all(|w| w[0] < w[1]), "sorted by id");
        assert!(ids.contains(&0) && ids.contains(&9) && !ids.contains(&10) && !ids.contains(&19));
        assert!(ids.contains(&20));
        // Kept: 0-1 and last-0; pruned: 10-11 (endpoints dropped); dangling: 5-9999999.
        assert_eq!(report.edges_written, 2);
        assert_eq!(report.dangling_edges, 1);
        let kept: Vec<(u32, u32)> = encoder.message().edges().map(|e| (e.source_id, e.target_id)).collect();
        assert_eq!(kept, [(0, 1), (total as u32 - 1, 0)]);
        assert!(check_message(&encoder.message()).is_ok());
    }

    #[test]
    fn a_small_profile_capacity_truncates_and_sets_the_flag() {
        let mut encoder = GraphEncoder::new(GraphCapacity { max_nodes: 3, max_edges: 2 }, 9);
        let nodes: Vec<GraphNode> = (0..5).map(|i| node(i, NodeKind::Object, u64::from(i))).collect();
        let edges = vec![edge(4, 3), edge(3, 2), edge(2, 4), edge(0, 1)];
        let graph = SceneGraph { version: 2, stamp_ns: 0, nodes, edges };
        let report = encoder.encode(&graph);
        assert!(report.truncated);
        assert_eq!(node_ids(&encoder), [2, 3, 4], "the three most recently seen");
        assert_eq!((report.edges_written, report.payload_bytes), (2, 3 * 144 + 2 * 64));
        let header = *encoder.header();
        assert_eq!((header.capacity_exceeded, header.node_capacity, header.edge_capacity), (1, 3, 2));
        assert_eq!((header.total_node_count, header.total_edge_count), (5, 4));
        let graph = Graph::from_message(&encoder.message()).expect("valid");
        assert!(graph.capacity_exceeded());
    }

    #[test]
    fn writing_into_a_loaned_buffer_matches_the_own_buffer() {
        let mut part = node(7, NodeKind::Part, 20);
        part.label = "x".repeat(60);
        let graph = SceneGraph {
            version: 3,
            stamp_ns: 1,
            nodes: vec![node(3, NodeKind::Object, 10), part],
            edges: vec![edge(7, 3)],
        };
        let mut own = encoder();
        let own_report = own.encode(&graph);
        let mut split = encoder();
        let mut report = split.select(&graph);
        let mut loaned = vec![0xAAu8; report.payload_bytes];
        split.write_payload(&graph, &mut loaned, &mut report);
        assert_eq!(report, own_report);
        assert_eq!((loaned.as_slice(), split.header()), (own.payload(), own.header()));
        assert_eq!((split.header().object_count, split.header().part_count, report.labels_cut), (1, 1, 1));
    }

    #[test]
    fn sparse_ids_encode_like_dense_ones() {
        let mut encoder = encoder();
        let ids = [3u32, 5_000_000, 4_000_000_000];
        let nodes: Vec<GraphNode> = ids.iter().map(|&id| node(id, NodeKind::Object, 1)).collect();
        let edges = vec![edge(3, 5_000_000), edge(4_000_000_000, 3), edge(3, 77)];
        let graph = SceneGraph { version: 1, stamp_ns: 0, nodes, edges };
        let report = encoder.encode(&graph);
        assert_eq!((report.edges_written, report.dangling_edges, report.truncated), (2, 1, false));
        assert_eq!(node_ids(&encoder), ids);
        let client = Graph::from_message(&encoder.message()).expect("valid");
        assert_eq!(client.node(4_000_000_000).map(|n| n.edges_from().count()), Some(1));
        assert_eq!(client.edges_to(3).map(|e| e.source_id()).collect::<Vec<_>>(), [4_000_000_000]);
        // A dense graph after a sparse one reuses the encoder.
        let dense = SceneGraph { version: 2, stamp_ns: 0, nodes: vec![node(0, NodeKind::Object, 1)], edges: vec![] };
        assert_eq!(encoder.encode(&dense).payload_bytes, 144);
        assert_eq!(node_ids(&encoder), [0]);
    }

    #[test]
    fn ties_at_the_cut_prefer_lower_ids() {
        let mut encoder = encoder();
        let nodes: Vec<GraphNode> = (0..MAX_NODES as u32 + 2).map(|i| node(i, NodeKind::Part, 5)).collect();
        let graph = SceneGraph { version: 1, stamp_ns: 1, nodes, edges: vec![] };
        let report = encoder.encode(&graph);
        assert!(report.truncated);
        assert_eq!(node_ids(&encoder).last().copied(), Some(MAX_NODES as u32 - 1));
        assert_eq!(encoder.header().part_count as usize, MAX_NODES);
    }

    #[test]
    fn too_many_edges_sets_capacity_flag() {
        let mut encoder = encoder();
        let nodes = vec![node(1, NodeKind::Object, 1), node(2, NodeKind::Object, 2)];
        let edges: Vec<GraphEdge> = (0..MAX_EDGES + 3).map(|_| edge(1, 2)).collect();
        let graph = SceneGraph { version: 3, stamp_ns: 0, nodes, edges };
        let report = encoder.encode(&graph);
        assert!(report.truncated);
        assert_eq!(report.edges_written, MAX_EDGES);
        let header = encoder.header();
        assert_eq!(header.edge_count as usize, MAX_EDGES);
        assert_eq!(header.total_edge_count as usize, MAX_EDGES + 3);
        assert_eq!(header.capacity_exceeded, 1);
    }

    #[test]
    fn long_labels_are_cut_at_a_char_boundary() {
        let mut encoder = encoder();
        let mut n = node(1, NodeKind::Object, 1);
        n.label = "ä".repeat(30); // 60 bytes; 48 bytes = 24 chars
        let graph = SceneGraph { version: 1, stamp_ns: 0, nodes: vec![n], edges: vec![] };
        let report = encoder.encode(&graph);
        assert_eq!(report.labels_cut, 1);
        assert_eq!(encoder.message().nodes().next().map(|n| n.label_str().to_owned()), Some("ä".repeat(24)));
    }

    #[test]
    fn unknown_kinds_name_the_entry() {
        let mut encoder = encoder();
        let graph = SceneGraph {
            version: 1,
            stamp_ns: 0,
            nodes: vec![node(1, NodeKind::Object, 1), node(2, NodeKind::Part, 1)],
            edges: vec![edge(1, 2)],
        };
        encoder.encode(&graph);
        let mut header = *encoder.header();
        let mut payload = encoder.payload().to_vec();
        payload[144 + 8] = 9; // the kind of node 1
        assert_eq!(
            message_to_scene_graph(&GraphMessage::new(&header, &payload)),
            Err(SnapshotError::UnknownNodeKind { index: 1, value: 9 })
        );
        payload[144 + 8] = 1;
        payload[2 * 144 + 9] = 7; // the origin of edge 0
        let err = message_to_scene_graph(&GraphMessage::new(&header, &payload)).expect_err("bad origin");
        assert_eq!(err.to_string(), "edges[0].origin: unknown value 7 (0..=3)");
        let other = op3dsg_ipc_types::SCHEMA_VERSION + 1;
        header.schema_version = other;
        assert!(matches!(
            message_to_scene_graph(&GraphMessage::new(&header, &payload)),
            Err(SnapshotError::SchemaVersion { found, .. }) if found == other
        ));
    }

    #[test]
    fn client_graph_converts_back_to_the_scene_graph() {
        let mut encoder = encoder();
        let mut part = node(7, NodeKind::Part, 20);
        part.parent_id = Some(3);
        let graph = SceneGraph {
            version: 5,
            stamp_ns: 77,
            nodes: vec![part, node(3, NodeKind::Object, 10)],
            edges: vec![edge(7, 3), GraphEdge { kind: EdgeKind::Functional, origin: EdgeOrigin::Llm, ..edge(3, 7) }],
        };
        encoder.encode(&graph);
        let client_graph = Graph::from_message(&encoder.message()).expect("valid message");
        assert_eq!(client_graph.instance_id(), 0x1234);
        let mut expected = graph;
        expected.nodes.sort_by_key(|n| n.id);
        assert_eq!(graph_to_scene_graph(&client_graph), expected);
        assert_eq!(message_to_scene_graph(&encoder.message()).expect("valid"), expected);
    }
}
