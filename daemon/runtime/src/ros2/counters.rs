//! The ROS 2 stages' figures, in every build (health reads them; without the feature `zenoh` the
//! stages never run and the counters stay absent).

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, PoisonError};

use op3dsg_ipc_types::{TfHealth, write_fixed_str};
use op3dsg_ros2::TfPath;

use crate::stats::StageStats;

/// The ROS output's figures.
#[derive(Debug)]
pub struct Ros2OutputCounters {
    /// The stage `ros2_out`: one graph version or map encoded and put; a failed put is an error.
    pub stage: Arc<StageStats>,
    /// `MarkerArray` messages put.
    pub marker_arrays: AtomicU64,
    /// `OccupancyGrid` messages put.
    pub occupancy_grids: AtomicU64,
    /// Graph JSON messages put.
    pub graph_jsons: AtomicU64,
    /// Bytes put, every topic.
    pub bytes: AtomicU64,
}

impl Default for Ros2OutputCounters {
    fn default() -> Self {
        Self {
            stage: Arc::new(StageStats::new("ros2_out")),
            marker_arrays: AtomicU64::new(0),
            occupancy_grids: AtomicU64::new(0),
            graph_jsons: AtomicU64::new(0),
            bytes: AtomicU64::new(0),
        }
    }
}

/// The tf input's figures (besides the pose counters it shares with the gate).
#[derive(Debug)]
pub struct TfInputCounters {
    /// The stage `ros2_tf`: one tf message decoded and applied; payloads that are not a
    /// TFMessage are its errors.
    pub stage: Arc<StageStats>,
    /// `/tf` messages received.
    pub dynamic_messages: AtomicU64,
    /// `/tf_static` messages received.
    pub static_messages: AtomicU64,
    /// Transforms refused by the buffer for other reasons than non-finite values or quaternions
    /// (an empty frame id, a frame its own parent, a repeated or too old stamp, too many frames).
    pub transforms_refused: AtomicU64,
    /// Payloads dropped because the thread was behind.
    pub intake_dropped: AtomicU64,
    /// Poses handed to the keyframe gate (a full hand-over counts in `pose.queue_full` too).
    pub poses: AtomicU64,
    /// `/tf` messages stamped wholly before the window of what was held: tf's time went back and
    /// the dynamic transforms were cleared.
    pub time_jumps: AtomicU64,
    /// The chain of the last successful lookup.
    pub last_path: Mutex<Option<TfPath>>,
}

impl TfInputCounters {
    /// The health record's `tf` entry.
    pub fn health(&self) -> TfHealth {
        let mut h = TfHealth {
            active: 1,
            dynamic_messages: self.dynamic_messages.load(Ordering::Relaxed),
            static_messages: self.static_messages.load(Ordering::Relaxed),
            transforms_refused: self.transforms_refused.load(Ordering::Relaxed),
            time_jumps: self.time_jumps.load(Ordering::Relaxed),
            ..TfHealth::default()
        };
        if let Some(path) = self.last_path.lock().unwrap_or_else(PoisonError::into_inner).as_ref() {
            let text = path.frames.iter().rev().map(String::as_str).collect::<Vec<_>>().join(" -> ");
            if !write_fixed_str(&mut h.path, &text) {
                let keep = h.path.len() - 3;
                write_fixed_str(&mut h.path[..keep], &text);
                let end = h.path.iter().position(|&b| b == 0).unwrap_or(keep);
                h.path[end..end + 3].copy_from_slice(b"...");
            }
            h.lookup_stamp_ns = path.stamp_ns;
            h.newest_data_ns = path.newest_data_ns.unwrap_or(0);
        }
        h
    }
}

impl Default for TfInputCounters {
    fn default() -> Self {
        Self {
            stage: Arc::new(StageStats::new("ros2_tf")),
            dynamic_messages: AtomicU64::new(0),
            static_messages: AtomicU64::new(0),
            transforms_refused: AtomicU64::new(0),
            intake_dropped: AtomicU64::new(0),
            poses: AtomicU64::new(0),
            time_jumps: AtomicU64::new(0),
            last_path: Mutex::new(None),
        }
    }
}
