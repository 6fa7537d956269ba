//! The oracle's configuration: the noise knobs ([`OracleConfig`], `[detector.oracle]`), where its
//! semantic features come from ([`SemanticSource`]), the `clean` / `realistic` presets and the
//! range checks.

use op3dsg_runtime::perception::candidates::CandidateMode;
use serde::{Deserialize, Serialize};

/// Largest erosion / dilation radius `validate` accepts, pixels.
const MAX_MORPH_RADIUS_PX: u32 = 32;
/// Largest false-positive mean `validate` accepts, per frame.
const MAX_FALSE_POSITIVES_PER_FRAME: f64 = 100.0;
/// Length of the oracle's semantic features in both presets.
pub(super) const SEMANTIC_DIM: usize = 64;
/// Largest semantic feature length `validate` accepts.
const MAX_SEMANTIC_DIM: usize = 4096;

/// Noise knobs of the oracle detector (`[detector.oracle]` in the daemon config).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct OracleConfig {
    /// Probability that an object visible in the frame (with at least `min_visible_px` pixels) is
    /// not detected, before the small / far boosts. Unitless, [0, 1].
    pub object_miss_rate: f64,
    /// Probability that a visible part is not detected, before the small / far boosts.
    /// Unitless, [0, 1].
    pub part_miss_rate: f64,
    /// Visible-area threshold of the small-instance boost, pixels: an instance whose visible mask
    /// has `area < small_area_px` pixels gets `small_miss_boost * (1 - area / small_area_px)`
    /// added to its miss probability. 0 disables the boost.
    pub small_area_px: u32,
    /// Extra miss probability of a vanishingly small instance (see `small_area_px`).
    /// Unitless, [0, 1].
    pub small_miss_boost: f64,
    /// Distance threshold of the far-instance boost, metres: an instance whose median valid depth
    /// `d` exceeds it gets `far_miss_boost * min(1, (d - far_distance_m) / far_distance_m)` added
    /// to its miss probability. Must be > 0.
    pub far_distance_m: f64,
    /// Extra miss probability of an instance at twice `far_distance_m` or beyond.
    /// Unitless, [0, 1].
    pub far_miss_boost: f64,
    /// Instances with fewer visible pixels than this are never detected (a real detector cannot
    /// see 3 pixels), pixels. At least 1.
    pub min_visible_px: u32,
    /// Probability that a detection's label is a synonym instead of the canonical label
    /// (`cupboard` for `cabinet`; for a part, its own synonyms or its label with the parent's
    /// label replaced by a parent synonym, `cupboard handle`). Instances without any synonym keep
    /// their canonical label. Unitless, [0, 1].
    pub synonym_rate: f64,
    /// Per detection, the true mask may be eroded by a uniformly drawn `0..=mask_erode_px_max`
    /// pixels (square structuring element), pixels.
    pub mask_erode_px_max: u32,
    /// Per detection, the true mask may be dilated by a uniformly drawn `0..=mask_dilate_px_max`
    /// pixels (square structuring element; bleeds into neighbours and background), pixels.
    /// When both maxima are non-zero, erosion and dilation are equally likely.
    pub mask_dilate_px_max: u32,
    /// Mean number of false positives per frame (Poisson). A false positive is an elliptic blob
    /// at a random place, labelled with a random label of the scene, with no ground truth.
    pub false_positives_per_frame: f64,
    /// Mean score of true detections; scores are `clamp(N(score_mean, score_std), 0.05, 1)`.
    /// Unitless, [0, 1].
    pub score_mean: f64,
    /// Standard deviation of the scores of true and false detections. Unitless, [0, 1].
    pub score_std: f64,
    /// Mean score of false positives (same spread and clamp as true detections).
    /// Unitless, [0, 1].
    pub false_positive_score_mean: f64,
    /// Length of the semantic feature given with every detection (0 = none). The oracle's
    /// stand-in for a detector's region embedding: a fixed pseudo-random unit vector per
    /// canonical label (seeded by the label's text, so every run and every scene agree),
    /// perturbed per detection by `semantic_noise` and re-normalised. Synonym labels keep the
    /// canonical label's vector: the region looks the same whatever the detector calls it.
    pub semantic_dim: usize,
    /// Norm of the Gaussian perturbation of a detection's semantic feature relative to the unit
    /// label vector (the expected cosine to the label vector is about `1 / sqrt(1 + noise²)`).
    /// Unitless, [0, 2].
    pub semantic_noise: f64,
    /// Seed of the noise; the stream of a frame is seeded from `(seed, frame.seq)`.
    pub seed: u64,
    /// Which parts are reported: `all` (every visible part), `knowledge` (those the frame's
    /// knowledge-guided prompt list asks for) or `generic` (those a fixed generic part
    /// vocabulary finds). See the [oracle module docs](super).
    pub part_prompts: CandidateMode,
    /// Where semantic features come from: `label_vector` (pseudo-random per label,
    /// `semantic_dim` long) or `text_encoder` (MiniLM embedding of the label, 384 long; needs
    /// `[text_encoder] enabled = true`).
    pub semantic_source: SemanticSource,
    /// Probability that a detection's label is replaced by one of its confusable neighbours
    /// (`drawer` for `cabinet`, for a part its part word: `cabinet button` for `cabinet knob`).
    /// The neighbours are the knowledge base's category names nearest to the label by MiniLM
    /// embedding (cosine at least 0.5, at most 3, never the label's own category; see
    /// [`ConfusionTable`](super::ConfusionTable)), not the ground truth's synonyms. Needs the
    /// text encoder's model when above 0. A label without a neighbour is kept. Unitless, [0, 1].
    pub confusion_rate: f64,
    /// Probability that a detected object comes out as two detections (its mask cut in two
    /// across its longer side, both with its label): an over-segmenting detector. Unitless, [0, 1].
    pub split_rate: f64,
    /// Probability that a detection swallows an overlapping detection of the same kind (boxes
    /// touching within 2 px): one detection with the union mask and the larger one's label, as
    /// when a detector sees two adjacent things as one. Unitless, [0, 1].
    pub merge_rate: f64,
    /// Probability that a detection's mask bleeds into the background at depth edges: it grows
    /// by up to `depth_bleed_px` pixels into neighbouring pixels whose depth is at least 0.15 m
    /// behind the instance (or invalid), so the back-projected points fly into the background.
    /// Unitless, [0, 1].
    pub depth_bleed_rate: f64,
    /// Width of the bleed of `depth_bleed_rate`, pixels (drawn uniformly in `1..=depth_bleed_px`).
    pub depth_bleed_px: u32,
    /// Probability that a detected part is reported as an object (kind error; the label stays
    /// the part's). Unitless, [0, 1].
    pub kind_error_rate: f64,
    /// Probability that the image tagger misses a visible object's tag, so the prompt list lacks
    /// its parts (prompt-list modes only). Unitless, [0, 1].
    pub tag_miss_rate: f64,
    /// Mean number of extra object tags per frame (Poisson), drawn from the knowledge base's
    /// object names: the prompt list asks for parts of things that are not there (prompt-list
    /// modes only).
    pub tag_add_per_frame: f64,
    /// Pose drift, as a fraction of the distance the camera travelled: the pose given to fusion
    /// walks away from the true one by `pose_drift_fraction` x the distance between keyframes,
    /// in a direction that itself wanders, so after a path of length D the error is at most
    /// `pose_drift_fraction x D` (a VIO's "1-2 % of distance"). Applied by the batch runner
    /// (`bench quality`, `fusion-eval`) to the keyframe poses; the live daemon's poses come from
    /// its pose source and are not perturbed. Unitless, [0, 0.5].
    pub pose_drift_fraction: f64,
    /// Heading drift per metre travelled, degrees per metre (about the vertical axis through the
    /// first keyframe's position, with a sign drawn per run). Batch runner only, as
    /// `pose_drift_fraction`. [0, 10].
    pub pose_drift_deg_per_m: f64,
    /// Standard deviation of the per-keyframe pose jitter's translation (per axis, not
    /// accumulated), metres. Batch runner only. [0, 0.5].
    pub pose_jitter_m: f64,
    /// Standard deviation of the per-keyframe pose jitter's rotation (about a random axis),
    /// degrees. Batch runner only. [0, 10].
    pub pose_jitter_deg: f64,
}

/// Where the oracle's semantic features come from (`detector.oracle.semantic_source`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SemanticSource {
    /// [`label_vector`](super::label_vector): a fixed pseudo-random unit vector per canonical label.
    #[default]
    LabelVector,
    /// The text encoder's embedding of the canonical label.
    TextEncoder,
}

impl Default for OracleConfig {
    fn default() -> Self {
        Self::realistic()
    }
}

impl OracleConfig {
    /// No noise at all: every instance with at least `min_visible_px` visible pixels is detected
    /// with its canonical label, its exact mask and score 1.
    pub fn clean() -> Self {
        Self {
            object_miss_rate: 0.0,
            part_miss_rate: 0.0,
            small_area_px: 0,
            small_miss_boost: 0.0,
            far_distance_m: 3.0,
            far_miss_boost: 0.0,
            min_visible_px: 30,
            synonym_rate: 0.0,
            mask_erode_px_max: 0,
            mask_dilate_px_max: 0,
            false_positives_per_frame: 0.0,
            score_mean: 1.0,
            score_std: 0.0,
            false_positive_score_mean: 0.35,
            semantic_dim: SEMANTIC_DIM,
            semantic_noise: 0.0,
            seed: 0,
            part_prompts: CandidateMode::All,
            semantic_source: SemanticSource::LabelVector,
            confusion_rate: 0.0,
            split_rate: 0.0,
            merge_rate: 0.0,
            depth_bleed_rate: 0.0,
            depth_bleed_px: 0,
            kind_error_rate: 0.0,
            tag_miss_rate: 0.0,
            tag_add_per_frame: 0.0,
            pose_drift_fraction: 0.0,
            pose_drift_deg_per_m: 0.0,
            pose_jitter_m: 0.0,
            pose_jitter_deg: 0.0,
        }
    }

    /// Noise of a decent open-vocabulary detector on a 640x480 stream.
    pub fn realistic() -> Self {
        Self {
            object_miss_rate: 0.05,
            part_miss_rate: 0.12,
            small_area_px: 400,
            small_miss_boost: 0.4,
            far_distance_m: 3.0,
            far_miss_boost: 0.3,
            min_visible_px: 30,
            synonym_rate: 0.15,
            mask_erode_px_max: 2,
            mask_dilate_px_max: 2,
            false_positives_per_frame: 0.3,
            score_mean: 0.8,
            score_std: 0.1,
            false_positive_score_mean: 0.35,
            semantic_dim: SEMANTIC_DIM,
            semantic_noise: 0.3,
            seed: 0,
            part_prompts: CandidateMode::All,
            semantic_source: SemanticSource::LabelVector,
            // No field noise: the clean preset's zeros.
            ..Self::clean()
        }
    }

    /// `realistic` plus perception as it is on a robot: confusion between similar categories,
    /// split and merged instances, masks bleeding at depth edges, parts reported as objects, a
    /// tagger that misses and adds tags, and pose drift (1.5 % of distance, 0.5 deg/m) with
    /// jitter (5 mm, 0.2 deg).
    pub fn field() -> Self {
        Self {
            confusion_rate: 0.1,
            split_rate: 0.05,
            merge_rate: 0.05,
            depth_bleed_rate: 0.3,
            depth_bleed_px: 4,
            kind_error_rate: 0.05,
            tag_miss_rate: 0.1,
            tag_add_per_frame: 0.3,
            pose_drift_fraction: 0.015,
            pose_drift_deg_per_m: 0.5,
            pose_jitter_m: 0.005,
            pose_jitter_deg: 0.2,
            ..Self::realistic()
        }
    }

    /// Whether any pose noise is on (the batch runner then perturbs keyframe poses).
    pub fn has_pose_noise(&self) -> bool {
        self.pose_drift_fraction > 0.0
            || self.pose_drift_deg_per_m > 0.0
            || self.pose_jitter_m > 0.0
            || self.pose_jitter_deg > 0.0
    }

    /// The preset names [`preset`](Self::preset) knows.
    pub const PRESETS: [&'static str; 3] = ["clean", "realistic", "field"];

    /// The preset called `name` (`clean`, `realistic`, `field`).
    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "clean" => Some(Self::clean()),
            "realistic" => Some(Self::realistic()),
            "field" => Some(Self::field()),
            _ => None,
        }
    }

    /// Checks ranges; the error names the offending field prefixed with `path`
    /// (`detector.oracle.part_miss_rate: must be within [0, 1], got 1.5`).
    pub fn validate(&self, path: &str) -> Result<(), String> {
        let field = |name: &str| if path.is_empty() { name.to_owned() } else { format!("{path}.{name}") };
        let unit_interval = [
            ("object_miss_rate", self.object_miss_rate),
            ("part_miss_rate", self.part_miss_rate),
            ("small_miss_boost", self.small_miss_boost),
            ("far_miss_boost", self.far_miss_boost),
            ("synonym_rate", self.synonym_rate),
            ("score_mean", self.score_mean),
            ("score_std", self.score_std),
            ("false_positive_score_mean", self.false_positive_score_mean),
            ("confusion_rate", self.confusion_rate),
            ("split_rate", self.split_rate),
            ("merge_rate", self.merge_rate),
            ("depth_bleed_rate", self.depth_bleed_rate),
            ("kind_error_rate", self.kind_error_rate),
            ("tag_miss_rate", self.tag_miss_rate),
        ];
        for (name, value) in unit_interval {
            if !(0.0..=1.0).contains(&value) {
                return Err(format!("{}: must be within [0, 1], got {value}", field(name)));
            }
        }
        if !(self.far_distance_m.is_finite() && self.far_distance_m > 0.0) {
            return Err(format!(
                "{}: must be a positive distance in metres, got {}",
                field("far_distance_m"),
                self.far_distance_m
            ));
        }
        if self.semantic_dim > MAX_SEMANTIC_DIM {
            return Err(format!(
                "{}: must be at most {MAX_SEMANTIC_DIM}, got {}",
                field("semantic_dim"),
                self.semantic_dim
            ));
        }
        if !(0.0..=2.0).contains(&self.semantic_noise) {
            return Err(format!("{}: must be within [0, 2], got {}", field("semantic_noise"), self.semantic_noise));
        }
        if self.min_visible_px == 0 {
            return Err(format!("{}: must be at least 1 pixel, got 0", field("min_visible_px")));
        }
        for (name, value) in
            [("mask_erode_px_max", self.mask_erode_px_max), ("mask_dilate_px_max", self.mask_dilate_px_max)]
        {
            if value > MAX_MORPH_RADIUS_PX {
                return Err(format!("{}: must be at most {MAX_MORPH_RADIUS_PX} pixels, got {value}", field(name)));
            }
        }
        if self.depth_bleed_px > MAX_MORPH_RADIUS_PX {
            return Err(format!(
                "{}: must be at most {MAX_MORPH_RADIUS_PX} pixels, got {}",
                field("depth_bleed_px"),
                self.depth_bleed_px
            ));
        }
        if self.depth_bleed_rate > 0.0 && self.depth_bleed_px == 0 {
            return Err(format!(
                "{}: must be at least 1 pixel when depth_bleed_rate is above 0 ({})",
                field("depth_bleed_px"),
                self.depth_bleed_rate
            ));
        }
        let bounded = [
            ("tag_add_per_frame", self.tag_add_per_frame, MAX_FALSE_POSITIVES_PER_FRAME),
            ("pose_drift_fraction", self.pose_drift_fraction, 0.5),
            ("pose_drift_deg_per_m", self.pose_drift_deg_per_m, 10.0),
            ("pose_jitter_m", self.pose_jitter_m, 0.5),
            ("pose_jitter_deg", self.pose_jitter_deg, 10.0),
        ];
        for (name, value, max) in bounded {
            if !(0.0..=max).contains(&value) {
                return Err(format!("{}: must be within [0, {max}], got {value}", field(name)));
            }
        }
        if !(0.0..=MAX_FALSE_POSITIVES_PER_FRAME).contains(&self.false_positives_per_frame) {
            return Err(format!(
                "{}: must be within [0, {MAX_FALSE_POSITIVES_PER_FRAME}], got {}",
                field("false_positives_per_frame"),
                self.false_positives_per_frame
            ));
        }
        Ok(())
    }
}
