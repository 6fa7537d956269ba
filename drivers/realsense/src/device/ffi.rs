//! librealsense's C API where `realsense-rust` stops short: the raw handles the source needs
//! (the device behind a frame for playback pacing, the motion sensor on a queue of its own, the
//! align block as a handle the capture thread may own), the frame-set lookup without an
//! allocation per frame, and the borrowing of a frame's pixels.
//!
//! Every `realsense-sys` call, raw pointer and borrowed buffer of the source is here, each behind
//! a safe wrapper the rest of the source calls: the only file of [`super`] that uses `unsafe`.

#![allow(unsafe_code)] // FFI: librealsense's handles and buffers, each use argued where it is.

use std::ffi::CStr;
use std::ptr::NonNull;
use std::time::Duration;

use realsense_rust::frame::{CompositeFrame, DepthFrame, FrameCategory, FrameEx, GyroFrame, ImageFrame};
use realsense_rust::kind::Rs2StreamKind;
use realsense_rust::processing_blocks::align::Align;
use realsense_rust::processing_blocks::errors::{ProcessFrameError, ProcessingBlockConstructionError};
use realsense_sys as sys;

/// The message of a librealsense error, freeing it.
fn take_error(err: *mut sys::rs2_error) -> Option<String> {
    if err.is_null() {
        return None;
    }
    // SAFETY: a non-null error from librealsense; its message lives until rs2_free_error.
    unsafe {
        let message = CStr::from_ptr(sys::rs2_get_error_message(err)).to_string_lossy().into_owned();
        sys::rs2_free_error(err);
        Some(message)
    }
}

/// librealsense's align block (`align = "librealsense"`), made per source.
pub(super) struct AlignBlock(Align);

// SAFETY: librealsense's processing blocks and their queues may be used from any thread;
// `realsense-rust` leaves `Align` without `Send` only because it holds raw pointers. The source
// that owns the block is used by one thread at a time (no `Sync`).
unsafe impl Send for AlignBlock {}

impl AlignBlock {
    /// An align block to the colour stream, its output queue holding one frame set.
    pub(super) fn to_colour() -> Result<Self, ProcessingBlockConstructionError> {
        Align::new(Rs2StreamKind::Color, 1).map(Self)
    }

    /// Hands `set` to the block.
    pub(super) fn queue(&mut self, set: CompositeFrame) -> Result<(), ProcessFrameError> {
        self.0.queue(set)
    }

    /// The aligned set, waiting up to `timeout` (the block runs on the calling thread).
    pub(super) fn wait(&mut self, timeout: Duration) -> Result<CompositeFrame, ProcessFrameError> {
        self.0.wait(timeout)
    }
}

/// A device handle made from a frame's sensor (realsense-rust has no playback control and no
/// raw device): the playback pacing and the motion sensor are reached through it.
pub(super) struct DeviceHandle(NonNull<sys::rs2_device>);

// SAFETY: librealsense's device handles may be used from any thread; the source that owns this
// one is used by one thread at a time (no `Sync`).
unsafe impl Send for DeviceHandle {}

impl Drop for DeviceHandle {
    fn drop(&mut self) {
        // SAFETY: made by rs2_create_device_from_sensor, owned here, deleted once.
        unsafe { sys::rs2_delete_device(self.0.as_ptr()) }
    }
}

impl DeviceHandle {
    /// The device a frame came from.
    pub(super) fn from_frame(frame: DepthFrame) -> Result<Self, String> {
        // SAFETY: the frame pointer is owned by us after get_owned_raw and released below; the
        // sensor handle is deleted after the device was made from it; every call checks `err`.
        unsafe {
            let raw = frame.get_owned_raw();
            let mut err = std::ptr::null_mut::<sys::rs2_error>();
            let sensor = sys::rs2_get_frame_sensor(raw.as_ptr(), &mut err);
            let device = if err.is_null() && !sensor.is_null() {
                let device = sys::rs2_create_device_from_sensor(sensor, &mut err);
                sys::rs2_delete_sensor(sensor);
                device
            } else {
                std::ptr::null_mut()
            };
            sys::rs2_release_frame(raw.as_ptr());
            match (take_error(err), NonNull::new(device)) {
                (None, Some(device)) => Ok(Self(device)),
                (Some(e), _) => Err(e),
                (None, None) => Err("no device behind the frame".to_owned()),
            }
        }
    }

    /// Sets a playback device's pacing: real time, or as fast as the reader takes frames.
    pub(super) fn set_real_time(&self, real_time: bool) -> Result<(), String> {
        let mut err = std::ptr::null_mut::<sys::rs2_error>();
        // SAFETY: a live device handle; the error is checked and freed.
        unsafe { sys::rs2_playback_device_set_real_time(self.0.as_ptr(), i32::from(real_time), &mut err) };
        take_error(err).map_or(Ok(()), Err)
    }

    /// Pauses a playback device: its reading thread finishes the read in hand and reads no
    /// further until resumed or stopped.
    pub(super) fn pause(&self) -> Result<(), String> {
        let mut err = std::ptr::null_mut::<sys::rs2_error>();
        // SAFETY: a live device handle; the error is checked and freed.
        unsafe { sys::rs2_playback_device_pause(self.0.as_ptr(), &mut err) };
        take_error(err).map_or(Ok(()), Err)
    }

    /// Whether a playback device has read its whole file.
    pub(super) fn stopped(&self) -> bool {
        let mut err = std::ptr::null_mut::<sys::rs2_error>();
        // SAFETY: a live device handle; the error is checked and freed.
        let status = unsafe { sys::rs2_playback_device_get_current_status(self.0.as_ptr(), &mut err) };
        take_error(err).is_none() && status == sys::rs2_playback_status_RS2_PLAYBACK_STATUS_STOPPED
    }
}

/// A device's motion sensor opened on a frame queue of its own: its gyro and accelerometer
/// streams, each at the lowest rate it offers (`MOTION_XYZ32F`), started into the queue.
pub(super) struct MotionSensor {
    sensor: NonNull<sys::rs2_sensor>,
    queue: NonNull<sys::rs2_frame_queue>,
    /// Gyro and accelerometer rates opened, Hz.
    rates_hz: [i32; 2],
}

// SAFETY: librealsense's sensor and frame-queue handles may be used from any thread; the source
// that owns this one is used by one thread at a time (no `Sync`).
unsafe impl Send for MotionSensor {}

impl Drop for MotionSensor {
    fn drop(&mut self) {
        let mut err = std::ptr::null_mut::<sys::rs2_error>();
        // SAFETY: the sensor was opened and started by `open`; stop and close it once, then free
        // the sensor and the queue (which releases the frames still in it). Errors are freed.
        unsafe {
            sys::rs2_stop(self.sensor.as_ptr(), &mut err);
            let _ = take_error(err);
            err = std::ptr::null_mut();
            sys::rs2_close(self.sensor.as_ptr(), &mut err);
            let _ = take_error(err);
            sys::rs2_delete_sensor(self.sensor.as_ptr());
            sys::rs2_delete_frame_queue(self.queue.as_ptr());
        }
    }
}

impl MotionSensor {
    /// Opens the gyro and accelerometer streams of `device` on a queue of `queue_len` frames
    /// (librealsense drops the oldest beyond) and starts them.
    pub(super) fn open(device: &DeviceHandle, queue_len: i32) -> Result<Self, String> {
        // SAFETY: every handle comes from librealsense and is checked for null and for an error
        // before use; lists are deleted after use, the chosen sensor is kept (and deleted in
        // Drop), the others are deleted; profile pointers are used while their list lives.
        unsafe {
            let mut err = std::ptr::null_mut::<sys::rs2_error>();
            let list = sys::rs2_query_sensors(device.0.as_ptr(), &mut err);
            if let Some(e) = take_error(err) {
                return Err(format!("cannot list the sensors: {e}"));
            }
            let Some(list) = NonNull::new(list) else { return Err("no sensor list".to_owned()) };
            let count = sys::rs2_get_sensors_count(list.as_ptr(), &mut err);
            let _ = take_error(err);
            let mut found = None;
            for i in 0..count {
                err = std::ptr::null_mut();
                let sensor = sys::rs2_create_sensor(list.as_ptr(), i, &mut err);
                if take_error(err).is_some() {
                    continue;
                }
                let Some(sensor) = NonNull::new(sensor) else { continue };
                match Self::try_start(sensor, queue_len) {
                    Ok(Some(motion)) => {
                        found = Some(Ok(motion));
                        break;
                    }
                    Ok(None) => sys::rs2_delete_sensor(sensor.as_ptr()),
                    Err(e) => {
                        sys::rs2_delete_sensor(sensor.as_ptr());
                        found = Some(Err(e));
                        break;
                    }
                }
            }
            sys::rs2_delete_sensor_list(list.as_ptr());
            found.unwrap_or_else(|| {
                Err("no sensor with gyro and accelerometer streams (a D435 without the i?)".to_owned())
            })
        }
    }

    /// Opens and starts `sensor` if it has gyro and accelerometer streams (`Ok(None)` if not);
    /// on success the sensor is owned by the result.
    ///
    /// # Safety
    /// `sensor` must be a live sensor handle.
    unsafe fn try_start(sensor: NonNull<sys::rs2_sensor>, queue_len: i32) -> Result<Option<Self>, String> {
        // SAFETY: as `open`'s; the profile list lives until the streams are opened.
        unsafe {
            let mut err = std::ptr::null_mut::<sys::rs2_error>();
            let profiles = sys::rs2_get_stream_profiles(sensor.as_ptr(), &mut err);
            if take_error(err).is_some() {
                return Ok(None);
            }
            let Some(profiles) = NonNull::new(profiles) else { return Ok(None) };
            let n = sys::rs2_get_stream_profiles_count(profiles.as_ptr(), &mut err);
            let _ = take_error(err);
            // Per kind (gyro, accel): the profile with the lowest rate.
            let mut chosen: [Option<(*const sys::rs2_stream_profile, i32)>; 2] = [None, None];
            for j in 0..n {
                err = std::ptr::null_mut();
                let profile = sys::rs2_get_stream_profile(profiles.as_ptr(), j, &mut err);
                if take_error(err).is_some() || profile.is_null() {
                    continue;
                }
                let (mut stream, mut format, mut index, mut uid, mut fps) = (0, 0, 0, 0, 0);
                sys::rs2_get_stream_profile_data(
                    profile,
                    &mut stream,
                    &mut format,
                    &mut index,
                    &mut uid,
                    &mut fps,
                    &mut err,
                );
                if take_error(err).is_some() || format != sys::rs2_format_RS2_FORMAT_MOTION_XYZ32F {
                    continue;
                }
                let slot = match stream {
                    sys::rs2_stream_RS2_STREAM_GYRO => 0,
                    sys::rs2_stream_RS2_STREAM_ACCEL => 1,
                    _ => continue,
                };
                if chosen[slot].is_none_or(|(_, best)| fps < best) {
                    chosen[slot] = Some((profile, fps));
                }
            }
            let result = match chosen {
                [Some((gyro, gyro_hz)), Some((accel, accel_hz))] => Self::start(sensor, [gyro, accel], queue_len)
                    .map(|queue| Some(Self { sensor, queue, rates_hz: [gyro_hz, accel_hz] })),
                _ => Ok(None),
            };
            sys::rs2_delete_stream_profiles_list(profiles.as_ptr());
            result
        }
    }

    /// Opens `profiles` on `sensor` and starts it into a new queue of `queue_len` frames.
    ///
    /// # Safety
    /// `sensor` must be live and the profiles must be its own, alive for the call.
    unsafe fn start(
        sensor: NonNull<sys::rs2_sensor>,
        mut profiles: [*const sys::rs2_stream_profile; 2],
        queue_len: i32,
    ) -> Result<NonNull<sys::rs2_frame_queue>, String> {
        // SAFETY: as `try_start`'s; the queue is deleted here on failure, else owned by the result.
        unsafe {
            let mut err = std::ptr::null_mut::<sys::rs2_error>();
            sys::rs2_open_multiple(sensor.as_ptr(), profiles.as_mut_ptr(), 2, &mut err);
            if let Some(e) = take_error(err) {
                return Err(format!("cannot open the gyro and accelerometer streams: {e}"));
            }
            let queue = sys::rs2_create_frame_queue(queue_len, &mut err);
            let queue = match (take_error(err), NonNull::new(queue)) {
                (None, Some(queue)) => queue,
                (e, _) => {
                    sys::rs2_close(sensor.as_ptr(), &mut err);
                    let _ = take_error(err);
                    return Err(format!("cannot make the motion frame queue: {}", e.unwrap_or_default()));
                }
            };
            sys::rs2_start_queue(sensor.as_ptr(), queue.as_ptr(), &mut err);
            if let Some(e) = take_error(err) {
                sys::rs2_close(sensor.as_ptr(), &mut err);
                let _ = take_error(err);
                sys::rs2_delete_frame_queue(queue.as_ptr());
                return Err(format!("cannot start the motion sensor: {e}"));
            }
            Ok(queue)
        }
    }

    /// Gyro and accelerometer rates opened, Hz.
    pub(super) fn rates_hz(&self) -> [i32; 2] {
        self.rates_hz
    }

    /// The next motion frame the queue holds (`None` when it is empty); frames that are not
    /// motion frames are released and passed over.
    pub(super) fn poll(&self) -> Option<GyroFrame> {
        loop {
            let mut err = std::ptr::null_mut::<sys::rs2_error>();
            let mut raw = std::ptr::null_mut::<sys::rs2_frame>();
            // SAFETY: a live queue; a frame it hands out is ours and released by the frame
            // wrapper (or here when it cannot be wrapped).
            let got = unsafe { sys::rs2_poll_for_frame(self.queue.as_ptr(), &mut raw, &mut err) };
            if take_error(err).is_some() || got == 0 {
                return None;
            }
            let raw = NonNull::new(raw)?;
            match GyroFrame::try_from(raw) {
                Ok(frame) => return Some(frame),
                // SAFETY: not wrapped, so still ours to release.
                Err(_) => unsafe { sys::rs2_release_frame(raw.as_ptr()) },
            }
        }
    }
}

/// A frame set (depth and colour), its frames looked up without the `Vec` realsense-rust's
/// `CompositeFrame::frames_of_type` allocates on each call: no allocation per frame.
pub(super) struct FrameSet(NonNull<sys::rs2_frame>);

impl FrameSet {
    pub(super) fn new(set: CompositeFrame) -> Self {
        // SAFETY: the wrapper hands over its reference to the set; `Drop` releases it.
        Self(unsafe { set.get_owned_raw() })
    }

    /// The set's first frame of type `F`, as `frames_of_type::<F>().into_iter().next()`.
    pub(super) fn first<F: TryFrom<NonNull<sys::rs2_frame>> + FrameCategory>(&self) -> Option<F> {
        // SAFETY: the set pointer lives as long as `self`; each extracted frame holds its own
        // reference, handed to the `F` made from it or released here; every call checks `err`.
        unsafe {
            let mut err = std::ptr::null_mut::<sys::rs2_error>();
            let count = sys::rs2_embedded_frames_count(self.0.as_ptr(), &mut err);
            if !err.is_null() {
                sys::rs2_free_error(err);
                return None;
            }
            for i in 0..count {
                let raw = sys::rs2_extract_frame(self.0.as_ptr(), i, &mut err);
                if !err.is_null() {
                    sys::rs2_free_error(err);
                    err = std::ptr::null_mut();
                    continue;
                }
                let Some(raw) = NonNull::new(raw) else { continue };
                let extendable = sys::rs2_is_frame_extendable_to(raw.as_ptr(), F::extension() as _, &mut err);
                if !err.is_null() {
                    sys::rs2_free_error(err);
                    err = std::ptr::null_mut();
                } else if extendable != 0 {
                    // On success the frame owns the reference (and releases it when dropped).
                    if let Ok(f) = F::try_from(raw) {
                        if F::kind() == Rs2StreamKind::Any || f.has_correct_kind() {
                            return Some(f);
                        }
                        continue;
                    }
                }
                sys::rs2_release_frame(raw.as_ptr());
            }
            None
        }
    }
}

impl Drop for FrameSet {
    fn drop(&mut self) {
        // SAFETY: the reference taken in `new`, released once.
        unsafe { sys::rs2_release_frame(self.0.as_ptr()) }
    }
}

/// The pixels of an image frame as librealsense holds them (`get_data_size` bytes, rows
/// `stride` apart), borrowed for as long as the frame.
pub(super) fn image_bytes<K>(frame: &ImageFrame<K>) -> &[u8] {
    // SAFETY: librealsense keeps each frame's buffer (get_data_size bytes) alive while the frame
    // object lives; the slice borrows `frame`, so it cannot outlive it.
    unsafe {
        std::slice::from_raw_parts((frame.get_data() as *const std::ffi::c_void).cast::<u8>(), frame.get_data_size())
    }
}
