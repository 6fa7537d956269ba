//! What travels on the pipeline's queues between the stage threads: frames as captured,
//! keyframes with their pose, each keyframe's detections, and graph versions. A leaf above
//! `graph`: it imports nothing of the stages.
//!
//! ```text
//! capture ──CapturedFrame──► keyframe gate ──KeyframeItem──► detect/i ──DetectionBatch──► fusion ──GraphItem──► publish
//! ```

use std::sync::Arc;
use std::time::{Duration, Instant};

use crossbeam_channel::Sender;
use op3dsg_drivers::frame::PooledFrame;
use op3dsg_drivers::pose::Isometry;
use op3dsg_ipc_types::{Health, PoseStamped, QueryRequest, QueryResponse};
use tracing::warn;

mod detection;
mod live;

pub use detection::{Detection, Mask};
pub use live::{LiveFeed, LiveImages, LiveIntake, live_feed};

use crate::graph::SceneGraph;
use crate::queue::{Latest, QueueSender};
use crate::stats::PoseStats;

/// How long a stage waits on an empty queue before it checks the stop flag again.
pub const POLL: Duration = Duration::from_millis(20);

/// A frame as the source delivered it, with the moment it was delivered (the start of the
/// `end_to_end` latency).
#[derive(Debug)]
pub struct CapturedFrame {
    /// The frame, in a buffer of the frame pool.
    pub frame: PooledFrame,
    /// When the source delivered it.
    pub captured_at: Instant,
}

/// A keyframe: a frame the gate accepted, with its pose.
#[derive(Debug)]
pub struct KeyframeItem {
    /// The frame.
    pub frame: PooledFrame,
    /// When the source delivered it.
    pub captured_at: Instant,
    /// Its pose.
    pub world_from_camera: Isometry,
}

/// A keyframe's detections, with the ticket that orders results for fusion.
#[derive(Debug)]
pub struct DetectionBatch {
    /// The keyframe's place in the order workers took keyframes (gapless).
    pub ticket: u64,
    /// The keyframe.
    pub frame: PooledFrame,
    /// When the source delivered it.
    pub captured_at: Instant,
    /// Its pose.
    pub world_from_camera: Isometry,
    /// What the worker's detector found (empty when it failed).
    pub detections: Vec<Detection>,
}

/// The newest graph the publisher sent, with the sending daemon's instance id: the query
/// worker's input (latest wins; a copy per version, made on the publisher thread).
pub type LatestGraph = Latest<(Arc<SceneGraph>, u64)>;

/// The publisher's hand-over to the off-robot stage (`crate::zenoh`): every graph version it
/// sent, with the daemon's instance id, on a bounded latest-wins queue (a slow network drops
/// versions there, counted, and never holds the publisher), and the newest health record with
/// the instance id in a slot.
#[derive(Debug, Clone)]
pub struct RemoteFeed {
    /// Graph versions as sent, with the instance id: one latest-wins queue per stage that takes
    /// them (Zenoh, the ROS output).
    pub graphs: Vec<QueueSender<(Arc<SceneGraph>, u64)>>,
    /// The newest health record and the instance id.
    pub health: Arc<Latest<(Health, u64)>>,
}

/// Where the answer to a query from off the computer goes: called once, on the query worker's
/// thread (or at once, by whoever refuses the request); it must not block.
pub type RemoteReply = Box<dyn FnOnce(&QueryResponse) + Send>;

/// How the off-robot stage hands a query to the language query service (`crate::query`): the
/// request and where its answer goes. Never blocks: a request the service cannot take now is
/// answered at once (busy, bad request, encoder off).
pub type RemoteQuerySubmit = Box<dyn Fn(QueryRequest, RemoteReply) + Send + Sync>;

/// The query service's intake for the off-robot stage, filled once the service has started
/// (the off-robot stage starts first); empty for good with `query.enabled = false`.
pub type RemoteQueries = Arc<std::sync::OnceLock<RemoteQuerySubmit>>;

/// A graph version for the publisher, with the capture moment of the newest keyframe fused into
/// it (`None` before the first keyframe).
#[derive(Debug)]
pub struct GraphItem {
    /// The version.
    pub graph: SceneGraph,
    /// When the newest keyframe in it was captured.
    pub newest_capture: Option<Instant>,
}

/// Hands a pose (`what`: received live, or recorded) to the keyframe gate without waiting. The
/// gate drains the hand-over every frame; when it is full the pose is dropped and counted in
/// `pose.queue_full` (losing the newest is acceptable too), with a warning at powers of two.
/// Returns false once the gate has ended (nothing is counted then).
pub fn hand_over_pose(tx: &Sender<PoseStamped>, pose: PoseStamped, stats: &PoseStats, what: &str) -> bool {
    match tx.try_send(pose) {
        Ok(()) => true,
        Err(crossbeam_channel::TrySendError::Full(_)) => {
            let dropped = stats.queue_full.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
            if dropped.is_power_of_two() {
                warn!(dropped, "pose hand-over queue to the keyframe gate full; {what} dropped");
            }
            true
        }
        Err(crossbeam_channel::TrySendError::Disconnected(_)) => false,
    }
}
