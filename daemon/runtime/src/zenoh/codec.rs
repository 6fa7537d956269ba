//! The bytes of every Zenoh message: a fixed envelope, then the body — a full graph (the
//! iceoryx2 graph sample's header and records, unchanged), a delta against an earlier version,
//! the health record as JSON, or the occupancy map (the iceoryx2 sample's header and cells).
//! Little-endian throughout; `docs/remote.md` lays it out field by field for readers in other
//! languages; the constants, the envelope and the header's bytes are
//! the client library's (`op3dsg_ipc_types::remote`).

use op3dsg_ipc_types::{EDGE_BYTES, GraphHeader, NODE_BYTES};

// The format itself belongs to the client library (its `RemoteFollower` reads it back).
pub use op3dsg_ipc_types::remote::{
    DELTA_COUNTS_BYTES, ENVELOPE_BYTES, Envelope, FORMAT_VERSION, HEADER_BYTES, MAGIC, MessageKind,
    OCCUPANCY_HEADER_BYTES, append_header, encode_occupancy, node_id, read_header, read_occupancy,
};

/// A full graph message: envelope, header, then the sample's payload (nodes sorted by id, then
/// edges), into `out` (cleared first).
pub fn encode_full(header: &GraphHeader, payload: &[u8], publish_time_ns: u64, out: &mut Vec<u8>) {
    out.clear();
    Envelope {
        kind: MessageKind::Graph,
        instance_id: header.instance_id,
        version: header.graph_version,
        base_version: 0,
        publish_time_ns,
    }
    .append_to(out);
    append_header(header, out);
    out.extend_from_slice(payload);
}

/// A health message: envelope and the health report's JSON, into `out` (cleared first).
pub fn encode_health(instance_id: u64, graph_version: u64, publish_time_ns: u64, json: &[u8], out: &mut Vec<u8>) {
    out.clear();
    Envelope { kind: MessageKind::Health, instance_id, version: graph_version, base_version: 0, publish_time_ns }
        .append_to(out);
    out.extend_from_slice(json);
}

/// What one delta holds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct DeltaCounts {
    /// Nodes new or changed (any byte of the record), whole records.
    pub nodes_upserted: u32,
    /// Nodes gone, by id.
    pub nodes_removed: u32,
    /// Edge records new in this version.
    pub edges_added: u32,
    /// Edge records of the base version gone in this one.
    pub edges_removed: u32,
}

/// Keeps the records of the last version it saw and writes the delta from it to the next.
///
/// A node is its id: a record whose bytes differ from the base's is sent whole, a missing id is
/// sent as removed. An edge is its whole record: a changed edge (its confidence, its origin) is
/// the old record removed and the new one added, which also keeps two edges between the same
/// nodes apart.
#[derive(Debug, Default)]
pub struct DeltaEncoder {
    base: Option<(u64, u64)>,
    nodes: Vec<[u8; NODE_BYTES]>,
    edges: Vec<[u8; EDGE_BYTES]>,
    new_edges: Vec<[u8; EDGE_BYTES]>,
}

impl DeltaEncoder {
    /// Remembers this version (header and payload, as [`encode_full`] takes them) and, when the
    /// last one came from the same instance, writes the delta from it into `out` (cleared first)
    /// and returns its counts. `None` (and `out` empty) for the first version of an instance.
    pub fn next(
        &mut self,
        header: &GraphHeader,
        payload: &[u8],
        publish_time_ns: u64,
        out: &mut Vec<u8>,
    ) -> Option<DeltaCounts> {
        out.clear();
        let split = (header.node_count as usize * NODE_BYTES).min(payload.len());
        let (node_bytes, edge_bytes) = payload.split_at(split);
        let nodes = node_bytes.as_chunks::<NODE_BYTES>().0;
        self.new_edges.clear();
        self.new_edges.extend_from_slice(edge_bytes.as_chunks::<EDGE_BYTES>().0);
        self.new_edges.sort_unstable();
        let base = self.base.filter(|&(instance, _)| instance == header.instance_id);
        let counts = base.map(|(_, base_version)| {
            Envelope {
                kind: MessageKind::Delta,
                instance_id: header.instance_id,
                version: header.graph_version,
                base_version,
                publish_time_ns,
            }
            .append_to(out);
            append_header(header, out);
            let counts_at = out.len();
            out.resize(counts_at + DELTA_COUNTS_BYTES, 0);
            let mut counts = DeltaCounts::default();
            let removed = self.write_nodes(nodes, out, &mut counts);
            counts.edges_added = write_only_in(&self.new_edges, &self.edges, out);
            counts.edges_removed = write_only_in(&self.edges, &self.new_edges, out);
            for id in removed {
                out.extend_from_slice(&id.to_le_bytes());
            }
            let fields = [counts.nodes_upserted, counts.nodes_removed, counts.edges_added, counts.edges_removed];
            for (i, v) in fields.into_iter().enumerate() {
                out[counts_at + 4 * i..counts_at + 4 * i + 4].copy_from_slice(&v.to_le_bytes());
            }
            counts
        });
        self.base = Some((header.instance_id, header.graph_version));
        self.nodes.clear();
        self.nodes.extend_from_slice(nodes);
        std::mem::swap(&mut self.edges, &mut self.new_edges);
        counts
    }

    /// Appends the new and changed node records (both lists are sorted by id); returns the ids
    /// of the base's nodes that are gone.
    fn write_nodes(&self, nodes: &[[u8; NODE_BYTES]], out: &mut Vec<u8>, counts: &mut DeltaCounts) -> Vec<u32> {
        let mut removed = Vec::new();
        let mut old = self.nodes.iter().peekable();
        for record in nodes {
            let id = node_id(record);
            while let Some(gone) = old.next_if(|o| node_id(o) < id) {
                removed.push(node_id(gone));
            }
            let unchanged = old.next_if(|o| node_id(o) == id).is_some_and(|o| o == record);
            if !unchanged {
                out.extend_from_slice(record);
                counts.nodes_upserted += 1;
            }
        }
        removed.extend(old.map(node_id));
        counts.nodes_removed = removed.len() as u32;
        removed
    }
}

/// Appends the records of `a` that `b` lacks (both sorted; as multisets); returns how many.
fn write_only_in(a: &[[u8; EDGE_BYTES]], b: &[[u8; EDGE_BYTES]], out: &mut Vec<u8>) -> u32 {
    let mut written = 0;
    let mut other = b.iter().peekable();
    for record in a {
        while other.next_if(|o| *o < record).is_some() {}
        if other.next_if(|o| *o == record).is_none() {
            out.extend_from_slice(record);
            written += 1;
        }
    }
    written
}
