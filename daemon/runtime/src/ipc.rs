//! # The iceoryx2 service layer
//!
//! `op3dsgd` serves its scene graph to planners over iceoryx2 0.10 shared memory. All services
//! live under a configurable prefix (default `op3dsg`, see [`IpcConfig::prefix`]); the payload
//! types and their layouts are the wire contract in [`op3dsg_ipc_types`].
//!
//! | service                  | pattern           | payload         | QoS (fixed by the creator)                       |
//! |--------------------------|-------------------|-----------------|--------------------------------------------------|
//! | `<prefix>/graph`         | publish-subscribe | `GraphSnapshot` | history 1, safe overflow, buffer 2, borrow 1     |
//! | `<prefix>/graph_updated` | event             | event id 0      | max event id 0                                   |
//! | `<prefix>/health`        | publish-subscribe | `Health`        | history 1, safe overflow                         |
//! | `<prefix>/pose`          | publish-subscribe | `PoseStamped`   | safe overflow, buffer 64 (input to the daemon)   |
//!
//! ## Why this QoS
//! - **History 1**: a planner that starts (or restarts) after the daemon receives the current
//!   graph and health at once instead of waiting for the next change; the graph may not change for
//!   a long time in a static room. iceoryx2 delivers the history from the *publisher* side when it
//!   next updates its connections, so the daemon's publisher thread calls
//!   [`GraphServer::update_connections`] whenever it wakes (at least every ~100 ms).
//! - **Safe overflow**: a slow or stuck planner must never block or slow the daemon. With safe
//!   overflow a full subscriber buffer drops its *oldest* sample, so a reader always finds the
//!   newest versions; each sample is a complete, self-consistent graph, so losing older ones loses
//!   nothing. The daemon never uses a blocking backpressure strategy.
//! - **Event**: the graph changes irregularly (per keyframe fusion, not per frame). Instead of
//!   polling the 3.9 MiB sample, a planner waits on a listener of `<prefix>/graph_updated`
//!   (or attaches it to a `WaitSet` with its other inputs) and reads the graph when woken; the
//!   version is in the sample's header. The event carries no data (one id, 0): a listener
//!   scans its whole id range on every wake-up, and a range of 2^16 ids (the version's low bits,
//!   as an earlier contract had it) cost about 0.3 ms per delivery (`op3dsg bench perf`).
//! - The snapshot is large: it is loaned from the publisher's data segment and filled in place,
//!   never built on the stack. A subscriber borrows at most one sample at a time (the service is
//!   created with `subscriber_max_borrowed_samples = 1`), which keeps the shared memory the
//!   daemon maps to `max_subscribers * (buffer + 1) + history + 1` samples (26 samples, about
//!   100 MiB, with the defaults).
//!
//! Who creates what: the daemon creates `graph`, `graph_updated` and `health` (or opens them if a
//! previous instance's survivors still hold them, stating its QoS as minimums); clients only open
//! them, so a client cannot fix a different QoS, and a client started before the daemon waits
//! ([`GraphClient::open_wait`]). `pose` is opened-or-created by both sides with the same QoS,
//! because the navigation stack may well start first.
//!
//! ## Subscribing from Python
//! ```python
//! import ctypes, iceoryx2 as iox2          # pip install iceoryx2==0.10.0
//! class Node(ctypes.Structure):            # mirror field by field, see op3dsg_ipc_types
//!     _fields_ = [("id", ctypes.c_uint32), ("parent_id", ctypes.c_uint32), ...]
//!     @staticmethod
//!     def type_name() -> str: return "op3dsg::Node"
//! class GraphSnapshot(ctypes.Structure):
//!     _fields_ = [("header", GraphHeader), ("nodes", Node * 16384), ("edges", Edge * 32768)]
//!     @staticmethod
//!     def type_name() -> str: return "op3dsg::GraphSnapshot"
//! node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
//! service = (node.service_builder(iox2.ServiceName.new("op3dsg/graph"))
//!            .publish_subscribe(GraphSnapshot).open())
//! subscriber = service.subscriber_builder().create()
//! sample = subscriber.receive()            # None until the daemon has published
//! if sample is not None:
//!     graph = sample.payload().contents    # check graph.header.schema_version == 1 first
//! ```
//! The `type_name()` strings must match exactly (`op3dsg::GraphSnapshot`, `op3dsg::Health`,
//! `op3dsg::PoseStamped`), or opening fails with incompatible types.
//!
//! ## Stale resources
//! A daemon killed with `SIGKILL` leaves its node and ports behind in shared memory; the node is
//! then `Dead`. [`GraphServer::open`] (and, harmlessly, every client) first removes the stale
//! resources of all dead nodes (`Node::try_cleanup_dead_nodes`), so a restarted daemon can create
//! its services again and clients do not wait on a publisher that no longer exists
//! ([`IpcConfig::cleanup_dead_nodes_at_start`]).
//!
//! iceoryx2 nodes are created with signal handling disabled: the daemon and the CLI install
//! their own Ctrl-C handlers.

use std::mem::MaybeUninit;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::{EventId, Node, NodeBuilder, NodeName, PlacementDefault, ServiceName, SignalHandlingMode};
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::sample_mut_uninit::SampleMutUninit;
use iceoryx2::service::builder::event::EventOpenError;
use iceoryx2::service::builder::publish_subscribe::{PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError};
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::{
    Edge, EdgeKind, EdgeOrigin, GraphHeader, GraphSnapshot, Health, MAX_EDGES, MAX_NODES, NAME_CAPACITY_BYTES, NO_NODE,
    NodeKind, PoseKind, PoseStamped, SCHEMA_VERSION, ServiceNames,
};
use serde::{Deserialize, Serialize};

use crate::graph::{GraphEdge, GraphNode, SceneGraph};

/// The iceoryx2 service flavour of every port here: inter-process, and `Send` so the daemon may
/// build its [`GraphServer`] on one thread and hand it to the publisher thread. It shares its
/// resources with plain `ipc::Service` peers (C, C++, Python).
pub type IpcService = iceoryx2::service::ipc_threadsafe::Service;

/// History depth of `graph` and `health`: a late joiner gets the newest sample.
pub const HISTORY_SIZE: usize = 1;
/// The one event id of `graph_updated` (a wake-up; the version is in the sample).
pub const GRAPH_UPDATED_EVENT_ID: usize = 0;
/// Largest event id of `graph_updated`: the listener's scan per wake-up is this wide.
pub const EVENT_ID_MAX_VALUE: usize = GRAPH_UPDATED_EVENT_ID;
/// Buffer of the `pose` service when a client creates it before the daemon (the daemon's default).
pub const DEFAULT_POSE_BUFFER: usize = 64;
/// Publishers allowed on `pose` (navigation stack, tools, tests).
pub const POSE_MAX_PUBLISHERS: usize = 4;
/// Subscribers allowed on `pose` (the daemon, a recorder).
pub const POSE_MAX_SUBSCRIBERS: usize = 4;
/// Largest accepted deviation of a pose quaternion's norm from 1.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;
/// Longest accepted prefix (the longest service name, `<prefix>/graph_updated`, must stay far
/// below iceoryx2's 255-byte limit).
pub const MAX_PREFIX_LEN: usize = 128;

/// Settings of the iceoryx2 services (the `[ipc]` table of a profile).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IpcConfig {
    /// Service name prefix: services are `<prefix>/graph`, `<prefix>/health`, ...
    pub prefix: String,
    /// Most subscribers per published service (each costs shared memory, see the module docs).
    pub max_subscribers: usize,
    /// Samples buffered per subscriber of `graph` before the oldest is overwritten.
    pub subscriber_buffer: usize,
    /// Poses buffered for the daemon on `pose` between two polls.
    pub pose_buffer: usize,
    /// Remove the shared-memory leftovers of dead processes when the daemon starts.
    pub cleanup_dead_nodes_at_start: bool,
}

impl Default for IpcConfig {
    fn default() -> Self {
        Self {
            prefix: "op3dsg".to_owned(),
            max_subscribers: 8,
            subscriber_buffer: 2,
            pose_buffer: DEFAULT_POSE_BUFFER,
            cleanup_dead_nodes_at_start: true,
        }
    }
}

impl IpcConfig {
    /// Checks every field; the message names the field as `<path>.<field>`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        validate_prefix(&self.prefix).map_err(|e| format!("{path}.prefix: {e}"))?;
        let ranges = [
            ("max_subscribers", self.max_subscribers, 64),
            ("subscriber_buffer", self.subscriber_buffer, 16),
            ("pose_buffer", self.pose_buffer, 4096),
        ];
        for (field, value, max) in ranges {
            if !(1..=max).contains(&value) {
                return Err(format!("{path}.{field}: must be between 1 and {max}, found {value}"));
            }
        }
        Ok(())
    }
}

/// Checks that `prefix` can prefix iceoryx2 service names: not empty, at most
/// [`MAX_PREFIX_LEN`] bytes, ASCII letters, digits, `_`, `-`, `.` and inner `/` only.
pub fn validate_prefix(prefix: &str) -> Result<(), String> {
    if prefix.is_empty() {
        return Err("must not be empty".to_owned());
    }
    if prefix.len() > MAX_PREFIX_LEN {
        return Err(format!("must be at most {MAX_PREFIX_LEN} bytes, found {}", prefix.len()));
    }
    if let Some(c) = prefix.chars().find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '/'))) {
        return Err(format!("invalid character {c:?} in \"{prefix}\" (allowed: A-Z a-z 0-9 _ - . /)"));
    }
    if prefix.starts_with('/') || prefix.ends_with('/') || prefix.contains("//") {
        return Err(format!("\"{prefix}\" must not start or end with '/' nor contain \"//\""));
    }
    ServiceName::new(&ServiceNames::new(prefix).graph_updated)
        .map_err(|e| format!("\"{prefix}\" is not a valid iceoryx2 service name fragment: {e:?}"))?;
    Ok(())
}

/// A snapshot that cannot be read back into a [`SceneGraph`]; names the offending entry.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SnapshotError {
    /// The publisher wrote another wire-contract version.
    #[error("header.schema_version: found {found}, this build reads {expected}")]
    SchemaVersion {
        /// Version in the sample.
        found: u32,
        /// [`SCHEMA_VERSION`].
        expected: u32,
    },
    /// A count in the header exceeds the array capacity.
    #[error("header.{field}: {value} exceeds the capacity {capacity}")]
    CountTooLarge {
        /// `node_count` or `edge_count`.
        field: &'static str,
        /// The count found.
        value: u32,
        /// The array capacity.
        capacity: usize,
    },
    /// A node with an unknown kind value.
    #[error("nodes[{index}].kind: unknown value {value} (0 object, 1 part)")]
    UnknownNodeKind {
        /// Index in `nodes`.
        index: usize,
        /// Wire value.
        value: u8,
    },
    /// An edge with an unknown kind value.
    #[error("edges[{index}].kind: unknown value {value} (0 spatial, 1 functional)")]
    UnknownEdgeKind {
        /// Index in `edges`.
        index: usize,
        /// Wire value.
        value: u8,
    },
    /// An edge with an unknown origin value.
    #[error("edges[{index}].origin: unknown value {value} (0..=3)")]
    UnknownEdgeOrigin {
        /// Index in `edges`.
        index: usize,
        /// Wire value.
        value: u8,
    },
}

/// Failures of the service layer; each names the service (or prefix, or node) and the operation.
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    /// The prefix cannot form service names.
    #[error("invalid service prefix '{prefix}': {reason}")]
    InvalidPrefix {
        /// The prefix given.
        prefix: String,
        /// Why it is invalid.
        reason: String,
    },
    /// The iceoryx2 node could not be created.
    #[error("cannot create iceoryx2 node '{node}': {reason}")]
    Node {
        /// Node name.
        node: String,
        /// iceoryx2's reason.
        reason: String,
    },
    /// A client found no daemon's service.
    #[error("no op3dsgd is serving under prefix '{prefix}' (service {service} not found)")]
    NotServing {
        /// The prefix.
        prefix: String,
        /// The missing service.
        service: String,
    },
    /// An iceoryx2 operation on a service failed.
    #[error("{operation} on service {service}: {reason}")]
    Service {
        /// Full service name.
        service: String,
        /// What was attempted ("open or create", "loan", "send", "notify", ...).
        operation: &'static str,
        /// iceoryx2's reason.
        reason: String,
    },
    /// A received sample is not a valid graph.
    #[error("invalid sample on service {service}: {source}")]
    InvalidSnapshot {
        /// Full service name.
        service: String,
        /// What is wrong.
        #[source]
        source: SnapshotError,
    },
    /// A received health record has another schema version.
    #[error("invalid sample on service {service}: schema_version {found}, this build reads {SCHEMA_VERSION}")]
    HealthSchema {
        /// Full service name.
        service: String,
        /// Version in the sample.
        found: u32,
    },
    /// An argument cannot be put on the wire.
    #[error("{what}: {reason}")]
    InvalidArgument {
        /// Which argument.
        what: &'static str,
        /// Why.
        reason: String,
    },
}

pub fn service_err(service: &str, operation: &'static str, reason: impl std::fmt::Debug) -> IpcError {
    IpcError::Service { service: service.to_owned(), operation, reason: format!("{reason:?}") }
}

pub fn service_name(prefix: &str, full: &str) -> Result<ServiceName, IpcError> {
    validate_prefix(prefix).map_err(|reason| IpcError::InvalidPrefix { prefix: prefix.to_owned(), reason })?;
    ServiceName::new(full)
        .map_err(|e| IpcError::InvalidPrefix { prefix: prefix.to_owned(), reason: format!("{full}: {e:?}") })
}

pub fn create_node(node_name: &str) -> Result<Node<IpcService>, IpcError> {
    let name = NodeName::new(node_name)
        .map_err(|e| IpcError::Node { node: node_name.to_owned(), reason: format!("invalid name: {e:?}") })?;
    NodeBuilder::new()
        .name(&name)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<IpcService>()
        .map_err(|e| IpcError::Node { node: node_name.to_owned(), reason: format!("{e:?}") })
}

/// Removes the resources of dead nodes; returns how many were cleaned.
fn cleanup_dead_nodes(node: &Node<IpcService>) -> u64 {
    let state = node.try_cleanup_dead_nodes();
    if state.failed_cleanups > 0 {
        tracing::warn!(
            cleaned = state.cleanups,
            failed = state.failed_cleanups,
            "could not remove the shared-memory leftovers of some dead iceoryx2 nodes (permissions?)"
        );
    }
    state.cleanups
}

/// Nanoseconds since the Unix epoch (0 if the clock is before 1970).
pub fn wall_clock_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map(|d| d.as_nanos() as u64).unwrap_or(0)
}

/// What one [`fill_snapshot`] / [`GraphServer::publish_graph`] wrote.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PublishReport {
    /// Graph version written.
    pub version: u64,
    /// Nodes written into the snapshot.
    pub nodes_written: usize,
    /// Edges written into the snapshot.
    pub edges_written: usize,
    /// Nodes in the graph.
    pub total_nodes: usize,
    /// Edges in the graph.
    pub total_edges: usize,
    /// `true` when nodes or edges were left out for capacity (`capacity_exceeded` was set).
    pub truncated: bool,
    /// Labels cut to fit the label buffer.
    pub labels_cut: usize,
    /// Edges left out because an endpoint is not in the graph at all (a pipeline bug).
    pub dangling_edges: usize,
}

/// Writes `graph` into `snapshot` (header, nodes sorted by id, edges). Pure: no shared memory.
///
/// Beyond [`MAX_NODES`] it keeps the most recently seen nodes (highest `last_seen_stamp_ns`, on
/// ties the lower id) and only the edges between kept nodes; beyond [`MAX_EDGES`] it keeps the
/// edges whose older endpoint was seen most recently (on ties the earlier edge). Either sets
/// `capacity_exceeded`. `total_*` are always the graph's real counts. `publish_time_ns` is set to 0;
/// the publisher stamps it.
pub fn fill_snapshot(graph: &SceneGraph, snapshot: &mut GraphSnapshot) -> PublishReport {
    let mut report = PublishReport {
        version: graph.version,
        total_nodes: graph.nodes.len(),
        total_edges: graph.edges.len(),
        ..PublishReport::default()
    };

    // Node selection: indices into graph.nodes.
    let mut selected: Vec<usize> = (0..graph.nodes.len()).collect();
    if selected.len() > MAX_NODES {
        let recency = |&a: &usize, &b: &usize| {
            let (na, nb) = (&graph.nodes[a], &graph.nodes[b]);
            nb.last_seen_stamp_ns.cmp(&na.last_seen_stamp_ns).then(na.id.cmp(&nb.id))
        };
        selected.select_nth_unstable_by(MAX_NODES - 1, recency);
        selected.truncate(MAX_NODES);
        report.truncated = true;
    }
    selected.sort_by_key(|&i| graph.nodes[i].id);

    // id -> last_seen of published nodes, for edge filtering.
    let published: std::collections::HashMap<u32, u64> =
        selected.iter().map(|&i| (graph.nodes[i].id, graph.nodes[i].last_seen_stamp_ns)).collect();
    let all_ids: std::collections::HashSet<u32> =
        if report.truncated { graph.nodes.iter().map(|n| n.id).collect() } else { std::collections::HashSet::new() };
    let exists = |id: u32| if report.truncated { all_ids.contains(&id) } else { published.contains_key(&id) };

    let mut edges: Vec<(usize, u64)> = Vec::with_capacity(graph.edges.len().min(MAX_EDGES));
    for (i, e) in graph.edges.iter().enumerate() {
        match (published.get(&e.source_id), published.get(&e.target_id)) {
            (Some(s), Some(t)) => edges.push((i, (*s).min(*t))),
            _ if !exists(e.source_id) || !exists(e.target_id) => report.dangling_edges += 1,
            _ => {} // endpoint left out for capacity
        }
    }
    if edges.len() > MAX_EDGES {
        edges.select_nth_unstable_by(MAX_EDGES - 1, |a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        edges.truncate(MAX_EDGES);
        edges.sort_by_key(|&(i, _)| i);
        report.truncated = true;
    }
    if edges.len() + report.dangling_edges < graph.edges.len() {
        report.truncated = true;
    }

    let mut object_count = 0u32;
    let mut part_count = 0u32;
    for (slot, &i) in snapshot.nodes.iter_mut().zip(selected.iter()) {
        let node = &graph.nodes[i];
        match node.kind {
            NodeKind::Object => object_count += 1,
            NodeKind::Part => part_count += 1,
        }
        slot.id = node.id;
        slot.parent_id = node.parent_id.unwrap_or(NO_NODE);
        slot.kind = node.kind as u8;
        slot.reserved = [0; 3];
        slot.observation_count = node.observation_count;
        if !op3dsg_ipc_types::write_fixed_str(&mut slot.label, &node.label) {
            report.labels_cut += 1;
        }
        slot.confidence = node.confidence;
        slot.centre_m = node.centre_m;
        slot.box_min_m = node.box_min_m;
        slot.box_max_m = node.box_max_m;
        slot.affordance_bits = node.affordance_bits;
        slot.reserved2 = [0; 6];
        slot.last_seen_stamp_ns = node.last_seen_stamp_ns;
    }
    for (slot, &(i, _)) in snapshot.edges.iter_mut().zip(edges.iter()) {
        write_edge(slot, &graph.edges[i]);
    }

    report.nodes_written = selected.len();
    report.edges_written = edges.len();
    let header = &mut snapshot.header;
    header.schema_version = SCHEMA_VERSION;
    header.node_count = selected.len() as u32;
    header.graph_version = graph.version;
    header.stamp_ns = graph.stamp_ns;
    header.publish_time_ns = 0;
    header.edge_count = edges.len() as u32;
    header.object_count = object_count;
    header.part_count = part_count;
    header.capacity_exceeded = u8::from(report.truncated);
    header.reserved = [0; 3];
    header.total_node_count = u32::try_from(graph.nodes.len()).unwrap_or(u32::MAX);
    header.total_edge_count = u32::try_from(graph.edges.len()).unwrap_or(u32::MAX);
    report
}

fn write_edge(slot: &mut Edge, edge: &GraphEdge) {
    slot.source_id = edge.source_id;
    slot.target_id = edge.target_id;
    slot.kind = edge.kind as u8;
    slot.origin = edge.origin as u8;
    slot.relation_id = edge.relation_id;
    slot.confidence = edge.confidence;
    op3dsg_ipc_types::write_fixed_str(
        &mut slot.phrase,
        op3dsg_ipc_types::relation_phrase(edge.relation_id).unwrap_or(""),
    );
}

/// Reads a snapshot back into a [`SceneGraph`], checking the schema version, the counts and every
/// kind and origin value.
pub fn snapshot_to_scene_graph(snapshot: &GraphSnapshot) -> Result<SceneGraph, SnapshotError> {
    let header = &snapshot.header;
    if header.schema_version != SCHEMA_VERSION {
        return Err(SnapshotError::SchemaVersion { found: header.schema_version, expected: SCHEMA_VERSION });
    }
    if header.node_count as usize > MAX_NODES {
        return Err(SnapshotError::CountTooLarge {
            field: "node_count",
            value: header.node_count,
            capacity: MAX_NODES,
        });
    }
    if header.edge_count as usize > MAX_EDGES {
        return Err(SnapshotError::CountTooLarge {
            field: "edge_count",
            value: header.edge_count,
            capacity: MAX_EDGES,
        });
    }
    let nodes = snapshot
        .valid_nodes()
        .iter()
        .enumerate()
        .map(|(index, n)| {
            let kind = NodeKind::from_u8(n.kind).ok_or(SnapshotError::UnknownNodeKind { index, value: n.kind })?;
            Ok(GraphNode {
                id: n.id,
                kind,
                parent_id: (n.parent_id != NO_NODE).then_some(n.parent_id),
                label: n.label_str().to_owned(),
                confidence: n.confidence,
                centre_m: n.centre_m,
                box_min_m: n.box_min_m,
                box_max_m: n.box_max_m,
                observation_count: n.observation_count,
                affordance_bits: n.affordance_bits,
                last_seen_stamp_ns: n.last_seen_stamp_ns,
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let edges = snapshot
        .valid_edges()
        .iter()
        .enumerate()
        .map(|(index, e)| {
            Ok(GraphEdge {
                source_id: e.source_id,
                target_id: e.target_id,
                kind: EdgeKind::from_u8(e.kind).ok_or(SnapshotError::UnknownEdgeKind { index, value: e.kind })?,
                relation_id: e.relation_id,
                confidence: e.confidence,
                origin: EdgeOrigin::from_u8(e.origin)
                    .ok_or(SnapshotError::UnknownEdgeOrigin { index, value: e.origin })?,
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(SceneGraph { version: header.graph_version, stamp_ns: header.stamp_ns, nodes, edges })
}

/// Initialises a loaned snapshot in place (every field to its placement default), without ever
/// materialising the 3.9 MiB value on the stack.
///
/// iceoryx2 0.10 offers no safe in-place initialisation: `Publisher::loan` needs `Default` and
/// moves a stack value into the sample. This is the only unsafe code of the daemon.
#[allow(unsafe_code)]
fn init_snapshot_in_place(
    mut sample: SampleMutUninit<IpcService, MaybeUninit<GraphSnapshot>, ()>,
) -> SampleMut<IpcService, GraphSnapshot, ()> {
    let ptr = sample.payload_mut().as_mut_ptr();
    // SAFETY: `ptr` points to the loaned chunk, sized and aligned for `GraphSnapshot` and owned
    // exclusively by this sample. The derived `PlacementDefault` writes every field of the header
    // and every element of both arrays (all plain data, no padding-dependent invariants), so the
    // payload is fully initialised before `assume_init`.
    unsafe {
        GraphSnapshot::placement_default(ptr);
        sample.assume_init()
    }
}

/// The daemon's side: publishes graph and health, receives poses.
#[derive(Debug)]
pub struct GraphServer {
    names: ServiceNames,
    graph_service: iceoryx2::service::port_factory::publish_subscribe::PortFactory<IpcService, GraphSnapshot, ()>,
    graph_publisher: Publisher<IpcService, GraphSnapshot, ()>,
    notifier: Notifier<IpcService>,
    health_publisher: Publisher<IpcService, Health, ()>,
    pose_subscriber: Subscriber<IpcService, PoseStamped, ()>,
    invalid_poses: u64,
    dead_nodes_cleaned: u64,
    node: Node<IpcService>,
}

impl GraphServer {
    /// Creates (or reopens) the daemon's services under `config.prefix`, after removing the
    /// leftovers of dead processes when `config.cleanup_dead_nodes_at_start` is set.
    pub fn open(config: &IpcConfig, node_name: &str) -> Result<Self, IpcError> {
        config.validate("ipc").map_err(|reason| IpcError::InvalidPrefix { prefix: config.prefix.clone(), reason })?;
        let names = ServiceNames::new(&config.prefix);
        let node = create_node(node_name)?;
        let dead_nodes_cleaned = if config.cleanup_dead_nodes_at_start { cleanup_dead_nodes(&node) } else { 0 };
        tracing::info!(dead_nodes_cleaned, prefix = %config.prefix, "iceoryx2 stale-resource cleanup done");

        let name = service_name(&config.prefix, &names.graph)?;
        let graph_service = node
            .service_builder(&name)
            .publish_subscribe::<GraphSnapshot>()
            .history_size(HISTORY_SIZE)
            .enable_safe_overflow(true)
            .subscriber_max_buffer_size(config.subscriber_buffer)
            .subscriber_max_borrowed_samples(1)
            .max_subscribers(config.max_subscribers)
            .max_publishers(1)
            .open_or_create()
            .map_err(|e| service_err(&names.graph, "open or create", e))?;
        let graph_publisher = graph_service
            .publisher_builder()
            .max_loaned_samples(1)
            .create()
            .map_err(|e| service_err(&names.graph, "create publisher", e))?;

        let name = service_name(&config.prefix, &names.graph_updated)?;
        let event = node
            .service_builder(&name)
            .event()
            .event_id_max_value(EVENT_ID_MAX_VALUE)
            .max_listeners(config.max_subscribers)
            .open_or_create()
            .map_err(|e| service_err(&names.graph_updated, "open or create", e))?;
        let notifier =
            event.notifier_builder().create().map_err(|e| service_err(&names.graph_updated, "create notifier", e))?;

        let name = service_name(&config.prefix, &names.health)?;
        let health_service = node
            .service_builder(&name)
            .publish_subscribe::<Health>()
            .history_size(HISTORY_SIZE)
            .enable_safe_overflow(true)
            .max_subscribers(config.max_subscribers)
            .max_publishers(1)
            .open_or_create()
            .map_err(|e| service_err(&names.health, "open or create", e))?;
        let health_publisher = health_service
            .publisher_builder()
            .create()
            .map_err(|e| service_err(&names.health, "create publisher", e))?;

        let pose_subscriber = open_pose_subscriber(&node, &config.prefix, &names.pose, config.pose_buffer)?;
        tracing::info!(prefix = %config.prefix, "serving the scene graph over iceoryx2");
        Ok(Self {
            names,
            graph_service,
            graph_publisher,
            notifier,
            health_publisher,
            pose_subscriber,
            invalid_poses: 0,
            dead_nodes_cleaned,
            node,
        })
    }

    /// The service names served.
    pub fn names(&self) -> &ServiceNames {
        &self.names
    }

    /// Dead nodes whose resources were removed at start.
    pub fn dead_nodes_cleaned(&self) -> u64 {
        self.dead_nodes_cleaned
    }

    /// The iceoryx2 node (for a `WaitSet` or `node.wait`).
    pub fn node(&self) -> &Node<IpcService> {
        &self.node
    }

    /// Subscribers connected to `graph` now.
    pub fn subscriber_count(&self) -> usize {
        use iceoryx2::service::port_factory::PortFactory as _;
        self.graph_service.dynamic_config().number_of_subscribers()
    }

    /// Connects subscribers that joined since the last call and hands them the history (the
    /// newest graph and health). iceoryx2 does this from the publisher side only, so the publisher
    /// thread must call this regularly (every ~100 ms) and not just on graph changes.
    pub fn update_connections(&self) -> Result<(), IpcError> {
        self.graph_publisher
            .update_connections()
            .map_err(|e| service_err(&self.names.graph, "update connections", e))?;
        self.health_publisher.update_connections().map_err(|e| service_err(&self.names.health, "update connections", e))
    }

    /// Publishes `graph` (written in place into a loaned sample), then notifies `graph_updated`
    /// (event id [`GRAPH_UPDATED_EVENT_ID`]).
    pub fn publish_graph(&mut self, graph: &SceneGraph) -> Result<PublishReport, IpcError> {
        let sample = self.graph_publisher.loan_uninit().map_err(|e| service_err(&self.names.graph, "loan", e))?;
        let mut sample = init_snapshot_in_place(sample);
        let report = fill_snapshot(graph, sample.payload_mut());
        sample.payload_mut().header.publish_time_ns = wall_clock_ns();
        sample.send().map_err(|e| service_err(&self.names.graph, "send", e))?;
        self.notifier
            .notify_with_custom_event_id(EventId::new(GRAPH_UPDATED_EVENT_ID))
            .map_err(|e| service_err(&self.names.graph_updated, "notify", e))?;
        if report.truncated {
            tracing::warn!(
                nodes = report.total_nodes,
                edges = report.total_edges,
                published_nodes = report.nodes_written,
                published_edges = report.edges_written,
                "graph exceeds the snapshot capacity; published the most recently seen part"
            );
        }
        Ok(report)
    }

    /// Publishes a health record.
    pub fn publish_health(&mut self, health: &Health) -> Result<(), IpcError> {
        self.health_publisher.send_copy(*health).map(|_| ()).map_err(|e| service_err(&self.names.health, "send", e))
    }

    /// Moves every received pose into `out`; poses with an unknown kind, a non-finite translation
    /// or a quaternion whose norm is off by more than [`QUATERNION_NORM_TOLERANCE`] are dropped
    /// and counted ([`Self::invalid_pose_count`]). Returns the number of poses appended.
    pub fn poll_poses(&mut self, out: &mut Vec<PoseStamped>) -> Result<usize, IpcError> {
        let mut accepted = 0;
        while let Some(sample) =
            self.pose_subscriber.receive().map_err(|e| service_err(&self.names.pose, "receive", e))?
        {
            let pose = *sample.payload();
            match check_pose(&pose) {
                Ok(()) => {
                    out.push(pose);
                    accepted += 1;
                }
                Err(reason) => {
                    self.invalid_poses += 1;
                    if self.invalid_poses.is_power_of_two() {
                        tracing::warn!(service = %self.names.pose, invalid = self.invalid_poses, "dropped pose: {reason}");
                    }
                }
            }
        }
        Ok(accepted)
    }

    /// Poses dropped as invalid since start.
    pub fn invalid_pose_count(&self) -> u64 {
        self.invalid_poses
    }
}

fn check_pose(pose: &PoseStamped) -> Result<(), String> {
    if PoseKind::from_u8(pose.kind).is_none() {
        return Err(format!("unknown kind {}", pose.kind));
    }
    if !pose.translation_m.iter().all(|v| v.is_finite()) {
        return Err("non-finite translation".to_owned());
    }
    let norm = pose.rotation_xyzw.iter().map(|v| v * v).sum::<f64>().sqrt();
    if !norm.is_finite() || (norm - 1.0).abs() > QUATERNION_NORM_TOLERANCE {
        return Err(format!("quaternion norm {norm} is not 1"));
    }
    Ok(())
}

/// Opens (or creates) `pose` for the daemon. If a client created it with a smaller buffer than
/// requested, the daemon still opens it (with the client's buffer) rather than refusing to start.
fn open_pose_subscriber(
    node: &Node<IpcService>,
    prefix: &str,
    service: &str,
    buffer: usize,
) -> Result<Subscriber<IpcService, PoseStamped, ()>, IpcError> {
    let name = service_name(prefix, service)?;
    let builder = || {
        node.service_builder(&name)
            .publish_subscribe::<PoseStamped>()
            .enable_safe_overflow(true)
            .max_publishers(POSE_MAX_PUBLISHERS)
            .max_subscribers(POSE_MAX_SUBSCRIBERS)
    };
    let factory = match builder().subscriber_max_buffer_size(buffer).open_or_create() {
        Ok(f) => f,
        Err(PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
            PublishSubscribeOpenError::DoesNotSupportRequestedMinBufferSize,
        )) => {
            tracing::warn!(service, buffer, "pose service exists with a smaller buffer than configured; using it");
            builder().open().map_err(|e| service_err(service, "open", e))?
        }
        Err(e) => return Err(service_err(service, "open or create", e)),
    };
    factory.subscriber_builder().create().map_err(|e| service_err(service, "create subscriber", e))
}

/// The planner's side: reads the newest graph and health, waits for updates.
#[derive(Debug)]
pub struct GraphClient {
    prefix: String,
    names: ServiceNames,
    graph_subscriber: Subscriber<IpcService, GraphSnapshot, ()>,
    listener: Listener<IpcService>,
    health_subscriber: Subscriber<IpcService, Health, ()>,
    last_header: Option<GraphHeader>,
    node: Node<IpcService>,
}

impl GraphClient {
    /// Opens the daemon's services under `prefix`; fails with [`IpcError::NotServing`] if no
    /// daemon has created them.
    pub fn open(prefix: &str, node_name: &str) -> Result<Self, IpcError> {
        let node = create_node(node_name)?;
        cleanup_dead_nodes(&node);
        Self::open_with_node(prefix, node)
    }

    /// Like [`Self::open`], but retries every 100 ms while no daemon serves `prefix`, up to
    /// `timeout`.
    pub fn open_wait(prefix: &str, node_name: &str, timeout: Duration) -> Result<Self, IpcError> {
        let deadline = Instant::now() + timeout;
        let mut node = create_node(node_name)?;
        cleanup_dead_nodes(&node);
        loop {
            match Self::open_with_node(prefix, node) {
                Err(IpcError::NotServing { .. }) if Instant::now() < deadline => {
                    std::thread::sleep(Duration::from_millis(100).min(deadline - Instant::now()));
                    node = create_node(node_name)?;
                }
                result => return result,
            }
        }
    }

    fn open_with_node(prefix: &str, node: Node<IpcService>) -> Result<Self, IpcError> {
        let names = ServiceNames::new(prefix);
        let not_serving =
            |service: &str| IpcError::NotServing { prefix: prefix.to_owned(), service: service.to_owned() };

        let name = service_name(prefix, &names.graph)?;
        let graph_service = match node.service_builder(&name).publish_subscribe::<GraphSnapshot>().open() {
            Ok(s) => s,
            Err(PublishSubscribeOpenError::DoesNotExist) => return Err(not_serving(&names.graph)),
            Err(e) => return Err(service_err(&names.graph, "open", e)),
        };
        let graph_subscriber = graph_service
            .subscriber_builder()
            .history_request(HISTORY_SIZE)
            .create()
            .map_err(|e| service_err(&names.graph, "create subscriber", e))?;

        let name = service_name(prefix, &names.graph_updated)?;
        let event = match node.service_builder(&name).event().open() {
            Ok(s) => s,
            Err(EventOpenError::DoesNotExist) => return Err(not_serving(&names.graph_updated)),
            Err(e) => return Err(service_err(&names.graph_updated, "open", e)),
        };
        let listener =
            event.listener_builder().create().map_err(|e| service_err(&names.graph_updated, "create listener", e))?;

        let name = service_name(prefix, &names.health)?;
        let health_service = match node.service_builder(&name).publish_subscribe::<Health>().open() {
            Ok(s) => s,
            Err(PublishSubscribeOpenError::DoesNotExist) => return Err(not_serving(&names.health)),
            Err(e) => return Err(service_err(&names.health, "open", e)),
        };
        let health_subscriber = health_service
            .subscriber_builder()
            .history_request(HISTORY_SIZE)
            .create()
            .map_err(|e| service_err(&names.health, "create subscriber", e))?;
        Ok(Self {
            prefix: prefix.to_owned(),
            names,
            graph_subscriber,
            listener,
            health_subscriber,
            last_header: None,
            node,
        })
    }

    /// The prefix served.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The iceoryx2 node (for a `WaitSet`).
    pub fn node(&self) -> &Node<IpcService> {
        &self.node
    }

    /// Drains the received graph samples and converts the newest; `None` when nothing arrived
    /// since the last call. Holds at most one sample at a time.
    pub fn latest_graph(&mut self) -> Result<Option<SceneGraph>, IpcError> {
        let service = &self.names.graph;
        let mut newest = None;
        while self.graph_subscriber.has_samples().map_err(|e| service_err(service, "connect", e))? {
            drop(newest.take()); // release the older sample before borrowing the next
            newest = self.graph_subscriber.receive().map_err(|e| service_err(service, "receive", e))?;
        }
        let Some(sample) = newest else { return Ok(None) };
        let graph = snapshot_to_scene_graph(sample.payload())
            .map_err(|source| IpcError::InvalidSnapshot { service: service.clone(), source })?;
        self.last_header = Some(sample.payload().header);
        Ok(Some(graph))
    }

    /// Header of the graph last returned by [`Self::latest_graph`] (publish time, capacity flag,
    /// real totals).
    pub fn last_header(&self) -> Option<&GraphHeader> {
        self.last_header.as_ref()
    }

    /// Waits up to `timeout` for a `graph_updated` notification; `true` if one (or more) came.
    /// A signal that interrupts the wait (Ctrl-C) returns `Ok(false)` early, so the caller can
    /// check its own stop flag.
    pub fn wait_for_update(&self, timeout: Duration) -> Result<bool, IpcError> {
        match self.listener.timed_wait(|_| {}, timeout) {
            Ok(count) => Ok(count > 0),
            Err(ListenerWaitError::InterruptSignal) => Ok(false),
            Err(e) => Err(service_err(&self.names.graph_updated, "wait", e)),
        }
    }

    /// Drains the received health records and returns the newest; `None` when nothing arrived
    /// since the last call.
    pub fn latest_health(&mut self) -> Result<Option<Health>, IpcError> {
        let service = &self.names.health;
        let mut newest = None;
        while let Some(sample) = self.health_subscriber.receive().map_err(|e| service_err(service, "receive", e))? {
            newest = Some(*sample.payload());
        }
        match newest {
            Some(h) if h.schema_version != SCHEMA_VERSION => {
                Err(IpcError::HealthSchema { service: service.clone(), found: h.schema_version })
            }
            other => Ok(other),
        }
    }
}

/// A [`Health`] record in owned, serialisable form (`op3dsg health --json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HealthReport {
    /// Wire-contract version of the record.
    pub schema_version: u32,
    /// Wall-clock time of the record, nanoseconds since the Unix epoch.
    pub stamp_ns: u64,
    /// Seconds since the daemon started.
    pub uptime_s: f64,
    /// Frames delivered by the source since start.
    pub frames_captured: u64,
    /// Frames accepted by the keyframe gate.
    pub keyframes: u64,
    /// Frames dropped for lack of a pose.
    pub frames_without_pose: u64,
    /// Detections fused since start.
    pub detections_fused: u64,
    /// Current graph version.
    pub graph_version: u64,
    /// Nodes in the map (confirmed and pending).
    pub map_node_count: u32,
    /// Heap bytes the fusion map holds.
    #[serde(default)]
    pub map_memory_bytes: u64,
    /// Whether the frame source delivers.
    pub source_connected: bool,
    /// Per-stage figures.
    pub stages: Vec<StageReport>,
    /// Per-queue figures.
    pub queues: Vec<QueueReport>,
    /// The LLM refiner.
    #[serde(default)]
    pub refiner: RefinerReport,
}

/// The LLM refiner in a [`HealthReport`] (see `op3dsg_ipc_types::RefinerHealth`).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RefinerReport {
    /// State (`off`, `idle`, `calling`, `backoff`, `breaker_open`, `budget_exhausted`).
    pub state: String,
    /// Whether the circuit breaker is open.
    pub breaker_open: bool,
    /// Refreshes started.
    pub refreshes: u64,
    /// HTTP requests sent, retries included.
    pub calls: u64,
    /// Requests that failed.
    pub failures: u64,
    /// Of `failures`: timeouts.
    pub timeouts: u64,
    /// Of `failures`: 429 answers.
    pub rate_limited: u64,
    /// Items that passed the verification gate.
    pub accepted: u64,
    /// Rejections by reason (`malformed`, `unknown_node`, `wrong_kind`, `non_canonical`, `stale`).
    pub rejections: std::collections::BTreeMap<String, u64>,
    /// Latency of the last call, microseconds.
    pub last_latency_us: u32,
    /// Graph version of the last verified result.
    pub last_graph_version: u64,
}

impl From<&op3dsg_ipc_types::RefinerHealth> for RefinerReport {
    fn from(r: &op3dsg_ipc_types::RefinerHealth) -> Self {
        Self {
            state: op3dsg_ipc_types::REFINER_STATES.get(r.state as usize).copied().unwrap_or("unknown").to_owned(),
            breaker_open: r.breaker_open != 0,
            refreshes: r.refreshes,
            calls: r.calls,
            failures: r.failures,
            timeouts: r.timeouts,
            rate_limited: r.rate_limited,
            accepted: r.accepted,
            rejections: op3dsg_ipc_types::REFINER_REJECTIONS
                .iter()
                .zip(r.rejections)
                .map(|(name, n)| ((*name).to_owned(), n))
                .collect(),
            last_latency_us: r.last_latency_us,
            last_graph_version: r.last_graph_version,
        }
    }
}

/// One stage of a [`HealthReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct StageReport {
    /// Stage name.
    pub name: String,
    /// Items processed since start.
    pub processed: u64,
    /// Items per second over the last period.
    pub rate_hz: f32,
    /// Median latency, microseconds.
    pub latency_p50_us: f32,
    /// 99th percentile latency, microseconds.
    pub latency_p99_us: f32,
    /// Errors since start.
    pub errors: u32,
}

/// One queue of a [`HealthReport`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QueueReport {
    /// Queue name.
    pub name: String,
    /// Items waiting now.
    pub depth: u32,
    /// Capacity.
    pub capacity: u32,
    /// Items dropped since start.
    pub dropped: u64,
    /// Items pushed since start.
    pub pushed: u64,
}

impl From<&Health> for HealthReport {
    fn from(h: &Health) -> Self {
        Self {
            schema_version: h.schema_version,
            stamp_ns: h.stamp_ns,
            uptime_s: h.uptime_ns as f64 * 1e-9,
            frames_captured: h.frames_captured,
            keyframes: h.keyframes,
            frames_without_pose: h.frames_without_pose,
            detections_fused: h.detections_fused,
            graph_version: h.graph_version,
            map_node_count: h.map_node_count,
            map_memory_bytes: h.map_memory_bytes,
            source_connected: h.source_connected != 0,
            stages: h
                .valid_stages()
                .iter()
                .map(|s| StageReport {
                    name: op3dsg_ipc_types::fixed_str(&s.name).to_owned(),
                    processed: s.processed,
                    rate_hz: s.rate_hz,
                    latency_p50_us: s.latency_p50_us,
                    latency_p99_us: s.latency_p99_us,
                    errors: s.errors,
                })
                .collect(),
            queues: h
                .valid_queues()
                .iter()
                .map(|q| QueueReport {
                    name: op3dsg_ipc_types::fixed_str(&q.name).to_owned(),
                    depth: q.depth,
                    capacity: q.capacity,
                    dropped: q.dropped,
                    pushed: q.pushed,
                })
                .collect(),
            refiner: RefinerReport::from(&h.refiner),
        }
    }
}

/// Sends camera or base poses to the daemon on `<prefix>/pose` (navigation stacks, tools, tests).
#[derive(Debug)]
pub struct PosePublisher {
    service: String,
    publisher: Publisher<IpcService, PoseStamped, ()>,
    _node: Node<IpcService>,
}

impl PosePublisher {
    /// Opens (or creates, with the daemon's default QoS) `<prefix>/pose`.
    pub fn open(prefix: &str, node_name: &str) -> Result<Self, IpcError> {
        let node = create_node(node_name)?;
        let service = ServiceNames::new(prefix).pose;
        let name = service_name(prefix, &service)?;
        let factory = node
            .service_builder(&name)
            .publish_subscribe::<PoseStamped>()
            .enable_safe_overflow(true)
            .subscriber_max_buffer_size(DEFAULT_POSE_BUFFER)
            .max_publishers(POSE_MAX_PUBLISHERS)
            .max_subscribers(POSE_MAX_SUBSCRIBERS)
            .open_or_create()
            .or_else(|e| match e {
                // The daemon created it with a smaller configured buffer: use it as it is.
                PublishSubscribeOpenOrCreateError::PublishSubscribeOpenError(
                    PublishSubscribeOpenError::DoesNotSupportRequestedMinBufferSize,
                ) => node
                    .service_builder(&name)
                    .publish_subscribe::<PoseStamped>()
                    .open()
                    .map_err(|e| service_err(&service, "open", e)),
                e => Err(service_err(&service, "open or create", e)),
            })?;
        let publisher =
            factory.publisher_builder().create().map_err(|e| service_err(&service, "create publisher", e))?;
        Ok(Self { service, publisher, _node: node })
    }

    /// Sends `world_from_x` (camera or base, as `kind` says) valid at `stamp_ns`; `frame_id`
    /// names the child frame and must fit 32 bytes.
    pub fn publish(
        &mut self,
        stamp_ns: u64,
        kind: PoseKind,
        world_from_x: &Isometry,
        frame_id: &str,
    ) -> Result<(), IpcError> {
        let q = world_from_x.rotation;
        let t = world_from_x.translation;
        let mut pose = PoseStamped {
            stamp_ns,
            kind: kind as u8,
            translation_m: [t.x, t.y, t.z],
            rotation_xyzw: [q.x, q.y, q.z, q.w],
            ..PoseStamped::default()
        };
        if !op3dsg_ipc_types::write_fixed_str(&mut pose.frame_id, frame_id) {
            return Err(IpcError::InvalidArgument {
                what: "frame_id",
                reason: format!("\"{frame_id}\" is longer than {NAME_CAPACITY_BYTES} bytes"),
            });
        }
        self.publisher.send_copy(pose).map(|_| ()).map_err(|e| service_err(&self.service, "send", e))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use op3dsg_ipc_types::Node as WireNode;

    fn node(id: u32, kind: NodeKind, last_seen: u64) -> GraphNode {
        GraphNode {
            id,
            kind,
            parent_id: None,
            label: format!("n{id}"),
            confidence: 0.5,
            centre_m: [id as f32, 0.0, 0.0],
            box_min_m: [0.0; 3],
            box_max_m: [1.0; 3],
            observation_count: 3,
            affordance_bits: 0,
            last_seen_stamp_ns: last_seen,
        }
    }

    fn edge(s: u32, t: u32) -> GraphEdge {
        GraphEdge {
            source_id: s,
            target_id: t,
            kind: EdgeKind::Spatial,
            relation_id: 5,
            confidence: 0.9,
            origin: EdgeOrigin::Geometry,
        }
    }

    /// A zeroed snapshot on the heap, built without the stack (tests only).
    fn heap_snapshot() -> Box<GraphSnapshot> {
        // Build through a Vec of the field arrays so nothing 3.9 MiB lands on the stack.
        let nodes: Box<[WireNode; MAX_NODES]> =
            vec![WireNode::default(); MAX_NODES].into_boxed_slice().try_into().expect("exact length");
        let edges: Box<[Edge; MAX_EDGES]> =
            vec![Edge::default(); MAX_EDGES].into_boxed_slice().try_into().expect("exact length");
        // Moving the arrays into a struct would copy them through the stack; test threads get a
        // large stack (see `big_stack`), which makes that acceptable here.
        Box::new(GraphSnapshot { header: Default::default(), nodes: *nodes, edges: *edges })
    }

    fn big_stack(f: impl FnOnce() + Send + 'static) {
        std::thread::Builder::new()
            .name("snapshot-test".into())
            .stack_size(64 << 20)
            .spawn(f)
            .expect("spawn test thread")
            .join()
            .expect("test thread panicked");
    }

    #[test]
    fn round_trip_small_graph() {
        big_stack(|| {
            let mut snap = heap_snapshot();
            let mut part = node(7, NodeKind::Part, 20);
            part.parent_id = Some(3);
            part.affordance_bits = 0b1000;
            let graph = SceneGraph {
                version: 42,
                stamp_ns: 99,
                nodes: vec![part, node(3, NodeKind::Object, 10)],
                edges: vec![edge(7, 3)],
            };
            let report = fill_snapshot(&graph, &mut snap);
            assert!(!report.truncated);
            assert_eq!((report.nodes_written, report.edges_written), (2, 1));
            assert_eq!(snap.header.capacity_exceeded, 0);
            assert_eq!((snap.header.object_count, snap.header.part_count), (1, 1));
            assert_eq!(snap.edges[0].phrase_str(), "next to");
            let back = snapshot_to_scene_graph(&snap).expect("valid");
            // Sorted by id on the wire.
            assert_eq!(back.nodes.iter().map(|n| n.id).collect::<Vec<_>>(), [3, 7]);
            let mut expected = graph.clone();
            expected.nodes.sort_by_key(|n| n.id);
            assert_eq!(back, expected);
        });
    }

    #[test]
    fn truncation_keeps_most_recent_nodes_and_prunes_edges() {
        big_stack(|| {
            let mut snap = heap_snapshot();
            let extra = 10;
            let total = MAX_NODES + extra;
            // Node id i seen at stamp i, except the ten lowest ids are the most recent.
            let mut nodes: Vec<GraphNode> = (0..total as u32)
                .map(|i| node(i, NodeKind::Object, if i < 10 { 1_000_000 } else { i as u64 }))
                .collect();
            nodes.reverse(); // input order must not matter
            let edges = vec![edge(0, 1), edge(10, 11), edge(total as u32 - 1, 0), edge(5, 9999999)];
            let graph = SceneGraph { version: 1, stamp_ns: 1, nodes, edges };
            let report = fill_snapshot(&graph, &mut snap);
            assert!(report.truncated);
            assert_eq!(report.nodes_written, MAX_NODES);
            assert_eq!(report.total_nodes, total);
            assert_eq!(snap.header.capacity_exceeded, 1);
            assert_eq!(snap.header.total_node_count as usize, total);
            assert_eq!(snap.header.total_edge_count, 4);
            // Dropped: ids 10..10+extra (the oldest stamps).
            let ids: Vec<u32> = snap.valid_nodes().iter().map(|n| n.id).collect();
            assert!(ids.windows(2).all(|w| w[0] < w[1]), "sorted by id");
            assert!(ids.contains(&0) && ids.contains(&9) && !ids.contains(&10) && !ids.contains(&19));
            assert!(ids.contains(&20));
            // Kept: 0-1 and last-0; pruned: 10-11 (endpoints dropped); dangling: 5-9999999.
            assert_eq!(report.edges_written, 2);
            assert_eq!(report.dangling_edges, 1);
            let kept: Vec<(u32, u32)> = snap.valid_edges().iter().map(|e| (e.source_id, e.target_id)).collect();
            assert_eq!(kept, [(0, 1), (total as u32 - 1, 0)]);
        });
    }

    #[test]
    fn ties_at_the_cut_prefer_lower_ids() {
        big_stack(|| {
            let mut snap = heap_snapshot();
            let nodes: Vec<GraphNode> = (0..MAX_NODES as u32 + 2).map(|i| node(i, NodeKind::Part, 5)).collect();
            let graph = SceneGraph { version: 1, stamp_ns: 1, nodes, edges: vec![] };
            let report = fill_snapshot(&graph, &mut snap);
            assert!(report.truncated);
            assert_eq!(snap.valid_nodes().last().map(|n| n.id), Some(MAX_NODES as u32 - 1));
            assert_eq!(snap.header.part_count as usize, MAX_NODES);
        });
    }

    #[test]
    fn too_many_edges_sets_capacity_flag() {
        big_stack(|| {
            let mut snap = heap_snapshot();
            let nodes = vec![node(1, NodeKind::Object, 1), node(2, NodeKind::Object, 2)];
            let edges: Vec<GraphEdge> = (0..MAX_EDGES + 3).map(|_| edge(1, 2)).collect();
            let graph = SceneGraph { version: 3, stamp_ns: 0, nodes, edges };
            let report = fill_snapshot(&graph, &mut snap);
            assert!(report.truncated);
            assert_eq!(report.edges_written, MAX_EDGES);
            assert_eq!(snap.header.edge_count as usize, MAX_EDGES);
            assert_eq!(snap.header.total_edge_count as usize, MAX_EDGES + 3);
            assert_eq!(snap.header.capacity_exceeded, 1);
        });
    }

    #[test]
    fn long_labels_are_cut_at_a_char_boundary() {
        big_stack(|| {
            let mut snap = heap_snapshot();
            let mut n = node(1, NodeKind::Object, 1);
            n.label = "ä".repeat(30); // 60 bytes; 48 bytes = 24 chars
            let graph = SceneGraph { version: 1, stamp_ns: 0, nodes: vec![n], edges: vec![] };
            let report = fill_snapshot(&graph, &mut snap);
            assert_eq!(report.labels_cut, 1);
            assert_eq!(snap.nodes[0].label_str(), "ä".repeat(24));
        });
    }

    #[test]
    fn unknown_kinds_name_the_entry() {
        big_stack(|| {
            let mut snap = heap_snapshot();
            let graph = SceneGraph {
                version: 1,
                stamp_ns: 0,
                nodes: vec![node(1, NodeKind::Object, 1), node(2, NodeKind::Part, 1)],
                edges: vec![edge(1, 2)],
            };
            fill_snapshot(&graph, &mut snap);
            snap.nodes[1].kind = 9;
            assert_eq!(snapshot_to_scene_graph(&snap), Err(SnapshotError::UnknownNodeKind { index: 1, value: 9 }));
            snap.nodes[1].kind = 1;
            snap.edges[0].origin = 7;
            let err = snapshot_to_scene_graph(&snap).expect_err("bad origin");
            assert_eq!(err.to_string(), "edges[0].origin: unknown value 7 (0..=3)");
            let other = op3dsg_ipc_types::SCHEMA_VERSION + 1;
            snap.header.schema_version = other;
            assert!(matches!(
                snapshot_to_scene_graph(&snap),
                Err(SnapshotError::SchemaVersion { found, .. }) if found == other
            ));
        });
    }

    #[test]
    fn config_validation_names_the_field() {
        let mut c = IpcConfig::default();
        assert_eq!(c.validate("ipc"), Ok(()));
        c.prefix.clear();
        assert_eq!(c.validate("ipc").expect_err("empty"), "ipc.prefix: must not be empty");
        c.prefix = "op3dsg robot".into();
        assert!(c.validate("ipc").expect_err("space").starts_with("ipc.prefix: invalid character ' '"));
        c.prefix = "/abs".into();
        assert!(c.validate("ipc").is_err());
        c.prefix = "lab/robot-1".into();
        assert_eq!(c.validate("ipc"), Ok(()));
        c.subscriber_buffer = 0;
        assert_eq!(c.validate("ipc").expect_err("zero"), "ipc.subscriber_buffer: must be between 1 and 16, found 0");
        let parsed: Result<IpcConfig, _> = toml::from_str("prefix = \"x\"\nbogus = 1\n");
        assert!(parsed.is_err());
        let parsed: IpcConfig = toml::from_str("prefix = \"x\"\n").expect("partial table");
        assert_eq!(parsed.max_subscribers, 8);
    }

    #[test]
    fn pose_checks() {
        let mut p = PoseStamped { rotation_xyzw: [0.0, 0.0, 0.0, 1.0], ..PoseStamped::default() };
        assert_eq!(check_pose(&p), Ok(()));
        p.kind = 4;
        assert!(check_pose(&p).is_err());
        p.kind = 1;
        p.rotation_xyzw = [0.0, 0.0, 0.0, 0.9];
        assert!(check_pose(&p).expect_err("norm").contains("norm"));
        p.rotation_xyzw = [0.0, 0.0, 0.0, 1.0];
        p.translation_m[0] = f64::NAN;
        assert!(check_pose(&p).is_err());
    }
}
