//! Tests of the owned graph and its views, on graphs built on the heap.

use super::*;
use crate::client::test_graphs::{empty, graph_of, kitchen, push_edge, push_node};
use crate::{EdgeKind, EdgeOrigin, SCHEMA_VERSION, write_fixed_str};

fn ids<'a>(nodes: impl Iterator<Item = NodeView<'a>>) -> Vec<u32> {
    nodes.map(|n| n.id()).collect()
}

#[test]
fn views_answer_the_planner_questions() {
    let graph = graph_of(&mut kitchen(7));
    assert_eq!((graph.version(), graph.stamp_ns()), (7, 1_007));
    assert_eq!((graph.node_count(), graph.edge_count()), (6, 6));
    assert_eq!(ids(graph.objects()), [1, 10]);
    assert_eq!(ids(graph.parts()), [2, 3, 11, 20]);
    assert!(!graph.capacity_exceeded());

    let handle = graph.node(2).expect("node 2");
    assert_eq!((handle.kind(), handle.label(), handle.parent_id()), (NodeKind::Part, "Cabinet Handle", Some(1)));
    assert!(handle.is_part() && !handle.is_object());
    assert_eq!(handle.centre_m(), [2.0, 0.5, 1.0]);
    assert_eq!(handle.size_m(), [1.0, 1.0, 0.75]);
    assert_eq!(handle.affordances().collect::<Vec<_>>(), ["hook_pull"]);
    assert!(handle.has_affordance("hook_pull") && !handle.has_affordance("rotate") && !handle.has_affordance("fly"));
    assert_eq!(handle.parent().map(|p| p.label()), Some("cabinet"));
    assert!(graph.node(99).is_none());

    assert_eq!(ids(graph.parts_of(1)), [2, 3]);
    assert_eq!(ids(graph.node(10).expect("stove").parts()), [11]);
    assert_eq!(ids(graph.parts_of(2)), Vec::<u32>::new());
    assert_eq!(ids(graph.parts_of(99)), Vec::<u32>::new());
    assert_eq!(graph.parent_of(11).map(|p| p.id()), Some(10));
    assert!(graph.parent_of(20).is_none(), "orphan part");
    assert!(graph.parent_of(1).is_none(), "object");

    let from_handle: Vec<_> = graph.edges_from(2).map(|e| (e.phrase(), e.target_id(), e.kind(), e.origin())).collect();
    assert_eq!(
        from_handle,
        [
            ("part of", 1, EdgeKind::Spatial, EdgeOrigin::Geometry),
            ("pull to open or close", 1, EdgeKind::Functional, EdgeOrigin::Knowledge),
        ]
    );
    let to_stove: Vec<_> = graph.edges_to(10).map(|e| (e.source_id(), e.phrase())).collect();
    assert_eq!(to_stove, [(11, "part of"), (11, "rotate to adjust the setting or temperature"), (1, "next to")]);
    let knob_edge = graph.node(11).expect("knob").edges_from().nth(1).expect("functional edge");
    assert_eq!(knob_edge.origin(), EdgeOrigin::KnowledgeAndLlm);
    assert_eq!(knob_edge.source().map(|n| n.label()), Some("knob"));
    assert_eq!(knob_edge.target().map(|n| n.label()), Some("stove"));
    assert_eq!(graph.edges_to(20).count(), 0);
    assert_eq!(graph.edges_from(99).count(), 0);

    assert_eq!(ids(graph.find_by_label("knob")), [11]);
    assert_eq!(ids(graph.find_by_label("handle")), Vec::<u32>::new(), "exact match only");
    assert_eq!(ids(graph.find_by_label_containing("HANDLE")), [2, 3]);
    assert_eq!(ids(graph.find_by_label_containing("")), [1, 2, 3, 10, 11, 20]);
    assert_eq!(ids(graph.find_by_affordance("hook_pull").expect("canonical")), [2, 3]);
    assert_eq!(ids(graph.find_by_affordance("rotate").expect("canonical")), [11]);
    assert_eq!(ids(graph.find_by_affordance("unplug").expect("canonical")), Vec::<u32>::new());
    assert_eq!(graph.find_by_affordance("fly").map(|_| ()), Err(UnknownAffordance));
    let both = affordance_bits(["hook_pull", "pinch_pull"]).expect("canonical");
    assert_eq!(ids(graph.find_by_affordance_bits(both)), [3]);
}

#[test]
fn copying_a_smaller_graph_replaces_everything() {
    let mut graph = graph_of(&mut kitchen(1));
    let mut small = empty(2);
    push_node(&mut small, 10, NodeKind::Object, NO_NODE, "stove", &[]);
    push_node(&mut small, 12, NodeKind::Part, 10, "knob", &["rotate"]);
    push_edge(&mut small, 12, 10, "part of", EdgeOrigin::Geometry);
    graph.copy_from(&small.encode()).expect("valid");
    assert_eq!(graph.version(), 2);
    assert!(!graph.restarted(), "same instance");
    assert_eq!(ids(graph.nodes()), [10, 12]);
    assert!(graph.node(1).is_none() && graph.node(11).is_none(), "old ids gone");
    assert_eq!(ids(graph.parts_of(10)), [12]);
    assert_eq!(graph.edges_from(2).count(), 0);
    assert_eq!(graph.edges_to(10).map(|e| e.source_id()).collect::<Vec<_>>(), [12]);
}

#[test]
fn dangling_edges_and_parents_stay_visible_but_unresolved() {
    let mut s = kitchen(1);
    push_node(&mut s, 30, NodeKind::Part, 77, "switch", &[]);
    push_edge(&mut s, 30, 77, "part of", EdgeOrigin::Geometry);
    let graph = graph_of(&mut s);
    let switch = graph.node(30).expect("switch");
    assert_eq!((switch.parent_id(), switch.parent().map(|p| p.id())), (Some(77), None));
    let edge = graph.edges_from(30).next().expect("edge to a node outside the graph");
    assert!(edge.target().is_none());
    assert_eq!(graph.edges_to(77).count(), 0);
    assert_eq!(graph.edges().count(), 7);
}

#[test]
fn contract_breaks_are_named_and_leave_the_graph_as_it_was() {
    let mut graph = graph_of(&mut kitchen(5));
    let mut s = kitchen(6);
    s.header.schema_version = SCHEMA_VERSION + 1;
    let err = graph.copy_from(&s.encode()).expect_err("other schema");
    assert_eq!(err, SnapshotError::SchemaVersion { found: SCHEMA_VERSION + 1, expected: SCHEMA_VERSION });
    assert_eq!(
        err.to_string(),
        format!("header.schema_version: found {}, this build reads {SCHEMA_VERSION}", SCHEMA_VERSION + 1)
    );
    assert_eq!(graph.version(), 5, "unchanged");
    assert_eq!(graph.node_count(), 6);

    let mut s = kitchen(6);
    s.nodes[1].kind = 9;
    assert_eq!(graph.copy_from(&s.encode()), Err(SnapshotError::UnknownNodeKind { index: 1, value: 9 }));
    let mut s = kitchen(6);
    s.edges[0].origin = 7;
    assert_eq!(
        graph.copy_from(&s.encode()).expect_err("origin").to_string(),
        "edges[0].origin: unknown value 7 (0..=3)"
    );
    let mut s = kitchen(6);
    s.edges[2].kind = 3;
    assert_eq!(graph.copy_from(&s.encode()), Err(SnapshotError::UnknownEdgeKind { index: 2, value: 3 }));
    let mut s = kitchen(6);
    s.header.node_capacity = 4;
    assert_eq!(
        graph.copy_from(&s.encode()),
        Err(SnapshotError::CountTooLarge { field: "node_count", value: 6, capacity: 4 })
    );
    let mut s = kitchen(6);
    let message = s.encode();
    let mut header = *message.header;
    header.edge_count += 1;
    let err = graph.copy_from(&GraphMessage::new(&header, message.payload)).expect_err("short payload");
    assert_eq!(err, SnapshotError::PayloadSize { found: 6 * 144 + 6 * 64, expected: 6 * 144 + 7 * 64 });
    let err = graph.copy_from(&GraphMessage::new(message.header, &message.payload[1..])).expect_err("cut payload");
    assert!(matches!(err, SnapshotError::PayloadSize { .. }), "{err}");
    assert_eq!(graph.version(), 5, "still unchanged");
    assert_eq!(ids(graph.parts_of(1)), [2, 3]);
}

#[test]
fn an_empty_graph_answers_nothing() {
    let graph = Graph::new();
    assert_eq!((graph.version(), graph.node_count(), graph.edge_count()), (0, 0, 0));
    assert!(graph.node(0).is_none());
    assert_eq!(graph.parts_of(0).count() + graph.edges_from(0).count() + graph.edges_to(0).count(), 0);
    let mut s = empty(1);
    let message = s.encode();
    assert!(message.payload.is_empty());
    let graph = Graph::from_message(&message).expect("empty but valid");
    assert_eq!(graph.nodes().len(), 0);
}

#[test]
fn unknown_relation_ids_fall_back_to_the_sample_phrase() {
    let mut s = kitchen(1);
    s.edges[5].relation_id = 60;
    write_fixed_str(&mut s.edges[5].phrase, "leans against");
    let graph = graph_of(&mut s);
    assert_eq!(graph.edges().nth(5).map(|e| e.phrase()), Some("leans against"));
}

#[test]
fn a_three_node_sample_is_small() {
    let mut s = empty(1);
    push_node(&mut s, 1, NodeKind::Object, NO_NODE, "cabinet", &[]);
    push_node(&mut s, 2, NodeKind::Part, 1, "handle", &["hook_pull"]);
    push_node(&mut s, 3, NodeKind::Part, 1, "knob", &["rotate"]);
    push_edge(&mut s, 2, 1, "part of", EdgeOrigin::Geometry);
    let message = s.encode();
    // Header and payload together: what the graph holds, not the 4.3 MiB maximum.
    assert_eq!(message.payload.len(), 3 * 144 + 64);
    assert_eq!(core::mem::size_of::<GraphHeader>() + message.payload.len(), 608);
    let graph = Graph::from_message(&message).expect("valid");
    assert_eq!(ids(graph.parts_of(1)), [2, 3]);
}

#[test]
fn another_instance_id_marks_a_restart() {
    let mut graph = graph_of(&mut kitchen(40));
    assert_eq!(graph.instance_id(), 0xabc);
    assert!(!graph.restarted(), "nothing before the first graph");
    let mut again = kitchen(41);
    graph.copy_from(&again.encode()).expect("valid");
    assert!(!graph.restarted());
    let mut restarted = kitchen(1);
    restarted.header.instance_id = 0xdef;
    graph.copy_from(&restarted.encode()).expect("valid");
    assert!(graph.restarted(), "instance changed");
    assert_eq!((graph.instance_id(), graph.version()), (0xdef, 1));
    graph.copy_from(&kitchen(2).encode()).map(|_| ()).expect("valid");
    assert!(graph.restarted(), "0xabc again is another instance than 0xdef");
}

#[test]
fn the_oriented_box_and_its_footprint_come_through() {
    let mut s = empty(1);
    push_node(&mut s, 1, NodeKind::Object, NO_NODE, "counter", &[]);
    // A 2 m x 0.6 m counter turned 90 degrees: its footprint runs along y.
    s.nodes[0].obb_centre_m = [1.0, 2.0, 0.45];
    s.nodes[0].obb_size_m = [2.0, 0.6, 0.9];
    s.nodes[0].obb_yaw_rad = std::f32::consts::FRAC_PI_2;
    let graph = graph_of(&mut s);
    let counter = graph.node(1).expect("node 1");
    assert_eq!(counter.oriented_box(), ([1.0, 2.0, 0.45], [2.0, 0.6, 0.9], std::f32::consts::FRAC_PI_2));
    let footprint = counter.footprint_z_up_m();
    let expected = [[1.3, 1.0], [1.3, 3.0], [0.7, 3.0], [0.7, 1.0]];
    for (corner, want) in footprint.iter().zip(expected) {
        assert!((corner[0] - want[0]).abs() < 1e-5 && (corner[1] - want[1]).abs() < 1e-5, "{footprint:?}");
    }
}

#[test]
fn each_affordance_names_its_origin() {
    let mut s = empty(3);
    push_node(&mut s, 1, NodeKind::Part, NO_NODE, "cabinet handle", &["tip_push", "hook_pull", "pinch_pull", "unplug"]);
    let node = s.nodes.last_mut().expect("pushed");
    node.affordance_knowledge_bits = affordance_bits(["hook_pull", "unplug"]).expect("canonical");
    node.affordance_llm_bits = affordance_bits(["pinch_pull", "unplug"]).expect("canonical");
    let graph = graph_of(&mut s);
    let handle = graph.node(1).expect("node 1");
    assert_eq!(
        handle.affordance_origins().collect::<Vec<_>>(),
        [
            ("tip_push", EdgeOrigin::Geometry),
            ("hook_pull", EdgeOrigin::Knowledge),
            ("pinch_pull", EdgeOrigin::Llm),
            ("unplug", EdgeOrigin::KnowledgeAndLlm),
        ]
    );
    assert_eq!(handle.affordance_origin("pinch_pull"), Some(EdgeOrigin::Llm));
    assert_eq!(handle.affordance_origin("rotate"), None, "not afforded");
    assert_eq!(handle.affordance_origin("fly"), None, "not canonical");
}

#[test]
fn the_graph_says_what_it_is_of_and_in_which_frame() {
    let mut s = kitchen(1);
    let graph = graph_of(&mut s);
    assert_eq!((graph.source_kind(), graph.world_frame()), (crate::SourceKind::Unknown, ""), "a default header");
    s.header.source_kind = crate::SourceKind::Replay as u8;
    write_fixed_str(&mut s.header.world_frame, "map");
    let graph = graph_of(&mut s);
    assert_eq!((graph.source_kind(), graph.world_frame()), (crate::SourceKind::Replay, "map"));
    assert_eq!(graph.source_kind().as_str(), "replay");
    // A value of a newer contract reads as unknown instead of failing the graph.
    s.header.source_kind = 200;
    assert_eq!(graph_of(&mut s).source_kind(), crate::SourceKind::Unknown);
    for (value, name) in crate::SOURCE_KINDS.iter().enumerate() {
        let kind = crate::SourceKind::from_u8(value as u8).expect("every listed value decodes");
        assert_eq!((kind as usize, kind.as_str()), (value, *name));
    }
    assert_eq!(crate::SourceKind::from_u8(crate::SOURCE_KINDS.len() as u8), None);
}
