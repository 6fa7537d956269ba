//! The graph codec: the runtime's [`SceneGraph`] encoded into a wire graph sample (a
//! [`GraphHeader`] and the byte payload of node and edge records, [`GraphEncoder`], capacity rules
//! included), and read back from a received sample or from the client library's owned [`Graph`]
//! ([`message_to_scene_graph`], [`graph_to_scene_graph`]).

use op3dsg_ipc_types::{
    Edge, EdgeKind, EdgeOrigin, Graph, GraphHeader, GraphMessage, MAX_EDGES, MAX_NODES, NO_NODE, Node as WireNode,
    NodeKind, SCHEMA_VERSION, SnapshotError, check_message, graph_payload_bytes,
};
use rustc_hash::{FxHashMap, FxHashSet};

use crate::graph::{GraphEdge, GraphNode, SceneGraph};
#[cfg(doc)]
use crate::ipc::GraphServer;

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

/// Encodes [`SceneGraph`]s into the wire form, keeping every buffer between calls: once a graph
/// of a given size has been encoded, encoding another of at most that size allocates nothing.
#[derive(Debug, Default)]
pub struct GraphEncoder {
    capacity: GraphCapacity,
    instance_id: u64,
    header: GraphHeader,
    payload: Vec<u8>,
    /// Indices into `graph.nodes` of the published nodes.
    selected: Vec<usize>,
    /// `(index into graph.edges, recency)` of the published edges.
    edges: Vec<(usize, u64)>,
    /// id -> last_seen of the published nodes, for edge filtering.
    published: FxHashMap<u32, u64>,
    /// Every node id, when nodes were left out (to tell capacity from dangling edges).
    all_ids: FxHashSet<u32>,
}

impl GraphEncoder {
    /// An encoder for samples of at most `capacity`, stamping `instance_id` into every header.
    pub fn new(capacity: GraphCapacity, instance_id: u64) -> Self {
        Self { capacity, instance_id, ..Self::default() }
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
        &self.payload
    }

    /// The last encoded graph as a subscriber receives it.
    pub fn message(&self) -> GraphMessage<'_> {
        GraphMessage::new(&self.header, &self.payload)
    }

    /// Encodes `graph` (header, nodes sorted by id, edges). Pure: no shared memory.
    ///
    /// Beyond `max_nodes` it keeps the most recently seen nodes (highest `last_seen_stamp_ns`,
    /// on ties the lower id) and only the edges between kept nodes; beyond `max_edges` it keeps
    /// the edges whose older endpoint was seen most recently (on ties the earlier edge). Either
    /// sets `capacity_exceeded`. `total_*` are always the graph's real counts. `publish_time_ns`
    /// is set to 0; the publisher stamps it.
    pub fn encode(&mut self, graph: &SceneGraph) -> PublishReport {
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

        let published = &mut self.published;
        published.clear();
        published.extend(selected.iter().map(|&i| (graph.nodes[i].id, graph.nodes[i].last_seen_stamp_ns)));
        let all_ids = &mut self.all_ids;
        all_ids.clear();
        if report.truncated {
            all_ids.extend(graph.nodes.iter().map(|n| n.id));
        }
        let exists = |id: u32| if report.truncated { all_ids.contains(&id) } else { published.contains_key(&id) };

        let edges = &mut self.edges;
        edges.clear();
        for (i, e) in graph.edges.iter().enumerate() {
            match (published.get(&e.source_id), published.get(&e.target_id)) {
                (Some(s), Some(t)) => edges.push((i, (*s).min(*t))),
                _ if !exists(e.source_id) || !exists(e.target_id) => report.dangling_edges += 1,
                _ => {} // endpoint left out for capacity
            }
        }
        if edges.len() > max_edges {
            if max_edges == 0 {
                edges.clear();
            } else {
                edges.select_nth_unstable_by(max_edges - 1, |a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
                edges.truncate(max_edges);
                edges.sort_unstable_by_key(|&(i, _)| i);
            }
            report.truncated = true;
        }
        if edges.len() + report.dangling_edges < graph.edges.len() {
            report.truncated = true;
        }

        let payload = &mut self.payload;
        payload.clear();
        payload.reserve(graph_payload_bytes(selected.len(), edges.len()));
        let mut object_count = 0u32;
        let mut part_count = 0u32;
        for &i in selected.iter() {
            let node = &graph.nodes[i];
            match node.kind {
                NodeKind::Object => object_count += 1,
                NodeKind::Part => part_count += 1,
            }
            let mut wire = WireNode {
                id: node.id,
                parent_id: node.parent_id.unwrap_or(NO_NODE),
                kind: node.kind as u8,
                reserved: [0; 3],
                observation_count: node.observation_count,
                confidence: node.confidence,
                centre_m: node.centre_m,
                box_min_m: node.box_min_m,
                box_max_m: node.box_max_m,
                affordance_bits: node.affordance_bits,
                reserved2: [0; 6],
                last_seen_stamp_ns: node.last_seen_stamp_ns,
                ..WireNode::default()
            };
            if !op3dsg_ipc_types::write_fixed_str(&mut wire.label, &node.label) {
                report.labels_cut += 1;
            }
            wire.append_bytes(payload);
        }
        for &(i, _) in edges.iter() {
            let mut wire = Edge::default();
            write_edge(&mut wire, &graph.edges[i]);
            wire.append_bytes(payload);
        }

        report.nodes_written = selected.len();
        report.edges_written = edges.len();
        report.payload_bytes = payload.len();
        self.header = GraphHeader {
            schema_version: SCHEMA_VERSION,
            node_count: selected.len() as u32,
            graph_version: graph.version,
            instance_id: self.instance_id,
            stamp_ns: graph.stamp_ns,
            publish_time_ns: 0,
            edge_count: edges.len() as u32,
            object_count,
            part_count,
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
}

fn write_edge(slot: &mut Edge, edge: &GraphEdge) {
    slot.source_id = edge.source_id;
    slot.target_id = edge.target_id;
    slot.kind = edge.kind as u8;
    slot.origin = edge.origin as u8;
    slot.relation_id = edge.relation_id;
    slot.confidence = edge.confidence;
    op3dsg_ipc_types::write_fixed_str(
        &mut slot.phrase,
        op3dsg_ipc_types::relation_phrase(edge.relation_id).unwrap_or(""),
    );
}

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

/// A node of a checked snapshot (its kind is known).
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
        observation_count: n.observation_count,
        affordance_bits: n.affordance_bits,
        last_seen_stamp_ns: n.last_seen_stamp_ns,
    }
}

/// An edge of a checked snapshot (its kind and origin are known).
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
            observation_count: 3,
            affordance_bits: 0,
            last_seen_stamp_ns: last_seen,
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
        let graph = SceneGraph {
            version: 42,
            stamp_ns: 99,
            nodes: vec![part, node(3, NodeKind::Object, 10)],
            edges: vec![edge(7, 3)],
        };
        let report = encoder.encode(&graph);
        assert!(!report.truncated);
        assert_eq!((report.nodes_written, report.edges_written), (2, 1));
        assert_eq!(report.payload_bytes, 2 * 120 + 64, "the sample holds what the graph holds");
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
        assert_eq!((report.edges_written, report.payload_bytes), (2, 3 * 120 + 2 * 64));
        let header = *encoder.header();
        assert_eq!((header.capacity_exceeded, header.node_capacity, header.edge_capacity), (1, 3, 2));
        assert_eq!((header.total_node_count, header.total_edge_count), (5, 4));
        let graph = Graph::from_message(&encoder.message()).expect("valid");
        assert!(graph.capacity_exceeded());
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
        payload[120 + 8] = 9; // the kind of node 1
        assert_eq!(
            message_to_scene_graph(&GraphMessage::new(&header, &payload)),
            Err(SnapshotError::UnknownNodeKind { index: 1, value: 9 })
        );
        payload[120 + 8] = 1;
        payload[2 * 120 + 9] = 7; // the origin of edge 0
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
