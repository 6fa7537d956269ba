//! # The iceoryx2 service layer: config, errors and node helpers; codec, server, health report below
//!
//! `op3dsgd` serves its scene graph to planners over iceoryx2 0.10 shared memory. All services
//! live under a configurable prefix (default `op3dsg`, see [`IpcConfig::prefix`]); the payload
//! types and their layouts are the wire contract in [`op3dsg_ipc_types`], and the service names,
//! QoS figures, event id, prefix rules, pose checks and the `pose` open-or-create rule are taken
//! from [`op3dsg_ipc_types::services`] and its client, which planners use too.
//!
//! | module | what |
//! |---|---|
//! | this one | [`IpcConfig`], [`IpcError`], the iceoryx2 node helpers |
//! | [`codec`] | [`SceneGraph`](crate::graph::SceneGraph) ⇄ graph sample ([`GraphHeader`](op3dsg_ipc_types::GraphHeader) + node and edge records): [`GraphEncoder`], [`message_to_scene_graph`], [`graph_to_scene_graph`] |
//! | [`server`] | [`GraphServer`]: graph, `graph_updated`, health, pose input |
//! | [`health_report`] | [`HealthReport`]: the serialisable form of a health record (`op3dsg health --json`) |
//! | [`card`] | [`card::DaemonCard`]: which process serves a prefix and where its snapshots are, a file in the root |
//!
//! ## Services and QoS
//!
//! | service                  | pattern           | payload                            | QoS (fixed by the creator)                     |
//! |--------------------------|-------------------|------------------------------------|------------------------------------------------|
//! | `<prefix>/graph`         | publish-subscribe | `[u8]` slice, `GraphHeader` header | history 1, safe overflow, buffer 2, borrow 1   |
//! | `<prefix>/graph_updated` | event             | event id 0                         | max event id 0                                 |
//! | `<prefix>/health`        | publish-subscribe | `Health`                           | history 1, safe overflow, 1 publisher          |
//! | `<prefix>/pose`          | publish-subscribe | `PoseStamped`                      | if op3dsg creates it: safe overflow, buffer 64, 4 publishers, 4 subscribers; any creator's QoS is accepted (input to the daemon) |
//! | `<prefix>/query`         | request-response  | `QueryRequest` → `QueryResponse`   | 1 server, 16 clients, 4 requests in flight per client; served by `crate::query::service` on its own threads |
//!
//! A graph sample is a [`GraphHeader`](op3dsg_ipc_types::GraphHeader) (counts, version, the
//! daemon's `instance_id`, stamps, capacity flag) and exactly `node_count * 144 + edge_count * 64`
//! bytes of node and edge records: it costs what the graph holds. The header's `instance_id` is
//! drawn at every start ([`new_instance_id`]), so a planner tells a restarted daemon (versions
//! from 1 again) from an old sample.
//!
//! ## Why this QoS
//! - **History 1**: a planner that starts (or restarts) after the daemon receives the current
//!   graph and health at once instead of waiting for the next change; the graph may not change for
//!   a long time in a static room. iceoryx2 delivers the history from the *publisher* side when it
//!   next updates its connections, so the daemon's publisher thread calls
//!   [`GraphServer::update_connections`] whenever it wakes (at least every ~100 ms).
//! - **Safe overflow**: a slow or stuck planner must never block or slow the daemon. With safe
//!   overflow a full subscriber buffer drops its *oldest* sample, so a reader always finds the
//!   newest versions; each sample is a complete, self-consistent graph, so losing older ones loses
//!   nothing. The daemon never uses a blocking backpressure strategy.
//! - **Sized samples, static segment**: the publisher reserves one data segment at start whose
//!   samples hold the largest graph the profile allows (`ipc.max_nodes`, `ipc.max_edges`;
//!   `initial_max_slice_len` with iceoryx2's static allocation strategy), and each publish loans
//!   and writes only the bytes of the current graph ([`GraphEncoder`] chooses the records, the
//!   sample is loaned uninitialised with `loan_slice_uninit`, and the records are written into it
//!   in place, every byte of it, before the one `assume_init`). The segment never grows, so late joiners get the history
//!   sample from the one segment they mapped and the memory bound below stays fixed; pages a
//!   small graph never writes are never touched.
//! - **Event**: the graph changes irregularly (per keyframe fusion, not per frame). Instead of
//!   polling the graph service, a planner waits on a listener of `<prefix>/graph_updated`
//!   (or attaches it to a `WaitSet` with its other inputs) and reads the graph when woken; the
//!   version is in the sample's header. The event carries no data (one id, 0): a listener
//!   scans its whole id range on every wake-up, and a range of 2^16 ids (the version's low bits,
//!   as an earlier contract had it) cost about 0.3 ms per delivery (`op3dsg bench perf`).
//! - A subscriber borrows at most one sample at a time (the service is created with
//!   `subscriber_max_borrowed_samples = 1`), which keeps the shared memory the daemon reserves to
//!   `max_subscribers * (buffer + 1) + history + 1` samples of the maximum size (26 samples,
//!   about 110 MiB of address space, with the defaults; only written pages are resident).
//!
//! Who creates what: the daemon creates `graph`, `graph_updated` and `health` (or opens them if a
//! previous instance's survivors still hold them, stating its QoS as minimums); clients only open
//! them, so a client cannot fix a different QoS, and a client started before the daemon waits
//! ([`op3dsg_ipc_types::GraphSubscriber::open_wait`]). `pose` may be created by either side,
//! because the navigation stack may well start first: the daemon opens an existing one with no
//! requirement beyond the payload type (iceoryx2's default QoS is fine; it logs the QoS found and
//! warns about a smaller buffer or no safe overflow), and creates it with the contract's QoS
//! otherwise ([`op3dsg_ipc_types::client::open_or_create_pose_service`]).
//!
//! One prefix, one daemon: `graph` and `health` allow one publisher, and a second daemon on a
//! served prefix fails with [`IpcError::PrefixInUse`], naming the prefix and the serving
//! daemon's pid (from iceoryx2's publisher list of `graph`); `op3dsgd` exits with code 1.
//!
//! ## Subscribing from Python
//! A sketch (the header and record layouts are documented field by field in
//! [`op3dsg_ipc_types`]):
//! ```python
//! import ctypes, iceoryx2 as iox2          # pip install iceoryx2==0.10.0
//! import numpy as np
//! class GraphHeader(ctypes.Structure):     # mirror field by field, 112 bytes
//!     _fields_ = [("schema_version", ctypes.c_uint32), ("node_count", ctypes.c_uint32),
//!                 ("graph_version", ctypes.c_uint64), ("instance_id", ctypes.c_uint64), ...]
//!     @staticmethod
//!     def type_name() -> str: return "op3dsg::GraphHeader"
//! config = iox2.config.default()             # the daemon's root and iceoryx2 prefix
//! config.global_cfg.root_path = iox2.Path.new("/tmp/op3dsg-1000")   # see op3dsg_ipc_types::access
//! config.global_cfg.prefix = iox2.FileName.new("op3dsg_")
//! node = iox2.NodeBuilder.new().config(config).create(iox2.ServiceType.Ipc)
//! service = (node.service_builder(iox2.ServiceName.new("op3dsg/graph"))
//!            .publish_subscribe(iox2.Slice[ctypes.c_uint8]).user_header(GraphHeader).open())
//! subscriber = service.subscriber_builder().create()
//! sample = subscriber.receive()            # None until the daemon has published
//! if sample is not None:
//!     header = sample.user_header().contents   # check header.schema_version == 12 first
//!     # node_count records of 144 bytes, then edge_count records of 64 bytes (numpy dtypes
//!     # mirroring Node and Edge view them without copying)
//! ```
//! The `type_name()` strings must match exactly (`op3dsg::GraphHeader`, `op3dsg::Health`,
//! `op3dsg::PoseStamped`), or opening fails with incompatible types. A header whose
//! `instance_id` differs from the last one seen comes from a restarted daemon: forget the
//! versions seen.
//!
//! ## Who can attach
//! iceoryx2 0.10 gives everything it creates owner-only modes, fixed in its code, so only
//! processes of the daemon's own user can read the graph, send poses or ask queries; the
//! daemon and its clients meet in a root folder of that user ([`op3dsg_ipc_types::access`]:
//! `ipc.root`, `$OP3DSG_IPC_ROOT`, `/run/op3dsg` of the service, `/tmp/op3dsg-<uid>`), and
//! a root of another user is refused at start with the owner's name.
//!
//! ## Stale resources
//! A daemon killed with `SIGKILL` leaves its node and ports behind in shared memory; the node is
//! then `Dead`. [`GraphServer::open`] (and, harmlessly, every client) first removes the stale
//! resources of all dead nodes (`Node::try_cleanup_dead_nodes`), so a restarted daemon can create
//! its services again and clients do not wait on a publisher that no longer exists
//! ([`IpcConfig::cleanup_dead_nodes_at_start`]).
//!
//! iceoryx2 nodes are created with signal handling disabled: the daemon and the CLI install
//! their own Ctrl-C handlers.

pub mod card;
pub mod codec;
pub mod health_report;
pub mod server;

use iceoryx2::prelude::{Node, NodeBuilder, NodeName, ServiceName, SignalHandlingMode};
pub use op3dsg_ipc_types::SnapshotError;
use op3dsg_ipc_types::access::{IpcRoot, RootError, RootSource};
/// The iceoryx2 service flavour of every port here (see [`op3dsg_ipc_types::services::IpcService`]):
/// inter-process, and `Send` so the daemon may build its [`GraphServer`] on one thread and hand
/// it to the publisher thread.
pub use op3dsg_ipc_types::services::IpcService;
use op3dsg_ipc_types::services::{
    DEFAULT_GRAPH_SUBSCRIBER_BUFFER, DEFAULT_MAX_SUBSCRIBERS, DEFAULT_POSE_BUFFER, DEFAULT_PREFIX, validate_prefix,
};
use op3dsg_ipc_types::{GraphHeader, Health, MAX_EDGES, MAX_NODES, NAME_CAPACITY_BYTES, SourceKind};
use serde::{Deserialize, Serialize};

pub use codec::{GraphCapacity, GraphEncoder, PublishReport, graph_to_scene_graph, message_to_scene_graph};
pub use health_report::{
    HealthReport, ModelReport, QueueReport, RefinerReport, RemoteReport, RemoteWorkerReport, StageReport, pose_counters,
};
pub use server::{GraphServer, PoseCheckCounts};

/// Settings of the iceoryx2 services (the `[ipc]` table of a profile).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct IpcConfig {
    /// Service name prefix: services are `<prefix>/graph`, `<prefix>/health`, ...
    pub prefix: String,
    /// Most subscribers per published service (each costs shared memory, see the module docs).
    pub max_subscribers: usize,
    /// Samples buffered per subscriber of `graph` before the oldest is overwritten.
    pub subscriber_buffer: usize,
    /// Poses buffered for the daemon on `pose` between two polls.
    pub pose_buffer: usize,
    /// Most nodes one graph sample holds; a larger map publishes its most recently seen nodes
    /// and sets the header's `capacity_exceeded`.
    pub max_nodes: usize,
    /// Most edges one graph sample holds (see `max_nodes`).
    pub max_edges: usize,
    /// Remove the shared-memory leftovers of dead processes when the daemon starts.
    pub cleanup_dead_nodes_at_start: bool,
    /// The iceoryx2 root folder (absolute). Empty: `$OP3DSG_IPC_ROOT`, else `/run/op3dsg` when
    /// it belongs to the daemon's user (the systemd unit's), else `/tmp/op3dsg-<uid>` — the
    /// rule every client follows too ([`op3dsg_ipc_types::access`]). A root of another user is
    /// refused at start.
    pub root: String,
}

impl Default for IpcConfig {
    fn default() -> Self {
        Self {
            prefix: DEFAULT_PREFIX.to_owned(),
            max_subscribers: DEFAULT_MAX_SUBSCRIBERS,
            subscriber_buffer: DEFAULT_GRAPH_SUBSCRIBER_BUFFER,
            pose_buffer: DEFAULT_POSE_BUFFER,
            max_nodes: MAX_NODES,
            max_edges: MAX_EDGES,
            cleanup_dead_nodes_at_start: true,
            root: String::new(),
        }
    }
}

impl IpcConfig {
    /// Checks every field; the message names the field as `<path>.<field>`. The prefix rules are
    /// [`op3dsg_ipc_types::validate_prefix`]'s.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        validate_prefix(&self.prefix).map_err(|e| format!("{path}.prefix: {e}"))?;
        if !self.root.is_empty() {
            self.ipc_root().config().map_err(|e| format!("{path}.root: {e}"))?;
        }
        let ranges = [
            ("max_subscribers", self.max_subscribers, 64),
            ("subscriber_buffer", self.subscriber_buffer, 16),
            ("pose_buffer", self.pose_buffer, 4096),
            ("max_nodes", self.max_nodes, MAX_CONFIGURABLE_NODES),
            ("max_edges", self.max_edges, MAX_CONFIGURABLE_EDGES),
        ];
        for (field, value, max) in ranges {
            if !(1..=max).contains(&value) {
                return Err(format!("{path}.{field}: must be between 1 and {max}, found {value}"));
            }
        }
        Ok(())
    }
}

/// Largest accepted `ipc.max_nodes` (1 Mi nodes: a 144 MiB sample).
pub const MAX_CONFIGURABLE_NODES: usize = 1 << 20;
/// Largest accepted `ipc.max_edges` (4 Mi edges: a 256 MiB sample).
pub const MAX_CONFIGURABLE_EDGES: usize = 1 << 22;

impl IpcConfig {
    /// The iceoryx2 root: `root` when set, else the clients' rule ([`IpcRoot::resolve`]).
    pub fn ipc_root(&self) -> IpcRoot {
        if self.root.is_empty() { IpcRoot::resolve() } else { IpcRoot::at(&self.root, RootSource::Profile) }
    }

    /// The graph sample capacity of this configuration.
    pub fn graph_capacity(&self) -> GraphCapacity {
        GraphCapacity { max_nodes: self.max_nodes, max_edges: self.max_edges }
    }
}

/// What every graph header and health record says about the daemon's input: the kind of source
/// it opened ([`SourceKind`]: live camera, replay, synthetic) and the name of the world frame the
/// coordinates are in (`world.frame_id`). Fixed for the daemon's run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct GraphOrigin {
    /// The wire kind of the opened source.
    pub source_kind: SourceKind,
    /// The world frame's name, NUL padded as on the wire.
    pub world_frame: [u8; NAME_CAPACITY_BYTES],
}

impl GraphOrigin {
    /// The origin of a source of `kind` (what the opened source says of itself) with its
    /// coordinates in `world_frame` (the profile's checked `world.frame_id`, which fits; a longer
    /// one would be cut at a character boundary).
    pub fn new(kind: op3dsg_drivers::source::SourceKind, world_frame: &str) -> Self {
        use op3dsg_drivers::source::SourceKind as Opened;
        let source_kind = match kind {
            Opened::LiveCamera => SourceKind::LiveCamera,
            Opened::Replay => SourceKind::Replay,
            Opened::Synthetic => SourceKind::Synthetic,
            Opened::Other => SourceKind::Unknown,
        };
        let mut frame = [0u8; NAME_CAPACITY_BYTES];
        let _ = op3dsg_ipc_types::write_fixed_str(&mut frame, world_frame);
        Self { source_kind, world_frame: frame }
    }

    /// Writes the source kind and the world frame into a graph header.
    pub fn stamp_header(&self, header: &mut GraphHeader) {
        header.source_kind = self.source_kind as u8;
        header.world_frame = self.world_frame;
    }

    /// Writes the source kind and the world frame into a health record.
    pub fn stamp_health(&self, health: &mut Health) {
        health.source_kind = self.source_kind as u8;
        health.world_frame = self.world_frame;
    }
}

/// Failures of the service layer; each names the service (or prefix, or node) and the operation.
#[derive(Debug, thiserror::Error)]
pub enum IpcError {
    /// The prefix cannot form service names.
    #[error("invalid service prefix '{prefix}': {reason}")]
    InvalidPrefix {
        /// The prefix given.
        prefix: String,
        /// Why it is invalid.
        reason: String,
    },
    /// The iceoryx2 node could not be created.
    #[error("cannot create iceoryx2 node '{node}': {reason}")]
    Node {
        /// Node name.
        node: String,
        /// iceoryx2's reason.
        reason: String,
    },
    /// The iceoryx2 root cannot be made or used by this user.
    #[error("{0}")]
    Root(#[from] RootError),
    /// An iceoryx2 operation on a service failed.
    #[error("{operation} on service {service}: {reason}")]
    Service {
        /// Full service name.
        service: String,
        /// What was attempted ("open or create", "loan", "send", "notify", ...).
        operation: &'static str,
        /// iceoryx2's reason.
        reason: String,
    },
    /// Another `op3dsgd` already publishes `<prefix>/graph`: one prefix, one daemon.
    #[error(
        "another op3dsgd already serves prefix '{prefix}'{}; stop it or give this one another ipc.prefix",
        pid_suffix(.other_pid)
    )]
    PrefixInUse {
        /// The prefix asked for.
        prefix: String,
        /// Process id of the daemon serving it, when iceoryx2's publisher list tells.
        other_pid: Option<u32>,
    },
}

fn pid_suffix(pid: &Option<u32>) -> String {
    pid.map(|pid| format!(" (pid {pid})")).unwrap_or_default()
}

/// An [`IpcError::Service`] for `operation` on `service`, with iceoryx2's reason.
pub fn service_err(service: &str, operation: &'static str, reason: impl std::fmt::Debug) -> IpcError {
    IpcError::Service { service: service.to_owned(), operation, reason: format!("{reason:?}") }
}

/// The iceoryx2 name `full` of a service under `prefix`, after checking the prefix
/// ([`op3dsg_ipc_types::validate_prefix`]). For services outside the contract (benchmarks); the
/// contract's own are [`op3dsg_ipc_types::services::service_name`].
pub fn service_name(prefix: &str, full: &str) -> Result<ServiceName, IpcError> {
    validate_prefix(prefix)
        .map_err(|e| IpcError::InvalidPrefix { prefix: prefix.to_owned(), reason: e.to_string() })?;
    ServiceName::new(full)
        .map_err(|e| IpcError::InvalidPrefix { prefix: prefix.to_owned(), reason: format!("{full}: {e:?}") })
}

/// An iceoryx2 node named `node_name` in `root` (made when missing, and checked first: a root of
/// another user is refused with the owner's name, before iceoryx2 could fail obscurely), with
/// signal handling disabled (the daemon and the CLI install their own Ctrl-C handlers).
pub fn create_node(root: &IpcRoot, node_name: &str) -> Result<Node<IpcService>, IpcError> {
    let name = NodeName::new(node_name)
        .map_err(|e| IpcError::Node { node: node_name.to_owned(), reason: format!("invalid name: {e:?}") })?;
    root.prepare()?;
    let config = root.config()?;
    NodeBuilder::new()
        .name(&name)
        .config(&config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<IpcService>()
        .map_err(|e| IpcError::Node { node: node_name.to_owned(), reason: format!("{e:?}") })
}

/// Removes the resources of dead nodes; returns how many were cleaned and how many could not
/// be (another user's, or removed by another process at the same moment).
fn cleanup_dead_nodes(node: &Node<IpcService>) -> (u64, u64) {
    let state = node.try_cleanup_dead_nodes();
    (state.cleanups, state.failed_cleanups)
}

fn warn_failed_cleanups(cleaned: u64, failed: u64) {
    tracing::warn!(
        cleaned,
        failed,
        "could not remove the shared-memory leftovers of some dead iceoryx2 nodes (permissions?)"
    );
}

/// A fresh daemon instance id: random (std's per-process random hash keys), mixed with the start
/// time and the pid, never 0. Two starts of the daemon practically never share one.
pub fn new_instance_id() -> u64 {
    use std::hash::{BuildHasher, Hasher};
    let mut hasher = std::collections::hash_map::RandomState::new().build_hasher();
    hasher.write_u64(crate::world::clock::wall_clock_ns());
    hasher.write_u32(std::process::id());
    match hasher.finish() {
        0 => 1,
        id => id,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn config_validation_names_the_field() {
        let mut c = IpcConfig::default();
        assert_eq!(c.validate("ipc"), Ok(()));
        c.prefix.clear();
        assert_eq!(c.validate("ipc").expect_err("empty"), "ipc.prefix: must not be empty");
        c.prefix = "op3dsg robot".into();
        assert!(c.validate("ipc").expect_err("space").starts_with("ipc.prefix: invalid character ' '"));
        c.prefix = "/abs".into();
        assert!(c.validate("ipc").is_err());
        c.prefix = "lab/robot-1".into();
        assert_eq!(c.validate("ipc"), Ok(()));
        c.subscriber_buffer = 0;
        assert_eq!(c.validate("ipc").expect_err("zero"), "ipc.subscriber_buffer: must be between 1 and 16, found 0");
        c.subscriber_buffer = 2;
        c.max_nodes = 0;
        assert_eq!(c.validate("ipc").expect_err("zero"), "ipc.max_nodes: must be between 1 and 1048576, found 0");
        c.max_nodes = 100;
        c.max_edges = (1 << 22) + 1;
        assert_eq!(c.validate("ipc").expect_err("big"), "ipc.max_edges: must be between 1 and 4194304, found 4194305");
        c.max_edges = 200;
        assert_eq!(c.validate("ipc"), Ok(()));
        assert_eq!(c.graph_capacity().max_payload_bytes(), 100 * 144 + 200 * 64);
        let parsed: Result<IpcConfig, _> = toml::from_str("prefix = \"x\"\nbogus = 1\n");
        assert!(parsed.is_err());
        let parsed: IpcConfig = toml::from_str("prefix = \"x\"\n").expect("partial table");
        assert_eq!(parsed.max_subscribers, 8);
    }

    #[test]
    fn the_origin_maps_every_opened_kind_and_stamps_header_and_health_alike() {
        use op3dsg_drivers::source::SourceKind as Opened;
        for (opened, wire) in [
            (Opened::LiveCamera, SourceKind::LiveCamera),
            (Opened::Replay, SourceKind::Replay),
            (Opened::Synthetic, SourceKind::Synthetic),
            (Opened::Other, SourceKind::Unknown),
        ] {
            let origin = GraphOrigin::new(opened, "map");
            let (mut header, mut health) = (GraphHeader::default(), Health::default());
            origin.stamp_header(&mut header);
            origin.stamp_health(&mut health);
            assert_eq!((header.source_kind(), header.world_frame_str()), (wire, "map"), "{opened:?}");
            assert_eq!((health.source_kind(), health.world_frame_str()), (wire, "map"), "{opened:?}");
            assert_eq!(header.reserved, [0; 2], "reserved bytes stay zero");
        }
    }

    #[test]
    fn defaults_are_the_contracts() {
        let c = IpcConfig::default();
        assert_eq!((c.prefix.as_str(), c.max_subscribers, c.subscriber_buffer, c.pose_buffer), ("op3dsg", 8, 2, 64));
        assert_eq!((c.max_nodes, c.max_edges), (16_384, 32_768));
    }
}
