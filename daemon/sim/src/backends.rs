//! The simulator's backends for the runtime: `source.kind = "synthetic"` (the seeded rooms of
//! `op3dsg-synthetic`) and `detector.kind = "oracle"` (the noisy ideal detector that reads
//! their ground truth), registered with [`op3dsg_runtime::backend::Backends`] like any other
//! backend. The ground truth goes from the source to the oracle through the runtime's opaque
//! side channel ([`op3dsg_runtime::backend::OpenedSource::side_channel`]), never through a
//! frame or a detection.
//!
//! Their profile sections, `[source.synthetic]` ([`SyntheticConfig`]) and `[detector.oracle]`
//! ([`OracleConfig`], with `preset = "clean" | "realistic"` expanded at load), are checked here
//! when the profile loads; [`synthetic_config`] / [`oracle_config`] read them back typed and
//! [`set_synthetic_config`] / [`set_oracle_config`] write them from code.
//!
//! ```
//! let loaded = op3dsg_sim::load_profile(None, &["source.synthetic.seed=3".to_owned()]).unwrap();
//! assert_eq!(op3dsg_sim::backends::synthetic_config(&loaded.profile).unwrap().seed, 3);
//! ```

use std::collections::HashMap;
use std::path::Path;
use std::sync::Arc;

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::mcap::messages::RawImageIn;
use op3dsg_drivers::source::FrameSource as _;
use op3dsg_runtime::backend::StartError;
use op3dsg_runtime::backend::{
    Backends, DetectorBackend, DetectorFactory, MCAP_SOURCE, McapBackend, OpenedSource, SectionError, SourceBackend,
    knowledge_base,
};
use op3dsg_runtime::config::{self, LoadedProfile, Profile, ProfileError};
use op3dsg_runtime::onnx::OnnxRuntime;
use op3dsg_runtime::onnx::text_encoder::TextEncoder;
use op3dsg_runtime::perception::Detector;
use op3dsg_runtime::perception::candidates::{CandidateMode, PartCandidates};
use op3dsg_runtime::record::SideChannelTap;
use op3dsg_synthetic::{GroundTruth, InstanceIdChannel, InstanceInfo, SyntheticConfig, SyntheticSource};
use serde::Serialize;
use serde::de::DeserializeOwned;
use tracing::warn;

use crate::oracle::{ConfusionTable, OracleConfig, OracleDetector, SemanticSource};

/// `source.kind` of the synthetic rooms.
pub const SYNTHETIC_SOURCE: &str = "synthetic";
/// `detector.kind` of the oracle detector.
pub const ORACLE_DETECTOR: &str = "oracle";
/// Profile path of the synthetic source's section.
pub const SYNTHETIC_SECTION: &str = "source.synthetic";
/// Profile path of the oracle detector's section.
pub const ORACLE_SECTION: &str = "detector.oracle";

/// The runtime's backends plus the simulator's: what `op3dsgd` and every `op3dsg` command use.
pub fn backends() -> Backends {
    let mut backends = Backends::runtime();
    backends
        .register_source(Arc::new(SyntheticBackend))
        .register_source(Arc::new(SimMcapBackend))
        .register_detector(Arc::new(OracleBackend))
        .register_fusion(Arc::new(crate::conceptgraphs::ConceptGraphsBackend));
    backends
}

/// [`config::load_with`] with [`backends`].
pub fn load_profile(profile_path: Option<&Path>, overrides: &[String]) -> Result<LoadedProfile, ProfileError> {
    config::load_with(&backends(), profile_path, overrides)
}

/// `[source.synthetic]` of `profile`, typed (the defaults when the profile has none).
pub fn synthetic_config(profile: &Profile) -> Result<SyntheticConfig, StartError> {
    typed_section(profile, SYNTHETIC_SECTION)
}

/// Writes `config` as `[source.synthetic]` of `profile`.
pub fn set_synthetic_config(profile: &mut Profile, config: &SyntheticConfig) {
    write_section(profile, SYNTHETIC_SECTION, config);
}

/// Changes `[source.synthetic]` of `profile` in place (for code that varies a loaded profile:
/// benchmarks, tests). A section that does not parse (a profile built by hand, not loaded) is an
/// error naming the section and field; the profile is then left unchanged.
pub fn edit_synthetic(profile: &mut Profile, edit: impl FnOnce(&mut SyntheticConfig)) -> Result<(), StartError> {
    let mut config = synthetic_config(profile)?;
    edit(&mut config);
    set_synthetic_config(profile, &config);
    Ok(())
}

/// `[detector.oracle]` of `profile`, typed (presets already expanded at load).
pub fn oracle_config(profile: &Profile) -> Result<OracleConfig, StartError> {
    typed_section(profile, ORACLE_SECTION)
}

/// Writes `config` as `[detector.oracle]` of `profile`.
pub fn set_oracle_config(profile: &mut Profile, config: &OracleConfig) {
    write_section(profile, ORACLE_SECTION, config);
}

fn typed_section<T: DeserializeOwned + Default>(profile: &Profile, path: &'static str) -> Result<T, StartError> {
    match profile.section(path) {
        None => Ok(T::default()),
        Some(section) => parse_section(section).map_err(|(field, message)| StartError::Incompatible {
            field: path,
            reason: format!("{field}: {message}"),
        }),
    }
}

fn write_section<T: Serialize>(profile: &mut Profile, path: &str, value: &T) {
    // A config struct of plain fields always converts to a table.
    if let Ok(table) = toml::Table::try_from(value) {
        profile.set_section(path, table);
    }
}

/// Deserialises a section, naming the offending field.
fn parse_section<T: DeserializeOwned>(section: &toml::Table) -> Result<T, SectionError> {
    serde_path_to_error::deserialize(toml::Value::Table(section.clone())).map_err(|e| {
        let path = e.path().to_string();
        let inner = e.into_inner().to_string();
        (if path == "." { String::new() } else { path }, inner.lines().next().unwrap_or("").trim().to_owned())
    })
}

fn check(ok: bool, field: &str, message: impl FnOnce() -> String) -> Result<(), SectionError> {
    if ok { Ok(()) } else { Err((field.to_owned(), message())) }
}

/// `source.kind = "synthetic"`.
struct SyntheticBackend;

impl SourceBackend for SyntheticBackend {
    fn name(&self) -> &'static str {
        SYNTHETIC_SOURCE
    }

    fn load_section(&self, section: &mut toml::Table) -> Result<(), SectionError> {
        let syn: SyntheticConfig = parse_section(section)?;
        check(syn.frame_rate_hz > 0.0 && syn.frame_rate_hz <= 1000.0, "frame_rate_hz", || {
            format!("must be within (0, 1000], got {}", syn.frame_rate_hz)
        })?;
        check(syn.intrinsics.width >= 16 && syn.intrinsics.height >= 16, "intrinsics", || {
            format!("image must be at least 16x16, got {}x{}", syn.intrinsics.width, syn.intrinsics.height)
        })?;
        check(syn.intrinsics.fx > 0.0 && syn.intrinsics.fy > 0.0, "intrinsics.fx", || {
            "focal lengths must be > 0".to_owned()
        })?;
        if let Some(noise) = &syn.depth_noise {
            let p = "depth_noise";
            check(noise.sigma_at_1m_m >= 0.0 && noise.sigma_at_1m_m < 0.1, &format!("{p}.sigma_at_1m_m"), || {
                format!("must be within [0, 0.1) metres, got {}", noise.sigma_at_1m_m)
            })?;
            check(
                noise.min_range_m >= 0.0 && noise.max_range_m > noise.min_range_m,
                &format!("{p}.max_range_m"),
                || format!("must be greater than min_range_m ({}), got {}", noise.min_range_m, noise.max_range_m),
            )?;
            for (name, v) in [
                ("edge_hole_probability", noise.edge_hole_probability),
                ("random_hole_probability", noise.random_hole_probability),
            ] {
                check((0.0..=1.0).contains(&v), &format!("{p}.{name}"), || format!("must be within [0, 1], got {v}"))?;
            }
        }
        check_change_script(&syn)
    }

    fn open(&self, profile: &Profile) -> Result<OpenedSource, StartError> {
        let source = SyntheticSource::new(&synthetic_config(profile)?)?;
        let truth: Arc<GroundTruth> = Arc::new(source.ground_truth());
        Ok(OpenedSource { source: Box::new(source), side_channel: Some(truth) })
    }

    fn side_channel_taps(&self, opened: &OpenedSource) -> Vec<Box<dyn SideChannelTap>> {
        instance_id_taps(opened)
    }
}

/// Checks `[[source.synthetic.changes]]` against the room it changes (generated here, with its
/// camera path), so a bad script stops the profile's load naming `changes[i].<key>`.
fn check_change_script(syn: &SyntheticConfig) -> Result<(), SectionError> {
    if syn.changes.is_empty() {
        return Ok(());
    }
    match syn.final_scene() {
        Ok(_) => Ok(()),
        Err(op3dsg_drivers::source::SourceError::Config(message)) => Err(match message.split_once(": ") {
            Some((field, reason)) => (field.to_owned(), reason.to_owned()),
            None => ("changes".to_owned(), message),
        }),
        Err(other) => Err(("changes".to_owned(), other.to_string())),
    }
}

/// Topic of the synthetic renderer's per-pixel instance ids in a recording (simulation only):
/// what the oracle detector reads, so a recorded synthetic run replays with the same detector.
pub const INSTANCE_IDS_TOPIC: &str = "/sim/instance_ids";

/// Records the instance ids of each frame of a source that has them.
struct InstanceIdTap(InstanceIdChannel);

impl SideChannelTap for InstanceIdTap {
    fn topic(&self) -> &str {
        INSTANCE_IDS_TOPIC
    }

    fn copy(&mut self, frame: &Frame, out: &mut [u16]) -> bool {
        self.0
            .with_ids(frame, |ids| {
                if ids.len() == out.len() {
                    out.copy_from_slice(ids);
                    true
                } else {
                    false
                }
            })
            .unwrap_or(false)
    }
}

fn instance_id_taps(opened: &OpenedSource) -> Vec<Box<dyn SideChannelTap>> {
    ground_truth(opened)
        .map(|truth| vec![Box::new(InstanceIdTap(truth.instance_ids.clone())) as Box<dyn SideChannelTap>])
        .unwrap_or_default()
}

/// `source.kind = "mcap"` in the simulator's build: the runtime's replay of a recording
/// ([`McapBackend`]), plus, when the recording holds [`INSTANCE_IDS_TOPIC`] (it was a synthetic
/// run), the ground truth for the oracle detector: the scene regenerated from the
/// `[source.synthetic]` section of the profile *the recording was made with* (its
/// `op3dsg.profile` metadata), and each frame's instance ids from the recording. A recording
/// from a camera has no such channel and replays exactly as in the runtime.
struct SimMcapBackend;

impl SourceBackend for SimMcapBackend {
    fn name(&self) -> &'static str {
        MCAP_SOURCE
    }

    fn load_section(&self, section: &mut toml::Table) -> Result<(), SectionError> {
        McapBackend.load_section(section)
    }

    fn validate(&self, profile: &Profile) -> Result<(), SectionError> {
        McapBackend.validate(profile)
    }

    fn open(&self, profile: &Profile) -> Result<OpenedSource, StartError> {
        let source = McapBackend::open_source(profile)?;
        if !source.has_channel(INSTANCE_IDS_TOPIC)? {
            return Ok(OpenedSource { source: Box::new(source), side_channel: None });
        }
        let recorded = source.recorded_profile()?.ok_or_else(|| StartError::Incompatible {
            field: "source.mcap.path",
            reason: format!(
                "{} has {INSTANCE_IDS_TOPIC} but no op3dsg.profile metadata: cannot rebuild the synthetic scene",
                source.describe()
            ),
        })?;
        let synthetic = recorded_synthetic_config(&recorded).map_err(|reason| StartError::Incompatible {
            field: "source.mcap.path",
            reason: format!("{}: op3dsg.profile: {reason}", source.describe()),
        })?;
        let truth = Arc::new(SyntheticSource::new(&synthetic)?.ground_truth());
        let channel = truth.instance_ids.clone();
        let source = source.with_side_channel(
            INSTANCE_IDS_TOPIC,
            Box::new(move |frame: &mut Frame, bytes: &[u8], message_encoding: &str| {
                let image = RawImageIn::parse(bytes, message_encoding)?;
                let mut result = Ok(());
                channel.write(frame, |frame, ids| {
                    ids.resize(frame.depth.len(), 0);
                    result = image.decode_into(&["16UC1", "mono16"], 2, bytemuck::cast_slice_mut(ids.as_mut_slice()));
                });
                result
            }),
        );
        Ok(OpenedSource { source: Box::new(source), side_channel: Some(truth) })
    }

    fn side_channel_taps(&self, opened: &OpenedSource) -> Vec<Box<dyn SideChannelTap>> {
        instance_id_taps(opened)
    }
}

/// `[source.synthetic]` of a recorded effective profile.
fn recorded_synthetic_config(profile_toml: &str) -> Result<SyntheticConfig, String> {
    let table: toml::Table = profile_toml.parse().map_err(|e: toml::de::Error| e.to_string())?;
    let section = table
        .get("source")
        .and_then(|s| s.get("synthetic"))
        .and_then(toml::Value::as_table)
        .ok_or_else(|| "no [source.synthetic] section".to_owned())?;
    parse_section(section).map_err(|(field, message)| format!("source.synthetic.{field}: {message}"))
}

/// The ground truth a source opened by [`SyntheticBackend`] carries, if `opened` is one.
pub fn ground_truth(opened: &OpenedSource) -> Option<Arc<GroundTruth>> {
    opened.side_channel.clone().and_then(|channel| channel.downcast::<GroundTruth>().ok())
}

/// `detector.kind = "oracle"`.
struct OracleBackend;

impl DetectorBackend for OracleBackend {
    fn name(&self) -> &'static str {
        ORACLE_DETECTOR
    }

    fn load_section(&self, section: &mut toml::Table) -> Result<(), SectionError> {
        expand_preset(section)?;
        let oracle: OracleConfig = parse_section(section)?;
        oracle.validate("").map_err(|message| match message.split_once(": ") {
            Some((path, msg)) => (path.trim_start_matches('.').to_owned(), msg.to_owned()),
            None => (String::new(), message),
        })
    }

    fn validate(&self, profile: &Profile) -> Result<(), SectionError> {
        let oracle = oracle_config(profile).map_err(|e| (ORACLE_SECTION.to_owned(), e.to_string()))?;
        check(
            oracle.semantic_source != SemanticSource::TextEncoder || profile.text_encoder.enabled,
            "detector.oracle.semantic_source",
            || "\"text_encoder\" needs the text encoder: set [text_encoder] enabled = true".to_owned(),
        )
    }

    fn prepare(&self, profile: &Profile, source: &OpenedSource) -> Result<DetectorFactory, StartError> {
        let truth = ground_truth(source);
        if truth.is_none() {
            warn!(
                "detector.kind = \"oracle\" reads the synthetic renderer's instance ids, which {} does not have: \
                 every keyframe's detection fails and the map stays empty",
                source.source.describe()
            );
        }
        let setup = OracleSetup::new(profile, truth.as_deref())?;
        if setup.config.has_pose_noise() {
            // The pipeline's poses come from its pose source; only the batch runner perturbs them.
            warn!(
                "detector.oracle.pose_drift_fraction / pose_drift_deg_per_m / pose_jitter_m / pose_jitter_deg are \
                 applied by the batch runner only (bench quality, fusion-eval); the daemon fuses its pose source's \
                 poses unchanged"
            );
        }
        Ok(Arc::new(move |worker| Box::new(setup.detector(worker)) as Box<dyn Detector>))
    }
}

/// What each worker's oracle detector is made from: the profile's `[detector.oracle]` over the
/// ground truth of the source it detects in (none: every detection fails, naming why).
#[derive(Debug, Clone)]
pub struct OracleSetup {
    config: OracleConfig,
    instances: Vec<InstanceInfo>,
    candidates: Option<Arc<PartCandidates>>,
    vectors: Option<LabelVectors>,
    instance_ids: Option<InstanceIdChannel>,
    confusions: Option<Arc<ConfusionTable>>,
}

impl OracleSetup {
    /// Loads what the oracle needs now (prompt lists, and with `semantic_source =
    /// "text_encoder"` the label embeddings, so a missing model stops start-up).
    pub fn new(profile: &Profile, truth: Option<&GroundTruth>) -> Result<Self, StartError> {
        let config = oracle_config(profile)?;
        let Some(truth) = truth else {
            return Ok(Self {
                config,
                instances: Vec::new(),
                candidates: None,
                vectors: None,
                instance_ids: None,
                confusions: None,
            });
        };
        let instances = truth.scene.instances().to_vec();
        let candidates = oracle_candidates(profile, &config)?;
        let vectors = oracle_label_vectors(profile, &config, &instances)?;
        let confusions = oracle_confusions(profile, &config, &instances)?;
        Ok(Self { config, instances, candidates, vectors, instance_ids: Some(truth.instance_ids.clone()), confusions })
    }

    /// The confusion table (with `detector.oracle.confusion_rate` above 0).
    pub fn confusions(&self) -> Option<&ConfusionTable> {
        self.confusions.as_deref()
    }

    /// The detector of worker `worker`.
    pub fn detector(&self, worker: u32) -> OracleDetector {
        let mut detector = OracleDetector::new(self.config.clone(), self.instances.clone(), worker);
        if let Some(instance_ids) = &self.instance_ids {
            detector = detector.with_instance_ids(instance_ids.clone());
        }
        if let Some(candidates) = &self.candidates {
            detector = detector.with_candidates(candidates.clone());
        }
        if let Some(vectors) = &self.vectors {
            detector = detector.with_label_vectors(vectors);
        }
        if let Some(confusions) = &self.confusions {
            detector = detector.with_confusions(confusions);
        }
        detector
    }
}

/// Replaces `preset = "<name>"` by the preset's knobs, keeping the keys set next to it as
/// overrides.
fn expand_preset(section: &mut toml::Table) -> Result<(), SectionError> {
    let Some(preset) = section.remove("preset") else {
        return Ok(());
    };
    let field = "preset".to_owned();
    let name =
        preset.as_str().ok_or_else(|| (field.clone(), format!("expected a string, found {}", preset.type_str())))?;
    let config = OracleConfig::preset(name).ok_or_else(|| {
        (field.clone(), format!("unknown preset \"{name}\", expected one of {:?}", OracleConfig::PRESETS))
    })?;
    let mut base = toml::Table::try_from(&config).map_err(|e| (field, e.to_string()))?;
    config::merge(&mut base, std::mem::take(section));
    *section = base;
    Ok(())
}

/// The oracle's prompt lists (`detector.oracle.part_prompts`), from the knowledge base the
/// reasoner uses (`reasoner.knowledge_dir`, else the built-in tables); `None` for `all`.
fn oracle_candidates(profile: &Profile, oracle: &OracleConfig) -> Result<Option<Arc<PartCandidates>>, StartError> {
    if oracle.part_prompts == CandidateMode::All {
        return Ok(None);
    }
    Ok(Some(Arc::new(PartCandidates::new(knowledge_base(profile)?, oracle.part_prompts))))
}

/// Label → semantic vector, shared by the detection workers.
type LabelVectors = Arc<HashMap<String, Vec<f32>>>;

/// With `detector.oracle.semantic_source = "text_encoder"`, the text encoder's embedding of
/// every label of the scene (loaded once here, so a missing model stops start-up).
fn oracle_label_vectors(
    profile: &Profile,
    oracle: &OracleConfig,
    instances: &[InstanceInfo],
) -> Result<Option<LabelVectors>, StartError> {
    if oracle.semantic_source != SemanticSource::TextEncoder {
        return Ok(None);
    }
    let runtime = OnnxRuntime::init(&profile.onnx)?;
    let mut encoder = TextEncoder::new(&runtime, &profile.text_encoder)?;
    let mut labels: Vec<&str> = instances.iter().map(|i| i.label.as_str()).collect();
    labels.sort_unstable();
    labels.dedup();
    let embeddings = encoder.encode_batch(&labels)?;
    Ok(Some(Arc::new(labels.iter().zip(embeddings).map(|(l, e)| ((*l).to_owned(), e.to_vec())).collect())))
}

/// The confusion table the oracle of `profile` would use for `instances` (`None` when
/// `detector.oracle.confusion_rate` is 0), for reports.
pub fn confusion_table(profile: &Profile, instances: &[InstanceInfo]) -> Result<Option<ConfusionTable>, StartError> {
    let oracle = oracle_config(profile)?;
    Ok(oracle_confusions(profile, &oracle, instances)?.map(|t| (*t).clone()))
}

/// With `detector.oracle.confusion_rate` above 0, the confusion table of the scene's labels
/// against the knowledge base's names, by the text encoder's embeddings (loaded here, so a
/// missing model stops start-up, naming the knob).
fn oracle_confusions(
    profile: &Profile,
    oracle: &OracleConfig,
    instances: &[InstanceInfo],
) -> Result<Option<Arc<ConfusionTable>>, StartError> {
    if oracle.confusion_rate <= 0.0 {
        return Ok(None);
    }
    let field = "detector.oracle.confusion_rate";
    let fail = |reason: String| StartError::Incompatible {
        field,
        reason: format!("the confusion neighbours are chosen by text embedding: {reason}"),
    };
    let runtime = OnnxRuntime::init(&profile.onnx).map_err(|e| fail(format!("onnx: {e}")))?;
    let mut encoder =
        TextEncoder::new(&runtime, &profile.text_encoder).map_err(|e| fail(format!("text_encoder: {e}")))?;
    let kb = knowledge_base(profile)?;
    let words = crate::oracle::confusion_words(instances);
    let mut embed = |texts: &[&str]| -> Result<Vec<Vec<f32>>, String> {
        let out = encoder.encode_batch(texts).map_err(|e| e.to_string())?;
        Ok(out.into_iter().map(|e| e.to_vec()).collect())
    };
    let table = ConfusionTable::build(&kb, &words, &mut embed).map_err(fail)?;
    Ok(Some(Arc::new(table)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn oracle_preset_with_override() {
        let oracle = |overrides: &[&str]| {
            let overrides: Vec<String> = overrides.iter().map(|s| (*s).to_owned()).collect();
            load_profile(None, &overrides).map(|l| oracle_config(&l.profile).unwrap())
        };
        assert_eq!(oracle(&["detector.oracle.preset=clean"]).unwrap(), OracleConfig::clean());
        let tuned = oracle(&["detector.oracle.preset=clean", "detector.oracle.part_miss_rate=0.5"]).unwrap();
        assert_eq!(tuned.part_miss_rate, 0.5);
        let err = oracle(&["detector.oracle.preset=noisy"]).unwrap_err();
        assert!(err.message.starts_with("detector.oracle.preset: unknown preset"), "{err}");
    }

    #[test]
    fn out_of_range_oracle_and_synthetic_knobs_name_file_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r2.toml");
        std::fs::write(&path, "[detector.oracle]\npart_miss_rate = 1.5\n").unwrap();
        let err = load_profile(Some(&path), &[]).unwrap_err();
        assert_eq!(err.file, path.display().to_string());
        assert!(err.message.starts_with("detector.oracle.part_miss_rate: "), "{err}");
        let err = load_profile(None, &["source.synthetic.frame_rate_hz=0".to_owned()]).unwrap_err();
        assert_eq!(err.to_string(), "--set: source.synthetic.frame_rate_hz: must be within (0, 1000], got 0");
        let err = load_profile(None, &["source.synthetic.sead=3".to_owned()]).unwrap_err();
        assert!(err.message.starts_with("source.synthetic.sead: unknown field `sead`"), "{err}");
    }

    #[test]
    fn a_bad_change_script_stops_the_load_naming_the_entry_and_key() {
        let set = |value: &str| vec![format!("source.synthetic.changes={value}")];
        let err = load_profile(None, &set("[{ at_lap = 1, remove = 9999 }]")).unwrap_err();
        assert!(err.message.starts_with("source.synthetic.changes[0].remove: no instance 9999"), "{err}");
        assert!(err.message.contains("op3dsg gt --room kitchen --seed 1"), "{err}");
        let err = load_profile(None, &set("[{ at_lap = 1, remove = 1 }, { remove = 2 }]")).unwrap_err();
        assert!(err.message.starts_with("source.synthetic.changes[1].at_frame: "), "{err}");
        let err = load_profile(None, &set("[{ at_lap = 1, remvoe = 2 }]")).unwrap_err();
        assert!(err.message.starts_with("source.synthetic.changes[0]"), "{err}");
        assert!(err.message.contains("unknown field `remvoe`"), "{err}");
        let loaded = load_profile(None, &set("[{ at_lap = 1, hide_depth = 1 }]")).unwrap();
        let config = synthetic_config(&loaded.profile).unwrap();
        assert_eq!(config.changes.len(), 1);
        let (opened, _) = backends().open(&loaded.profile, None).unwrap();
        let truth = ground_truth(&opened).unwrap();
        assert_eq!(truth.scene.depthless(), [1]);
        assert_eq!(truth.changes.len(), 1);
    }

    #[test]
    fn the_oracle_reads_ground_truth_from_the_synthetic_source_only() {
        let profile = load_profile(None, &["source.synthetic.frame_count=3".to_owned()]).unwrap().profile;
        let backends = backends();
        let (opened, _) = backends.open(&profile, None).unwrap();
        assert!(ground_truth(&opened).is_some_and(|truth| !truth.scene.instances().is_empty()));
        let err = load_profile(None, &["detector.kind=oracle_v2".to_owned()]).unwrap_err();
        assert!(
            err.message.contains("no detector \"oracle_v2\" in this build (it has: open_vocab, oracle, remote, yolox)"),
            "{err}"
        );
    }
}
