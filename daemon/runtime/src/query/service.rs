//! The query service's two threads: `op3dsg-query-rx` takes requests off `<prefix>/query` and
//! `op3dsg-query` answers them, one at a time, with its own text encoder.
//!
//! ```text
//! planners ──[iceoryx2 request-response <prefix>/query]──► query-rx ──[jobs: bounded, query.queue_capacity]──► query worker
//!                                        ◄── busy / bad request / encoder off (at once) ◄┘                      │
//!                                        ◄───────────────────────── top-k reply ◄───────────────────────────────┘
//! publisher ──[latest graph, latest wins]──────────────────────────────────────────────────────────────────────►┘
//! ```
//!
//! - The receiver never blocks: a request finds room in the bounded job queue or is refused at
//!   once with [`QueryStatus::Busy`] (counted; the count travels in every reply). Malformed
//!   requests and, without the text encoder, every request get their error reply here.
//! - Every reply's hits carry approach poses ([`Navigator`]: the newest occupancy map the
//!   occupancy thread handed over, inflated and flooded once per map version, A* per hit; see
//!   [`crate::occupancy::nav`]). A request naming a node (`QueryRequest::node_id`) is answered
//!   with that node alone and needs no text encoder, so the worker runs with the encoder off
//!   too; text requests then get [`QueryStatus::EncoderOff`] from the receiver at once.
//! - The worker holds the only [`TextEncoder`] of the service (ONNX Runtime with the profile's
//!   `text_encoder.intra_op_threads`), so at most one query is scored at a time and the fusion
//!   thread never waits on a query. It takes the newest graph the publisher has sent
//!   ([`LatestGraph`]) and re-indexes only when the version changed.
//! - Shutdown: both end with the stop flag, or when the publisher has ended (the end of a
//!   finite source with `run.exit_at_end`); requests still queued get [`QueryStatus::ShuttingDown`].

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError, Sender, TrySendError};
use iceoryx2::active_request::ActiveRequest;
use iceoryx2::port::server::Server;
use op3dsg_ipc_types::services::{
    QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT, QUERY_MAX_CLIENTS, QUERY_MAX_NODES, QUERY_MAX_SERVERS, QUERY_RESPONSE_BUFFER,
    query_service_name,
};
use op3dsg_ipc_types::{
    ApproachStatus, QUERY_MAX_K, QUERY_SCHEMA_VERSION, QueryHit, QueryRequest, QueryResponse, QueryStatus,
    write_fixed_str,
};
use tracing::{info, warn};

use super::{Hit, QueryConfig, QueryIndex, ScoringOptions};
use crate::config::UpAxis;
use crate::graph::SceneGraph;
use crate::ipc::{IpcError, IpcService, create_node, service_err, service_name};
use crate::occupancy::nav::{MapView, NavigationConfig, Planner, Target};
use crate::occupancy::service::{LatestOccupancy, MapCopy};
use crate::onnx::OnnxConfig;
use crate::onnx::text_encoder::{TextEncoder, TextEncoderConfig};

/// A request taken off the service, with its reply port.
type Request = ActiveRequest<IpcService, QueryRequest, (), QueryResponse, ()>;

/// How long the receiver sleeps when no request is waiting.
const RECEIVE_POLL: Duration = Duration::from_millis(1);
/// How long the worker waits for a job before it checks the stop flag again.
const WORKER_POLL: Duration = Duration::from_millis(20);

/// The newest graph the publisher sent, for the query worker (latest wins; a copy per version,
/// made on the publisher thread).
#[derive(Debug, Default)]
pub struct LatestGraph {
    slot: Mutex<Option<(Arc<SceneGraph>, u64)>>,
    closed: AtomicBool,
}

impl LatestGraph {
    /// An empty slot.
    pub fn new() -> Self {
        Self::default()
    }

    /// Replaces the graph (published by daemon instance `instance_id`).
    pub fn set(&self, graph: Arc<SceneGraph>, instance_id: u64) {
        *self.slot.lock().unwrap_or_else(std::sync::PoisonError::into_inner) = Some((graph, instance_id));
    }

    /// The newest graph and its instance id.
    pub fn get(&self) -> Option<(Arc<SceneGraph>, u64)> {
        self.slot.lock().unwrap_or_else(std::sync::PoisonError::into_inner).clone()
    }

    /// The publisher has ended: no newer graph will come, the query threads end too.
    pub fn close(&self) {
        self.closed.store(true, Ordering::Relaxed);
    }

    fn is_closed(&self) -> bool {
        self.closed.load(Ordering::Relaxed)
    }
}

/// Counters of the query service, shared by its threads.
#[derive(Debug, Default)]
pub struct QueryCounters {
    /// Requests answered with hits.
    pub served: AtomicU64,
    /// Requests refused because the job queue was full.
    pub refused: AtomicU64,
    /// Requests answered with an error (bad request, encoder off or failed, no graph).
    pub failed: AtomicU64,
}

/// What the worker needs to load its encoder; `None` when the profile has the encoder off.
#[derive(Debug, Clone)]
pub struct EncoderSetup {
    /// `[onnx]`.
    pub onnx: OnnxConfig,
    /// `[text_encoder]`.
    pub text_encoder: TextEncoderConfig,
}

/// The receiver's side, created on its thread: the iceoryx2 node, service and server port.
#[derive(Debug)]
pub struct QueryReceiver {
    server: Server<IpcService, QueryRequest, (), QueryResponse, ()>,
    service: String,
    _node: iceoryx2::node::Node<IpcService>,
}

impl QueryReceiver {
    /// Creates (or reopens) `<prefix>/query` with the contract's QoS and its server port.
    pub fn open(prefix: &str) -> Result<Self, IpcError> {
        let full = query_service_name(prefix);
        let name = service_name(prefix, &full)?;
        let node = create_node("op3dsgd-query")?;
        let factory = node
            .service_builder(&name)
            .request_response::<QueryRequest, QueryResponse>()
            .max_servers(QUERY_MAX_SERVERS)
            .max_clients(QUERY_MAX_CLIENTS)
            .max_active_requests_per_client(QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT)
            .max_response_buffer_size(QUERY_RESPONSE_BUFFER)
            .max_nodes(QUERY_MAX_NODES)
            .open_or_create()
            .map_err(|e| service_err(&full, "open or create", e))?;
        let server = factory.server_builder().create().map_err(|e| service_err(&full, "create server", e))?;
        info!(service = %full, "serving language queries");
        Ok(Self { server, service: full, _node: node })
    }
}

fn reply(request: &Request, response: &QueryResponse) {
    if let Err(e) = request.send_copy(*response) {
        // The client gave up (dropped its pending response) or died: nothing to tell anyone.
        tracing::debug!(error = ?e, "query reply not delivered");
    }
}

fn failure(status: QueryStatus, message: &str, capacity: usize, counters: &QueryCounters) -> QueryResponse {
    let mut response = QueryResponse::failure(status, message);
    response.queue_capacity = capacity as u32;
    response.served_count = counters.served.load(Ordering::Relaxed);
    response.refused_count = counters.refused.load(Ordering::Relaxed);
    response
}

/// Why a request cannot be scored, decided before it is queued.
fn check_request(request: &QueryRequest) -> Result<(), String> {
    if request.schema_version != QUERY_SCHEMA_VERSION {
        return Err(format!(
            "schema_version: request has {}, the daemon speaks {QUERY_SCHEMA_VERSION}",
            request.schema_version
        ));
    }
    if request.k == 0 {
        return Err(format!("k: must be within [1, {QUERY_MAX_K}], got 0"));
    }
    if request.asked_node().is_none() && request.text_str().trim().is_empty() {
        return Err("text: empty (or not UTF-8), and node_id names no node".to_owned());
    }
    Ok(())
}

/// The receiver thread's loop.
pub fn receive_loop(
    receiver: QueryReceiver,
    jobs: Sender<Request>,
    encoder_on: bool,
    config: &QueryConfig,
    counters: &QueryCounters,
    latest: &LatestGraph,
    stop: &AtomicBool,
) {
    let capacity = config.queue_capacity;
    let mut receive_errors = 0u64;
    while !stop.load(Ordering::Relaxed) && !latest.is_closed() {
        let mut got_any = false;
        loop {
            let request = match receiver.server.receive() {
                Ok(Some(request)) => request,
                Ok(None) => break,
                Err(e) => {
                    receive_errors += 1;
                    if receive_errors.is_power_of_two() {
                        warn!(service = %receiver.service, error = ?e, receive_errors, "query receive failed");
                    }
                    break;
                }
            };
            got_any = true;
            if let Err(message) = check_request(request.payload()) {
                counters.failed.fetch_add(1, Ordering::Relaxed);
                reply(&request, &failure(QueryStatus::BadRequest, &message, capacity, counters));
                continue;
            }
            if !encoder_on && request.payload().asked_node().is_none() {
                counters.failed.fetch_add(1, Ordering::Relaxed);
                let message = "the daemon runs without the text encoder: set text_encoder.enabled = true \
                               (and run scripts/setup-models.sh) to serve queries";
                reply(&request, &failure(QueryStatus::EncoderOff, message, capacity, counters));
                continue;
            }
            match jobs.try_send(request) {
                Ok(()) => {}
                Err(TrySendError::Full(request)) => {
                    let refused = counters.refused.fetch_add(1, Ordering::Relaxed) + 1;
                    if refused.is_power_of_two() {
                        warn!(refused, queue_capacity = capacity, "query queue full; request refused");
                    }
                    let message = format!("busy: {capacity} queries already wait (query.queue_capacity); retry later");
                    reply(&request, &failure(QueryStatus::Busy, &message, capacity, counters));
                }
                Err(TrySendError::Disconnected(request)) => {
                    reply(
                        &request,
                        &failure(QueryStatus::ShuttingDown, "the query worker has ended", capacity, counters),
                    );
                }
            }
        }
        if !got_any {
            std::thread::sleep(RECEIVE_POLL);
        }
    }
}

/// What the worker needs for approach poses.
#[derive(Debug, Clone)]
pub struct NavigationSetup {
    /// The occupancy thread's map (`None` with `occupancy.enabled = false`).
    pub occupancy: Option<Arc<LatestOccupancy>>,
    /// `[navigation]`.
    pub config: NavigationConfig,
    /// `world.up_axis`.
    pub up_axis: UpAxis,
}

/// Approach poses for the hits of a reply: the newest map the occupancy thread handed over,
/// inflated and flooded once per map version ([`Planner::prepare`]).
#[derive(Debug)]
pub struct Navigator {
    setup: NavigationSetup,
    map: Option<MapCopy>,
    prepared_version: Option<u64>,
    planner: Planner,
}

impl Navigator {
    /// A navigator over `setup`.
    pub fn new(setup: NavigationSetup) -> Self {
        let planner = Planner::new(&setup.config);
        Self { setup, map: None, prepared_version: None, planner }
    }

    /// Fills the approach fields of `response`'s hits from `graph` (the graph the hits came from).
    pub fn fill(&mut self, graph: &SceneGraph, response: &mut QueryResponse) {
        let hit_count = (response.hit_count as usize).min(QUERY_MAX_K);
        let Some(latest) = self.setup.occupancy.as_ref() else {
            return; // Hits keep `ApproachStatus::Off`.
        };
        if !latest.copy_if_newer(&mut self.map) {
            for hit in &mut response.hits[..hit_count] {
                hit.approach_status = ApproachStatus::NoMap as u8;
            }
            return;
        }
        let Some(map) = self.map.as_ref() else { return };
        if self.prepared_version != Some(map.version) {
            let robot = map.robot.unwrap_or_default();
            self.planner.prepare(&MapView { geometry: map.geometry, cells: &map.cells }, robot);
            if map.robot.is_none() {
                self.planner = Planner::new(&self.setup.config);
            }
            self.prepared_version = Some(map.version);
        }
        for hit in &mut response.hits[..hit_count] {
            let Some(node) = graph.nodes.iter().find(|n| n.id == hit.node_id) else {
                hit.approach_status = ApproachStatus::NoFreeCell as u8;
                continue;
            };
            let target = Target::of_node(graph, node, self.setup.up_axis);
            match self.planner.approach(&target) {
                Ok(approach) => {
                    hit.approach_status = ApproachStatus::Ok as u8;
                    hit.approach_x_m = approach.xy_m[0];
                    hit.approach_y_m = approach.xy_m[1];
                    hit.approach_yaw_rad = approach.yaw_rad;
                    hit.approach_standoff_m = approach.standoff_m;
                    hit.approach_path_m = approach.path_m;
                }
                Err(status) => hit.approach_status = status as u8,
            }
        }
    }
}

/// The worker thread's loop: loads the encoder (when `setup` is given), then answers jobs until
/// the receiver has ended (it drops the job sender) or the stop flag is set.
pub fn worker_loop(
    setup: Option<&EncoderSetup>,
    navigation: NavigationSetup,
    jobs: &Receiver<Request>,
    config: &QueryConfig,
    counters: &QueryCounters,
    latest: &LatestGraph,
    stop: &AtomicBool,
) {
    let capacity = config.queue_capacity;
    let options = ScoringOptions { functional: config.functional };
    let mut encoder = setup.and_then(|setup| {
        match crate::onnx::OnnxRuntime::init(&setup.onnx)
            .and_then(|runtime| TextEncoder::new(&runtime, &setup.text_encoder))
        {
            Ok(encoder) => Some(encoder),
            Err(e) => {
                warn!(error = %e, "query worker: text encoder failed to load; text queries get an error reply");
                None
            }
        }
    });
    let load_error = "the text encoder failed to load in the query worker (see the daemon log)";
    let mut navigator = Navigator::new(navigation);
    let mut index: Option<(QueryIndex, u64)> = None;
    let mut hits = Vec::with_capacity(QUERY_MAX_K);
    loop {
        let request = match jobs.recv_timeout(WORKER_POLL) {
            Ok(request) => request,
            Err(RecvTimeoutError::Timeout) => {
                if stop.load(Ordering::Relaxed) {
                    break;
                }
                continue;
            }
            Err(RecvTimeoutError::Disconnected) => break,
        };
        if stop.load(Ordering::Relaxed) {
            reply(&request, &failure(QueryStatus::ShuttingDown, "the daemon is stopping", capacity, counters));
            continue;
        }
        let payload = request.payload();
        let (response, graph) = if let Some(node_id) = payload.asked_node() {
            answer_node(node_id, latest, capacity, counters)
        } else {
            let Some(encoder) = encoder.as_mut() else {
                counters.failed.fetch_add(1, Ordering::Relaxed);
                reply(&request, &failure(QueryStatus::EncoderFailed, load_error, capacity, counters));
                continue;
            };
            answer(payload, encoder, &mut index, &mut hits, latest, options, capacity, counters)
        };
        let mut response = response;
        if let Some(graph) = graph {
            navigator.fill(&graph, &mut response);
        }
        reply(&request, &response);
    }
    // Whatever is still queued learns why it gets no hits.
    while let Ok(request) = jobs.try_recv() {
        reply(&request, &failure(QueryStatus::ShuttingDown, "the daemon is stopping", capacity, counters));
    }
}

/// The reply to a request for one node by id, and the graph it came from.
fn answer_node(
    node_id: u32,
    latest: &LatestGraph,
    capacity: usize,
    counters: &QueryCounters,
) -> (QueryResponse, Option<Arc<SceneGraph>>) {
    let fail = |status, message: &str| {
        counters.failed.fetch_add(1, Ordering::Relaxed);
        (failure(status, message, capacity, counters), None)
    };
    let Some((graph, instance_id)) = latest.get() else {
        return fail(QueryStatus::NoGraph, "no graph published yet; retry once the daemon has mapped");
    };
    let Some(node) = graph.nodes.iter().find(|n| n.id == node_id) else {
        return fail(
            QueryStatus::BadRequest,
            &format!("node_id: no node {node_id} in graph version {} ({} nodes)", graph.version, graph.nodes.len()),
        );
    };
    let hit = Hit {
        node_id: node.id,
        parent_id: node.parent_id.unwrap_or(op3dsg_ipc_types::NO_NODE),
        kind: node.kind,
        matched: op3dsg_ipc_types::QueryMatch::Label,
        score: 1.0,
        label: node.label.clone(),
        matched_text: node.label.clone(),
    };
    let served = counters.served.fetch_add(1, Ordering::Relaxed) + 1;
    let mut response = QueryResponse {
        graph_version: graph.version,
        instance_id,
        hit_count: 1,
        queue_capacity: capacity as u32,
        served_count: served,
        refused_count: counters.refused.load(Ordering::Relaxed),
        scored_node_count: 1,
        ..QueryResponse::default()
    };
    response.hits[0] = to_wire(&hit);
    (response, Some(graph))
}

#[allow(clippy::too_many_arguments)]
fn answer(
    request: &QueryRequest,
    encoder: &mut TextEncoder,
    index: &mut Option<(QueryIndex, u64)>,
    hits: &mut Vec<Hit>,
    latest: &LatestGraph,
    options: ScoringOptions,
    capacity: usize,
    counters: &QueryCounters,
) -> (QueryResponse, Option<Arc<SceneGraph>>) {
    let fail = |status, message: &str| {
        counters.failed.fetch_add(1, Ordering::Relaxed);
        (failure(status, message, capacity, counters), None)
    };
    let Some((graph, instance_id)) = latest.get() else {
        return fail(QueryStatus::NoGraph, "no graph published yet; retry once the daemon has mapped");
    };
    let current = index.as_ref().is_some_and(|(i, id)| i.graph_version() == graph.version && *id == instance_id);
    if !current {
        match QueryIndex::build(&graph, encoder, options) {
            Ok(built) => *index = Some((built, instance_id)),
            Err(e) => return fail(QueryStatus::EncoderFailed, &format!("indexing the graph: {e}")),
        }
    }
    let Some((index, instance_id)) = index.as_mut() else {
        return fail(QueryStatus::NoGraph, "no graph indexed");
    };
    let started = Instant::now();
    let query = match encoder.encode(request.text_str()) {
        Ok(query) => query,
        Err(e) => return fail(QueryStatus::EncoderFailed, &format!("encoding the query text: {e}")),
    };
    let encoded = Instant::now();
    index.top_k(&query, (request.k as usize).min(QUERY_MAX_K), hits);
    let scored = Instant::now();
    let served = counters.served.fetch_add(1, Ordering::Relaxed) + 1;
    let mut response = QueryResponse {
        graph_version: index.graph_version(),
        instance_id: *instance_id,
        hit_count: hits.len() as u32,
        queue_capacity: capacity as u32,
        served_count: served,
        refused_count: counters.refused.load(Ordering::Relaxed),
        encode_us: encoded.duration_since(started).as_micros() as u32,
        score_us: scored.duration_since(encoded).as_micros() as u32,
        scored_node_count: index.node_count() as u32,
        ..QueryResponse::default()
    };
    for (slot, hit) in response.hits.iter_mut().zip(hits.iter()) {
        *slot = to_wire(hit);
    }
    (response, Some(graph))
}

/// A hit as its wire record.
pub fn to_wire(hit: &Hit) -> QueryHit {
    let mut out = QueryHit {
        node_id: hit.node_id,
        parent_id: hit.parent_id,
        kind: hit.kind as u8,
        matched: hit.matched as u8,
        score: hit.score,
        ..QueryHit::default()
    };
    write_fixed_str(&mut out.label, &hit.label);
    write_fixed_str(&mut out.matched_text, &hit.matched_text);
    out
}
