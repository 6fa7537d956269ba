//! The off-robot stages in `Pipeline::start`: the Zenoh stage and the ROS output (fed by the
//! publisher), and the tf input (feeding the keyframe gate). With the feature `zenoh` they start
//! here (`zenoh_stages`); without it nothing that speaks Zenoh is built, and `Profile::validate`
//! has refused a profile that turns any of them on, so there is nothing to start.

use std::sync::Arc;
use std::sync::atomic::AtomicBool;

use crossbeam_channel::Sender;
use op3dsg_drivers::source::{FrameSource, SourceKind};
use op3dsg_ipc_types::PoseStamped;

use super::Counters;
use super::stages::{RemoteQueue, Stages};
use crate::backend::StartError;
use crate::config::Profile;
use crate::flow::{RemoteFeed, RemoteQueries};
use crate::occupancy::LatestOccupancy;
use crate::zenoh::ZenohSession;

/// What the off-robot stages share with the rest of the pipeline: the query service's intake,
/// the occupancy thread's newest map, and the process's Zenoh session (`None` when nothing
/// needs one).
pub(super) type Shared = (RemoteQueries, Option<Arc<LatestOccupancy>>, Option<ZenohSession>);

/// The Zenoh stage (`[zenoh] enabled`, on the process's session) and the ROS output (a topic of `[ros2.out]` on), each
/// started once its session is open; the publisher's feed of both (`None` with neither).
#[cfg(feature = "zenoh")]
pub(super) fn stages(
    stages: &mut Stages,
    profile: &Profile,
    source_kind: SourceKind,
    (zenoh_queue, ros2_queue): (Option<RemoteQueue>, Option<RemoteQueue>),
    counters: &Counters,
    (queries, occupancy, session): Shared,
    stop: &Arc<AtomicBool>,
) -> Result<Option<RemoteFeed>, StartError> {
    use super::zenoh_stages;
    use crate::queue::Latest;

    let mut remote = match (zenoh_queue, counters.zenoh.as_ref(), session) {
        (Some(queue), Some(zenoh), Some(session)) => {
            let shared = (queries, occupancy.clone(), session);
            Some(zenoh_stages::zenoh(stages, profile, source_kind, queue, zenoh, shared)?)
        }
        _ => None,
    };
    if let Some(queue) = ros2_queue {
        let map = if profile.ros2.out.occupancy { occupancy } else { None };
        let graphs = zenoh_stages::ros2_out(stages, profile, queue, counters, (map, stop))?;
        let feed = remote.get_or_insert_with(|| RemoteFeed { graphs: Vec::new(), health: Arc::new(Latest::new()) });
        feed.graphs.push(graphs);
    }
    Ok(remote)
}

/// Without the feature `zenoh`: no off-robot stage (the profile could not turn one on).
#[cfg(not(feature = "zenoh"))]
pub(super) fn stages(
    _stages: &mut Stages,
    _profile: &Profile,
    _source_kind: SourceKind,
    _queues: (Option<RemoteQueue>, Option<RemoteQueue>),
    _counters: &Counters,
    _shared: Shared,
    _stop: &Arc<AtomicBool>,
) -> Result<Option<RemoteFeed>, StartError> {
    Ok(None)
}

/// The tf input (`pose.source = "ros2"`), started once its session is open and subscribed; the
/// sender the keyframe gate's thread keeps while it runs (`None` for other pose sources).
#[cfg(feature = "zenoh")]
pub(super) fn tf_input(
    stages: &mut Stages,
    profile: &Profile,
    source: &dyn FrameSource,
    poses: Sender<PoseStamped>,
    counters: &Counters,
    stop: &Arc<AtomicBool>,
) -> Result<Option<Sender<()>>, StartError> {
    if profile.pose.source != crate::keyframe::PoseSourceKind::Ros2 {
        return Ok(None);
    }
    let upright = source.camera_from_upright();
    super::zenoh_stages::ros2_tf(stages, profile, upright, poses, counters, stop).map(Some)
}

/// Without the feature `zenoh`: no tf input (the profile could not ask for one).
#[cfg(not(feature = "zenoh"))]
pub(super) fn tf_input(
    _stages: &mut Stages,
    _profile: &Profile,
    _source: &dyn FrameSource,
    _poses: Sender<PoseStamped>,
    _counters: &Counters,
    _stop: &Arc<AtomicBool>,
) -> Result<Option<Sender<()>>, StartError> {
    Ok(None)
}
