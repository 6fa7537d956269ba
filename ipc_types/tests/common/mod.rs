//! A stand-in for the daemon's side of the services, built from the crate's QoS constants the way
//! `op3dsgd` creates them, and graph samples written in place in shared memory.

#![allow(dead_code)] // Each test binary uses a different part.

use std::sync::atomic::{AtomicUsize, Ordering};

use iceoryx2::node::Node as IoxNode;
use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::{EventId, NodeBuilder, NodeName, SignalHandlingMode};
use op3dsg_ipc_types::publish::{GraphBuffer, GraphPayload};
use op3dsg_ipc_types::services::{
    EVENT_ID_MAX_VALUE, GRAPH_MAX_PUBLISHERS, GRAPH_PUBLISHER_MAX_LOANED_SAMPLES, GRAPH_UPDATED_EVENT_ID,
    HEALTH_MAX_PUBLISHERS, HISTORY_SIZE, SAFE_OVERFLOW, SUBSCRIBER_MAX_BORROWED_SAMPLES, service_name,
};
use op3dsg_ipc_types::{
    Edge, EdgeOrigin, GraphHeader, Health, IpcService, MAX_EDGES, MAX_NODES, NO_NODE, Node, NodeKind, SCHEMA_VERSION,
    ServiceKind, affordance_bits, graph_payload_bytes, relation_id, write_fixed_str,
};

/// The fake daemon's instance id.
pub const INSTANCE_ID: u64 = 0x0bad_cafe;

static NEXT: AtomicUsize = AtomicUsize::new(0);

/// A prefix no other test, nor another run of this test binary, uses.
pub fn unique_prefix() -> String {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    format!("op3dsg-ipc-test-{}-{}", std::process::id(), NEXT.fetch_add(1, Ordering::SeqCst))
}

pub fn node(name: &str) -> IoxNode<IpcService> {
    NodeBuilder::new()
        .name(&NodeName::new(name).expect("valid node name"))
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .config(&op3dsg_ipc_types::access::creator_config().expect("IPC root"))
        .create::<IpcService>()
        .expect("create iceoryx2 node")
}

/// The daemon's services under one prefix, created with the contract's QoS.
pub struct FakeDaemon {
    graph: Option<(Publisher<IpcService, GraphPayload, GraphHeader>, Notifier<IpcService>)>,
    buffer: std::cell::RefCell<GraphBuffer>,
    health: Publisher<IpcService, Health, ()>,
    _node: IoxNode<IpcService>,
}

impl FakeDaemon {
    /// All of `graph`, `graph_updated` and `health`; `max_subscribers` per service (the daemon's
    /// `ipc.max_subscribers`), buffer 2 per graph subscriber.
    pub fn start(prefix: &str, max_subscribers: usize) -> Self {
        let node = node("op3dsg-test-daemon");
        let name = service_name(prefix, ServiceKind::Graph).expect("valid prefix");
        let graph_service = node
            .service_builder(&name)
            .publish_subscribe::<GraphPayload>()
            .user_header::<GraphHeader>()
            .history_size(HISTORY_SIZE)
            .enable_safe_overflow(SAFE_OVERFLOW)
            .subscriber_max_buffer_size(op3dsg_ipc_types::services::DEFAULT_GRAPH_SUBSCRIBER_BUFFER)
            .subscriber_max_borrowed_samples(SUBSCRIBER_MAX_BORROWED_SAMPLES)
            .max_subscribers(max_subscribers)
            .max_publishers(GRAPH_MAX_PUBLISHERS)
            .create()
            .expect("create graph service");
        let graph_publisher = graph_service
            .publisher_builder()
            .max_loaned_samples(GRAPH_PUBLISHER_MAX_LOANED_SAMPLES)
            .initial_max_slice_len(graph_payload_bytes(MAX_NODES, MAX_EDGES))
            .create()
            .expect("create graph publisher");
        let name = service_name(prefix, ServiceKind::GraphUpdated).expect("valid prefix");
        let event = node
            .service_builder(&name)
            .event()
            .event_id_max_value(EVENT_ID_MAX_VALUE)
            .max_listeners(max_subscribers)
            .create()
            .expect("create graph_updated");
        let notifier = event.notifier_builder().create().expect("create notifier");
        let health = Self::health_publisher(&node, prefix, max_subscribers);
        Self { graph: Some((graph_publisher, notifier)), buffer: Default::default(), health, _node: node }
    }

    /// `health` alone, as when only the health service is up.
    pub fn start_health_only(prefix: &str) -> Self {
        let node = node("op3dsg-test-daemon");
        let health = Self::health_publisher(&node, prefix, 2);
        Self { graph: None, buffer: Default::default(), health, _node: node }
    }

    fn health_publisher(
        node: &IoxNode<IpcService>,
        prefix: &str,
        max_subscribers: usize,
    ) -> Publisher<IpcService, Health, ()> {
        let name = service_name(prefix, ServiceKind::Health).expect("valid prefix");
        node.service_builder(&name)
            .publish_subscribe::<Health>()
            .history_size(HISTORY_SIZE)
            .enable_safe_overflow(SAFE_OVERFLOW)
            .max_subscribers(max_subscribers)
            .max_publishers(HEALTH_MAX_PUBLISHERS)
            .create()
            .expect("create health service")
            .publisher_builder()
            .create()
            .expect("create health publisher")
    }

    /// Lets `fill` write a graph (into a cleared, reused buffer with the daemon's capacities),
    /// sends it in a sample sized to it and notifies `graph_updated`.
    pub fn publish_graph(&self, fill: impl FnOnce(&mut GraphBuffer)) {
        let (publisher, notifier) = self.graph.as_ref().expect("graph service started");
        let mut buffer = self.buffer.borrow_mut();
        buffer.header = GraphHeader {
            node_capacity: MAX_NODES as u32,
            edge_capacity: MAX_EDGES as u32,
            instance_id: INSTANCE_ID,
            ..GraphHeader::default()
        };
        buffer.nodes.clear();
        buffer.edges.clear();
        fill(&mut buffer);
        buffer.send(publisher).expect("send graph");
        notifier.notify_with_custom_event_id(EventId::new(GRAPH_UPDATED_EVENT_ID)).expect("notify");
    }

    pub fn publish_health(&self, health: &Health) {
        self.health.send_copy(*health).expect("send health");
    }

    /// Hands late subscribers the history, as the daemon's publisher thread does every ~100 ms.
    pub fn update_connections(&self) {
        if let Some((publisher, _)) = &self.graph {
            publisher.update_connections().expect("update graph connections");
        }
        self.health.update_connections().expect("update health connections");
    }
}

fn push_node(s: &mut GraphBuffer, id: u32, kind: NodeKind, parent_id: u32, label: &str, affordances: &[&str]) {
    let mut node = Node { id, parent_id, kind: kind as u8, ..Node::default() };
    write_fixed_str(&mut node.label, label);
    node.confidence = 0.9;
    node.centre_m = [id as f32 * 0.5, 0.25, 0.75];
    node.box_min_m = [id as f32 * 0.5 - 0.1, 0.0, 0.5];
    node.box_max_m = [id as f32 * 0.5 + 0.1, 0.5, 1.0];
    node.affordance_bits = affordance_bits(affordances.iter().copied()).expect("canonical affordances");
    s.nodes.push(node);
    match kind {
        NodeKind::Object => s.header.object_count += 1,
        NodeKind::Part => s.header.part_count += 1,
    }
}

fn push_edge(s: &mut GraphBuffer, source_id: u32, target_id: u32, phrase: &str, origin: EdgeOrigin) {
    let (kind, relation) = relation_id(phrase).expect("canonical phrase");
    let mut edge =
        Edge { source_id, target_id, kind: kind as u8, origin: origin as u8, relation_id: relation, ..Edge::default() };
    write_fixed_str(&mut edge.phrase, phrase);
    s.edges.push(edge);
}

/// A small kitchen at `version`: cabinet (1) with a handle (2) and a drawer handle (3), stove (10)
/// with a knob (11), a TV (20) and its remote (21, an object); part-of, functional and spatial
/// edges. 4 objects, 3 parts, 6 edges.
pub fn write_kitchen(s: &mut GraphBuffer, version: u64) {
    s.header.schema_version = SCHEMA_VERSION;
    s.header.graph_version = version;
    s.header.stamp_ns = 1_000_000_000 + version;
    push_node(s, 1, NodeKind::Object, NO_NODE, "cabinet", &[]);
    push_node(s, 2, NodeKind::Part, 1, "cabinet handle", &["hook_pull"]);
    push_node(s, 3, NodeKind::Part, 1, "drawer handle", &["pinch_pull"]);
    push_node(s, 10, NodeKind::Object, NO_NODE, "stove", &[]);
    push_node(s, 11, NodeKind::Part, 10, "knob", &["rotate"]);
    push_node(s, 20, NodeKind::Object, NO_NODE, "tv", &[]);
    push_node(s, 21, NodeKind::Object, NO_NODE, "remote", &["key_press"]);
    push_edge(s, 2, 1, "part of", EdgeOrigin::Geometry);
    push_edge(s, 3, 1, "part of", EdgeOrigin::Geometry);
    push_edge(s, 11, 10, "part of", EdgeOrigin::Geometry);
    push_edge(s, 2, 1, "pull to open or close", EdgeOrigin::Knowledge);
    push_edge(s, 21, 20, "remote to control", EdgeOrigin::Llm);
    push_edge(s, 1, 10, "next to", EdgeOrigin::Geometry);
    s.header.total_node_count = s.nodes.len() as u32;
    s.header.total_edge_count = s.edges.len() as u32;
}

/// `count` objects with one part each (ids `2i` and `2i + 1`) and a part-of edge per part.
pub fn write_large(s: &mut GraphBuffer, version: u64, count: u32) {
    s.header.schema_version = SCHEMA_VERSION;
    s.header.graph_version = version;
    for i in 0..count {
        push_node(s, 2 * i, NodeKind::Object, NO_NODE, "cabinet", &[]);
        push_node(s, 2 * i + 1, NodeKind::Part, 2 * i, "handle", &["hook_pull"]);
        push_edge(s, 2 * i + 1, 2 * i, "part of", EdgeOrigin::Geometry);
    }
}
