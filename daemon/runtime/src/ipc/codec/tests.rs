//! Tests of the graph codec: selection under capacity, the records and the header.

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
        first_seen_stamp_ns: 0,
        missing: false,
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
            [("rotate", "knowledge"), ("key_press", "knowledge+llm"), ("tip_push", "llm"), ("hook_pull", "geometry")]
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
fn writing_into_uninitialised_bytes_writes_every_byte_as_the_own_buffer() {
    let graph = SceneGraph {
        version: 4,
        stamp_ns: 2,
        nodes: vec![node(3, NodeKind::Object, 10), node(7, NodeKind::Part, 20)],
        edges: vec![edge(7, 3), edge(3, 7)],
    };
    let mut own = encoder();
    own.encode(&graph);
    let mut split = encoder();
    let mut report = split.select(&graph);
    let mut loaned = vec![std::mem::MaybeUninit::<u8>::uninit(); report.payload_bytes];
    split.write_payload(&graph, &mut loaned, &mut report);
    // Every byte was written: reading them back is what the publisher's `assume_init` relies on.
    #[allow(unsafe_code)]
    let written: Vec<u8> = loaned.iter().map(|b| unsafe { b.assume_init() }).collect();
    assert_eq!(written.as_slice(), own.payload());
}

#[test]
#[should_panic(expected = "graph payload length")]
fn a_buffer_of_another_length_is_refused() {
    let graph = SceneGraph { version: 1, stamp_ns: 1, nodes: vec![node(3, NodeKind::Object, 10)], edges: vec![] };
    let mut encoder = encoder();
    let mut report = encoder.select(&graph);
    let mut short = vec![std::mem::MaybeUninit::<u8>::uninit(); report.payload_bytes - 1];
    encoder.write_payload(&graph, &mut short, &mut report);
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

#[test]
fn every_header_carries_the_origin_and_zero_reserved_bytes() {
    let graph = SceneGraph { version: 1, stamp_ns: 5, nodes: vec![node(1, NodeKind::Object, 1)], edges: vec![] };
    let mut encoder = encoder();
    encoder.encode(&graph);
    let header = *encoder.header();
    assert_eq!((header.source_kind(), header.world_frame_str()), (op3dsg_ipc_types::SourceKind::Unknown, ""));
    encoder.set_origin(GraphOrigin::new(op3dsg_drivers::source::SourceKind::LiveCamera, "map"));
    for version in 2..4 {
        encoder.encode(&SceneGraph { version, ..graph.clone() });
        let header = encoder.header();
        assert_eq!(
            (header.source_kind(), header.world_frame_str()),
            (op3dsg_ipc_types::SourceKind::LiveCamera, "map"),
            "version {version}"
        );
        assert_eq!((header.reserved, header.reserved2), ([0; 2], 0));
        assert_eq!(header.schema_version, SCHEMA_VERSION);
    }
}
