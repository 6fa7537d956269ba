//! What `op3dsg watch` reads: the graph and the health record, from the daemon's iceoryx2
//! services on its computer (the client library's [`GraphSubscriber`] and [`HealthSubscriber`])
//! or from its Zenoh keys on another ([`RemoteGraphSubscriber`]). Neither way blocks: the
//! full-screen view keeps answering its keys while the daemon is not up.

use std::time::{Duration, Instant};

use anyhow::{Context, Result};
#[cfg(feature = "zenoh")]
use op3dsg_ipc_types::client::RemoteGraphSubscriber;
use op3dsg_ipc_types::{ClientError, Graph, GraphSubscriber, HealthSubscriber};
use op3dsg_runtime::ipc::HealthReport;

use super::super::{DaemonAt, node_name};

/// How often a daemon that is not up yet is looked for again.
const RETRY: Duration = Duration::from_millis(500);

/// The graph and health of one daemon, as far as they have arrived.
#[derive(Debug)]
pub(super) enum Feed<'a> {
    /// The daemon's iceoryx2 services, on this computer.
    Local {
        /// Their prefix.
        prefix: &'a str,
        /// The subscribers, once the daemon serves.
        subscribers: Option<Box<(GraphSubscriber, HealthSubscriber)>>,
        /// When the services were last looked for.
        tried: Option<Instant>,
        /// The newest health record received.
        health: Option<HealthReport>,
    },
    /// The daemon's Zenoh keys, from another computer.
    #[cfg(feature = "zenoh")]
    Remote {
        /// The endpoint connected to.
        endpoint: &'a str,
        /// The daemon's key prefix.
        key_prefix: &'a str,
        /// The subscriber following the graph and the health record.
        remote: Box<RemoteGraphSubscriber>,
        /// The graph held.
        graph: Option<Box<Graph>>,
        /// The newest health record received.
        health: Option<HealthReport>,
    },
}

/// The graph and health subscribers of `watch`; "not serving" until the daemon has created
/// `graph`, `graph_updated` and `health`.
fn open_subscribers(prefix: &str) -> Result<(GraphSubscriber, HealthSubscriber), ClientError> {
    let graphs = GraphSubscriber::open_wait(prefix, &node_name(), Duration::ZERO)?;
    let healths = HealthSubscriber::open_wait(prefix, &node_name(), Duration::ZERO)?;
    Ok((graphs, healths))
}

impl<'a> Feed<'a> {
    /// A feed from `from`: over Zenoh it connects now (a Zenoh client session; the daemon need not
    /// be up), over iceoryx2 it looks for the daemon at the first [`Self::poll`].
    pub(super) fn open(from: DaemonAt<'a>) -> Result<Self> {
        Ok(match from {
            DaemonAt::Iceoryx2 { prefix } => Self::Local { prefix, subscribers: None, tried: None, health: None },
            #[cfg(feature = "zenoh")]
            DaemonAt::Zenoh { endpoint, key_prefix } => Self::Remote {
                endpoint,
                key_prefix,
                remote: Box::new(RemoteGraphSubscriber::connect(endpoint, key_prefix)?),
                graph: None,
                health: None,
            },
        })
    }

    /// Where it reads from, in words.
    pub(super) fn describe(&self) -> String {
        match self {
            Self::Local { prefix, .. } => format!("op3dsgd under prefix {prefix}"),
            #[cfg(feature = "zenoh")]
            Self::Remote { endpoint, key_prefix, .. } => format!("{key_prefix} on zenoh endpoint {endpoint}"),
        }
    }

    /// Whether the daemon was found (over Zenoh: always, a daemon not up shows as no graph yet).
    pub(super) fn connected(&self) -> bool {
        match self {
            Self::Local { subscribers, .. } => subscribers.is_some(),
            #[cfg(feature = "zenoh")]
            Self::Remote { .. } => true,
        }
    }

    /// The graph held, if any.
    pub(super) fn graph(&self) -> Option<&Graph> {
        match self {
            Self::Local { subscribers, .. } => subscribers.as_deref().and_then(|(graphs, _)| graphs.graph()),
            #[cfg(feature = "zenoh")]
            Self::Remote { graph, .. } => graph.as_deref(),
        }
    }

    /// The newest health record, if any.
    pub(super) fn health(&self) -> Option<&HealthReport> {
        match self {
            Self::Local { health, .. } => health.as_ref(),
            #[cfg(feature = "zenoh")]
            Self::Remote { health, .. } => health.as_ref(),
        }
    }

    /// Takes what arrived without waiting (over iceoryx2, first looks for the daemon when it has
    /// not been found, at most every half second); whether the graph changed.
    pub(super) fn poll(&mut self) -> Result<bool> {
        match self {
            Self::Local { prefix, subscribers, tried, health } => {
                if subscribers.is_none() {
                    if tried.is_some_and(|t| t.elapsed() < RETRY) {
                        return Ok(false);
                    }
                    *tried = Some(Instant::now());
                    match open_subscribers(prefix) {
                        Ok(opened) => *subscribers = Some(Box::new(opened)),
                        Err(e) if e.is_not_serving() => return Ok(false),
                        Err(e) => {
                            return Err(e).with_context(|| format!("connecting to op3dsgd under prefix '{prefix}'"));
                        }
                    }
                }
                let Some((graphs, healths)) = subscribers.as_deref_mut() else { return Ok(false) };
                // Drain the update events (the samples are what is read) without waiting:
                // iceoryx2's `timed_wait` with a zero timeout waits for the next event.
                graphs.listener().try_wait(|_| {}).with_context(|| format!("reading events of {prefix}/graph"))?;
                let changed = graphs.poll().with_context(|| format!("reading service {prefix}/graph"))?;
                let record = healths.latest().with_context(|| format!("reading service {prefix}/health"))?;
                if let Some(record) = record.filter(|r| health.as_ref().is_none_or(|h| h.stamp_ns != r.stamp_ns)) {
                    *health = Some(HealthReport::from(&record));
                }
                Ok(changed)
            }
            #[cfg(feature = "zenoh")]
            Self::Remote { remote, graph, health, .. } => {
                let changed = remote.poll()?;
                if changed {
                    *graph = remote.graph()?.map(Box::new);
                }
                if let Some(report) =
                    remote.health_json().and_then(|json| serde_json::from_str::<HealthReport>(json).ok())
                    && health.as_ref() != Some(&report)
                {
                    *health = Some(report);
                }
                Ok(changed)
            }
        }
    }

    /// Waits up to `timeout` (1 ms at least) for a graph update (over Zenoh, or before the daemon
    /// is found: at most 50 ms, the remote subscriber is polled).
    pub(super) fn wait(&self, timeout: Duration) -> Result<()> {
        let timeout = timeout.max(Duration::from_millis(1));
        match self {
            Self::Local { subscribers: Some(opened), .. } => {
                let (graphs, _) = opened.as_ref();
                graphs.wait_for_update(timeout).context("waiting for graph updates")?;
            }
            _ => std::thread::sleep(timeout.min(Duration::from_millis(50))),
        }
        Ok(())
    }
}
