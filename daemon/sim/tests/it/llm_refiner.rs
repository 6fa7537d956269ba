//! The LLM refiner against a chat-completions server on 127.0.0.1 in this process (axum):
//! good answers are applied; malformed JSON, unknown node ids, wrong kinds, non-canonical
//! labels, a 500, a 429 with Retry-After and a 30-second stall are each handled and counted;
//! during the stall the pipeline keeps producing frames and graph versions; the API key never
//! appears in logs, prompts or published data. The last tests run the real `op3dsgd` as a child
//! process against the same server (build it first: `cargo build -p op3dsgd`): affordances
//! published with their origin; answers in a fence, in prose, with extra fields or numbers as
//! strings giving the plain answers' items; hallucinated ids and implausible items rejected,
//! counted by rule in health and absent from every published graph; with a flaky agent, no
//! accepted item unpublished while its nodes are unchanged; non-chat 200s opening the breaker,
//! named `not_chat` in health.

// The server and helpers below are test code outside `#[test]` functions: a failed unwrap is a
// failed test.
#![allow(clippy::unwrap_used)]

use std::io::Write as _;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock};
use std::time::{Duration, Instant};

use axum::Router;
use axum::extract::State;
use axum::http::{HeaderMap, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::post;
use op3dsg_ipc_types::{EdgeKind, EdgeOrigin, NodeKind, affordance_names, relation_phrase};
use op3dsg_runtime::graph::{GraphNode, SceneGraph};
use op3dsg_runtime::pipeline::Pipeline;
use op3dsg_runtime::reasoner::GraphEnricher;
use op3dsg_runtime::reasoner::llm::gate::Rejection;
use op3dsg_runtime::reasoner::llm::{RefinerState, RefinerStats};
use op3dsg_runtime::stats::HealthSource as _;
use serde_json::{Value, json};

/// Watchdog of each wait (not a speed requirement).
const WATCHDOG: Duration = Duration::from_secs(90);

#[derive(Debug, Clone, Copy, PartialEq)]
enum Mode {
    Good,
    Malformed,
    UnknownIds,
    WrongKinds,
    NonCanonical,
    /// This status for the next `n` requests, then good answers.
    Status {
        status: u16,
        retry_after_s: Option<u32>,
        n: u32,
    },
    /// Answers after 30 s.
    Stall,
    /// The answer inside a markdown code fence (```` ```json ````).
    Fenced,
    /// The answer with a sentence before and after it.
    Prose,
    /// Each item (and the answer) carries a field the schema does not name.
    ExtraFields,
    /// Ids and confidences written as strings.
    StringNumbers,
    /// A 200 with an HTML page.
    Html,
    /// A 200 chat completion with an empty `choices` list.
    EmptyChoices,
    /// A 200 chat completion whose message content is null.
    NullContent,
    /// Good answers, except every second call of this agent gets a 500.
    Flaky(&'static str),
    /// Ids and canonical labels, but items that make no sense for their nodes: a remote
    /// relation from a part to its own object, `press to flush` on a cabinet handle, `provide
    /// power` from a remote control, `foot_push` and `plug_in` on every object; besides them
    /// the plausible relation and affordance of each handle and knob, whatever its geometry.
    Implausible,
    /// A server without structured output: 400 to `response_format = json_schema`, good
    /// answers to `json_object`.
    NoSchema,
}

#[derive(Debug, Clone)]
struct Recorded {
    at: Instant,
    agent: String,
    /// `response_format.type` of the request.
    format: String,
    body: String,
    authorization: Option<String>,
}

#[derive(Debug)]
struct ServerState {
    mode: Mode,
    requests: Vec<Recorded>,
}

impl ServerState {
    fn calls_of(&self, agent: &str) -> usize {
        self.requests.iter().filter(|r| r.agent == agent).count()
    }
}

type Shared = Arc<Mutex<ServerState>>;

/// A chat-completions server on 127.0.0.1:0 with its own runtime.
struct TestServer {
    state: Shared,
    base_url: String,
    _runtime: tokio::runtime::Runtime,
}

impl TestServer {
    fn start(mode: Mode) -> Self {
        let runtime = tokio::runtime::Builder::new_multi_thread().worker_threads(1).enable_all().build().unwrap();
        let state: Shared = Arc::new(Mutex::new(ServerState { mode, requests: Vec::new() }));
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        listener.set_nonblocking(true).unwrap();
        let base_url = format!("http://{}/v1", listener.local_addr().unwrap());
        let app = Router::new().route("/v1/chat/completions", post(handle)).with_state(state.clone());
        runtime.spawn(async move {
            let listener = tokio::net::TcpListener::from_std(listener).unwrap();
            axum::serve(listener, app).await.unwrap();
        });
        Self { state, base_url, _runtime: runtime }
    }
    fn set_mode(&self, mode: Mode) {
        self.state.lock().unwrap().mode = mode;
    }
    fn requests(&self) -> Vec<Recorded> {
        self.state.lock().unwrap().requests.clone()
    }
}

async fn handle(State(state): State<Shared>, headers: HeaderMap, body: String) -> Response {
    let request: Value = serde_json::from_str(&body).unwrap_or(Value::Null);
    let user: Value = serde_json::from_str(request["messages"][1]["content"].as_str().unwrap_or("null")).unwrap();
    // The schema names the agent; without one (json_object), the prompt's data does.
    let agent = match request["response_format"]["json_schema"]["name"].as_str() {
        Some(name) => name.to_owned(),
        None if user.get("part_of_pairs").is_some() => "local_relations".to_owned(),
        None if user.get("sources").is_some() => "remote_relations".to_owned(),
        None => "affordances".to_owned(),
    };
    let format = request["response_format"]["type"].as_str().unwrap_or("").to_owned();
    let mode = {
        let mut s = state.lock().unwrap();
        s.requests.push(Recorded {
            at: Instant::now(),
            agent: agent.clone(),
            format: format.clone(),
            body: body.clone(),
            authorization: headers.get("authorization").and_then(|v| v.to_str().ok()).map(str::to_owned),
        });
        let mode = s.mode;
        if let Mode::Status { status, retry_after_s, n } = mode {
            s.mode = if n > 1 { Mode::Status { status, retry_after_s, n: n - 1 } } else { Mode::Good };
        }
        if let Mode::Flaky(flaky) = mode
            && flaky == agent
            && s.calls_of(&agent) % 2 == 0
        {
            Mode::Status { status: 500, retry_after_s: None, n: 1 }
        } else {
            mode
        }
    };
    match mode {
        Mode::Status { status, retry_after_s, .. } => {
            let mut response = (StatusCode::from_u16(status).unwrap(), "try later").into_response();
            if let Some(s) = retry_after_s {
                response.headers_mut().insert("retry-after", s.to_string().parse().unwrap());
            }
            return response;
        }
        Mode::Stall => tokio::time::sleep(Duration::from_secs(30)).await,
        Mode::NoSchema if format == "json_schema" => {
            let error = json!({"error": {"message": "response_format type 'json_schema' is not supported", "type": "invalid_request_error"}});
            return (StatusCode::BAD_REQUEST, [("content-type", "application/json")], error.to_string())
                .into_response();
        }
        Mode::Html => {
            let page = "<!DOCTYPE html><html><body><h1>Welcome to nginx!</h1></body></html>";
            return (StatusCode::OK, [("content-type", "text/html")], page).into_response();
        }
        _ => {}
    }
    let content = answer(&agent, &user, mode);
    let choices = match mode {
        Mode::EmptyChoices => json!([]),
        Mode::NullContent => {
            json!([{"index": 0, "message": {"role": "assistant", "content": null}, "finish_reason": "length"}])
        }
        _ => json!([{"index": 0, "message": {"role": "assistant", "content": content}, "finish_reason": "stop"}]),
    };
    let completion = json!({
        "id": "chatcmpl-test",
        "object": "chat.completion",
        "model": request["model"],
        "choices": choices,
        "usage": {"prompt_tokens": 1, "completion_tokens": 1, "total_tokens": 2}
    });
    (StatusCode::OK, [("content-type", "application/json")], completion.to_string()).into_response()
}

/// The model's answer: built from the prompt's own data, then spoiled as `mode` asks.
fn answer(agent: &str, user: &Value, mode: Mode) -> String {
    if mode == Mode::Malformed {
        return "Here are the relations: {relations: [handle -> cabinet]}".to_owned();
    }
    if mode == Mode::Implausible {
        return implausible(agent, user).to_string();
    }
    let id_shift = if mode == Mode::UnknownIds { 100_000 } else { 0 };
    let relation = |canonical: &'static str| if mode == Mode::NonCanonical { "opens it by yanking" } else { canonical };
    let id = |v: &Value| {
        let id = v["id"].as_u64().unwrap() + id_shift;
        if mode == Mode::StringNumbers { json!(id.to_string()) } else { json!(id) }
    };
    let conf = |c: f64| if mode == Mode::StringNumbers { json!(c.to_string()) } else { json!(c) };
    let answer = match agent {
        "local_relations" => {
            let mut items = Vec::new();
            for pair in user["part_of_pairs"].as_array().unwrap() {
                let (part, object) = (&pair["part"], &pair["object"]);
                let (part_id, object_id) =
                    if mode == Mode::WrongKinds { (id(object), id(part)) } else { (id(part), id(object)) };
                let label = part["label"].as_str().unwrap();
                if label.ends_with("handle") {
                    items.push(json!({"part_id": part_id, "object_id": object_id, "relation": relation("pull to open or close"), "confidence": conf(0.9)}));
                    // Some cabinets open by pushing; a model that knows furniture says so for them only.
                    if object["label"].as_str().unwrap().contains("cabinet") {
                        items.push(json!({"part_id": part_id, "object_id": object_id, "relation": relation("push or press to open"), "confidence": conf(0.6)}));
                    }
                } else if label.ends_with("knob") {
                    items.push(json!({"part_id": part_id, "object_id": object_id, "relation": relation("rotate to adjust the setting or temperature"), "confidence": conf(0.8)}));
                }
            }
            json!({"relations": items})
        }
        "remote_relations" => {
            let mut items = Vec::new();
            for source in user["sources"].as_array().unwrap() {
                let source_id = id(&source["source"]);
                let target_id =
                    if mode == Mode::WrongKinds { source_id.clone() } else { id(&source["candidate_targets"][0]) };
                let canonical = remote_relation(source["source"]["label"].as_str().unwrap());
                items.push(json!({"source_id": source_id, "target_id": target_id, "relation": relation(canonical), "confidence": conf(0.9)}));
            }
            json!({"relations": items})
        }
        _ => {
            let mut items = Vec::new();
            for node in user["nodes"].as_array().unwrap() {
                let label = node["label"].as_str().unwrap();
                let names: Vec<&str> = if mode == Mode::NonCanonical {
                    vec!["yank"]
                } else if label.ends_with("handle") {
                    // Small handles on cabinets and drawers can be pinched too.
                    let parent = node["parent"]["label"].as_str().unwrap_or("");
                    if parent.contains("cabinet") || parent.contains("drawer") {
                        vec!["hook_pull", "pinch pull"]
                    } else {
                        vec!["hook_pull"]
                    }
                } else if label.ends_with("knob") {
                    vec!["rotate"]
                } else {
                    continue;
                };
                items.push(json!({"node_id": id(node), "affordances": names, "confidence": conf(0.8)}));
            }
            json!({"affordances": items})
        }
    };
    dress(answer, mode)
}

/// How a remote source acts on its target, by the source's label (as a model that knows
/// homes answers).
fn remote_relation(label: &str) -> &'static str {
    const BY_WORD: [(&str, &str); 10] = [
        ("outlet", "provide power"),
        ("socket", "provide power"),
        ("strip", "provide power"),
        ("dimmer", "operate or adjust the flow or setting"),
        ("valve", "operate or adjust the flow or setting"),
        ("switch", "turn on or turn off"),
        ("faucet", "control the water flow"),
        ("tap", "control the water flow"),
        ("flush", "press to flush"),
        ("knob", "rotate to adjust the setting or temperature"),
    ];
    BY_WORD.iter().find(|(word, _)| label.contains(word)).map_or("remote to control", |(_, relation)| relation)
}

/// [`Mode::Implausible`]'s answers, from the prompt's ids and labels.
fn implausible(agent: &str, user: &Value) -> Value {
    let mut items = Vec::new();
    match agent {
        "local_relations" => {
            for pair in user["part_of_pairs"].as_array().unwrap() {
                let (part, object) = (&pair["part"]["id"], &pair["object"]["id"]);
                let label = pair["part"]["label"].as_str().unwrap();
                let mut relations = vec!["remote to control"];
                if label.ends_with("handle") {
                    relations.extend(["press to flush", "pull to open or close"]);
                } else if label.ends_with("knob") {
                    relations.push("rotate to adjust the setting or temperature");
                }
                for r in relations {
                    items.push(json!({"part_id": part, "object_id": object, "relation": r, "confidence": 0.8}));
                }
            }
            json!({"relations": items})
        }
        "remote_relations" => {
            for source in user["sources"].as_array().unwrap() {
                let (source_id, target_id) = (&source["source"]["id"], &source["candidate_targets"][0]["id"]);
                let label = source["source"]["label"].as_str().unwrap();
                for r in ["provide power", remote_relation(label)] {
                    items.push(
                        json!({"source_id": source_id, "target_id": target_id, "relation": r, "confidence": 0.8}),
                    );
                }
            }
            json!({"relations": items})
        }
        _ => {
            for node in user["nodes"].as_array().unwrap() {
                let label = node["label"].as_str().unwrap();
                let names = if node["kind"] == "object" {
                    vec!["foot_push", "plug_in"]
                } else if label.ends_with("handle") {
                    vec!["hook_pull"]
                } else if label.ends_with("knob") {
                    vec!["rotate"]
                } else {
                    continue;
                };
                items.push(json!({"node_id": node["id"], "affordances": names, "confidence": 0.8}));
            }
            json!({"affordances": items})
        }
    }
}

/// The answer as the mode's model writes it around the JSON.
fn dress(mut answer: Value, mode: Mode) -> String {
    match mode {
        Mode::Fenced => format!("```json\n{answer:#}\n```"),
        Mode::Prose => format!("Here is the JSON you asked for:\n{answer}\nI left out anything I was unsure of."),
        Mode::ExtraFields => {
            for list in answer.as_object_mut().unwrap().values_mut() {
                for item in list.as_array_mut().unwrap() {
                    item["reasoning"] = json!("handles are usually pulled");
                }
            }
            answer["notes"] = json!("all ids are from the prompt");
            answer.to_string()
        }
        _ => answer.to_string(),
    }
}

fn node(id: u32, label: &str, kind: NodeKind, parent: Option<u32>, min: [f32; 3], max: [f32; 3]) -> GraphNode {
    GraphNode {
        id,
        kind,
        parent_id: parent,
        label: label.to_owned(),
        confidence: 0.9,
        centre_m: std::array::from_fn(|i| (min[i] + max[i]) * 0.5),
        box_min_m: min,
        box_max_m: max,
        obb: Default::default(),
        observation_count: 5,
        affordance_bits: 0,
        last_seen_stamp_ns: 0,
        first_seen_stamp_ns: 0,
        missing: false,
        ..Default::default()
    }
}

/// A kitchen corner as fusion would hand it over (part-of edges included).
fn corner() -> SceneGraph {
    let mut graph = SceneGraph {
        version: 12,
        stamp_ns: 0,
        nodes: vec![
            node(1, "cabinet", NodeKind::Object, None, [0.0, 0.0, 0.0], [0.6, 0.6, 0.9]),
            node(2, "stove", NodeKind::Object, None, [1.0, 0.0, 0.0], [1.6, 0.6, 0.9]),
            node(3, "tv", NodeKind::Object, None, [3.0, 2.0, 1.0], [4.0, 2.1, 1.6]),
            node(4, "remote control", NodeKind::Object, None, [3.2, 0.5, 0.5], [3.35, 0.55, 0.53]),
            node(5, "cabinet handle", NodeKind::Part, Some(1), [0.3, -0.03, 0.5], [0.4, 0.0, 0.52]),
            node(6, "stove knob", NodeKind::Part, Some(2), [1.2, -0.03, 0.8], [1.24, 0.0, 0.84]),
        ],
        edges: Vec::new(),
    };
    part_of(&mut graph, &[(5, 1), (6, 2)]);
    graph
}

fn overrides(server: &TestServer, extra: &[&str]) -> Vec<String> {
    let mut o = vec![
        "reasoner.kind=\"llm\"".to_owned(),
        format!("reasoner.llm.base_url={:?}", server.base_url),
        "reasoner.llm.model=\"test-model\"".to_owned(),
        "reasoner.llm.api_key_env=\"\"".to_owned(),
        "reasoner.llm.request_timeout_s=2.0".to_owned(),
        "reasoner.llm.max_retries=1".to_owned(),
        "reasoner.llm.backoff_initial_s=0.01".to_owned(),
        "reasoner.llm.backoff_max_s=3.0".to_owned(),
        "reasoner.llm.breaker_failures=100".to_owned(),
    ];
    o.extend(extra.iter().map(|s| (*s).to_owned()));
    o
}

fn enricher(overrides: &[String]) -> (GraphEnricher, Arc<RefinerStats>) {
    let profile = op3dsg_sim::load_profile(None, overrides).expect("profile").profile;
    let mut enricher = op3dsg_runtime::pipeline::make_enricher(&profile).expect("enricher").expect("kind = llm");
    enricher.set_synchronous(true);
    let stats = enricher.refiner_stats().expect("refiner");
    (enricher, stats)
}

/// Enriches the corner and refines it once; the graph.
fn refine(enricher: &mut GraphEnricher) -> SceneGraph {
    let mut graph = corner();
    let prior = enricher.enrich(&mut graph);
    assert!(enricher.refine_now(&mut graph, prior, Duration::from_secs(30)), "a result arrives");
    graph
}

fn functional(graph: &SceneGraph) -> Vec<(u32, u32, &'static str, EdgeOrigin)> {
    let mut edges: Vec<_> = graph
        .edges
        .iter()
        .filter(|e| e.kind == EdgeKind::Functional)
        .map(|e| (e.source_id, e.target_id, relation_phrase(e.relation_id).unwrap(), e.origin))
        .collect();
    edges.sort_by_key(|e| (e.0, e.1, e.2));
    edges
}

#[test]
fn good_answers_are_applied_with_their_origin() {
    let server = TestServer::start(Mode::Good);
    let (mut enricher, stats) = enricher(&overrides(&server, &[]));
    let graph = refine(&mut enricher);
    assert_eq!(
        functional(&graph),
        [
            (4, 3, "remote to control", EdgeOrigin::KnowledgeAndLlm),
            (5, 1, "pull to open or close", EdgeOrigin::KnowledgeAndLlm),
            (5, 1, "push or press to open", EdgeOrigin::Llm),
            (6, 2, "rotate to adjust the setting or temperature", EdgeOrigin::KnowledgeAndLlm),
        ]
    );
    let handle = graph.nodes.iter().find(|n| n.id == 5).unwrap();
    assert_eq!(affordance_names(handle.affordance_bits).collect::<Vec<_>>(), ["hook_pull", "pinch_pull"]);
    // The knowledge base gives the handle's hook_pull, the LLM confirms it and adds pinch_pull.
    assert_eq!(
        handle.affordance_origins().collect::<Vec<_>>(),
        [("hook_pull", EdgeOrigin::KnowledgeAndLlm), ("pinch_pull", EdgeOrigin::Llm)]
    );
    // One prompt per agent for this refresh, never one per pair.
    let mut agents: Vec<String> = server.requests().into_iter().map(|r| r.agent).collect();
    agents.sort();
    assert_eq!(agents, ["affordances", "local_relations", "remote_relations"]);
    assert_eq!(stats.calls.load(Ordering::Relaxed), 3);
    assert_eq!(stats.accepted.load(Ordering::Relaxed), 6);
    assert_eq!(stats.health().rejections, [0; 8]);
    assert_eq!(stats.last_graph_version.load(Ordering::Relaxed), 12);
}

#[test]
fn bad_answers_are_rejected_and_counted_by_reason() {
    let server = TestServer::start(Mode::Malformed);
    let (mut enricher, stats) = enricher(&overrides(&server, &[]));
    let only_knowledge = |graph: &SceneGraph| {
        assert!(graph.edges.iter().all(|e| e.origin == EdgeOrigin::Knowledge || e.origin == EdgeOrigin::Geometry));
        let handle = graph.nodes.iter().find(|n| n.id == 5).unwrap();
        assert_eq!(handle.affordance_origins().collect::<Vec<_>>(), [("hook_pull", EdgeOrigin::Knowledge)]);
    };
    only_knowledge(&refine(&mut enricher));
    assert_eq!(stats.rejections(Rejection::Malformed), 3, "one per agent's answer");

    server.set_mode(Mode::UnknownIds);
    only_knowledge(&refine(&mut enricher));
    assert_eq!(stats.rejections(Rejection::UnknownNode), 3 + 1 + 2);

    server.set_mode(Mode::WrongKinds);
    let graph = refine(&mut enricher);
    assert!(!graph.edges.iter().any(|e| e.kind == EdgeKind::Functional && e.origin == EdgeOrigin::Llm));
    assert_eq!(stats.rejections(Rejection::WrongKind), 3 + 1);

    server.set_mode(Mode::NonCanonical);
    only_knowledge(&refine(&mut enricher));
    // Three local items, one remote, one affordance label for each of the six nodes.
    assert_eq!(stats.rejections(Rejection::NonCanonical), 3 + 1 + 6);
    assert_eq!(stats.failures.load(Ordering::Relaxed), 0, "answered calls are no failures");
}

#[test]
fn a_500_is_retried_then_counted_and_the_breaker_opens() {
    let server = TestServer::start(Mode::Status { status: 500, retry_after_s: None, n: 1000 });
    let (mut enricher, stats) = enricher(&overrides(&server, &["reasoner.llm.breaker_failures=3"]));
    let mut graph = corner();
    let prior = enricher.enrich(&mut graph);
    assert!(enricher.refine_now(&mut graph, prior.clone(), Duration::from_secs(30)), "an empty result arrives");
    assert!(graph.edges.iter().all(|e| e.origin != EdgeOrigin::Llm));
    // Three agents, each tried twice (max_retries = 1).
    assert_eq!(stats.calls.load(Ordering::Relaxed), 6);
    assert_eq!(stats.failures.load(Ordering::Relaxed), 6);
    assert!(stats.breaker_open());
    assert_eq!(stats.state(), RefinerState::BreakerOpen as u8);
    // While the breaker is open, refreshes send nothing.
    assert!(enricher.refine_now(&mut graph, prior, Duration::from_secs(30)));
    assert_eq!(server.requests().len(), 6);
}

#[test]
fn a_429_waits_for_retry_after_then_succeeds() {
    let server = TestServer::start(Mode::Status { status: 429, retry_after_s: Some(1), n: 1 });
    let (mut enricher, stats) = enricher(&overrides(&server, &["reasoner.llm.max_concurrent_calls=1"]));
    let graph = refine(&mut enricher);
    assert_eq!(stats.rate_limited.load(Ordering::Relaxed), 1);
    assert_eq!(stats.failures.load(Ordering::Relaxed), 1);
    assert_eq!(stats.calls.load(Ordering::Relaxed), 4, "three agents and one retry");
    assert!(functional(&graph).iter().any(|e| e.3 == EdgeOrigin::Llm), "the retried answers were applied");
    // The retry of the rate-limited agent came no sooner than Retry-After (backoff is 10 ms).
    let requests = server.requests();
    let first = &requests[0];
    let retry = requests.iter().skip(1).find(|r| r.agent == first.agent).expect("a retry");
    assert!(retry.at.duration_since(first.at) >= Duration::from_millis(950), "{:?}", retry.at - first.at);
}

#[test]
fn a_stalled_server_times_out_while_the_pipeline_keeps_going() {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let server = TestServer::start(Mode::Stall);
    let prefix = format!("op3dsg-test-llm-stall-{}", std::process::id());
    let profile = op3dsg_sim::load_profile(
        None,
        &overrides(
            &server,
            &[
                &format!("ipc.prefix={prefix:?}"),
                "reasoner.llm.request_timeout_s=10.0",
                "reasoner.llm.max_retries=0",
                "reasoner.llm.refresh_min_changed_nodes=1",
                "reasoner.llm.refresh_period_s=0.5",
            ],
        ),
    )
    .expect("profile")
    .profile;
    let stop = Arc::new(AtomicBool::new(false));
    let pipeline = Pipeline::start(&profile, &op3dsg_sim::backends(), stop.clone()).expect("pipeline starts");
    let stats = pipeline.counters().clone();
    let wait = |what: &str, done: &dyn Fn() -> bool| {
        let deadline = Instant::now() + WATCHDOG;
        while !done() {
            assert!(Instant::now() < deadline, "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    wait("a stalled request", &|| !server.requests().is_empty());
    let frames = stats.capture.frames_captured.load(Ordering::Relaxed);
    let version = stats.fusion.graph_version.load(Ordering::Relaxed);
    // While the server sits on the request, frames and graph versions keep coming.
    let timed_out = || stats.refiner.timeouts.load(Ordering::Relaxed) > 0;
    wait("frames and graph versions during the stall", &|| {
        timed_out()
            || stats.capture.frames_captured.load(Ordering::Relaxed) > frames + 5
                && stats.fusion.graph_version.load(Ordering::Relaxed) > version + 1
    });
    assert_eq!(stats.refiner.timeouts.load(Ordering::Relaxed), 0, "the counters rose before the timeout");
    wait("the timeout", &|| stats.refiner.timeouts.load(Ordering::Relaxed) >= 1);
    let health = stats.health();
    assert!(health.refiner.timeouts >= 1 && health.refiner.failures >= 1 && health.refiner.calls >= 1);
    stop.store(true, Ordering::SeqCst);
    let summary = pipeline.wait().expect("orderly shutdown with a request in flight");
    assert!(summary.graph_version > version);
}

/// Everything the crate logs, for the key test (this test binary's global subscriber).
fn captured_logs() -> &'static Mutex<Vec<u8>> {
    static LOGS: OnceLock<&'static Mutex<Vec<u8>>> = OnceLock::new();
    LOGS.get_or_init(|| {
        let logs: &'static Mutex<Vec<u8>> = Box::leak(Box::new(Mutex::new(Vec::new())));
        struct Sink(&'static Mutex<Vec<u8>>);
        impl std::io::Write for Sink {
            fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
                self.0.lock().unwrap().extend_from_slice(buf);
                Ok(buf.len())
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        let subscriber = tracing_subscriber::fmt()
            .with_max_level(tracing::Level::TRACE)
            .with_ansi(false)
            .with_writer(move || Sink(logs))
            .finish();
        tracing::subscriber::set_global_default(subscriber).expect("one subscriber");
        logs
    })
}

#[test]
fn the_api_key_never_appears_in_logs_prompts_or_published_data() {
    let logs = captured_logs();
    const KEY: &str = "sk-op3dsg-test-9f2c4e7a1b";
    let dir = tempfile::tempdir().unwrap();
    let key_file = dir.path().join("llm.key");
    let mut f = std::fs::File::create(&key_file).unwrap();
    writeln!(f, "{KEY}").unwrap();
    let server = TestServer::start(Mode::Status { status: 500, retry_after_s: None, n: 1 });
    let mut o = overrides(&server, &[]);
    o.push(format!("reasoner.llm.api_key_file={:?}", key_file.display().to_string()));
    let profile = op3dsg_sim::load_profile(None, &o).expect("profile").profile;
    let (mut enricher, stats) = enricher(&o);
    let graph = refine(&mut enricher);
    assert!(functional(&graph).iter().any(|e| e.3 == EdgeOrigin::Llm));
    let requests = server.requests();
    assert!(requests.len() >= 3);
    for r in &requests {
        assert_eq!(r.authorization.as_deref(), Some(format!("Bearer {KEY}").as_str()), "the key is sent");
        assert!(!r.body.contains(KEY), "the key is in a prompt");
    }
    let logs = String::from_utf8_lossy(&logs.lock().unwrap()).into_owned();
    assert!(logs.contains("LLM call failed"), "failures were logged: {logs}");
    assert!(!logs.contains(KEY), "the key is in the logs");
    let published = serde_json::to_string(&graph.to_json("test")).unwrap();
    assert!(!published.contains(KEY));
    let health = op3dsg_runtime::ipc::HealthReport::from(&op3dsg_ipc_types::Health {
        refiner: stats.health(),
        ..op3dsg_ipc_types::Health::default()
    });
    assert!(!serde_json::to_string(&health).unwrap().contains(KEY));
    assert!(!format!("{enricher:?} {profile:?}").contains(KEY));
    assert!(!toml::to_string(&profile).unwrap().contains(KEY), "--print-config shows the path only");
}

#[test]
fn batch_runs_await_the_refiner_on_the_synthetic_kitchen() {
    let server = TestServer::start(Mode::Good);
    let mut o = overrides(&server, &[]);
    o.push("source.synthetic.frame_count=300".to_owned());
    let profile = op3dsg_sim::load_profile(None, &o).expect("profile").profile;
    let run = op3dsg_sim::batch::run(&profile, &op3dsg_sim::batch::VisibilityThresholds::default()).expect("batch run");
    let graph = &run.graph;
    let label = |id: u32| graph.nodes.iter().find(|n| n.id == id).map_or("?", |n| n.label.as_str());
    let mut agreeing = 0;
    let mut agreeing_on_cabinets = 0;
    let mut llm_only = 0;
    for e in graph.edges.iter().filter(|e| e.kind == EdgeKind::Functional) {
        match (e.origin, relation_phrase(e.relation_id).unwrap()) {
            (EdgeOrigin::KnowledgeAndLlm, "pull to open or close") => {
                assert!(label(e.source_id).ends_with("handle"));
                agreeing += 1;
                agreeing_on_cabinets += usize::from(label(e.target_id).contains("cabinet"));
            }
            (EdgeOrigin::Llm, "push or press to open") => {
                assert!(label(e.target_id).contains("cabinet"), "{}", label(e.target_id));
                llm_only += 1;
            }
            _ => {}
        }
    }
    // The handles' pulls the knowledge base agrees with are K+L; every cabinet handle the server
    // saw also gets its LLM-only push.
    assert!(
        agreeing >= 2 && llm_only >= agreeing_on_cabinets,
        "{agreeing} agreeing ({agreeing_on_cabinets} on cabinets), {llm_only} from the LLM alone"
    );
    let mut agents: Vec<String> = server.requests().into_iter().map(|r| r.agent).collect();
    agents.sort();
    // One refresh for the one graph; this short run has no remotable source with a candidate
    // target other than its own parent, so the remote agent had nothing to ask.
    assert_eq!(agents, ["affordances", "local_relations"], "one prompt per agent");
}

#[test]
fn the_pipeline_publishes_verified_llm_edges_and_the_refiner_health() {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let server = TestServer::start(Mode::Good);
    let prefix = format!("op3dsg-test-llm-good-{}", std::process::id());
    let extra = [&*format!("ipc.prefix={prefix:?}"), "health.period_ms=100"];
    let profile = op3dsg_sim::load_profile(None, &overrides(&server, &extra)).expect("profile").profile;
    let stop = Arc::new(AtomicBool::new(false));
    let pipeline = Pipeline::start(&profile, &op3dsg_sim::backends(), stop.clone()).expect("pipeline starts");
    let mut graphs = op3dsg_ipc_types::GraphSubscriber::open_wait(&prefix, "llm-test-client", Duration::from_secs(10))
        .expect("the daemon serves");
    let mut health = op3dsg_ipc_types::HealthSubscriber::open_wait(&prefix, "llm-test-health", Duration::from_secs(10))
        .expect("the daemon serves health");
    let deadline = Instant::now() + WATCHDOG;
    let (mut llm_edge, mut refiner_health) = (false, None);
    while !(llm_edge && refiner_health.is_some()) {
        assert!(Instant::now() < deadline, "timed out waiting for published LLM edges (llm {llm_edge})");
        if let Some(graph) = graphs.latest().expect("graph") {
            llm_edge |= graph.edges().any(|e| e.kind() == EdgeKind::Functional && e.origin() == EdgeOrigin::Llm);
        }
        if let Some(h) = health.latest().expect("health")
            && h.refiner.accepted > 0
        {
            refiner_health = Some(h.refiner);
        }
        std::thread::sleep(Duration::from_millis(20));
    }
    let refiner = refiner_health.unwrap();
    assert!(refiner.calls >= 2 && refiner.failures == 0 && refiner.last_graph_version > 0, "{refiner:?}");
    assert_eq!(refiner.rejections, [0; 8]);
    stop.store(true, Ordering::SeqCst);
    pipeline.wait().expect("orderly shutdown");
}

/// The nearest canonical phrase by MiniLM similarity (needs `.models/`, like
/// `tests/text_encoder.rs`; never skips).
#[test]
fn paraphrased_labels_map_to_the_nearest_canonical_phrase_with_the_text_encoder() {
    use op3dsg_runtime::onnx::text_encoder::{TextEncoder, TextEncoderConfig};
    use op3dsg_runtime::onnx::{OnnxConfig, OnnxRuntime};
    use op3dsg_runtime::reasoner::llm::gate::LabelMapper;
    let runtime = OnnxRuntime::init(&OnnxConfig::default()).expect("ONNX Runtime (run scripts/setup-models.sh)");
    let encoder = TextEncoder::new(&runtime, &TextEncoderConfig { enabled: true, ..TextEncoderConfig::default() })
        .expect("MiniLM (run scripts/setup-models.sh)");
    let mut mapper = LabelMapper::new(Some(Box::new(encoder)), 0.8);
    let id = |phrase: &str| op3dsg_ipc_types::relation_id(phrase).unwrap().1;
    assert_eq!(mapper.relation("pull to open or shut"), Some(id("pull to open or close")));
    assert_eq!(mapper.relation("turn on and turn off"), Some(id("turn on or turn off")));
    assert_eq!(mapper.relation("sing a song"), None);
    assert_eq!(mapper.affordance("hook pulling"), Some(3));
    let mut plain = LabelMapper::new(None, 0.8);
    assert_eq!(plain.relation("pull to open or shut"), None, "no encoder: rejected");
}

/// A functional edge as the tests compare them: source, target, phrase, origin.
type Functional = (u32, u32, &'static str, EdgeOrigin);

/// The LLM's contribution to a graph: its functional edges and every node's affordances.
fn llm_view(graph: &SceneGraph) -> (Vec<Functional>, Vec<(u32, u16)>) {
    let affordances = graph.nodes.iter().map(|n| (n.id, n.affordance_bits)).collect();
    (functional(graph), affordances)
}

#[test]
fn fenced_prose_extra_field_and_string_number_answers_give_the_same_edges() {
    let server = TestServer::start(Mode::Good);
    let (mut plain_enricher, _) = enricher(&overrides(&server, &[]));
    let plain = llm_view(&refine(&mut plain_enricher));
    assert!(plain.0.iter().any(|e| e.3 == EdgeOrigin::Llm), "the plain answers were applied: {plain:?}");
    for mode in [Mode::Fenced, Mode::Prose, Mode::ExtraFields, Mode::StringNumbers] {
        let server = TestServer::start(mode);
        let (mut enricher, stats) = enricher(&overrides(&server, &[]));
        assert_eq!(llm_view(&refine(&mut enricher)), plain, "{mode:?}");
        assert_eq!(stats.health().rejections, [0; 8], "{mode:?}");
        assert_eq!(stats.accepted.load(Ordering::Relaxed), 6, "{mode:?}");
        assert_eq!(stats.failures.load(Ordering::Relaxed), 0, "{mode:?}");
    }
}

#[test]
fn extra_fields_are_malformed_when_the_profile_asks_for_strict_items() {
    let server = TestServer::start(Mode::ExtraFields);
    let (mut enricher, stats) = enricher(&overrides(&server, &["reasoner.llm.ignore_unknown_fields=false"]));
    let graph = refine(&mut enricher);
    assert!(functional(&graph).iter().all(|e| e.3 != EdgeOrigin::Llm));
    // The answer objects carry "notes": each of the three answers is unusable as a whole.
    assert_eq!(stats.rejections(Rejection::Malformed), 3);
}

#[test]
fn non_chat_200s_are_failures_that_open_the_breaker() {
    for mode in [Mode::Html, Mode::EmptyChoices, Mode::NullContent] {
        let server = TestServer::start(mode);
        let (mut enricher, stats) = enricher(&overrides(&server, &["reasoner.llm.breaker_failures=3"]));
        let mut graph = corner();
        let prior = enricher.enrich(&mut graph);
        assert!(enricher.refine_now(&mut graph, prior.clone(), Duration::from_secs(30)), "{mode:?}");
        assert!(graph.edges.iter().all(|e| e.origin != EdgeOrigin::Llm), "{mode:?}");
        // Not retried (the server answered, just not with a completion): one failed call per agent.
        assert_eq!(stats.calls.load(Ordering::Relaxed), 3, "{mode:?}");
        assert_eq!(stats.failures.load(Ordering::Relaxed), 3, "{mode:?}");
        assert!(stats.breaker_open(), "{mode:?}");
        assert_eq!(stats.state(), RefinerState::BreakerOpen as u8, "{mode:?}");
        assert_eq!(stats.last_error(), "not_chat", "{mode:?}");
        assert_eq!(stats.health().rejections, [0; 8], "no answer reached the gate: {mode:?}");
        let report = op3dsg_runtime::ipc::HealthReport::from(&op3dsg_ipc_types::Health {
            refiner: stats.health(),
            ..op3dsg_ipc_types::Health::default()
        });
        assert_eq!(report.refiner.last_error, "not_chat");
        assert!(enricher.refine_now(&mut graph, prior, Duration::from_secs(30)));
        assert_eq!(server.requests().len(), 3, "the open breaker sends nothing: {mode:?}");
    }
}

#[test]
fn with_a_flaky_agent_no_accepted_edge_disappears_while_its_nodes_exist() {
    let server = TestServer::start(Mode::Flaky("local_relations"));
    let (mut enricher, stats) = enricher(&overrides(&server, &["reasoner.llm.max_retries=0"]));
    let mut seen: Vec<Functional> = Vec::new();
    for round in 0..8u64 {
        let mut graph = corner();
        graph.version = 12 + round;
        let prior = enricher.enrich(&mut graph);
        assert!(enricher.refine_now(&mut graph, prior, Duration::from_secs(30)));
        let now = functional(&graph);
        for edge in &seen {
            assert!(now.contains(edge), "round {round}: {edge:?} disappeared; now {now:?}");
        }
        for edge in now.into_iter().filter(|e| matches!(e.3, EdgeOrigin::Llm | EdgeOrigin::KnowledgeAndLlm)) {
            if !seen.contains(&edge) {
                seen.push(edge);
            }
        }
    }
    // The local agent failed on every second call, the others never.
    assert_eq!(stats.failures.load(Ordering::Relaxed), 4);
    assert!(seen.contains(&(5, 1, "push or press to open", EdgeOrigin::Llm)), "{seen:?}");
    assert!(seen.contains(&(4, 3, "remote to control", EdgeOrigin::KnowledgeAndLlm)), "{seen:?}");
    assert_eq!(stats.rejections(Rejection::Stale), 0);

    // When the knob and its stove go while every call fails, their LLM edge and the knob's
    // affordances go (counted stale) and the rest stays.
    server.set_mode(Mode::Status { status: 500, retry_after_s: None, n: 3 });
    let mut graph = corner();
    graph.version = 30;
    graph.nodes.retain(|n| n.id != 6 && n.id != 2);
    graph.edges.retain(|e| e.source_id != 6);
    let prior = enricher.enrich(&mut graph);
    assert!(enricher.refine_now(&mut graph, prior, Duration::from_secs(30)));
    let now = functional(&graph);
    assert!(!now.iter().any(|e| e.0 == 6), "{now:?}");
    assert!(now.contains(&(5, 1, "push or press to open", EdgeOrigin::Llm)), "{now:?}");
    assert!(now.contains(&(4, 3, "remote to control", EdgeOrigin::KnowledgeAndLlm)), "{now:?}");
    assert_eq!(stats.failures.load(Ordering::Relaxed), 4 + 3);
    // The knob's local relation and its affordances.
    assert_eq!(stats.rejections(Rejection::Stale), 2);
}

/// Adds the geometry's `part of` edge for each (part, object).
fn part_of(graph: &mut SceneGraph, pairs: &[(u32, u32)]) {
    for &(part, object) in pairs {
        graph.edges.push(op3dsg_runtime::graph::GraphEdge {
            source_id: part,
            target_id: object,
            kind: EdgeKind::Spatial,
            relation_id: 0,
            confidence: 0.9,
            origin: EdgeOrigin::Geometry,
        });
    }
}

/// The corner with two parts whose geometry rules items out: a cabinet knob 56 cm off the
/// cabinet it is fused onto, and a stove "knob" 60 cm long (a smeared segment).
fn corner_with_odd_parts() -> SceneGraph {
    let mut graph = corner();
    graph.nodes.push(node(7, "cabinet knob", NodeKind::Part, Some(1), [-0.6, -0.03, 0.5], [-0.56, 0.0, 0.54]));
    graph.nodes.push(node(8, "stove knob", NodeKind::Part, Some(2), [1.0, -0.05, 0.7], [1.6, 0.0, 0.75]));
    part_of(&mut graph, &[(7, 1), (8, 2)]);
    graph
}

fn refine_graph(enricher: &mut GraphEnricher, mut graph: SceneGraph) -> SceneGraph {
    let prior = enricher.enrich(&mut graph);
    assert!(enricher.refine_now(&mut graph, prior, Duration::from_secs(30)), "a result arrives");
    graph
}

fn llm_edges(graph: &SceneGraph) -> Vec<Functional> {
    functional(graph).into_iter().filter(|e| matches!(e.3, EdgeOrigin::Llm | EdgeOrigin::KnowledgeAndLlm)).collect()
}

#[test]
fn canonical_but_implausible_items_are_rejected_and_counted_by_rule() {
    let server = TestServer::start(Mode::Implausible);
    // The remote control is 1.73 m from the TV: within the knowledge base's 10 m for "remote to
    // control", beyond this profile's 1 m.
    let extra = ["reasoner.llm.plausibility.remote_max_distance_m.remote_to_control=1.0"];
    let (mut enricher, stats) = enricher(&overrides(&server, &extra));
    let graph = refine_graph(&mut enricher, corner_with_odd_parts());
    let h = stats.health();
    let count = |reason: Rejection| h.rejections[reason as usize];
    // Geometry (checked first for local relations): both relations of the knob 56 cm off its
    // cabinet, the remote 1.73 m from the TV, the 60 cm knob's "rotate".
    assert_eq!(count(Rejection::ImplausibleGeometry), 2 + 1 + 1);
    // Knowledge: "remote to control" from each of the three attached parts to its own object,
    // "press to flush" on the cabinet handle, "provide power" from the remote control.
    assert_eq!(count(Rejection::ImplausibleRelation), 3 + 1 + 1);
    // Knowledge: "foot_push" and "plug_in" on each of the four objects.
    assert_eq!(count(Rejection::ImplausibleAffordance), 4 * 2);
    assert_eq!(h.rejections[..5], [0; 5], "ids, kinds and labels were all fine");
    // What passed: the handle's and the two attached knobs' relations, the handle's and the
    // small knobs' affordances.
    assert_eq!(
        llm_edges(&graph),
        [
            (5, 1, "pull to open or close", EdgeOrigin::KnowledgeAndLlm),
            (6, 2, "rotate to adjust the setting or temperature", EdgeOrigin::KnowledgeAndLlm),
            (8, 2, "rotate to adjust the setting or temperature", EdgeOrigin::KnowledgeAndLlm),
        ]
    );
    assert_eq!(stats.accepted.load(Ordering::Relaxed), 3 + 3);
    for object in graph.nodes.iter().filter(|n| n.kind == NodeKind::Object) {
        let names: Vec<&str> = affordance_names(object.affordance_bits).collect();
        assert!(!names.contains(&"foot_push") && !names.contains(&"plug_in"), "{}: {names:?}", object.label);
    }
    // Health as `op3dsg health` prints it: every rule under its own name.
    let report = op3dsg_runtime::ipc::HealthReport::from(&op3dsg_ipc_types::Health {
        refiner: h,
        ..op3dsg_ipc_types::Health::default()
    });
    let by_name = &report.refiner.rejections;
    assert_eq!(
        (by_name["implausible_geometry"], by_name["implausible_relation"], by_name["implausible_affordance"]),
        (4, 5, 8)
    );
}

#[test]
fn without_the_plausibility_rules_the_same_answers_get_through() {
    let server = TestServer::start(Mode::Implausible);
    let (mut enricher, stats) = enricher(&overrides(&server, &["reasoner.llm.plausibility.enabled=false"]));
    let graph = refine_graph(&mut enricher, corner_with_odd_parts());
    assert_eq!(stats.health().rejections, [0; 8]);
    let edges = llm_edges(&graph);
    for edge in [
        (5, 1, "press to flush", EdgeOrigin::Llm),
        (5, 1, "remote to control", EdgeOrigin::Llm),
        (7, 1, "rotate to adjust the setting or temperature", EdgeOrigin::Llm),
        (4, 3, "provide power", EdgeOrigin::Llm),
        (4, 3, "remote to control", EdgeOrigin::KnowledgeAndLlm),
    ] {
        assert!(edges.contains(&edge), "{edge:?} in {edges:?}");
    }
    let cabinet = graph.nodes.iter().find(|n| n.id == 1).unwrap();
    assert!(affordance_names(cabinet.affordance_bits).any(|a| a == "foot_push"));
}

#[test]
fn a_server_without_structured_output_is_sent_json_object_after_its_first_400() {
    let logs = captured_logs();
    let good = TestServer::start(Mode::Good);
    let (mut plain_enricher, _) = enricher(&overrides(&good, &[]));
    let structured = llm_view(&refine(&mut plain_enricher));
    let server = TestServer::start(Mode::NoSchema);
    let (mut enricher, stats) = enricher(&overrides(&server, &[]));
    assert_eq!(stats.response_format(), "json_schema");
    assert_eq!(llm_view(&refine(&mut enricher)), structured, "the same edges as with structured output");
    // Each agent in flight when the first 400 came was refused once and repeated at once.
    let refused = stats.schema_refusals.load(Ordering::Relaxed);
    assert!((1..=3).contains(&refused), "{refused}");
    assert_eq!(stats.failures.load(Ordering::Relaxed), 0, "a refused schema is no failure");
    assert!(!stats.breaker_open());
    assert_eq!(stats.response_format(), "json_object_fallback");
    let requests = server.requests();
    assert_eq!(requests.iter().filter(|r| r.format == "json_schema").count() as u64, refused);
    assert_eq!(requests.iter().filter(|r| r.format == "json_object").count(), 3);
    // Later refreshes ask for json_object straight away.
    refine(&mut enricher);
    let requests = server.requests();
    assert_eq!(requests.iter().filter(|r| r.format == "json_schema").count() as u64, refused);
    assert_eq!(requests.len() as u64, refused + 6);
    let report = op3dsg_runtime::ipc::HealthReport::from(&op3dsg_ipc_types::Health {
        refiner: stats.health(),
        ..op3dsg_ipc_types::Health::default()
    });
    assert_eq!(report.refiner.response_format, "json_object_fallback");
    let logs = String::from_utf8_lossy(&logs.lock().unwrap()).into_owned();
    let lines = logs.lines().filter(|l| l.contains("answered 400 to response_format json_schema")).count();
    assert_eq!(lines, 1, "logged once: {logs}");
}

/// The project venv's Python and the independent MCAP reader (PyPI `mcap`, set up by
/// `scripts/setup-python.sh`, which `scripts/test.sh` runs).
fn mcap_check(file: &std::path::Path, find: &[&str]) -> Value {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let python = root.join(".venv/bin/python");
    assert!(python.exists(), "{} missing: run ./scripts/setup-python.sh (scripts/test.sh does)", python.display());
    let mut command = std::process::Command::new(python);
    command.arg(root.join("tests/python/mcap_check.py")).arg(file);
    for text in find {
        command.arg("--find").arg(text);
    }
    let output = command.output().expect("run mcap_check.py");
    assert!(output.status.success(), "mcap_check.py failed: {}", String::from_utf8_lossy(&output.stderr));
    serde_json::from_slice(&output.stdout).expect("mcap_check.py prints JSON")
}

#[test]
fn the_recorder_keeps_every_llm_exchange_and_never_the_key() {
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    const KEY: &str = "sk-op3dsg-record-test-5d1e8b3c";
    let dir = tempfile::tempdir().unwrap();
    let key_file = dir.path().join("llm.key");
    std::fs::write(&key_file, format!("{KEY}\n")).unwrap();
    let record_dir = dir.path().join("rec");
    // The first request gets a 500 and is not retried: one exchange with an error.
    let server = TestServer::start(Mode::Status { status: 500, retry_after_s: None, n: 1 });
    let prefix = format!("op3dsg-test-llm-record-{}", std::process::id());
    let mut o = overrides(
        &server,
        &[
            &format!("ipc.prefix={prefix:?}"),
            "reasoner.llm.max_retries=0",
            "reasoner.llm.refresh_min_changed_nodes=1",
            "reasoner.llm.refresh_period_s=0.3",
            "record.enabled=true",
            // Uncompressed chunks: the key check below also reads the file's raw bytes.
            "record.compression=\"none\"",
        ],
    );
    o.push(format!("reasoner.llm.api_key_file={:?}", key_file.display().to_string()));
    o.push(format!("record.dir={:?}", record_dir.display().to_string()));
    let profile = op3dsg_sim::load_profile(None, &o).expect("profile").profile;
    let stop = Arc::new(AtomicBool::new(false));
    let pipeline = Pipeline::start(&profile, &op3dsg_sim::backends(), stop.clone()).expect("pipeline starts");
    let stats = pipeline.counters().clone();
    let wait = |what: &str, done: &dyn Fn() -> bool| {
        let deadline = Instant::now() + WATCHDOG;
        while !done() {
            assert!(Instant::now() < deadline, "timed out waiting for {what}");
            std::thread::sleep(Duration::from_millis(20));
        }
    };
    wait("accepted LLM items", &|| stats.refiner.accepted.load(Ordering::Relaxed) > 0);
    // Then answers naming nodes the graph does not have: rejected, counted by reason.
    server.set_mode(Mode::UnknownIds);
    wait("rejected LLM items", &|| stats.refiner.rejections(Rejection::UnknownNode) > 0);
    stop.store(true, Ordering::SeqCst);
    pipeline.wait().expect("orderly shutdown");

    let files: Vec<_> = std::fs::read_dir(&record_dir).unwrap().map(|e| e.unwrap().path()).collect();
    assert_eq!(files.len(), 1, "{files:?}");
    let bytes = std::fs::read(&files[0]).unwrap();
    assert!(!bytes.windows(KEY.len()).any(|w| w == KEY.as_bytes()), "the key is in the recording");
    assert!(!bytes.windows(6).any(|w| w.eq_ignore_ascii_case(b"bearer")), "an auth header is in the recording");
    let summary = mcap_check(&files[0], &[KEY, "Bearer", "authorization"]);
    assert_eq!(summary["error"], Value::Null, "{summary}");
    assert_eq!(summary["message_texts_with"][KEY], Value::Null, "the key is in a message: {summary}");
    assert_eq!(summary["message_texts_with"]["Bearer"], Value::Null, "{summary}");
    assert_eq!(summary["message_texts_with"]["authorization"], Value::Null, "{summary}");
    assert_eq!(summary["embedded_errors"], json!([]), "{summary}");
    assert_eq!(summary["channels"]["/op3dsg/llm"]["schema"], "op3dsg.LlmExchange");
    let exchanges = summary["llm_exchanges"].as_array().unwrap().clone();
    let requests = server.requests();
    // Every request the server saw is one exchange's (no retries here), except those of a
    // refresh the shutdown cancelled in flight (at most one per agent).
    assert!(
        exchanges.len() <= requests.len() && exchanges.len() + 3 >= requests.len(),
        "{} exchanges, {} requests",
        exchanges.len(),
        requests.len()
    );
    for r in &requests {
        assert_eq!(r.authorization.as_deref(), Some(format!("Bearer {KEY}").as_str()), "the key is sent");
    }
    for (e, r) in exchanges.iter().zip(&requests) {
        let sent: Value = serde_json::from_str(&r.body).unwrap();
        // The recorded prompt is the one sent (requests and exchanges of a refresh may be in
        // another order: matched by agent and prompt).
        let same = requests.iter().any(|r| {
            let sent: Value = serde_json::from_str(&r.body).unwrap();
            sent["messages"] == e["messages"]
        });
        assert!(same, "exchange prompt not among the requests: {e}");
        assert_eq!(sent["messages"].as_array().unwrap().len(), 2);
        assert_eq!(e["model"], "test-model");
        assert_eq!(e["attempts"], 1);
        assert!(e["latency_ms"].as_f64().unwrap() > 0.0);
    }
    let failed: Vec<&Value> = exchanges.iter().filter(|e| e["answer"].is_null()).collect();
    assert_eq!(failed.len(), 1, "one 500: {exchanges:?}");
    assert!(failed[0]["error"].as_str().unwrap().contains("500"), "{}", failed[0]);
    assert_eq!(failed[0]["verdict"], Value::Null);
    let accepted = exchanges.iter().filter(|e| e["verdict"]["accepted"].as_u64().unwrap_or(0) > 0).count();
    assert!(accepted >= 1, "{exchanges:?}");
    let rejected: u64 = exchanges.iter().filter_map(|e| e["verdict"]["rejected"]["unknown_node"].as_u64()).sum();
    assert_eq!(rejected, stats.refiner.rejections(Rejection::UnknownNode), "rejections by reason as counted");
    for e in exchanges.iter().filter(|e| !e["answer"].is_null()) {
        assert_eq!(e["error"], Value::Null);
        assert_eq!(e["verdict"]["parsed"], true, "{e}");
    }
}

// The real daemon: `op3dsgd` as a child process on the synthetic kitchen, its refiner calling the
// test server over HTTP, read back over iceoryx2 and through the `op3dsg` CLI as a planner would.

/// `op3dsgd` (the built binary, `cargo build -p op3dsgd` first) on the synthetic kitchen at
/// 30 frames/s, the refiner pointed at `server` and refreshing every 0.5 s; `extra` are more
/// profile overrides.
fn start_daemon(name: &str, server: &TestServer, extra: &[&str]) -> op3dsg_tests::Daemon {
    let prefix = op3dsg_tests::unique_prefix(name);
    let mut sets = vec!["source.rate_hz=30".to_owned(), "health.period_ms=100".to_owned()];
    sets.extend(overrides(
        server,
        &[
            "reasoner.llm.api_key_credential=\"\"",
            "reasoner.llm.refresh_min_changed_nodes=1",
            "reasoner.llm.refresh_period_s=0.5",
        ],
    ));
    sets.extend(extra.iter().map(|s| (*s).to_owned()));
    let args: Vec<&str> = sets.iter().flat_map(|s| ["--set", s.as_str()]).collect();
    op3dsg_tests::Daemon::start(&prefix, &args)
}

/// `op3dsg --prefix <prefix> <args>` (the built CLI); its standard output.
fn op3dsg_cli(prefix: &str, args: &[&str]) -> String {
    let output = std::process::Command::new(op3dsg_tests::binary("op3dsg"))
        .arg("--prefix")
        .arg(prefix)
        .args(args)
        .output()
        .unwrap();
    assert!(output.status.success(), "op3dsg {args:?}: {}", String::from_utf8_lossy(&output.stderr));
    String::from_utf8(output.stdout).unwrap()
}

/// From the LLM (alone or confirming the knowledge base).
fn from_llm(origin: Option<EdgeOrigin>) -> bool {
    matches!(origin, Some(EdgeOrigin::Llm | EdgeOrigin::KnowledgeAndLlm))
}

#[test]
fn the_daemon_publishes_each_affordance_with_its_origin_over_iceoryx2_and_in_op3dsg_dump() {
    let server = TestServer::start(Mode::Good);
    let daemon = start_daemon("llm-origins", &server, &[]);
    let mut graphs = daemon.graph_subscriber("llm-origins-graph");
    // A cabinet handle: hook_pull from the knowledge base and the LLM, pinch_pull from the LLM
    // alone (the server's answer for handles on cabinets); and a node whose affordance only the
    // knowledge base gives (the server names affordances for handles and knobs only).
    let (handle, knowledge_only) = op3dsg_tests::wait_for("a handle with LLM affordances", WATCHDOG, || {
        let graph = graphs.latest().ok().flatten()?;
        let handle = graph.nodes().find(|n| {
            n.label() == "cabinet handle"
                && n.affordance_origin("hook_pull") == Some(EdgeOrigin::KnowledgeAndLlm)
                && n.affordance_origin("pinch_pull") == Some(EdgeOrigin::Llm)
        })?;
        let other = graph.nodes().find_map(|n| {
            n.affordance_origins()
                .find(|(_, origin)| *origin == EdgeOrigin::Knowledge)
                .filter(|_| !n.label().ends_with("handle") && !n.label().ends_with("knob"))
                .map(|(name, _)| (n.id(), n.label().to_owned(), name))
        })?;
        Some((handle.id(), other))
    });
    // The graph JSON of `op3dsg dump --json` (what `op3dsg eval` and the MCAP recorder write)
    // carries the same origins beside the names, and so does the LLM form.
    let dumped: Value = serde_json::from_str(&op3dsg_cli(&daemon.prefix, &["dump", "--json"])).unwrap();
    let node = |id: u32| dumped["nodes"].as_array().unwrap().iter().find(|n| n["id"] == id).cloned().unwrap();
    let handle_json = node(handle);
    assert_eq!(handle_json["affordances"], json!(["hook_pull", "pinch_pull"]), "{handle_json}");
    assert_eq!(handle_json["affordance_origins"], json!({"hook_pull": "knowledge+llm", "pinch_pull": "llm"}));
    let (id, label, name) = knowledge_only;
    assert_eq!(node(id)["affordance_origins"][name], "knowledge", "{label}: {}", node(id));
    let llm_form = op3dsg_cli(&daemon.prefix, &["dump", "--format", "llm"]);
    let parts: Vec<Value> = llm_form
        .lines()
        .skip(1)
        .map(|line| serde_json::from_str::<Value>(line).unwrap())
        .flat_map(|line| line["object"]["parts"].as_array().cloned().unwrap_or_default())
        .collect();
    let part = parts.iter().find(|p| p["id"] == handle).unwrap();
    assert_eq!(part["affordance_origins"], json!({"hook_pull": "knowledge+llm", "pinch_pull": "llm"}), "{part}");
}

#[test]
fn the_daemon_rejects_implausible_items_counts_them_by_rule_and_publishes_none() {
    let server = TestServer::start(Mode::Implausible);
    // For this test no part longer than 1 cm is rotated, so every knob's "rotate" from the server
    // fails on its size (implausible_geometry); the kitchen's parts are all attached close to
    // their objects, so geometry rules nothing else out there.
    let daemon = start_daemon("llm-implausible", &server, &["reasoner.llm.plausibility.part_max_extent_m.rotate=0.01"]);
    let mut health = daemon.health_subscriber("llm-implausible-health");
    let mut graphs = daemon.graph_subscriber("llm-implausible-graph");
    let count = |h: &op3dsg_ipc_types::Health, reason: &str| {
        h.refiner.rejections[op3dsg_ipc_types::REFINER_REJECTIONS.iter().position(|r| *r == reason).unwrap()]
    };
    let plausibility = ["implausible_geometry", "implausible_relation", "implausible_affordance"];
    let counted = op3dsg_tests::health_where(&mut health, "a rejection under each plausibility rule", WATCHDOG, |h| {
        h.refiner.accepted > 0 && plausibility.iter().all(|reason| count(h, reason) > 0)
    });
    for reason in ["malformed", "unknown_node", "wrong_kind", "non_canonical"] {
        assert_eq!(
            count(&counted, reason),
            0,
            "{reason}: the answers use the prompt's ids, kinds and canonical labels"
        );
    }
    assert_eq!(counted.refiner.failures, 0, "{:?}", counted.refiner);

    // Every graph published from then on: no implausible item, the plausible ones there.
    let (mut last, mut graphs_checked, mut confirmed) = (counted.graph_version, 0, false);
    op3dsg_tests::wait_for("five newer graphs with a confirmed edge and affordance", WATCHDOG, || {
        let graph = graphs.latest().ok().flatten()?;
        if graph.version() <= last {
            return None;
        }
        last = graph.version();
        graphs_checked += 1;
        for e in graph.edges().filter(|e| e.kind() == EdgeKind::Functional && from_llm(Some(e.origin()))) {
            let source = graph.node(e.source_id()).unwrap();
            let (label, phrase) = (source.label(), e.phrase());
            let what = format!("v{}: {label} {} -[{phrase}]-> {}", graph.version(), e.source_id(), e.target_id());
            assert!(!(phrase == "remote to control" && source.parent_id() == Some(e.target_id())), "{what}");
            assert!(!(phrase == "press to flush" && label.ends_with("handle")), "{what}");
            assert!(phrase != "provide power" || remote_relation(label) == "provide power", "{what}");
        }
        for n in graph.nodes() {
            let what = format!("v{}: {} {}", graph.version(), n.id(), n.label());
            if n.is_object() {
                // The knowledge base gives plug_in to no kitchen object and foot_push only to the
                // trash can (its pedal).
                assert!(!from_llm(n.affordance_origin("plug_in")), "{what}");
                assert!(n.label() == "trash can" || !from_llm(n.affordance_origin("foot_push")), "{what}");
            }
            assert!(!(n.label().ends_with("knob") && from_llm(n.affordance_origin("rotate"))), "{what}");
        }
        confirmed |=
            graph.edges().any(|e| e.origin() == EdgeOrigin::KnowledgeAndLlm && e.phrase() == "pull to open or close")
                && graph.nodes().any(|n| n.affordance_origin("hook_pull") == Some(EdgeOrigin::KnowledgeAndLlm));
        (graphs_checked >= 5 && confirmed).then_some(())
    });

    // `op3dsg health --json` names each rule's count.
    let report: Value = serde_json::from_str(&op3dsg_cli(&daemon.prefix, &["health", "--json"])).unwrap();
    for reason in plausibility {
        let n = report["refiner"]["rejections"][reason].as_u64().unwrap();
        assert!(n >= count(&counted, reason), "{reason}: {n} in {}", report["refiner"]);
    }
    // And so does its text form, each reason with its count on the rejections line.
    let text = op3dsg_cli(&daemon.prefix, &["health"]);
    let line = text.lines().find(|l| l.starts_with("llm rejections")).unwrap_or_else(|| panic!("{text}"));
    let shown: Vec<(&str, u64)> = line["llm rejections".len()..]
        .split("  ")
        .filter_map(|kv| kv.trim().split_once(' '))
        .map(|(k, v)| (k, v.parse().unwrap()))
        .collect();
    assert_eq!(shown.len(), op3dsg_ipc_types::REFINER_REJECTIONS.len(), "{line}");
    for (reason, n) in shown {
        let least = count(&counted, reason);
        // Stale items (nodes fusion pruned since) may be counted on a live run; nothing else is.
        let right = match reason {
            _ if plausibility.contains(&reason) => n >= least && n > 0,
            "stale" => n >= least,
            _ => n == 0,
        };
        assert!(right, "{reason} {n}: {line}");
    }
}

/// The LLM's items in a published graph, by label so that runs can be compared whatever ids
/// fusion gave: `"cabinet handle -[pull to open or close]-> cabinet (knowledge+llm)"` for an
/// edge, `"cabinet handle: pinch_pull (llm)"` for an affordance.
fn llm_items_by_label(graph: &op3dsg_ipc_types::Graph) -> std::collections::BTreeSet<String> {
    let label = |id: u32| graph.node(id).map_or("?", |n| n.label());
    let edges = graph.edges().filter(|e| e.kind() == EdgeKind::Functional && from_llm(Some(e.origin()))).map(|e| {
        let (source, target) = (label(e.source_id()), label(e.target_id()));
        format!("{source} -[{}]-> {target} ({})", e.phrase(), e.origin().as_str())
    });
    let affordances = graph.nodes().flat_map(|n| {
        n.affordance_origins()
            .filter(|(_, origin)| from_llm(Some(*origin)))
            .map(move |(name, origin)| format!("{}: {name} ({})", n.label(), origin.as_str()))
    });
    edges.chain(affordances).collect()
}

#[test]
fn the_daemon_reads_fenced_prose_extra_field_and_string_number_answers_like_plain_ones() {
    // Plain answers first: what the LLM adds to the kitchen once the set has held for five newer
    // graphs (the robot's path keeps showing the same nodes).
    let plain = {
        let server = TestServer::start(Mode::Good);
        let daemon = start_daemon("llm-plain", &server, &[]);
        let mut graphs = daemon.graph_subscriber("llm-plain-graph");
        let (mut last, mut held, mut items) = (0, 0, Default::default());
        op3dsg_tests::wait_for("the LLM's items holding for five graphs", WATCHDOG, || {
            let graph = graphs.latest().ok().flatten().filter(|g| g.version() > last)?;
            last = graph.version();
            let now = llm_items_by_label(graph);
            held = if now == items { held + 1 } else { 0 };
            items = now;
            (held >= 5 && items.iter().any(|i| i.starts_with("cabinet handle: pinch_pull"))).then(|| items.clone())
        })
    };
    assert!(plain.contains("cabinet handle: hook_pull (knowledge+llm)"), "{plain:#?}");
    assert!(plain.iter().any(|i| i.starts_with("cabinet handle -[pull to open or close]->")), "{plain:#?}");

    // Each dressed answer: every item of it accepted, none rejected, no failure, and a published
    // graph with at least the plain answers' items (each answer is built from its own prompt).
    for mode in [Mode::Fenced, Mode::Prose, Mode::ExtraFields, Mode::StringNumbers] {
        let name = format!("llm-{mode:?}").to_lowercase();
        let server = TestServer::start(mode);
        let daemon = start_daemon(&name, &server, &[]);
        let mut health = daemon.health_subscriber(&format!("{name}-health"));
        let mut graphs = daemon.graph_subscriber(&format!("{name}-graph"));
        let mut last = 0;
        let graph_version = op3dsg_tests::wait_for(&format!("{mode:?}: the plain answers' items"), WATCHDOG, || {
            let graph = graphs.latest().ok().flatten().filter(|g| g.version() > last)?;
            last = graph.version();
            llm_items_by_label(graph).is_superset(&plain).then_some(last)
        });
        let counted = op3dsg_tests::health_where(&mut health, "health of that graph", WATCHDOG, |h| {
            h.graph_version >= graph_version && h.refiner.accepted > 0
        });
        let rejected: Vec<_> = op3dsg_ipc_types::REFINER_REJECTIONS
            .iter()
            .zip(counted.refiner.rejections)
            .filter(|(_, n)| *n > 0)
            .collect();
        assert!(rejected.is_empty(), "{mode:?}: rejected {rejected:?}");
        assert_eq!(counted.refiner.failures, 0, "{mode:?}: {:?}", counted.refiner);
    }
}

#[test]
fn with_a_flaky_agent_the_daemon_publishes_every_accepted_edge_while_its_nodes_exist() {
    use std::collections::HashMap;
    let server = TestServer::start(Mode::Flaky("local_relations"));
    // No retries: every second call of the local agent is a failed call.
    let daemon = start_daemon("llm-flaky", &server, &["reasoner.llm.max_retries=0"]);
    let mut health = daemon.health_subscriber("llm-flaky-health");
    let mut graphs = daemon.graph_subscriber("llm-flaky-graph");
    // A node as an item was checked against: kind, parent, label (a new label is a new prompt,
    // and the next answer may rightly differ).
    type Seen = (NodeKind, Option<u32>, String);
    let node_now = |graph: &op3dsg_ipc_types::Graph, id: u32| -> Option<Seen> {
        graph.node(id).map(|n| (n.kind(), n.parent_id(), n.label().to_owned()))
    };
    // Each LLM edge (source, target, phrase) and affordance (node, name) first seen, with its
    // nodes as they were then.
    let mut edges: HashMap<(u32, u32, String), (Seen, Seen)> = HashMap::new();
    let mut affordances: HashMap<(u32, &'static str), Seen> = HashMap::new();
    let (mut last, mut graphs_checked, mut failures) = (0, 0, 0);
    op3dsg_tests::wait_for("four failed calls of the local agent while graphs are published", WATCHDOG, || {
        if let Some(h) = health.latest().ok().flatten() {
            failures = h.refiner.failures;
        }
        let graph = graphs.latest().ok().flatten().filter(|g| g.version() > last)?;
        last = graph.version();
        graphs_checked += 1;
        for ((source, target, phrase), (s, t)) in &edges {
            if node_now(graph, *source).as_ref() == Some(s) && node_now(graph, *target).as_ref() == Some(t) {
                let kept = graph
                    .edges_from(*source)
                    .any(|e| e.target_id() == *target && e.phrase() == phrase && from_llm(Some(e.origin())));
                assert!(kept, "v{last}: {} -[{phrase}]-> {} from the LLM is gone, its nodes unchanged", s.2, t.2);
            }
        }
        for ((id, name), n) in &affordances {
            if node_now(graph, *id).as_ref() == Some(n) {
                let origin = graph.node(*id).and_then(|node| node.affordance_origin(name));
                assert!(from_llm(origin), "v{last}: {} {id}: {name} from the LLM is now {origin:?}", n.2);
            }
        }
        for e in graph.edges().filter(|e| e.kind() == EdgeKind::Functional && from_llm(Some(e.origin()))) {
            let nodes = node_now(graph, e.source_id()).zip(node_now(graph, e.target_id()));
            if let Some(nodes) = nodes {
                edges.entry((e.source_id(), e.target_id(), e.phrase().to_owned())).or_insert(nodes);
            }
        }
        for n in graph.nodes() {
            for (name, _) in n.affordance_origins().filter(|(_, origin)| from_llm(Some(*origin))) {
                affordances.entry((n.id(), name)).or_insert_with(|| node_now(graph, n.id()).unwrap());
            }
        }
        (failures >= 4 && graphs_checked >= 10).then_some(())
    });
    // The failures were the local agent's, and its items were among those kept.
    let requests = server.requests();
    assert!(requests.iter().filter(|r| r.agent == "local_relations").count() >= 8, "{}", requests.len());
    assert!(
        edges.keys().any(|(_, _, phrase)| phrase == "push or press to open"),
        "an LLM-only local relation was published: {:?}",
        edges.keys().collect::<Vec<_>>()
    );
}

#[test]
fn non_chat_200s_open_the_daemons_breaker_named_in_health_while_the_graph_goes_on() {
    // An nginx welcome page with status 200 for every request (a proxy in front of no model).
    let server = TestServer::start(Mode::Html);
    let daemon = start_daemon(
        "llm-not-chat",
        &server,
        &["reasoner.llm.max_retries=0", "reasoner.llm.breaker_failures=3", "reasoner.llm.breaker_cooldown_s=60"],
    );
    let mut health = daemon.health_subscriber("llm-not-chat-health");
    let open = op3dsg_tests::health_where(&mut health, "the breaker open", WATCHDOG, |h| h.refiner.breaker_open == 1);
    let r = &open.refiner;
    assert_eq!(op3dsg_ipc_types::REFINER_ERRORS[usize::from(r.last_error)], "not_chat", "{r:?}");
    assert!(r.failures >= 3, "each page is a failed call: {r:?}");
    assert_eq!((r.accepted, r.rejections), (0, [0; 8]), "a page is no answer to reject: {r:?}");
    // Fusion goes on without the refiner.
    op3dsg_tests::health_where(&mut health, "newer graphs with the breaker open", WATCHDOG, |h| {
        h.graph_version > open.graph_version + 5 && h.refiner.breaker_open == 1
    });
    let text = op3dsg_cli(&daemon.prefix, &["health"]);
    assert!(text.contains("(breaker open)") && text.contains("last not_chat)"), "{text}");
}

#[test]
fn the_daemon_publishes_nothing_from_answers_with_hallucinated_ids_and_counts_them() {
    // Every id in every answer is one the prompt never had (the prompt's ids + 100000).
    let server = TestServer::start(Mode::UnknownIds);
    let daemon = start_daemon("llm-unknown-ids", &server, &[]);
    let mut health = daemon.health_subscriber("llm-unknown-ids-health");
    let mut graphs = daemon.graph_subscriber("llm-unknown-ids-graph");
    let unknown = op3dsg_ipc_types::REFINER_REJECTIONS.iter().position(|r| *r == "unknown_node").unwrap();
    let counted = op3dsg_tests::health_where(&mut health, "rejections as unknown_node", WATCHDOG, |h| {
        h.refiner.rejections[unknown] >= 5 && h.refiner.refreshes >= 2
    });
    assert_eq!(counted.refiner.accepted, 0, "{:?}", counted.refiner);
    let others: u64 =
        counted.refiner.rejections.iter().enumerate().filter(|(i, _)| *i != unknown).map(|(_, n)| n).sum();
    assert_eq!(others, 0, "only unknown ids are wrong in these answers: {:?}", counted.refiner);
    // Graphs published from then on carry nothing from the LLM, and the knowledge base's
    // affordances as soon as fusion has parts.
    let (mut last, mut checked, mut knowledge) = (counted.graph_version, 0, false);
    op3dsg_tests::wait_for("five newer graphs, one with a knowledge-base affordance", WATCHDOG, || {
        let graph = graphs.latest().ok().flatten().filter(|g| g.version() > last)?;
        last = graph.version();
        checked += 1;
        let from_the_llm = llm_items_by_label(graph);
        assert!(from_the_llm.is_empty(), "v{last}: {from_the_llm:#?}");
        knowledge |= graph.nodes().any(|n| n.affordance_origins().any(|(_, o)| o == EdgeOrigin::Knowledge));
        (checked >= 5 && knowledge).then_some(())
    });
    let text = op3dsg_cli(&daemon.prefix, &["health"]);
    assert!(!text.contains("unknown_node 0 ") && text.contains("unknown_node "), "{text}");
}
