//! The client's error: which service, which operation, and why (iceoryx2's own reason, or a
//! contract check of this crate).

use iceoryx2::node::NodeCreationFailure;
use iceoryx2::port::listener::{ListenerCreateError, ListenerWaitError};
use iceoryx2::port::publisher::PublisherCreateError;
use iceoryx2::port::subscriber::SubscriberCreateError;
use iceoryx2::port::update_connections::ConnectionFailure;
use iceoryx2::port::{ReceiveError, SendError};
use iceoryx2::prelude::SemanticStringError;
use iceoryx2::service::builder::event::EventOpenError;
use iceoryx2::service::builder::publish_subscribe::{PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError};

use crate::access::{AccessDenied, IPC_ROOT_ENV, IpcRoot};
use crate::client::{OccupancyError, SnapshotError};
use crate::services::{PrefixError, ServiceKind};
use crate::{PoseError, SCHEMA_VERSION};

/// What the client was doing when it failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Operation {
    /// Creating the client's iceoryx2 node.
    CreateNode,
    /// Opening a service the daemon creates.
    Open,
    /// Opening or creating `pose`.
    OpenOrCreate,
    /// Creating a subscriber port.
    CreateSubscriber,
    /// Creating a listener port.
    CreateListener,
    /// Creating a publisher port.
    CreatePublisher,
    /// Receiving (or checking) a sample.
    Receive,
    /// Waiting for an event.
    Wait,
    /// Checking and sending a sample.
    Publish,
}

impl Operation {
    /// Lower-case words, as in the error messages.
    pub fn as_str(self) -> &'static str {
        match self {
            Self::CreateNode => "create node",
            Self::Open => "open",
            Self::OpenOrCreate => "open or create",
            Self::CreateSubscriber => "create subscriber",
            Self::CreateListener => "create listener",
            Self::CreatePublisher => "create publisher",
            Self::Receive => "receive",
            Self::Wait => "wait",
            Self::Publish => "publish",
        }
    }
}

/// Why an operation failed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ErrorCause {
    /// The prefix cannot form service names.
    InvalidPrefix(PrefixError),
    /// The node name is not a valid iceoryx2 node name.
    InvalidNodeName(SemanticStringError),
    /// iceoryx2 could not create the node.
    Node(NodeCreationFailure),
    /// No daemon has created the service under this prefix (or its IPC root does not exist).
    NotServing,
    /// The IPC root belongs to another user or is open to others
    /// ([`IpcRoot::check`](crate::access::IpcRoot::check)).
    AccessDenied(AccessDenied),
    /// `$OP3DSG_IPC_ROOT` is no valid root (relative, too long, not UTF-8).
    InvalidRoot,
    /// Opening a publish-subscribe service failed.
    OpenPublishSubscribe(PublishSubscribeOpenError),
    /// Opening or creating a publish-subscribe service failed.
    OpenOrCreatePublishSubscribe(PublishSubscribeOpenOrCreateError),
    /// Opening an event service failed.
    OpenEvent(EventOpenError),
    /// Creating a subscriber failed.
    CreateSubscriber(SubscriberCreateError),
    /// Creating a listener failed.
    CreateListener(ListenerCreateError),
    /// Creating a publisher failed.
    CreatePublisher(PublisherCreateError),
    /// Connecting to the publisher's data segment failed.
    Connection(ConnectionFailure),
    /// Receiving a sample failed.
    Receive(ReceiveError),
    /// Waiting on the listener failed.
    Wait(ListenerWaitError),
    /// Sending a sample failed.
    Send(SendError),
    /// A received graph sample breaks the contract (another schema version, a bad count or kind).
    InvalidGraph(SnapshotError),
    /// A received occupancy map breaks the contract (another schema version, a bad size).
    InvalidOccupancy(OccupancyError),
    /// A received health record has another schema version.
    HealthSchemaVersion {
        /// Version in the sample.
        found: u32,
        /// [`SCHEMA_VERSION`].
        expected: u32,
    },
    /// The pose was refused before sending.
    InvalidPose(PoseError),
}

impl core::fmt::Display for ErrorCause {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::InvalidPrefix(e) => write!(f, "invalid prefix: {e}"),
            Self::InvalidNodeName(e) => write!(f, "invalid node name: {e}"),
            Self::Node(e) => write!(f, "{e}"),
            // Filled in by ClientError's Display, which knows the prefix.
            Self::NotServing => write!(f, "no op3dsgd is serving (service not found)"),
            Self::AccessDenied(why) => f.write_str(&why.explain(IpcRoot::resolve().path())),
            Self::InvalidRoot => match IpcRoot::resolve().config() {
                Err(e) => write!(f, "{e} (${IPC_ROOT_ENV})"),
                Ok(_) => write!(f, "invalid IPC root (${IPC_ROOT_ENV})"),
            },
            Self::OpenPublishSubscribe(e @ PublishSubscribeOpenError::IncompatibleTypes) => write!(
                f,
                "{e}: the service carries another payload type or layout than this build \
                 (wire contract schema {SCHEMA_VERSION})"
            ),
            Self::OpenPublishSubscribe(e) => write!(f, "{e}"),
            Self::OpenOrCreatePublishSubscribe(e) => write!(f, "{e}"),
            Self::OpenEvent(e) => write!(f, "{e}"),
            Self::CreateSubscriber(e @ SubscriberCreateError::ExceedsMaxSupportedSubscribers) => {
                write!(f, "{e}: every subscriber slot of the service is taken (the daemon's ipc.max_subscribers)")
            }
            Self::CreateSubscriber(e) => write!(f, "{e}"),
            Self::CreateListener(e) => write!(f, "{e}"),
            Self::CreatePublisher(e) => write!(f, "{e}"),
            Self::Connection(e) => write!(f, "{e}"),
            Self::Receive(e) => write!(f, "{e}"),
            Self::Wait(e) => write!(f, "{e}"),
            Self::Send(e) => write!(f, "{e}"),
            Self::InvalidGraph(e) => write!(f, "invalid sample: {e}"),
            Self::InvalidOccupancy(e) => write!(f, "invalid map: {e}"),
            Self::HealthSchemaVersion { found, expected } => {
                write!(f, "invalid sample: schema_version: found {found}, this build reads {expected}")
            }
            Self::InvalidPose(e) => write!(f, "invalid pose: {e}"),
        }
    }
}

/// A failed client operation: the service (full name), the operation and the cause, shown as
/// `op3dsg/graph: open: <cause>`.
#[derive(Debug, Clone, PartialEq)]
pub struct ClientError {
    service_name: String,
    service: ServiceKind,
    operation: Operation,
    cause: ErrorCause,
}

impl ClientError {
    pub(crate) fn new(prefix: &str, service: ServiceKind, operation: Operation, cause: ErrorCause) -> Self {
        Self { service_name: service.name(prefix), service, operation, cause }
    }

    /// The service concerned.
    pub fn service(&self) -> ServiceKind {
        self.service
    }

    /// The full service name (`<prefix>/<service>`).
    pub fn service_name(&self) -> &str {
        &self.service_name
    }

    /// The prefix the client used.
    pub fn prefix(&self) -> &str {
        let suffix_len = self.service.suffix().len() + 1;
        &self.service_name[..self.service_name.len().saturating_sub(suffix_len)]
    }

    /// What the client was doing.
    pub fn operation(&self) -> Operation {
        self.operation
    }

    /// Why it failed.
    pub fn cause(&self) -> ErrorCause {
        self.cause
    }

    /// `true` when no daemon serves the prefix (yet): retrying later may succeed.
    pub fn is_not_serving(&self) -> bool {
        self.cause == ErrorCause::NotServing
    }
}

impl core::fmt::Display for ClientError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let (service, operation) = (&self.service_name, self.operation.as_str());
        match self.cause {
            ErrorCause::NotServing => {
                let root = IpcRoot::resolve();
                write!(
                    f,
                    "{service}: {operation}: no op3dsgd is serving under prefix '{}' in IPC root {} \
                     (service {service} not found)",
                    self.prefix(),
                    root.path().display()
                )?;
                match root.foreign_service_note() {
                    Some(note) => write!(f, "; {note}"),
                    None => Ok(()),
                }
            }
            cause => write!(f, "{service}: {operation}: {cause}"),
        }
    }
}

impl std::error::Error for ClientError {
    fn source(&self) -> Option<&(dyn std::error::Error + 'static)> {
        match &self.cause {
            ErrorCause::InvalidPrefix(e) => Some(e),
            ErrorCause::Node(e) => Some(e),
            ErrorCause::OpenPublishSubscribe(e) => Some(e),
            ErrorCause::OpenOrCreatePublishSubscribe(e) => Some(e),
            ErrorCause::CreateListener(e) => Some(e),
            ErrorCause::Connection(e) => Some(e),
            ErrorCause::Receive(e) => Some(e),
            ErrorCause::Wait(e) => Some(e),
            ErrorCause::Send(e) => Some(e),
            ErrorCause::InvalidGraph(e) => Some(e),
            ErrorCause::InvalidOccupancy(e) => Some(e),
            ErrorCause::InvalidPose(e) => Some(e),
            ErrorCause::InvalidNodeName(e) => Some(e),
            ErrorCause::OpenEvent(e) => Some(e),
            ErrorCause::CreateSubscriber(e) => Some(e),
            ErrorCause::CreatePublisher(e) => Some(e),
            ErrorCause::NotServing
            | ErrorCause::AccessDenied(_)
            | ErrorCause::InvalidRoot
            | ErrorCause::HealthSchemaVersion { .. } => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_name_service_operation_and_cause() {
        let err = ClientError::new("lab/robot", ServiceKind::Graph, Operation::Open, ErrorCause::NotServing);
        let expected = format!(
            "lab/robot/graph: open: no op3dsgd is serving under prefix 'lab/robot' in IPC root {} \
             (service lab/robot/graph not found)",
            IpcRoot::resolve().path().display()
        );
        assert!(err.to_string().starts_with(&expected), "{err}");
        assert!(err.is_not_serving());
        assert_eq!(err.prefix(), "lab/robot");
        let err = ClientError::new(
            "op3dsg",
            ServiceKind::Graph,
            Operation::Receive,
            ErrorCause::InvalidGraph(SnapshotError::SchemaVersion { found: 2, expected: 3 }),
        );
        assert_eq!(
            err.to_string(),
            "op3dsg/graph: receive: invalid sample: header.schema_version: found 2, this build reads 3"
        );
        assert!(std::error::Error::source(&err).is_some());
        let err = ClientError::new(
            "op3dsg",
            ServiceKind::Pose,
            Operation::Publish,
            ErrorCause::InvalidPose(PoseError::NonUnitQuaternion { norm: 2.0 }),
        );
        assert_eq!(err.to_string(), "op3dsg/pose: publish: invalid pose: quaternion norm 2 is not 1 (tolerance 0.001)");
        assert!(core::mem::size_of::<ClientError>() <= 96, "keep Result<_, ClientError> small");
    }
}
