//! The stages that speak Zenoh (feature `zenoh`): the Zenoh stage, the ROS output and the tf
//! input, each started once its session is open.

use std::sync::Arc;

use crossbeam_channel::Sender;
use op3dsg_drivers::source::SourceKind;
use op3dsg_ipc_types::PoseStamped;
use op3dsg_ros2::TfConfig;

use super::Counters;
use super::stages::{RemoteQueue, Stages};
use crate::backend::StartError;
use crate::config::Profile;
use crate::flow::{RemoteFeed, RemoteQueries};
use crate::graph::SceneGraph;
use crate::ipc::{GraphCapacity, GraphOrigin};
use crate::occupancy::LatestOccupancy;
use crate::queue::{Latest, QueueSender};
use crate::ros2::{Ros2OutputThread, TfInputThread};
use crate::zenoh::{ZenohCounters, ZenohSession, ZenohThread};

/// The Zenoh stage (`[zenoh] enabled`) on the process's session, started once its keys are
/// declared; returns the publisher's end of its hand-over.
pub(super) fn zenoh(
    stages: &mut Stages,
    profile: &Profile,
    source_kind: SourceKind,
    queue: RemoteQueue,
    counters: &Arc<ZenohCounters>,
    (queries, occupancy, session): (RemoteQueries, Option<Arc<LatestOccupancy>>, ZenohSession),
) -> Result<RemoteFeed, StartError> {
    let (ready, ready_rx) = crossbeam_channel::bounded(1);
    let (graphs_tx, graphs_rx) = queue;
    let health = Arc::new(Latest::new());
    let thread = ZenohThread {
        config: profile.zenoh.clone(),
        session,
        capacity: GraphCapacity { max_nodes: profile.ipc.max_nodes, max_edges: profile.ipc.max_edges },
        origin: GraphOrigin::new(source_kind, &profile.world.frame_id),
        graphs: graphs_rx,
        health: health.clone(),
        occupancy,
        queries,
        counters: counters.clone(),
        ready,
    };
    stages.spawn("zenoh", move || thread.run())?;
    match ready_rx.recv() {
        Ok(Ok(())) => Ok(RemoteFeed { graphs: vec![graphs_tx], health }),
        Ok(Err(reason)) => Err(StartError::Zenoh(reason)),
        Err(_) => Err(StartError::Zenoh("zenoh: the thread ended during start-up".to_owned())),
    }
}

/// The ROS output (a topic of `[ros2.out]` on), started once its session is open and its
/// publishers declared; returns the publisher's end of its hand-over.
pub(super) fn ros2_out(
    stages: &mut Stages,
    profile: &Profile,
    queue: RemoteQueue,
    counters: &Counters,
    (occupancy, stop): (Option<Arc<LatestOccupancy>>, &Arc<std::sync::atomic::AtomicBool>),
) -> Result<QueueSender<(Arc<SceneGraph>, u64)>, StartError> {
    let Some(out_counters) = counters.ros2_out.clone() else {
        return Err(StartError::Zenoh("ros2: the output has no counters".to_owned()));
    };
    let (ready, ready_rx) = crossbeam_channel::bounded(1);
    let (graphs_tx, graphs_rx) = queue;
    let thread = Ros2OutputThread {
        config: profile.ros2.clone(),
        world_frame: ros2_world_frame(profile),
        up_axis: profile.world.up_axis,
        source: "op3dsgd".to_owned(),
        graphs: graphs_rx,
        occupancy,
        counters: out_counters,
        stop: stop.clone(),
        ready,
    };
    stages.spawn("ros2-out", move || thread.run())?;
    match ready_rx.recv() {
        Ok(Ok(())) => Ok(graphs_tx),
        Ok(Err(reason)) => Err(StartError::Zenoh(reason)),
        Err(_) => Err(StartError::Zenoh("ros2: the output thread ended during start-up".to_owned())),
    }
}

/// The frame ROS sees the map in: `ros2.tf.world_frame`, or `world.frame_id`.
fn ros2_world_frame(profile: &Profile) -> String {
    match profile.ros2.tf.world_frame.as_str() {
        "" => profile.world.frame_id.clone(),
        frame => frame.to_owned(),
    }
}

/// The tf input (`pose.source = "ros2"`), started once its session is open and subscribed;
/// returns the sender the keyframe gate's thread keeps while it runs (the tf thread ends with it).
pub(super) fn ros2_tf(
    stages: &mut Stages,
    profile: &Profile,
    camera_from_upright: op3dsg_drivers::pose::Isometry,
    poses: Sender<PoseStamped>,
    counters: &Counters,
    stop: &Arc<std::sync::atomic::AtomicBool>,
) -> Result<Sender<()>, StartError> {
    let Some(tf_counters) = counters.ros2_tf.clone() else {
        return Err(StartError::Zenoh("ros2: the tf input has no counters".to_owned()));
    };
    let (ready, ready_rx) = crossbeam_channel::bounded(1);
    let (alive_tx, alive_rx) = crossbeam_channel::bounded(0);
    let pose = &profile.pose;
    let ms = |v: f64| (v * 1e6) as u64;
    let thread = TfInputThread {
        config: profile.ros2.clone(),
        world_frame: ros2_world_frame(profile),
        camera_from_upright,
        buffer: TfConfig {
            window_ns: (profile.ros2.tf.window_s * 1e9) as u64,
            max_interpolation_gap_ns: ms(pose.max_interpolation_gap_ms),
            hold_tolerance_ns: ms(pose.tolerance_ms),
            ..TfConfig::default()
        },
        poses,
        pose_stats: counters.keyframe.pose.clone(),
        counters: tf_counters,
        stop: stop.clone(),
        gate_alive: alive_rx,
        ready,
    };
    stages.spawn("ros2-tf", move || thread.run())?;
    match ready_rx.recv() {
        Ok(Ok(())) => Ok(alive_tx),
        Ok(Err(reason)) => Err(StartError::Zenoh(reason)),
        Err(_) => Err(StartError::Zenoh("ros2: the tf thread ended during start-up".to_owned())),
    }
}
