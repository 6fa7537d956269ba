//! [`GraphServer`]: the daemon's side of the services. It creates `graph`, `graph_updated` and
//! `health` with the contract's QoS, publishes graphs (in loaned samples sized to the graph) and
//! health records, and receives and checks poses on `pose`.

use iceoryx2::port::notifier::Notifier;
use iceoryx2::port::publisher::{Publisher, PublisherCreateError};
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::port::update_connections::UpdateConnections;
use iceoryx2::prelude::{EventId, Node};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use op3dsg_ipc_types::client::open_or_create_pose_service;
use op3dsg_ipc_types::publish::GraphPayload;
use op3dsg_ipc_types::services::{
    EVENT_ID_MAX_VALUE, GRAPH_MAX_PUBLISHERS, GRAPH_PUBLISHER_MAX_LOANED_SAMPLES, GRAPH_UPDATED_EVENT_ID,
    GRAPH_UPDATED_MAX_NOTIFIERS, HEALTH_MAX_PUBLISHERS, HEALTH_SUBSCRIBER_BUFFER,
    HEALTH_SUBSCRIBER_MAX_BORROWED_SAMPLES, HISTORY_SIZE, SAFE_OVERFLOW, SUBSCRIBER_MAX_BORROWED_SAMPLES,
    daemon_service_max_nodes,
};
use op3dsg_ipc_types::{ClientError, GraphHeader, Health, PoseError, PoseStamped, ServiceNames, check_pose};

use super::{
    GraphEncoder, IpcConfig, IpcError, IpcService, PublishReport, cleanup_dead_nodes, create_node, warn_failed_cleanups,
};
use super::{new_instance_id, service_err, service_name};
use crate::graph::SceneGraph;
use crate::world::clock::wall_clock_ns;

/// The daemon's side: publishes graph and health, receives poses.
#[derive(Debug)]
pub struct GraphServer {
    names: ServiceNames,
    graph_service: PortFactory<IpcService, GraphPayload, GraphHeader>,
    graph_publisher: Publisher<IpcService, GraphPayload, GraphHeader>,
    encoder: GraphEncoder,
    notifier: Notifier<IpcService>,
    health_publisher: Publisher<IpcService, Health, ()>,
    pose_subscriber: Subscriber<IpcService, PoseStamped, ()>,
    pose_checks: PoseCheckCounts,
    dead_nodes_cleaned: u64,
    /// Dead nodes the last cleanup could not remove (warned once per change).
    failed_cleanups: u64,
    node: Node<IpcService>,
}

impl GraphServer {
    /// Creates (or reopens) the daemon's services under `config.prefix`, after removing the
    /// leftovers of dead processes when `config.cleanup_dead_nodes_at_start` is set.
    pub fn open(config: &IpcConfig, node_name: &str) -> Result<Self, IpcError> {
        config.validate("ipc").map_err(|reason| IpcError::InvalidPrefix { prefix: config.prefix.clone(), reason })?;
        let names = ServiceNames::new(&config.prefix);
        let root = config.ipc_root();
        let node = create_node(&root, node_name)?;
        tracing::info!(root = %root, "iceoryx2 root");
        let (dead_nodes_cleaned, failed_cleanups) =
            if config.cleanup_dead_nodes_at_start { cleanup_dead_nodes(&node) } else { (0, 0) };
        if failed_cleanups > 0 {
            warn_failed_cleanups(dead_nodes_cleaned, failed_cleanups);
        }
        tracing::info!(dead_nodes_cleaned, prefix = %config.prefix, "iceoryx2 stale-resource cleanup done");

        let name = service_name(&config.prefix, &names.graph)?;
        let graph_service = node
            .service_builder(&name)
            .publish_subscribe::<GraphPayload>()
            .user_header::<GraphHeader>()
            .history_size(HISTORY_SIZE)
            .enable_safe_overflow(SAFE_OVERFLOW)
            .subscriber_max_buffer_size(config.subscriber_buffer)
            .subscriber_max_borrowed_samples(SUBSCRIBER_MAX_BORROWED_SAMPLES)
            .max_subscribers(config.max_subscribers)
            .max_publishers(GRAPH_MAX_PUBLISHERS)
            .max_nodes(daemon_service_max_nodes(config.max_subscribers))
            .open_or_create()
            .map_err(|e| service_err(&names.graph, "open or create", e))?;
        // Static allocation with room for the largest graph: one data segment reserved at start,
        // never reallocated, so late joiners and the memory bound stay simple (see
        // `op3dsg_ipc_types::services`). Each publish loans and writes only the graph's bytes.
        let capacity = config.graph_capacity();
        let graph_publisher = graph_service
            .publisher_builder()
            .max_loaned_samples(GRAPH_PUBLISHER_MAX_LOANED_SAMPLES)
            .initial_max_slice_len(capacity.max_payload_bytes())
            .create()
            .map_err(|e| match e {
                PublisherCreateError::ExceedsMaxSupportedPublishers => {
                    IpcError::PrefixInUse { prefix: config.prefix.clone(), other_pid: publisher_pid(&graph_service) }
                }
                e => service_err(&names.graph, "create publisher", e),
            })?;

        let name = service_name(&config.prefix, &names.graph_updated)?;
        let event = node
            .service_builder(&name)
            .event()
            .event_id_max_value(EVENT_ID_MAX_VALUE)
            .max_notifiers(GRAPH_UPDATED_MAX_NOTIFIERS)
            .max_listeners(config.max_subscribers)
            .max_nodes(daemon_service_max_nodes(config.max_subscribers))
            .open_or_create()
            .map_err(|e| service_err(&names.graph_updated, "open or create", e))?;
        let notifier =
            event.notifier_builder().create().map_err(|e| service_err(&names.graph_updated, "create notifier", e))?;

        let name = service_name(&config.prefix, &names.health)?;
        let health_service = node
            .service_builder(&name)
            .publish_subscribe::<Health>()
            .history_size(HISTORY_SIZE)
            .enable_safe_overflow(SAFE_OVERFLOW)
            .subscriber_max_buffer_size(HEALTH_SUBSCRIBER_BUFFER)
            .subscriber_max_borrowed_samples(HEALTH_SUBSCRIBER_MAX_BORROWED_SAMPLES)
            .max_subscribers(config.max_subscribers)
            .max_publishers(HEALTH_MAX_PUBLISHERS)
            .max_nodes(daemon_service_max_nodes(config.max_subscribers))
            .open_or_create()
            .map_err(|e| service_err(&names.health, "open or create", e))?;
        let health_publisher = health_service
            .publisher_builder()
            .create()
            .map_err(|e| service_err(&names.health, "create publisher", e))?;

        let pose_subscriber = open_pose_subscriber(&node, &config.prefix, &names.pose, config.pose_buffer)?;
        let instance_id = new_instance_id();
        tracing::info!(prefix = %config.prefix, instance_id = format_args!("{instance_id:#018x}"), "serving the scene graph over iceoryx2");
        Ok(Self {
            names,
            graph_service,
            graph_publisher,
            encoder: GraphEncoder::new(capacity, instance_id),
            notifier,
            health_publisher,
            pose_subscriber,
            pose_checks: PoseCheckCounts::default(),
            dead_nodes_cleaned,
            failed_cleanups,
            node,
        })
    }

    /// The service names served.
    pub fn names(&self) -> &ServiceNames {
        &self.names
    }

    /// This daemon instance's id, in every graph header (drawn at [`Self::open`], never 0).
    pub fn instance_id(&self) -> u64 {
        self.encoder.instance_id()
    }

    /// Stamps `origin` (the opened source's kind, the world frame's name) into every graph header
    /// from now on; the publisher stamps the same into its health records.
    pub fn set_origin(&mut self, origin: super::GraphOrigin) {
        self.encoder.set_origin(origin);
    }

    /// Dead nodes whose resources were removed since start (at start and by
    /// [`Self::planner_health`]).
    pub fn dead_nodes_cleaned(&self) -> u64 {
        self.dead_nodes_cleaned
    }

    /// Fills the planners' part of `health`: the graph subscribers connected now, after removing
    /// the resources of dead nodes (a planner killed mid-read holds a subscriber slot until
    /// then), and how many dead nodes were removed since start. Called once per health period
    /// from the publisher thread: iceoryx2 lists the nodes from the file system, off the hot path.
    pub fn planner_health(&mut self, health: &mut Health) {
        let (cleaned, failed) = cleanup_dead_nodes(&self.node);
        // Once per change, not once per period: a leftover that cannot be removed stays.
        if failed > 0 && failed != self.failed_cleanups {
            warn_failed_cleanups(cleaned, failed);
        }
        self.failed_cleanups = failed;
        if cleaned > 0 {
            tracing::info!(
                cleaned,
                "removed the iceoryx2 resources of dead processes (planners killed without closing?)"
            );
        }
        self.dead_nodes_cleaned += cleaned;
        health.graph_subscribers = u16::try_from(self.subscriber_count()).unwrap_or(u16::MAX);
        health.dead_nodes_cleaned = u32::try_from(self.dead_nodes_cleaned).unwrap_or(u32::MAX);
    }

    /// The iceoryx2 node (for a `WaitSet` or `node.wait`).
    pub fn node(&self) -> &Node<IpcService> {
        &self.node
    }

    /// Subscribers connected to `graph` now.
    pub fn subscriber_count(&self) -> usize {
        use iceoryx2::service::port_factory::PortFactory as _;
        self.graph_service.dynamic_config().number_of_subscribers()
    }

    /// Connects subscribers that joined since the last call and hands them the history (the
    /// newest graph and health). iceoryx2 does this from the publisher side only, so the publisher
    /// thread must call this regularly (every ~100 ms) and not just on graph changes.
    pub fn update_connections(&self) -> Result<(), IpcError> {
        self.graph_publisher
            .update_connections()
            .map_err(|e| service_err(&self.names.graph, "update connections", e))?;
        self.health_publisher.update_connections().map_err(|e| service_err(&self.names.health, "update connections", e))
    }

    /// Publishes `graph` in a loaned sample of exactly the graph's size (its records written
    /// straight into the sample), then notifies `graph_updated` (event id
    /// [`GRAPH_UPDATED_EVENT_ID`]). Allocates nothing once a graph of this size was published.
    pub fn publish_graph(&mut self, graph: &SceneGraph) -> Result<PublishReport, IpcError> {
        let mut report = self.encoder.select(graph);
        // Loaned without zero-filling (profiled at 2,000 nodes, the memset of the whole sample
        // took about a quarter of the call's time): the records are written straight into the
        // uninitialised bytes.
        let mut sample = self
            .graph_publisher
            .loan_slice_uninit(report.payload_bytes)
            .map_err(|e| service_err(&self.names.graph, "loan", e))?;
        self.encoder.write_payload(graph, sample.payload_mut(), &mut report);
        self.encoder.set_publish_time_ns(wall_clock_ns());
        *sample.user_header_mut() = *self.encoder.header();
        // SAFETY: `write_payload` wrote every byte of the payload: it asserts that the payload is
        // exactly its records' length, and writes each record in full.
        #[allow(unsafe_code)]
        let sample = unsafe { sample.assume_init() };
        sample.send().map_err(|e| service_err(&self.names.graph, "send", e))?;
        self.notifier
            .notify_with_custom_event_id(EventId::new(GRAPH_UPDATED_EVENT_ID))
            .map_err(|e| service_err(&self.names.graph_updated, "notify", e))?;
        if report.truncated {
            tracing::warn!(
                nodes = report.total_nodes,
                edges = report.total_edges,
                published_nodes = report.nodes_written,
                published_edges = report.edges_written,
                "graph exceeds the sample capacity (ipc.max_nodes / ipc.max_edges); published the most recently seen part"
            );
        }
        Ok(report)
    }

    /// Publishes a health record.
    pub fn publish_health(&mut self, health: &Health) -> Result<(), IpcError> {
        self.health_publisher.send_copy(*health).map(|_| ()).map_err(|e| service_err(&self.names.health, "send", e))
    }

    /// Moves every received pose into `out`; poses that fail [`check_pose`] (an unknown kind, a
    /// non-finite translation or rotation, or a quaternion whose norm is off by more than
    /// [`QUATERNION_NORM_TOLERANCE`](op3dsg_ipc_types::services::QUATERNION_NORM_TOLERANCE))
    /// are dropped and counted by reason ([`Self::pose_checks`]). Returns the number of poses
    /// appended.
    pub fn poll_poses(&mut self, out: &mut Vec<PoseStamped>) -> Result<usize, IpcError> {
        let mut accepted = 0;
        while let Some(sample) =
            self.pose_subscriber.receive().map_err(|e| service_err(&self.names.pose, "receive", e))?
        {
            let pose = *sample.payload();
            match check_pose(&pose) {
                Ok(()) => {
                    out.push(pose);
                    accepted += 1;
                }
                Err(reason) => {
                    let count = self.pose_checks.count(&reason);
                    if count.is_power_of_two() {
                        tracing::warn!(service = %self.names.pose, count, "dropped pose: {reason}");
                    }
                }
            }
        }
        Ok(accepted)
    }

    /// Poses dropped as invalid since start, all reasons together.
    pub fn invalid_pose_count(&self) -> u64 {
        let c = &self.pose_checks;
        c.unknown_kind + c.non_finite + c.non_unit_quaternion
    }

    /// Poses dropped as invalid since start, by reason.
    pub fn pose_checks(&self) -> &PoseCheckCounts {
        &self.pose_checks
    }
}

/// Received poses that failed [`check_pose`], by reason, since start.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PoseCheckCounts {
    /// `kind` is not a known value.
    pub unknown_kind: u64,
    /// NaN or infinite translation or rotation.
    pub non_finite: u64,
    /// Quaternion norm off 1.
    pub non_unit_quaternion: u64,
}

impl PoseCheckCounts {
    /// Counts `reason`; returns the new count of that reason (for rate-limited warnings).
    fn count(&mut self, reason: &PoseError) -> u64 {
        let counter = match reason {
            PoseError::UnknownKind { .. } => &mut self.unknown_kind,
            PoseError::NonFiniteTranslation { .. } | PoseError::NonFiniteRotation { .. } => &mut self.non_finite,
            // Not a wire check (a received frame id always fits); counted with the kind checks.
            PoseError::FrameIdTooLong { .. } => &mut self.unknown_kind,
            PoseError::NonUnitQuaternion { .. } => &mut self.non_unit_quaternion,
        };
        *counter += 1;
        *counter
    }
}

/// Opens (or creates) `pose` for the daemon with the rule both sides share
/// ([`open_or_create_pose_service`]). If a client created it with a smaller buffer than
/// requested, the daemon still opens it (with the client's buffer) rather than refusing to start.
fn open_pose_subscriber(
    node: &Node<IpcService>,
    prefix: &str,
    service: &str,
    buffer: usize,
) -> Result<Subscriber<IpcService, PoseStamped, ()>, IpcError> {
    let pose_service = open_or_create_pose_service(node, prefix, buffer).map_err(|e| pose_err(service, &e))?;
    {
        use iceoryx2::service::port_factory::PortFactory as _;
        let qos = pose_service.factory.static_config();
        tracing::info!(
            service,
            created = pose_service.created,
            max_publishers = qos.max_publishers(),
            max_subscribers = qos.max_subscribers(),
            buffer = qos.subscriber_max_buffer_size(),
            safe_overflow = qos.has_safe_overflow(),
            "pose service ready"
        );
    }
    if pose_service.smaller_buffer {
        tracing::warn!(service, buffer, "pose service exists with a smaller buffer than configured; using it");
    }
    if pose_service.unsafe_overflow {
        tracing::warn!(
            service,
            "pose service exists without safe overflow; a pose publisher may block on a full buffer"
        );
    }
    pose_service.factory.subscriber_builder().create().map_err(|e| service_err(service, "create subscriber", e))
}

/// The process id of a publisher already on `service` (the daemon that serves the prefix), if
/// iceoryx2 can tell.
fn publisher_pid(service: &PortFactory<IpcService, GraphPayload, GraphHeader>) -> Option<u32> {
    use iceoryx2::prelude::CallbackProgression;
    use iceoryx2::service::port_factory::PortFactory as _;
    let mut pid = None;
    service.dynamic_config().list_publishers(|details| {
        pid = details.node_id.pid::<IpcService>().ok().map(|p| p.value() as u32);
        CallbackProgression::Stop
    });
    pid
}

/// A failure of the shared `pose` rule as an [`IpcError::Service`]: the operation it names and
/// iceoryx2's reason.
fn pose_err(service: &str, error: &ClientError) -> IpcError {
    IpcError::Service {
        service: service.to_owned(),
        operation: error.operation().as_str(),
        reason: error.cause().to_string(),
    }
}
