//! Starting the pipeline: the configured streams (or a recording's) enabled and resolved, the
//! colour format, the calibration read (intrinsics, lens models, extrinsics, depth units), the
//! sensors' options set, and our alignment made for the streams.

use std::collections::HashSet;
use std::ffi::CString;

use op3dsg_drivers::frame::Intrinsics;
use op3dsg_drivers::source::SourceError;
use realsense_rust::config::Config;
use realsense_rust::context::Context;
use realsense_rust::kind::{Rs2CameraInfo, Rs2Format, Rs2Option, Rs2StreamKind};
use realsense_rust::pipeline::{ActivePipeline, InactivePipeline};
use realsense_sys as sys;
use tracing::{info, warn};

use super::{RealsenseSource, device_err};
use crate::align::{DepthToColour, Distortion, Extrinsics, Lens};
use crate::config::AlignMode;
use crate::rotate::ColourOrder;
use crate::select::{CameraId, choose_camera, product_matches};

/// What the stream resolution gave at start.
#[derive(Debug, Clone, Copy)]
pub(super) struct Streams {
    pub(super) colour: Intrinsics,
    pub(super) depth_units_per_m: f32,
    pub(super) colour_order: ColourOrder,
    /// Half the colour frame period: depth and colour further apart are not one instant.
    pub(super) half_period_ms: f64,
}

/// The colour order of a colour stream's format.
fn colour_order(format: Rs2Format, name: &str) -> Result<ColourOrder, SourceError> {
    Ok(match format {
        Rs2Format::Rgb8 => ColourOrder::Rgb8,
        Rs2Format::Bgr8 => ColourOrder::Bgr8,
        Rs2Format::Rgba8 => ColourOrder::Rgba8,
        Rs2Format::Bgra8 => ColourOrder::Bgra8,
        other => {
            return Err(device_err(format!(
                "{name}: colour stream format {other:?}; supported: RGB8, BGR8, RGBA8, BGRA8"
            )));
        }
    })
}

impl RealsenseSource {
    /// Starts the pipeline and reads the streams' calibration.
    pub(super) fn start(&mut self) -> Result<Streams, SourceError> {
        let name = self.name();
        let (depth, colour) = self.modes;
        let cfg = self.stream_config().map_err(|e| self.open_error(&name, e))?;
        let pipeline =
            InactivePipeline::try_from(&self.context).map_err(|e| device_err(format!("{name}: pipeline: {e}")))?;
        if self.bag.is_none() && !pipeline.can_resolve(&cfg) {
            return Err(device_err(format!(
                "{name}: cannot deliver depth {}x{}@{} Z16 with colour {}x{}@{} RGB8 (another process using it, or a mode this camera lacks)",
                depth.width, depth.height, depth.fps, colour.width, colour.height, colour.fps
            )));
        }
        if self.bag.is_some() {
            // The recording's camera is checked before it plays: a playback stopped right after
            // it started can leave librealsense's reading thread spinning at the end of the file.
            let profile = pipeline
                .resolve(&cfg)
                .ok_or_else(|| self.open_error(&name, "cannot resolve its streams".to_owned()))?;
            self.check_recorded_camera(profile.device(), &name)?;
        }
        let pipeline = pipeline.start(Some(cfg)).map_err(|e| self.open_error(&name, e.to_string()))?;
        match self.read_streams(&pipeline, &name) {
            Ok(streams) => {
                self.pipeline = Some(pipeline);
                self.motion = None;
                self.playback = None;
                self.last_numbers = None;
                self.delivered_any = false;
                self.received_any = false;
                Ok(streams)
            }
            Err(refused) => {
                // Stopped, and a recording's device released, before it is dropped.
                self.pipeline = Some(pipeline);
                self.stop_streams();
                Err(refused)
            }
        }
    }

    /// The started pipeline's streams and calibration, the sensors' options set and our
    /// alignment made for them.
    fn read_streams(&mut self, pipeline: &ActivePipeline, name: &str) -> Result<Streams, SourceError> {
        let profile = pipeline.profile();
        let colour_stream = profile.streams().iter().find(|s| s.kind() == Rs2StreamKind::Color);
        let depth_stream = profile.streams().iter().find(|s| s.kind() == Rs2StreamKind::Depth);
        let (Some(colour_stream), Some(depth_stream)) = (colour_stream, depth_stream) else {
            return Err(device_err(format!("{name}: needs a depth and a colour stream")));
        };
        let colour_order = colour_order(colour_stream.format(), name)?;
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
        let depth_units_per_m = self.configure_sensors(&mut profile.device().sensors(), name);
        let extrinsics_of_depth =
            extrinsics.as_ref().map(|e| Extrinsics { rotation: e.rotation(), translation_m: e.translation() });
        self.aligner = self.aligner_for(depth_lens, colour_lens, extrinsics_of_depth, depth_units_per_m, name)?;
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
        Ok(Streams { colour, depth_units_per_m, colour_order, half_period_ms })
    }

    /// Logs the camera a recording was made with; with `product` set it must match, so that a
    /// profile made for one camera (its rotation, its presets) does not play another camera's
    /// recording. `serial` is not checked: it names one unit, and recordings move between robots.
    fn check_recorded_camera(&self, device: &realsense_rust::device::Device, name: &str) -> Result<(), SourceError> {
        let recorded =
            CameraId { name: info(device, Rs2CameraInfo::Name), serial: info(device, Rs2CameraInfo::SerialNumber) };
        info!(
            source = %name,
            camera = %recorded.name,
            serial = %recorded.serial,
            firmware = %info(device, Rs2CameraInfo::FirmwareVersion),
            "realsense recording made with this camera"
        );
        if product_matches(&self.config.product, &recorded.name) {
            return Ok(());
        }
        Err(SourceError::Config(format!(
            "source.realsense.product: {:?}, but {name} was recorded with {recorded}; set product = \"\" to play any camera's recording",
            self.config.product
        )))
    }

    /// The streams to start: a recording's, or the camera's (by serial when set) in the modes
    /// resolved from the profile.
    fn stream_config(&self) -> Result<Config, String> {
        let mut cfg = Config::new();
        let (depth, colour) = self.modes;
        match &self.bag {
            Some(bag) => {
                cfg.enable_device_from_file(bag, false).map_err(|e| e.to_string())?;
                cfg.enable_stream(Rs2StreamKind::Depth, None, 0, 0, Rs2Format::Z16, 0).map_err(|e| e.to_string())?;
                cfg.enable_stream(Rs2StreamKind::Color, None, 0, 0, Rs2Format::Any, 0).map_err(|e| e.to_string())?;
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
        Ok(cfg)
    }

    /// Sets the sensors' options (global time; the depth sensor's preset, emitter and laser
    /// power; none on a recording) and returns the depth sensor's units, metres per unit.
    fn configure_sensors(&self, sensors: &mut [realsense_rust::sensor::Sensor], name: &str) -> f32 {
        // Depth units: the depth sensor's option (metres per unit); the first frame corrects it
        // when the sensor does not report it.
        let mut depth_units_per_m = 1000.0;
        for sensor in sensors.iter_mut() {
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
        depth_units_per_m
    }

    /// Our depth-to-colour alignment for these lenses (`None` with librealsense's).
    fn aligner_for(
        &self,
        depth_lens: Lens,
        colour_lens: Lens,
        extrinsics: Option<Extrinsics>,
        depth_units_per_m: f32,
        name: &str,
    ) -> Result<Option<DepthToColour>, SourceError> {
        Ok(match self.config.align {
            AlignMode::Librealsense => None,
            AlignMode::Op3dsg => {
                let Some(e) = extrinsics else {
                    return Err(device_err(format!(
                        "{name}: no depth to colour extrinsics, cannot align (source.realsense.align = \"op3dsg\")"
                    )));
                };
                let aligner = DepthToColour::new(depth_lens, colour_lens, e, 1.0 / depth_units_per_m)
                    .map_err(|e| device_err(format!("{name}: {e}")))?;
                for (stream, model) in aligner.ignored_coefficients() {
                    warn!(source = %name, stream, model = ?model, "lens coefficients not applied by the depth to colour alignment (nor by librealsense's align)");
                }
                Some(aligner)
            }
        })
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
pub(super) fn units_per_m(metres_per_unit: f32) -> f32 {
    let per_m = 1.0 / f64::from(metres_per_unit);
    let whole = per_m.round();
    if whole > 0.0 && ((per_m - whole) / whole).abs() < 1e-5 { whole as f32 } else { per_m as f32 }
}

pub(super) fn info(device: &realsense_rust::device::Device, what: Rs2CameraInfo) -> String {
    device.info(what).map(|s| s.to_string_lossy().into_owned()).unwrap_or_default()
}

/// The connected camera `[source.realsense]` names: by `serial` when set, else the first whose
/// name matches `product` ([`choose_camera`]); a warning is logged when the choice was not
/// unambiguous, and the error lists every camera seen.
pub(super) fn find_device(
    context: &Context,
    product: &str,
    serial: &str,
) -> Result<realsense_rust::device::Device, SourceError> {
    let devices = context.query_devices(HashSet::new());
    let cameras: Vec<CameraId> = devices
        .iter()
        .map(|d| CameraId { name: info(d, Rs2CameraInfo::Name), serial: info(d, Rs2CameraInfo::SerialNumber) })
        .collect();
    let choice = choose_camera(&cameras, product, serial).map_err(device_err)?;
    if let Some(warning) = &choice.warning {
        warn!("{warning}");
    }
    devices
        .into_iter()
        .nth(choice.index)
        .ok_or_else(|| device_err(format!("camera {} left the device list while it was read", cameras[choice.index])))
}
