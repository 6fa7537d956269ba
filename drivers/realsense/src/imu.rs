//! The D435i's IMU (`source.realsense.imu = true`): gyro and accelerometer samples, stamped on
//! the frames' clock, kept in a bounded buffer that other threads read.
//!
//! **Where the samples go.** [`ImuBuffer`] holds the newest [`IMU_BUFFER_LEN`] samples (5 s or
//! more of the D435i's gyro at 200 Hz with its accelerometer at 100 or 200 Hz); when it is full the oldest is
//! dropped and counted ([`ImuBuffer::dropped`]). The source fills it from its capture thread
//! ([`crate::RealsenseSource::imu`] hands out the shared buffer); the runtime backend passes it
//! on as the opened source's side channel (`OpenedSource::side_channel`, an
//! `Arc<ImuBuffer>`), the place the runtime keeps a source's extra data for the stages that know
//! its type. The MCAP recorder and health do not carry IMU samples (yet).
//!
//! **Every sample, on a queue of their own.** librealsense's pipeline would hand over only the
//! newest gyro and accelerometer frame with each frame set (at 200 Hz against 30 Hz video most
//! samples lost), so the motion streams stay out of the pipeline: at the first frame set the
//! source opens the device's motion sensor (gyro and accelerometer at the lowest rate each
//! offers: the D435i's 200 Hz and 63 or 100 Hz) on a librealsense frame queue of its own and
//! moves what it holds into the buffer at every `next_frame`. Samples taken before that first
//! frame set are not seen; a camera or recording without motion streams is an error naming
//! `source.realsense.imu`. Playing a `.bag` in real time, librealsense's playback itself skips a
//! motion frame now and then when its reading thread is late; `bag_real_time = false` delivers
//! every one (the playback test checks that every recorded sample from the first delivered on
//! comes through exactly).
//!
//! **Units and axes** as librealsense delivers them: gyro in rad/s, accelerometer in m/s², in
//! the IMU's axes (`rs2_motion_frame`; on the D435i x right, y down, z forward, like the depth
//! camera, and at rest the accelerometer reads about `(0, -9.81, 0)`: it measures the reaction
//! to gravity). `rotate` does not turn them. Stamps follow the frames' rule: librealsense global
//! time on a live camera (host clock, ns since the Unix epoch), the recorded stamps in playback.

use std::collections::VecDeque;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

/// Samples kept: 5 s or more of a D435i's gyro and accelerometer together.
pub const IMU_BUFFER_LEN: usize = 2048;

/// Which sensor a sample is from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MotionKind {
    /// Angular velocity, rad/s.
    Gyro,
    /// Linear acceleration (reaction to gravity included), m/s².
    Accel,
}

/// One IMU sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// When it was taken, ns, on the frames' clock.
    pub stamp_ns: u64,
    /// The sensor.
    pub kind: MotionKind,
    /// x, y, z in the IMU's axes (rad/s or m/s²).
    pub xyz: [f32; 3],
}

/// The newest samples, shared between the capture thread and readers.
#[derive(Debug)]
pub struct ImuBuffer {
    samples: Mutex<VecDeque<ImuSample>>,
    capacity: usize,
    received: AtomicU64,
    dropped: AtomicU64,
}

impl ImuBuffer {
    /// A buffer of `capacity` samples (at least 1), allocated now.
    pub fn new(capacity: usize) -> Self {
        let capacity = capacity.max(1);
        Self {
            samples: Mutex::new(VecDeque::with_capacity(capacity)),
            capacity,
            received: AtomicU64::new(0),
            dropped: AtomicU64::new(0),
        }
    }

    /// Adds a sample, dropping (and counting) the oldest when full; never allocates.
    pub fn push(&self, sample: ImuSample) {
        self.received.fetch_add(1, Ordering::Relaxed);
        let mut samples = self.samples.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        if samples.len() == self.capacity {
            samples.pop_front();
            self.dropped.fetch_add(1, Ordering::Relaxed);
        }
        samples.push_back(sample);
    }

    /// Moves every buffered sample, oldest first, to the end of `out`.
    pub fn drain_into(&self, out: &mut Vec<ImuSample>) {
        let mut samples = self.samples.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        out.extend(samples.drain(..));
    }

    /// The newest sample of `kind` still buffered.
    pub fn latest(&self, kind: MotionKind) -> Option<ImuSample> {
        let samples = self.samples.lock().unwrap_or_else(std::sync::PoisonError::into_inner);
        samples.iter().rev().find(|s| s.kind == kind).copied()
    }

    /// Samples received since start.
    pub fn received(&self) -> u64 {
        self.received.load(Ordering::Relaxed)
    }

    /// Samples dropped unread because the buffer was full.
    pub fn dropped(&self) -> u64 {
        self.dropped.load(Ordering::Relaxed)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(k: u64) -> ImuSample {
        ImuSample {
            stamp_ns: k,
            kind: if k.is_multiple_of(2) { MotionKind::Gyro } else { MotionKind::Accel },
            xyz: [k as f32; 3],
        }
    }

    #[test]
    fn keeps_the_newest_and_counts_what_it_drops() {
        let buffer = ImuBuffer::new(3);
        for k in 0..5 {
            buffer.push(sample(k));
        }
        assert_eq!((buffer.received(), buffer.dropped()), (5, 2));
        assert_eq!(buffer.latest(MotionKind::Gyro), Some(sample(4)));
        assert_eq!(buffer.latest(MotionKind::Accel), Some(sample(3)));
        let mut out = Vec::new();
        buffer.drain_into(&mut out);
        assert_eq!(out, [sample(2), sample(3), sample(4)]);
        buffer.drain_into(&mut out);
        assert_eq!(out.len(), 3, "drained");
        assert_eq!(buffer.latest(MotionKind::Gyro), None);
    }
}
