//! One frame set into the pooled frame: the set's depth and colour looked up, the first set's
//! device handle taken (playback pacing, the motion sensor), repeated or mismatched sets passed
//! over, colour copied and depth aligned (or copied) with the rotation on the way, the frame
//! stamped.

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::source::{SourceError, SourceStatus};
use realsense_rust::frame::{ColorFrame, CompositeFrame, DepthFrame, FrameEx};
use realsense_rust::kind::{Rs2FrameMetadata, Rs2TimestampDomain};
use tracing::warn;

use super::ffi::{DeviceHandle, FrameSet, image_bytes};
use super::streams::units_per_m;
use super::{RealsenseSource, device_err, source_name};
use crate::rotate::{SourceLayout, copy_colour, copy_depth};

impl RealsenseSource {
    pub(super) fn fill(&mut self, set: CompositeFrame, frame: &mut Frame) -> Result<SourceStatus, SourceError> {
        // (The source's name is made only for messages: no allocation per frame for it.)
        let set = FrameSet::new(set);
        let depth = set.first::<DepthFrame>();
        let colour = set.first::<ColorFrame>();
        let (Some(depth), Some(colour)) = (depth, colour) else {
            return Err(device_err(format!("{}: frame set without depth and colour", self.name())));
        };
        if !self.received_any {
            self.received_any = true;
            self.take_device(&set)?;
        }
        let numbers = (depth.frame_number(), colour.frame_number());
        let repeated = self.last_numbers.is_some_and(|(d, c)| numbers.0 == d || numbers.1 == c);
        let apart_ms = (depth.timestamp() - colour.timestamp()).abs();
        if repeated || apart_ms > self.streams.half_period_ms {
            self.repeated_sets += 1;
            tracing::trace!(depth = numbers.0, colour = numbers.1, apart_ms, "frame set passed over");
            return Ok(SourceStatus::Pending);
        }
        self.last_numbers = Some(numbers);
        let k = self.streams.colour;
        let (w, h) = (k.width as usize, k.height as usize);
        let (depth_what, dw, dh) = match &self.aligner {
            Some(aligner) => ("depth", aligner.depth().width as usize, aligner.depth().height as usize),
            None => ("aligned depth", w, h),
        };
        for (what, fw, fh, sw, sh) in
            [("colour", colour.width(), colour.height(), w, h), (depth_what, depth.width(), depth.height(), dw, dh)]
        {
            if (fw, fh) != (sw, sh) {
                return Err(SourceError::Frame {
                    seq: self.seq,
                    reason: format!("{}: {what} frame is {fw}x{fh}, the stream is {sw}x{sh}", self.name()),
                });
            }
        }
        if !self.delivered_any
            && let Ok(units) = depth.depth_units()
            && units > 0.0
        {
            self.streams.depth_units_per_m = units_per_m(units);
            if let Some(aligner) = &mut self.aligner {
                aligner.set_metres_per_unit(units);
            }
        }
        // (The source's fields it names, apart from the aligner written below.)
        let (seq, bag, serial) = (self.seq, self.bag.as_deref(), self.serial.as_str());
        let copy_err = |e: crate::rotate::CopyError| SourceError::Frame {
            seq,
            reason: format!("{}: {e}", source_name(bag, serial)),
        };
        let (colour_bytes, depth_bytes) = (image_bytes(&colour), image_bytes(&depth));
        copy_colour(
            colour_bytes,
            SourceLayout { width: w, height: h, stride_bytes: colour.stride() },
            self.streams.colour_order,
            self.rotation,
            &mut frame.rgb,
        )
        .map_err(copy_err)?;
        let depth_layout = SourceLayout { width: dw, height: dh, stride_bytes: depth.stride() };
        match &mut self.aligner {
            Some(aligner) => aligner.align(depth_bytes, depth_layout, self.rotation, &mut frame.depth),
            None => copy_depth(depth_bytes, depth_layout, self.rotation, &mut frame.depth),
        }
        .map_err(copy_err)?;
        let stamp_ms = self.stamp_ms(&colour);
        frame.seq = self.seq;
        frame.stamp_ns = (stamp_ms * 1e6).round().max(0.0) as u64;
        frame.intrinsics = self.intrinsics;
        frame.depth_units_per_m = self.streams.depth_units_per_m;
        frame.world_from_camera = self.world_from_camera;
        self.seq += 1;
        self.delivered_any = true;
        Ok(SourceStatus::Frame)
    }

    /// The device behind the first frame set received (delivered or passed over): playback
    /// pacing and its end, the motion sensor.
    fn take_device(&mut self, set: &FrameSet) -> Result<(), SourceError> {
        if (self.bag.is_some() || self.imu.is_some())
            && let Some(first) = set.first::<DepthFrame>()
        {
            match DeviceHandle::from_frame(first) {
                Ok(device) => {
                    if self.imu.is_some() {
                        self.open_motion(&device)?;
                    }
                    if self.bag.is_some() {
                        match device.set_real_time(self.config.bag_real_time) {
                            Ok(()) => self.playback = Some(device),
                            Err(e) => {
                                warn!(bag = %self.name(), error = %e, "cannot control playback pacing; playing in real time")
                            }
                        }
                    }
                }
                Err(e) => {
                    warn!(source = %self.name(), error = %e, "no device handle behind the first frame: no playback pacing, no IMU")
                }
            }
        }
        Ok(())
    }

    /// The frame's stamp, milliseconds: librealsense's global (or system) time, a recording's
    /// own stamps, else the host arrival time (the camera's hardware clock is no host clock).
    fn stamp_ms(&mut self, colour: &ColorFrame) -> f64 {
        match colour.timestamp_domain() {
            Rs2TimestampDomain::GlobalTime | Rs2TimestampDomain::SystemTime => colour.timestamp(),
            _ if self.bag.is_some() => colour.timestamp(),
            _ => {
                if !self.warned_hardware_clock {
                    self.warned_hardware_clock = true;
                    warn!(camera = %self.name(), "frames are stamped by the camera's hardware clock, not global time: using the host arrival time instead (update the firmware)");
                }
                colour.metadata(Rs2FrameMetadata::TimeOfArrival).map_or_else(|| colour.timestamp(), |ms| ms as f64)
            }
        }
    }
}
