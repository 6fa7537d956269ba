//! Service names, prefix rules and QoS of the op3dsg services: the one place the daemon and its
//! clients take them from.
//!
//! | service | pattern | payload (type name) | history | buffer | borrowed | overflow | publishers | subscribers | nodes | event ids |
//! |---|---|---|---|---|---|---|---|---|---|---|
//! | `<prefix>/graph` | publish-subscribe | `[u8]` slice (`u8`), user header [`GraphHeader`] (`op3dsg::GraphHeader`) | 1 | 2 | 1 | safe | 1 | 8 | 10 | – |
//! | `<prefix>/graph_updated` | event | – | – | – | – | – | 1 | 8 | 10 | 0 |
//! | `<prefix>/health` | publish-subscribe | [`Health`] (`op3dsg::Health`) | 1 | 2 | 2 | safe | 1 | 8 | 10 | – |
//! | `<prefix>/pose` | publish-subscribe | [`PoseStamped`] (`op3dsg::PoseStamped`) | 0 | 64 | 2 | safe | 4 | 4 | 8 | – |
//!
//! The request-response service (not in the table above, whose columns are publish-subscribe's):
//!
//! | request-response service | request → response (type names) | servers | clients | active requests per client | response buffer | nodes |
//! |---|---|---|---|---|---|---|
//! | query: `<prefix>/query` | [`QueryRequest`] (`op3dsg::QueryRequest`) → [`QueryResponse`] (`op3dsg::QueryResponse`) | 1 | 16 | 4 | 4 | 18 |
//!
//! The occupancy map (publish-subscribe, but in a table of its own so the one above stays the
//! graph services' contract):
//!
//! | occupancy service | payload (type name) | history | buffer | borrowed | overflow | publishers | subscribers | nodes | rate |
//! |---|---|---|---|---|---|---|---|---|---|
//! | occupancy: `<prefix>/occupancy` | `[i8]` slice (`i8`), user header [`OccupancyHeader`] (`op3dsg::OccupancyHeader`) | 1 | 1 | 1 | safe | 1 | 8 | 10 | `occupancy.publish_period_ms` (1 s) |
//!
//! Its sample holds the whole grid (`width_cells * height_cells` bytes, fixed by the profile at
//! start: the publisher reserves that slice length once); see
//! [`occupancy_types`](crate::occupancy_types) for the cell encoding. The daemon creates it when
//! `occupancy.enabled` (default); clients open it.
//!
//! Every request gets exactly one response; a request beyond the daemon's bounded queue gets
//! [`QueryStatus::Busy`](crate::QueryStatus::Busy) at once (see [`query_types`](crate::query_types)).
//! The daemon creates `query`; clients open it.
//!
//! Columns: `history` samples a late joiner gets ([`HISTORY_SIZE`]); `buffer` samples queued per
//! subscriber before the oldest is overwritten; `borrowed` samples one subscriber may hold at
//! once; `overflow` safe = a full buffer loses its oldest sample, the publisher never blocks;
//! `publishers` / `subscribers` the most ports (for `graph_updated`: notifiers / listeners);
//! `nodes` the most iceoryx2 nodes (processes, usually) that may open the service; `event ids`
//! the ids `graph_updated` carries (it is a wake-up only: the version is in the sample).
//!
//! These are the values with the daemon's default profile; `ipc.max_subscribers` sets the
//! subscriber and listener counts (nodes = subscribers + 2: the daemon, and one spare so a second
//! daemon can still open the service and be told who serves it), `ipc.subscriber_buffer` the
//! graph buffer and `ipc.pose_buffer` the pose buffer. The pose row holds when op3dsg creates the
//! service; a pose service someone else created keeps its own QoS (below). A test
//! (`tests/tests/it/service_contract.rs`) reads this table and opens every service against a running
//! daemon with exactly these values.
//!
//! Clocks: `GraphHeader::stamp_ns` and `PoseStamped::stamp_ns` are on the clock of the frames of
//! the daemon's source (synthetic: scene time from the source's start, frame `k` at `k` times
//! the frame period; replay: the recording's own stamps; camera: the host clock, through
//! librealsense global time). `GraphHeader::publish_time_ns` and `Health::publish_time_ns` are
//! wall-clock time (`CLOCK_REALTIME`), comparable across processes of one machine.
//!
//! Who creates what: the daemon creates `graph`, `graph_updated` and `health` (subscriber and
//! listener counts from its profile, [`DEFAULT_MAX_SUBSCRIBERS`] by default); clients only open
//! them, so a client can never fix another QoS. `pose` may be created by any side, because the
//! navigation stack may well start first, possibly with its own iceoryx2 code and iceoryx2's
//! default QoS (2 publishers, 8 subscribers, buffer 2, safe overflow): whoever opens it states
//! no requirement beyond the payload type, and op3dsg's side creates it with the QoS above when it
//! does not exist ([`open_or_create_pose_service`](crate::client::open_or_create_pose_service)).
//! A creator must leave one subscriber slot for the daemon and one publisher slot per pose
//! publisher; it should keep safe overflow (the daemon warns otherwise).
//!
//! `graph` and `health` have one publisher: a second daemon on a prefix fails to create its
//! graph publisher, and `op3dsgd` reports that another daemon (with its pid) serves the prefix.
//!
//! - History 1: a client that starts after the daemon gets the current graph and health at once
//!   (delivered when the daemon's publisher next updates its connections, every 20 ms; opening
//!   waits for it, [`ATTACH_HISTORY_WAIT`]).
//! - Safe overflow: a slow client never blocks the daemon; a full buffer drops its oldest sample,
//!   and every graph sample is complete, so losing older ones loses nothing.
//! - Borrow 1: a subscriber holds at most one graph sample at a time, which bounds the shared
//!   memory the daemon maps to `max_subscribers * (buffer + 1) + history + 1` samples.
//! - Graph sample size: the publisher is created with `initial_max_slice_len` equal to the
//!   profile's maximum (`ipc.max_nodes * NODE_BYTES + ipc.max_edges * EDGE_BYTES`, 4.3 MiB by
//!   default) and iceoryx2's static allocation strategy: the data segment is reserved once at
//!   start with that many sample slots and never grows or moves, so a late joiner maps one
//!   segment and gets the history sample, and a subscriber's mapped memory is bounded by the
//!   figure above. Each publish loans only the bytes the graph fills and writes nothing else, so
//!   pages beyond a small graph are never touched. (A dynamic strategy would start small and
//!   reallocate segments as graphs grow; it saves address space, not touched memory, and makes
//!   every subscriber map new segments on growth.)
//! - One event id: a listener scans its whole id range on each wake-up; the version is in the
//!   sample, not in the event.

use std::time::Duration;

use iceoryx2::prelude::ServiceName;
use iceoryx2::service::service_name::ServiceNameError;

#[cfg(doc)]
use crate::{GraphHeader, Health, OccupancyHeader, PoseStamped, QueryRequest, QueryResponse};

/// The iceoryx2 service flavour of every port: inter-process, and `Send` so a port may be built
/// on one thread and used on another. It shares its resources with plain `ipc::Service` peers
/// (C, C++, Python).
pub type IpcService = iceoryx2::service::ipc_threadsafe::Service;

/// Prefix of the services when a profile or a client names none.
pub const DEFAULT_PREFIX: &str = "op3dsg";
/// The environment variable whose value is the prefix when none is given: `op3dsgd`, the
/// `op3dsg` CLI, the examples and the Python client read it ([`default_prefix`]).
pub const PREFIX_ENV: &str = "OP3DSG_PREFIX";

/// The prefix a client uses when its caller names none: `$OP3DSG_PREFIX` when set and not
/// empty, else [`DEFAULT_PREFIX`] (what `op3dsg` and `op3dsgd` do without `--prefix`).
pub fn default_prefix() -> String {
    std::env::var(PREFIX_ENV).ok().filter(|p| !p.is_empty()).unwrap_or_else(|| DEFAULT_PREFIX.to_owned())
}
/// Longest accepted prefix (the longest service name, `<prefix>/graph_updated`, must stay far
/// below iceoryx2's 255-byte limit).
pub const MAX_PREFIX_LEN: usize = 128;

/// History depth of `graph` and `health`: a late joiner gets the newest sample.
pub const HISTORY_SIZE: usize = 1;
/// `graph`, `health` and `pose` drop a full subscriber buffer's oldest sample instead of
/// blocking the publisher.
pub const SAFE_OVERFLOW: bool = true;
/// Subscribers (and `graph_updated` listeners) per daemon service when the profile sets none.
pub const DEFAULT_MAX_SUBSCRIBERS: usize = 8;
/// Samples buffered per `graph` subscriber before the oldest is overwritten, when the profile
/// sets none.
pub const DEFAULT_GRAPH_SUBSCRIBER_BUFFER: usize = 2;
/// Samples a `graph` subscriber may hold at once.
pub const SUBSCRIBER_MAX_BORROWED_SAMPLES: usize = 1;
/// Publishers of `graph`: the daemon.
pub const GRAPH_MAX_PUBLISHERS: usize = 1;
/// Samples the `graph` publisher loans at once (it writes one sample in place, then sends it).
pub const GRAPH_PUBLISHER_MAX_LOANED_SAMPLES: usize = 1;
/// The one event id of `graph_updated` (a wake-up; the version is in the sample).
pub const GRAPH_UPDATED_EVENT_ID: usize = 0;
/// Largest event id of `graph_updated`: the listener's scan per wake-up is this wide.
pub const EVENT_ID_MAX_VALUE: usize = GRAPH_UPDATED_EVENT_ID;
/// Publishers of `health`: the daemon.
pub const HEALTH_MAX_PUBLISHERS: usize = 1;
/// Samples buffered per `health` subscriber.
pub const HEALTH_SUBSCRIBER_BUFFER: usize = 2;
/// Samples a `health` subscriber may hold at once.
pub const HEALTH_SUBSCRIBER_MAX_BORROWED_SAMPLES: usize = 2;
/// Notifiers of `graph_updated`: the daemon.
pub const GRAPH_UPDATED_MAX_NOTIFIERS: usize = 1;
/// History of `pose` when op3dsg creates it: none (a pose is only good for frames around its
/// stamp; a late subscriber waits for the next).
pub const POSE_HISTORY_SIZE: usize = 0;
/// Samples a `pose` subscriber may hold at once when op3dsg creates it.
pub const POSE_SUBSCRIBER_MAX_BORROWED_SAMPLES: usize = 2;
/// Nodes that may open `pose` when op3dsg creates it (one per publisher and subscriber).
pub const POSE_MAX_NODES: usize = POSE_MAX_PUBLISHERS + POSE_MAX_SUBSCRIBERS;

/// Nodes that may open `graph`, `graph_updated` and `health` for a daemon serving
/// `max_subscribers` subscribers: one per subscriber, the daemon, and one spare (a second daemon
/// started on the same prefix still opens the service and learns who serves it).
pub const fn daemon_service_max_nodes(max_subscribers: usize) -> usize {
    max_subscribers + 2
}
/// Buffer of the `pose` service when an op3dsg client creates it before the daemon (the daemon's
/// default). A service someone else created keeps its own buffer.
pub const DEFAULT_POSE_BUFFER: usize = 64;
/// Publishers allowed on `pose` when op3dsg creates it (navigation stack, tools, tests); not
/// required of a service someone else created.
pub const POSE_MAX_PUBLISHERS: usize = 4;
/// Subscribers allowed on `pose` when op3dsg creates it (the daemon, a recorder); not required
/// of a service someone else created.
pub const POSE_MAX_SUBSCRIBERS: usize = 4;
/// Largest accepted deviation of a pose quaternion's norm from 1.
pub const QUATERNION_NORM_TOLERANCE: f64 = 1e-3;
/// How often a client started before the daemon retries opening its services.
pub const OPEN_RETRY_INTERVAL: Duration = Duration::from_millis(100);
/// How long opening a subscriber of `graph`, `health` or `occupancy` waits for the service's
/// history (the newest sample) to arrive. The daemon hands it over on its next connection
/// update, at most 20 ms later, so a first read after opening returns it; only a daemon that has
/// published nothing yet (it has just started) makes opening wait this long, and then gives none.
pub const ATTACH_HISTORY_WAIT: Duration = Duration::from_secs(1);
/// How often opening looks for the history sample while it waits ([`ATTACH_HISTORY_WAIT`]).
pub const ATTACH_HISTORY_POLL: Duration = Duration::from_millis(2);

/// Name of the query service after `<prefix>/`.
pub const QUERY_SUFFIX: &str = "query";
/// Servers of `query`: the daemon.
pub const QUERY_MAX_SERVERS: usize = 1;
/// Clients (planners, `op3dsg query`) that may hold a `query` port at once.
pub const QUERY_MAX_CLIENTS: usize = 16;
/// Requests one client may have in flight at once on `query`.
pub const QUERY_MAX_ACTIVE_REQUESTS_PER_CLIENT: usize = 4;
/// Responses buffered per request on `query` (one is ever sent; the rest is headroom).
pub const QUERY_RESPONSE_BUFFER: usize = 4;
/// Nodes that may open `query`: every client, the daemon and one spare.
pub const QUERY_MAX_NODES: usize = QUERY_MAX_CLIENTS + 2;

/// Name of the occupancy map service after `<prefix>/`.
pub const OCCUPANCY_SUFFIX: &str = "occupancy";
/// History of `occupancy`: a late joiner gets the newest map.
pub const OCCUPANCY_HISTORY_SIZE: usize = 1;
/// Samples buffered per `occupancy` subscriber (older maps are worthless once a newer came).
pub const OCCUPANCY_SUBSCRIBER_BUFFER: usize = 1;
/// Samples an `occupancy` subscriber may hold at once.
pub const OCCUPANCY_SUBSCRIBER_MAX_BORROWED_SAMPLES: usize = 1;
/// Publishers of `occupancy`: the daemon.
pub const OCCUPANCY_MAX_PUBLISHERS: usize = 1;
/// Subscribers of `occupancy`.
pub const OCCUPANCY_MAX_SUBSCRIBERS: usize = 8;
/// Nodes that may open `occupancy`: every subscriber, the daemon and one spare.
pub const OCCUPANCY_MAX_NODES: usize = OCCUPANCY_MAX_SUBSCRIBERS + 2;

/// The full name of the occupancy service under `prefix` (a trailing `/` of the prefix is ignored).
pub fn occupancy_service_name(prefix: &str) -> String {
    format!("{}/{OCCUPANCY_SUFFIX}", prefix.trim_end_matches('/'))
}

/// The full name of the query service under `prefix` (a trailing `/` of the prefix is ignored).
pub fn query_service_name(prefix: &str) -> String {
    format!("{}/{QUERY_SUFFIX}", prefix.trim_end_matches('/'))
}

/// One of the services under a prefix.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum ServiceKind {
    /// `<prefix>/graph`: graph publish-subscribe (bytes, [`GraphHeader`] user header).
    Graph,
    /// `<prefix>/graph_updated`: event after each new graph sample.
    GraphUpdated,
    /// `<prefix>/health`: [`Health`] publish-subscribe.
    Health,
    /// `<prefix>/pose`: [`PoseStamped`] publish-subscribe (input to the daemon).
    Pose,
    /// `<prefix>/occupancy`: the occupancy map, `[i8]` cells with an [`OccupancyHeader`] (its own
    /// table above).
    Occupancy,
}

impl ServiceKind {
    /// The services of the first table (graph, graph_updated, health, pose), in table order.
    pub const ALL: [ServiceKind; 4] = [Self::Graph, Self::GraphUpdated, Self::Health, Self::Pose];

    /// The name after `<prefix>/`.
    pub fn suffix(self) -> &'static str {
        match self {
            Self::Graph => "graph",
            Self::GraphUpdated => "graph_updated",
            Self::Health => "health",
            Self::Pose => "pose",
            Self::Occupancy => OCCUPANCY_SUFFIX,
        }
    }

    /// The full service name under `prefix` (a trailing `/` of the prefix is ignored).
    pub fn name(self, prefix: &str) -> String {
        format!("{}/{}", prefix.trim_end_matches('/'), self.suffix())
    }
}

/// The service names for a prefix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ServiceNames {
    /// `<prefix>/graph`: graph publish-subscribe (bytes, [`GraphHeader`] user header).
    pub graph: String,
    /// `<prefix>/graph_updated`: event after each new graph version.
    pub graph_updated: String,
    /// `<prefix>/health`: [`Health`] publish-subscribe.
    pub health: String,
    /// `<prefix>/pose`: [`PoseStamped`] publish-subscribe (input to the daemon).
    pub pose: String,
    /// `<prefix>/occupancy`: the occupancy map.
    pub occupancy: String,
}

impl ServiceNames {
    /// Names under `prefix` (no trailing slash).
    pub fn new(prefix: &str) -> Self {
        Self {
            graph: ServiceKind::Graph.name(prefix),
            graph_updated: ServiceKind::GraphUpdated.name(prefix),
            health: ServiceKind::Health.name(prefix),
            pose: ServiceKind::Pose.name(prefix),
            occupancy: ServiceKind::Occupancy.name(prefix),
        }
    }

    /// The name of one service.
    pub fn get(&self, kind: ServiceKind) -> &str {
        match kind {
            ServiceKind::Graph => &self.graph,
            ServiceKind::GraphUpdated => &self.graph_updated,
            ServiceKind::Health => &self.health,
            ServiceKind::Pose => &self.pose,
            ServiceKind::Occupancy => &self.occupancy,
        }
    }
}

/// Why a prefix cannot prefix the service names.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PrefixError {
    /// The prefix is empty.
    Empty,
    /// The prefix is longer than [`MAX_PREFIX_LEN`].
    TooLong {
        /// Its length, bytes.
        len: usize,
    },
    /// The prefix holds a character outside `A-Z a-z 0-9 _ - . /`.
    InvalidCharacter {
        /// The first such character.
        character: char,
    },
    /// The prefix starts or ends with `/`, or holds `//`.
    MisplacedSlash,
    /// iceoryx2 refuses the resulting service names.
    InvalidServiceName(ServiceNameError),
}

impl core::fmt::Display for PrefixError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Empty => write!(f, "must not be empty"),
            Self::TooLong { len } => write!(f, "must be at most {MAX_PREFIX_LEN} bytes, found {len}"),
            Self::InvalidCharacter { character } => {
                write!(f, "invalid character {character:?} (allowed: A-Z a-z 0-9 _ - . /)")
            }
            Self::MisplacedSlash => write!(f, "must not start or end with '/' nor contain \"//\""),
            Self::InvalidServiceName(e) => write!(f, "not a valid iceoryx2 service name fragment: {e}"),
        }
    }
}

impl std::error::Error for PrefixError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match self {
            Self::InvalidServiceName(e) => Some(e),
            _ => None,
        }
    }
}

/// Checks that `prefix` can prefix iceoryx2 service names: not empty, at most
/// [`MAX_PREFIX_LEN`] bytes, ASCII letters, digits, `_`, `-`, `.` and inner `/` only.
pub fn validate_prefix(prefix: &str) -> Result<(), PrefixError> {
    if prefix.is_empty() {
        return Err(PrefixError::Empty);
    }
    if prefix.len() > MAX_PREFIX_LEN {
        return Err(PrefixError::TooLong { len: prefix.len() });
    }
    if let Some(character) = prefix.chars().find(|c| !(c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '/')))
    {
        return Err(PrefixError::InvalidCharacter { character });
    }
    if prefix.starts_with('/') || prefix.ends_with('/') || prefix.contains("//") {
        return Err(PrefixError::MisplacedSlash);
    }
    // The longest name; the others are then valid too.
    ServiceName::new(&ServiceKind::GraphUpdated.name(prefix)).map_err(PrefixError::InvalidServiceName)?;
    Ok(())
}

/// The iceoryx2 name of one service under a prefix checked with [`validate_prefix`].
pub fn service_name(prefix: &str, kind: ServiceKind) -> Result<ServiceName, PrefixError> {
    validate_prefix(prefix)?;
    ServiceName::new(&kind.name(prefix)).map_err(PrefixError::InvalidServiceName)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_follow_the_prefix() {
        let names = ServiceNames::new("lab/robot-1/");
        assert_eq!(names.graph, "lab/robot-1/graph");
        assert_eq!(names.graph_updated, "lab/robot-1/graph_updated");
        assert_eq!(names.health, "lab/robot-1/health");
        assert_eq!(names.pose, "lab/robot-1/pose");
        for kind in ServiceKind::ALL {
            assert_eq!(names.get(kind), kind.name("lab/robot-1"));
        }
    }

    #[test]
    fn prefix_rules_name_what_is_wrong() {
        assert_eq!(validate_prefix(DEFAULT_PREFIX), Ok(()));
        assert_eq!(validate_prefix("lab/robot-1.v2_a"), Ok(()));
        assert_eq!(validate_prefix(""), Err(PrefixError::Empty));
        assert_eq!(validate_prefix("op3dsg robot"), Err(PrefixError::InvalidCharacter { character: ' ' }));
        assert_eq!(
            validate_prefix("op3dsg robot").expect_err("space").to_string(),
            "invalid character ' ' (allowed: A-Z a-z 0-9 _ - . /)"
        );
        for slashes in ["/abs", "trailing/", "a//b"] {
            assert_eq!(validate_prefix(slashes), Err(PrefixError::MisplacedSlash), "{slashes}");
        }
        let long = "p".repeat(MAX_PREFIX_LEN + 1);
        assert_eq!(validate_prefix(&long), Err(PrefixError::TooLong { len: MAX_PREFIX_LEN + 1 }));
        assert_eq!(validate_prefix(&long[..MAX_PREFIX_LEN]), Ok(()));
        assert_eq!(service_name("op3dsg", ServiceKind::Pose).map(|n| n.as_str().to_owned()), Ok("op3dsg/pose".into()));
        assert_eq!(service_name("", ServiceKind::Pose).map(|_| ()), Err(PrefixError::Empty));
    }

    #[test]
    fn qos_is_the_contract() {
        // A change here changes what every deployed client and daemon agree on.
        assert_eq!((HISTORY_SIZE, SUBSCRIBER_MAX_BORROWED_SAMPLES, GRAPH_MAX_PUBLISHERS), (1, 1, 1));
        assert_eq!((GRAPH_UPDATED_EVENT_ID, EVENT_ID_MAX_VALUE), (0, 0));
        assert_eq!((DEFAULT_POSE_BUFFER, POSE_MAX_PUBLISHERS, POSE_MAX_SUBSCRIBERS), (64, 4, 4));
        assert_eq!((DEFAULT_MAX_SUBSCRIBERS, DEFAULT_GRAPH_SUBSCRIBER_BUFFER), (8, 2));
    }
}
