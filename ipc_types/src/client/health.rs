//! [`HealthSubscriber`]: a reader of `<prefix>/health` that needs no graph subscriber slot.

use std::time::{Duration, Instant};

use iceoryx2::node::Node as IoxNode;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::service::builder::publish_subscribe::PublishSubscribeOpenError;

use crate::client::{ClientError, ErrorCause, Operation, RootUse, await_history, create_node, retry_while_not_serving};
use crate::services::{HISTORY_SIZE, IpcService, ServiceKind, service_name};
use crate::{Health, SCHEMA_VERSION};

/// Reads the daemon's [`Health`] records. It opens `<prefix>/health` only, so a monitor works
/// when every `graph` subscriber slot is taken, and it holds no 4.3 MiB graph sample.
///
/// Opening waits for the service's history, the daemon's newest record (up to
/// [`ATTACH_HISTORY_WAIT`](crate::services::ATTACH_HISTORY_WAIT); it comes within 20 ms), so the
/// first [`Self::latest`] after opening returns it.
#[derive(Debug)]
pub struct HealthSubscriber {
    prefix: String,
    subscriber: Subscriber<IpcService, Health, ()>,
    latest: Option<Health>,
    node: IoxNode<IpcService>,
}

impl HealthSubscriber {
    /// Opens the daemon's `health` under `prefix` as iceoryx2 node `node_name`; fails with a
    /// "not serving" error ([`ClientError::is_not_serving`]) when no daemon has created it.
    pub fn open(prefix: &str, node_name: &str) -> Result<Self, ClientError> {
        let node = create_node(prefix, ServiceKind::Health, node_name, RootUse::Existing)?;
        let subscriber = open_subscriber(&node, prefix)?;
        await_history(|| subscriber.has_samples().unwrap_or(true));
        Ok(Self { prefix: prefix.to_owned(), subscriber, latest: None, node })
    }

    /// Like [`Self::open`], but while no daemon serves `prefix` retries every
    /// [`OPEN_RETRY_INTERVAL`](crate::services::OPEN_RETRY_INTERVAL), up to `timeout`.
    pub fn open_wait(prefix: &str, node_name: &str, timeout: Duration) -> Result<Self, ClientError> {
        let deadline = Instant::now() + timeout;
        let node = retry_while_not_serving(timeout, || {
            create_node(prefix, ServiceKind::Health, node_name, RootUse::Existing)
        })?;
        let timeout = deadline.saturating_duration_since(Instant::now());
        let subscriber = retry_while_not_serving(timeout, || open_subscriber(&node, prefix))?;
        await_history(|| subscriber.has_samples().unwrap_or(true));
        Ok(Self { prefix: prefix.to_owned(), subscriber, latest: None, node })
    }

    /// The prefix served.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// The client's iceoryx2 node.
    pub fn node(&self) -> &IoxNode<IpcService> {
        &self.node
    }

    /// Takes every queued record and returns a copy of the newest received so far; `None` while
    /// the daemon has published none this client could receive. Compare
    /// [`Health::stamp_ns`] to tell a fresh record from the last one. A record of another schema
    /// version is an error naming both versions, and is not kept.
    pub fn latest(&mut self) -> Result<Option<Health>, ClientError> {
        let fail = |operation, cause| ClientError::new(&self.prefix, ServiceKind::Health, operation, cause);
        let mut newest = None;
        while let Some(sample) =
            self.subscriber.receive().map_err(|e| fail(Operation::Receive, ErrorCause::Receive(e)))?
        {
            newest = Some(*sample.payload());
        }
        if let Some(health) = newest {
            if health.schema_version != SCHEMA_VERSION {
                return Err(fail(
                    Operation::Receive,
                    ErrorCause::HealthSchemaVersion { found: health.schema_version, expected: SCHEMA_VERSION },
                ));
            }
            self.latest = Some(health);
        }
        Ok(self.latest)
    }
}

fn open_subscriber(
    node: &IoxNode<IpcService>,
    prefix: &str,
) -> Result<Subscriber<IpcService, Health, ()>, ClientError> {
    let fail = |operation, cause| ClientError::new(prefix, ServiceKind::Health, operation, cause);
    let name =
        service_name(prefix, ServiceKind::Health).map_err(|e| fail(Operation::Open, ErrorCause::InvalidPrefix(e)))?;
    let service = match node.service_builder(&name).publish_subscribe::<Health>().open() {
        Ok(service) => service,
        Err(PublishSubscribeOpenError::DoesNotExist) => return Err(fail(Operation::Open, ErrorCause::NotServing)),
        Err(e) => return Err(fail(Operation::Open, ErrorCause::OpenPublishSubscribe(e))),
    };
    service
        .subscriber_builder()
        .history_request(HISTORY_SIZE)
        .create()
        .map_err(|e| fail(Operation::CreateSubscriber, ErrorCause::CreateSubscriber(e)))
}
