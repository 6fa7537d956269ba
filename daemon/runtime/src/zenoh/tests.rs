//! Tests of the Zenoh messages: a reader that knows only the documented layout follows full
//! graphs and deltas and ends up with the daemon's graph.

use std::collections::BTreeMap;

use op3dsg_ipc_types::{EDGE_BYTES, EdgeKind, EdgeOrigin, GraphHeader, NODE_BYTES, NodeKind};

use super::codec::*;
use crate::graph::{GraphEdge, GraphNode, SceneGraph};
use crate::ipc::{GraphCapacity, GraphEncoder};

fn node(id: u32, label: &str, x: f32) -> GraphNode {
    GraphNode {
        id,
        kind: NodeKind::Object,
        label: label.to_owned(),
        confidence: 0.5,
        centre_m: [x, 0.0, 0.0],
        observation_count: 1,
        ..Default::default()
    }
}

fn edge(s: u32, t: u32, relation_id: u16, confidence: f32) -> GraphEdge {
    GraphEdge {
        source_id: s,
        target_id: t,
        kind: EdgeKind::Spatial,
        relation_id,
        confidence,
        origin: EdgeOrigin::Geometry,
    }
}

/// What a reader keeps: node records by id, edge records as a multiset, the header.
#[derive(Debug, Default, PartialEq)]
struct Reader {
    instance_id: u64,
    version: u64,
    header: Option<GraphHeader>,
    nodes: BTreeMap<u32, [u8; NODE_BYTES]>,
    edges: BTreeMap<[u8; EDGE_BYTES], u32>,
}

fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b[o..o + 4].try_into().unwrap())
}

fn u64_at(b: &[u8], o: usize) -> u64 {
    u64::from_le_bytes(b[o..o + 8].try_into().unwrap())
}

impl Reader {
    /// Applies a message; `false` when a delta does not apply to the version held.
    fn apply(&mut self, m: &[u8]) -> bool {
        assert_eq!(&m[0..4], b"O3DZ");
        assert_eq!(u16::from_le_bytes([m[4], m[5]]), FORMAT_VERSION);
        let kind = u16::from_le_bytes([m[6], m[7]]);
        let (instance, version, base) = (u64_at(m, 8), u64_at(m, 16), u64_at(m, 24));
        let header = read_header(m[ENVELOPE_BYTES..ENVELOPE_BYTES + HEADER_BYTES].try_into().unwrap());
        let mut at = ENVELOPE_BYTES + HEADER_BYTES;
        let take = |at: &mut usize, n: usize| {
            let s = &m[*at..*at + n];
            *at += n;
            s
        };
        match kind {
            1 => {
                *self = Reader { instance_id: instance, version, header: Some(header), ..Reader::default() };
                for r in take(&mut at, header.node_count as usize * NODE_BYTES).as_chunks::<NODE_BYTES>().0 {
                    self.nodes.insert(node_id(r), *r);
                }
                for r in take(&mut at, header.edge_count as usize * EDGE_BYTES).as_chunks::<EDGE_BYTES>().0 {
                    *self.edges.entry(*r).or_default() += 1;
                }
            }
            2 => {
                if instance != self.instance_id || base != self.version {
                    return false;
                }
                let c = take(&mut at, DELTA_COUNTS_BYTES);
                let (up, rm, add, gone) = (u32_at(c, 0), u32_at(c, 4), u32_at(c, 8), u32_at(c, 12));
                for r in take(&mut at, up as usize * NODE_BYTES).as_chunks::<NODE_BYTES>().0 {
                    self.nodes.insert(node_id(r), *r);
                }
                for r in take(&mut at, add as usize * EDGE_BYTES).as_chunks::<EDGE_BYTES>().0 {
                    *self.edges.entry(*r).or_default() += 1;
                }
                for r in take(&mut at, gone as usize * EDGE_BYTES).as_chunks::<EDGE_BYTES>().0 {
                    let count = self.edges.get_mut(r).expect("a removed edge was held");
                    *count -= 1;
                    if *count == 0 {
                        self.edges.remove(r);
                    }
                }
                for id in take(&mut at, rm as usize * 4).chunks(4) {
                    assert!(self.nodes.remove(&u32_at(id, 0)).is_some(), "a removed node was held");
                }
                self.version = version;
                self.header = Some(header);
            }
            other => panic!("unexpected kind {other}"),
        }
        assert_eq!(at, m.len(), "every byte read");
        true
    }
}

fn versions() -> Vec<SceneGraph> {
    let v1 = SceneGraph {
        version: 1,
        stamp_ns: 10,
        nodes: vec![node(1, "table", 0.0), node(2, "chair", 1.0), node(4, "cup", 2.0)],
        edges: vec![edge(2, 1, 1, 0.9), edge(4, 1, 2, 0.8), edge(4, 1, 2, 0.8)],
    };
    let mut v2 = v1.clone();
    v2.version = 2;
    v2.nodes[1].centre_m = [1.5, 0.0, 0.0]; // changed
    v2.nodes.remove(2); // node 4 gone with its edges
    v2.nodes.push(node(5, "lamp", 3.0)); // new
    v2.edges = vec![edge(2, 1, 1, 0.95), edge(5, 1, 3, 0.7)];
    let mut v3 = v2.clone();
    v3.version = 3;
    v3.nodes.clear();
    v3.edges.clear();
    vec![v1, v2, v3]
}

#[test]
fn deltas_bring_a_reader_to_the_full_graph_of_each_version() {
    let mut encoder = GraphEncoder::new(GraphCapacity::default(), 77);
    let mut deltas = DeltaEncoder::default();
    let (mut full, mut delta) = (Vec::new(), Vec::new());
    let mut follower = Reader::default();
    for (i, graph) in versions().iter().enumerate() {
        encoder.encode(graph);
        let header = *encoder.header();
        encode_full(&header, encoder.payload(), 5, &mut full);
        let counts = deltas.next(&header, encoder.payload(), 5, &mut delta);
        if i == 0 {
            assert!(counts.is_none() && delta.is_empty(), "the first version has no base");
            assert!(follower.apply(&full));
        } else {
            assert!(follower.apply(&delta), "the delta applies to the version before");
        }
        let mut fresh = Reader::default();
        assert!(fresh.apply(&full));
        assert_eq!(follower, fresh, "version {}", graph.version);
        if i == 1 {
            let c = counts.unwrap();
            // chair changed, lamp new; cup removed; chair-table changed and lamp-table new; the
            // old chair-table and both cup-table edges gone.
            assert_eq!((c.nodes_upserted, c.nodes_removed, c.edges_added, c.edges_removed), (2, 1, 2, 3));
        }
    }
    // A reader that missed version 2 cannot apply version 3's delta: it waits for a full graph.
    let mut behind = Reader::default();
    encoder.encode(&versions()[0]);
    encode_full(encoder.header(), encoder.payload(), 5, &mut full);
    behind.apply(&full);
    assert!(!behind.apply(&delta));
}

#[test]
fn a_delta_costs_what_changed() {
    let mut graph = SceneGraph {
        version: 1,
        nodes: (0..100).map(|i| node(i, "box", i as f32)).collect(),
        edges: (1..100).map(|i| edge(i, 0, 1, 0.9)).collect(),
        ..SceneGraph::default()
    };
    let mut encoder = GraphEncoder::new(GraphCapacity::default(), 3);
    let mut deltas = DeltaEncoder::default();
    let (mut full, mut delta) = (Vec::new(), Vec::new());
    encoder.encode(&graph);
    deltas.next(encoder.header(), encoder.payload(), 0, &mut delta);
    graph.version = 2;
    graph.nodes[10].centre_m[1] = 0.5;
    encoder.encode(&graph);
    encode_full(encoder.header(), encoder.payload(), 0, &mut full);
    deltas.next(encoder.header(), encoder.payload(), 0, &mut delta).unwrap();
    assert_eq!(full.len(), ENVELOPE_BYTES + HEADER_BYTES + 100 * NODE_BYTES + 99 * EDGE_BYTES);
    assert_eq!(delta.len(), ENVELOPE_BYTES + HEADER_BYTES + DELTA_COUNTS_BYTES + NODE_BYTES);
}

#[test]
fn a_new_instance_starts_without_a_delta() {
    let mut deltas = DeltaEncoder::default();
    let mut out = Vec::new();
    let mut encoder = GraphEncoder::new(GraphCapacity::default(), 1);
    let graph = &versions()[0];
    encoder.encode(graph);
    assert!(deltas.next(encoder.header(), encoder.payload(), 0, &mut out).is_none());
    let mut restarted = GraphEncoder::new(GraphCapacity::default(), 2);
    restarted.encode(graph);
    assert!(deltas.next(restarted.header(), restarted.payload(), 0, &mut out).is_none());
    assert!(out.is_empty());
}

#[test]
fn the_header_round_trips_through_its_bytes() {
    let mut encoder = GraphEncoder::new(GraphCapacity::default(), 0xfeed_beef);
    encoder.encode(&versions()[1]);
    encoder.set_publish_time_ns(123_456);
    let mut bytes = Vec::new();
    append_header(encoder.header(), &mut bytes);
    assert_eq!(bytes.len(), HEADER_BYTES);
    assert_eq!(read_header(bytes.as_slice().try_into().unwrap()), *encoder.header());
    assert_eq!(u64_at(&bytes, 16), 0xfeed_beef, "instance_id at offset 16");
}

#[test]
fn a_health_message_is_the_envelope_and_json() {
    let mut out = Vec::new();
    encode_health(9, 4, 100, br#"{"uptime_s":1.0}"#, &mut out);
    assert_eq!(&out[..4], b"O3DZ");
    assert_eq!(u16::from_le_bytes([out[6], out[7]]), MessageKind::Health as u16);
    assert_eq!((u64_at(&out, 8), u64_at(&out, 16)), (9, 4));
    assert_eq!(&out[ENVELOPE_BYTES..], br#"{"uptime_s":1.0}"#);
}

#[test]
fn the_client_librarys_follower_reads_what_the_stage_writes() {
    use op3dsg_ipc_types::client::{Applied, RemoteFollower};
    let mut encoder = GraphEncoder::new(GraphCapacity::default(), 77);
    let mut deltas = DeltaEncoder::default();
    let (mut full, mut delta) = (Vec::new(), Vec::new());
    let mut follower = RemoteFollower::new();
    let mut missed = RemoteFollower::new();
    for (i, graph) in versions().iter().enumerate() {
        encoder.encode(graph);
        let header = *encoder.header();
        encode_full(&header, encoder.payload(), 5, &mut full);
        deltas.next(&header, encoder.payload(), 5, &mut delta);
        let applied = if i == 0 { follower.apply(&full) } else { follower.apply(&delta) };
        assert_eq!(applied.unwrap(), if i == 0 { Applied::Full } else { Applied::Delta });
        assert_eq!(follower.held(), Some((77, graph.version)));
        let held = follower.graph().unwrap().unwrap();
        let ids: Vec<u32> = held.nodes().map(|n| n.id()).collect();
        assert_eq!(ids, graph.nodes.iter().map(|n| n.id).collect::<Vec<_>>());
        assert_eq!(held.edge_count(), graph.edges.len());
        assert_eq!(follower.apply(&full).unwrap(), Applied::Stale, "a full graph of the version held");
        if i == 0 {
            missed.apply(&full).unwrap();
        }
    }
    // Version 2 was lost on the way: version 3's delta asks for a full graph.
    assert_eq!(missed.apply(&delta).unwrap(), Applied::NeedFull);
    assert_eq!(missed.held(), None);
    assert_eq!(missed.apply(&full).unwrap(), Applied::Full);
    // A restarted daemon: its first full graph replaces the old instance's graph.
    let mut restarted = GraphEncoder::new(GraphCapacity::default(), 78);
    restarted.encode(&versions()[0]);
    encode_full(restarted.header(), restarted.payload(), 5, &mut full);
    assert_eq!(follower.apply(&full).unwrap(), Applied::Full);
    assert_eq!(follower.instances(), [77, 78]);
    let mut bad = full.clone();
    bad[4] = 9;
    assert!(follower.apply(&bad).unwrap_err().to_string().contains("format"));
}
