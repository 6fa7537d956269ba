//! [`GraphSubscriber`]: the planner's reader of `<prefix>/graph`, woken by `<prefix>/graph_updated`.

use std::time::{Duration, Instant};

use iceoryx2::node::Node as IoxNode;
use iceoryx2::port::listener::{Listener, ListenerWaitError};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::sample::Sample;
use iceoryx2::service::builder::event::EventOpenError;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;

use crate::client::{
    ClientError, ErrorCause, Graph, GraphView, Operation, RootUse, await_history, create_node, retry_while_not_serving,
};
use crate::publish::GraphPayload;
use crate::services::{HISTORY_SIZE, IpcService, ServiceKind, ServiceNames, service_name};
use crate::{GraphHeader, GraphMessage};

/// Reads the daemon's scene graph: waits for `graph_updated`, then reads the newest sample of
/// `graph` in one of two ways:
///
/// - [`Self::with_latest`]: in place, a [`GraphView`] of the sample lent to a closure (no copy;
///   the sample goes back when the closure returns). For a planner that reads a few nodes of
///   each new graph.
/// - [`Self::latest`] / [`Self::latest_if_newer`]: copied into an owned [`Graph`] it keeps (and
///   reuses) across calls, with lookup indices built on first use. For a planner that keeps the
///   graph between updates or asks many questions of it.
///
/// A subscriber may borrow only one sample at a time: both release each older queued sample
/// before taking the next, and return the sample to the daemon when done with it.
///
/// A daemon restart shows as a new [`Graph::instance_id`]: [`Self::latest_if_newer`] then returns
/// the new daemon's graph whatever its version, and [`Self::restarted`] says so.
///
/// Opening waits for the service's history, the daemon's newest graph (up to
/// [`ATTACH_HISTORY_WAIT`](crate::services::ATTACH_HISTORY_WAIT); the daemon hands it over
/// within 20 ms), so the first [`Self::latest`] after opening returns it. Only a daemon that has
/// published no graph yet gives none; its first one then comes with a `graph_updated` event.
#[derive(Debug)]
pub struct GraphSubscriber {
    prefix: String,
    names: ServiceNames,
    subscriber: Subscriber<IpcService, GraphPayload, GraphHeader>,
    listener: Listener<IpcService>,
    graph: Graph,
    received: bool,
    /// Instance of the graph [`Self::latest_if_newer`] last returned (0: none yet).
    returned_instance: u64,
    /// The last returned graph came from another instance than the one before it.
    restarted: bool,
    /// Instance of the last sample received, by either path (0: none yet).
    last_instance: u64,
    node: IoxNode<IpcService>,
}

impl GraphSubscriber {
    /// Opens the daemon's `graph` and `graph_updated` under `prefix` as iceoryx2 node
    /// `node_name`; fails with a "not serving" error ([`ClientError::is_not_serving`]) when no
    /// daemon has created them.
    pub fn open(prefix: &str, node_name: &str) -> Result<Self, ClientError> {
        let node = create_node(prefix, ServiceKind::Graph, node_name, RootUse::Existing)?;
        let (subscriber, listener) = open_ports(&node, prefix)?;
        Ok(Self::from_ports(prefix, node, subscriber, listener))
    }

    /// Like [`Self::open`], but while no daemon serves `prefix` retries every
    /// [`OPEN_RETRY_INTERVAL`](crate::services::OPEN_RETRY_INTERVAL), up to `timeout`: for a
    /// client started before the daemon.
    pub fn open_wait(prefix: &str, node_name: &str, timeout: Duration) -> Result<Self, ClientError> {
        let deadline = Instant::now() + timeout;
        let node =
            retry_while_not_serving(timeout, || create_node(prefix, ServiceKind::Graph, node_name, RootUse::Existing))?;
        let timeout = deadline.saturating_duration_since(Instant::now());
        let (subscriber, listener) = retry_while_not_serving(timeout, || open_ports(&node, prefix))?;
        Ok(Self::from_ports(prefix, node, subscriber, listener))
    }

    fn from_ports(
        prefix: &str,
        node: IoxNode<IpcService>,
        subscriber: Subscriber<IpcService, GraphPayload, GraphHeader>,
        listener: Listener<IpcService>,
    ) -> Self {
        await_history(|| subscriber.has_samples().unwrap_or(true));
        Self {
            prefix: prefix.to_owned(),
            names: ServiceNames::new(prefix),
            subscriber,
            listener,
            graph: Graph::new(),
            received: false,
            returned_instance: 0,
            restarted: false,
            last_instance: 0,
            node,
        }
    }

    /// The prefix served.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The service names under the prefix.
    pub fn names(&self) -> &ServiceNames {
        &self.names
    }

    /// The client's iceoryx2 node.
    pub fn node(&self) -> &IoxNode<IpcService> {
        &self.node
    }

    /// The `graph_updated` listener, to attach to a `WaitSet` with the planner's other inputs
    /// (then call [`Self::latest_if_newer`] when it fires, after draining it with `try_wait`).
    pub fn listener(&self) -> &Listener<IpcService> {
        &self.listener
    }

    /// Waits up to `timeout` for a new graph; `true` when one is waiting (a `graph_updated`
    /// event came, or a sample is already queued), `false` on timeout (at once for a zero
    /// timeout). A signal that interrupts
    /// the wait (Ctrl-C under the planner's own handler) returns `Ok(false)` early, so the caller
    /// can check its stop flag.
    pub fn wait_for_update(&self, timeout: Duration) -> Result<bool, ClientError> {
        let queued =
            self.subscriber.has_samples().map_err(|e| self.error(Operation::Receive, ErrorCause::Connection(e)))?;
        // iceoryx2's timed wait takes a zero timeout as "no limit": a zero timeout only looks.
        let wait = if queued || timeout.is_zero() {
            self.listener.try_wait(|_| {})
        } else {
            self.listener.timed_wait(|_| {}, timeout)
        };
        match wait {
            Ok(count) => Ok(queued || count > 0),
            Err(ListenerWaitError::InterruptSignal) => Ok(queued),
            Err(e) => {
                Err(ClientError::new(&self.prefix, ServiceKind::GraphUpdated, Operation::Wait, ErrorCause::Wait(e)))
            }
        }
    }

    /// Takes the newest queued sample, if any, into the owned graph; `true` when one was copied.
    /// Older queued samples are released unread.
    pub fn poll(&mut self) -> Result<bool, ClientError> {
        let Some(sample) = self.receive_newest()? else { return Ok(false) };
        let message = GraphMessage::new(sample.user_header(), sample.payload());
        self.graph.copy_from(&message).map_err(|e| self.error(Operation::Receive, ErrorCause::InvalidGraph(e)))?;
        self.last_instance = self.graph.instance_id();
        self.received = true;
        Ok(true)
    }

    /// Lends the newest graph that arrived since the last receive to `read`, in place: a
    /// [`GraphView`] of the sample in shared memory, nothing copied. The sample is held only
    /// while `read` runs and goes back to the daemon when it returns. `Ok(None)` (and `read` not
    /// called) when no sample arrived since the last [`Self::with_latest`] or [`Self::poll`].
    ///
    /// The sample is checked first, in constant time (schema version, counts within capacity,
    /// payload length, alignment; see [`GraphView::from_message`]): one that breaks the contract
    /// is an error naming what is wrong, and `read` is not called. The records are not scanned
    /// ([`GraphView::check_records`] does, as [`Self::latest`] does on every sample). Older
    /// queued samples are released unread.
    ///
    /// While `read` runs the daemon publishes on: this subscriber's buffer takes the next
    /// samples (dropping its oldest when full) and the held sample is one of the slots the
    /// daemon reserved for it, so holding a view never stalls the publisher (see
    /// [`services`](crate::services)). Keep the closure short all the same: what it holds is
    /// the graph as it was when it was published.
    ///
    /// A sample taken here is not copied into the owned graph: [`Self::graph`] and
    /// [`Self::latest`] keep the graph they held. A planner that wants to keep one calls
    /// [`GraphView::to_graph`] (or [`Graph::copy_from_view`] into a graph it reuses).
    ///
    /// ```no_run
    /// # use std::time::Duration;
    /// # let mut graphs = op3dsg_ipc_types::GraphSubscriber::open("op3dsg", "doc-view")?;
    /// graphs.wait_for_update(Duration::from_millis(500))?;
    /// let handles = graphs.with_latest(|graph| {
    ///     graph.find_by_label("cabinet handle").map(|h| (h.id(), h.centre_m())).collect::<Vec<_>>()
    /// })?;
    /// # Ok::<(), op3dsg_ipc_types::ClientError>(())
    /// ```
    pub fn with_latest<R>(&mut self, read: impl FnOnce(GraphView<'_>) -> R) -> Result<Option<R>, ClientError> {
        let Some(sample) = self.receive_newest()? else { return Ok(None) };
        let view = GraphView::from_message(GraphMessage::new(sample.user_header(), sample.payload()))
            .map_err(|e| self.error(Operation::Receive, ErrorCause::InvalidGraph(e)))?;
        let instance = view.instance_id();
        let restarted = self.last_instance != 0 && self.last_instance != instance;
        self.last_instance = instance;
        let result = read(view.with_restarted(restarted));
        drop(sample);
        Ok(Some(result))
    }

    /// Receives every queued sample and keeps the newest, releasing each older one before taking
    /// the next (one borrowed sample at most); `None` when none is queued.
    fn receive_newest(&self) -> Result<Option<GraphSample>, ClientError> {
        let mut newest = None;
        while self.subscriber.has_samples().map_err(|e| self.error(Operation::Receive, ErrorCause::Connection(e)))? {
            // Release the older sample before borrowing the next (one borrowed sample at most).
            drop(newest.take());
            newest = self.subscriber.receive().map_err(|e| self.error(Operation::Receive, ErrorCause::Receive(e)))?;
        }
        Ok(newest)
    }

    /// The newest graph received so far ([`Self::poll`] first); `None` while the daemon has
    /// published nothing this client could receive. A sample that breaks the contract (another
    /// schema version) is an error naming the expected and the found version, and leaves the
    /// previous graph in place.
    pub fn latest(&mut self) -> Result<Option<&Graph>, ClientError> {
        self.poll()?;
        Ok(self.graph())
    }

    /// Like [`Self::latest`], but `None` also when the newest graph has version
    /// `last_seen_version` and comes from the same daemon instance as the graph this call
    /// returned last (pass 0 before the first graph). Versions only grow while one daemon
    /// instance runs; a restarted daemon starts again at 1 (or after its map snapshot's version)
    /// with a new [`instance_id`](Graph::instance_id), and its graphs count as new whatever their version
    /// ([`Self::restarted`] is then `true`).
    pub fn latest_if_newer(&mut self, last_seen_version: u64) -> Result<Option<&Graph>, ClientError> {
        self.poll()?;
        let Some(instance) = self.graph().map(Graph::instance_id) else { return Ok(None) };
        let other_instance = instance != self.returned_instance;
        if !other_instance && self.graph.version() == last_seen_version {
            return Ok(None);
        }
        self.restarted = other_instance && self.returned_instance != 0;
        self.returned_instance = instance;
        Ok(self.graph())
    }

    /// `true` when the graph [`Self::latest_if_newer`] returned last came from another daemon
    /// instance than the one it returned before: the daemon restarted in between. Forget version
    /// bookkeeping and cached node ids of the old instance.
    pub fn restarted(&self) -> bool {
        self.restarted
    }

    /// The graph last copied, without receiving.
    pub fn graph(&self) -> Option<&Graph> {
        self.received.then_some(&self.graph)
    }

    fn error(&self, operation: Operation, cause: ErrorCause) -> ClientError {
        ClientError::new(&self.prefix, ServiceKind::Graph, operation, cause)
    }
}

type GraphSample = Sample<IpcService, GraphPayload, GraphHeader>;

type GraphPorts = (Subscriber<IpcService, GraphPayload, GraphHeader>, Listener<IpcService>);

fn open_ports(node: &IoxNode<IpcService>, prefix: &str) -> Result<GraphPorts, ClientError> {
    let graph_error = |operation, cause| ClientError::new(prefix, ServiceKind::Graph, operation, cause);
    let event_error = |operation, cause| ClientError::new(prefix, ServiceKind::GraphUpdated, operation, cause);

    let name = service_name(prefix, ServiceKind::Graph)
        .map_err(|e| graph_error(Operation::Open, ErrorCause::InvalidPrefix(e)))?;
    let service =
        match node.service_builder(&name).publish_subscribe::<GraphPayload>().user_header::<GraphHeader>().open() {
            Ok(service) => service,
            Err(PublishSubscribeOpenError::DoesNotExist) => {
                return Err(graph_error(Operation::Open, ErrorCause::NotServing));
            }
            Err(e) => return Err(graph_error(Operation::Open, ErrorCause::OpenPublishSubscribe(e))),
        };
    let subscriber = service
        .subscriber_builder()
        .history_request(HISTORY_SIZE)
        .create()
        .map_err(|e| graph_error(Operation::CreateSubscriber, ErrorCause::CreateSubscriber(e)))?;

    let name = service_name(prefix, ServiceKind::GraphUpdated)
        .map_err(|e| event_error(Operation::Open, ErrorCause::InvalidPrefix(e)))?;
    let event = match node.service_builder(&name).event().open() {
        Ok(event) => event,
        Err(EventOpenError::DoesNotExist) => return Err(event_error(Operation::Open, ErrorCause::NotServing)),
        Err(e) => return Err(event_error(Operation::Open, ErrorCause::OpenEvent(e))),
    };
    let listener = event
        .listener_builder()
        .create()
        .map_err(|e| event_error(Operation::CreateListener, ErrorCause::CreateListener(e)))?;
    Ok((subscriber, listener))
}
