//! `source.kind = "realsense"` for the runtime's backend registry: [`register`] adds
//! `op3dsg-realsense`'s source to a [`Backends`] (what the binaries built with `--features
//! realsense` do), which then checks `[source.realsense]` when the profile loads and opens the
//! camera or `.bag` at start.

use std::sync::Arc;

use op3dsg_runtime::backend::StartError;
use op3dsg_runtime::backend::{Backends, OpenedSource, SectionError, SourceBackend};
use op3dsg_runtime::config::Profile;
use op3dsg_runtime::keyframe::PoseSourceKind;

use op3dsg_realsense::{REALSENSE_SOURCE, RealsenseConfig, RealsenseSource};

/// Profile path of the section.
pub const REALSENSE_SECTION: &str = "source.realsense";

/// Registers `source.kind = "realsense"`.
pub fn register(backends: &mut Backends) -> &mut Backends {
    backends.register_source(Arc::new(RealsenseBackend))
}

/// `[source.realsense]` of `profile`, typed (the defaults when the profile has none).
pub fn realsense_config(profile: &Profile) -> Result<RealsenseConfig, StartError> {
    match profile.section(REALSENSE_SECTION) {
        None => Ok(RealsenseConfig::default()),
        Some(section) => parse(section).map_err(|(field, reason)| StartError::Incompatible {
            field: REALSENSE_SECTION,
            reason: format!("{field}: {reason}"),
        }),
    }
}

fn parse(section: &toml::Table) -> Result<RealsenseConfig, SectionError> {
    serde_path_to_error::deserialize(toml::Value::Table(section.clone())).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner().to_string();
        (if path == "." { String::new() } else { path }, inner.lines().next().unwrap_or("").trim().to_owned())
    })
}

/// The backend.
#[derive(Debug)]
struct RealsenseBackend;

impl SourceBackend for RealsenseBackend {
    fn name(&self) -> &'static str {
        REALSENSE_SOURCE
    }

    fn load_section(&self, section: &mut toml::Table) -> Result<(), SectionError> {
        parse(section)?.validate()
    }

    fn validate(&self, profile: &Profile) -> Result<(), SectionError> {
        let config = realsense_config(profile).map_err(|e| (REALSENSE_SECTION.to_owned(), e.to_string()))?;
        if profile.pose.source == PoseSourceKind::Frame && config.world_from_camera.is_none() {
            return Err((
                "pose.source".to_owned(),
                "a RealSense camera carries no poses: set pose.source = \"ipc\" (the navigation stack publishes them) \
                 or give source.realsense.world_from_camera for a camera that does not move"
                    .to_owned(),
            ));
        }
        let paced_by_us = config.is_playback() && !config.bag_real_time;
        if profile.source.rate_hz != 0.0 && !paced_by_us {
            return Err((
                "source.rate_hz".to_owned(),
                format!(
                    "must be 0 with source.kind = \"realsense\": the camera (or real-time playback) paces frames; got {}",
                    profile.source.rate_hz
                ),
            ));
        }
        Ok(())
    }

    fn open(&self, profile: &Profile) -> Result<OpenedSource, StartError> {
        let config = realsense_config(profile)?;
        // Relative `bag` paths were resolved against the profile's folder when it loaded.
        let source = RealsenseSource::open(&config, None)?;
        // With `imu = true` the IMU samples (`Arc<op3dsg_realsense::imu::ImuBuffer>`) are the
        // side channel, for the stages that know the type.
        let side_channel = source.imu().map(|imu| imu as Arc<dyn std::any::Any + Send + Sync>);
        Ok(OpenedSource { source: Box::new(source), side_channel })
    }
}
