//! The backends the runtime provides itself: sources `replay` and `mcap`, detectors `yolox` and
//! `open_vocab` (with `[detector.region_encoder]` around any detector) and `remote`, fusion
//! `op3dsg`.

use std::sync::{Arc, Mutex, PoisonError};

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::mcap::{McapReplayConfig, McapSource};
use op3dsg_drivers::replay::{PlaybackMode, ReplaySource};
use serde::Deserialize as _;

use super::{DetectorBackend, DetectorFactory, FusionBackend, OpenedSource, SectionError, SourceBackend, StartError};
use crate::capture::REPLAY_SOURCE;
use crate::config::Profile;
use crate::fusion::{Fusion, OP3DSG_FUSION};
use crate::knowledge::KnowledgeBase;
use crate::onnx::{OnnxError, OnnxRuntime};
use crate::perception::open_vocab::OpenVocabDetector;
use crate::perception::region_encoder::{RegionEncoder, RegionEncoderConfig, WithRegionEncoder};
use crate::perception::remote::REMOTE_DETECTOR;
#[cfg(feature = "zenoh")]
use crate::perception::remote::{RemoteClient, RemoteDetector};
use crate::perception::yolox::YoloxDetector;
use crate::perception::{Detection, Detector, DetectorError, OPEN_VOCAB_DETECTOR, YOLOX_DETECTOR};
use crate::zenoh::ZenohSession;

pub(super) fn sources() -> Vec<Arc<dyn SourceBackend>> {
    vec![Arc::new(ReplayBackend), Arc::new(McapBackend)]
}

pub(super) fn detectors() -> Vec<Arc<dyn DetectorBackend>> {
    vec![Arc::new(YoloxBackend), Arc::new(OpenVocabBackend), Arc::new(RemoteBackend)]
}

pub(super) fn fusions() -> Vec<Arc<dyn FusionBackend>> {
    vec![Arc::new(Op3dsgFusionBackend)]
}

/// `fusion.method = "op3dsg"`: the paper's part-aware fusion (`[fusion]`).
struct Op3dsgFusionBackend;

impl FusionBackend for Op3dsgFusionBackend {
    fn name(&self) -> &'static str {
        OP3DSG_FUSION
    }

    fn build(&self, profile: &Profile) -> Result<Box<dyn Fusion>, StartError> {
        Ok(crate::fusion::build(&profile.fusion, profile.world.up_axis))
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

/// `detector.kind = "remote"` (`[detector.remote]`): its detectors come from [`remote`], which
/// also prepares the fallback's; by itself it has no fallback (`skip`).
struct RemoteBackend;

impl DetectorBackend for RemoteBackend {
    fn name(&self) -> &'static str {
        REMOTE_DETECTOR
    }

    fn prepare(&self, profile: &Profile, _source: &OpenedSource) -> Result<DetectorFactory, StartError> {
        remote(profile, None, None)
    }
}

/// The remote detectors of `[detector.remote]` on `session` (the process's session of
/// `[zenoh]`, which the Zenoh stage shares; opened here when the caller has none), each with its
/// own detector of `fallback`'s factory.
#[cfg(feature = "zenoh")]
pub(super) fn remote(
    profile: &Profile,
    session: Option<&ZenohSession>,
    fallback: Option<DetectorFactory>,
) -> Result<DetectorFactory, StartError> {
    let session = match session {
        Some(session) => session.clone(),
        None => ZenohSession::open(&profile.zenoh).map_err(StartError::Zenoh)?,
    };
    let client = RemoteClient::open(session.session().clone(), &profile.zenoh.prefix(), &profile.detector.remote)
        .map_err(StartError::Zenoh)?;
    Ok(Arc::new(move |worker| {
        let fallback = fallback.as_ref().map(|f| f(worker));
        Box::new(RemoteDetector::new(client.clone(), fallback)) as Box<dyn Detector>
    }))
}

/// Without the cargo feature `zenoh` there is no remote detection (`Profile::validate` refuses
/// the profile before it gets here).
#[cfg(not(feature = "zenoh"))]
pub(super) fn remote(
    _profile: &Profile,
    _session: Option<&ZenohSession>,
    _fallback: Option<DetectorFactory>,
) -> Result<DetectorFactory, StartError> {
    Err(StartError::Zenoh(
        "detector.kind = \"remote\" needs Zenoh, which this build leaves out: build with the cargo feature `zenoh`"
            .to_owned(),
    ))
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
pub(super) fn with_region_encoder(
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
