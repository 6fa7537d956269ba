//! The worker thread `op3dsg-query`: answers queued requests one at a time with its own text
//! encoder, and gives each hit an approach pose on the newest occupancy map.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, RecvTimeoutError};
use op3dsg_ipc_types::{
    ApproachStatus, QUERY_MAX_K, QueryHit, QueryRequest, QueryResponse, QueryStatus, write_fixed_str,
};
use tracing::warn;

use super::receiver::{Job, QueryCounters, failure};
use super::{Hit, QueryConfig, QueryIndex, ScoringOptions};
use crate::flow::LatestGraph;
use crate::graph::SceneGraph;
use crate::occupancy::nav::{MapView, Planner, Target};
use crate::occupancy::{LatestOccupancy, MapCopy, NavigationConfig, copy_if_newer};
use crate::onnx::OnnxConfig;
use crate::onnx::text_encoder::{TextEncoder, TextEncoderConfig};
use crate::world::UpAxis;

/// How long the worker waits for a job before it checks the stop flag again.
const WORKER_POLL: Duration = Duration::from_millis(20);

/// What the worker needs to load its encoder; `None` when the profile has the encoder off.
#[derive(Debug, Clone)]
pub struct EncoderSetup {
    /// `[onnx]`.
    pub onnx: OnnxConfig,
    /// `[text_encoder]`.
    pub text_encoder: TextEncoderConfig,
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
        if !copy_if_newer(latest, &mut self.map) {
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

/// The worker thread `op3dsg-query`, built with the receiver by [`super::query_threads`];
/// [`QueryWorkerThread::run`] is its body.
pub struct QueryWorkerThread {
    pub(super) encoder_setup: Option<EncoderSetup>,
    pub(super) navigation: NavigationSetup,
    pub(super) jobs: Receiver<Job>,
    pub(super) config: QueryConfig,
    pub(super) counters: Arc<QueryCounters>,
    pub(super) latest: Arc<LatestGraph>,
    pub(super) stop: Arc<AtomicBool>,
}

impl std::fmt::Debug for QueryWorkerThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QueryWorkerThread").field("encoder", &self.encoder_setup.is_some()).finish_non_exhaustive()
    }
}

impl QueryWorkerThread {
    /// The counters both threads count in.
    pub fn counters(&self) -> &Arc<QueryCounters> {
        &self.counters
    }

    /// Loads the encoder (when set up), then answers jobs until the receiver has ended (it drops
    /// the job sender) or the stop flag is set.
    pub fn run(self) {
        let capacity = self.config.queue_capacity;
        let encoder = self.encoder_setup.as_ref().and_then(|setup| {
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
        let mut answers = Answers {
            encoder,
            index: None,
            hits: Vec::with_capacity(QUERY_MAX_K),
            options: ScoringOptions { functional: self.config.functional },
            capacity,
            counters: &self.counters,
            latest: &self.latest,
        };
        let mut navigator = Navigator::new(self.navigation.clone());
        loop {
            let request = match self.jobs.recv_timeout(WORKER_POLL) {
                Ok(request) => request,
                Err(RecvTimeoutError::Timeout) => {
                    // The off-robot stage may hold a sender until it ends; the publisher's end
                    // ends the service as it ends the receiver.
                    if self.stop.load(Ordering::Relaxed) || self.latest.is_closed() {
                        break;
                    }
                    continue;
                }
                Err(RecvTimeoutError::Disconnected) => break,
            };
            if self.stop.load(Ordering::Relaxed) {
                request.answer(&failure(QueryStatus::ShuttingDown, "the daemon is stopping", capacity, &self.counters));
                continue;
            }
            let (mut response, graph) = answers.answer(request.request());
            if let Some(graph) = graph {
                navigator.fill(&graph, &mut response);
            }
            request.answer(&response);
        }
        // Whatever is still queued learns why it gets no hits.
        while let Ok(request) = self.jobs.try_recv() {
            request.answer(&failure(QueryStatus::ShuttingDown, "the daemon is stopping", capacity, &self.counters));
        }
    }
}

/// The worker's state between requests: its encoder, the index of the newest graph, scratch hits.
struct Answers<'a> {
    encoder: Option<TextEncoder>,
    index: Option<(QueryIndex, u64)>,
    hits: Vec<Hit>,
    options: ScoringOptions,
    capacity: usize,
    counters: &'a QueryCounters,
    latest: &'a LatestGraph,
}

impl Answers<'_> {
    /// The reply to `request`, and the graph it came from (`None` for a failure).
    fn answer(&mut self, request: &QueryRequest) -> (QueryResponse, Option<Arc<SceneGraph>>) {
        match request.asked_node() {
            Some(node_id) => self.answer_node(node_id),
            None => self.answer_text(request),
        }
    }

    fn fail(&self, status: QueryStatus, message: &str) -> (QueryResponse, Option<Arc<SceneGraph>>) {
        self.counters.failed.fetch_add(1, Ordering::Relaxed);
        (failure(status, message, self.capacity, self.counters), None)
    }

    /// A reply's counts and capacity, with one more request served.
    fn served(&self) -> QueryResponse {
        QueryResponse {
            queue_capacity: self.capacity as u32,
            served_count: self.counters.served.fetch_add(1, Ordering::Relaxed) + 1,
            refused_count: self.counters.refused.load(Ordering::Relaxed),
            ..QueryResponse::default()
        }
    }

    /// The reply to a request for one node by id.
    fn answer_node(&self, node_id: u32) -> (QueryResponse, Option<Arc<SceneGraph>>) {
        let Some((graph, instance_id)) = self.latest.get() else {
            return self.fail(QueryStatus::NoGraph, "no graph published yet; retry once the daemon has mapped");
        };
        let Some(node) = graph.nodes.iter().find(|n| n.id == node_id) else {
            return self.fail(
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
        let mut response = QueryResponse {
            graph_version: graph.version,
            instance_id,
            hit_count: 1,
            scored_node_count: 1,
            ..self.served()
        };
        response.hits[0] = to_wire(&hit);
        (response, Some(graph))
    }

    /// The reply to a text request: the top k nodes of the newest graph.
    fn answer_text(&mut self, request: &QueryRequest) -> (QueryResponse, Option<Arc<SceneGraph>>) {
        if self.encoder.is_none() {
            let load_error = "the text encoder failed to load in the query worker (see the daemon log)";
            return self.fail(QueryStatus::EncoderFailed, load_error);
        }
        let Some((graph, instance_id)) = self.latest.get() else {
            return self.fail(QueryStatus::NoGraph, "no graph published yet; retry once the daemon has mapped");
        };
        let Some(encoder) = self.encoder.as_mut() else { return (QueryResponse::default(), None) };
        let current =
            self.index.as_ref().is_some_and(|(i, id)| i.graph_version() == graph.version && *id == instance_id);
        if !current {
            match QueryIndex::build(&graph, encoder, self.options) {
                Ok(built) => self.index = Some((built, instance_id)),
                Err(e) => return self.fail(QueryStatus::EncoderFailed, &format!("indexing the graph: {e}")),
            }
        }
        let started = Instant::now();
        let query = match encoder.encode(request.text_str()) {
            Ok(query) => query,
            Err(e) => return self.fail(QueryStatus::EncoderFailed, &format!("encoding the query text: {e}")),
        };
        let encoded = Instant::now();
        let Some((index, instance_id)) = self.index.as_mut() else {
            return self.fail(QueryStatus::NoGraph, "no graph indexed");
        };
        index.top_k(&query, (request.k as usize).min(QUERY_MAX_K), &mut self.hits);
        let scored = Instant::now();
        let (graph_version, instance_id, node_count) = (index.graph_version(), *instance_id, index.node_count());
        let mut response = QueryResponse {
            graph_version,
            instance_id,
            hit_count: self.hits.len() as u32,
            encode_us: encoded.duration_since(started).as_micros() as u32,
            score_us: scored.duration_since(encoded).as_micros() as u32,
            scored_node_count: node_count as u32,
            ..self.served()
        };
        for (slot, hit) in response.hits.iter_mut().zip(self.hits.iter()) {
            *slot = to_wire(hit);
        }
        (response, Some(graph))
    }
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
