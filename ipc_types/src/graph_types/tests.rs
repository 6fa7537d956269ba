use super::*;

fn node(seed: u32) -> Node {
    let f = |k: u32| (seed * 31 + k) as f32 * 0.125 - 3.0;
    let mut label = [0u8; LABEL_CAPACITY_BYTES];
    crate::write_fixed_str(&mut label, "stove knob");
    Node {
        id: seed,
        parent_id: seed.wrapping_add(7),
        kind: (seed % 2) as u8,
        reserved: 1,
        affordance_knowledge_bits: 0x1ff & (seed as u16 * 11),
        observation_count: seed * 3 + 1,
        label,
        confidence: f(1),
        centre_m: [f(2), f(3), f(4)],
        box_min_m: [f(5), f(6), f(7)],
        box_max_m: [f(8), f(9), f(10)],
        affordance_bits: 0x1ff & (seed as u16 * 37),
        affordance_llm_bits: 0x1ff & (seed as u16 * 13),
        obb_yaw_rad: f(11),
        last_seen_stamp_ns: u64::from(seed) * 1_000_000_007 + 0x0102_0304_0506_0708,
        obb_centre_m: [f(12), f(13), f(14)],
        obb_size_m: [f(15), f(16), f(17)],
    }
}

fn edge(seed: u32) -> Edge {
    let mut phrase = [0u8; PHRASE_CAPACITY_BYTES];
    crate::write_fixed_str(&mut phrase, "rotate to adjust the setting");
    Edge {
        source_id: seed,
        target_id: seed ^ 0xa5a5,
        kind: (seed % 2) as u8,
        origin: (seed % 4) as u8,
        relation_id: (seed % 300) as u16,
        confidence: seed as f32 / 7.0,
        phrase,
    }
}

/// The block copies of little-endian machines and the field-by-field form agree byte for
/// byte, both ways.
#[test]
fn block_and_field_encodings_agree() {
    for seed in [0, 1, 2, 977, 65_537] {
        let n = node(seed);
        let (mut block, mut fields) = ([0u8; NODE_BYTES], [0u8; NODE_BYTES]);
        n.write_bytes(&mut block);
        n.write_fields(&mut fields);
        assert_eq!(block, fields);
        assert_eq!(bytemuck::bytes_of(&Node::from_bytes(&fields)), bytemuck::bytes_of(&Node::from_fields(&block)));
        let e = edge(seed);
        let (mut block, mut fields) = ([0u8; EDGE_BYTES], [0u8; EDGE_BYTES]);
        e.write_bytes(&mut block);
        e.write_fields(&mut fields);
        assert_eq!(block, fields);
        assert_eq!(bytemuck::bytes_of(&Edge::from_bytes(&fields)), bytemuck::bytes_of(&Edge::from_fields(&block)));
    }
}

/// `copy_nodes_into` / `copy_edges_into` decode what was written, shrinking and growing the
/// reused buffer.
#[test]
fn bulk_copies_decode_every_record() {
    let nodes: Vec<Node> = (0..50).map(node).collect();
    let edges: Vec<Edge> = (0..90).map(edge).collect();
    let mut payload = Vec::new();
    nodes.iter().for_each(|n| n.append_bytes(&mut payload));
    edges.iter().for_each(|e| e.append_bytes(&mut payload));
    let header = GraphHeader { node_count: 50, edge_count: 90, ..GraphHeader::default() };
    let message = GraphMessage::new(&header, &payload);
    let (mut out_nodes, mut out_edges) = (vec![node(999); 70], Vec::new());
    for _ in 0..2 {
        message.copy_nodes_into(&mut out_nodes);
        message.copy_edges_into(&mut out_edges);
        assert_eq!(bytemuck::cast_slice::<Node, u8>(&out_nodes), bytemuck::cast_slice::<Node, u8>(&nodes));
        assert_eq!(bytemuck::cast_slice::<Edge, u8>(&out_edges), bytemuck::cast_slice::<Edge, u8>(&edges));
        out_nodes.truncate(10);
    }
}
