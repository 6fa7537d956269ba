//! [`RemoteRequester`]: one-shot requests to a daemon's Zenoh queryables from another computer
//! (cargo feature `zenoh`): a language query or a node's approach pose on `<prefix>/query` (the
//! bytes of the iceoryx2 [`QueryRequest`] and [`QueryResponse`]), the newest health record on
//! `<prefix>/health`, the newest occupancy map on `<prefix>/occupancy`.

use std::time::Duration;

use zenoh::Wait;
use zenoh::qos::CongestionControl;

use super::remote::{RemoteClientError, open_client_session};
use crate::remote::{Envelope, MessageKind};
use crate::{OccupancyHeader, QueryRequest, QueryResponse};

/// A client session to one daemon's Zenoh endpoint and key prefix, for requests.
///
/// ```no_run
/// use std::time::Duration;
/// use op3dsg_ipc_types::QueryRequest;
/// use op3dsg_ipc_types::client::RemoteRequester;
/// let remote = RemoteRequester::connect("tcp/192.168.1.20:7447", "op3dsg/stretch-1").unwrap();
/// let request = QueryRequest::new("somewhere to wash my hands", 3).unwrap();
/// let response = remote.query(&request, Duration::from_secs(5)).unwrap();
/// for hit in response.hits() {
///     println!("{} {} {:.3}", hit.node_id, hit.label_str(), hit.score);
/// }
/// ```
pub struct RemoteRequester {
    session: zenoh::Session,
    endpoint: String,
    key_prefix: String,
}

impl std::fmt::Debug for RemoteRequester {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RemoteRequester")
            .field("endpoint", &self.endpoint)
            .field("key_prefix", &self.key_prefix)
            .finish_non_exhaustive()
    }
}

impl RemoteRequester {
    /// Connects as a Zenoh client to `endpoint` (the daemon's `zenoh.listen`, or a router),
    /// multicast scouting off; `key_prefix` is the daemon's `zenoh.key_prefix`.
    pub fn connect(endpoint: &str, key_prefix: &str) -> Result<Self, RemoteClientError> {
        let session = open_client_session(endpoint)?;
        Ok(Self { session, endpoint: endpoint.to_owned(), key_prefix: key_prefix.to_owned() })
    }

    /// The key of `suffix` under the prefix.
    pub fn key(&self, suffix: &str) -> String {
        format!("{}/{suffix}", self.key_prefix)
    }

    /// Asks `<prefix>/query`; the daemon's response, whatever its status.
    pub fn query(&self, request: &QueryRequest, timeout: Duration) -> Result<QueryResponse, RemoteClientError> {
        let key = self.key("query");
        let bytes = self.first_reply(&key, Some(request.to_bytes()), timeout)?;
        let response = QueryResponse::from_bytes(&bytes).ok_or_else(|| {
            RemoteClientError(format!(
                "{key} on {}: a reply of {} bytes is no query response ({} bytes)",
                self.endpoint,
                bytes.len(),
                crate::query_types::QUERY_RESPONSE_BYTES
            ))
        })?;
        if response.schema_version != crate::QUERY_SCHEMA_VERSION {
            return Err(RemoteClientError(format!(
                "{key} on {}: the daemon speaks query schema {}, this client {}",
                self.endpoint,
                response.schema_version,
                crate::QUERY_SCHEMA_VERSION
            )));
        }
        Ok(response)
    }

    /// The newest health record from `<prefix>/health`: its envelope and its JSON (the same
    /// object `op3dsg health --json` prints).
    pub fn health(&self, timeout: Duration) -> Result<(Envelope, String), RemoteClientError> {
        let key = self.key("health");
        let bytes = self.first_reply(&key, None, timeout)?;
        let bad = |what: String| RemoteClientError(format!("{key} on {}: {what}", self.endpoint));
        let envelope = Envelope::read(&bytes).map_err(|e| bad(e.to_string()))?;
        if envelope.kind != MessageKind::Health {
            return Err(bad(format!("a message of kind {:?}, not health", envelope.kind)));
        }
        let json = std::str::from_utf8(&bytes[crate::remote::ENVELOPE_BYTES..])
            .map_err(|e| bad(format!("health JSON is not UTF-8: {e}")))?;
        Ok((envelope, json.to_owned()))
    }

    /// The newest occupancy map from `<prefix>/occupancy`: its envelope (`version` counts the
    /// maps the daemon published), header and cells (row-major, as [`OccupancyHeader`]
    /// documents them). A daemon with `occupancy.enabled = false` answers nothing: the error
    /// says no daemon answered.
    pub fn occupancy(&self, timeout: Duration) -> Result<(Envelope, OccupancyHeader, Vec<i8>), RemoteClientError> {
        let key = self.key("occupancy");
        let bytes = self.first_reply(&key, None, timeout)?;
        let (envelope, header, cells) = crate::remote::read_occupancy(&bytes)
            .map_err(|e| RemoteClientError(format!("{key} on {}: {e}", self.endpoint)))?;
        if header.schema_version != crate::OCCUPANCY_SCHEMA_VERSION {
            return Err(RemoteClientError(format!(
                "{key} on {}: the daemon sends occupancy schema {}, this client reads {}",
                self.endpoint,
                header.schema_version,
                crate::OCCUPANCY_SCHEMA_VERSION
            )));
        }
        Ok((envelope, header, cells.to_vec()))
    }

    /// The payload of the first reply to a query on `key`, asked with congestion control `drop`
    /// (so is the reply), waiting at most `timeout`.
    fn first_reply(
        &self,
        key: &str,
        payload: Option<Vec<u8>>,
        timeout: Duration,
    ) -> Result<Vec<u8>, RemoteClientError> {
        let mut get = self.session.get(key).congestion_control(CongestionControl::Drop).timeout(timeout);
        if let Some(payload) = payload {
            get = get.payload(payload);
        }
        let replies = get.wait().map_err(|e| RemoteClientError(format!("querying {key} on {}: {e}", self.endpoint)))?;
        if let Ok(reply) = replies.recv() {
            return match reply.result() {
                Ok(sample) => Ok(sample.payload().to_bytes().into_owned()),
                Err(e) => {
                    let text = e.payload().try_to_string().map(|s| s.into_owned()).unwrap_or_default();
                    Err(RemoteClientError(format!("{key} on {}: error reply: {text}", self.endpoint)))
                }
            };
        }
        Err(RemoteClientError(format!(
            "no daemon answered {key} on zenoh endpoint {} within {:.1} s (is op3dsgd running there with \
             zenoh.enabled = true, and is its zenoh.key_prefix {:?}?)",
            self.endpoint,
            timeout.as_secs_f64(),
            self.key_prefix
        )))
    }
}
