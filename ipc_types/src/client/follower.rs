//! [`RemoteFollower`]: a graph kept up to date from the daemon's Zenoh messages (full graphs and
//! deltas, `crate::remote`), whatever carried them.

use std::cmp::Ordering;

use super::{Graph, SnapshotError};
use crate::remote::{
    DELTA_COUNTS_BYTES, ENVELOPE_BYTES, Envelope, HEADER_BYTES, MessageKind, RemoteError, node_id, read_header, u32_at,
};
use crate::{EDGE_BYTES, GraphHeader, GraphMessage, NODE_BYTES};

/// What [`RemoteFollower::apply`] did with a message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Applied {
    /// A full graph replaced what was held.
    Full,
    /// A delta brought the graph one step on.
    Delta,
    /// A message older than the graph held (or a full graph of the same version): ignored.
    Stale,
    /// A delta that does not start at the version held (versions were lost) or from another
    /// instance (a restart): the graph held was dropped; a full graph is needed.
    NeedFull,
    /// A health record: its JSON.
    Health(String),
}

/// Keeps a graph up to date from full graphs and deltas (see the module's docs): node records
/// sorted by id (one per id), edge records sorted by their bytes (a multiset), the header of the
/// version held.
///
/// Sorted arrays rather than maps: a full graph is then one copy (and a sort of the edges), a
/// delta one merge, and [`Self::graph`] two copies; a map of 10,000 nodes and 20,000 edges cost
/// an allocation and a search per record on every full graph.
#[derive(Debug, Default)]
pub struct RemoteFollower {
    held: Option<(u64, GraphHeader)>,
    nodes: Vec<[u8; NODE_BYTES]>,
    edges: Vec<[u8; EDGE_BYTES]>,
    /// The merge's output, swapped with `nodes` / `edges` (buffers kept across messages).
    spare_nodes: Vec<[u8; NODE_BYTES]>,
    spare_edges: Vec<[u8; EDGE_BYTES]>,
    /// A delta's upserted nodes and its added and gone edges, sorted.
    upserted: Vec<[u8; NODE_BYTES]>,
    added: Vec<[u8; EDGE_BYTES]>,
    gone: Vec<[u8; EDGE_BYTES]>,
    removed: Vec<u32>,
    instances: Vec<u64>,
}

impl RemoteFollower {
    /// Nothing held yet.
    pub fn new() -> Self {
        Self::default()
    }

    /// `(instance_id, version)` of the graph held, `None` before the first full graph or after
    /// [`Applied::NeedFull`].
    pub fn held(&self) -> Option<(u64, u64)> {
        self.held.map(|(instance, header)| (instance, header.graph_version))
    }

    /// Daemon instances seen so far, in order (more than one: the daemon restarted).
    pub fn instances(&self) -> &[u64] {
        &self.instances
    }

    /// Applies one message.
    pub fn apply(&mut self, message: &[u8]) -> Result<Applied, RemoteError> {
        let envelope = Envelope::read(message)?;
        if envelope.kind == MessageKind::Occupancy {
            return Err(RemoteError::WrongKind { found: envelope.kind, expected: "a graph, a delta or health" });
        }
        if !self.instances.contains(&envelope.instance_id) {
            self.instances.push(envelope.instance_id);
        }
        if envelope.kind == MessageKind::Health {
            return Ok(Applied::Health(String::from_utf8_lossy(&message[ENVELOPE_BYTES..]).into_owned()));
        }
        let body = &message[ENVELOPE_BYTES..];
        let header_bytes: &[u8; HEADER_BYTES] = body
            .get(..HEADER_BYTES)
            .and_then(|b| b.try_into().ok())
            .ok_or(RemoteError::Length { len: message.len(), described: ENVELOPE_BYTES + HEADER_BYTES })?;
        let header = read_header(header_bytes);
        let body = &body[HEADER_BYTES..];
        let same_instance = self.held.is_some_and(|(instance, _)| instance == envelope.instance_id);
        let held_version = self.held.map(|(_, h)| h.graph_version);
        let stale = same_instance && held_version.is_some_and(|v| v >= envelope.version);
        if envelope.kind == MessageKind::Graph {
            if stale {
                return Ok(Applied::Stale);
            }
            self.full(envelope.instance_id, header, body, message.len())?;
            return Ok(Applied::Full);
        }
        if stale {
            return Ok(Applied::Stale);
        }
        if !same_instance || held_version != Some(envelope.base_version) {
            self.held = None;
            return Ok(Applied::NeedFull);
        }
        self.delta(envelope.version, header, body, message.len())?;
        Ok(Applied::Delta)
    }

    fn full(&mut self, instance: u64, header: GraphHeader, body: &[u8], len: usize) -> Result<(), RemoteError> {
        let nodes = header.node_count as usize * NODE_BYTES;
        let described = nodes + header.edge_count as usize * EDGE_BYTES;
        if body.len() != described {
            return Err(RemoteError::Length { len, described: described + len - body.len() });
        }
        let (node_bytes, edge_bytes) = body.split_at(nodes);
        self.nodes.clear();
        self.nodes.extend_from_slice(node_bytes.as_chunks::<NODE_BYTES>().0);
        one_per_id(&mut self.nodes);
        self.edges.clear();
        self.edges.extend_from_slice(edge_bytes.as_chunks::<EDGE_BYTES>().0);
        self.edges.sort_unstable_by(edge_order);
        self.held = Some((instance, header));
        Ok(())
    }

    fn delta(&mut self, version: u64, header: GraphHeader, body: &[u8], len: usize) -> Result<(), RemoteError> {
        let counts = body.get(..DELTA_COUNTS_BYTES).ok_or(RemoteError::Length { len, described: len + 1 })?;
        let [upserted, removed, added, gone] = [0, 4, 8, 12].map(|o| u32_at(counts, o) as usize);
        let sizes = [upserted * NODE_BYTES, added * EDGE_BYTES, gone * EDGE_BYTES, removed * 4];
        let described = DELTA_COUNTS_BYTES + sizes.iter().sum::<usize>();
        if body.len() != described {
            return Err(RemoteError::Length { len, described: described + len - body.len() });
        }
        let mut at = DELTA_COUNTS_BYTES;
        let mut part = |size: usize| {
            let part = &body[at..at + size];
            at += size;
            part
        };
        let (upserted, added, gone, removed) = (part(sizes[0]), part(sizes[1]), part(sizes[2]), part(sizes[3]));
        self.upserted.clear();
        self.upserted.extend_from_slice(upserted.as_chunks::<NODE_BYTES>().0);
        one_per_id(&mut self.upserted);
        self.removed.clear();
        self.removed.extend(removed.chunks_exact(4).map(|id| u32_at(id, 0)));
        self.removed.sort_unstable();
        for (records, bytes) in [(&mut self.added, added), (&mut self.gone, gone)] {
            records.clear();
            records.extend_from_slice(bytes.as_chunks::<EDGE_BYTES>().0);
            records.sort_unstable_by(edge_order);
        }
        // Nodes: the upserted records replace or join the held ones, then the removed ids go
        // (each must be held, or be upserted by this delta).
        let merged_nodes = merge_nodes(&self.nodes, &self.upserted, &self.removed, &mut self.spare_nodes);
        // Edges: the held multiset plus the added records, less the gone ones (each must be
        // there).
        let merged_edges = merge_edges(&self.edges, &self.added, &self.gone, &mut self.spare_edges);
        if !(merged_nodes && merged_edges) {
            return Err(self.inconsistent(version));
        }
        std::mem::swap(&mut self.nodes, &mut self.spare_nodes);
        std::mem::swap(&mut self.edges, &mut self.spare_edges);
        let edge_count = self.edges.len();
        if self.nodes.len() != header.node_count as usize || edge_count != header.edge_count as usize {
            return Err(self.inconsistent(version));
        }
        if let Some((_, held)) = self.held.as_mut() {
            *held = header;
        }
        Ok(())
    }

    /// Drops the graph held (a delta did not fit it): the next full graph starts again.
    fn inconsistent(&mut self, version: u64) -> RemoteError {
        self.held = None;
        RemoteError::Inconsistent(version)
    }

    /// The graph held, as the client library's [`Graph`] (checked against the wire contract);
    /// `None` when none is held. Nodes are sorted by id as on the wire; edges come in the order
    /// of their records' bytes, not the daemon's order.
    pub fn graph(&self) -> Option<Result<Graph, SnapshotError>> {
        let (_, header) = self.held?;
        let mut payload = Vec::with_capacity(header.payload_bytes());
        payload.extend_from_slice(self.nodes.as_flattened());
        payload.extend_from_slice(self.edges.as_flattened());
        Some(Graph::from_message(&GraphMessage::new(&header, &payload)))
    }
}

/// The order of edge records: their bytes', compared eight at a time (the first eight, source
/// and target id, mostly decide).
fn edge_order(a: &[u8; EDGE_BYTES], b: &[u8; EDGE_BYTES]) -> Ordering {
    let head = |r: &[u8; EDGE_BYTES]| u64::from_be_bytes([r[0], r[1], r[2], r[3], r[4], r[5], r[6], r[7]]);
    head(a).cmp(&head(b)).then_with(|| a.cmp(b))
}

/// Sorts node records by id and keeps one per id: the last of those sharing it (as inserting
/// them in order into a map by id would).
fn one_per_id(records: &mut Vec<[u8; NODE_BYTES]>) {
    if records.is_sorted_by(|a, b| node_id(a) < node_id(b)) {
        return;
    }
    records.sort_by_key(node_id);
    let mut kept = 0;
    for i in 0..records.len() {
        if i + 1 < records.len() && node_id(&records[i + 1]) == node_id(&records[i]) {
            continue;
        }
        records[kept] = records[i];
        kept += 1;
    }
    records.truncate(kept);
}

/// `held` (sorted by id, one per id) with `upserted` (the same) replacing or joining it, less
/// the ids of `removed` (sorted), into `out`; `false` when a removed id is in neither.
fn merge_nodes(
    held: &[[u8; NODE_BYTES]],
    upserted: &[[u8; NODE_BYTES]],
    removed: &[u32],
    out: &mut Vec<[u8; NODE_BYTES]>,
) -> bool {
    out.clear();
    out.reserve(held.len() + upserted.len());
    let (mut h, mut u) = (held.iter().peekable(), upserted.iter().peekable());
    let mut removed = removed.iter().peekable();
    loop {
        let record = match (h.peek(), u.peek()) {
            (None, None) => break,
            (Some(a), Some(b)) if node_id(a) == node_id(b) => {
                h.next();
                u.next().copied()
            }
            (Some(a), Some(b)) if node_id(a) < node_id(b) => h.next().copied(),
            (Some(_), None) => h.next().copied(),
            _ => u.next().copied(),
        };
        let Some(record) = record else { break };
        let id = node_id(&record);
        if removed.next_if(|&&r| r < id).is_some() {
            return false;
        }
        let mut gone = false;
        while removed.next_if(|&&r| r == id).is_some() {
            if gone {
                return false;
            }
            gone = true;
        }
        if !gone {
            out.push(record);
        }
    }
    removed.next().is_none()
}

/// The multiset `held` plus `added` less `gone` (all sorted by [`edge_order`]) into `out`;
/// `false` when a gone record is not there.
fn merge_edges(
    held: &[[u8; EDGE_BYTES]],
    added: &[[u8; EDGE_BYTES]],
    gone: &[[u8; EDGE_BYTES]],
    out: &mut Vec<[u8; EDGE_BYTES]>,
) -> bool {
    out.clear();
    out.reserve(held.len() + added.len());
    let (mut h, mut a) = (held.iter().peekable(), added.iter().peekable());
    let mut gone = gone.iter().peekable();
    loop {
        let record = match (h.peek(), a.peek()) {
            (None, None) => break,
            (Some(x), Some(y)) if edge_order(x, y) != Ordering::Greater => h.next(),
            (Some(_), None) => h.next(),
            _ => a.next(),
        };
        let Some(record) = record else { break };
        if gone.next_if(|g| edge_order(g, record) == Ordering::Less).is_some() {
            return false;
        }
        if gone.next_if(|g| *g == record).is_none() {
            out.push(*record);
        }
    }
    gone.next().is_none()
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;
    use crate::{MAX_EDGES, MAX_NODES, SCHEMA_VERSION};

    const INSTANCE: u64 = 5;

    fn node(id: u32, fill: u8) -> [u8; NODE_BYTES] {
        let mut r = [fill; NODE_BYTES];
        r[..4].copy_from_slice(&id.to_le_bytes());
        r[8] = 0; // kind: object
        r
    }

    fn edge(source: u32, target: u32, fill: u8) -> [u8; EDGE_BYTES] {
        let mut r = [fill; EDGE_BYTES];
        r[..4].copy_from_slice(&source.to_le_bytes());
        r[4..8].copy_from_slice(&target.to_le_bytes());
        (r[8], r[9]) = (0, 0); // kind spatial, origin 0
        r
    }

    fn header(version: u64, nodes: usize, edges: usize) -> GraphHeader {
        GraphHeader {
            schema_version: SCHEMA_VERSION,
            node_count: nodes as u32,
            edge_count: edges as u32,
            graph_version: version,
            instance_id: INSTANCE,
            node_capacity: MAX_NODES as u32,
            edge_capacity: MAX_EDGES as u32,
            ..GraphHeader::default()
        }
    }

    fn message(kind: MessageKind, version: u64, base: u64, h: &GraphHeader, body: &[u8]) -> Vec<u8> {
        let mut out = Vec::new();
        Envelope { kind, instance_id: INSTANCE, version, base_version: base, publish_time_ns: 0 }.append_to(&mut out);
        crate::remote::append_header(h, &mut out);
        out.extend_from_slice(body);
        out
    }

    /// What the follower must hold: nodes by id, edges as a multiset, in bytes order.
    #[derive(Default, Clone)]
    struct Model {
        nodes: BTreeMap<u32, [u8; NODE_BYTES]>,
        edges: BTreeMap<[u8; EDGE_BYTES], u32>,
    }

    impl Model {
        fn payload(&self) -> Vec<u8> {
            let mut p: Vec<u8> = self.nodes.values().flatten().copied().collect();
            for (r, &n) in &self.edges {
                for _ in 0..n {
                    p.extend_from_slice(r);
                }
            }
            p
        }
        fn edge_count(&self) -> usize {
            self.edges.values().sum::<u32>() as usize
        }
    }

    fn held_payload(f: &RemoteFollower) -> Vec<u8> {
        let g = f.graph().unwrap().unwrap();
        let mut p: Vec<u8> = bytemuck::cast_slice(g.wire_nodes()).to_vec();
        p.extend_from_slice(bytemuck::cast_slice(g.wire_edges()));
        p
    }

    #[test]
    fn full_graphs_and_deltas_give_the_records_a_map_by_id_and_a_multiset_would() {
        let mut model = Model::default();
        let mut body = Vec::new();
        for id in [3u32, 1, 7] {
            model.nodes.insert(id, node(id, id as u8));
            body.extend_from_slice(&node(id, id as u8));
        }
        let edges = [edge(7, 3, 1), edge(1, 3, 2), edge(7, 3, 1), edge(3, 1, 9)];
        for e in edges {
            *model.edges.entry(e).or_default() += 1;
            body.extend_from_slice(&e);
        }
        // Nodes out of id order, edges out of bytes order, one edge twice.
        let mut f = RemoteFollower::new();
        assert_eq!(f.apply(&message(MessageKind::Graph, 1, 0, &header(1, 3, 4), &body)), Ok(Applied::Full));
        assert_eq!(held_payload(&f), model.payload());

        // Deltas drawn from a fixed sequence: upserts (new, changed, an id twice: the last
        // wins), removals, edges added (duplicates too) and gone.
        let mut seed = 0x2545_f491_4f6c_dd1du64;
        let mut next = |n: u32| {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed % u64::from(n)) as u32
        };
        for version in 2..60u64 {
            let mut after = model.clone();
            let (mut upserted, mut removed, mut added, mut gone) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
            for _ in 0..next(6) {
                let id = next(40);
                let r = node(id, next(250) as u8);
                after.nodes.insert(id, r);
                upserted.push(r);
            }
            let held: Vec<u32> = after.nodes.keys().copied().collect();
            for _ in 0..next(3) {
                let id = held[next(held.len() as u32) as usize];
                if !removed.contains(&id) {
                    removed.push(id);
                    after.nodes.remove(&id);
                }
            }
            for _ in 0..next(6) {
                let e = edge(next(40), next(40), next(3) as u8);
                *after.edges.entry(e).or_default() += 1;
                added.push(e);
            }
            let present: Vec<[u8; EDGE_BYTES]> = after.edges.keys().copied().collect();
            for _ in 0..next(4) {
                let e = present[next(present.len() as u32) as usize];
                if let Some(n) = after.edges.get_mut(&e) {
                    *n -= 1;
                    if *n == 0 {
                        after.edges.remove(&e);
                    }
                    gone.push(e);
                }
            }
            let mut body = Vec::new();
            for v in [upserted.len(), removed.len(), added.len(), gone.len()] {
                body.extend_from_slice(&(v as u32).to_le_bytes());
            }
            body.extend(upserted.iter().flatten());
            body.extend(added.iter().flatten());
            body.extend(gone.iter().flatten());
            body.extend(removed.iter().flat_map(|id| id.to_le_bytes()));
            let h = header(version, after.nodes.len(), after.edge_count());
            let applied = f.apply(&message(MessageKind::Delta, version, version - 1, &h, &body));
            assert_eq!(applied, Ok(Applied::Delta), "version {version}");
            model = after;
            assert_eq!(held_payload(&f), model.payload(), "version {version}");
        }
    }

    #[test]
    fn a_delta_that_removes_what_is_not_held_drops_the_graph() {
        let body: Vec<u8> = [node(1, 0), node(2, 0)].iter().flatten().copied().chain(edge(1, 2, 0)).collect();
        let full = message(MessageKind::Graph, 1, 0, &header(1, 2, 1), &body);
        let delta = |counts: [u32; 4], tail: &[u8], nodes: usize, edges: usize| {
            let mut b: Vec<u8> = counts.iter().flat_map(|c| c.to_le_bytes()).collect();
            b.extend_from_slice(tail);
            message(MessageKind::Delta, 2, 1, &header(2, nodes, edges), &b)
        };
        for bad in [
            delta([0, 1, 0, 0], &9u32.to_le_bytes(), 1, 1),       // node 9 is not held
            delta([0, 0, 0, 1], &edge(2, 1, 0), 2, 0),            // nor is this edge
            delta([0, 2, 0, 0], &[1, 0, 0, 0, 1, 0, 0, 0], 1, 1), // node 1 twice
        ] {
            let mut f = RemoteFollower::new();
            f.apply(&full).unwrap();
            assert_eq!(f.apply(&bad), Err(RemoteError::Inconsistent(2)));
            assert_eq!(f.held(), None);
        }
        let mut f = RemoteFollower::new();
        f.apply(&full).unwrap();
        assert_eq!(
            f.apply(&delta([0, 1, 0, 1], &[edge(1, 2, 0).as_slice(), &2u32.to_le_bytes()].concat(), 1, 0)),
            Ok(Applied::Delta)
        );
        assert_eq!(held_payload(&f), node(1, 0).to_vec());
    }
}
