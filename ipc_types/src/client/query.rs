//! [`QueryClient`]: asks the daemon's `<prefix>/query` service for the nodes that match a need
//! in words.
//!
//! ```no_run
//! use std::time::Duration;
//! use op3dsg_ipc_types::{QueryClient, QueryStatus};
//! let client = QueryClient::open_wait("op3dsg", "planner-query", Duration::from_secs(5))?;
//! let response = client.query("somewhere to wash my hands", 3, Duration::from_secs(2))?;
//! if response.query_status() == Some(QueryStatus::Ok) {
//!     for hit in response.hits() {
//!         println!("{} {} {:.3} ({})", hit.node_id, hit.label_str(), hit.score, hit.matched_text_str());
//!     }
//! }
//! # Ok::<(), op3dsg_ipc_types::QueryClientError>(())
//! ```

use std::time::{Duration, Instant};

use iceoryx2::node::Node as IoxNode;
use iceoryx2::port::client::Client;
use iceoryx2::prelude::{NodeBuilder, NodeName, ServiceName, SignalHandlingMode};
use iceoryx2::service::builder::request_response::RequestResponseOpenError;

use crate::access::IpcRoot;
use crate::client::{ErrorCause, RootUse, client_config};
use crate::query_types::{QUERY_SCHEMA_VERSION, QUERY_TEXT_CAPACITY_BYTES, QueryRequest, QueryResponse};
use crate::services::{
    IpcService, OPEN_RETRY_INTERVAL, PrefixError, QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT, query_service_name,
    validate_prefix,
};

/// How often [`QueryClient::query`] looks for the response while it waits.
const RESPONSE_POLL: Duration = Duration::from_micros(200);

/// Why a query could not be asked or answered. Each names the service it concerns.
#[derive(Debug)]
pub enum QueryClientError {
    /// The prefix cannot prefix service names.
    InvalidPrefix {
        /// The prefix.
        prefix: String,
        /// Why.
        reason: PrefixError,
    },
    /// The iceoryx2 node could not be created.
    Node {
        /// Service name.
        service: String,
        /// iceoryx2's error.
        reason: String,
    },
    /// No daemon serves the query service under this prefix (not running, another prefix, or a
    /// daemon without the query service).
    NotServing {
        /// Service name.
        service: String,
    },
    /// The service exists but could not be opened (other types, too many clients, ...).
    Open {
        /// Service name.
        service: String,
        /// iceoryx2's error.
        reason: String,
    },
    /// The IPC root belongs to another user, or is no valid root.
    NoAccess {
        /// Service name.
        service: String,
        /// Why, and the fix.
        reason: String,
    },
    /// The text does not fit a request.
    TextTooLong {
        /// Its length, bytes.
        len: usize,
    },
    /// The request could not be sent.
    Send {
        /// Service name.
        service: String,
        /// iceoryx2's error.
        reason: String,
    },
    /// The response could not be received.
    Receive {
        /// Service name.
        service: String,
        /// iceoryx2's error.
        reason: String,
    },
    /// No response within the timeout.
    Timeout {
        /// Service name.
        service: String,
        /// How long it waited, milliseconds.
        waited_ms: u64,
    },
    /// The daemon answers with another query schema.
    SchemaVersion {
        /// Service name.
        service: String,
        /// The daemon's.
        found: u32,
        /// This client's.
        expected: u32,
    },
}

impl core::fmt::Display for QueryClientError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::InvalidPrefix { prefix, reason } => write!(f, "prefix {prefix:?}: {reason}"),
            Self::Node { service, reason } => write!(f, "{service}: creating the iceoryx2 node failed: {reason}"),
            Self::NotServing { service } => {
                let root = IpcRoot::resolve();
                write!(
                    f,
                    "{service}: no op3dsgd daemon serves it in IPC root {} (is op3dsgd running with this prefix?)",
                    root.path().display()
                )?;
                match root.foreign_service_note() {
                    Some(note) => write!(f, "; {note}"),
                    None => Ok(()),
                }
            }
            Self::NoAccess { service, reason } => write!(f, "{service}: {reason}"),
            Self::Open { service, reason } => write!(f, "{service}: open failed: {reason}"),
            Self::TextTooLong { len } => {
                write!(f, "query text is {len} bytes; at most {QUERY_TEXT_CAPACITY_BYTES} fit a request")
            }
            Self::Send { service, reason } => write!(f, "{service}: sending the request failed: {reason}"),
            Self::Receive { service, reason } => write!(f, "{service}: receiving the response failed: {reason}"),
            Self::Timeout { service, waited_ms } => {
                write!(f, "{service}: no response within {waited_ms} ms (daemon stopped or stuck?)")
            }
            Self::SchemaVersion { service, found, expected } => {
                write!(f, "{service}: response has query schema {found}, this client speaks {expected}")
            }
        }
    }
}

impl std::error::Error for QueryClientError {}

impl QueryClientError {
    /// No daemon serves the service (yet).
    pub fn is_not_serving(&self) -> bool {
        matches!(self, Self::NotServing { .. })
    }
}

/// A client of `<prefix>/query`.
#[derive(Debug)]
pub struct QueryClient {
    service: String,
    client: Client<IpcService, QueryRequest, (), QueryResponse, ()>,
    node: IoxNode<IpcService>,
}

impl QueryClient {
    /// Opens `<prefix>/query` as iceoryx2 node `node_name`; [`QueryClientError::NotServing`] when
    /// no daemon has created it.
    pub fn open(prefix: &str, node_name: &str) -> Result<Self, QueryClientError> {
        let (node, service) = create_node(prefix, node_name)?;
        let client = open_client(&node, &service)?;
        Ok(Self { service, client, node })
    }

    /// Like [`Self::open`], but while no daemon serves `prefix` retries every
    /// [`OPEN_RETRY_INTERVAL`], up to `timeout`.
    pub fn open_wait(prefix: &str, node_name: &str, timeout: Duration) -> Result<Self, QueryClientError> {
        let deadline = Instant::now() + timeout;
        let (node, service) = loop {
            match create_node(prefix, node_name) {
                Err(e) if e.is_not_serving() && Instant::now() < deadline => {
                    std::thread::sleep(OPEN_RETRY_INTERVAL.min(deadline.saturating_duration_since(Instant::now())));
                }
                created => break created?,
            }
        };
        loop {
            match open_client(&node, &service) {
                Err(e) if e.is_not_serving() && Instant::now() < deadline => {
                    std::thread::sleep(OPEN_RETRY_INTERVAL.min(deadline.saturating_duration_since(Instant::now())));
                }
                Err(e) => return Err(e),
                Ok(client) => return Ok(Self { service, client, node }),
            }
        }
    }

    /// The service name.
    pub fn service_name(&self) -> &str {
        &self.service
    }

    /// The client's iceoryx2 node.
    pub fn node(&self) -> &IoxNode<IpcService> {
        &self.node
    }

    /// Sends `text` asking for `k` nodes and waits up to `timeout` for the one response. Every
    /// answer the daemon gives is `Ok` here, a refusal ([`QueryStatus::Busy`](crate::QueryStatus::Busy))
    /// or an error status included: look at [`QueryResponse::query_status`].
    pub fn query(&self, text: &str, k: u32, timeout: Duration) -> Result<QueryResponse, QueryClientError> {
        let request = QueryRequest::new(text, k).ok_or(QueryClientError::TextTooLong { len: text.len() })?;
        self.send(request, timeout)
    }

    /// Asks for node `node_id` alone: the reply holds it with its approach pose
    /// ([`QueryHit::approach`](crate::QueryHit::approach)), or
    /// [`QueryStatus::BadRequest`](crate::QueryStatus::BadRequest) naming `node_id` when the current
    /// graph has no such node. Needs no text encoder.
    pub fn query_node(&self, node_id: u32, timeout: Duration) -> Result<QueryResponse, QueryClientError> {
        self.send(QueryRequest::for_node(node_id), timeout)
    }

    /// Sends `request` as it is (a text or a node) and waits up to `timeout` for its response.
    pub fn request(&self, request: &QueryRequest, timeout: Duration) -> Result<QueryResponse, QueryClientError> {
        self.send(*request, timeout)
    }

    fn send(&self, request: QueryRequest, timeout: Duration) -> Result<QueryResponse, QueryClientError> {
        let service = || self.service.clone();
        let pending = self
            .client
            .send_copy(request)
            .map_err(|e| QueryClientError::Send { service: service(), reason: e.to_string() })?;
        let started = Instant::now();
        loop {
            if let Some(response) = pending
                .receive()
                .map_err(|e| QueryClientError::Receive { service: service(), reason: e.to_string() })?
            {
                let response = *response.payload();
                if response.schema_version != QUERY_SCHEMA_VERSION {
                    return Err(QueryClientError::SchemaVersion {
                        service: service(),
                        found: response.schema_version,
                        expected: QUERY_SCHEMA_VERSION,
                    });
                }
                return Ok(response);
            }
            if started.elapsed() >= timeout {
                return Err(QueryClientError::Timeout { service: service(), waited_ms: timeout.as_millis() as u64 });
            }
            std::thread::sleep(RESPONSE_POLL);
        }
    }
}

fn create_node(prefix: &str, node_name: &str) -> Result<(IoxNode<IpcService>, String), QueryClientError> {
    validate_prefix(prefix).map_err(|reason| QueryClientError::InvalidPrefix { prefix: prefix.to_owned(), reason })?;
    let service = query_service_name(prefix);
    let fail = |reason: String| QueryClientError::Node { service: service.clone(), reason };
    let name = NodeName::new(node_name).map_err(|e| fail(format!("node name {node_name:?}: {e}")))?;
    let config = match client_config(RootUse::Existing) {
        Ok(config) => config,
        Err(ErrorCause::NotServing) => return Err(QueryClientError::NotServing { service }),
        Err(cause) => return Err(QueryClientError::NoAccess { service, reason: cause.to_string() }),
    };
    let node = NodeBuilder::new()
        .name(&name)
        .config(&config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<IpcService>()
        .map_err(|e| fail(e.to_string()))?;
    let _ = node.try_cleanup_dead_nodes();
    Ok((node, service))
}

fn open_client(
    node: &IoxNode<IpcService>,
    service: &str,
) -> Result<Client<IpcService, QueryRequest, (), QueryResponse, ()>, QueryClientError> {
    let fail = |reason: String| QueryClientError::Open { service: service.to_owned(), reason };
    let name = ServiceName::new(service).map_err(|e| fail(e.to_string()))?;
    let factory = node
        .service_builder(&name)
        .request_response::<QueryRequest, QueryResponse>()
        .max_active_requests_per_client(QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT)
        .open()
        .map_err(|e| match e {
            RequestResponseOpenError::DoesNotExist => QueryClientError::NotServing { service: service.to_owned() },
            e => fail(format!("{e:?}")),
        })?;
    factory.client_builder().create().map_err(|e| fail(format!("creating the client port: {e:?}")))
}
