//! The graph codec: the runtime's [`SceneGraph`] written into a wire [`GraphSnapshot`]
//! ([`fill_snapshot`], capacity rules included), and read back from a snapshot or from the
//! client library's owned [`Graph`] ([`snapshot_to_scene_graph`], [`graph_to_scene_graph`]).

use op3dsg_ipc_types::client::check_snapshot;
use op3dsg_ipc_types::{
    Edge, EdgeKind, EdgeOrigin, Graph, GraphSnapshot, MAX_EDGES, MAX_NODES, NO_NODE, Node as WireNode, NodeKind,
    SCHEMA_VERSION, SnapshotError,
};

use crate::graph::{GraphEdge, GraphNode, SceneGraph};
#[cfg(doc)]
use crate::ipc::GraphServer;

/// What one [`fill_snapshot`] / [`GraphServer::publish_graph`] wrote.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PublishReport {
    /// Graph version written.
    pub version: u64,
    /// Nodes written into the snapshot.
    pub nodes_written: usize,
    /// Edges written into the snapshot.
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
}

/// Writes `graph` into `snapshot` (header, nodes sorted by id, edges). Pure: no shared memory.
///
/// Beyond [`MAX_NODES`] it keeps the most recently seen nodes (highest `last_seen_stamp_ns`, on
/// ties the lower id) and only the edges between kept nodes; beyond [`MAX_EDGES`] it keeps the
/// edges whose older endpoint was seen most recently (on ties the earlier edge). Either sets
/// `capacity_exceeded`. `total_*` are always the graph's real counts. `publish_time_ns` is set to 0;
/// the publisher stamps it.
pub fn fill_snapshot(graph: &SceneGraph, snapshot: &mut GraphSnapshot) -> PublishReport {
    let mut report = PublishReport {
        version: graph.version,
        total_nodes: graph.nodes.len(),
        total_edges: graph.edges.len(),
        ..PublishReport::default()
    };

    // Node selection: indices into graph.nodes.
    let mut selected: Vec<usize> = (0..graph.nodes.len()).collect();
    if selected.len() > MAX_NODES {
        let recency = |&a: &usize, &b: &usize| {
            let (na, nb) = (&graph.nodes[a], &graph.nodes[b]);
            nb.last_seen_stamp_ns.cmp(&na.last_seen_stamp_ns).then(na.id.cmp(&nb.id))
        };
        selected.select_nth_unstable_by(MAX_NODES - 1, recency);
        selected.truncate(MAX_NODES);
        report.truncated = true;
    }
    selected.sort_by_key(|&i| graph.nodes[i].id);

    // id -> last_seen of published nodes, for edge filtering.
    let published: std::collections::HashMap<u32, u64> =
        selected.iter().map(|&i| (graph.nodes[i].id, graph.nodes[i].last_seen_stamp_ns)).collect();
    let all_ids: std::collections::HashSet<u32> =
        if report.truncated { graph.nodes.iter().map(|n| n.id).collect() } else { std::collections::HashSet::new() };
    let exists = |id: u32| if report.truncated { all_ids.contains(&id) } else { published.contains_key(&id) };

    let mut edges: Vec<(usize, u64)> = Vec::with_capacity(graph.edges.len().min(MAX_EDGES));
    for (i, e) in graph.edges.iter().enumerate() {
        match (published.get(&e.source_id), published.get(&e.target_id)) {
            (Some(s), Some(t)) => edges.push((i, (*s).min(*t))),
            _ if !exists(e.source_id) || !exists(e.target_id) => report.dangling_edges += 1,
            _ => {} // endpoint left out for capacity
        }
    }
    if edges.len() > MAX_EDGES {
        edges.select_nth_unstable_by(MAX_EDGES - 1, |a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        edges.truncate(MAX_EDGES);
        edges.sort_by_key(|&(i, _)| i);
        report.truncated = true;
    }
    if edges.len() + report.dangling_edges < graph.edges.len() {
        report.truncated = true;
    }

    let mut object_count = 0u32;
    let mut part_count = 0u32;
    for (slot, &i) in snapshot.nodes.iter_mut().zip(selected.iter()) {
        let node = &graph.nodes[i];
        match node.kind {
            NodeKind::Object => object_count += 1,
            NodeKind::Part => part_count += 1,
        }
        slot.id = node.id;
        slot.parent_id = node.parent_id.unwrap_or(NO_NODE);
        slot.kind = node.kind as u8;
        slot.reserved = [0; 3];
        slot.observation_count = node.observation_count;
        if !op3dsg_ipc_types::write_fixed_str(&mut slot.label, &node.label) {
            report.labels_cut += 1;
        }
        slot.confidence = node.confidence;
        slot.centre_m = node.centre_m;
        slot.box_min_m = node.box_min_m;
        slot.box_max_m = node.box_max_m;
        slot.affordance_bits = node.affordance_bits;
        slot.reserved2 = [0; 6];
        slot.last_seen_stamp_ns = node.last_seen_stamp_ns;
    }
    for (slot, &(i, _)) in snapshot.edges.iter_mut().zip(edges.iter()) {
        write_edge(slot, &graph.edges[i]);
    }

    report.nodes_written = selected.len();
    report.edges_written = edges.len();
    let header = &mut snapshot.header;
    header.schema_version = SCHEMA_VERSION;
    header.node_count = selected.len() as u32;
    header.graph_version = graph.version;
    header.stamp_ns = graph.stamp_ns;
    header.publish_time_ns = 0;
    header.edge_count = edges.len() as u32;
    header.object_count = object_count;
    header.part_count = part_count;
    header.capacity_exceeded = u8::from(report.truncated);
    header.reserved = [0; 3];
    header.total_node_count = u32::try_from(graph.nodes.len()).unwrap_or(u32::MAX);
    header.total_edge_count = u32::try_from(graph.edges.len()).unwrap_or(u32::MAX);
    report
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

/// Reads a snapshot back into a [`SceneGraph`], checking it against the wire contract first
/// ([`check_snapshot`]: schema version, counts, every kind and origin value).
pub fn snapshot_to_scene_graph(snapshot: &GraphSnapshot) -> Result<SceneGraph, SnapshotError> {
    check_snapshot(snapshot)?;
    let header = &snapshot.header;
    Ok(SceneGraph {
        version: header.graph_version,
        stamp_ns: header.stamp_ns,
        nodes: snapshot.valid_nodes().iter().map(node_from_wire).collect(),
        edges: snapshot.valid_edges().iter().map(edge_from_wire).collect(),
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
    use op3dsg_ipc_types::publish::boxed_snapshot;

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

    #[test]
    fn round_trip_small_graph() {
        let mut snap = boxed_snapshot();
        let mut part = node(7, NodeKind::Part, 20);
        part.parent_id = Some(3);
        part.affordance_bits = 0b1000;
        let graph = SceneGraph {
            version: 42,
            stamp_ns: 99,
            nodes: vec![part, node(3, NodeKind::Object, 10)],
            edges: vec![edge(7, 3)],
        };
        let report = fill_snapshot(&graph, &mut snap);
        assert!(!report.truncated);
        assert_eq!((report.nodes_written, report.edges_written), (2, 1));
        assert_eq!(snap.header.capacity_exceeded, 0);
        assert_eq!((snap.header.object_count, snap.header.part_count), (1, 1));
        assert_eq!(snap.edges[0].phrase_str(), "next to");
        let back = snapshot_to_scene_graph(&snap).expect("valid");
        // Sorted by id on the wire.
        assert_eq!(back.nodes.iter().map(|n| n.id).collect::<Vec<_>>(), [3, 7]);
        let mut expected = graph.clone();
        expected.nodes.sort_by_key(|n| n.id);
        assert_eq!(back, expected);
    }

    #[test]
    fn truncation_keeps_most_recent_nodes_and_prunes_edges() {
        let mut snap = boxed_snapshot();
        let extra = 10;
        let total = MAX_NODES + extra;
        // Node id i seen at stamp i, except the ten lowest ids are the most recent.
        let mut nodes: Vec<GraphNode> =
            (0..total as u32).map(|i| node(i, NodeKind::Object, if i < 10 { 1_000_000 } else { i as u64 })).collect();
        nodes.reverse(); // input order must not matter
        let edges = vec![edge(0, 1), edge(10, 11), edge(total as u32 - 1, 0), edge(5, 9999999)];
        let graph = SceneGraph { version: 1, stamp_ns: 1, nodes, edges };
        let report = fill_snapshot(&graph, &mut snap);
        assert!(report.truncated);
        assert_eq!(report.nodes_written, MAX_NODES);
        assert_eq!(report.total_nodes, total);
        assert_eq!(snap.header.capacity_exceeded, 1);
        assert_eq!(snap.header.total_node_count as usize, total);
        assert_eq!(snap.header.total_edge_count, 4);
        // Dropped: ids 10..10+extra (the oldest stamps).
        let ids: Vec<u32> = snap.valid_nodes().iter().map(|n| n.id).collect();
        assert!(ids.windows(2).all(|w| w[0] < w[1]), "sorted by id");
        assert!(ids.contains(&0) && ids.contains(&9) && !ids.contains(&10) && !ids.contains(&19));
        assert!(ids.contains(&20));
        // Kept: 0-1 and last-0; pruned: 10-11 (endpoints dropped); dangling: 5-9999999.
        assert_eq!(report.edges_written, 2);
        assert_eq!(report.dangling_edges, 1);
        let kept: Vec<(u32, u32)> = snap.valid_edges().iter().map(|e| (e.source_id, e.target_id)).collect();
        assert_eq!(kept, [(0, 1), (total as u32 - 1, 0)]);
    }

    #[test]
    fn ties_at_the_cut_prefer_lower_ids() {
        let mut snap = boxed_snapshot();
        let nodes: Vec<GraphNode> = (0..MAX_NODES as u32 + 2).map(|i| node(i, NodeKind::Part, 5)).collect();
        let graph = SceneGraph { version: 1, stamp_ns: 1, nodes, edges: vec![] };
        let report = fill_snapshot(&graph, &mut snap);
        assert!(report.truncated);
        assert_eq!(snap.valid_nodes().last().map(|n| n.id), Some(MAX_NODES as u32 - 1));
        assert_eq!(snap.header.part_count as usize, MAX_NODES);
    }

    #[test]
    fn too_many_edges_sets_capacity_flag() {
        let mut snap = boxed_snapshot();
        let nodes = vec![node(1, NodeKind::Object, 1), node(2, NodeKind::Object, 2)];
        let edges: Vec<GraphEdge> = (0..MAX_EDGES + 3).map(|_| edge(1, 2)).collect();
        let graph = SceneGraph { version: 3, stamp_ns: 0, nodes, edges };
        let report = fill_snapshot(&graph, &mut snap);
        assert!(report.truncated);
        assert_eq!(report.edges_written, MAX_EDGES);
        assert_eq!(snap.header.edge_count as usize, MAX_EDGES);
        assert_eq!(snap.header.total_edge_count as usize, MAX_EDGES + 3);
        assert_eq!(snap.header.capacity_exceeded, 1);
    }

    #[test]
    fn long_labels_are_cut_at_a_char_boundary() {
        let mut snap = boxed_snapshot();
        let mut n = node(1, NodeKind::Object, 1);
        n.label = "ä".repeat(30); // 60 bytes; 48 bytes = 24 chars
        let graph = SceneGraph { version: 1, stamp_ns: 0, nodes: vec![n], edges: vec![] };
        let report = fill_snapshot(&graph, &mut snap);
        assert_eq!(report.labels_cut, 1);
        assert_eq!(snap.nodes[0].label_str(), "ä".repeat(24));
    }

    #[test]
    fn unknown_kinds_name_the_entry() {
        let mut snap = boxed_snapshot();
        let graph = SceneGraph {
            version: 1,
            stamp_ns: 0,
            nodes: vec![node(1, NodeKind::Object, 1), node(2, NodeKind::Part, 1)],
            edges: vec![edge(1, 2)],
        };
        fill_snapshot(&graph, &mut snap);
        snap.nodes[1].kind = 9;
        assert_eq!(snapshot_to_scene_graph(&snap), Err(SnapshotError::UnknownNodeKind { index: 1, value: 9 }));
        snap.nodes[1].kind = 1;
        snap.edges[0].origin = 7;
        let err = snapshot_to_scene_graph(&snap).expect_err("bad origin");
        assert_eq!(err.to_string(), "edges[0].origin: unknown value 7 (0..=3)");
        let other = op3dsg_ipc_types::SCHEMA_VERSION + 1;
        snap.header.schema_version = other;
        assert!(matches!(
            snapshot_to_scene_graph(&snap),
            Err(SnapshotError::SchemaVersion { found, .. }) if found == other
        ));
    }

    #[test]
    fn client_graph_converts_back_to_the_scene_graph() {
        let mut snap = boxed_snapshot();
        let mut part = node(7, NodeKind::Part, 20);
        part.parent_id = Some(3);
        let graph = SceneGraph {
            version: 5,
            stamp_ns: 77,
            nodes: vec![part, node(3, NodeKind::Object, 10)],
            edges: vec![edge(7, 3), GraphEdge { kind: EdgeKind::Functional, origin: EdgeOrigin::Llm, ..edge(3, 7) }],
        };
        fill_snapshot(&graph, &mut snap);
        let client_graph = Graph::from_snapshot(&snap).expect("valid snapshot");
        let mut expected = graph;
        expected.nodes.sort_by_key(|n| n.id);
        assert_eq!(graph_to_scene_graph(&client_graph), expected);
        assert_eq!(snapshot_to_scene_graph(&snap).expect("valid"), expected);
    }
}
