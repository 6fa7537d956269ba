//! The thread `op3dsg-zenoh`: on the process's Zenoh session, publishes `<prefix>/graph`,
//! `<prefix>/graph/delta`, `<prefix>/health` and `<prefix>/occupancy`, and answers the
//! queryables `<prefix>/graph` (the newest full graph), `<prefix>/health` (the newest health
//! record), `<prefix>/occupancy` (the newest map) and `<prefix>/query` (handed to the language
//! query service's worker, which replies from its own thread).

use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use ::zenoh::Wait;
use ::zenoh::pubsub::Publisher;
use ::zenoh::qos::CongestionControl;
use ::zenoh::query::{Query, Queryable};
use crossbeam_channel::Sender;
use op3dsg_ipc_types::{Health, QueryRequest, QueryResponse, QueryStatus};
use tracing::{debug, info};

use super::codec::{DeltaEncoder, encode_full, encode_health, encode_occupancy};
use super::config::ZenohConfig;
use super::counters::ZenohCounters;
use super::session::ZenohSession;
use crate::flow::RemoteQueries;
use crate::graph::SceneGraph;
use crate::ipc::{GraphCapacity, GraphEncoder, GraphOrigin, HealthReport};
use crate::occupancy::LatestOccupancy;
use crate::queue::{Latest, Popped, QueueReceiver};

/// How long the thread waits for a graph before it looks at the health slot and the full
/// graph's period again.
const TICK: Duration = Duration::from_millis(50);

/// The Zenoh thread, built by the composition; [`ZenohThread::run`] is its body. It declares
/// its publishers and queryables on the process's session and says on `ready` whether it could.
pub struct ZenohThread {
    /// `[zenoh]`.
    pub config: ZenohConfig,
    /// The process's session (opened by the composition, shared with remote detection).
    pub session: ZenohSession,
    /// The most nodes and edges a graph holds (`ipc.max_nodes`, `ipc.max_edges`: the same
    /// selection as the iceoryx2 graph).
    pub capacity: GraphCapacity,
    /// Source kind and world frame, stamped into every graph header.
    pub origin: GraphOrigin,
    /// Graph versions from the publisher (latest wins); ends when the publisher does.
    pub graphs: QueueReceiver<(Arc<SceneGraph>, u64)>,
    /// The publisher's newest health record.
    pub health: Arc<Latest<(Health, u64)>>,
    /// The occupancy thread's newest map (`occupancy.enabled`), for `<prefix>/occupancy`.
    pub occupancy: Option<Arc<LatestOccupancy>>,
    /// The language query service's intake, for `<prefix>/query` (set once it has started).
    pub queries: RemoteQueries,
    /// This stage's figures.
    pub counters: Arc<ZenohCounters>,
    /// Told once the session and its publishers exist, or why they could not be made.
    pub ready: Sender<Result<(), String>>,
}

impl std::fmt::Debug for ZenohThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ZenohThread").field("prefix", &self.config.prefix()).finish_non_exhaustive()
    }
}

/// How a queryable answers a query: the key to reply on, and the query.
type Answer = Box<dyn Fn(&str, Query) + Send + Sync>;

/// What was declared on the session.
struct Session {
    graph: Publisher<'static>,
    delta: Publisher<'static>,
    health: Publisher<'static>,
    occupancy: Option<Publisher<'static>>,
    _queryables: Vec<Queryable<()>>,
}

impl ZenohThread {
    /// Declares its keys on the session, then publishes until the publisher has ended.
    pub fn run(self) {
        let latest = Encoded::default();
        let session = match self.declare(&latest) {
            Ok(session) => {
                let _ = self.ready.send(Ok(()));
                session
            }
            Err(e) => {
                let _ = self.ready.send(Err(e));
                return;
            }
        };
        let full_period = Duration::from_secs_f64(self.config.full_period_s);
        let mut state = State::default();
        loop {
            match self.graphs.pop_timeout(TICK) {
                Popped::Item((graph, instance_id)) => {
                    self.send_graph(&session, &latest.full, &mut state, &graph, instance_id)
                }
                Popped::Empty => {}
                Popped::Finished => break,
            }
            if state.last_full.is_some_and(|at| at.elapsed() >= full_period)
                && let Some(full) = latest.full.get()
            {
                self.put_full(&session, &full);
                state.last_full = Some(Instant::now());
            }
            self.send_health(&session, &mut state);
            self.send_occupancy(&session, &latest.occupancy, &mut state);
        }
        info!(
            fulls = self.counters.fulls.load(Ordering::Relaxed),
            deltas = self.counters.deltas.load(Ordering::Relaxed),
            full_bytes = self.counters.full_bytes.load(Ordering::Relaxed),
            delta_bytes = self.counters.delta_bytes.load(Ordering::Relaxed),
            occupancy_maps = self.counters.occupancies.load(Ordering::Relaxed),
            queries = self.counters.queries.load(Ordering::Relaxed),
            language_queries = self.counters.language_queries.load(Ordering::Relaxed),
            "zenoh stage ending"
        );
        // The declarations go with `session`; the session itself is the composition's to close.
        drop(session);
    }

    fn declare(&self, latest: &Encoded) -> Result<Session, String> {
        let session = self.session.session();
        let prefix = self.config.prefix();
        let publisher = |suffix: &str| {
            session
                .declare_publisher(format!("{prefix}/{suffix}"))
                .congestion_control(CongestionControl::Drop)
                .wait()
                .map_err(|e| format!("zenoh.key_prefix: declaring {prefix}/{suffix}: {e}"))
        };
        let (graph, delta, health) = (publisher("graph")?, publisher("graph/delta")?, publisher("health")?);
        let occupancy = self.occupancy.as_ref().map(|_| publisher("occupancy")).transpose()?;
        let queryable = |suffix: &str, answer: Answer| {
            let key = format!("{prefix}/{suffix}");
            let reply_key = key.clone();
            session
                .declare_queryable(key)
                .callback(move |query| answer(&reply_key, query))
                .wait()
                .map_err(|e| format!("zenoh.key_prefix: declaring the queryable {prefix}/{suffix}: {e}"))
        };
        let (full, counters) = (latest.full.clone(), self.counters.clone());
        let graph_queryable = queryable(
            "graph",
            Box::new(move |key, query| {
                // Before the first version there is nothing to answer: the query ends empty.
                if let Some(full) = full.get()
                    && reply(&query, key, full.to_vec())
                {
                    counters.queries.fetch_add(1, Ordering::Relaxed);
                }
            }),
        )?;
        let latest_health = self.health.clone();
        let health_queryable = queryable(
            "health",
            Box::new(move |key, query| {
                if let Some((health, instance_id)) = latest_health.get() {
                    reply(&query, key, health_message(&health, instance_id));
                }
            }),
        )?;
        let (queries, counters) = (self.queries.clone(), self.counters.clone());
        let query_queryable = queryable(
            "query",
            Box::new(move |key, query| {
                answer_query(&queries, key.to_owned(), query, &counters);
            }),
        )?;
        let mut queryables = vec![graph_queryable, health_queryable, query_queryable];
        if self.occupancy.is_some() {
            let map = latest.occupancy.clone();
            queryables.push(queryable(
                "occupancy",
                Box::new(move |key, query| {
                    // Before the first map there is nothing to answer: the query ends empty.
                    if let Some(map) = map.get() {
                        reply(&query, key, map.to_vec());
                    }
                }),
            )?);
        }
        info!(prefix = %prefix, "zenoh stage serving");
        Ok(Session { graph, delta, health, occupancy, _queryables: queryables })
    }

    fn send_graph(
        &self,
        session: &Session,
        latest_full: &Latest<Arc<Vec<u8>>>,
        state: &mut State,
        graph: &SceneGraph,
        instance_id: u64,
    ) {
        let started = Instant::now();
        let encoder = match &mut state.encoder {
            Some(encoder) if encoder.instance_id() == instance_id => encoder,
            slot => {
                let mut encoder = GraphEncoder::new(self.capacity, instance_id);
                encoder.set_origin(self.origin);
                slot.insert(encoder)
            }
        };
        encoder.encode(graph);
        let now_ns = crate::world::clock::wall_clock_ns();
        encoder.set_publish_time_ns(now_ns);
        let (header, payload) = (*encoder.header(), encoder.payload());
        let mut full = Vec::with_capacity(state.full_capacity);
        encode_full(&header, payload, now_ns, &mut full);
        state.full_capacity = full.len();
        let delta = state.deltas.next(&header, payload, now_ns, &mut state.delta_buf);
        let full = Arc::new(full);
        latest_full.set(full.clone());
        let mut ok = true;
        if delta.is_some() {
            let c = &self.counters;
            ok &= self.put(&session.delta, &state.delta_buf, &c.deltas, Some((&c.last_delta_bytes, &c.delta_bytes)));
        }
        // The first version of an instance goes out whole at once; then every full period.
        if delta.is_none() || state.last_full.is_none() {
            ok &= self.put_full(session, &full);
            state.last_full = Some(Instant::now());
        }
        if ok {
            self.counters.stage.record(started);
        }
    }

    fn send_health(&self, session: &Session, state: &mut State) {
        let Some((health, instance_id)) = self.health.get() else { return };
        if health.stamp_ns == state.health_stamp_ns {
            return;
        }
        state.health_stamp_ns = health.stamp_ns;
        self.put(&session.health, &health_message(&health, instance_id), &self.counters.healths, None);
    }

    /// Sends the newest map when the occupancy thread has shared a newer one than the last sent
    /// (about every `occupancy.publish_period_ms` while the map changes), and keeps it for the
    /// queryable.
    fn send_occupancy(&self, session: &Session, encoded: &Latest<Arc<Vec<u8>>>, state: &mut State) {
        let (Some(latest), Some(publisher)) = (&self.occupancy, &session.occupancy) else { return };
        let sent = state.occupancy_version;
        let mut message = Vec::new();
        let version = latest.read(|map| {
            let map = map.filter(|map| map.version != sent)?;
            encode_occupancy(&map.header, &map.cells, map.version, crate::world::clock::wall_clock_ns(), &mut message);
            Some(map.version)
        });
        let Some(version) = version else { return };
        state.occupancy_version = version;
        let message = Arc::new(message);
        encoded.set(message.clone());
        self.put(publisher, &message, &self.counters.occupancies, None);
    }

    /// Puts a full graph message on `<prefix>/graph`.
    fn put_full(&self, session: &Session, full: &[u8]) -> bool {
        let c = &self.counters;
        self.put(&session.graph, full, &c.fulls, Some((&c.last_full_bytes, &c.full_bytes)))
    }

    /// Puts `bytes`; counts it in `count` and its size in `sizes` (the last, the total), or a
    /// stage error.
    fn put(
        &self,
        publisher: &Publisher<'_>,
        bytes: &[u8],
        count: &AtomicU64,
        sizes: Option<(&AtomicU64, &AtomicU64)>,
    ) -> bool {
        match publisher.put(bytes).wait() {
            Ok(()) => {
                count.fetch_add(1, Ordering::Relaxed);
                if let Some((last, total)) = sizes {
                    last.store(bytes.len() as u64, Ordering::Relaxed);
                    total.fetch_add(bytes.len() as u64, Ordering::Relaxed);
                }
                true
            }
            Err(e) => {
                self.counters.stage.record_error();
                debug!(error = %e, key = %publisher.key_expr(), "zenoh put failed");
                false
            }
        }
    }
}

/// The health message (envelope and the record's JSON) of `health`.
fn health_message(health: &Health, instance_id: u64) -> Vec<u8> {
    let json = serde_json::to_vec(&HealthReport::from(health)).unwrap_or_default();
    let mut message = Vec::with_capacity(json.len() + super::codec::ENVELOPE_BYTES);
    encode_health(instance_id, health.graph_version, crate::world::clock::wall_clock_ns(), &json, &mut message);
    message
}

/// Replies `bytes` to `query` on `key`; whether it went out. Zenoh replies take the querier's
/// congestion control (the op3dsg clients ask with `drop`).
fn reply(query: &Query, key: &str, bytes: Vec<u8>) -> bool {
    match query.reply(key, bytes).wait() {
        Ok(()) => true,
        Err(e) => {
            debug!(error = %e, key, "zenoh reply failed");
            false
        }
    }
}

/// A query on `<prefix>/query`: its payload is a query request's bytes (the iceoryx2 layout);
/// the query service's worker replies with the response's bytes from its own thread, so this
/// callback (on a Zenoh thread) never waits for the text encoder. A payload that is no request
/// gets a bad-request response at once.
fn answer_query(queries: &RemoteQueries, key: String, query: Query, counters: &ZenohCounters) {
    let bytes = query.payload().map(|p| p.to_bytes().into_owned()).unwrap_or_default();
    let Some(request) = QueryRequest::from_bytes(&bytes) else {
        let message = format!(
            "payload: {} bytes, a query request is {} (op3dsg_ipc_types::QueryRequest, docs/remote.md)",
            bytes.len(),
            op3dsg_ipc_types::query_types::QUERY_REQUEST_BYTES
        );
        reply(&query, &key, QueryResponse::failure(QueryStatus::BadRequest, &message).to_bytes());
        return;
    };
    let Some(submit) = queries.get() else {
        let message = "the daemon runs with query.enabled = false: no language queries";
        reply(&query, &key, QueryResponse::failure(QueryStatus::BadRequest, message).to_bytes());
        return;
    };
    counters.language_queries.fetch_add(1, Ordering::Relaxed);
    submit(
        request,
        Box::new(move |response: &QueryResponse| {
            reply(&query, &key, response.to_bytes());
        }),
    );
}

/// What the thread keeps between versions.
#[derive(Default)]
struct State {
    encoder: Option<GraphEncoder>,
    deltas: DeltaEncoder,
    delta_buf: Vec<u8>,
    full_capacity: usize,
    last_full: Option<Instant>,
    health_stamp_ns: u64,
    occupancy_version: u64,
}

/// The newest messages the queryables answer with (shared with their callbacks).
#[derive(Default)]
struct Encoded {
    full: Arc<Latest<Arc<Vec<u8>>>>,
    occupancy: Arc<Latest<Arc<Vec<u8>>>>,
}
