//! The librealsense part: a live camera or a `.bag` recording through `realsense-rust`'s
//! pipeline, depth aligned to colour (by [`crate::align::DepthToColour`] from the streams'
//! calibration, written straight into the pooled frame, or with `align = "librealsense"` by
//! librealsense's align block), rotated and copied into the pooled frame.
//!
//! **Clock.** A live camera's frames are stamped in librealsense's *global time* domain
//! (`RS2_OPTION_GLOBAL_TIME_ENABLED`, switched on at start for every sensor that has it): the
//! camera's hardware timestamp mapped onto the host's system clock (`CLOCK_REALTIME`,
//! nanoseconds since the Unix epoch), the clock a navigation stack on the same computer stamps
//! its poses with. A frame that still comes in the hardware-clock domain (old firmware) is
//! stamped with its host arrival time (`RS2_FRAME_METADATA_TIME_OF_ARRIVAL`) and a warning says
//! so once. A recording's frames keep the stamps it was recorded with (the recording's clock).
//!
//! **Frame sets.** After alignment, a set is delivered when both its depth and its colour frame
//! are new (by frame number) and were taken within half a frame period of each other; a set
//! that repeats the previous depth or colour frame, or pairs frames of different instants (the
//! pipeline does both when one stream runs ahead), is passed over and counted
//! ([`RealsenseSource::repeated_sets`]). librealsense's pipeline never delivers a recording's
//! first depth frame with both streams enabled (pyrealsense2 shows the same), so a `.bag` of N
//! frame pairs plays as N - 1 frames.
//!
//! **Unplug.** A live camera whose frames stop is looked for among the connected devices after
//! each timeout; once it is gone the pipeline is stopped, [`FrameSource::connected`] turns
//! `false` (health's `source_connected`) and the source retries with a doubling backoff
//! (`reconnect.initial_ms` .. `max_ms`), returning [`SourceStatus::Pending`] meanwhile, until the
//! same serial number is back with the same stream modes.

#![allow(unsafe_code)] // FFI: librealsense buffers and the playback controls realsense-rust lacks.

use std::collections::HashSet;
use std::ffi::{CStr, CString};
use std::path::{Path, PathBuf};
use std::ptr::NonNull;
use std::sync::Arc;
use std::time::{Duration, Instant};

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::pose::Isometry;
use op3dsg_drivers::source::{FrameSource, SourceError, SourceStatus, StampClock};
use realsense_rust::config::Config;
use realsense_rust::context::Context;
use realsense_rust::frame::{ColorFrame, CompositeFrame, DepthFrame, FrameCategory, FrameEx, GyroFrame};
use realsense_rust::kind::{Rs2CameraInfo, Rs2Format, Rs2FrameMetadata, Rs2Option, Rs2StreamKind, Rs2TimestampDomain};
use realsense_rust::pipeline::{ActivePipeline, InactivePipeline};
use realsense_rust::processing_blocks::align::Align;
use realsense_sys as sys;
use tracing::{info, warn};

use crate::align::{DepthToColour, Distortion, Extrinsics, Lens};
use crate::config::{AlignMode, RealsenseConfig, StreamMode};
use crate::imu::{IMU_BUFFER_LEN, ImuBuffer, ImuSample, MotionKind};
use crate::rotate::{ColourOrder, Rotation, SourceLayout, copy_colour, copy_depth};

/// Longest wait for the first frame set after a (re)start.
const FIRST_FRAME_TIMEOUT: Duration = Duration::from_secs(10);
/// Wait for the frame sets still queued once playback has read the whole file.
const END_DRAIN_TIMEOUT: Duration = Duration::from_millis(250);
/// Longest a call to `next_frame` sleeps while waiting to retry a lost camera.
const RETRY_SLICE: Duration = Duration::from_millis(100);

/// What the stream resolution gave at start.
#[derive(Debug, Clone, Copy)]
struct Streams {
    colour: Intrinsics,
    depth_units_per_m: f32,
    colour_order: ColourOrder,
    /// Half the colour frame period: depth and colour further apart are not one instant.
    half_period_ms: f64,
}

/// The librealsense frame source (`source.kind = "realsense"`).
pub struct RealsenseSource {
    config: RealsenseConfig,
    bag: Option<PathBuf>,
    context: Context,
    pipeline: Option<ActivePipeline>,
    /// librealsense's align block (`align = "librealsense"`).
    align: Option<Align>,
    /// Our alignment (`align = "op3dsg"`), made for the streams at each start.
    aligner: Option<DepthToColour>,
    /// IMU samples (`imu = true`).
    imu: Option<Arc<ImuBuffer>>,
    /// The motion sensor on its own queue (`imu = true`), opened at the first frame set.
    motion: Option<MotionSensor>,
    streams: Streams,
    /// Intrinsics of delivered (rotated) frames.
    intrinsics: Intrinsics,
    rotation: Rotation,
    modes: (StreamMode, StreamMode),
    serial: String,
    playback: Option<DeviceHandle>,
    seq: u64,
    last_numbers: Option<(u64, u64)>,
    repeated_sets: u64,
    warned_hardware_clock: bool,
    delivered_any: bool,
    /// A frame set came from the pipeline (delivered or passed over) since the streams started.
    received_any: bool,
    connected: bool,
    retry_at: Instant,
    backoff: Duration,
    world_from_camera: Option<Isometry>,
}

impl std::fmt::Debug for RealsenseSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RealsenseSource").field("source", &self.describe()).field("seq", &self.seq).finish()
    }
}

// SAFETY: the source is used by one thread at a time (the capture thread); librealsense's
// context, pipeline, processing block and device handles may be used from any thread.
unsafe impl Send for RealsenseSource {}

/// A device handle made from a frame's sensor (realsense-rust has no playback control and no
/// raw device): the playback pacing and the motion sensor are reached through it.
struct DeviceHandle(NonNull<sys::rs2_device>);

impl Drop for DeviceHandle {
    fn drop(&mut self) {
        // SAFETY: made by rs2_create_device_from_sensor, owned here, deleted once.
        unsafe { sys::rs2_delete_device(self.0.as_ptr()) }
    }
}

impl DeviceHandle {
    /// The device a frame came from.
    fn from_frame(frame: DepthFrame) -> Result<Self, String> {
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
    fn set_real_time(&self, real_time: bool) -> Result<(), String> {
        let mut err = std::ptr::null_mut::<sys::rs2_error>();
        // SAFETY: a live device handle; the error is checked and freed.
        unsafe { sys::rs2_playback_device_set_real_time(self.0.as_ptr(), i32::from(real_time), &mut err) };
        take_error(err).map_or(Ok(()), Err)
    }

    fn stopped(&self) -> bool {
        let mut err = std::ptr::null_mut::<sys::rs2_error>();
        // SAFETY: a live device handle; the error is checked and freed.
        let status = unsafe { sys::rs2_playback_device_get_current_status(self.0.as_ptr(), &mut err) };
        take_error(err).is_none() && status == sys::rs2_playback_status_RS2_PLAYBACK_STATUS_STOPPED
    }
}

/// Motion frames the motion sensor's queue holds (librealsense drops the oldest beyond): over
/// 3 s of the D435i's gyro and accelerometer at their lowest rates, drained at every frame.
const MOTION_QUEUE_LEN: i32 = 1024;

/// The device's motion sensor opened on a frame queue of its own (`imu = true`).
/// librealsense's pipeline would hand over only the newest gyro and accelerometer frame with
/// each frame set (most samples lost at 200 Hz against 30 Hz video), so the motion streams stay
/// out of the pipeline and every sample comes through this queue instead.
struct MotionSensor {
    sensor: NonNull<sys::rs2_sensor>,
    queue: NonNull<sys::rs2_frame_queue>,
    /// Gyro and accelerometer rates opened, Hz.
    rates_hz: [i32; 2],
}

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
    /// Opens the gyro and accelerometer streams of `device` (each at the lowest rate it offers,
    /// `MOTION_XYZ32F`) on a queue of their own and starts them.
    fn open(device: &DeviceHandle) -> Result<Self, String> {
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
                match Self::try_start(sensor) {
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
    unsafe fn try_start(sensor: NonNull<sys::rs2_sensor>) -> Result<Option<Self>, String> {
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
                [Some((gyro, gyro_hz)), Some((accel, accel_hz))] => Self::start(sensor, [gyro, accel])
                    .map(|queue| Some(Self { sensor, queue, rates_hz: [gyro_hz, accel_hz] })),
                _ => Ok(None),
            };
            sys::rs2_delete_stream_profiles_list(profiles.as_ptr());
            result
        }
    }

    /// Opens `profiles` on `sensor` and starts it into a new queue.
    ///
    /// # Safety
    /// `sensor` must be live and the profiles must be its own, alive for the call.
    unsafe fn start(
        sensor: NonNull<sys::rs2_sensor>,
        mut profiles: [*const sys::rs2_stream_profile; 2],
    ) -> Result<NonNull<sys::rs2_frame_queue>, String> {
        // SAFETY: as `try_start`'s; the queue is deleted here on failure, else owned by the result.
        unsafe {
            let mut err = std::ptr::null_mut::<sys::rs2_error>();
            sys::rs2_open_multiple(sensor.as_ptr(), profiles.as_mut_ptr(), 2, &mut err);
            if let Some(e) = take_error(err) {
                return Err(format!("cannot open the gyro and accelerometer streams: {e}"));
            }
            let queue = sys::rs2_create_frame_queue(MOTION_QUEUE_LEN, &mut err);
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

    /// Moves every motion frame the queue holds into `imu`; how many.
    fn drain(&self, imu: &ImuBuffer, playback: bool) -> usize {
        let mut taken = 0;
        loop {
            let mut err = std::ptr::null_mut::<sys::rs2_error>();
            let mut raw = std::ptr::null_mut::<sys::rs2_frame>();
            // SAFETY: a live queue; a frame it hands out is ours and released by the frame
            // wrapper (or here when it cannot be wrapped).
            let got = unsafe { sys::rs2_poll_for_frame(self.queue.as_ptr(), &mut raw, &mut err) };
            if take_error(err).is_some() || got == 0 {
                return taken;
            }
            let Some(raw) = NonNull::new(raw) else { return taken };
            match GyroFrame::try_from(raw) {
                Ok(frame) => {
                    let kind = match frame.stream_profile().kind() {
                        Rs2StreamKind::Gyro => MotionKind::Gyro,
                        Rs2StreamKind::Accel => MotionKind::Accel,
                        _ => continue,
                    };
                    // (Gyro and accelerometer frames share one layout: three f32.)
                    imu.push(ImuSample {
                        stamp_ns: host_stamp_ns(&frame, playback),
                        kind,
                        xyz: *frame.rotational_velocity(),
                    });
                    taken += 1;
                }
                // SAFETY: not wrapped, so still ours to release.
                Err(_) => unsafe { sys::rs2_release_frame(raw.as_ptr()) },
            }
        }
    }
}

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

fn device_err(what: impl std::fmt::Display) -> SourceError {
    SourceError::Device(what.to_string())
}

impl RealsenseSource {
    /// Opens the camera (or the `.bag` file) `config` names; `base_dir` resolves a relative
    /// `bag`. Fails naming the camera or file when it cannot deliver the configured streams.
    pub fn open(config: &RealsenseConfig, base_dir: Option<&Path>) -> Result<Self, SourceError> {
        config
            .validate()
            .map_err(|(field, message)| SourceError::Config(format!("source.realsense.{field}: {message}")))?;
        let bag = config.is_playback().then(|| {
            let path = PathBuf::from(&config.bag);
            match base_dir {
                Some(dir) if path.is_relative() => dir.join(path),
                _ => path,
            }
        });
        if let Some(bag) = &bag
            && let Err(e) = std::fs::metadata(bag)
        {
            return Err(SourceError::File { path: bag.display().to_string(), reason: format!("cannot open: {e}") });
        }
        let context = Context::new().map_err(|e| device_err(format!("librealsense context: {e}")))?;
        let align = match config.align {
            AlignMode::Librealsense => {
                Some(Align::new(Rs2StreamKind::Color, 1).map_err(|e| device_err(format!("align block: {e}")))?)
            }
            AlignMode::Op3dsg => None,
        };
        let mut modes = (config.depth, config.colour);
        let mut serial = config.serial.clone();
        if bag.is_none() {
            let device = find_device(&context, &config.serial)?;
            serial = info(&device, Rs2CameraInfo::SerialNumber);
            let usb = info(&device, Rs2CameraInfo::UsbTypeDescriptor);
            let name = info(&device, Rs2CameraInfo::Name);
            info!(camera = %name, serial = %serial, usb = %usb, firmware = %info(&device, Rs2CameraInfo::FirmwareVersion), "realsense camera found");
            if usb.starts_with('2') {
                if config.usb2_fallback {
                    modes = (config.usb2_mode, config.usb2_mode);
                    warn!(
                        serial = %serial, usb = %usb,
                        "camera is on a USB 2 link, too slow for depth {}x{}@{} + colour {}x{}@{}: falling back to {}x{}@{} for both (plug it into a USB 3 port)",
                        config.depth.width, config.depth.height, config.depth.fps,
                        config.colour.width, config.colour.height, config.colour.fps,
                        config.usb2_mode.width, config.usb2_mode.height, config.usb2_mode.fps
                    );
                } else {
                    warn!(serial = %serial, usb = %usb, "camera is on a USB 2 link: the configured streams may not start or may drop frames (usb2_fallback = false)");
                }
            }
        }
        let world_from_camera = config.world_from_camera.map(|p| {
            let [x, y, z, w] = p.rotation_xyzw;
            Isometry::new(glam::DQuat::from_xyzw(x, y, z, w).normalize(), glam::DVec3::from_array(p.translation_m))
        });
        let mut source = Self {
            config: config.clone(),
            bag,
            context,
            pipeline: None,
            align,
            aligner: None,
            imu: config.imu.then(|| Arc::new(ImuBuffer::new(IMU_BUFFER_LEN))),
            motion: None,
            streams: Streams {
                colour: Intrinsics { width: 0, height: 0, fx: 1.0, fy: 1.0, cx: 0.0, cy: 0.0 },
                depth_units_per_m: 1000.0,
                colour_order: ColourOrder::Rgb8,
                half_period_ms: 0.0,
            },
            intrinsics: Intrinsics { width: 0, height: 0, fx: 1.0, fy: 1.0, cx: 0.0, cy: 0.0 },
            rotation: config.rotate,
            modes,
            serial,
            playback: None,
            seq: 0,
            last_numbers: None,
            repeated_sets: 0,
            warned_hardware_clock: false,
            delivered_any: false,
            received_any: false,
            connected: false,
            retry_at: Instant::now(),
            backoff: Duration::from_millis(config.reconnect.initial_ms),
            world_from_camera,
        };
        source.streams = source.start()?;
        source.intrinsics = source.rotation.intrinsics(&source.streams.colour);
        source.connected = true;
        Ok(source)
    }

    fn name(&self) -> String {
        source_name(self.bag.as_deref(), &self.serial)
    }

    /// Starts the pipeline and reads the streams' calibration.
    fn start(&mut self) -> Result<Streams, SourceError> {
        let name = self.name();
        let mut cfg = Config::new();
        let (depth, colour) = self.modes;
        let enable = |cfg: &mut Config| -> Result<(), String> {
            match &self.bag {
                Some(bag) => {
                    cfg.enable_device_from_file(bag, false).map_err(|e| e.to_string())?;
                    cfg.enable_stream(Rs2StreamKind::Depth, None, 0, 0, Rs2Format::Z16, 0)
                        .map_err(|e| e.to_string())?;
                    cfg.enable_stream(Rs2StreamKind::Color, None, 0, 0, Rs2Format::Any, 0)
                        .map_err(|e| e.to_string())?;
                }
                None => {
                    if !self.serial.is_empty() {
                        let serial = CString::new(self.serial.clone()).map_err(|e| e.to_string())?;
                        cfg.enable_device_from_serial(&serial).map_err(|e| e.to_string())?;
                    }
                    cfg.enable_stream(
                        Rs2StreamKind::Depth,
                        None,
                        depth.width as usize,
                        depth.height as usize,
                        Rs2Format::Z16,
                        depth.fps as usize,
                    )
                    .map_err(|e| e.to_string())?;
                    cfg.enable_stream(
                        Rs2StreamKind::Color,
                        None,
                        colour.width as usize,
                        colour.height as usize,
                        Rs2Format::Rgb8,
                        colour.fps as usize,
                    )
                    .map_err(|e| e.to_string())?;
                }
            }
            Ok(())
        };
        enable(&mut cfg).map_err(|e| self.open_error(&name, e))?;
        let pipeline =
            InactivePipeline::try_from(&self.context).map_err(|e| device_err(format!("{name}: pipeline: {e}")))?;
        if self.bag.is_none() && !pipeline.can_resolve(&cfg) {
            return Err(device_err(format!(
                "{name}: cannot deliver depth {}x{}@{} Z16 with colour {}x{}@{} RGB8 (another process using it, or a mode this camera lacks)",
                depth.width, depth.height, depth.fps, colour.width, colour.height, colour.fps
            )));
        }
        let pipeline = pipeline.start(Some(cfg)).map_err(|e| self.open_error(&name, e.to_string()))?;
        let profile = pipeline.profile();
        let colour_stream = profile.streams().iter().find(|s| s.kind() == Rs2StreamKind::Color);
        let depth_stream = profile.streams().iter().find(|s| s.kind() == Rs2StreamKind::Depth);
        let (Some(colour_stream), Some(depth_stream)) = (colour_stream, depth_stream) else {
            return Err(device_err(format!("{name}: needs a depth and a colour stream")));
        };
        let colour_order = match colour_stream.format() {
            Rs2Format::Rgb8 => ColourOrder::Rgb8,
            Rs2Format::Bgr8 => ColourOrder::Bgr8,
            Rs2Format::Rgba8 => ColourOrder::Rgba8,
            Rs2Format::Bgra8 => ColourOrder::Bgra8,
            other => {
                return Err(device_err(format!(
                    "{name}: colour stream format {other:?}; supported: RGB8, BGR8, RGBA8, BGRA8"
                )));
            }
        };
        let k = colour_stream.intrinsics().map_err(|e| device_err(format!("{name}: colour intrinsics: {e}")))?;
        let colour = Intrinsics {
            width: k.width() as u32,
            height: k.height() as u32,
            fx: k.fx(),
            fy: k.fy(),
            cx: k.ppx(),
            cy: k.ppy(),
        };
        let extrinsics = depth_stream.extrinsics(colour_stream).ok();
        let depth_lens = depth_stream
            .intrinsics()
            .map(|k| lens(&k.0))
            .map_err(|e| device_err(format!("{name}: depth intrinsics: {e}")))?;
        let colour_lens = lens(&k.0);
        let half_period_ms = 500.0 / f64::from(colour_stream.framerate().max(1));
        // Depth units: the depth sensor's option (metres per unit); the first frame corrects it
        // when the sensor does not report it.
        let mut depth_units_per_m = 1000.0;
        let mut sensors = profile.device().sensors();
        for sensor in &mut sensors {
            // (Sensor::extension panics on sensors of recordings; the depth sensor is the one
            // with depth units.)
            let is_depth = sensor.supports_option(Rs2Option::DepthUnits);
            if is_depth && let Some(units) = sensor.get_option(Rs2Option::DepthUnits).filter(|u| *u > 0.0) {
                depth_units_per_m = units_per_m(units);
            }
            if self.bag.is_some() {
                continue;
            }
            let mut set = |option: Rs2Option, value: Option<f32>, what: &str| {
                if let Some(value) = value
                    && sensor.supports_option(option)
                    && let Err(e) = sensor.set_option(option, value)
                {
                    warn!(camera = %name, option = what, value, error = %e, "cannot set realsense option");
                }
            };
            set(Rs2Option::GlobalTimeEnabled, Some(1.0), "global_time_enabled");
            if is_depth {
                set(Rs2Option::VisualPreset, self.config.visual_preset.option_value(), "visual_preset");
                set(Rs2Option::EmitterEnabled, self.config.emitter.option_value(), "emitter");
                set(Rs2Option::LaserPower, self.config.laser_power_mw, "laser_power_mw");
            }
        }
        self.aligner = match self.config.align {
            AlignMode::Librealsense => None,
            AlignMode::Op3dsg => {
                let Some(e) = &extrinsics else {
                    return Err(device_err(format!(
                        "{name}: no depth to colour extrinsics, cannot align (source.realsense.align = \"op3dsg\")"
                    )));
                };
                let e = Extrinsics { rotation: e.rotation(), translation_m: e.translation() };
                let aligner = DepthToColour::new(depth_lens, colour_lens, e, 1.0 / depth_units_per_m)
                    .map_err(|e| device_err(format!("{name}: {e}")))?;
                for (stream, model) in aligner.ignored_coefficients() {
                    warn!(source = %name, stream, model = ?model, "lens coefficients not applied by the depth to colour alignment (nor by librealsense's align)");
                }
                Some(aligner)
            }
        };
        info!(
            source = %name,
            align = ?self.config.align,
            depth = format!("{}x{}", depth_lens.width, depth_lens.height),
            colour = format!("{}x{} {:?}", colour.width, colour.height, colour_order),
            fx = colour.fx, fy = colour.fy, cx = colour.cx, cy = colour.cy,
            depth_units_per_m,
            depth_to_colour_translation_m = ?extrinsics.map(|e| e.translation()),
            rotate = self.rotation.degrees(),
            "realsense streams started (depth aligned to colour)"
        );
        self.pipeline = Some(pipeline);
        self.motion = None;
        self.playback = None;
        self.last_numbers = None;
        self.delivered_any = false;
        self.received_any = false;
        Ok(Streams { colour, depth_units_per_m, colour_order, half_period_ms })
    }

    fn open_error(&self, name: &str, reason: String) -> SourceError {
        match &self.bag {
            Some(bag) => SourceError::File {
                path: bag.display().to_string(),
                reason: format!("librealsense cannot play it: {reason}"),
            },
            None => device_err(format!("{name}: {reason}")),
        }
    }

    /// The IMU samples (`imu = true`): the buffer this source fills, for other threads to read.
    pub fn imu(&self) -> Option<Arc<ImuBuffer>> {
        self.imu.clone()
    }

    /// Opens the motion sensor of `device` on its own queue (`imu = true`); a camera or
    /// recording without gyro and accelerometer streams is an error naming the key.
    fn open_motion(&mut self, device: &DeviceHandle) -> Result<(), SourceError> {
        let motion = MotionSensor::open(device)
            .map_err(|e| SourceError::Config(format!("source.realsense.imu = true, but {}: {e}", self.name())))?;
        info!(source = %self.name(), gyro_hz = motion.rates_hz[0], accel_hz = motion.rates_hz[1], "IMU streaming on its own queue");
        self.motion = Some(motion);
        Ok(())
    }

    /// Frame sets passed over because they repeated the previous depth or colour frame.
    pub fn repeated_sets(&self) -> u64 {
        self.repeated_sets
    }

    /// The intrinsics of the colour stream as the camera delivers it (before `rotate`).
    pub fn camera_intrinsics(&self) -> Intrinsics {
        self.streams.colour
    }

    /// Lost camera: stop, and retry after the backoff.
    fn lose(&mut self, reason: &str) {
        self.motion = None;
        if let Some(pipeline) = self.pipeline.take() {
            let _ = pipeline.stop();
        }
        self.connected = false;
        self.backoff = Duration::from_millis(self.config.reconnect.initial_ms);
        self.retry_at = Instant::now() + self.backoff;
        warn!(camera = %self.name(), reason, retry_in_ms = self.backoff.as_millis() as u64, "realsense camera lost; reconnecting");
    }

    fn try_reconnect(&mut self) -> Result<SourceStatus, SourceError> {
        let now = Instant::now();
        if now < self.retry_at {
            std::thread::sleep((self.retry_at - now).min(RETRY_SLICE));
            return Ok(SourceStatus::Pending);
        }
        let attempt = find_device(&self.context, &self.serial).and_then(|_| self.start());
        match attempt {
            Ok(streams)
                if streams.colour == self.streams.colour && streams.colour_order == self.streams.colour_order =>
            {
                self.streams = streams;
                self.connected = true;
                info!(camera = %self.name(), "realsense camera reconnected");
                Ok(SourceStatus::Pending)
            }
            Ok(streams) => {
                self.pipeline = None;
                self.schedule_retry();
                Err(device_err(format!(
                    "{}: reconnected camera delivers colour {}x{} (fx {}), not the {}x{} (fx {}) frames were sized for",
                    self.name(),
                    streams.colour.width,
                    streams.colour.height,
                    streams.colour.fx,
                    self.streams.colour.width,
                    self.streams.colour.height,
                    self.streams.colour.fx
                )))
            }
            Err(e) => {
                self.schedule_retry();
                tracing::debug!(error = %e, retry_in_ms = self.backoff.as_millis() as u64, "realsense reconnect attempt failed");
                Ok(SourceStatus::Pending)
            }
        }
    }

    fn schedule_retry(&mut self) {
        self.backoff = (self.backoff * 2).min(Duration::from_millis(self.config.reconnect.max_ms));
        self.retry_at = Instant::now() + self.backoff;
    }

    fn fill(&mut self, set: CompositeFrame, frame: &mut Frame) -> Result<SourceStatus, SourceError> {
        // (The source's name is made only for messages: no allocation per frame for it.)
        let set = FrameSet::new(set);
        let depth = set.first::<DepthFrame>();
        let colour = set.first::<ColorFrame>();
        let (Some(depth), Some(colour)) = (depth, colour) else {
            return Err(device_err(format!("{}: frame set without depth and colour", self.name())));
        };
        // The device behind the first frame set received (delivered or passed over): playback
        // pacing and its end, the motion sensor.
        if !self.received_any {
            self.received_any = true;
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
        // SAFETY: librealsense keeps each frame's buffer (get_data_size bytes) alive while the
        // frame object lives; the slices do not outlive `colour` / `depth`.
        let (colour_bytes, depth_bytes) = unsafe {
            (
                std::slice::from_raw_parts(
                    (colour.get_data() as *const std::ffi::c_void).cast::<u8>(),
                    colour.get_data_size(),
                ),
                std::slice::from_raw_parts(
                    (depth.get_data() as *const std::ffi::c_void).cast::<u8>(),
                    depth.get_data_size(),
                ),
            )
        };
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
        let stamp_ms = match colour.timestamp_domain() {
            Rs2TimestampDomain::GlobalTime | Rs2TimestampDomain::SystemTime => colour.timestamp(),
            _ if self.bag.is_some() => colour.timestamp(),
            _ => {
                if !self.warned_hardware_clock {
                    self.warned_hardware_clock = true;
                    warn!(camera = %self.name(), "frames are stamped by the camera's hardware clock, not global time: using the host arrival time instead (update the firmware)");
                }
                colour.metadata(Rs2FrameMetadata::TimeOfArrival).map_or_else(|| colour.timestamp(), |ms| ms as f64)
            }
        };
        frame.seq = self.seq;
        frame.stamp_ns = (stamp_ms * 1e6).round().max(0.0) as u64;
        frame.intrinsics = self.intrinsics;
        frame.depth_units_per_m = self.streams.depth_units_per_m;
        frame.world_from_camera = self.world_from_camera;
        self.seq += 1;
        self.delivered_any = true;
        Ok(SourceStatus::Frame)
    }
}

/// A frame set (depth and colour), its frames looked up without the `Vec` realsense-rust's
/// `CompositeFrame::frames_of_type` allocates on each call: no allocation per frame.
struct FrameSet(NonNull<sys::rs2_frame>);

impl FrameSet {
    fn new(set: CompositeFrame) -> Self {
        // SAFETY: the wrapper hands over its reference to the set; `Drop` releases it.
        Self(unsafe { set.get_owned_raw() })
    }

    /// The set's first frame of type `F`, as `frames_of_type::<F>().into_iter().next()`.
    fn first<F: TryFrom<NonNull<sys::rs2_frame>> + FrameCategory>(&self) -> Option<F> {
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

/// A stream's intrinsics and lens model from librealsense's.
pub fn lens(k: &sys::rs2_intrinsics) -> Lens {
    #[allow(non_upper_case_globals)]
    let model = match k.model {
        sys::rs2_distortion_RS2_DISTORTION_NONE => Distortion::None,
        sys::rs2_distortion_RS2_DISTORTION_MODIFIED_BROWN_CONRADY => Distortion::ModifiedBrownConrady,
        sys::rs2_distortion_RS2_DISTORTION_INVERSE_BROWN_CONRADY => Distortion::InverseBrownConrady,
        sys::rs2_distortion_RS2_DISTORTION_BROWN_CONRADY => Distortion::BrownConrady,
        other => Distortion::Other(other as i32),
    };
    Lens {
        width: k.width.max(0) as u32,
        height: k.height.max(0) as u32,
        fx: k.fx,
        fy: k.fy,
        ppx: k.ppx,
        ppy: k.ppy,
        model,
        coeffs: k.coeffs,
    }
}

/// Depth units per metre from librealsense's metres per unit. The option is an `f32`, so
/// decimal units (0.001, 0.00025) arrive rounded; a reciprocal within 1e-5 (relative) of a whole
/// number is that number.
fn units_per_m(metres_per_unit: f32) -> f32 {
    let per_m = 1.0 / f64::from(metres_per_unit);
    let whole = per_m.round();
    if whole > 0.0 && ((per_m - whole) / whole).abs() < 1e-5 { whole as f32 } else { per_m as f32 }
}

fn info(device: &realsense_rust::device::Device, what: Rs2CameraInfo) -> String {
    device.info(what).map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

/// The connected camera with `serial` (any when empty).
fn find_device(context: &Context, serial: &str) -> Result<realsense_rust::device::Device, SourceError> {
    let devices = context.query_devices(HashSet::new());
    let serials: Vec<String> = devices.iter().map(|d| info(d, Rs2CameraInfo::SerialNumber)).collect();
    let found =
        devices.into_iter().zip(&serials).find(|(_, s)| serial.is_empty() || s.as_str() == serial).map(|(d, _)| d);
    found.ok_or_else(|| {
        if serials.is_empty() {
            device_err(
                "no RealSense camera connected (check the USB cable, `rs-enumerate-devices`, and the udev rules)",
            )
        } else {
            device_err(format!("no RealSense camera with serial {serial:?}; connected: {}", serials.join(", ")))
        }
    })
}

impl FrameSource for RealsenseSource {
    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn has_poses(&self) -> bool {
        self.world_from_camera.is_some()
    }

    fn connected(&self) -> bool {
        self.connected
    }

    fn stamp_clock(&self) -> StampClock {
        if self.bag.is_some() { StampClock::Recording } else { StampClock::HostGlobalTime }
    }

    fn next_frame(&mut self, frame: &mut Frame) -> Result<SourceStatus, SourceError> {
        let Some(pipeline) = self.pipeline.as_mut() else {
            return if self.bag.is_some() { Ok(SourceStatus::EndOfStream) } else { self.try_reconnect() };
        };
        let timeout = if self.playback.as_ref().is_some_and(DeviceHandle::stopped) {
            // Playback read the whole file: drain what the pipeline still holds, then end.
            END_DRAIN_TIMEOUT
        } else if self.received_any {
            Duration::from_millis(self.config.frame_timeout_ms)
        } else {
            FIRST_FRAME_TIMEOUT.max(Duration::from_millis(self.config.frame_timeout_ms))
        };
        let waited = pipeline.wait(Some(timeout));
        if let (Some(motion), Some(imu)) = (&self.motion, &self.imu) {
            motion.drain(imu, self.bag.is_some());
        }
        match waited {
            Ok(set) => match &mut self.align {
                Some(align) => {
                    let name = || source_name(self.bag.as_deref(), &self.serial);
                    align.queue(set).map_err(|e| device_err(format!("{}: align: {e}", name())))?;
                    let aligned = align.wait(timeout).map_err(|e| device_err(format!("{}: align: {e}", name())))?;
                    self.fill(aligned, frame)
                }
                None => self.fill(set, frame),
            },
            Err(e) => {
                if self.bag.is_some() {
                    // librealsense shows the end of a non-looping file only as a timeout. (Its
                    // syncer may pair every set of a short file across frame numbers, all
                    // passed over: the file still ended, with nothing to deliver.)
                    if self.received_any {
                        if !self.delivered_any {
                            warn!(bag = %self.name(), passed_over = self.repeated_sets, "recording ended without a frame set whose depth and colour belong together");
                        }
                        self.pipeline = None;
                        return Ok(SourceStatus::EndOfStream);
                    }
                    return Err(SourceError::File {
                        path: self.name(),
                        reason: format!("no frame set within {timeout:?}: {e}"),
                    });
                }
                if find_device(&self.context, &self.serial).is_err() {
                    self.lose("unplugged");
                    return Ok(SourceStatus::Pending);
                }
                Err(device_err(format!("{}: {e}", self.name())))
            }
        }
    }

    fn stops_on_error(&self) -> bool {
        self.bag.is_some()
    }

    fn describe(&self) -> String {
        match &self.bag {
            Some(bag) => format!("realsense playback {}", bag.display()),
            None => format!(
                "realsense {} depth {}x{}@{} colour {}x{}@{} rotate {}",
                if self.serial.is_empty() { "(first found)" } else { &self.serial },
                self.modes.0.width,
                self.modes.0.height,
                self.modes.0.fps,
                self.modes.1.width,
                self.modes.1.height,
                self.modes.1.fps,
                self.rotation.degrees()
            ),
        }
    }
}

/// A source as messages name it: the recording's path, or the camera's serial number.
fn source_name(bag: Option<&std::path::Path>, serial: &str) -> String {
    match bag {
        Some(bag) => bag.display().to_string(),
        None => format!("camera {}", if serial.is_empty() { "(first found)" } else { serial }),
    }
}
