//! Graphs built on the heap for the tests of the owned [`Graph`] and the borrowed
//! [`GraphView`](crate::GraphView): a small kitchen with parts, part-of and functional edges.

use crate::client::Graph;
use crate::publish::GraphBuffer;
use crate::{
    Edge, EdgeOrigin, MAX_EDGES, MAX_NODES, NO_NODE, Node, NodeKind, SCHEMA_VERSION, affordance_bits, relation_id,
    write_fixed_str,
};

pub(crate) fn push_node(
    snapshot: &mut GraphBuffer,
    id: u32,
    kind: NodeKind,
    parent_id: u32,
    label: &str,
    affordances: &[&str],
) {
    let mut node = Node { id, parent_id, kind: kind as u8, ..Node::default() };
    write_fixed_str(&mut node.label, label);
    node.centre_m = [id as f32, 0.5, 1.0];
    node.box_min_m = [id as f32 - 0.5, 0.0, 0.5];
    node.box_max_m = [id as f32 + 0.5, 1.0, 1.25];
    node.affordance_bits = affordance_bits(affordances.iter().copied()).expect("canonical affordances");
    snapshot.nodes.push(node);
    match kind {
        NodeKind::Object => snapshot.header.object_count += 1,
        NodeKind::Part => snapshot.header.part_count += 1,
    }
}

pub(crate) fn push_edge(snapshot: &mut GraphBuffer, source_id: u32, target_id: u32, phrase: &str, origin: EdgeOrigin) {
    let (kind, relation) = relation_id(phrase).expect("canonical phrase");
    let mut edge =
        Edge { source_id, target_id, kind: kind as u8, origin: origin as u8, relation_id: relation, ..Edge::default() };
    write_fixed_str(&mut edge.phrase, phrase);
    snapshot.edges.push(edge);
}

pub(crate) fn empty(version: u64) -> GraphBuffer {
    let mut s = GraphBuffer::new();
    s.header.schema_version = SCHEMA_VERSION;
    s.header.graph_version = version;
    s.header.instance_id = 0xabc;
    s.header.node_capacity = MAX_NODES as u32;
    s.header.edge_capacity = MAX_EDGES as u32;
    s
}

pub(crate) fn graph_of(s: &mut GraphBuffer) -> Graph {
    Graph::from_message(&s.encode()).expect("valid graph")
}

/// A kitchen: a cabinet with two handles, a stove with a knob, a remote-less TV, an orphan
/// button; part-of and functional edges.
pub(crate) fn kitchen(version: u64) -> GraphBuffer {
    let mut s = empty(version);
    s.header.stamp_ns = 1_000 + version;
    push_node(&mut s, 1, NodeKind::Object, NO_NODE, "cabinet", &[]);
    push_node(&mut s, 2, NodeKind::Part, 1, "Cabinet Handle", &["hook_pull"]);
    push_node(&mut s, 3, NodeKind::Part, 1, "drawer handle", &["hook_pull", "pinch_pull"]);
    push_node(&mut s, 10, NodeKind::Object, NO_NODE, "stove", &[]);
    push_node(&mut s, 11, NodeKind::Part, 10, "knob", &["rotate"]);
    push_node(&mut s, 20, NodeKind::Part, NO_NODE, "button", &["tip_push"]);
    push_edge(&mut s, 2, 1, "part of", EdgeOrigin::Geometry);
    push_edge(&mut s, 3, 1, "part of", EdgeOrigin::Geometry);
    push_edge(&mut s, 11, 10, "part of", EdgeOrigin::Geometry);
    push_edge(&mut s, 2, 1, "pull to open or close", EdgeOrigin::Knowledge);
    push_edge(&mut s, 11, 10, "rotate to adjust the setting or temperature", EdgeOrigin::KnowledgeAndLlm);
    push_edge(&mut s, 1, 10, "next to", EdgeOrigin::Geometry);
    s
}
