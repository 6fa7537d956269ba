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
//! **Which camera.** A live camera is chosen by `serial`, else by `product`
//! ([`crate::select`]); the start log names it (name, serial, firmware, USB link). A recording's
//! camera is logged the same way and must match `product` when that is set; `serial` is not
//! checked against a recording.
//!
//! **Unplug.** A live camera whose frames stop is looked for among the connected devices after
//! each timeout; once it is gone the pipeline is stopped, [`FrameSource::connected`] turns
//! `false` (health's `source_connected`) and the source retries with a doubling backoff
//! (`reconnect.initial_ms` .. `max_ms`), returning [`SourceStatus::Pending`] meanwhile, until the
//! same serial number is back with the same stream modes.
//!
//! **Files.** This one holds the source and its [`FrameSource`] face; `streams` starts the
//! pipeline and reads the calibration, `fill` turns one frame set into the pooled frame,
//! `reconnect` handles a lost camera, `motion` the IMU. `ffi` holds every call into librealsense's
//! C API that `realsense-rust` lacks, behind safe wrappers: the only file here that uses `unsafe`.

mod ffi;
mod fill;
mod motion;
mod reconnect;
mod streams;

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_drivers::pose::Isometry;
use op3dsg_drivers::source::{FrameSource, SourceError, SourceKind, SourceStatus, StampClock};
use realsense_rust::context::Context;
use realsense_rust::frame::DepthFrame;
use realsense_rust::kind::Rs2CameraInfo;
use realsense_rust::pipeline::ActivePipeline;
use tracing::{debug, info, warn};

use self::ffi::{AlignBlock, DeviceHandle, MotionSensor};
pub use self::streams::lens;
use self::streams::{Streams, find_device, info};
use crate::align::DepthToColour;
use crate::config::{AlignMode, RealsenseConfig, StreamMode};
use crate::imu::{IMU_BUFFER_LEN, ImuBuffer};
use crate::rotate::{ColourOrder, Rotation};

/// Longest wait for the first frame set after a (re)start.
const FIRST_FRAME_TIMEOUT: Duration = Duration::from_secs(10);
/// Longest wait at a stop for the frame set that gives a recording's device handle.
const HANDLE_WAIT: Duration = Duration::from_secs(1);
/// Wait for the frame sets still queued once playback has read the whole file.
const END_DRAIN_TIMEOUT: Duration = Duration::from_millis(250);

/// The librealsense frame source (`source.kind = "realsense"`).
pub struct RealsenseSource {
    config: RealsenseConfig,
    bag: Option<PathBuf>,
    context: Context,
    pipeline: Option<ActivePipeline>,
    /// librealsense's align block (`align = "librealsense"`).
    align: Option<AlignBlock>,
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
                Some(AlignBlock::to_colour().map_err(|e| device_err(format!("align block: {e}")))?)
            }
            AlignMode::Op3dsg => None,
        };
        let mut modes = (config.depth, config.colour);
        let mut serial = config.serial.clone();
        if let Some(bag) = &bag
            && !config.serial.is_empty()
        {
            info!(bag = %bag.display(), serial = %config.serial, "source.realsense.serial is not checked against a recording");
        }
        if bag.is_none() {
            let device = find_device(&context, &config.product, &config.serial)?;
            serial = info(&device, Rs2CameraInfo::SerialNumber);
            let usb = info(&device, Rs2CameraInfo::UsbTypeDescriptor);
            let name = info(&device, Rs2CameraInfo::Name);
            info!(
                camera = %name,
                serial = %serial,
                firmware = %info(&device, Rs2CameraInfo::FirmwareVersion),
                usb = %usb,
                product = %config.product,
                "realsense camera chosen"
            );
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

    /// Stops the streams: the motion sensor, then the pipeline, then a recording's playback
    /// device. librealsense's playback stopped while its reading thread runs on to the end of the
    /// file can leave that thread spinning there; paused first, it reads nothing more. Dropping a
    /// started pipeline deletes it without stopping it, and the context keeps a recording's
    /// device until it is removed: either would leave librealsense's threads running into the
    /// library's teardown at process exit, where they crash.
    pub(super) fn stop_streams(&mut self) {
        self.motion = None;
        let playback = self.playback.take();
        if let Some(mut pipeline) = self.pipeline.take() {
            if self.bag.is_some() {
                // Before the first frame set there is no handle yet: the next set gives one.
                let device = playback.or_else(|| {
                    let set = pipeline.wait(Some(HANDLE_WAIT)).ok()?;
                    let depth = set.frames_of_type::<DepthFrame>().into_iter().next()?;
                    DeviceHandle::from_frame(depth).ok()
                });
                if let Some(device) = device
                    && let Err(e) = device.pause()
                {
                    debug!(bag = %self.name(), error = %e, "cannot pause playback before stopping it");
                }
            }
            let _ = pipeline.stop();
        }
        if let Some(bag) = &self.bag {
            // Not an error when the context holds no device for the file (never started).
            let _ = self.context.remove_device(bag);
        }
    }

    /// The IMU samples (`imu = true`): the buffer this source fills, for other threads to read.
    pub fn imu(&self) -> Option<Arc<ImuBuffer>> {
        self.imu.clone()
    }

    /// Frame sets passed over because they repeated the previous depth or colour frame.
    pub fn repeated_sets(&self) -> u64 {
        self.repeated_sets
    }

    /// The intrinsics of the colour stream as the camera delivers it (before `rotate`).
    pub fn camera_intrinsics(&self) -> Intrinsics {
        self.streams.colour
    }
}

impl Drop for RealsenseSource {
    fn drop(&mut self) {
        self.stop_streams();
    }
}

impl FrameSource for RealsenseSource {
    fn intrinsics(&self) -> Intrinsics {
        self.intrinsics
    }

    fn camera_from_upright(&self) -> Isometry {
        self.rotation.camera_from_upright()
    }

    /// A `.bag` is a replay although this source plays it; only a camera is live.
    fn kind(&self) -> SourceKind {
        if self.bag.is_some() { SourceKind::Replay } else { SourceKind::LiveCamera }
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
            motion::drain(motion, imu, self.bag.is_some());
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
                        self.stop_streams();
                        return Ok(SourceStatus::EndOfStream);
                    }
                    return Err(SourceError::File {
                        path: self.name(),
                        reason: format!("no frame set within {timeout:?}: {e}"),
                    });
                }
                if find_device(&self.context, "", &self.serial).is_err() {
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
