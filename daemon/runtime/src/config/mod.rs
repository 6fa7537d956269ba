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
//! The profile is made of the stages' own sections: each stage owns its section's type and its
//! range checks (`[source]`: `crate::capture`, `[pose]` and `[keyframe]`: `crate::keyframe`,
//! `[detector]`: `crate::perception`, `[fusion]` and `[snapshot]`: `crate::fusion`, ...); this
//! module puts them together and adds what belongs to the whole pipeline (`[queues]`, `[run]`)
//! and the checks across sections. Every struct denies unknown fields; [`Profile::validate`]
//! runs every section's checks. Errors name the file that set the offending key and the dotted
//! field path, e.g. `profiles/robot.toml: fusion.voxel_size_m: must be > 0, got -0.01`.
//!
//! Sources, detectors and fusions are backends (`crate::backend`): the runtime's own (`replay`,
//! `mcap`, `yolox`, `open_vocab`, `op3dsg`) have typed sections here; a registered backend (the
//! simulator's `synthetic` source, `oracle` detector and `conceptgraphs` fusion) owns its section
//! `[source.<name>]` / `[detector.<name>]` / `[fusion.<name>]`, which [`load_with`] hands to the
//! registry ([`SectionRegistry`]) to check and complete, and keeps in [`Profile::sections`].
//!
//! Loading and layering live in `layers.rs`; this file holds the profile and its checks.
//!
//! File paths in a profile (`extends`, and the keys in [`PATH_KEYS`]: `source.replay.path`,
//! `source.realsense.bag`, `detector.yolox.model_path`, `reasoner.knowledge_dir`,
//! `reasoner.llm.api_key_file`, `snapshot.dir`) are
//! relative to the folder of the file that sets them; a path given with `--set` is relative to
//! the working directory. Two exceptions find op3dsg's own files wherever it is installed
//! (`crate::install`): a path that starts with `.models/` names a file of the model store (a
//! checkout's `.models/`, an installed `/usr/lib/op3dsg/`), and an `extends` that names no file
//! beside its profile is looked up among the installed profiles (`/usr/share/op3dsg/profiles`).
//! `--print-config` shows them resolved, model and library files included
//! ([`LoadedProfile::effective_with_files`]).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::capture::SourceConfig;
use crate::fusion::FusionConfig;
use crate::fusion::snapshot::SnapshotConfig;
use crate::ipc::IpcConfig;
use crate::keyframe::{KeyframeConfig, MAX_PENDING_FRAMES, PoseConfig};
use crate::live_view::LiveViewConfig;
use crate::occupancy::{NavigationConfig, OccupancyConfig};
use crate::onnx::OnnxConfig;
use crate::onnx::text_encoder::TextEncoderConfig;
use crate::perception::DetectorConfig;
use crate::publish::HealthConfig;
use crate::query::QueryConfig;
use crate::queue::QueueConfig;
use crate::reasoner::ReasonerConfig;
use crate::record::RecordConfig;
use crate::ros2::Ros2Config;
use crate::world::WorldConfig;
use crate::zenoh::ZenohConfig;

mod files;
mod layers;
#[cfg(test)]
mod tests;

pub use files::LOOKUP_KEYS;
pub use layers::{LoadedProfile, SectionError, SectionRegistry, load, load_with, load_with_environment, merge};

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
    "zenoh.config_file",
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
    /// Map snapshots (`crate::fusion::snapshot`).
    #[serde(default)]
    pub snapshot: SnapshotConfig,
    /// The MCAP recorder (`crate::record`); off unless `enabled`.
    #[serde(default)]
    pub record: RecordConfig,
    /// The language query service `<prefix>/query` (`crate::query`).
    #[serde(default)]
    pub query: QueryConfig,
    /// The 2D occupancy map `<prefix>/occupancy` (`crate::occupancy`).
    #[serde(default)]
    pub occupancy: OccupancyConfig,
    /// Approach poses on the occupancy map (`crate::occupancy::nav`).
    #[serde(default)]
    pub navigation: NavigationConfig,
    /// The graph for consumers off the robot over Zenoh (`crate::zenoh`); off unless `enabled`.
    #[serde(default)]
    pub zenoh: ZenohConfig,
    /// The robot's ROS 2 software through Zenoh (`crate::ros2`): poses from tf with
    /// `pose.source = "ros2"`.
    #[serde(default)]
    pub ros2: Ros2Config,
    /// The Foxglove live view (`crate::live_view`); off unless `enabled`.
    #[serde(default)]
    pub live_view: LiveViewConfig,
    /// The sections of registered backends, by dotted path (`source.synthetic`,
    /// `detector.oracle`, `fusion.conceptgraphs`), as their backend checked and completed them
    /// at load time.
    #[serde(skip)]
    pub sections: BTreeMap<String, toml::Table>,
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

impl QueuesConfig {
    /// Each queue's checks; messages start with `path.<queue>.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        for (name, queue) in [
            ("frames", &self.frames),
            ("keyframes", &self.keyframes),
            ("detections", &self.detections),
            ("graph", &self.graph),
        ] {
            queue.validate(&format!("{path}.{name}"))?;
        }
        Ok(())
    }
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

impl RunConfig {
    /// Range checks; messages start with `path.field`.
    pub fn validate(&self, path: &str) -> Result<(), String> {
        if !(self.shutdown_timeout_s > 0.0 && self.shutdown_timeout_s <= 600.0) {
            return Err(format!("{path}.shutdown_timeout_s: must be within (0, 600], got {}", self.shutdown_timeout_s));
        }
        Ok(())
    }
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
    /// Every section's checks, in the order of the sections. Errors are `(field path, message)`.
    pub fn validate(&self) -> Result<(), (String, String)> {
        [
            self.source.validate("source"),
            self.pose.validate("pose"),
            self.keyframe.validate("keyframe"),
            self.detector.validate("detector"),
            self.fusion.validate("fusion"),
            self.queues.validate("queues"),
            self.ipc.validate("ipc"),
            self.onnx.validate("onnx"),
            self.record.validate("record"),
            self.text_encoder.validate("text_encoder"),
            self.snapshot.validate("snapshot"),
            self.query.validate("query"),
            self.occupancy.validate("occupancy"),
            self.navigation.validate("navigation"),
            self.zenoh.validate("zenoh"),
            self.ros2.validate("ros2"),
            self.live_view.validate("live_view"),
            self.reasoner.validate("reasoner"),
            self.health.validate("health"),
            self.run.validate("run"),
            self.world.validate("world"),
            self.zenoh_in_build(),
            self.zenoh_reachable(),
        ]
        .into_iter()
        .collect::<Result<(), String>>()
        .map_err(split_message)
    }

    /// The first key of this profile that needs Zenoh, and what it turns on (`None`: the
    /// profile runs in a build without the feature `zenoh`).
    pub fn needs_zenoh(&self) -> Option<(&'static str, &'static str)> {
        let uses = [
            (self.zenoh.enabled, "zenoh.enabled", "the Zenoh stage"),
            (self.ros2.out.any(), "ros2.out", "a ROS 2 topic"),
            (self.pose.source == crate::keyframe::PoseSourceKind::Ros2, "pose.source", "poses from ROS 2's tf"),
            (self.detector.kind == crate::perception::remote::REMOTE_DETECTOR, "detector.kind", "remote detection"),
        ];
        uses.into_iter().find(|(on, _, _)| *on).map(|(_, key, what)| (key, what))
    }

    /// The daemon's `[zenoh]` session (the Zenoh stage, remote detection) must be reachable: a
    /// session that neither listens nor connects, without multicast scouting or a Zenoh
    /// configuration file, can reach nothing and nothing can reach it, so a profile that needs
    /// one is refused naming the keys instead of starting silent.
    fn zenoh_reachable(&self) -> Result<(), String> {
        let z = &self.zenoh;
        let remote = self.detector.kind == crate::perception::remote::REMOTE_DETECTOR;
        let users: Vec<&str> =
            [(z.enabled, "zenoh.enabled (the graph off this computer)"), (remote, "detector.kind = \"remote\"")]
                .into_iter()
                .filter_map(|(on, what)| on.then_some(what))
                .collect();
        if users.is_empty()
            || z.config_file.is_some()
            || !z.listen.is_empty()
            || !z.connect.is_empty()
            || z.multicast_scouting
        {
            return Ok(());
        }
        Err(format!(
            "zenoh.listen: {} speaks Zenoh, but the session neither listens (zenoh.listen) nor connects \
             (zenoh.connect) and zenoh.multicast_scouting is off, so nothing can reach it: set zenoh.listen \
             (e.g. [\"tcp/127.0.0.1:7447\"]) for consumers and detection workers to connect to, or \
             zenoh.connect to a router, worker or consumer that listens",
            users.join(" and ")
        ))
    }

    /// Without the cargo feature `zenoh` nothing that speaks Zenoh is built: a profile that
    /// turns any of it on is refused, naming the key and the feature.
    #[cfg(not(feature = "zenoh"))]
    fn zenoh_in_build(&self) -> Result<(), String> {
        match self.needs_zenoh() {
            Some((key, what)) => Err(format!(
                "{key}: {what} needs Zenoh, which this build leaves out: build op3dsgd with the cargo \
                 feature `zenoh` (`cargo build --release -p op3dsgd --features zenoh`; the Debian \
                 package and scripts/test.sh have it)"
            )),
            None => Ok(()),
        }
    }

    /// With the cargo feature `zenoh` every Zenoh-speaking stage is built.
    #[cfg(feature = "zenoh")]
    fn zenoh_in_build(&self) -> Result<(), String> {
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
            + if self.pose.source.is_received() { MAX_PENDING_FRAMES } else { 0 }
    }
}

/// Splits a `path: message` string from a section's `validate` into its parts.
fn split_message(message: String) -> (String, String) {
    match message.split_once(": ") {
        Some((path, msg)) => (path.to_owned(), msg.to_owned()),
        None => (String::new(), message),
    }
}

/// The effective profile as TOML, the sections of registered backends included (what
/// `--print-config` shows), for the recording's `op3dsg.profile` metadata.
pub fn effective_toml(profile: &Profile) -> String {
    let mut table = toml::Table::try_from(profile).unwrap_or_default();
    for (path, section) in &profile.sections {
        if let Some((group, name)) = path.split_once('.')
            && let Some(toml::Value::Table(group)) = table.get_mut(group)
        {
            group.insert(name.to_owned(), toml::Value::Table(section.clone()));
        }
    }
    toml::to_string(&table).unwrap_or_default()
}
