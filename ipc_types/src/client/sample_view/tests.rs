//! The borrowed view on crafted bytes: it answers as the owned graph does, and every sample
//! that breaks the layout (counts past the end, a short or misaligned block, another schema
//! version) is refused with the error naming it, before any record is read; unknown kinds and
//! origins are named by the record check and refused by the owned copy.

use super::*;
use crate::client::test_graphs::{empty, graph_of, kitchen, push_node};
use crate::publish::GraphBuffer;
use crate::{EdgeOrigin, SCHEMA_VERSION};

/// A sample laid out as one block (header, then payload) in 8-byte-aligned memory.
struct Block(Vec<u64>);

impl Block {
    fn of(s: &mut GraphBuffer) -> Self {
        let message = s.encode();
        let mut bytes = bytemuck::bytes_of(message.header).to_vec();
        bytes.extend_from_slice(message.payload);
        Self::from_bytes(&bytes)
    }

    fn from_bytes(bytes: &[u8]) -> Self {
        let mut words = vec![0u64; bytes.len().div_ceil(8) + 1];
        bytemuck::cast_slice_mut::<u64, u8>(&mut words)[..bytes.len()].copy_from_slice(bytes);
        let block = Self(words);
        assert_eq!(block.bytes().as_ptr() as usize % 8, 0);
        block
    }

    /// The whole block, aligned (plus the trailing padding word's bytes, cut by `len`).
    fn bytes(&self) -> &[u8] {
        bytemuck::cast_slice(&self.0)
    }

    fn header_mut(&mut self) -> &mut GraphHeader {
        bytemuck::from_bytes_mut(&mut bytemuck::cast_slice_mut::<u64, u8>(&mut self.0)[..size_of::<GraphHeader>()])
    }
}

fn sample_len(s: &mut GraphBuffer) -> usize {
    size_of::<GraphHeader>() + s.encode().payload.len()
}

fn ids<'a>(nodes: impl Iterator<Item = NodeRef<'a>>) -> Vec<u32> {
    nodes.map(|n| n.id()).collect()
}

#[test]
fn the_view_answers_as_the_owned_graph_does() {
    let mut s = kitchen(7);
    let owned = graph_of(&mut s);
    let len = sample_len(&mut s);
    let block = Block::of(&mut s);
    let view = GraphView::from_bytes(&block.bytes()[..len]).expect("valid sample");
    assert_eq!((view.version(), view.instance_id(), view.stamp_ns()), (7, 0xabc, 1_007));
    assert_eq!((view.node_count(), view.edge_count()), (owned.node_count(), owned.edge_count()));
    assert_eq!(view.header(), owned.header());
    assert_eq!(
        bytemuck::cast_slice::<Node, u8>(view.wire_nodes()),
        bytemuck::cast_slice::<Node, u8>(owned.wire_nodes())
    );
    assert_eq!(ids(view.objects()), [1, 10]);
    assert_eq!(ids(view.parts()), [2, 3, 11, 20]);
    for id in [1, 2, 3, 10, 11, 20, 0, 4, 99, NO_NODE] {
        let (v, o) = (view.node(id), owned.node(id));
        assert_eq!(v.map(|n| (n.id(), n.label(), n.kind())), o.map(|n| (n.id(), n.label(), n.kind())), "node {id}");
        assert_eq!(ids(view.parts_of(id)), owned.parts_of(id).map(|n| n.id()).collect::<Vec<_>>(), "parts of {id}");
        assert_eq!(view.parent_of(id).map(|n| n.id()), owned.parent_of(id).map(|n| n.id()), "parent of {id}");
        let from = |e: EdgeRef<'_>| (e.source_id(), e.target_id(), e.phrase().to_owned(), e.origin());
        let from_owned = |e: crate::EdgeView<'_>| (e.source_id(), e.target_id(), e.phrase().to_owned(), e.origin());
        assert_eq!(
            view.edges_from(id).map(from).collect::<Vec<_>>(),
            owned.edges_from(id).map(from_owned).collect::<Vec<_>>()
        );
        assert_eq!(
            view.edges_to(id).map(from).collect::<Vec<_>>(),
            owned.edges_to(id).map(from_owned).collect::<Vec<_>>()
        );
    }
    let handle = view.node(2).expect("node 2");
    assert_eq!((handle.label(), handle.parent().map(|p| p.label())), ("Cabinet Handle", Some("cabinet")));
    assert_eq!((handle.size_m(), handle.index()), ([1.0, 1.0, 0.75], 1));
    assert_eq!(ids(view.node(1).expect("cabinet").parts()), [2, 3]);
    let knob_edge = view.node(11).expect("knob").edges_from().nth(1).expect("functional edge");
    assert_eq!(knob_edge.origin(), EdgeOrigin::KnowledgeAndLlm);
    assert_eq!((knob_edge.source().map(|n| n.id()), knob_edge.target().map(|n| n.label())), (Some(11), Some("stove")));
    assert_eq!(view.node(10).expect("stove").edges_to().count(), 3);
    assert_eq!(ids(view.find_by_label("knob")), [11]);
    assert_eq!(ids(view.find_by_label_containing("HANDLE")), [2, 3]);
    assert_eq!(ids(view.find_by_affordance("hook_pull").expect("canonical")), [2, 3]);
    assert_eq!(view.find_by_affordance("fly").map(|_| ()), Err(UnknownAffordance));
    // The owned copy of the view is the owned decode of the sample.
    view.check_records().expect("valid records");
    let copy = view.to_graph().expect("valid records");
    assert_eq!((copy.header(), copy.wire_edges().len()), (owned.header(), owned.wire_edges().len()));
    assert_eq!(ids(view.find_by_label_containing("")), copy.nodes().map(|n| n.id()).collect::<Vec<_>>());
}

#[test]
fn sparse_ids_are_found_by_binary_search() {
    let mut s = empty(1);
    for id in [5, 9, 1_000, 70_000] {
        push_node(&mut s, id, NodeKind::Object, NO_NODE, "box", &[]);
    }
    let message = s.encode();
    let block = Block::from_bytes(message.payload);
    let view = GraphView::from_message(GraphMessage::new(message.header, &block.bytes()[..message.payload.len()]))
        .expect("valid");
    assert_eq!([5, 9, 1_000, 70_000].map(|id| view.index_of(id)), [Some(0), Some(1), Some(2), Some(3)]);
    assert_eq!([0, 3, 6, 999, 70_001].map(|id| view.index_of(id)), [None; 5]);
}

#[test]
fn counts_past_the_end_are_refused_naming_the_lengths() {
    let mut s = kitchen(1);
    let len = sample_len(&mut s);
    let mut block = Block::of(&mut s);
    block.header_mut().node_count += 1;
    let err = GraphView::from_bytes(&block.bytes()[..len]).expect_err("one node more than the payload holds");
    let payload = len - size_of::<GraphHeader>();
    assert_eq!(err, SnapshotError::PayloadSize { found: payload, expected: payload + NODE_BYTES });
    assert_eq!(
        err.to_string(),
        format!("payload: {payload} bytes, but the header's counts need {} (144 per node, 64 per edge)", payload + 144)
    );

    // A payload cut short (the transport lost its end).
    let block = Block::of(&mut s);
    let err = GraphView::from_bytes(&block.bytes()[..len - 10]).expect_err("cut payload");
    assert_eq!(err, SnapshotError::PayloadSize { found: payload - 10, expected: payload });

    // The largest counts the header can state: refused without overflow or a read past the end.
    let mut block = Block::of(&mut s);
    let header = block.header_mut();
    (header.node_count, header.edge_count, header.node_capacity, header.edge_capacity) =
        (u32::MAX, u32::MAX, u32::MAX, u32::MAX);
    let err = GraphView::from_bytes(&block.bytes()[..len]).expect_err("counts far past the end");
    assert!(matches!(err, SnapshotError::PayloadSize { found, .. } if found == payload), "{err}");

    // A count beyond the capacity the header states.
    let mut block = Block::of(&mut s);
    block.header_mut().edge_capacity = 2;
    let err = GraphView::from_bytes(&block.bytes()[..len]).expect_err("more edges than the capacity");
    assert_eq!(err.to_string(), "header.edge_count: 6 exceeds the capacity 2");
}

#[test]
fn misaligned_samples_are_refused_naming_the_address() {
    let mut s = kitchen(1);
    let len = sample_len(&mut s);
    // The same bytes, one byte further on: the header no longer lies on an 8-byte boundary.
    let mut shifted = vec![0u8];
    shifted.extend_from_slice(&Block::of(&mut s).bytes()[..len]);
    let shifted = Block::from_bytes(&shifted);
    let bytes = &shifted.bytes()[1..=len];
    let err = GraphView::from_bytes(bytes).expect_err("misaligned header");
    assert_eq!(err, SnapshotError::Misaligned { field: "header", address: bytes.as_ptr() as usize, alignment: 8 });
    assert!(
        err.to_string()
            .starts_with(&format!("header: starts at address {:#x}, not a multiple of 8", bytes.as_ptr() as usize)),
        "{err}"
    );

    // A payload 4 bytes off its alignment, behind a header of its own.
    let message = s.encode();
    let mut padded = vec![0u8; 4];
    padded.extend_from_slice(message.payload);
    let padded_block = Block::from_bytes(&padded);
    let payload = &padded_block.bytes()[4..4 + message.payload.len()];
    let err = GraphView::from_message(GraphMessage::new(message.header, payload)).expect_err("misaligned payload");
    assert_eq!(err, SnapshotError::Misaligned { field: "payload", address: payload.as_ptr() as usize, alignment: 8 });
    assert!(err.to_string().contains("so it cannot be read in place"), "{err}");

    // An empty graph has no records to align: any address will do.
    let mut none = empty(3);
    let message = none.encode();
    let view = GraphView::from_message(GraphMessage::new(message.header, &padded[1..1])).expect("empty graph");
    assert_eq!((view.node_count(), view.edge_count(), view.nodes().count()), (0, 0, 0));
}

#[test]
fn a_short_header_and_another_schema_version_are_refused() {
    let mut s = kitchen(1);
    let len = sample_len(&mut s);
    let block = Block::of(&mut s);
    for cut in [0, 1, 50, size_of::<GraphHeader>() - 1] {
        let err = GraphView::from_bytes(&block.bytes()[..cut]).expect_err("truncated header");
        assert_eq!(err, SnapshotError::HeaderSize { found: cut, expected: 112 });
    }
    assert_eq!(
        GraphView::from_bytes(&block.bytes()[..50]).expect_err("short").to_string(),
        "header: 50 bytes, but a GraphHeader has 112"
    );

    let mut block = Block::of(&mut s);
    block.header_mut().schema_version = SCHEMA_VERSION + 1;
    let err = GraphView::from_bytes(&block.bytes()[..len]).expect_err("another schema");
    assert_eq!(err, SnapshotError::SchemaVersion { found: SCHEMA_VERSION + 1, expected: SCHEMA_VERSION });
    // The schema is checked first: a sample of another version is not measured by this one's rules.
    block.header_mut().node_count = 1_000;
    let err = GraphView::from_bytes(&block.bytes()[..len]).expect_err("another schema");
    assert!(matches!(err, SnapshotError::SchemaVersion { .. }), "{err}");
}

#[test]
fn unknown_kinds_and_origins_are_found_by_the_record_check_and_refused_by_the_copy() {
    let mut s = kitchen(1);
    s.nodes[4].kind = 9;
    let message = s.encode();
    let block = Block::from_bytes(message.payload);
    let payload = &block.bytes()[..message.payload.len()];
    // Nothing scans the records on receipt; the value reads as the first kind.
    let view = GraphView::from_message(GraphMessage::new(message.header, payload)).expect("layout fits");
    assert_eq!((view.node(11).map(|n| n.kind()), view.wire_nodes()[4].kind), (Some(NodeKind::Object), 9));
    let err = view.check_records().expect_err("unknown kind");
    assert_eq!(err.to_string(), "nodes[4].kind: unknown value 9 (0 object, 1 part)");
    assert_eq!(view.to_graph().map(|_| ()), Err(err), "the owned copy refuses it as the owned decode does");
    let mut kept = graph_of(&mut kitchen(2));
    assert_eq!(kept.copy_from_view(&view), Err(err));
    assert_eq!(kept.version(), 2, "left as it was");
    assert_eq!(Graph::from_message(&message).map(|_| ()), Err(err));

    let mut s = kitchen(1);
    s.edges[3].origin = 4;
    let message = s.encode();
    let block = Block::from_bytes(message.payload);
    let payload = &block.bytes()[..message.payload.len()];
    let view = GraphView::from_message(GraphMessage::new(message.header, payload)).expect("layout fits");
    assert_eq!(view.check_records(), Err(SnapshotError::UnknownEdgeOrigin { index: 3, value: 4 }));
}
