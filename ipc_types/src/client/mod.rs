//! The client side of the op3dsg services, for planners, navigation stacks and tools:
//!
//! - [`GraphSubscriber`]: opens `<prefix>/graph` and `<prefix>/graph_updated` (waiting for the
//!   daemon if it is not up yet), wakes on updates and lends the newest sample as a
//!   [`GraphView`] or copies it into an owned [`Graph`] with typed views ([`NodeView`],
//!   [`EdgeView`]).
//! - [`GraphView`]: one graph sample read in place, lent by [`GraphSubscriber::with_latest`]
//!   (no copy; [`NodeRef`], [`EdgeRef`]).
//! - [`HealthSubscriber`]: reads `<prefix>/health` alone, so it works even when every graph
//!   subscriber slot is taken.
//! - [`OccupancySubscriber`]: reads the occupancy map (`<prefix>/occupancy`) into an
//!   [`OccupancyMap`].
//! - [`PosePublisher`]: sends checked camera or base poses on `<prefix>/pose`.
//!
//! Every port uses the QoS of [`crate::services`]; clients never create the daemon's services.
//! Each client owns one iceoryx2 node, created with signal handling disabled (a planner installs
//! its own Ctrl-C handler; a signal interrupts [`GraphSubscriber::wait_for_update`], which then
//! returns `Ok(false)`). Opening first removes the shared-memory leftovers of dead processes, so a
//! client never waits on a daemon that was killed.

mod accessors;
mod check;
mod error;
mod follower;
mod graph;
mod health;
mod occupancy;
mod pose;
mod query;
#[cfg(feature = "zenoh")]
mod remote;
#[cfg(feature = "zenoh")]
mod remote_request;
mod sample_view;
#[cfg(test)]
mod test_graphs;
mod view;

use std::time::{Duration, Instant};

use iceoryx2::config::Config;
use iceoryx2::node::Node as IoxNode;
use iceoryx2::prelude::{NodeBuilder, NodeName, SignalHandlingMode};

pub use check::{SnapshotError, check_layout, check_message};
pub use error::{ClientError, ErrorCause, Operation};
pub use follower::{Applied, RemoteFollower};
pub use graph::GraphSubscriber;
pub use health::HealthSubscriber;
pub use occupancy::{OccupancyError, OccupancyMap, OccupancySubscriber, check_occupancy};
pub use pose::{Pose, PosePublisher, PoseService, open_or_create_pose_service};
pub use query::{QueryClient, QueryClientError};
#[cfg(feature = "zenoh")]
pub use remote::{RemoteClientError, RemoteGraphSubscriber};
#[cfg(feature = "zenoh")]
pub use remote_request::RemoteRequester;
pub use sample_view::{EdgeRef, GraphView, NodeRef};
pub use view::{EdgeView, Graph, NodeView, UnknownAffordance};

use crate::access::{IpcRoot, RootError};
use crate::services::{
    ATTACH_HISTORY_POLL, ATTACH_HISTORY_WAIT, IpcService, OPEN_RETRY_INTERVAL, ServiceKind, validate_prefix,
};

/// Waits until a newly connected subscriber holds the service's history sample
/// (`has_samples` says so, or fails: the read reports the failure), up to
/// [`ATTACH_HISTORY_WAIT`]. A daemon that has published nothing yet gives none.
pub(crate) fn await_history(mut has_samples: impl FnMut() -> bool) {
    let deadline = Instant::now() + ATTACH_HISTORY_WAIT;
    while !has_samples() && Instant::now() < deadline {
        std::thread::sleep(ATTACH_HISTORY_POLL);
    }
}

/// Checks the prefix and creates the client's node; errors name `service`, the one being opened.
pub(crate) fn create_node(
    prefix: &str,
    service: ServiceKind,
    node_name: &str,
    root: RootUse,
) -> Result<IoxNode<IpcService>, ClientError> {
    let fail = |cause| ClientError::new(prefix, service, Operation::CreateNode, cause);
    validate_prefix(prefix).map_err(|e| fail(ErrorCause::InvalidPrefix(e)))?;
    let name = NodeName::new(node_name).map_err(|e| fail(ErrorCause::InvalidNodeName(e)))?;
    let config = client_config(root).map_err(fail)?;
    let node = NodeBuilder::new()
        .name(&name)
        .config(&config)
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<IpcService>()
        .map_err(|e| fail(ErrorCause::Node(e)))?;
    // Failures here are the daemon's to report (it logs them at start); a client loses nothing
    // but a faster start when leftovers stay.
    let _ = node.try_cleanup_dead_nodes();
    Ok(node)
}

/// What a client does with a missing IPC root.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RootUse {
    /// Only use an existing root: a missing one means no daemon of this user has started.
    Existing,
    /// Make it (mode 0700) when missing: for a client that may create a service before the
    /// daemon starts (the pose publisher).
    MakeIfMissing,
}

/// The iceoryx2 configuration of a client: the root [`IpcRoot::resolve`] chooses, checked
/// ([`IpcRoot::check`]) before iceoryx2 could create anything in it. A missing root is "not
/// serving" (no daemon of this user has started), so `open_wait` keeps waiting for one.
pub fn client_config(root_use: RootUse) -> Result<Config, ErrorCause> {
    let root = IpcRoot::resolve();
    let usable = match root_use {
        RootUse::Existing => root.check(),
        RootUse::MakeIfMissing => root.prepare(),
    };
    match usable.and_then(|()| root.config()) {
        Ok(config) => Ok(config),
        Err(RootError::Missing(_)) => Err(ErrorCause::NotServing),
        Err(RootError::Denied(_, why)) => Err(ErrorCause::AccessDenied(why)),
        Err(RootError::InvalidPath(..) | RootError::Create(..)) => Err(ErrorCause::InvalidRoot),
    }
}

/// Calls `open` until it succeeds, fails with another error than "not serving", or `timeout`
/// has passed; retries every [`OPEN_RETRY_INTERVAL`].
pub(crate) fn retry_while_not_serving<T>(
    timeout: Duration,
    mut open: impl FnMut() -> Result<T, ClientError>,
) -> Result<T, ClientError> {
    let deadline = Instant::now() + timeout;
    loop {
        match open() {
            Err(e) if e.is_not_serving() => {
                let left = deadline.saturating_duration_since(Instant::now());
                if left.is_zero() {
                    return Err(e);
                }
                std::thread::sleep(OPEN_RETRY_INTERVAL.min(left));
            }
            result => return result,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clients_can_move_to_another_thread() {
        fn assert_send<T: Send>() {}
        assert_send::<GraphSubscriber>();
        assert_send::<OccupancySubscriber>();
        assert_send::<HealthSubscriber>();
        assert_send::<PosePublisher>();
        assert_send::<Graph>();
        assert_send::<ClientError>();
    }
}
