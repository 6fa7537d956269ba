//! The language query service `<prefix>/query` against the real `op3dsgd` (real iceoryx2
//! request-response between processes, real ONNX Runtime and MiniLM from `.models/`):
//!
//! - this test process is the planner: it asks in words while the daemon maps, and every reply
//!   names node ids of the daemon's graph of the version the reply gives (read over `graph` as
//!   any planner reads it), from the same daemon instance;
//! - a flood from many clients against a queue of one gets immediate "busy" refusals, every
//!   request gets exactly one reply, and fusion keeps going (keyframes and graph versions grow
//!   during the flood; the fusion stage's p99 before and during is printed, not asserted);
//! - without the text encoder every query gets the "encoder off" reply, and `op3dsg query` says
//!   so (exit code 1), as it does when no daemon runs.

use std::collections::{HashMap, HashSet};
use std::process::Command;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use op3dsg_ipc_types::iceoryx2::prelude::{NodeBuilder, PortFactory as _, ServiceName};
use op3dsg_ipc_types::services::{
    IpcService, QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT, QUERY_MAX_CLIENTS, QUERY_MAX_NODES, QUERY_MAX_SERVERS,
    QUERY_RESPONSE_BUFFER, query_service_name,
};
use op3dsg_ipc_types::{GraphSubscriber, Health, NodeKind, QueryClient, QueryRequest, QueryResponse, QueryStatus};
use op3dsg_tests::{Daemon, binary, health_where, unique_prefix, wait_for};

const QUERIES: [&str; 6] = [
    "somewhere to wash my hands",
    "what controls the ceiling light",
    "open the fridge door",
    "throw away the rubbish",
    "plug in the kettle",
    "turn up the heat on the hob",
];

fn fusion_p99_us(health: &Health) -> f32 {
    health
        .valid_stages()
        .iter()
        .find(|s| op3dsg_ipc_types::fixed_str(&s.name) == "fusion")
        .map_or(0.0, |s| s.latency_p99_us)
}

/// Remembers the node ids of the newest graph by version, and its instance.
fn record(graphs: &mut GraphSubscriber, seen: &mut HashMap<u64, HashSet<u32>>, instance: &mut u64) {
    if let Ok(Some(graph)) = graphs.latest() {
        *instance = graph.instance_id();
        seen.entry(graph.version()).or_insert_with(|| graph.nodes().map(|n| n.id()).collect());
    }
}

#[test]
fn planner_queries_name_nodes_of_the_current_graph_while_the_daemon_maps() {
    let prefix = unique_prefix("query");
    let daemon = Daemon::start(&prefix, &["--set", "text_encoder.enabled=true", "--set", "source.rate_hz=15"]);
    let mut graphs = daemon.graph_subscriber("query-planner-graph");
    let client = QueryClient::open_wait(&prefix, "query-planner", Duration::from_secs(60)).expect("query service");

    // Node ids of every graph version seen, by version, and the instance serving them.
    let mut seen: HashMap<u64, HashSet<u32>> = HashMap::new();
    let mut instance = 0u64;

    let mut verified = 0usize;
    let mut versions = HashSet::new();
    let mut kinds = HashSet::new();
    let deadline = Instant::now() + Duration::from_secs(120);
    while (verified < 20 || versions.len() < 3) && Instant::now() < deadline {
        for text in QUERIES {
            record(&mut graphs, &mut seen, &mut instance);
            let response = client.query(text, 5, Duration::from_secs(20)).expect("a reply");
            record(&mut graphs, &mut seen, &mut instance);
            match response.query_status() {
                Some(QueryStatus::NoGraph) => continue,
                Some(QueryStatus::Ok) => {}
                other => panic!("{text:?}: unexpected status {other:?}: {}", response.message_str()),
            }
            // k = 5 nodes, or all of them while the map is smaller (the first versions are empty).
            assert_eq!(
                response.hit_count,
                response.scored_node_count.min(5),
                "{text:?}: {} hits of {} nodes",
                response.hit_count,
                response.scored_node_count
            );
            let scores: Vec<f32> = response.hits().iter().map(|h| h.score).collect();
            assert!(scores.windows(2).all(|w| w[0] >= w[1]), "{text:?}: hits not best first: {scores:?}");
            for hit in response.hits() {
                assert!(hit.query_match().is_some(), "{text:?}: unknown match kind {}", hit.matched);
                assert!(!hit.matched_text_str().is_empty(), "{text:?}: hit {} without the matched text", hit.node_id);
                kinds.insert(hit.node_kind().expect("known kind") as u8);
            }
            // The graph of the reply's version, as the planner received it.
            let Some(ids) = seen.get(&response.graph_version) else { continue };
            assert_eq!(response.instance_id, instance, "reply from the instance that serves the graph");
            for hit in response.hits() {
                assert!(
                    ids.contains(&hit.node_id),
                    "{text:?}: node {} ({}) is not in graph version {}",
                    hit.node_id,
                    hit.label_str(),
                    response.graph_version
                );
            }
            verified += 1;
            versions.insert(response.graph_version);
        }
    }
    assert!(verified >= 20, "only {verified} replies could be checked against a graph seen");
    assert!(versions.len() >= 3, "replies came from {} graph versions only: the daemon was mapping", versions.len());
    assert!(
        kinds.contains(&(NodeKind::Object as u8)) && kinds.contains(&(NodeKind::Part as u8)),
        "objects and parts among the hits"
    );
    drop(daemon);
}

#[test]
fn a_flood_of_queries_gets_refusals_and_fusion_goes_on() {
    let prefix = unique_prefix("query-flood");
    let daemon = Daemon::start(
        &prefix,
        &["--set", "text_encoder.enabled=true", "--set", "source.rate_hz=15", "--set", "query.queue_capacity=1"],
    );
    let mut health = daemon.health_subscriber("query-flood-health");
    let before = health_where(&mut health, "a few keyframes fused", Duration::from_secs(120), |h| h.keyframes >= 3);
    let probe = QueryClient::open_wait(&prefix, "query-flood-probe", Duration::from_secs(30)).expect("query service");
    wait_for("a first answered query", Duration::from_secs(60), || {
        probe
            .query("somewhere to wash my hands", 3, Duration::from_secs(20))
            .ok()
            .filter(|r| r.query_status() == Some(QueryStatus::Ok))
    });

    let stop = Arc::new(AtomicBool::new(false));
    let (ok, busy, replies) = (Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)), Arc::new(AtomicU64::new(0)));
    let busy_message = Arc::new(Mutex::new(String::new()));
    let mut threads = Vec::new();
    for t in 0..12 {
        let (prefix, stop, ok, busy, replies, busy_message) =
            (prefix.clone(), stop.clone(), ok.clone(), busy.clone(), replies.clone(), busy_message.clone());
        threads.push(
            std::thread::Builder::new()
                .name(format!("flood-{t}"))
                .spawn(move || {
                    let client = QueryClient::open(&prefix, &format!("query-flood-{t}")).expect("client");
                    let mut n = 0u64;
                    while !stop.load(Ordering::Relaxed) {
                        let text = QUERIES[(t + n as usize) % QUERIES.len()];
                        let response =
                            client.query(text, 3, Duration::from_secs(20)).expect("every request gets a reply");
                        replies.fetch_add(1, Ordering::Relaxed);
                        match response.query_status() {
                            Some(QueryStatus::Ok) => ok.fetch_add(1, Ordering::Relaxed),
                            Some(QueryStatus::Busy) => {
                                *busy_message.lock().expect("lock") = response.message_str().to_owned();
                                assert_eq!(response.queue_capacity, 1);
                                busy.fetch_add(1, Ordering::Relaxed)
                            }
                            other => panic!("flood: unexpected status {other:?}: {}", response.message_str()),
                        };
                        n += 1;
                    }
                })
                .expect("spawn"),
        );
    }
    let flood_started = Instant::now();
    // Fusion keeps going while the flood runs: more keyframes and newer graphs arrive.
    let during = health_where(&mut health, "keyframes fused during the flood", Duration::from_secs(120), |h| {
        h.keyframes >= before.keyframes + 10 && h.graph_version > before.graph_version + 3
    });
    while flood_started.elapsed() < Duration::from_secs(3) {
        std::thread::sleep(Duration::from_millis(50));
    }
    stop.store(true, Ordering::Relaxed);
    for thread in threads {
        thread.join().expect("flood thread");
    }
    let (ok, busy, replies) =
        (ok.load(Ordering::Relaxed), busy.load(Ordering::Relaxed), replies.load(Ordering::Relaxed));
    eprintln!(
        "flood: {replies} replies ({ok} ok, {busy} busy) in {:.1} s; keyframes {} -> {}; fusion p99 {:.0} us before, {:.0} us during",
        flood_started.elapsed().as_secs_f64(),
        before.keyframes,
        during.keyframes,
        fusion_p99_us(&before),
        fusion_p99_us(&during)
    );
    assert_eq!(ok + busy, replies, "every reply is an answer or a refusal");
    assert!(ok > 0, "some flood queries were answered");
    assert!(busy > 0, "12 clients against a queue of one: some requests were refused");
    let message = busy_message.lock().expect("lock").clone();
    assert!(message.contains("query.queue_capacity"), "the refusal says which setting bounds it: {message}");
    // The daemon still answers after the flood, and its counters saw the refusals.
    let after = probe.query("plug in the kettle", 3, Duration::from_secs(20)).expect("a reply after the flood");
    assert_eq!(after.query_status(), Some(QueryStatus::Ok), "{}", after.message_str());
    assert!(after.refused_count >= busy, "refused_count {} counts the {busy} refusals", after.refused_count);
    drop(daemon);
}

#[test]
fn without_the_text_encoder_queries_get_a_clear_error() {
    let prefix = unique_prefix("query-off");
    let daemon = Daemon::start(&prefix, &["--set", "source.rate_hz=15"]);
    let client = QueryClient::open_wait(&prefix, "query-off", Duration::from_secs(60)).expect("query service");
    // The service has exactly the QoS `op3dsg_ipc_types::services` documents.
    let node = NodeBuilder::new()
        .config(&op3dsg_ipc_types::access::creator_config().expect("IPC root"))
        .create::<IpcService>()
        .expect("a plain iceoryx2 node");
    let service = node
        .service_builder(&ServiceName::new(&query_service_name(&prefix)).expect("service name"))
        .request_response::<QueryRequest, QueryResponse>()
        .open()
        .expect("query opens with the contract's types");
    let config = service.static_config();
    assert_eq!(
        (config.max_servers(), config.max_clients(), config.max_active_requests_per_client()),
        (QUERY_MAX_SERVERS, QUERY_MAX_CLIENTS, QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT)
    );
    assert_eq!((config.max_response_buffer_size(), config.max_nodes()), (QUERY_RESPONSE_BUFFER, QUERY_MAX_NODES));

    let response = client.query("somewhere to wash my hands", 3, Duration::from_secs(10)).expect("a reply");
    assert_eq!(response.query_status(), Some(QueryStatus::EncoderOff));
    assert!(response.message_str().contains("text_encoder.enabled = true"), "{}", response.message_str());
    let bad = client.query(" ", 3, Duration::from_secs(10)).expect("a reply");
    assert_eq!(bad.query_status(), Some(QueryStatus::BadRequest));
    assert!(bad.message_str().starts_with("text:"), "names the field: {}", bad.message_str());

    // The CLI, a process of its own, says the same and fails.
    let out = Command::new(binary("op3dsg"))
        .args(["--prefix", &prefix, "query", "somewhere to wash my hands"])
        .output()
        .expect("run op3dsg query");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("text_encoder.enabled = true") && stderr.contains("encoder_off"), "{stderr}");
    drop(daemon);

    let out = Command::new(binary("op3dsg"))
        .args(["--prefix", &unique_prefix("query-none"), "query", "anything", "--timeout-s", "0.5"])
        .output()
        .expect("run op3dsg query");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{stderr}");
    assert!(stderr.contains("no op3dsgd daemon serves it"), "{stderr}");
}
