//! The pose input's counters: every received pose counted once, under its outcome.

use std::sync::atomic::{AtomicU64, Ordering};

use op3dsg_ipc_types::PoseHealth;

/// The pose input's counters, one per outcome ([`PoseHealth`] documents each). The publisher
/// thread adds the wire-check counts (it checks every received pose), the keyframe thread the
/// gate's outcomes, whoever hands a pose to the gate `queue_full`.
#[derive(Debug, Default)]
pub struct PoseStats {
    /// Adopted by the keyframe gate.
    pub accepted: AtomicU64,
    /// Unknown `kind`.
    pub unknown_kind: AtomicU64,
    /// NaN or infinite components.
    pub non_finite: AtomicU64,
    /// Quaternion norm off 1.
    pub non_unit_quaternion: AtomicU64,
    /// `world_from_base` without `pose.base_from_camera`.
    pub no_base_from_camera: AtomicU64,
    /// Older than the newest adopted pose.
    pub out_of_order: AtomicU64,
    /// Older than the newest frame by more than the tolerance.
    pub stale: AtomicU64,
    /// Too far after the newest frame.
    pub future: AtomicU64,
    /// Hand-over queue to the gate full.
    pub queue_full: AtomicU64,
    /// tf: no chain between the world and camera frames.
    pub no_transform_path: AtomicU64,
    /// tf: the world or camera frame unknown.
    pub frame_not_found: AtomicU64,
    /// tf: a link without transforms around the stamp.
    pub extrapolation: AtomicU64,
}

impl PoseStats {
    /// The wire form.
    pub fn health(&self) -> PoseHealth {
        let load = |c: &AtomicU64| c.load(Ordering::Relaxed);
        PoseHealth {
            accepted: load(&self.accepted),
            unknown_kind: load(&self.unknown_kind),
            non_finite: load(&self.non_finite),
            non_unit_quaternion: load(&self.non_unit_quaternion),
            no_base_from_camera: load(&self.no_base_from_camera),
            out_of_order: load(&self.out_of_order),
            stale: load(&self.stale),
            future: load(&self.future),
            queue_full: load(&self.queue_full),
            no_transform_path: load(&self.no_transform_path),
            frame_not_found: load(&self.frame_not_found),
            extrapolation: load(&self.extrapolation),
        }
    }
}
