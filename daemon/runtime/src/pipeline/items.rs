//! What travels on the pipeline's queues between the stage threads.

use std::time::{Duration, Instant};

use op3dsg_drivers::frame::PooledFrame;
use op3dsg_drivers::pose::Isometry;

use crate::graph::SceneGraph;
use crate::perception::Detection;

/// How long a stage waits on an empty queue before it checks the stop flag again.
pub(crate) const POLL: Duration = Duration::from_millis(20);

/// A frame as the source delivered it, with the moment it was delivered (the start of the
/// `end_to_end` latency).
pub(crate) struct CapturedFrame {
    pub(crate) frame: PooledFrame,
    pub(crate) captured_at: Instant,
}

pub(crate) struct KeyframeItem {
    pub(crate) frame: PooledFrame,
    pub(crate) captured_at: Instant,
    pub(crate) world_from_camera: Isometry,
}

pub(crate) struct DetectionBatch {
    pub(crate) ticket: u64,
    pub(crate) frame: PooledFrame,
    pub(crate) captured_at: Instant,
    pub(crate) world_from_camera: Isometry,
    pub(crate) detections: Vec<Detection>,
}

/// A graph version for the publisher, with the capture moment of the newest keyframe fused into
/// it (`None` before the first keyframe).
pub(crate) struct GraphItem {
    pub(crate) graph: SceneGraph,
    pub(crate) newest_capture: Option<Instant>,
}
