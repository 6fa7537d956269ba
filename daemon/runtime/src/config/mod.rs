//! The profile: typed, strict, layered configuration of the daemon.
//!
//! A profile is TOML. The effective configuration is built in layers, each overriding the one
//! below key by key:
//! 1. the built-in base (`profiles/base.toml`, compiled into the binary: the synthetic kitchen);
//! 2. the chain of `extends = "other.toml"` files of the chosen profile (paths relative to the
//!    file that names them), farthest first;
//! 3. the profile given with `--profile`;
//! 4. `--set section.key=value` overrides from the command line (value in TOML syntax).
//!
//! Every struct denies unknown fields; [`Profile::validate`] checks ranges. Errors name the file
//! that set the offending key and the dotted field path, e.g.
//! `profiles/robot.toml: fusion.voxel_size_m: must be > 0, got -0.01`.
//!
//! Sources and detectors are backends ([`crate::backend`]): the runtime's own (`replay`, `yolox`,
//! `open_vocab`) have typed sections here; a registered backend (the simulator's `synthetic`
//! source and `oracle` detector) owns its section `[source.<name>]` / `[detector.<name>]`, which
//! [`load_with`] hands to it to check and complete, and keeps in [`Profile::sections`].
//!
//! Loading and layering live in `layers.rs`; this file holds the types and their checks.
//!
//! File paths in a profile (`extends`, and the keys in [`PATH_KEYS`]: `source.replay.path`,
//! `source.realsense.bag`, `detector.yolox.model_path`, `reasoner.knowledge_dir`,
//! `reasoner.llm.api_key_file`, `snapshot.dir`) are
//! relative to the folder of the file that sets them; a path given with `--set` is relative to
//! the working directory. `--print-config` shows them resolved.

use std::collections::BTreeMap;

use op3dsg_drivers::replay::{PlaybackMode, ReplayConfig};
use serde::{Deserialize, Serialize};

use crate::fusion::FusionConfig;
use crate::ipc::IpcConfig;
use crate::onnx::OnnxConfig;
use crate::onnx::text_encoder::TextEncoderConfig;
use crate::perception::open_vocab::OpenVocabConfig;
use crate::perception::region_encoder::RegionEncoderConfig;
use crate::perception::yolox::YoloxConfig;
use crate::queue::QueueConfig;

mod layers;

pub use layers::{LoadedProfile, load, load_with, merge};

/// The built-in base profile.
pub const BASE_PROFILE: &str = include_str!("../../../../profiles/base.toml");
/// Name used for the built-in base in messages.
pub const BASE_PROFILE_NAME: &str = "<built-in profiles/base.toml>";
/// Keys (besides `extends`) whose value is a file path, resolved against the folder of the file
/// that sets them.
pub const PATH_KEYS: &[&str] = &[
    "source.replay.path",
    "source.realsense.bag",
    "detector.yolox.model_path",
    "detector.open_vocab.model_path",
    "detector.open_vocab.clip.model_path",
    "detector.open_vocab.clip.tokenizer_path",
    "detector.open_vocab.mask_decoder.encoder_path",
    "detector.open_vocab.mask_decoder.decoder_path",
    "detector.yolox.mask_decoder.encoder_path",
    "detector.yolox.mask_decoder.decoder_path",
    "detector.region_encoder.path",
    "detector.open_vocab.tagger.path",
    "detector.open_vocab.tagger.tags_path",
    "detector.open_vocab.tagger.thresholds_path",
    "reasoner.knowledge_dir",
    "reasoner.llm.api_key_file",
    "snapshot.dir",
    "record.dir",
    "source.mcap.path",
];

/// The whole daemon configuration.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Profile {
    /// A profile this one overrides (only meaningful in files; resolved while loading).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub extends: Option<String>,
    /// Where frames come from.
    pub source: SourceConfig,
    /// Where poses come from.
    pub pose: PoseConfig,
    /// Which frames become keyframes.
    pub keyframe: KeyframeConfig,
    /// Detection worker pool and backend.
    pub detector: DetectorConfig,
    /// Multi-view fusion.
    pub fusion: FusionConfig,
    /// Queues between stages.
    pub queues: QueuesConfig,
    /// iceoryx2 services.
    pub ipc: IpcConfig,
    /// Health reporting.
    pub health: HealthConfig,
    /// Run control (stop conditions, shutdown).
    pub run: RunConfig,
    /// World frame conventions.
    pub world: WorldConfig,
    /// The ONNX Runtime library shared by the models.
    pub onnx: OnnxConfig,
    /// The label text encoder (all-MiniLM-L6-v2).
    pub text_encoder: TextEncoderConfig,
    /// The prior graph and the reasoner run on every published graph.
    pub reasoner: ReasonerConfig,
    /// Map snapshots (`crate::service::snapshot`).
    #[serde(default)]
    pub snapshot: crate::service::snapshot::SnapshotConfig,
    /// The MCAP recorder (`crate::record`); off unless `enabled`.
    #[serde(default)]
    pub record: crate::record::RecordConfig,
    /// The language query service `<prefix>/query` (`crate::query`).
    #[serde(default)]
    pub query: crate::query::QueryConfig,
    /// The 2D occupancy map `<prefix>/occupancy` (`crate::occupancy`).
    #[serde(default)]
    pub occupancy: crate::occupancy::OccupancyConfig,
    /// Approach poses on the occupancy map (`crate::occupancy::nav`).
    #[serde(default)]
    pub navigation: crate::occupancy::NavigationConfig,
    /// The sections of registered backends, by dotted path (`source.synthetic`,
    /// `detector.oracle`), as their backend checked and completed them at load time.
    #[serde(skip)]
    pub sections: BTreeMap<String, toml::Table>,
}

/// Reasoner kinds (`reasoner.kind`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReasonerKind {
    /// Published graphs carry fusion's nodes and part-of edges only.
    None,
    /// Prior graph (spatial relations) + the offline knowledge reasoner (functional relations,
    /// affordances); see `crate::reasoner::knowledge`.
    Knowledge,
    /// `knowledge` on every published graph, plus the asynchronous LLM refiner
    /// (`[reasoner.llm]`, `crate::reasoner::llm`): verified LLM edges are added as they arrive.
    Llm,
}

/// `[reasoner]`: the prior graph (`crate::prior`) and the reasoner applied to each published
/// graph.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReasonerConfig {
    /// Which reasoner runs.
    pub kind: ReasonerKind,
    /// Folder with `objects.toml`, `parts.toml`, `remote.toml` replacing the built-in knowledge
    /// base (relative to the profile file that sets it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub knowledge_dir: Option<String>,
    /// Nodes whose centres are this close are neighbours, metres.
    pub neighbour_radius_m: f32,
    /// `on` / `under` when the vertical gap is at most this, metres.
    pub contact_tolerance_m: f32,
    /// `next to` when footprints are at most this far apart, metres.
    pub next_to_gap_m: f32,
    /// Footprint overlap (fraction of the smaller footprint) for `on`/`under`/`above`/`below`.
    pub min_footprint_overlap: f32,
    /// Slack for `inside`, metres.
    pub inside_tolerance_m: f32,
    /// The LLM endpoint and the refiner's policies (used with `kind = "llm"`).
    #[serde(default)]
    pub llm: crate::reasoner::llm::LlmConfig,
}

/// The source the runtime itself provides (`source.kind`); other names are registered backends
/// ([`crate::backend`]).
pub const REPLAY_SOURCE: &str = "replay";

/// `[source]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SourceConfig {
    /// Which source backend: `replay`, or one registered with [`crate::backend::Backends`]
    /// (`synthetic` in `op3dsgd`).
    pub kind: String,
    /// Delivery rate for sources that can go faster than real time, Hz; 0 = as fast as the
    /// pipeline takes frames.
    pub rate_hz: f64,
    /// Frames allocated for the frame pool on top of the queue capacities and workers.
    pub pool_headroom: usize,
    /// `[source.replay]`: required with `kind = "replay"`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub replay: Option<ReplayConfig>,
}

/// Pose source kinds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseSourceKind {
    /// The frame source carries `world_from_camera` (synthetic, replay).
    Frame,
    /// The navigation stack publishes [`op3dsg_ipc_types::PoseStamped`] on `<prefix>/pose`.
    Ipc,
}

/// A fixed transform in the profile.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TransformConfig {
    /// Translation, metres.
    pub translation_m: [f64; 3],
    /// Unit quaternion `[x, y, z, w]`.
    pub rotation_xyzw: [f64; 4],
}

impl TransformConfig {
    /// As an isometry.
    pub fn to_isometry(&self) -> op3dsg_drivers::pose::Isometry {
        let [x, y, z, w] = self.rotation_xyzw;
        op3dsg_drivers::pose::Isometry::new(
            glam::DQuat::from_xyzw(x, y, z, w),
            glam::DVec3::from_array(self.translation_m),
        )
    }
}

/// `[pose]`: where a frame's `world_from_camera` comes from and how received poses are used
/// (the rules are in [`crate::keyframe`]'s docs).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseConfig {
    /// Where poses come from.
    pub source: PoseSourceKind,
    /// Hold tolerance, milliseconds: without two poses around a frame close enough to
    /// interpolate, the nearest pose is used when it is at most this far from the frame's stamp
    /// (never further: no extrapolation); otherwise the frame is dropped and counted.
    pub tolerance_ms: f64,
    /// Two poses at most this far apart (milliseconds) are interpolated to the stamp of a frame
    /// between them (a 10 Hz stream is 100 ms apart; the default also bridges one lost pose).
    pub max_interpolation_gap_ms: f64,
    /// A frame stamped after the newest pose waits up to this long (milliseconds, host clock)
    /// for the pose after it before it is held within `tolerance_ms` or dropped (0 = never wait).
    pub max_wait_ms: f64,
    /// A pose stamped more than this (milliseconds) after the newest frame is refused as
    /// `future`, and not adopted, so it cannot block the poses that follow.
    pub future_tolerance_ms: f64,
    /// When frame and pose stamps disagree by more than the tolerances for this long (seconds),
    /// the daemon warns that their clocks differ (then again at most once per this period).
    pub clock_warning_after_s: f64,
    /// Poses kept for interpolation.
    pub buffer_len: usize,
    /// Fixed `base_from_camera` for `world_from_base` poses (rigid mounts only).
    #[serde(default)]
    pub base_from_camera: Option<TransformConfig>,
}

/// `[keyframe]`: a frame becomes a keyframe when the camera moved or turned enough since the
/// last keyframe, or when `max_interval_s` passed.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct KeyframeConfig {
    /// Translation since the last keyframe, metres.
    pub min_translation_m: f64,
    /// Rotation since the last keyframe, degrees.
    pub min_rotation_deg: f64,
    /// Longest time without a keyframe, seconds (0 = every frame is a keyframe).
    pub max_interval_s: f64,
}

/// YOLOX through ONNX Runtime (`detector.kind`; `"onnx"` is accepted as a synonym).
pub const YOLOX_DETECTOR: &str = "yolox";
/// An open-vocabulary detector through ONNX Runtime (`detector.kind`).
pub const OPEN_VOCAB_DETECTOR: &str = "open_vocab";

/// `[detector]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DetectorConfig {
    /// Backend: `yolox` (YOLOX, closed vocabulary, COCO, `[detector.yolox]`; `"onnx"` is a
    /// synonym), `open_vocab` (text-prompted, `[detector.open_vocab]`; contract in
    /// `perception/open_vocab.rs`), or one registered with [`crate::backend::Backends`]
    /// (`oracle` in `op3dsgd`).
    pub kind: String,
    /// Worker threads (`op3dsg-detect-<i>`), each with its own detector instance.
    pub workers: usize,
    /// `[detector.yolox]`: model, thresholds, class map, depth masks (used with
    /// `kind = "yolox"`).
    #[serde(default)]
    pub yolox: YoloxConfig,
    /// `[detector.open_vocab]`: model contract, prompts, thresholds (used with
    /// `kind = "open_vocab"`).
    #[serde(default)]
    pub open_vocab: OpenVocabConfig,
    /// `[detector.region_encoder]`: a CLIP image encoder whose embedding of each detection's
    /// crop becomes its semantic feature, for any detector kind (contract in
    /// `perception/region_encoder.rs`). Unset: the detector's own features, if any.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub region_encoder: Option<RegionEncoderConfig>,
}

/// `[queues]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct QueuesConfig {
    /// Capture → keyframe gate.
    pub frames: QueueConfig,
    /// Keyframe gate → detection workers.
    pub keyframes: QueueConfig,
    /// Detection workers → fusion.
    pub detections: QueueConfig,
    /// Fusion → publisher.
    pub graph: QueueConfig,
}

/// `[health]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HealthConfig {
    /// Period of health records and of the log summary, milliseconds.
    pub period_ms: u64,
    /// Log a one-line summary at info every this many periods (0 = never).
    pub log_every_periods: u32,
}

/// `[run]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunConfig {
    /// Stop the source after this many frames (0 = no limit); whether the daemon then exits is
    /// `exit_at_end`.
    pub max_frames: u64,
    /// Exit once the source ended (finite source or `max_frames`) and the last graph is
    /// published; otherwise keep serving it.
    pub exit_at_end: bool,
    /// Longest orderly shutdown before the daemon gives up on a stuck stage, seconds.
    pub shutdown_timeout_s: f64,
    /// Minimum time between two published graph versions, milliseconds (0 = every change).
    pub min_publish_interval_ms: u64,
}

/// Up axis of the world frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum UpAxis {
    /// +z up (robotics convention; the synthetic world).
    Z,
    /// +y up.
    Y,
    /// -y up (OpenCV camera-like worlds).
    NegY,
}

/// `[world]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WorldConfig {
    /// Which axis is up (gravity is opposite).
    pub up_axis: UpAxis,
}

/// A profile that could not be loaded. The message names the file and the field.
#[derive(Debug, thiserror::Error)]
#[error("{file}: {message}")]
pub struct ProfileError {
    /// The file that set the offending value (or could not be read).
    pub file: String,
    /// Field path and what is wrong.
    pub message: String,
}

impl ProfileError {
    pub(crate) fn new(file: impl Into<String>, message: impl Into<String>) -> Self {
        Self { file: file.into(), message: message.into() }
    }
}

impl Profile {
    /// Range checks across the profile. Errors are `(field path, message)`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        check(self.source.rate_hz >= 0.0 && self.source.rate_hz <= 1000.0, "source.rate_hz", || {
            format!("must be within [0, 1000] (0 = as fast as possible), got {}", self.source.rate_hz)
        })?;
        check(self.source.pool_headroom <= 64, "source.pool_headroom", || {
            format!("must be at most 64, got {}", self.source.pool_headroom)
        })?;
        check(self.pose.tolerance_ms > 0.0 && self.pose.tolerance_ms <= 5000.0, "pose.tolerance_ms", || {
            format!("must be within (0, 5000], got {}", self.pose.tolerance_ms)
        })?;
        let p = &self.pose;
        check(
            p.max_interpolation_gap_ms > 0.0 && p.max_interpolation_gap_ms <= 10_000.0,
            "pose.max_interpolation_gap_ms",
            || format!("must be within (0, 10000] milliseconds, got {}", p.max_interpolation_gap_ms),
        )?;
        check((0.0..=5000.0).contains(&p.max_wait_ms), "pose.max_wait_ms", || {
            format!("must be within [0, 5000] milliseconds (0 = never wait), got {}", p.max_wait_ms)
        })?;
        check(p.future_tolerance_ms > 0.0 && p.future_tolerance_ms <= 3_600_000.0, "pose.future_tolerance_ms", || {
            format!("must be within (0, 3600000] milliseconds, got {}", p.future_tolerance_ms)
        })?;
        check(
            p.clock_warning_after_s > 0.0 && p.clock_warning_after_s <= 3600.0,
            "pose.clock_warning_after_s",
            || format!("must be within (0, 3600] seconds, got {}", p.clock_warning_after_s),
        )?;
        check((2..=100_000).contains(&self.pose.buffer_len), "pose.buffer_len", || {
            format!("must be within [2, 100000], got {}", self.pose.buffer_len)
        })?;
        if let Some(t) = &self.pose.base_from_camera {
            check(t.translation_m.iter().all(|v| v.is_finite()), "pose.base_from_camera.translation_m", || {
                format!("must be finite metres, got {:?}", t.translation_m)
            })?;
            let norm = t.rotation_xyzw.iter().map(|v| v * v).sum::<f64>().sqrt();
            check((norm - 1.0).abs() < 1e-3, "pose.base_from_camera.rotation_xyzw", || {
                format!("must be a unit quaternion, norm is {norm}")
            })?;
        }
        let k = &self.keyframe;
        check(k.min_translation_m >= 0.0, "keyframe.min_translation_m", || {
            format!("must be >= 0, got {}", k.min_translation_m)
        })?;
        check((0.0..=180.0).contains(&k.min_rotation_deg), "keyframe.min_rotation_deg", || {
            format!("must be within [0, 180], got {}", k.min_rotation_deg)
        })?;
        check(k.max_interval_s >= 0.0, "keyframe.max_interval_s", || {
            format!("must be >= 0, got {}", k.max_interval_s)
        })?;
        check((1..=64).contains(&self.detector.workers), "detector.workers", || {
            format!("must be within [1, 64], got {}", self.detector.workers)
        })?;
        if self.detector.kind == YOLOX_DETECTOR {
            self.detector.yolox.validate("detector.yolox").map_err(split_message)?;
            check(!self.detector.yolox.class_map.is_empty(), "detector.yolox.class_map", || {
                "must map at least one class of the model to a label (unmapped classes are dropped)".to_owned()
            })?;
        }
        if self.detector.kind == OPEN_VOCAB_DETECTOR {
            self.detector.open_vocab.validate("detector.open_vocab").map_err(split_message)?;
        }
        if let Some(encoder) = &self.detector.region_encoder {
            encoder.validate("detector.region_encoder").map_err(split_message)?;
        }
        self.fusion.validate("fusion").map_err(split_message)?;
        self.queues.frames.validate("queues.frames").map_err(split_message)?;
        self.queues.keyframes.validate("queues.keyframes").map_err(split_message)?;
        self.queues.detections.validate("queues.detections").map_err(split_message)?;
        self.queues.graph.validate("queues.graph").map_err(split_message)?;
        self.ipc.validate("ipc").map_err(split_message)?;
        self.onnx.validate("onnx").map_err(split_message)?;
        self.record.validate("record").map_err(split_message)?;
        self.text_encoder.validate("text_encoder").map_err(split_message)?;
        self.snapshot.validate("snapshot").map_err(split_message)?;
        self.query.validate("query").map_err(split_message)?;
        self.occupancy.validate("occupancy").map_err(split_message)?;
        self.navigation.validate("navigation").map_err(split_message)?;
        let r = &self.reasoner;
        check(r.neighbour_radius_m > 0.0 && r.neighbour_radius_m <= 10.0, "reasoner.neighbour_radius_m", || {
            format!("must be within (0, 10] metres, got {}", r.neighbour_radius_m)
        })?;
        for (name, v) in [
            ("contact_tolerance_m", r.contact_tolerance_m),
            ("next_to_gap_m", r.next_to_gap_m),
            ("inside_tolerance_m", r.inside_tolerance_m),
        ] {
            check((0.0..=1.0).contains(&v), &format!("reasoner.{name}"), || {
                format!("must be within [0, 1] metres, got {v}")
            })?;
        }
        check((0.0..=1.0).contains(&r.min_footprint_overlap), "reasoner.min_footprint_overlap", || {
            format!("must be within [0, 1], got {}", r.min_footprint_overlap)
        })?;
        r.llm.validate("reasoner.llm", r.kind == ReasonerKind::Llm).map_err(split_message)?;
        check((10..=60_000).contains(&self.health.period_ms), "health.period_ms", || {
            format!("must be within [10, 60000], got {}", self.health.period_ms)
        })?;
        check(
            self.run.shutdown_timeout_s > 0.0 && self.run.shutdown_timeout_s <= 600.0,
            "run.shutdown_timeout_s",
            || format!("must be within (0, 600], got {}", self.run.shutdown_timeout_s),
        )?;
        if self.source.kind == REPLAY_SOURCE {
            let Some(replay) = &self.source.replay else {
                return Err((
                    "source.replay".to_owned(),
                    "required with source.kind = \"replay\" (at least `path`, the recording's folder)".to_owned(),
                ));
            };
            replay.validate("source.replay").map_err(split_message)?;
            check(replay.mode == PlaybackMode::Fast || self.source.rate_hz == 0.0, "source.replay.mode", || {
                let mode = if replay.mode == PlaybackMode::Stepped { "stepped" } else { "recorded" };
                format!("\"{mode}\" paces frames itself; set source.rate_hz = 0 (it is {})", self.source.rate_hz)
            })?;
        }
        Ok(())
    }

    /// The section of a registered backend (`"source.synthetic"`), as loaded.
    pub fn section(&self, path: &str) -> Option<&toml::Table> {
        self.sections.get(path)
    }

    /// Replaces the section of a registered backend (a caller that edits a loaded profile
    /// in code; the backend checks it again when it opens).
    pub fn set_section(&mut self, path: &str, section: toml::Table) {
        self.sections.insert(path.to_owned(), section);
    }

    /// Frames the frame pool needs so that no stage starves another: every queue full, every
    /// worker busy, one in capture, one in fusion, plus headroom.
    pub fn frame_pool_capacity(&self) -> usize {
        self.queues.frames.capacity
            + self.queues.keyframes.capacity
            + self.queues.detections.capacity
            + self.detector.workers
            + 3
            + self.source.pool_headroom
            + if self.pose.source == PoseSourceKind::Ipc { crate::keyframe::MAX_PENDING_FRAMES } else { 0 }
    }
}

pub(crate) fn check(ok: bool, path: &str, message: impl FnOnce() -> String) -> Result<(), (String, String)> {
    if ok { Ok(()) } else { Err((path.to_owned(), message())) }
}

/// Splits a `path: message` string from a sub-config's `validate` into its parts.
pub(crate) fn split_message(message: String) -> (String, String) {
    match message.split_once(": ") {
        Some((path, msg)) => (path.to_owned(), msg.to_owned()),
        None => (String::new(), message),
    }
}

#[cfg(test)]
mod tests {
    use std::path::PathBuf;

    use super::*;

    fn write(dir: &tempfile::TempDir, name: &str, text: &str) -> PathBuf {
        let path = dir.path().join(name);
        std::fs::write(&path, text).unwrap();
        path
    }

    #[test]
    fn built_in_base_loads_and_validates() {
        let loaded = load(None, &[]).unwrap();
        assert_eq!(loaded.profile.source.kind, "synthetic");
        assert_eq!(loaded.layers, [BASE_PROFILE_NAME]);
    }

    #[test]
    fn yolox_detector_paths_resolve_and_ranges_name_the_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(
            &dir,
            "icl.toml",
            "[detector]\nkind = \"onnx\"\n[detector.yolox]\nmodel_path = \"m/yolox.onnx\"\n\
             [detector.yolox.class_map]\nchair = \"chair\"\n",
        );
        let profile = load(Some(&path), &[]).unwrap().profile;
        assert_eq!(profile.detector.kind, YOLOX_DETECTOR, "onnx is an alias of yolox");
        assert_eq!(profile.detector.yolox.model_path, dir.path().join("m/yolox.onnx"), "relative to the profile");
        let path = write(&dir, "bad.toml", "[detector]\nkind = \"yolox\"\n[detector.yolox]\nnms_iou_threshold = 0.0\n");
        let err = load(Some(&path), &[]).unwrap_err();
        assert!(err.to_string().contains("detector.yolox.nms_iou_threshold: must be within (0, 1]"), "{err}");
        let path = write(&dir, "empty.toml", "[detector]\nkind = \"yolox\"\n");
        let err = load(Some(&path), &[]).unwrap_err();
        assert!(err.to_string().contains("detector.yolox.class_map: must map at least one class"), "{err}");
    }

    #[test]
    fn unknown_key_names_file_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(&dir, "robot.toml", "[fusion]\nvoxel_sise_m = 0.02\n");
        let err = load(Some(&path), &[]).unwrap_err();
        assert_eq!(err.file, path.display().to_string());
        assert!(err.message.starts_with("fusion"), "{err}");
        assert!(err.message.contains("voxel_sise_m"), "{err}");
    }

    #[test]
    fn the_fusion_method_is_checked_by_name_and_its_section_by_field() {
        let dir = tempfile::tempdir().unwrap();
        let path =
            write(&dir, "cg.toml", "[fusion]\nmethod = \"conceptgraphs\"\n[fusion.conceptgraphs]\nvoxel_m = 0.02\n");
        let fusion = load(Some(&path), &[]).unwrap().profile.fusion;
        assert_eq!((fusion.method, fusion.conceptgraphs.voxel_m), (crate::fusion::FusionMethod::Conceptgraphs, 0.02));
        assert!(crate::fusion::build(&fusion, UpAxis::Z).export_state().is_none(), "no saved form");
        let path = write(&dir, "typo.toml", "[fusion]\nmethod = \"concept_graphs\"\n");
        let err = load(Some(&path), &[]).unwrap_err();
        assert!(err.message.starts_with("fusion.method") && err.message.contains("conceptgraphs"), "{err}");
        let path = write(&dir, "bad.toml", "[fusion.conceptgraphs]\ndbscan_eps_m = 0.0\n");
        let err = load(Some(&path), &[]).unwrap_err();
        assert!(err.to_string().contains("fusion.conceptgraphs.dbscan_eps_m: must be within"), "{err}");
    }

    #[test]
    fn wrong_type_names_file_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(&dir, "robot.toml", "[detector]\nworkers = \"two\"\n");
        let err = load(Some(&path), &[]).unwrap_err();
        assert_eq!(err.file, path.display().to_string());
        assert!(err.message.starts_with("detector.workers: "), "{err}");
    }

    #[test]
    fn out_of_range_names_file_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(&dir, "robot.toml", "[detector]\nworkers = 0\n");
        let err = load(Some(&path), &[]).unwrap_err();
        assert_eq!(err.to_string(), format!("{}: detector.workers: must be within [1, 64], got 0", path.display()));
    }

    #[test]
    fn sections_of_backends_not_in_the_registry_are_refused_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(
            &dir,
            "r.toml",
            "[source]\nkind = \"replay\"\nrate_hz = 0.0\n[source.replay]\npath = \"rec\"\n[detector.yolx]\nmodel_path = \"m.onnx\"\n",
        );
        let backends = crate::backend::Backends::runtime();
        let err = load_with(&backends, Some(&path), &[]).unwrap_err();
        // The base's [source.synthetic] comes first: no such backend in the runtime alone.
        assert_eq!(
            err.to_string(),
            format!(
                "{BASE_PROFILE_NAME}: source.synthetic: no source backend \"synthetic\" in this build (it has: mcap, replay)"
            )
        );
        // Without a registry the sections are kept as they are, for their backend to check.
        let loaded = load(Some(&path), &[]).unwrap();
        assert!(loaded.profile.section("detector.yolx").is_some());
        assert!(loaded.profile.section("source.synthetic").is_some());
        assert!(loaded.effective["detector"]["yolx"].is_table(), "--print-config shows them");
    }

    #[test]
    fn extends_chain_and_set_overrides_layer_in_order() {
        let dir = tempfile::tempdir().unwrap();
        write(&dir, "common.toml", "[detector]\nworkers = 3\n[health]\nperiod_ms = 250\n");
        let path = write(&dir, "robot.toml", "extends = \"common.toml\"\n[detector]\nworkers = 4\n");
        let loaded = load(Some(&path), &["health.period_ms=500".to_owned()]).unwrap();
        assert_eq!(loaded.profile.detector.workers, 4);
        assert_eq!(loaded.profile.health.period_ms, 500);
        assert_eq!(loaded.layers.len(), 4);
        let err = load(Some(&path), &["detector.workers=99".to_owned()]).unwrap_err();
        assert_eq!(err.file, "--set");
    }

    const REPLAY: &str = "[source]\nkind = \"replay\"\nrate_hz = 0.0\n[source.replay]\npath = \"rec/icl\"\n";

    #[test]
    fn replay_path_is_relative_to_the_profile_that_sets_it() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("robots")).unwrap();
        let path = write(&dir, "robots/replay.toml", REPLAY);
        let loaded = load(Some(&path), &[]).unwrap();
        let replay = loaded.profile.source.replay.unwrap();
        assert_eq!(replay.path, dir.path().join("robots").join("rec/icl"));
        assert_eq!(replay.mode, PlaybackMode::Recorded);
        assert_eq!(replay.on_bad_frame, op3dsg_drivers::replay::OnBadFrame::Stop);
        // An extending profile that does not set the path keeps the base file's folder.
        let child = write(&dir, "child.toml", "extends = \"robots/replay.toml\"\n[source.replay]\nloop = true\n");
        let replay = load(Some(&child), &[]).unwrap().profile.source.replay.unwrap();
        assert_eq!(replay.path, dir.path().join("robots").join("rec/icl"));
        assert!(replay.looping);
        // Absolute paths stay; --set paths are relative to the working directory.
        let replay = load(Some(&path), &["source.replay.path=\"/data/seq\"".to_owned()]).unwrap().profile.source.replay;
        assert_eq!(replay.unwrap().path, PathBuf::from("/data/seq"));
        let replay = load(Some(&path), &["source.replay.path=\"seq\"".to_owned()]).unwrap().profile.source.replay;
        assert_eq!(replay.unwrap().path, PathBuf::from("seq"));
    }

    #[test]
    fn replay_errors_name_file_and_field() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            ("[source]\nkind = \"replay\"\nrate_hz = 0.0\n", "source.replay: required with source.kind = \"replay\""),
            (&format!("{REPLAY}on_bad_frame = \"ignore\"\n"), "source.replay.on_bad_frame: unknown variant `ignore`"),
            (&format!("{REPLAY}speed = 2.0\n"), "source.replay.speed: unknown field `speed`"),
            (
                &format!("{REPLAY}max_pose_gap_ms = -1.0\n"),
                "source.replay.max_pose_gap_ms: must be within (0, 10000], got -1",
            ),
            (
                &format!(
                    "{REPLAY}intrinsics = {{ width = 640, height = 480, fx = 0.0, fy = 525.0, cx = 319.5, cy = 239.5 }}\n"
                ),
                "source.replay.intrinsics.fx: must be > 0, got 0",
            ),
            (
                &REPLAY.replace("rate_hz = 0.0\n", ""),
                "source.replay.mode: \"recorded\" paces frames itself; set source.rate_hz = 0 (it is 30)",
            ),
        ];
        for (i, (text, expected)) in cases.iter().enumerate() {
            let path = write(&dir, &format!("r{i}.toml"), text);
            let err = load(Some(&path), &[]).unwrap_err();
            assert_eq!(err.file, path.display().to_string(), "{err}");
            assert!(err.message.starts_with(expected), "case {i}: {err}");
        }
        // Fast mode is paced by source.rate_hz like the synthetic source.
        let path = write(&dir, "fast.toml", &format!("{REPLAY}mode = \"fast\"\n"));
        assert!(load(Some(&path), &["source.rate_hz=15".to_owned()]).is_ok());
    }

    #[test]
    fn pose_keys_are_checked_by_name() {
        let dir = tempfile::tempdir().unwrap();
        let cases = [
            (
                "[pose]\nmax_interpolation_gap_ms = 0.0\n",
                "pose.max_interpolation_gap_ms: must be within (0, 10000] milliseconds, got 0",
            ),
            (
                "[pose]\nmax_wait_ms = -5.0\n",
                "pose.max_wait_ms: must be within [0, 5000] milliseconds (0 = never wait), got -5",
            ),
            (
                "[pose]\nfuture_tolerance_ms = 0.0\n",
                "pose.future_tolerance_ms: must be within (0, 3600000] milliseconds, got 0",
            ),
            (
                "[pose]\nclock_warning_after_s = 0.0\n",
                "pose.clock_warning_after_s: must be within (0, 3600] seconds, got 0",
            ),
            ("[pose]\nmax_wait = 5.0\n", "pose.max_wait: unknown field `max_wait`"),
            (
                "[pose]\nbase_from_camera = { translation_m = [0.0, 0.0, nan], rotation_xyzw = [0.0, 0.0, 0.0, 1.0] }\n",
                "pose.base_from_camera.translation_m: must be finite metres, got [0.0, 0.0, NaN]",
            ),
            (
                "[pose]\nbase_from_camera = { translation_m = [0.0, 0.0, 1.3], rotation_xyzw = [0.0, 0.0, 0.0, 2.0] }\n",
                "pose.base_from_camera.rotation_xyzw: must be a unit quaternion, norm is 2",
            ),
        ];
        for (i, (text, expected)) in cases.iter().enumerate() {
            let path = write(&dir, &format!("p{i}.toml"), text);
            let err = load(Some(&path), &[]).unwrap_err();
            assert_eq!(err.file, path.display().to_string(), "{err}");
            assert!(err.message.starts_with(expected), "case {i}: {err}");
        }
        let pose = load(None, &[]).unwrap().profile.pose;
        assert_eq!((pose.max_interpolation_gap_ms, pose.max_wait_ms, pose.tolerance_ms), (250.0, 200.0, 50.0));
        assert_eq!(pose.future_tolerance_ms * 1e6, op3dsg_ipc_types::FUTURE_POSE_LIMIT_NS as f64);
    }

    #[test]
    fn llm_section_is_checked_by_field_and_its_key_file_is_a_path() {
        let loaded = load(None, &[]).unwrap();
        assert_eq!(loaded.profile.reasoner.llm, crate::reasoner::llm::LlmConfig::default());
        let dir = tempfile::tempdir().unwrap();
        let path = write(&dir, "robot.toml", "[reasoner]\nkind = \"llm\"\n");
        let err = load(Some(&path), &[]).unwrap_err();
        // Named by the field (the empty base URL comes from the built-in base).
        assert!(err.to_string().ends_with(": reasoner.llm.base_url: required with reasoner.kind = \"llm\""), "{err}");
        let path = write(
            &dir,
            "robot.toml",
            "[reasoner]\nkind = \"llm\"\n[reasoner.llm]\nbase_url = \"http://127.0.0.1:8000/v1\"\nmodel = \"m\"\napi_key_file = \"llm.key\"\nmax_concurrent_calls = 0\n",
        );
        let err = load(Some(&path), &[]).unwrap_err();
        assert!(err.to_string().ends_with("reasoner.llm.max_concurrent_calls: must be within [1, 64], got 0"), "{err}");
        let ok = load(Some(&path), &["reasoner.llm.max_concurrent_calls=2".to_owned()]).unwrap();
        assert_eq!(ok.profile.reasoner.llm.api_key_file, Some(dir.path().join("llm.key")));
    }

    #[test]
    fn text_encoder_is_off_in_the_base_and_checked_by_field() {
        let loaded = load(None, &[]).unwrap();
        assert!(!loaded.profile.text_encoder.enabled);
        assert_eq!(loaded.profile.text_encoder, TextEncoderConfig::default());
        assert_eq!(loaded.profile.onnx, OnnxConfig::default());
        let dir = tempfile::tempdir().unwrap();
        let path = write(&dir, "robot.toml", "[text_encoder]\nenabled = true\nmax_sequence_length = 2\n");
        let err = load(Some(&path), &[]).unwrap_err();
        assert_eq!(
            err.to_string(),
            format!("{}: text_encoder.max_sequence_length: must be within [4, 512], got 2", path.display())
        );
        load(None, &["onnx.execution_provider=cuda".to_owned()])
            .expect("cuda is a provider (CPU fallback at run time)");
        let err = load(None, &["onnx.execution_provider=tpu".to_owned()]).unwrap_err();
        assert_eq!(err.file, "--set");
        assert!(err.message.starts_with("onnx.execution_provider: unknown variant `tpu`"), "{err}");
    }

    #[test]
    fn toml_syntax_error_names_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = write(&dir, "bad.toml", "[fusion\n");
        let err = load(Some(&path), &[]).unwrap_err();
        assert_eq!(err.file, path.display().to_string());
    }
}
