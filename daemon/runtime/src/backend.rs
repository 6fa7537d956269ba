//! The registry of frame-source and detector backends a profile names with `source.kind` and
//! `detector.kind`, and the composition of the ones the runtime provides itself.
//!
//! The runtime brings `replay` (recorded RGB-D, [`op3dsg_drivers::replay`]) and the ONNX
//! detectors `yolox` and `open_vocab`. Other backends register here and own their profile
//! section (`[source.<name>]`, `[detector.<name>]`): the `op3dsgd` binary registers the
//! simulator's `synthetic` source and `oracle` detector this way, so the runtime never sees a
//! synthetic scene or its ground truth. A source may hand its detectors an opaque side channel
//! ([`OpenedSource::side_channel`]); the runtime passes it along without looking inside.
//!
//! ```
//! use op3dsg_runtime::backend::Backends;
//! let backends = Backends::runtime();
//! assert!(backends.source("replay").is_ok());
//! assert!(backends.detector("yolox").is_ok());
//! assert!(backends.source("synthetic").is_err());
//! ```

use std::any::Any;
use std::sync::{Arc, Mutex, PoisonError};

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::mcap::{McapReplayConfig, McapSource};
use op3dsg_drivers::replay::{PlaybackMode, ReplaySource};
use op3dsg_drivers::source::FrameSource;
use serde::Deserialize as _;

use crate::config::{OPEN_VOCAB_DETECTOR, Profile, REPLAY_SOURCE, YOLOX_DETECTOR};
use crate::knowledge::KnowledgeBase;
use crate::onnx::{OnnxError, OnnxRuntime};
use crate::perception::open_vocab::OpenVocabDetector;
use crate::perception::region_encoder::{RegionEncoder, RegionEncoderConfig, WithRegionEncoder};
use crate::perception::yolox::YoloxDetector;
use crate::perception::{Detection, Detector, DetectorError};
use crate::pipeline::StartError;
use crate::record::SideChannelTap;

/// A check of a backend's section failed: `(field path inside the section, message)`; the
/// loader prefixes the section's path and names the file that set the field.
pub type SectionError = (String, String);

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

/// The backends a build knows, by name.
#[derive(Clone)]
pub struct Backends {
    sources: Vec<Arc<dyn SourceBackend>>,
    detectors: Vec<Arc<dyn DetectorBackend>>,
}

impl std::fmt::Debug for Backends {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Backends")
            .field("sources", &self.source_names())
            .field("detectors", &self.detector_names())
            .finish()
    }
}

impl Backends {
    /// The runtime's own backends: source `replay`, detectors `yolox` and `open_vocab`.
    pub fn runtime() -> Self {
        Self {
            sources: vec![Arc::new(ReplayBackend), Arc::new(McapBackend)],
            detectors: vec![Arc::new(YoloxBackend), Arc::new(OpenVocabBackend)],
        }
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

    /// Opens the profile's source and prepares its detectors, as the pipeline and the batch
    /// runner both do.
    pub fn open(&self, profile: &Profile) -> Result<(OpenedSource, DetectorFactory), StartError> {
        let opened = self.source(&profile.source.kind)?.open(profile)?;
        let factory = self.detector(&profile.detector.kind)?.prepare(profile, &opened)?;
        let factory = match &profile.detector.region_encoder {
            Some(config) => with_region_encoder(profile, factory, config)?,
            None => factory,
        };
        Ok((opened, factory))
    }
}

/// `source.kind = "replay"`: a recording in the TUM RGB-D layout (`[source.replay]`).
struct ReplayBackend;

impl SourceBackend for ReplayBackend {
    fn name(&self) -> &'static str {
        REPLAY_SOURCE
    }

    fn open(&self, profile: &Profile) -> Result<OpenedSource, StartError> {
        let Some(config) = &profile.source.replay else {
            return Err(StartError::Incompatible {
                field: "source.replay",
                reason: "required with source.kind = \"replay\"".to_owned(),
            });
        };
        Ok(OpenedSource { source: Box::new(ReplaySource::new(config)?), side_channel: None })
    }
}

/// `source.kind` of a recording the recorder wrote (`[source.mcap]`).
pub const MCAP_SOURCE: &str = "mcap";

/// `source.kind = "mcap"`: replays the raw input of recordings of `crate::record`
/// (`[source.mcap]`: `path`, `mode`; [`op3dsg_drivers::mcap::McapSource`]).
#[derive(Debug, Clone, Copy, Default)]
pub struct McapBackend;

impl McapBackend {
    /// `[source.mcap]` of `profile`, typed.
    pub fn config(profile: &Profile) -> Result<McapReplayConfig, StartError> {
        let section = profile.section("source.mcap").cloned().unwrap_or_default();
        McapReplayConfig::deserialize(toml::Value::Table(section))
            .map_err(|e| StartError::Incompatible { field: "source.mcap", reason: e.to_string() })
    }

    /// Opens the recording `[source.mcap]` names, for a backend that wraps this one (the
    /// simulator's, which adds the instance-id side channel).
    pub fn open_source(profile: &Profile) -> Result<McapSource, StartError> {
        Ok(McapSource::new(&Self::config(profile)?)?)
    }
}

impl SourceBackend for McapBackend {
    fn name(&self) -> &'static str {
        MCAP_SOURCE
    }

    fn load_section(&self, section: &mut toml::Table) -> Result<(), SectionError> {
        let config: McapReplayConfig =
            serde_path_to_error::deserialize(toml::Value::Table(section.clone())).map_err(|e| {
                let path = e.path().to_string();
                let inner = e.into_inner().to_string();
                (if path == "." { String::new() } else { path }, inner.lines().next().unwrap_or("").trim().to_owned())
            })?;
        config.validate("").map_err(|e| (String::new(), e.trim_start_matches('.').to_owned()))
    }

    fn validate(&self, profile: &Profile) -> Result<(), SectionError> {
        if profile.source.kind != MCAP_SOURCE {
            return Ok(());
        }
        let config = Self::config(profile).map_err(|e| ("source.mcap".to_owned(), e.to_string()))?;
        if config.mode != PlaybackMode::Fast && profile.source.rate_hz != 0.0 {
            return Err((
                "source.mcap.mode".to_owned(),
                format!(
                    "{:?} paces frames itself; set source.rate_hz = 0 (it is {})",
                    config.mode, profile.source.rate_hz
                )
                .to_lowercase(),
            ));
        }
        Ok(())
    }

    fn open(&self, profile: &Profile) -> Result<OpenedSource, StartError> {
        Ok(OpenedSource { source: Box::new(Self::open_source(profile)?), side_channel: None })
    }
}

/// `detector.kind = "yolox"` (`[detector.yolox]`).
struct YoloxBackend;

impl DetectorBackend for YoloxBackend {
    fn name(&self) -> &'static str {
        YOLOX_DETECTOR
    }

    fn prepare(&self, profile: &Profile, _source: &OpenedSource) -> Result<DetectorFactory, StartError> {
        let runtime = OnnxRuntime::init(&profile.onnx)?;
        let config = profile.detector.yolox.clone();
        preloaded_factory(profile.detector.workers, move || {
            YoloxDetector::new(&runtime, &config).map(|d| Box::new(d) as Box<dyn Detector>)
        })
    }
}

/// `detector.kind = "open_vocab"` (`[detector.open_vocab]`, `[text_encoder]`).
struct OpenVocabBackend;

impl DetectorBackend for OpenVocabBackend {
    fn name(&self) -> &'static str {
        OPEN_VOCAB_DETECTOR
    }

    fn prepare(&self, profile: &Profile, _source: &OpenedSource) -> Result<DetectorFactory, StartError> {
        let runtime = OnnxRuntime::init(&profile.onnx)?;
        let config = profile.detector.open_vocab.clone();
        let text_encoder = profile.text_encoder.clone();
        let knowledge = knowledge_base(profile)?;
        preloaded_factory(profile.detector.workers, move || {
            OpenVocabDetector::new(&runtime, &config, knowledge.clone(), &text_encoder)
                .map(|d| Box::new(d) as Box<dyn Detector>)
        })
    }
}

/// The knowledge base of `reasoner.knowledge_dir`, else the built-in tables (the detectors' part
/// candidates use the reasoner's tables).
pub fn knowledge_base(profile: &Profile) -> Result<Arc<KnowledgeBase>, StartError> {
    KnowledgeBase::from_profile_dir(profile.reasoner.knowledge_dir.as_deref())
        .map(Arc::new)
        .map_err(|e| StartError::Incompatible { field: "reasoner.knowledge_dir", reason: e.to_string() })
}

/// Loads one `T` (a model session) per detection worker now, so a missing runtime or model
/// stops start-up with the error that says what to run. The returned function hands worker `i`
/// its preloaded one; a worker index beyond `workers` (none in the pipeline) loads a fresh one.
fn preload<T: Send + 'static>(
    workers: usize,
    load: impl Fn() -> Result<T, OnnxError> + Send + Sync + 'static,
) -> Result<impl Fn(u32) -> Result<T, OnnxError> + Send + Sync + 'static, StartError> {
    let mut preloaded = Vec::with_capacity(workers.max(1));
    for _ in 0..workers.max(1) {
        preloaded.push(Some(load()?));
    }
    let preloaded = Mutex::new(preloaded);
    Ok(move |worker: u32| {
        let taken =
            preloaded.lock().unwrap_or_else(PoisonError::into_inner).get_mut(worker as usize).and_then(Option::take);
        taken.map_or_else(&load, Ok)
    })
}

/// The detector factory of [`preload`]ed detectors; one that fails to load later fails its
/// detections with the load error.
fn preloaded_factory(
    workers: usize,
    load: impl Fn() -> Result<Box<dyn Detector>, OnnxError> + Send + Sync + 'static,
) -> Result<DetectorFactory, StartError> {
    let take = preload(workers, load)?;
    Ok(Arc::new(move |worker| take(worker).unwrap_or_else(|e| Box::new(FailedDetector(e.to_string())))))
}

/// `factory`'s detectors with `[detector.region_encoder]` giving their detections' semantic
/// features: one encoder session per worker, [`preload`]ed so that a missing or wrong model
/// stops start-up naming the key.
fn with_region_encoder(
    profile: &Profile,
    factory: DetectorFactory,
    config: &RegionEncoderConfig,
) -> Result<DetectorFactory, StartError> {
    let runtime = OnnxRuntime::init(&profile.onnx)?;
    let config = config.clone();
    let take =
        preload(profile.detector.workers, move || RegionEncoder::new(&runtime, &config, "detector.region_encoder"))?;
    Ok(Arc::new(move |worker| match take(worker) {
        Ok(encoder) => Box::new(WithRegionEncoder::new(factory(worker), encoder)) as Box<dyn Detector>,
        Err(e) => Box::new(FailedDetector(e.to_string())),
    }))
}

/// A detector whose model could not be loaded: every detection fails with the load error.
struct FailedDetector(String);

impl Detector for FailedDetector {
    fn detect(&mut self, _frame: &Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError> {
        out.clear();
        Err(DetectorError::Backend(self.0.clone()))
    }

    fn name(&self) -> &str {
        "failed"
    }
}
