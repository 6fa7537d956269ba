//! The services table in `ipc_types/src/services.rs` is the contract a C or Python client is
//! written from. This test reads that table and opens every service of a running `op3dsgd` with
//! plain iceoryx2 (no op3dsg client code), stating exactly the documented QoS as requirements,
//! then checks that the service has exactly those values, the documented type names, and behaves
//! as documented (history for late joiners, the borrow limit, the event id).

use std::collections::HashMap;
use std::fmt::Debug;
use std::path::Path;
use std::time::{Duration, Instant};

use iceoryx2::port::ReceiveError;
use iceoryx2::prelude::{IceoryxSend, NodeBuilder, PortFactory as _, ServiceName, ZeroCopySend};
use iceoryx2::service::static_config::message_type_details::MessageTypeDetails;
use iceoryx2::service::static_config::publish_subscribe::StaticConfig;
use iceoryx2::service::{builder, port_factory};
use op3dsg_ipc_types::services::IpcService;
use op3dsg_ipc_types::{GraphHeader, Health, PoseStamped, ServiceKind};
use op3dsg_tests::{Daemon, unique_prefix, wait_for};

/// One row of the documented table.
#[derive(Debug)]
struct Row {
    pattern: String,
    payload: String,
    history: Option<usize>,
    buffer: Option<usize>,
    borrowed: Option<usize>,
    safe_overflow: Option<bool>,
    publishers: usize,
    subscribers: usize,
    nodes: usize,
    event_id: Option<usize>,
}

impl Row {
    /// The type names written in backticks inside parentheses of the payload cell.
    fn type_names(&self) -> Vec<&str> {
        self.payload.split("(`").skip(1).filter_map(|rest| rest.split("`)").next()).collect()
    }
}

/// The table of `ipc_types/src/services.rs`'s module docs, by service suffix.
fn documented_services() -> HashMap<String, Row> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("../ipc_types/src/services.rs");
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("read {}: {e}", path.display()));
    let number = |cell: &str, what: &str, service: &str| -> Option<usize> {
        if cell == "–" {
            return None;
        }
        Some(cell.parse().unwrap_or_else(|_| panic!("{}: {service}: {what} {cell:?} is not a number", path.display())))
    };
    let mut rows = HashMap::new();
    for line in text.lines() {
        let Some(row) = line.strip_prefix("//! | `<prefix>/") else { continue };
        let cells: Vec<&str> = row.split(" | ").map(|c| c.trim().trim_end_matches('|').trim()).collect();
        assert_eq!(cells.len(), 11, "{}: a services row has 11 cells: {line}", path.display());
        let service = cells[0].trim_end_matches('`').to_owned();
        let parsed = Row {
            pattern: cells[1].to_owned(),
            payload: cells[2].to_owned(),
            history: number(cells[3], "history", &service),
            buffer: number(cells[4], "buffer", &service),
            borrowed: number(cells[5], "borrowed", &service),
            safe_overflow: match cells[6] {
                "safe" => Some(true),
                "unsafe" => Some(false),
                _ => None,
            },
            publishers: number(cells[7], "publishers", &service).expect("publishers"),
            subscribers: number(cells[8], "subscribers", &service).expect("subscribers"),
            nodes: number(cells[9], "nodes", &service).expect("nodes"),
            event_id: number(cells[10], "event ids", &service),
        };
        rows.insert(service, parsed);
    }
    rows
}

fn assert_types(service: &str, details: &MessageTypeDetails, names: &[&str]) {
    let actual = [details.payload.type_name().to_string(), details.user_header.type_name().to_string()];
    for name in names {
        assert!(actual.iter().any(|a| a == name), "{service}: documented type name {name:?}, service has {actual:?}");
    }
}

/// `service_builder` with every QoS value of the documented `row` of `service` as a requirement.
fn with_documented_qos<Payload, UserHeader>(
    service_builder: builder::publish_subscribe::Builder<Payload, UserHeader, IpcService>,
    row: &Row,
    service: &str,
) -> builder::publish_subscribe::Builder<Payload, UserHeader, IpcService>
where
    Payload: Debug + IceoryxSend + ?Sized,
    UserHeader: Debug + ZeroCopySend,
{
    service_builder
        .history_size(row.history.unwrap_or_else(|| panic!("{service} history")))
        .subscriber_max_buffer_size(row.buffer.unwrap_or_else(|| panic!("{service} buffer")))
        .subscriber_max_borrowed_samples(row.borrowed.unwrap_or_else(|| panic!("{service} borrowed")))
        .enable_safe_overflow(row.safe_overflow.unwrap_or_else(|| panic!("{service} overflow")))
        .max_publishers(row.publishers)
        .max_subscribers(row.subscribers)
        .max_nodes(row.nodes)
}

/// The publish-subscribe `service` has exactly the QoS and type names of its documented `row`.
fn assert_documented_qos(service: &str, row: &Row, config: &StaticConfig) {
    assert_eq!(Some(config.history_size()), row.history, "{service} history");
    assert_eq!(Some(config.subscriber_max_buffer_size()), row.buffer, "{service} buffer");
    assert_eq!(Some(config.subscriber_max_borrowed_samples()), row.borrowed, "{service} borrowed");
    assert_eq!(Some(config.has_safe_overflow()), row.safe_overflow, "{service} overflow");
    assert_eq!(config.max_publishers(), row.publishers, "{service} publishers");
    assert_eq!(config.max_subscribers(), row.subscribers, "{service} subscribers");
    assert_eq!(config.max_nodes(), row.nodes, "{service} nodes");
    assert_types(service, config.message_type_details(), &row.type_names());
}

#[test]
fn every_service_opens_with_exactly_the_documented_qos() {
    let table = documented_services();
    let mut suffixes: Vec<&str> = table.keys().map(String::as_str).collect();
    suffixes.sort_unstable();
    let mut expected: Vec<&str> = ServiceKind::ALL.iter().map(|k| k.suffix()).collect();
    expected.sort_unstable();
    assert_eq!(suffixes, expected, "the table documents every service and nothing else");

    let prefix = unique_prefix("contract");
    let daemon = Daemon::start(&prefix, &["--set", "source.rate_hz=10", "--set", "health.period_ms=100"]);
    let mut health = daemon.health_subscriber("contract-health");
    wait_for("the daemon's first health record", Duration::from_secs(60), || health.latest().ok().flatten());

    let node = NodeBuilder::new()
        .config(&op3dsg_ipc_types::access::creator_config().expect("IPC root"))
        .create::<IpcService>()
        .expect("a plain iceoryx2 node");
    let name = |kind: ServiceKind| ServiceName::new(&kind.name(&prefix)).expect("service name");

    // graph: a [u8] slice with the GraphHeader user header.
    let row = &table["graph"];
    assert_eq!(row.pattern, "publish-subscribe");
    let graph_builder = node.service_builder(&name(ServiceKind::Graph)).publish_subscribe::<[u8]>();
    let graph = with_documented_qos(graph_builder.user_header::<GraphHeader>(), row, "graph")
        .open()
        .expect("graph opens with the documented QoS as requirements");
    assert_documented_qos("graph", row, graph.static_config());

    // graph_updated: one event id.
    let row = &table["graph_updated"];
    assert_eq!(row.pattern, "event");
    let event = node
        .service_builder(&name(ServiceKind::GraphUpdated))
        .event()
        .event_id_max_value(row.event_id.expect("graph_updated event id"))
        .max_notifiers(row.publishers)
        .max_listeners(row.subscribers)
        .max_nodes(row.nodes)
        .open()
        .expect("graph_updated opens with the documented QoS as requirements");
    let config = event.static_config();
    assert_eq!(config.event_id_max_value(), row.event_id.unwrap(), "graph_updated event ids");
    assert_eq!(config.max_notifiers(), row.publishers, "graph_updated notifiers");
    assert_eq!(config.max_listeners(), row.subscribers, "graph_updated listeners");
    assert_eq!(config.max_nodes(), row.nodes, "graph_updated nodes");

    // health
    let row = &table["health"];
    assert_eq!(row.pattern, "publish-subscribe");
    let health_builder = node.service_builder(&name(ServiceKind::Health)).publish_subscribe::<Health>();
    let health_service = with_documented_qos(health_builder, row, "health")
        .open()
        .expect("health opens with the documented QoS as requirements");
    assert_documented_qos("health", row, health_service.static_config());

    // pose: the daemon created it (nobody else was there first).
    let row = &table["pose"];
    assert_eq!(row.pattern, "publish-subscribe");
    let pose_builder = node.service_builder(&name(ServiceKind::Pose)).publish_subscribe::<PoseStamped>();
    let pose = with_documented_qos(pose_builder, row, "pose")
        .open()
        .expect("pose opens with the documented QoS as requirements");
    assert_documented_qos("pose", row, pose.static_config());

    assert_late_joiner_event_and_borrow_limit(&graph, &event, &table);
}

/// Behaviour: a late joiner gets the newest graph from the history; the one event id wakes it;
/// a second borrow while the first sample is held is refused.
fn assert_late_joiner_event_and_borrow_limit(
    graph: &port_factory::publish_subscribe::PortFactory<IpcService, [u8], GraphHeader>,
    event: &port_factory::event::PortFactory<IpcService>,
    table: &HashMap<String, Row>,
) {
    let history = table["graph"].history.expect("graph history");
    let subscriber = graph.subscriber_builder().history_request(history).create().expect("graph subscriber");
    let listener = event.listener_builder().create().expect("graph_updated listener");
    let first = wait_for("the history sample (or the next graph)", Duration::from_secs(60), || {
        subscriber.receive().expect("receive a graph").filter(|s| s.payload().len() == s.user_header().payload_bytes())
    });
    assert_eq!(first.user_header().schema_version, op3dsg_ipc_types::SCHEMA_VERSION);
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut ids = Vec::new();
    while ids.is_empty() && Instant::now() < deadline {
        listener
            .timed_wait(|id| ids.push(id.id.as_value()), Duration::from_millis(200))
            .expect("wait on graph_updated");
    }
    assert!(!ids.is_empty(), "no graph_updated event within 60 s");
    let event_id = table["graph_updated"].event_id.expect("graph_updated event id");
    assert!(ids.iter().all(|&id| id == event_id), "event ids {ids:?}");
    let deadline = Instant::now() + Duration::from_secs(60);
    let refused = loop {
        match subscriber.receive() {
            Err(ReceiveError::ExceedsMaxBorrows) => break true,
            Ok(Some(_)) => panic!("a second graph sample was borrowed while the first is held (borrow limit 1)"),
            Ok(None) | Err(_) if Instant::now() > deadline => break false,
            _ => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    assert!(refused, "no further graph was published within 60 s to try a second borrow");
    drop(first);
    wait_for("a graph sample once the first is released", Duration::from_secs(60), || {
        subscriber.receive().expect("receive after release")
    });
}
