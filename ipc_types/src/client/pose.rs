//! [`PosePublisher`]: sends checked camera or base poses to the daemon on `<prefix>/pose`, and
//! the open-or-create rule both sides of `pose` share.

use iceoryx2::node::Node as IoxNode;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeCreateError, PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::PortFactory as _;
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;

use crate::client::{ClientError, ErrorCause, Operation, RootUse, create_node};
use crate::services::{
    DEFAULT_POSE_BUFFER, IpcService, POSE_HISTORY_SIZE, POSE_MAX_NODES, POSE_MAX_PUBLISHERS, POSE_MAX_SUBSCRIBERS,
    POSE_SUBSCRIBER_MAX_BORROWED_SAMPLES, SAFE_OVERFLOW, ServiceKind, service_name,
};
use crate::{PoseKind, PoseStamped, check_pose};

/// A rigid transform `world_from_x`: a point in frame `x` maps into the world as
/// `rotation * point_in_x + translation_m`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Pose {
    /// Translation, metres, world frame.
    pub translation_m: [f64; 3],
    /// Rotation as a unit quaternion `[x, y, z, w]`.
    pub rotation_xyzw: [f64; 4],
}

impl Pose {
    /// No rotation, no translation.
    pub const IDENTITY: Pose = Pose { translation_m: [0.0; 3], rotation_xyzw: [0.0, 0.0, 0.0, 1.0] };

    /// A pose from its parts.
    pub fn new(translation_m: [f64; 3], rotation_xyzw: [f64; 4]) -> Self {
        Self { translation_m, rotation_xyzw }
    }

    /// A pose turned by `yaw_rad` about the world `+z` axis (a ground robot's base with the
    /// default `world.up_axis`).
    pub fn from_translation_yaw(translation_m: [f64; 3], yaw_rad: f64) -> Self {
        let (sin, cos) = (yaw_rad * 0.5).sin_cos();
        Self { translation_m, rotation_xyzw: [0.0, 0.0, sin, cos] }
    }
}

/// The `pose` service as [`open_or_create_pose_service`] found it.
#[derive(Debug)]
pub struct PoseService {
    /// The service, to create publishers or subscribers from.
    pub factory: PortFactory<IpcService, PoseStamped, ()>,
    /// `true` when this call created the service (with the contract's QoS).
    pub created: bool,
    /// `true` when the service already existed with a smaller subscriber buffer than requested
    /// and was opened as it is (the daemon warns about this).
    pub smaller_buffer: bool,
    /// `true` when the service already existed without safe overflow: a publisher may then
    /// block or fail while a subscriber's buffer is full (the daemon warns about this).
    pub unsafe_overflow: bool,
}

/// Opens `<prefix>/pose`, or creates it when it does not exist: the rule of both the daemon (its
/// profile's buffer) and [`PosePublisher`] ([`DEFAULT_POSE_BUFFER`]), since either may start
/// first, and so may a navigation stack with its own iceoryx2 code.
///
/// - **Open** states no requirement beyond the payload type ([`PoseStamped`], type name
///   `op3dsg::PoseStamped`): a service created with iceoryx2's default QoS (2 publishers,
///   8 subscribers, buffer 2, safe overflow) is opened as it is. What a creator must allow is
///   one publisher and one subscriber slot for each side that joins later (the daemon takes one
///   subscriber slot); a full service fails later, when the port is created
///   (`ExceedsMaxSupportedPublishers` / `ExceedsMaxSupportedSubscribers`). A buffer smaller
///   than `buffer` or no safe overflow is reported in [`PoseService`] rather than refused.
/// - **Create** fixes the contract's QoS: safe overflow, a subscriber buffer of `buffer` poses,
///   [`POSE_MAX_PUBLISHERS`] publishers and [`POSE_MAX_SUBSCRIBERS`] subscribers. If another
///   process creates it in between, it is opened instead.
pub fn open_or_create_pose_service(
    node: &IoxNode<IpcService>,
    prefix: &str,
    buffer: usize,
) -> Result<PoseService, ClientError> {
    let fail = |operation, cause| ClientError::new(prefix, ServiceKind::Pose, operation, cause);
    let name = service_name(prefix, ServiceKind::Pose)
        .map_err(|e| fail(Operation::OpenOrCreate, ErrorCause::InvalidPrefix(e)))?;
    let create_failed = |e| {
        fail(
            Operation::OpenOrCreate,
            ErrorCause::OpenOrCreatePublishSubscribe(PublishSubscribeOpenOrCreateError::PublishSubscribeCreateError(e)),
        )
    };
    let builder = || node.service_builder(&name).publish_subscribe::<PoseStamped>();
    let opened = |factory: PortFactory<IpcService, PoseStamped, ()>| {
        let config = factory.static_config();
        let smaller_buffer = config.subscriber_max_buffer_size() < buffer;
        let unsafe_overflow = !config.has_safe_overflow();
        PoseService { factory, created: false, smaller_buffer, unsafe_overflow }
    };
    // A few rounds: between a failed open and a create, another process may create it, and
    // between a failed create and the open, the creator may still be initialising it.
    let mut last = None;
    for _ in 0..OPEN_OR_CREATE_ATTEMPTS {
        match builder().open() {
            Ok(factory) => return Ok(opened(factory)),
            Err(PublishSubscribeOpenError::DoesNotExist) => {}
            Err(e) => return Err(fail(Operation::Open, ErrorCause::OpenPublishSubscribe(e))),
        }
        match builder()
            .enable_safe_overflow(SAFE_OVERFLOW)
            .history_size(POSE_HISTORY_SIZE)
            .subscriber_max_buffer_size(buffer)
            .subscriber_max_borrowed_samples(POSE_SUBSCRIBER_MAX_BORROWED_SAMPLES)
            .max_publishers(POSE_MAX_PUBLISHERS)
            .max_subscribers(POSE_MAX_SUBSCRIBERS)
            .max_nodes(POSE_MAX_NODES)
            .create()
        {
            Ok(factory) => {
                return Ok(PoseService { factory, created: true, smaller_buffer: false, unsafe_overflow: false });
            }
            Err(
                e @ (PublishSubscribeCreateError::AlreadyExists
                | PublishSubscribeCreateError::IsBeingCreatedByAnotherInstance),
            ) => {
                last = Some(e);
                std::thread::sleep(OPEN_OR_CREATE_RETRY);
            }
            Err(e) => return Err(create_failed(e)),
        }
    }
    Err(create_failed(last.unwrap_or(PublishSubscribeCreateError::AlreadyExists)))
}

/// Rounds of open, then create, before [`open_or_create_pose_service`] gives up.
const OPEN_OR_CREATE_ATTEMPTS: usize = 20;
/// Pause between two rounds.
const OPEN_OR_CREATE_RETRY: std::time::Duration = std::time::Duration::from_millis(10);

/// Sends camera or base poses to the daemon on `<prefix>/pose` (navigation stacks, tools,
/// tests). Every pose is checked before it is sent ([`check_pose`]): the daemon would drop a
/// non-finite or non-unit one, so it is refused here with the reason instead.
#[derive(Debug)]
pub struct PosePublisher {
    prefix: String,
    publisher: Publisher<IpcService, PoseStamped, ()>,
    node: IoxNode<IpcService>,
}

impl PosePublisher {
    /// Opens (or creates, with the daemon's default QoS) `<prefix>/pose` as iceoryx2 node
    /// `node_name`. It works before the daemon starts; poses sent while no daemon listens are
    /// lost (the service keeps no history).
    pub fn open(prefix: &str, node_name: &str) -> Result<Self, ClientError> {
        let node = create_node(prefix, ServiceKind::Pose, node_name, RootUse::MakeIfMissing)?;
        let service = open_or_create_pose_service(&node, prefix, DEFAULT_POSE_BUFFER)?;
        let publisher = service.factory.publisher_builder().create().map_err(|e| {
            ClientError::new(prefix, ServiceKind::Pose, Operation::CreatePublisher, ErrorCause::CreatePublisher(e))
        })?;
        Ok(Self { prefix: prefix.to_owned(), publisher, node })
    }

    /// The prefix served.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The client's iceoryx2 node.
    pub fn node(&self) -> &IoxNode<IpcService> {
        &self.node
    }

    /// Sends `world_from_x` (camera or base, as `kind` says) valid at `stamp_ns` on the camera's
    /// clock; `frame_id` names the child frame (`camera_color_optical_frame`, `base_link`) and
    /// must fit [`NAME_CAPACITY_BYTES`](crate::NAME_CAPACITY_BYTES). Returns the number of
    /// subscribers reached (0 while no daemon listens).
    pub fn publish(
        &self,
        stamp_ns: u64,
        kind: PoseKind,
        world_from_x: &Pose,
        frame_id: &str,
    ) -> Result<usize, ClientError> {
        let pose = PoseStamped::new(stamp_ns, kind, world_from_x.translation_m, world_from_x.rotation_xyzw, frame_id)
            .map_err(|e| self.error(ErrorCause::InvalidPose(e)))?;
        self.send(pose)
    }

    /// Sends a pose built by the caller, after the same checks as [`Self::publish`].
    pub fn publish_stamped(&self, pose: &PoseStamped) -> Result<usize, ClientError> {
        check_pose(pose).map_err(|e| self.error(ErrorCause::InvalidPose(e)))?;
        self.send(*pose)
    }

    fn send(&self, pose: PoseStamped) -> Result<usize, ClientError> {
        self.publisher.send_copy(pose).map_err(|e| self.error(ErrorCause::Send(e)))
    }

    fn error(&self, cause: ErrorCause) -> ClientError {
        ClientError::new(&self.prefix, ServiceKind::Pose, Operation::Publish, cause)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yaw_pose_is_a_unit_quaternion_about_z() {
        let pose = Pose::from_translation_yaw([1.0, 2.0, 0.0], core::f64::consts::PI);
        let [x, y, z, w] = pose.rotation_xyzw;
        assert_eq!((x, y), (0.0, 0.0));
        assert!((z - 1.0).abs() < 1e-12 && w.abs() < 1e-12);
        assert_eq!(Pose::IDENTITY.rotation_xyzw, [0.0, 0.0, 0.0, 1.0]);
    }
}
