//! The registry of frame-source, detector and fusion backends a profile names with
//! `source.kind`, `detector.kind` and `fusion.method`, and the composition of the ones the
//! runtime provides itself.
//!
//! The runtime brings `replay` (recorded RGB-D, [`op3dsg_drivers::replay`]) and `mcap`, the ONNX
//! detectors `yolox` and `open_vocab`, and the OP3DSG fusion `op3dsg` (`runtime.rs`). Other
//! backends register here and own their profile section (`[source.<name>]`, `[detector.<name>]`,
//! `[fusion.<name>]`): the `op3dsgd` binary registers the simulator's `synthetic` source,
//! `oracle` detector and `conceptgraphs` peer fusion this way, so the runtime never sees a
//! synthetic scene, its ground truth or a research baseline. A source may hand its detectors an
//! opaque side channel ([`OpenedSource::side_channel`]); the runtime passes it along without
//! looking inside.
//!
//! ```
//! use op3dsg_runtime::backend::Backends;
//! let backends = Backends::runtime();
//! assert!(backends.source("replay").is_ok());
//! assert!(backends.detector("yolox").is_ok());
//! assert!(backends.source("synthetic").is_err());
//! ```

use std::any::Any;
use std::sync::Arc;

use op3dsg_drivers::source::{FrameSource, SourceError};

pub use crate::config::SectionError;
use crate::config::{Profile, SectionRegistry};
use crate::fusion::Fusion;
use crate::fusion::snapshot::SnapshotError;
use crate::onnx::OnnxError;
use crate::perception::Detector;
use crate::perception::remote::{REMOTE_DETECTOR, SKIP_FALLBACK};
use crate::record::SideChannelTap;
use crate::zenoh::ZenohSession;

mod runtime;

pub use runtime::{MCAP_SOURCE, McapBackend, knowledge_base};

/// Errors that stop the pipeline from starting.
#[derive(Debug, thiserror::Error)]
pub enum StartError {
    /// The frame source could not be opened.
    #[error("source: {0}")]
    Source(#[from] SourceError),
    /// The profile combines things that cannot work together.
    #[error("{field}: {reason}")]
    Incompatible {
        /// Profile field.
        field: &'static str,
        /// Why.
        reason: String,
    },
    /// The iceoryx2 services could not be created.
    #[error("iceoryx2: {0}")]
    Ipc(String),
    /// A model or the ONNX Runtime could not be loaded (the message says what to run).
    #[error("detector: {0}")]
    Model(#[from] OnnxError),
    /// The snapshot directory could not be used (or another daemon holds it).
    #[error("snapshot.dir: {0}")]
    Snapshot(#[from] SnapshotError),
    /// A Zenoh session could not be opened (the message names the `[zenoh]` or `[ros2]` key).
    #[error("{0}")]
    Zenoh(String),
    /// A thread could not be started.
    #[error("thread {name}: {reason}")]
    Thread {
        /// Thread name.
        name: String,
        /// OS error.
        reason: String,
    },
}

/// The process's one Zenoh session on the robot's network (`[zenoh]`), opened when the Zenoh
/// stage (`zenoh.enabled`) or remote detection (`detector.kind = "remote"`) needs it: both use
/// it, so the listeners and connections of `[zenoh]` serve both. `None` when nothing needs it.
pub fn zenoh_session(profile: &Profile) -> Result<Option<ZenohSession>, StartError> {
    if !(profile.zenoh.enabled || profile.detector.kind == REMOTE_DETECTOR) {
        return Ok(None);
    }
    ZenohSession::open(&profile.zenoh).map(Some).map_err(StartError::Zenoh)
}

/// Makes one detector per worker (the argument is the worker index, for logs only).
pub type DetectorFactory = Arc<dyn Fn(u32) -> Box<dyn Detector> + Send + Sync>;

/// What a source backend opened.
pub struct OpenedSource {
    /// The source, for the capture thread (or the batch runner).
    pub source: Box<dyn FrameSource>,
    /// What the source hands its detectors besides frames (the simulator's ground truth), for
    /// detector backends that know its type; opaque to the runtime.
    pub side_channel: Option<Arc<dyn Any + Send + Sync>>,
}

impl std::fmt::Debug for OpenedSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpenedSource")
            .field("source", &self.source.describe())
            .field("side_channel", &self.side_channel.is_some())
            .finish()
    }
}

/// A frame source a profile can name in `source.kind`.
pub trait SourceBackend: Send + Sync {
    /// The name in `source.kind` and of its section `[source.<name>]`.
    fn name(&self) -> &'static str;

    /// Checks, and may complete, the backend's section when the profile is loaded. The section
    /// is empty when the profile has none.
    fn load_section(&self, _section: &mut toml::Table) -> Result<(), SectionError> {
        Ok(())
    }

    /// Cross-checks against the whole profile, after it loaded (`(field path, message)`).
    fn validate(&self, _profile: &Profile) -> Result<(), SectionError> {
        Ok(())
    }

    /// Opens the source the profile describes.
    fn open(&self, profile: &Profile) -> Result<OpenedSource, StartError>;

    /// Side channels of an opened source the recorder writes with each frame
    /// (`[record.channels] side_channels`): the simulator's instance ids, so a recording of a
    /// synthetic run can replay with the oracle detector. None by default.
    fn side_channel_taps(&self, _opened: &OpenedSource) -> Vec<Box<dyn SideChannelTap>> {
        Vec::new()
    }
}

/// A detector a profile can name in `detector.kind`.
pub trait DetectorBackend: Send + Sync {
    /// The name in `detector.kind` and of its section `[detector.<name>]`.
    fn name(&self) -> &'static str;

    /// Checks, and may complete, the backend's section when the profile is loaded.
    fn load_section(&self, _section: &mut toml::Table) -> Result<(), SectionError> {
        Ok(())
    }

    /// Cross-checks against the whole profile, after it loaded (`(field path, message)`).
    fn validate(&self, _profile: &Profile) -> Result<(), SectionError> {
        Ok(())
    }

    /// Loads what the workers need now (models, tables), so that a missing file stops start-up,
    /// and returns the factory that makes each worker's detector.
    fn prepare(&self, profile: &Profile, source: &OpenedSource) -> Result<DetectorFactory, StartError>;
}

/// A map a profile can name in `fusion.method`.
pub trait FusionBackend: Send + Sync {
    /// The name in `fusion.method` and of its section `[fusion.<name>]`.
    fn name(&self) -> &'static str;

    /// Checks, and may complete, the backend's section when the profile is loaded.
    fn load_section(&self, _section: &mut toml::Table) -> Result<(), SectionError> {
        Ok(())
    }

    /// Makes an empty map as the profile describes it.
    fn build(&self, profile: &Profile) -> Result<Box<dyn Fusion>, StartError>;
}

/// The backends a build knows, by name.
#[derive(Clone)]
pub struct Backends {
    sources: Vec<Arc<dyn SourceBackend>>,
    detectors: Vec<Arc<dyn DetectorBackend>>,
    fusions: Vec<Arc<dyn FusionBackend>>,
}

impl std::fmt::Debug for Backends {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Backends")
            .field("sources", &self.source_names())
            .field("detectors", &self.detector_names())
            .field("fusions", &self.fusion_names())
            .finish()
    }
}

impl Backends {
    /// The runtime's own backends: sources `replay` and `mcap`, detectors `yolox` and
    /// `open_vocab`, fusion `op3dsg`.
    pub fn runtime() -> Self {
        Self { sources: runtime::sources(), detectors: runtime::detectors(), fusions: runtime::fusions() }
    }

    /// Adds (or replaces, by name) a source backend.
    pub fn register_source(&mut self, backend: Arc<dyn SourceBackend>) -> &mut Self {
        self.sources.retain(|b| b.name() != backend.name());
        self.sources.push(backend);
        self
    }

    /// Adds (or replaces, by name) a detector backend.
    pub fn register_detector(&mut self, backend: Arc<dyn DetectorBackend>) -> &mut Self {
        self.detectors.retain(|b| b.name() != backend.name());
        self.detectors.push(backend);
        self
    }

    /// Adds (or replaces, by name) a fusion backend.
    pub fn register_fusion(&mut self, backend: Arc<dyn FusionBackend>) -> &mut Self {
        self.fusions.retain(|b| b.name() != backend.name());
        self.fusions.push(backend);
        self
    }

    /// Names of the source backends, sorted.
    pub fn source_names(&self) -> Vec<&'static str> {
        let mut names: Vec<_> = self.sources.iter().map(|b| b.name()).collect();
        names.sort_unstable();
        names
    }

    /// Names of the detector backends, sorted.
    pub fn detector_names(&self) -> Vec<&'static str> {
        let mut names: Vec<_> = self.detectors.iter().map(|b| b.name()).collect();
        names.sort_unstable();
        names
    }

    /// Names of the fusion backends, sorted.
    pub fn fusion_names(&self) -> Vec<&'static str> {
        let mut names: Vec<_> = self.fusions.iter().map(|b| b.name()).collect();
        names.sort_unstable();
        names
    }

    /// The source backend called `name`, or an error listing the ones this build has.
    pub fn source(&self, name: &str) -> Result<&Arc<dyn SourceBackend>, StartError> {
        self.sources.iter().find(|b| b.name() == name).ok_or_else(|| StartError::Incompatible {
            field: "source.kind",
            reason: format!("no source \"{name}\" in this build (it has: {})", self.source_names().join(", ")),
        })
    }

    /// The detector backend called `name`, or an error listing the ones this build has.
    pub fn detector(&self, name: &str) -> Result<&Arc<dyn DetectorBackend>, StartError> {
        self.detectors.iter().find(|b| b.name() == name).ok_or_else(|| StartError::Incompatible {
            field: "detector.kind",
            reason: format!("no detector \"{name}\" in this build (it has: {})", self.detector_names().join(", ")),
        })
    }

    /// The fusion backend called `name`, or an error listing the ones this build has.
    pub fn fusion_backend(&self, name: &str) -> Result<&Arc<dyn FusionBackend>, StartError> {
        self.fusions.iter().find(|b| b.name() == name).ok_or_else(|| StartError::Incompatible {
            field: "fusion.method",
            reason: format!("no fusion \"{name}\" in this build (it has: {})", self.fusion_names().join(", ")),
        })
    }

    /// The empty map the profile asks for (`fusion.method`), as the pipeline and the batch
    /// runner both make it.
    pub fn fusion(&self, profile: &Profile) -> Result<Box<dyn Fusion>, StartError> {
        self.fusion_backend(&profile.fusion.method)?.build(profile)
    }

    /// Opens the profile's source and prepares its detectors, as the pipeline and the batch
    /// runner both do. Remote detection uses `zenoh`, the process's session
    /// ([`zenoh_session`]), or opens one when there is none.
    pub fn open(
        &self,
        profile: &Profile,
        zenoh: Option<&ZenohSession>,
    ) -> Result<(OpenedSource, DetectorFactory), StartError> {
        let opened = self.source(&profile.source.kind)?.open(profile)?;
        let factory = self.prepare_detectors(profile, &profile.detector.kind, &opened, zenoh)?;
        Ok((opened, factory))
    }

    /// The factory of detector `kind` (with `[detector.region_encoder]` around it), as `open`
    /// and a detection worker process (`op3dsg-detectd`) make it. `remote` prepares its
    /// fallback (`detector.remote.fallback`) the same way; the region encoder then runs on the
    /// worker, not around the remote detector.
    pub fn prepare_detectors(
        &self,
        profile: &Profile,
        kind: &str,
        opened: &OpenedSource,
        zenoh: Option<&ZenohSession>,
    ) -> Result<DetectorFactory, StartError> {
        if kind == REMOTE_DETECTOR {
            let fallback = &profile.detector.remote.fallback;
            let fallback = (fallback != SKIP_FALLBACK)
                .then(|| self.prepare_detectors(profile, fallback, opened, zenoh))
                .transpose()?;
            return runtime::remote(profile, zenoh, fallback);
        }
        let factory = self.detector(kind)?.prepare(profile, opened)?;
        Ok(match &profile.detector.region_encoder {
            Some(config) => runtime::with_region_encoder(profile, factory, config)?,
            None => factory,
        })
    }
}

impl SectionRegistry for Backends {
    fn load_section(&self, group: &str, name: &str, section: &mut toml::Table) -> Result<(), SectionError> {
        let (found, known) = match group {
            "source" => (self.source(name).map(|b| b.load_section(section)).ok(), self.source_names()),
            "detector" => (self.detector(name).map(|b| b.load_section(section)).ok(), self.detector_names()),
            _ => (self.fusion_backend(name).map(|b| b.load_section(section)).ok(), self.fusion_names()),
        };
        found.unwrap_or_else(|| {
            Err((String::new(), format!("no {group} backend \"{name}\" in this build (it has: {})", known.join(", "))))
        })
    }

    fn check_kinds(&self, profile: &Profile) -> Result<(), SectionError> {
        let to_pair = |e: StartError| match e {
            StartError::Incompatible { field, reason } => (field.to_owned(), reason),
            other => (String::new(), other.to_string()),
        };
        let source = self.source(&profile.source.kind).map_err(to_pair)?;
        let detector = self.detector(&profile.detector.kind).map_err(to_pair)?;
        self.fusion_backend(&profile.fusion.method).map_err(to_pair)?;
        source.validate(profile)?;
        if profile.detector.kind == REMOTE_DETECTOR && profile.detector.remote.fallback != SKIP_FALLBACK {
            let fallback = &profile.detector.remote.fallback;
            let backend = self.detector(fallback).map_err(|_| {
                (
                    "detector.remote.fallback".to_owned(),
                    format!(
                        "no detector \"{fallback}\" in this build (\"skip\" or one of: {})",
                        self.detector_names()
                            .into_iter()
                            .filter(|n| *n != REMOTE_DETECTOR)
                            .collect::<Vec<_>>()
                            .join(", ")
                    ),
                )
            })?;
            backend.validate(profile)?;
        }
        detector.validate(profile)
    }
}
