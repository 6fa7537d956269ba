//! The owned graph a client reads: [`Graph`], copied out of one graph sample ([`GraphMessage`])
//! into reused buffers, with its lookup indices and the typed read-only views [`NodeView`] and
//! [`EdgeView`].

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};
use std::sync::{Mutex, OnceLock, PoisonError};

use crate::client::accessors::{contains_ignore_ascii_case, edge_record_accessors, node_record_accessors};
use crate::client::{GraphView, SnapshotError, check_message};
use crate::{AFFORDANCES, Edge, GraphHeader, GraphMessage, NO_NODE, Node, NodeKind, affordance_bits};

/// A hasher for node ids (u32): one multiply, as rustc's FxHash does. Ids come from the daemon,
/// not from an adversary, so no DoS-resistant hashing is needed on this per-graph path.
#[derive(Default, Clone, Copy)]
struct IdHasher(u64);

impl Hasher for IdHasher {
    fn finish(&self) -> u64 {
        self.0
    }
    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 = (self.0.rotate_left(5) ^ u64::from(b)).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
        }
    }
    fn write_u32(&mut self, id: u32) {
        self.0 = (self.0.rotate_left(5) ^ u64::from(id)).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

type IdMap = HashMap<u32, u32, BuildHasherDefault<IdHasher>>;

/// Node id → index in the graph. The daemon hands out ids from a counter, so they are usually
/// dense: then a table indexed by id (one load per lookup), else a hash map.
#[derive(Clone, Default)]
struct IdIndex {
    /// `dense[id]` is the index of node `id`, or [`NO_INDEX`]; empty when `sparse` is used.
    dense: Vec<u32>,
    sparse: IdMap,
}

impl IdIndex {
    /// A table is used while it is at most this many times longer than the node list (plus a
    /// small allowance), so its size stays proportional to the graph.
    const DENSE_FACTOR: usize = 4;
    const DENSE_SLACK: usize = 1024;

    fn rebuild(&mut self, nodes: &[Node]) {
        self.dense.clear();
        self.sparse.clear();
        let max_id = nodes.iter().map(|n| n.id).filter(|&id| id != NO_NODE).max();
        let dense_len = max_id.map_or(0, |id| id as usize + 1);
        if dense_len <= nodes.len() * Self::DENSE_FACTOR + Self::DENSE_SLACK {
            self.dense.resize(dense_len, NO_INDEX);
            for (i, node) in nodes.iter().enumerate() {
                if let Some(slot) = self.dense.get_mut(node.id as usize) {
                    *slot = i as u32;
                }
            }
        } else {
            self.sparse.reserve(nodes.len());
            for (i, node) in nodes.iter().enumerate() {
                self.sparse.insert(node.id, i as u32);
            }
        }
    }

    fn get(&self, id: u32) -> Option<u32> {
        if self.sparse.is_empty() {
            self.dense.get(id as usize).copied().filter(|&i| i != NO_INDEX)
        } else {
            self.sparse.get(&id).copied()
        }
    }
}

/// Index meaning "no node" in the per-edge and per-node index arrays.
const NO_INDEX: u32 = u32::MAX;

/// An affordance name that is not one of [`AFFORDANCES`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnknownAffordance;

impl core::fmt::Display for UnknownAffordance {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "unknown affordance (canonical: {})", AFFORDANCES.join(", "))
    }
}

impl std::error::Error for UnknownAffordance {}

/// One version of the scene graph, owned by the client: the header, the nodes and edges
/// copied out of one graph sample ([`GraphMessage`]), and lookup indices (id → node, node →
/// parent and parts, node → outgoing and incoming edges).
///
/// [`Graph::copy_from`] copies the records only (one block copy each for nodes and edges on
/// little-endian machines); the indices are built once per graph, on the first lookup that
/// needs them ([`Self::node`], [`Self::parts_of`], [`NodeView::parent`], [`EdgeView::source`],
/// ...), so a planner that only scans the nodes never pays for them.
/// Every buffer is reused, so once a graph of a given size has been copied and indexed, copying
/// and indexing another of at most that size allocates nothing.
#[derive(Default)]
pub struct Graph {
    header: GraphHeader,
    nodes: Vec<Node>,
    edges: Vec<Edge>,
    /// The previous graph held came from another daemon instance (see [`Self::restarted`]).
    restarted: bool,
    /// Built on first use for the graph held now.
    indices: OnceLock<Indices>,
    /// The buffers of the previous graph's indices, reused by the next build.
    spare: Mutex<Indices>,
}

impl Clone for Graph {
    fn clone(&self) -> Self {
        Self {
            header: self.header,
            nodes: self.nodes.clone(),
            edges: self.edges.clone(),
            restarted: self.restarted,
            indices: self.indices.clone(),
            spare: Mutex::default(),
        }
    }
}

/// The lookup indices of one graph.
#[derive(Clone, Default)]
struct Indices {
    index_of_id: IdIndex,
    /// Per node: index of its parent node, or [`NO_INDEX`].
    parent_index: Vec<u32>,
    /// Per edge: index of its source / target node, or [`NO_INDEX`] when not in the graph.
    source_index: Vec<u32>,
    target_index: Vec<u32>,
    /// Compressed adjacency: the items of node `i` are `items[start[i]..start[i + 1]]`.
    parts: Adjacency,
    outgoing: Adjacency,
    incoming: Adjacency,
    /// Scratch space of [`Adjacency::rebuild`].
    cursor: Vec<u32>,
}

impl Indices {
    fn rebuild(&mut self, nodes: &[Node], edges: &[Edge]) {
        let Self { index_of_id, parent_index, source_index, target_index, parts, outgoing, incoming, cursor } = self;
        index_of_id.rebuild(nodes);
        let index = |id: u32| if id == NO_NODE { NO_INDEX } else { index_of_id.get(id).unwrap_or(NO_INDEX) };
        parent_index.clear();
        parent_index.extend(nodes.iter().map(|n| index(n.parent_id)));
        source_index.clear();
        source_index.extend(edges.iter().map(|e| index(e.source_id)));
        target_index.clear();
        target_index.extend(edges.iter().map(|e| index(e.target_id)));
        let node_count = nodes.len();
        parts.rebuild(node_count, parent_index, cursor);
        outgoing.rebuild(node_count, source_index, cursor);
        incoming.rebuild(node_count, target_index, cursor);
    }
}

#[derive(Clone, Default)]
struct Adjacency {
    start: Vec<u32>,
    items: Vec<u32>,
}

impl Adjacency {
    /// Counting sort of `(bucket, item)` pairs into `node_count` buckets; items keep their order
    /// within a bucket. Pairs whose bucket is [`NO_INDEX`] are left out.
    fn rebuild(&mut self, node_count: usize, buckets: &[u32], cursor: &mut Vec<u32>) {
        self.start.clear();
        self.start.resize(node_count + 1, 0);
        for &bucket in buckets.iter().filter(|b| **b != NO_INDEX) {
            self.start[bucket as usize + 1] += 1;
        }
        for i in 0..node_count {
            self.start[i + 1] += self.start[i];
        }
        self.items.clear();
        self.items.resize(self.start[node_count] as usize, 0);
        cursor.clear();
        cursor.extend_from_slice(&self.start[..node_count]);
        for (item, &bucket) in buckets.iter().enumerate().filter(|(_, b)| **b != NO_INDEX) {
            let slot = &mut cursor[bucket as usize];
            self.items[*slot as usize] = item as u32;
            *slot += 1;
        }
    }

    fn of(&self, index: u32) -> &[u32] {
        let i = index as usize;
        match (self.start.get(i), self.start.get(i + 1)) {
            (Some(&a), Some(&b)) => &self.items[a as usize..b as usize],
            _ => &[],
        }
    }
}

impl TryFrom<&GraphView<'_>> for Graph {
    type Error = SnapshotError;

    /// An owned copy of the sample the view reads, its records checked ([`GraphView::to_graph`]).
    fn try_from(view: &GraphView<'_>) -> Result<Self, SnapshotError> {
        let mut graph = Self::new();
        graph.copy_from_view(view)?;
        graph.restarted = view.restarted();
        Ok(graph)
    }
}

impl core::fmt::Debug for Graph {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Graph")
            .field("instance_id", &self.instance_id())
            .field("version", &self.version())
            .field("stamp_ns", &self.stamp_ns())
            .field("nodes", &self.nodes.len())
            .field("edges", &self.edges.len())
            .field("capacity_exceeded", &self.capacity_exceeded())
            .finish()
    }
}

impl Graph {
    /// An empty graph (version 0).
    pub fn new() -> Self {
        Self::default()
    }

    /// A graph copied out of `message` (see [`Self::copy_from`]).
    pub fn from_message(message: &GraphMessage<'_>) -> Result<Self, SnapshotError> {
        let mut graph = Self::new();
        graph.copy_from(message)?;
        Ok(graph)
    }

    /// Replaces this graph with the nodes and edges of `message` and rebuilds the indices,
    /// reusing the buffers. The message is checked first ([`check_message`]); on error the graph
    /// is left as it was.
    pub fn copy_from(&mut self, message: &GraphMessage<'_>) -> Result<(), SnapshotError> {
        check_message(message)?;
        let previous_instance = self.header.instance_id;
        self.header = *message.header;
        self.restarted = previous_instance != 0 && previous_instance != self.header.instance_id;
        message.copy_nodes_into(&mut self.nodes);
        message.copy_edges_into(&mut self.edges);
        if let Some(old) = self.indices.take() {
            *self.spare.get_mut().unwrap_or_else(PoisonError::into_inner) = old;
        }
        Ok(())
    }

    /// Replaces this graph with a copy of `view`'s nodes and edges, reusing the buffers: one
    /// block copy each for nodes and edges. For a planner that reads samples through
    /// [`GraphSubscriber::with_latest`](crate::GraphSubscriber::with_latest) and keeps some of
    /// them. The records are checked first ([`GraphView::check_records`]); on error the graph is
    /// left as it was.
    pub fn copy_from_view(&mut self, view: &GraphView<'_>) -> Result<(), SnapshotError> {
        view.check_records()?;
        let previous_instance = self.header.instance_id;
        self.header = *view.header();
        self.restarted = previous_instance != 0 && previous_instance != self.header.instance_id;
        self.nodes.clear();
        self.nodes.extend_from_slice(view.wire_nodes());
        self.edges.clear();
        self.edges.extend_from_slice(view.wire_edges());
        if let Some(old) = self.indices.take() {
            *self.spare.get_mut().unwrap_or_else(PoisonError::into_inner) = old;
        }
        Ok(())
    }

    /// The indices of the graph held now, built on first use (reusing the previous graph's
    /// buffers).
    fn indices(&self) -> &Indices {
        self.indices.get_or_init(|| {
            let mut indices = std::mem::take(&mut *self.spare.lock().unwrap_or_else(PoisonError::into_inner));
            indices.rebuild(&self.nodes, &self.edges);
            indices
        })
    }

    /// Graph version: increases by one with every published change while one daemon instance
    /// runs (0 for an empty graph); compare versions only between graphs of the same
    /// [`Self::instance_id`].
    pub fn version(&self) -> u64 {
        self.header.graph_version
    }

    /// The daemon instance that published this graph: drawn anew (never 0) each time the daemon
    /// starts, so a different value than before means the daemon restarted and its versions and
    /// node ids started again (0 for an empty graph).
    pub fn instance_id(&self) -> u64 {
        self.header.instance_id
    }

    /// `true` when the graph this one replaced (in the last [`Self::copy_from`]) came from
    /// another daemon instance: the daemon restarted in between, so version bookkeeping and
    /// cached node ids of the old instance no longer apply.
    pub fn restarted(&self) -> bool {
        self.restarted
    }

    /// Stamp of the newest keyframe fused into this version, nanoseconds.
    pub fn stamp_ns(&self) -> u64 {
        self.header.stamp_ns
    }

    /// Wall-clock time the daemon wrote the sample, nanoseconds since the Unix epoch.
    pub fn publish_time_ns(&self) -> u64 {
        self.header.publish_time_ns
    }

    /// `true` when the daemon's map had more nodes or edges than a sample holds: this graph is
    /// then the most recently seen part of it (see [`GraphHeader::capacity_exceeded`]).
    pub fn capacity_exceeded(&self) -> bool {
        self.header.capacity_exceeded != 0
    }

    /// What the daemon reads its frames from: a live camera, a replay or the synthetic rooms
    /// ([`SourceKind`](crate::SourceKind); `Unknown` from a publisher that does not say).
    pub fn source_kind(&self) -> crate::SourceKind {
        self.header.source_kind()
    }

    /// Name of the frame every coordinate of this graph is in (the daemon's `world.frame_id`:
    /// `world` by default, `map` on the Stretch profile).
    pub fn world_frame(&self) -> &str {
        self.header.world_frame_str()
    }

    /// The header as received (counts, totals beyond capacity, publish time).
    pub fn header(&self) -> &GraphHeader {
        &self.header
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Number of edges.
    pub fn edge_count(&self) -> usize {
        self.edges.len()
    }

    /// The nodes as on the wire, sorted by id.
    pub fn wire_nodes(&self) -> &[Node] {
        &self.nodes
    }

    /// The edges as on the wire.
    pub fn wire_edges(&self) -> &[Edge] {
        &self.edges
    }

    /// Every node, in wire order (sorted by id).
    pub fn nodes(&self) -> impl ExactSizeIterator<Item = NodeView<'_>> {
        (0..self.nodes.len() as u32).map(|index| NodeView { graph: self, index })
    }

    /// The object nodes.
    pub fn objects(&self) -> impl Iterator<Item = NodeView<'_>> {
        self.nodes().filter(|n| n.kind() == NodeKind::Object)
    }

    /// The part nodes.
    pub fn parts(&self) -> impl Iterator<Item = NodeView<'_>> {
        self.nodes().filter(|n| n.kind() == NodeKind::Part)
    }

    /// Every edge, in wire order.
    pub fn edges(&self) -> impl ExactSizeIterator<Item = EdgeView<'_>> {
        (0..self.edges.len() as u32).map(|index| EdgeView { graph: self, index })
    }

    /// The node with this id.
    pub fn node(&self, id: u32) -> Option<NodeView<'_>> {
        self.indices().index_of_id.get(id).map(|index| NodeView { graph: self, index })
    }

    /// The parts whose parent is `object_id` (empty for an unknown id).
    pub fn parts_of(&self, object_id: u32) -> impl Iterator<Item = NodeView<'_>> {
        self.related(object_id, |ix| &ix.parts).map(|index| NodeView { graph: self, index })
    }

    /// The parent object of the part `part_id` (`None` for objects, unattached parts and unknown
    /// ids).
    pub fn parent_of(&self, part_id: u32) -> Option<NodeView<'_>> {
        self.node(part_id).and_then(|n| n.parent())
    }

    /// The edges whose source is `id`.
    pub fn edges_from(&self, id: u32) -> impl Iterator<Item = EdgeView<'_>> {
        self.related(id, |ix| &ix.outgoing).map(|index| EdgeView { graph: self, index })
    }

    /// The edges whose target is `id`.
    pub fn edges_to(&self, id: u32) -> impl Iterator<Item = EdgeView<'_>> {
        self.related(id, |ix| &ix.incoming).map(|index| EdgeView { graph: self, index })
    }

    /// The nodes labelled exactly `label`.
    pub fn find_by_label<'a>(&'a self, label: &'a str) -> impl Iterator<Item = NodeView<'a>> {
        self.nodes().filter(move |n| n.label() == label)
    }

    /// The nodes whose label contains `text`, ASCII letters compared without case
    /// (`"handle"` finds "Cabinet Handle" and "drawer handle").
    pub fn find_by_label_containing<'a>(&'a self, text: &'a str) -> impl Iterator<Item = NodeView<'a>> {
        self.nodes().filter(move |n| contains_ignore_ascii_case(n.label(), text))
    }

    /// The nodes that afford `name` (one of [`AFFORDANCES`]).
    pub fn find_by_affordance(&self, name: &str) -> Result<impl Iterator<Item = NodeView<'_>>, UnknownAffordance> {
        let bits = affordance_bits([name]).map_err(|_| UnknownAffordance)?;
        Ok(self.find_by_affordance_bits(bits))
    }

    /// The nodes that afford every affordance in `bits` (a set over [`AFFORDANCES`], see
    /// [`affordance_bits`]).
    pub fn find_by_affordance_bits(&self, bits: u16) -> impl Iterator<Item = NodeView<'_>> {
        self.nodes().filter(move |n| n.affordance_bits() & bits == bits)
    }

    fn related(&self, id: u32, adjacency: impl Fn(&Indices) -> &Adjacency) -> impl Iterator<Item = u32> + '_ {
        let indices = self.indices();
        let items = indices.index_of_id.get(id).map(|i| adjacency(indices).of(i)).unwrap_or(&[]);
        items.iter().copied()
    }
}

/// One node of a [`Graph`], with typed accessors.
#[derive(Clone, Copy)]
pub struct NodeView<'a> {
    graph: &'a Graph,
    index: u32,
}

impl core::fmt::Debug for NodeView<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("NodeView")
            .field("id", &self.id())
            .field("kind", &self.kind())
            .field("label", &self.label())
            .field("parent_id", &self.parent_id())
            .finish()
    }
}

impl<'a> NodeView<'a> {
    /// The node as on the wire.
    pub fn wire(&self) -> &'a Node {
        &self.graph.nodes[self.index as usize]
    }

    node_record_accessors!('a);

    /// The parent object of a part, when it is in this graph.
    pub fn parent(&self) -> Option<NodeView<'a>> {
        let index = self.graph.indices().parent_index[self.index as usize];
        (index != NO_INDEX).then_some(NodeView { graph: self.graph, index })
    }

    /// The parts attached to this node.
    pub fn parts(&self) -> impl Iterator<Item = NodeView<'a>> + use<'a> {
        let graph = self.graph;
        graph.indices().parts.of(self.index).iter().map(move |&index| NodeView { graph, index })
    }

    /// The edges whose source is this node.
    pub fn edges_from(&self) -> impl Iterator<Item = EdgeView<'a>> + use<'a> {
        let graph = self.graph;
        graph.indices().outgoing.of(self.index).iter().map(move |&index| EdgeView { graph, index })
    }

    /// The edges whose target is this node.
    pub fn edges_to(&self) -> impl Iterator<Item = EdgeView<'a>> + use<'a> {
        let graph = self.graph;
        graph.indices().incoming.of(self.index).iter().map(move |&index| EdgeView { graph, index })
    }
}

/// One directed edge of a [`Graph`]: `source` relates to `target` as [`Self::phrase`] says.
#[derive(Clone, Copy)]
pub struct EdgeView<'a> {
    graph: &'a Graph,
    index: u32,
}

impl core::fmt::Debug for EdgeView<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("EdgeView")
            .field("source_id", &self.source_id())
            .field("phrase", &self.phrase())
            .field("target_id", &self.target_id())
            .field("origin", &self.origin())
            .finish()
    }
}

impl<'a> EdgeView<'a> {
    /// The edge as on the wire.
    pub fn wire(&self) -> &'a Edge {
        &self.graph.edges[self.index as usize]
    }

    /// The source node, when it is in this graph.
    pub fn source(&self) -> Option<NodeView<'a>> {
        let index = self.graph.indices().source_index[self.index as usize];
        (index != NO_INDEX).then_some(NodeView { graph: self.graph, index })
    }

    /// The target node, when it is in this graph.
    pub fn target(&self) -> Option<NodeView<'a>> {
        let index = self.graph.indices().target_index[self.index as usize];
        (index != NO_INDEX).then_some(NodeView { graph: self.graph, index })
    }

    edge_record_accessors!('a);
}

#[cfg(test)]
mod tests;
