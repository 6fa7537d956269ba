//! [`GraphView`]: one graph sample read where it lies (in the daemon's shared memory, or any
//! byte block), with typed records ([`NodeRef`], [`EdgeRef`]) and the lookups of the owned
//! [`Graph`] that need no index.
//!
//! The sample's payload is cast to `&[Node]` and `&[Edge]` (`bytemuck`, no copy) after one
//! constant-time check of the header against the payload's length ([`check_layout`]) and of the
//! payload's alignment; every later read is within those slices. Nothing scans the records on
//! receipt: a planner that reads a few nodes of each new graph pays for those alone. Lookups
//! scan the records (a binary search for an id); one that asks many questions of one graph keeps
//! an owned [`Graph`] ([`GraphView::to_graph`]), whose indices answer in constant time.
//!
//! The kind and origin bytes of the records are decoded when read. The owned decode also checks
//! every one of them on receipt; the view does so on request ([`GraphView::check_records`]) and
//! in [`GraphView::to_graph`]. Within one schema version only a broken publisher writes a value
//! outside the vocabulary (a new kind or origin comes with a new schema version, which the view
//! refuses at once); the view's accessors read such a value as the first of the vocabulary
//! (object, spatial, geometry).

use crate::client::accessors::{contains_ignore_ascii_case, edge_record_accessors, node_record_accessors};
use crate::client::check::{check_layout, check_records};
use crate::client::{Graph, SnapshotError, UnknownAffordance};
use crate::{Edge, GraphHeader, GraphMessage, NO_NODE, NODE_BYTES, Node, NodeKind, affordance_bits};

/// One graph sample, read in place: the header and the node and edge records as slices of the
/// sample (no copy), checked once when the view is made.
///
/// From a subscriber: [`GraphSubscriber::with_latest`](crate::GraphSubscriber::with_latest)
/// lends one for as long as its closure runs. From bytes: [`Self::from_message`] (a header and a
/// payload) or [`Self::from_bytes`] (the header's 112 bytes, then the payload, in one block).
///
/// Lookups without an index: [`Self::node`] is a binary search over the nodes (sorted by id, as
/// the contract and the daemon's publisher order them; a direct hit when ids are dense), the
/// others one scan of the nodes or edges. [`Self::to_graph`] copies the sample into an owned
/// [`Graph`] for a planner that keeps it or asks many questions of it.
#[derive(Clone, Copy)]
pub struct GraphView<'a> {
    header: &'a GraphHeader,
    payload: &'a [u8],
    nodes: &'a [Node],
    edges: &'a [Edge],
    restarted: bool,
}

impl core::fmt::Debug for GraphView<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("GraphView")
            .field("instance_id", &self.instance_id())
            .field("version", &self.version())
            .field("stamp_ns", &self.stamp_ns())
            .field("nodes", &self.nodes.len())
            .field("edges", &self.edges.len())
            .field("capacity_exceeded", &self.capacity_exceeded())
            .finish()
    }
}

impl<'a> GraphView<'a> {
    /// A view of `message`, after checking it in constant time: the header's schema version,
    /// its counts within its capacities and the payload's length ([`check_layout`]), and the
    /// payload's start on an 8-byte boundary (the records' alignment). A sample that fails is
    /// refused with the error naming what is wrong; nothing beyond the payload is ever read.
    /// The records' kinds and origins are checked by [`Self::check_records`].
    pub fn from_message(message: GraphMessage<'a>) -> Result<Self, SnapshotError> {
        let GraphMessage { header, payload } = message;
        check_layout(header, payload.len())?;
        let node_bytes = header.node_count as usize * NODE_BYTES;
        let (node_bytes, edge_bytes) = payload.split_at(node_bytes);
        let nodes = records::<Node>(node_bytes, payload)?;
        let edges = records::<Edge>(edge_bytes, payload)?;
        Ok(Self { header, payload, nodes, edges, restarted: false })
    }

    /// The record half of [`check_message`](crate::check_message), which the view skips on
    /// receipt: every node's kind and every edge's kind and origin within the vocabulary, the
    /// first one outside named. One pass over the records (as long as reading every one).
    pub fn check_records(&self) -> Result<(), SnapshotError> {
        check_records(&self.message())
    }

    /// A view of a sample laid out in one byte block: the [`GraphHeader`]'s 112 bytes, then the
    /// payload (as a file or another transport may carry a sample). Refused, naming why, when
    /// the block is shorter than a header, does not start on an 8-byte boundary, or fails
    /// [`Self::from_message`]'s checks.
    pub fn from_bytes(bytes: &'a [u8]) -> Result<Self, SnapshotError> {
        let header_len = size_of::<GraphHeader>();
        let Some((head, payload)) = bytes.split_at_checked(header_len) else {
            return Err(SnapshotError::HeaderSize { found: bytes.len(), expected: header_len });
        };
        let header: &GraphHeader = bytemuck::try_from_bytes(head).map_err(|_| SnapshotError::Misaligned {
            field: "header",
            address: head.as_ptr() as usize,
            alignment: align_of::<GraphHeader>(),
        })?;
        Self::from_message(GraphMessage::new(header, payload))
    }

    /// The same view with [`Self::restarted`] set (by the subscriber that received it).
    pub(crate) fn with_restarted(self, restarted: bool) -> Self {
        Self { restarted, ..self }
    }

    /// An owned copy of this graph (header, nodes, edges; one block copy each), valid after the
    /// sample went back: for a graph a planner keeps, or asks many questions of. The records are
    /// checked first ([`Self::check_records`]), as the owned decode checks them.
    pub fn to_graph(&self) -> Result<Graph, SnapshotError> {
        Graph::try_from(self)
    }

    /// The sample as received: its header and its payload bytes (for [`Graph::from_message`],
    /// a recorder, or another transport).
    pub fn message(&self) -> GraphMessage<'a> {
        GraphMessage::new(self.header, self.payload)
    }

    /// Graph version (see [`Graph::version`]).
    pub fn version(&self) -> u64 {
        self.header.graph_version
    }

    /// The daemon instance that published this graph (see [`Graph::instance_id`]).
    pub fn instance_id(&self) -> u64 {
        self.header.instance_id
    }

    /// `true` when the sample the same subscriber received before this one came from another
    /// daemon instance: the daemon restarted in between (see [`Graph::restarted`]).
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

    /// `true` when the daemon's map had more nodes or edges than a sample holds (see
    /// [`GraphHeader::capacity_exceeded`]).
    pub fn capacity_exceeded(&self) -> bool {
        self.header.capacity_exceeded != 0
    }

    /// What the daemon reads its frames from ([`SourceKind`](crate::SourceKind)).
    pub fn source_kind(&self) -> crate::SourceKind {
        self.header.source_kind()
    }

    /// Name of the frame every coordinate of this graph is in.
    pub fn world_frame(&self) -> &'a str {
        self.header.world_frame_str()
    }

    /// The header as received.
    pub fn header(&self) -> &'a GraphHeader {
        self.header
    }

    /// Number of nodes.
    pub fn node_count(&self) -> usize {
        self.nodes.len()
    }

    /// Number of edges.
    pub fn edge_count(&self) -> usize {
        self.edges.len()
    }

    /// The node records, in the sample, sorted by id.
    pub fn wire_nodes(&self) -> &'a [Node] {
        self.nodes
    }

    /// The edge records, in the sample.
    pub fn wire_edges(&self) -> &'a [Edge] {
        self.edges
    }

    /// Every node, in wire order (sorted by id).
    pub fn nodes(&self) -> impl ExactSizeIterator<Item = NodeRef<'a>> + use<'a> {
        let view = *self;
        (0..self.nodes.len() as u32).map(move |index| NodeRef { view, index })
    }

    /// The object nodes.
    pub fn objects(&self) -> impl Iterator<Item = NodeRef<'a>> + use<'a> {
        self.nodes().filter(|n| n.kind() == NodeKind::Object)
    }

    /// The part nodes.
    pub fn parts(&self) -> impl Iterator<Item = NodeRef<'a>> + use<'a> {
        self.nodes().filter(|n| n.kind() == NodeKind::Part)
    }

    /// Every edge, in wire order.
    pub fn edges(&self) -> impl ExactSizeIterator<Item = EdgeRef<'a>> + use<'a> {
        let view = *self;
        (0..self.edges.len() as u32).map(move |index| EdgeRef { view, index })
    }

    /// Index of the node with this id: a direct hit when ids are dense (node `id` at index `id`),
    /// else a binary search over the nodes, which the contract sorts by id.
    pub fn index_of(&self, id: u32) -> Option<usize> {
        if self.nodes.get(id as usize).is_some_and(|n| n.id == id) {
            return Some(id as usize);
        }
        self.nodes.binary_search_by_key(&id, |n| n.id).ok()
    }

    /// The node with this id ([`Self::index_of`]).
    pub fn node(&self, id: u32) -> Option<NodeRef<'a>> {
        self.index_of(id).map(|index| NodeRef { view: *self, index: index as u32 })
    }

    /// The parts whose parent is `object_id` (empty for an id not in this graph).
    pub fn parts_of(&self, object_id: u32) -> impl Iterator<Item = NodeRef<'a>> + use<'a> {
        let present = self.index_of(object_id).is_some();
        self.nodes().filter(move |n| present && n.wire().parent_id == object_id)
    }

    /// The parent object of the part `part_id` (`None` for objects, unattached parts, parents
    /// not in this graph and unknown ids).
    pub fn parent_of(&self, part_id: u32) -> Option<NodeRef<'a>> {
        self.node(part_id).and_then(|n| n.parent())
    }

    /// The edges whose source is `id` (empty for an id not in this graph).
    pub fn edges_from(&self, id: u32) -> impl Iterator<Item = EdgeRef<'a>> + use<'a> {
        let present = self.index_of(id).is_some();
        self.edges().filter(move |e| present && e.wire().source_id == id)
    }

    /// The edges whose target is `id` (empty for an id not in this graph).
    pub fn edges_to(&self, id: u32) -> impl Iterator<Item = EdgeRef<'a>> + use<'a> {
        let present = self.index_of(id).is_some();
        self.edges().filter(move |e| present && e.wire().target_id == id)
    }

    /// The nodes labelled exactly `label`.
    pub fn find_by_label<'s>(&self, label: &'s str) -> impl Iterator<Item = NodeRef<'a>> + use<'a, 's> {
        self.nodes().filter(move |n| n.label() == label)
    }

    /// The nodes whose label contains `text`, ASCII letters compared without case.
    pub fn find_by_label_containing<'s>(&self, text: &'s str) -> impl Iterator<Item = NodeRef<'a>> + use<'a, 's> {
        self.nodes().filter(move |n| contains_ignore_ascii_case(n.label(), text))
    }

    /// The nodes that afford `name` (one of [`AFFORDANCES`](crate::AFFORDANCES)).
    pub fn find_by_affordance(
        &self,
        name: &str,
    ) -> Result<impl Iterator<Item = NodeRef<'a>> + use<'a>, UnknownAffordance> {
        let bits = affordance_bits([name]).map_err(|_| UnknownAffordance)?;
        Ok(self.find_by_affordance_bits(bits))
    }

    /// The nodes that afford every affordance in `bits` (see [`affordance_bits`]).
    pub fn find_by_affordance_bits(&self, bits: u16) -> impl Iterator<Item = NodeRef<'a>> + use<'a> {
        self.nodes().filter(move |n| n.affordance_bits() & bits == bits)
    }
}

/// `bytes` (a part of `payload`) as records of `T`; an empty part is no records wherever it
/// points. The layout was checked, so only the alignment can fail.
fn records<'a, T: bytemuck::Pod>(bytes: &'a [u8], payload: &[u8]) -> Result<&'a [T], SnapshotError> {
    if !cfg!(target_endian = "little") {
        return Err(SnapshotError::ByteOrder);
    }
    if bytes.is_empty() {
        return Ok(&[]);
    }
    bytemuck::try_cast_slice(bytes).map_err(|_| SnapshotError::Misaligned {
        field: "payload",
        address: payload.as_ptr() as usize,
        alignment: align_of::<Node>(),
    })
}

/// One node of a [`GraphView`]: its record in the sample, with the accessors of
/// [`NodeView`](crate::NodeView).
#[derive(Clone, Copy)]
pub struct NodeRef<'a> {
    view: GraphView<'a>,
    index: u32,
}

impl core::fmt::Debug for NodeRef<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("NodeRef")
            .field("id", &self.id())
            .field("kind", &self.kind())
            .field("label", &self.label())
            .field("parent_id", &self.parent_id())
            .finish()
    }
}

impl<'a> NodeRef<'a> {
    /// The record as it lies in the sample.
    pub fn wire(&self) -> &'a Node {
        &self.view.nodes[self.index as usize]
    }

    /// Index of the node in the sample.
    pub fn index(&self) -> usize {
        self.index as usize
    }

    node_record_accessors!('a);

    /// The parent object of a part, when it is in this graph.
    pub fn parent(&self) -> Option<NodeRef<'a>> {
        let id = self.wire().parent_id;
        if id == NO_NODE { None } else { self.view.node(id) }
    }

    /// The parts attached to this node (one scan of the nodes).
    pub fn parts(&self) -> impl Iterator<Item = NodeRef<'a>> + use<'a> {
        let id = self.id();
        self.view.nodes().filter(move |n| n.wire().parent_id == id)
    }

    /// The edges whose source is this node (one scan of the edges).
    pub fn edges_from(&self) -> impl Iterator<Item = EdgeRef<'a>> + use<'a> {
        let id = self.id();
        self.view.edges().filter(move |e| e.wire().source_id == id)
    }

    /// The edges whose target is this node (one scan of the edges).
    pub fn edges_to(&self) -> impl Iterator<Item = EdgeRef<'a>> + use<'a> {
        let id = self.id();
        self.view.edges().filter(move |e| e.wire().target_id == id)
    }
}

/// One directed edge of a [`GraphView`]: its record in the sample, with the accessors of
/// [`EdgeView`](crate::EdgeView).
#[derive(Clone, Copy)]
pub struct EdgeRef<'a> {
    view: GraphView<'a>,
    index: u32,
}

impl core::fmt::Debug for EdgeRef<'_> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("EdgeRef")
            .field("source_id", &self.source_id())
            .field("phrase", &self.phrase())
            .field("target_id", &self.target_id())
            .field("origin", &self.origin())
            .finish()
    }
}

impl<'a> EdgeRef<'a> {
    /// The record as it lies in the sample.
    pub fn wire(&self) -> &'a Edge {
        &self.view.edges[self.index as usize]
    }

    edge_record_accessors!('a);

    /// The source node, when it is in this graph.
    pub fn source(&self) -> Option<NodeRef<'a>> {
        self.view.node(self.source_id())
    }

    /// The target node, when it is in this graph.
    pub fn target(&self) -> Option<NodeRef<'a>> {
        self.view.node(self.target_id())
    }
}

#[cfg(test)]
mod tests;
