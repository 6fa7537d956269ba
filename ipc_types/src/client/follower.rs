//! [`RemoteFollower`]: a graph kept up to date from the daemon's Zenoh messages (full graphs and
//! deltas, `crate::remote`), whatever carried them.

use std::collections::BTreeMap;

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
/// by id, edge records as a multiset, the header of the version held.
#[derive(Debug, Default)]
pub struct RemoteFollower {
    held: Option<(u64, GraphHeader)>,
    nodes: BTreeMap<u32, [u8; NODE_BYTES]>,
    edges: BTreeMap<[u8; EDGE_BYTES], u32>,
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
        self.edges.clear();
        for record in node_bytes.as_chunks::<NODE_BYTES>().0 {
            self.nodes.insert(node_id(record), *record);
        }
        for record in edge_bytes.as_chunks::<EDGE_BYTES>().0 {
            *self.edges.entry(*record).or_default() += 1;
        }
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
        for record in upserted.as_chunks::<NODE_BYTES>().0 {
            self.nodes.insert(node_id(record), *record);
        }
        for record in added.as_chunks::<EDGE_BYTES>().0 {
            *self.edges.entry(*record).or_default() += 1;
        }
        for record in gone.as_chunks::<EDGE_BYTES>().0 {
            match self.edges.get_mut(record) {
                Some(1) => {
                    self.edges.remove(record);
                }
                Some(count) => *count -= 1,
                None => return Err(self.inconsistent(version)),
            }
        }
        for id in removed.chunks_exact(4) {
            if self.nodes.remove(&u32_at(id, 0)).is_none() {
                return Err(self.inconsistent(version));
            }
        }
        let edge_count: u32 = self.edges.values().sum();
        if self.nodes.len() != header.node_count as usize || edge_count != header.edge_count {
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
        for record in self.nodes.values() {
            payload.extend_from_slice(record);
        }
        for (record, &count) in &self.edges {
            for _ in 0..count {
                payload.extend_from_slice(record);
            }
        }
        Some(Graph::from_message(&GraphMessage::new(&header, &payload)))
    }
}
