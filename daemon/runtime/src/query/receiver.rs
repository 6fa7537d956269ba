//! The receiver thread `op3dsg-query-rx`: takes requests off `<prefix>/query`, answers what it
//! can at once (bad request, encoder off, busy) and queues the rest for the worker (the
//! picture and the rules are in the module docs of [`crate::query`]).

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use crossbeam_channel::{Sender, TrySendError};
use iceoryx2::active_request::ActiveRequest;
use iceoryx2::port::server::Server;
use op3dsg_ipc_types::services::{
    QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT, QUERY_MAX_CLIENTS, QUERY_MAX_NODES, QUERY_MAX_SERVERS, QUERY_RESPONSE_BUFFER,
    query_service_name,
};
use op3dsg_ipc_types::{QUERY_MAX_K, QUERY_SCHEMA_VERSION, QueryRequest, QueryResponse, QueryStatus};
use tracing::{info, warn};

use crate::flow::{LatestGraph, RemoteQuerySubmit, RemoteReply};
use crate::ipc::{IpcConfig, IpcError, IpcService, create_node, service_err, service_name};

/// A request taken off the service, with its reply port.
pub(super) type Request = ActiveRequest<IpcService, QueryRequest, (), QueryResponse, ()>;

/// How long the receiver sleeps when no request is waiting.
const RECEIVE_POLL: Duration = Duration::from_millis(1);

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

/// The receiver's side, created on its thread: the iceoryx2 node, service and server port.
#[derive(Debug)]
pub struct QueryReceiver {
    server: Server<IpcService, QueryRequest, (), QueryResponse, ()>,
    service: String,
    _node: iceoryx2::node::Node<IpcService>,
}

impl QueryReceiver {
    /// Creates (or reopens) `<prefix>/query` with the contract's QoS and its server port.
    pub fn open(ipc: &IpcConfig) -> Result<Self, IpcError> {
        let prefix = ipc.prefix.as_str();
        let full = query_service_name(prefix);
        let name = service_name(prefix, &full)?;
        let node = create_node(&ipc.ipc_root(), "op3dsgd-query")?;
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

/// A request for the worker: from iceoryx2, with its reply port, or from off the computer
/// (`crate::zenoh`), with where its answer goes.
pub(super) enum Job {
    /// Taken off `<prefix>/query` (iceoryx2).
    Local(Request),
    /// Handed over by the off-robot stage.
    Remote(QueryRequest, RemoteReply),
}

impl Job {
    pub(super) fn request(&self) -> &QueryRequest {
        match self {
            Self::Local(request) => request.payload(),
            Self::Remote(request, _) => request,
        }
    }

    /// Sends the one answer this request gets.
    pub(super) fn answer(self, response: &QueryResponse) {
        match self {
            Self::Local(request) => reply(&request, response),
            Self::Remote(_, reply) => reply(response),
        }
    }
}

/// Answers what can be answered at once (bad request, encoder off), else queues `job` for the
/// worker without waiting: a full queue is a busy answer, never a wait.
fn submit(job: Job, jobs: &Sender<Job>, encoder_on: bool, capacity: usize, counters: &QueryCounters) {
    if let Err(message) = check_request(job.request()) {
        counters.failed.fetch_add(1, Ordering::Relaxed);
        job.answer(&failure(QueryStatus::BadRequest, &message, capacity, counters));
        return;
    }
    if !encoder_on && job.request().asked_node().is_none() {
        counters.failed.fetch_add(1, Ordering::Relaxed);
        let message = "the daemon runs without the text encoder: set text_encoder.enabled = true \
                       (and run scripts/setup-models.sh) to serve queries";
        job.answer(&failure(QueryStatus::EncoderOff, message, capacity, counters));
        return;
    }
    match jobs.try_send(job) {
        Ok(()) => {}
        Err(TrySendError::Full(job)) => {
            let refused = counters.refused.fetch_add(1, Ordering::Relaxed) + 1;
            if refused.is_power_of_two() {
                warn!(refused, queue_capacity = capacity, "query queue full; request refused");
            }
            let message = format!("busy: {capacity} queries already wait (query.queue_capacity); retry later");
            job.answer(&failure(QueryStatus::Busy, &message, capacity, counters));
        }
        Err(TrySendError::Disconnected(job)) => {
            job.answer(&failure(QueryStatus::ShuttingDown, "the query worker has ended", capacity, counters));
        }
    }
}

fn reply(request: &Request, response: &QueryResponse) {
    if let Err(e) = request.send_copy(*response) {
        // The client gave up (dropped its pending response) or died: nothing to tell anyone.
        tracing::debug!(error = ?e, "query reply not delivered");
    }
}

pub(super) fn failure(status: QueryStatus, message: &str, capacity: usize, counters: &QueryCounters) -> QueryResponse {
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

/// The receiver thread `op3dsg-query-rx`, built with the worker by [`super::query_threads`];
/// [`QueryReceiverThread::run`] is its body. It creates `<prefix>/query` itself (the service
/// belongs to its thread) and says on `ready` whether it could.
pub struct QueryReceiverThread {
    pub(super) ipc: IpcConfig,
    pub(super) ready: Sender<Result<(), String>>,
    pub(super) jobs: Sender<Job>,
    pub(super) encoder_on: bool,
    pub(super) capacity: usize,
    pub(super) counters: Arc<QueryCounters>,
    pub(super) latest: Arc<LatestGraph>,
    pub(super) stop: Arc<AtomicBool>,
}

impl std::fmt::Debug for QueryReceiverThread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("QueryReceiverThread").field("prefix", &self.ipc.prefix).finish_non_exhaustive()
    }
}

impl QueryReceiverThread {
    /// The intake for queries from off the computer (`crate::zenoh`): the same checks and the
    /// same bounded queue to the same worker as requests over iceoryx2.
    pub fn remote_intake(&self) -> RemoteQuerySubmit {
        let (jobs, encoder_on, capacity, counters) =
            (self.jobs.clone(), self.encoder_on, self.capacity, self.counters.clone());
        Box::new(move |request, reply| {
            submit(Job::Remote(request, reply), &jobs, encoder_on, capacity, &counters);
        })
    }

    /// Creates the service, then takes requests until the stop flag or the publisher's end.
    pub fn run(self) {
        let receiver = match QueryReceiver::open(&self.ipc) {
            Ok(receiver) => {
                let _ = self.ready.send(Ok(()));
                receiver
            }
            Err(e) => {
                let _ = self.ready.send(Err(e.to_string()));
                return;
            }
        };
        self.receive(&receiver);
    }

    fn receive(&self, receiver: &QueryReceiver) {
        let (capacity, counters, jobs, encoder_on) = (self.capacity, &*self.counters, &self.jobs, self.encoder_on);
        let mut receive_errors = 0u64;
        while !self.stop.load(Ordering::Relaxed) && !self.latest.is_closed() {
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
                submit(Job::Local(request), jobs, encoder_on, capacity, counters);
            }
            if !got_any {
                std::thread::sleep(RECEIVE_POLL);
            }
        }
    }
}
