//! The IMU (`imu = true`): the device's motion sensor on a queue of its own, drained into the
//! [`ImuBuffer`] at every frame set.
//!
//! librealsense's pipeline would hand over only the newest gyro and accelerometer frame with
//! each frame set (most samples lost at 200 Hz against 30 Hz video), so the motion streams stay
//! out of the pipeline and every sample comes through this queue instead.

use op3dsg_drivers::source::SourceError;
use realsense_rust::frame::FrameEx;
use realsense_rust::kind::{Rs2FrameMetadata, Rs2StreamKind, Rs2TimestampDomain};
use tracing::info;

use super::RealsenseSource;
use super::ffi::{DeviceHandle, MotionSensor};
use crate::imu::{ImuBuffer, ImuSample, MotionKind};

/// Motion frames the motion sensor's queue holds (librealsense drops the oldest beyond): over
/// 3 s of the D435i's gyro and accelerometer at their lowest rates, drained at every frame.
const MOTION_QUEUE_LEN: i32 = 1024;

impl RealsenseSource {
    /// Opens the motion sensor of `device` on its own queue (`imu = true`); a camera or
    /// recording without gyro and accelerometer streams is an error naming the key.
    pub(super) fn open_motion(&mut self, device: &DeviceHandle) -> Result<(), SourceError> {
        let motion = MotionSensor::open(device, MOTION_QUEUE_LEN)
            .map_err(|e| SourceError::Config(format!("source.realsense.imu = true, but {}: {e}", self.name())))?;
        info!(source = %self.name(), gyro_hz = motion.rates_hz()[0], accel_hz = motion.rates_hz()[1], "IMU streaming on its own queue");
        self.motion = Some(motion);
        Ok(())
    }
}

/// Moves every motion frame `motion`'s queue holds into `imu`; how many.
pub(super) fn drain(motion: &MotionSensor, imu: &ImuBuffer, playback: bool) -> usize {
    let mut taken = 0;
    while let Some(frame) = motion.poll() {
        let kind = match frame.stream_profile().kind() {
            Rs2StreamKind::Gyro => MotionKind::Gyro,
            Rs2StreamKind::Accel => MotionKind::Accel,
            _ => continue,
        };
        // (Gyro and accelerometer frames share one layout: three f32.)
        imu.push(ImuSample { stamp_ns: host_stamp_ns(&frame, playback), kind, xyz: *frame.rotational_velocity() });
        taken += 1;
    }
    taken
}

/// A frame's stamp in ns on the frames' clock: global (or system) time as delivered, a
/// recording's as recorded, else the host arrival time.
fn host_stamp_ns(frame: &impl FrameEx, playback: bool) -> u64 {
    let ms = match frame.timestamp_domain() {
        Rs2TimestampDomain::GlobalTime | Rs2TimestampDomain::SystemTime => frame.timestamp(),
        _ if playback => frame.timestamp(),
        _ => frame.metadata(Rs2FrameMetadata::TimeOfArrival).map_or_else(|| frame.timestamp(), |ms| ms as f64),
    };
    (ms * 1e6).round().max(0.0) as u64
}
