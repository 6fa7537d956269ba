//! The graph read benchmark's two Rust sides (`ipc_types/python/bench_latest.py` runs them next to
//! the Python client):
//!
//! - `graph_bench publish --prefix P [--nodes 2000] [--period-ms 10] [--seconds 30]` serves
//!   `P/graph` and `P/graph_updated` with the daemon's QoS (`op3dsg_ipc_types::services`) and
//!   publishes a graph of `--nodes` nodes (three objects to one part, two edges per node, like
//!   `op3dsg bench perf`) as a new version every period, until the time is up.
//! - `graph_bench read --prefix P [--samples 500] [--view]` reads it as a planner does with
//!   [`GraphSubscriber`]: wait for `graph_updated`, then time `latest_if_newer` (receive the newest
//!   sample, check it, copy it into the owned `Graph`), or with `--view` `with_latest` up to the
//!   first node's id and label read through the zero-copy `GraphView` (receive, check, records
//!   cast in place). Prints one JSON line: p50 / p99 of that call and of publish → graph in hand
//!   (the header's `publish_time_ns` to the end of the read, both on the wall clock),
//!   microseconds.

use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use op3dsg_ipc_types::iceoryx2;
use op3dsg_ipc_types::iceoryx2::port::update_connections::UpdateConnections as _;
use op3dsg_ipc_types::iceoryx2::prelude::{NodeBuilder, ServiceName};
use op3dsg_ipc_types::publish::{GraphBuffer, GraphPayload, send_graph};
use op3dsg_ipc_types::services::{
    DEFAULT_GRAPH_SUBSCRIBER_BUFFER, DEFAULT_MAX_SUBSCRIBERS, EVENT_ID_MAX_VALUE, GRAPH_MAX_PUBLISHERS,
    GRAPH_PUBLISHER_MAX_LOANED_SAMPLES, HISTORY_SIZE, IpcService, SAFE_OVERFLOW, SUBSCRIBER_MAX_BORROWED_SAMPLES,
    ServiceKind,
};
use op3dsg_ipc_types::{
    Edge, EdgeKind, GraphHeader, GraphSubscriber, MAX_EDGES, MAX_NODES, Node, NodeKind, SCHEMA_VERSION,
    graph_payload_bytes, relation_id, write_fixed_str,
};

type Error = Box<dyn std::error::Error>;

fn wall_clock_ns() -> u64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_nanos() as u64)
}

/// A graph of `count` nodes (every fourth a part of the object before it) with two `next to`
/// edges per node.
fn synthetic_graph(count: usize) -> GraphBuffer {
    const OBJECTS: [&str; 6] = ["cabinet", "refrigerator", "microwave", "sink", "stove", "drawer"];
    let next_to = relation_id("next to").map_or(0, |(_, id)| id);
    let mut graph = GraphBuffer::new();
    let mut last_object = 0u32;
    for i in 0..count.min(MAX_NODES) as u32 {
        let part = i % 4 == 3;
        let centre = [(i % 100) as f32 * 0.5, (i / 100) as f32 * 0.5, 0.8];
        let half = if part { 0.02 } else { 0.3 };
        let mut node = Node {
            id: i,
            parent_id: if part { last_object } else { op3dsg_ipc_types::NO_NODE },
            kind: if part { NodeKind::Part as u8 } else { NodeKind::Object as u8 },
            observation_count: 5,
            confidence: 0.8,
            centre_m: centre,
            box_min_m: centre.map(|v| v - half),
            box_max_m: centre.map(|v| v + half),
            affordance_bits: u16::from(part),
            last_seen_stamp_ns: u64::from(i),
            ..Node::default()
        };
        let object = OBJECTS[last_object as usize % OBJECTS.len()];
        let label = if part { format!("{object} handle") } else { OBJECTS[i as usize % OBJECTS.len()].to_owned() };
        write_fixed_str(&mut node.label, &label);
        graph.nodes.push(node);
        if !part {
            last_object = i;
        }
    }
    let n = graph.nodes.len() as u32;
    for i in 0..n {
        for step in [1, 7] {
            if graph.edges.len() < MAX_EDGES && n > 1 {
                let mut edge = Edge {
                    source_id: i,
                    target_id: (i + step) % n,
                    kind: EdgeKind::Spatial as u8,
                    relation_id: next_to,
                    confidence: 0.9,
                    ..Edge::default()
                };
                write_fixed_str(&mut edge.phrase, "next to");
                graph.edges.push(edge);
            }
        }
    }
    graph.header.schema_version = SCHEMA_VERSION;
    graph.header.instance_id = wall_clock_ns() | 1;
    graph.header.node_capacity = MAX_NODES as u32;
    graph.header.edge_capacity = MAX_EDGES as u32;
    graph.header.object_count = graph.nodes.iter().filter(|n| n.kind == NodeKind::Object as u8).count() as u32;
    graph.header.part_count = n - graph.header.object_count;
    graph.header.total_node_count = n;
    graph.header.total_edge_count = graph.edges.len() as u32;
    graph
}

fn publish(prefix: &str, nodes: usize, period: Duration, seconds: f64) -> Result<(), Error> {
    let node = NodeBuilder::new().config(&op3dsg_ipc_types::access::creator_config()?).create::<IpcService>()?;
    let service = node
        .service_builder(&ServiceName::new(&ServiceKind::Graph.name(prefix))?)
        .publish_subscribe::<GraphPayload>()
        .user_header::<GraphHeader>()
        .history_size(HISTORY_SIZE)
        .enable_safe_overflow(SAFE_OVERFLOW)
        .subscriber_max_buffer_size(DEFAULT_GRAPH_SUBSCRIBER_BUFFER)
        .subscriber_max_borrowed_samples(SUBSCRIBER_MAX_BORROWED_SAMPLES)
        .max_subscribers(DEFAULT_MAX_SUBSCRIBERS)
        .max_publishers(GRAPH_MAX_PUBLISHERS)
        .create()?;
    let publisher = service
        .publisher_builder()
        .max_loaned_samples(GRAPH_PUBLISHER_MAX_LOANED_SAMPLES)
        .initial_max_slice_len(graph_payload_bytes(MAX_NODES, MAX_EDGES))
        .create()?;
    let event = node
        .service_builder(&ServiceName::new(&ServiceKind::GraphUpdated.name(prefix))?)
        .event()
        .event_id_max_value(EVENT_ID_MAX_VALUE)
        .max_listeners(DEFAULT_MAX_SUBSCRIBERS)
        .create()?;
    let notifier = event.notifier_builder().create()?;

    let mut graph = synthetic_graph(nodes);
    println!("publishing {} nodes, {} edges under {prefix}", graph.nodes.len(), graph.edges.len());
    let end = Instant::now() + Duration::from_secs_f64(seconds);
    let mut version = 0;
    while Instant::now() < end {
        version += 1;
        graph.header.graph_version = version;
        graph.header.stamp_ns = version;
        graph.header.publish_time_ns = wall_clock_ns();
        let message = graph.encode();
        send_graph(&publisher, message.header, message.payload)?;
        notifier.notify()?;
        // Late joiners get the history sample when the publisher updates its connections.
        publisher.update_connections()?;
        std::thread::sleep(period);
    }
    Ok(())
}

fn percentile_us(sorted_ns: &[u64], p: f64) -> f64 {
    if sorted_ns.is_empty() {
        return f64::NAN;
    }
    let i = ((sorted_ns.len() - 1) as f64 * p).round() as usize;
    sorted_ns[i] as f64 / 1e3
}

/// One timed read: the call's duration, publish → in hand, and the version read.
struct Read {
    call_ns: u64,
    latency_ns: u64,
    version: u64,
    nodes: usize,
}

/// `latest_if_newer` into the owned graph.
fn read_owned(graphs: &mut GraphSubscriber, last_seen: u64) -> Result<Option<Read>, Error> {
    let t0 = Instant::now();
    let Some(graph) = graphs.latest_if_newer(last_seen)? else { return Ok(None) };
    let call_ns = t0.elapsed().as_nanos() as u64;
    let latency_ns = wall_clock_ns().saturating_sub(graph.publish_time_ns());
    Ok(Some(Read { call_ns, latency_ns, version: graph.version(), nodes: graph.node_count() }))
}

/// `with_latest` up to the first node read through the view.
fn read_view(graphs: &mut GraphSubscriber) -> Result<Option<Read>, Error> {
    let t0 = Instant::now();
    let read = graphs.with_latest(|view| {
        std::hint::black_box(view.nodes().next().map(|n| (n.id(), n.label().len())));
        let call_ns = t0.elapsed().as_nanos() as u64;
        let latency_ns = wall_clock_ns().saturating_sub(view.publish_time_ns());
        Read { call_ns, latency_ns, version: view.version(), nodes: view.node_count() }
    })?;
    Ok(read)
}

fn read(prefix: &str, samples: usize, view: bool) -> Result<(), Error> {
    let mut graphs = GraphSubscriber::open_wait(prefix, "op3dsg-bench-rust-reader", Duration::from_secs(30))?;
    let (mut call_ns, mut latency_ns) = (Vec::with_capacity(samples), Vec::with_capacity(samples));
    let (mut last_seen, mut nodes, mut warmed) = (0, 0, false);
    let deadline = Instant::now() + Duration::from_secs(120);
    while call_ns.len() < samples && Instant::now() < deadline {
        graphs.wait_for_update(Duration::from_secs(1))?;
        let taken = if view { read_view(&mut graphs)? } else { read_owned(&mut graphs, last_seen)? };
        let Some(read) = taken else { continue };
        (last_seen, nodes) = (read.version, read.nodes);
        // The first graph may be the history sample, delivered late, into cold buffers: not timed.
        if warmed {
            call_ns.push(read.call_ns);
            latency_ns.push(read.latency_ns);
        }
        warmed = true;
    }
    call_ns.sort_unstable();
    latency_ns.sort_unstable();
    let reader = if view {
        "rust GraphSubscriber::with_latest (view, first node read)"
    } else {
        "rust GraphSubscriber::latest_if_newer (copy into Graph)"
    };
    println!(
        "{{\"reader\": \"{reader}\", \"nodes\": {nodes}, \"samples\": {}, \
         \"call_p50_us\": {:.1}, \"call_p99_us\": {:.1}, \"latency_p50_us\": {:.1}, \"latency_p99_us\": {:.1}}}",
        call_ns.len(),
        percentile_us(&call_ns, 0.5),
        percentile_us(&call_ns, 0.99),
        percentile_us(&latency_ns, 0.5),
        percentile_us(&latency_ns, 0.99),
    );
    Ok(())
}

fn main() -> Result<(), Error> {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let args: Vec<String> = std::env::args().skip(1).collect();
    let arg = |flag: &str| args.iter().position(|a| a == flag).and_then(|i| args.get(i + 1)).cloned();
    let prefix = arg("--prefix").ok_or("--prefix P is required")?;
    match args.first().map(String::as_str) {
        Some("publish") => {
            let nodes = arg("--nodes").map(|s| s.parse()).transpose()?.unwrap_or(2000);
            let period_ms: u64 = arg("--period-ms").map(|s| s.parse()).transpose()?.unwrap_or(10);
            let seconds = arg("--seconds").map(|s| s.parse()).transpose()?.unwrap_or(30.0);
            publish(&prefix, nodes, Duration::from_millis(period_ms), seconds)
        }
        Some("read") => read(
            &prefix,
            arg("--samples").map(|s| s.parse()).transpose()?.unwrap_or(500),
            args.iter().any(|a| a == "--view"),
        ),
        _ => Err(
            "usage: graph_bench publish|read --prefix P [--nodes N --period-ms MS --seconds S | --samples N [--view]]"
                .into(),
        ),
    }
}
