//! [`RemoteGraphSubscriber`]: the daemon's graph from another computer, over Zenoh (cargo
//! feature `zenoh`): a client session to one endpoint, the full graph from the queryable
//! `<prefix>/graph`, then the deltas of `<prefix>/graph/delta` ([`RemoteFollower`]).

use std::time::{Duration, Instant};

use zenoh::Wait;
use zenoh::handlers::FifoChannelHandler;
use zenoh::pubsub::Subscriber;
use zenoh::sample::Sample;

use super::{Applied, Graph, RemoteFollower, SnapshotError};

/// Why the remote graph could not be had; the message names the endpoint or key.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RemoteClientError(pub String);

impl std::fmt::Display for RemoteClientError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for RemoteClientError {}

/// How long [`RemoteGraphSubscriber::connect`] waits for the daemon's current graph, so the first
/// [`RemoteGraphSubscriber::latest`] returns it. Only a daemon that has no graph yet (or does not
/// answer) makes connecting wait this long.
pub const REMOTE_ATTACH_WAIT: Duration = Duration::from_secs(3);

/// Refuses what is no Zenoh endpoint (`<protocol>/<address>`, e.g. `tcp/192.168.1.20:7447`),
/// naming it and the form, before Zenoh's configuration parser would answer in its own terms.
pub(super) fn check_endpoint(endpoint: &str) -> Result<(), RemoteClientError> {
    let protocol = endpoint.split_once('/').map(|(protocol, address)| (protocol, address.is_empty()));
    match protocol {
        Some((protocol, false))
            if !protocol.is_empty() && protocol.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-') =>
        {
            Ok(())
        }
        _ => Err(RemoteClientError(format!(
            "zenoh endpoint {endpoint:?}: not an endpoint; write <protocol>/<address>, e.g. tcp/{}",
            if endpoint.contains(':') && !endpoint.contains('/') { endpoint } else { "192.168.1.20:7447" }
        ))),
    }
}

/// A Zenoh session in client mode to `endpoint` alone, multicast scouting off.
pub(super) fn open_client_session(endpoint: &str) -> Result<zenoh::Session, RemoteClientError> {
    let fail = |what: &str, e: &dyn std::fmt::Display| {
        RemoteClientError(crate::without_source_locations(&format!("{what}: {e}")))
    };
    check_endpoint(endpoint)?;
    let mut config = zenoh::Config::default();
    let endpoints = format!("[{endpoint:?}]");
    for (key, value) in
        [("mode", "\"client\""), ("connect/endpoints", endpoints.as_str()), ("scouting/multicast/enabled", "false")]
    {
        config.insert_json5(key, value).map_err(|e| fail(&format!("zenoh endpoint {endpoint:?}"), &e))?;
    }
    zenoh::open(config).wait().map_err(|e| fail(&format!("connecting to zenoh endpoint {endpoint}"), &e))
}

/// The graph of a daemon on another computer, kept up to date from full graphs and deltas.
///
/// ```no_run
/// use std::time::Duration;
/// use op3dsg_ipc_types::client::RemoteGraphSubscriber;
/// let mut remote = RemoteGraphSubscriber::connect("tcp/192.168.1.20:7447", "op3dsg/stretch-1").unwrap();
/// let graph = remote.wait_graph(Duration::from_secs(10)).unwrap();
/// println!("version {} of instance {:x}: {} nodes", graph.version(), graph.instance_id(), graph.node_count());
/// ```
pub struct RemoteGraphSubscriber {
    session: zenoh::Session,
    key: String,
    subscribers: [Subscriber<FifoChannelHandler<Sample>>; 3],
    follower: RemoteFollower,
    health: Option<String>,
    errors: u64,
}

impl std::fmt::Debug for RemoteGraphSubscriber {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteGraphSubscriber").field("key", &self.key).finish_non_exhaustive()
    }
}

impl RemoteGraphSubscriber {
    /// Connects as a Zenoh client to `endpoint` (e.g. `tcp/192.168.1.20:7447`, the daemon's
    /// `zenoh.listen` or a router), multicast scouting off, and subscribes under `key_prefix`
    /// (the daemon's `zenoh.key_prefix`) to the graph, its deltas and the health record; then
    /// waits for the current graph (up to [`REMOTE_ATTACH_WAIT`]).
    pub fn connect(endpoint: &str, key_prefix: &str) -> Result<Self, RemoteClientError> {
        let fail = |what: &str, e: &dyn std::fmt::Display| {
            RemoteClientError(crate::without_source_locations(&format!("{what}: {e}")))
        };
        let session = open_client_session(endpoint)?;
        let key = format!("{key_prefix}/graph");
        let subscribe = |key: String| {
            session.declare_subscriber(key.clone()).wait().map_err(|e| fail(&format!("subscribing to {key}"), &e))
        };
        let subscribers =
            [subscribe(format!("{key}/delta"))?, subscribe(key.clone())?, subscribe(format!("{key_prefix}/health"))?];
        let mut remote = Self { session, key, subscribers, follower: RemoteFollower::new(), health: None, errors: 0 };
        // The first read after connecting returns the daemon's graph: ask for it now, again while
        // the route to the daemon's queryable is still being made, up to REMOTE_ATTACH_WAIT.
        let deadline = Instant::now() + REMOTE_ATTACH_WAIT;
        while remote.follower.held().is_none() && Instant::now() < deadline {
            remote.fetch_full()?;
            if remote.follower.held().is_none() {
                std::thread::sleep(Duration::from_millis(50));
            }
        }
        Ok(remote)
    }

    /// Applies what arrived since the last call (asking the queryable for a full graph when
    /// none is held) and returns the graph held, if any.
    pub fn latest(&mut self) -> Result<Option<Graph>, RemoteClientError> {
        self.poll()?;
        self.graph()
    }

    /// Applies what arrived since the last call (asking the queryable for a full graph when
    /// none is held); whether the graph held is now another version than before.
    pub fn poll(&mut self) -> Result<bool, RemoteClientError> {
        let before = self.follower.held();
        if before.is_none() {
            self.fetch_full()?;
        }
        for i in 0..self.subscribers.len() {
            while let Ok(Some(sample)) = self.subscribers[i].try_recv() {
                match self.follower.apply(&sample.payload().to_bytes()) {
                    Ok(Applied::NeedFull) => self.fetch_full()?,
                    Ok(Applied::Health(json)) => self.health = Some(json),
                    Ok(_) => {}
                    Err(_) => self.errors += 1,
                }
            }
        }
        Ok(self.follower.held() != before)
    }

    /// The graph held, if any (built from the records held; [`Self::poll`] brings it on).
    pub fn graph(&self) -> Result<Option<Graph>, RemoteClientError> {
        self.follower.graph().transpose().map_err(|e: SnapshotError| RemoteClientError(format!("{}: {e}", self.key)))
    }

    /// The newest health record received on `<prefix>/health` (JSON, the object
    /// `op3dsg health --json` prints), if one came since the subscriber connected.
    pub fn health_json(&self) -> Option<&str> {
        self.health.as_deref()
    }

    /// [`Self::latest`] until a graph is held, at most `timeout`.
    pub fn wait_graph(&mut self, timeout: Duration) -> Result<Graph, RemoteClientError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(graph) = self.latest()? {
                return Ok(graph);
            }
            if Instant::now() >= deadline {
                return Err(RemoteClientError(format!(
                    "no graph on {} within {:.1} s (is the daemon's [zenoh] on, under this key prefix?)",
                    self.key,
                    timeout.as_secs_f64()
                )));
            }
            std::thread::sleep(Duration::from_millis(50));
        }
    }

    /// Daemon instances seen so far, in order (more than one: the daemon restarted).
    pub fn instances(&self) -> &[u64] {
        self.follower.instances()
    }

    /// Messages that could not be read (another format version, a broken delta).
    pub fn errors(&self) -> u64 {
        self.errors
    }

    fn fetch_full(&mut self) -> Result<(), RemoteClientError> {
        let replies =
            self.session.get(self.key.as_str()).timeout(Duration::from_secs(5)).wait().map_err(|e| {
                RemoteClientError(crate::without_source_locations(&format!("querying {}: {e}", self.key)))
            })?;
        while let Ok(reply) = replies.recv() {
            if let Ok(sample) = reply.result()
                && self.follower.apply(&sample.payload().to_bytes()).is_err()
            {
                self.errors += 1;
            }
        }
        Ok(())
    }
}
