//! The oracle detector: turns the synthetic renderer's per-pixel instance-id image into
//! detections with realistic, configurable noise (misses that grow for small and far instances,
//! synonym labels, eroded or dilated masks, false positives, noisy scores), so fusion, the graph
//! and evaluation run as if a real detector were in the loop.
//!
//! The noise of a frame is a pure function of `(config, frame)`: the random stream is seeded from
//! `hash(config.seed, frame.seq)`, so the output does not depend on which worker handles which
//! frame, and different frames (hence different workers) draw uncorrelated noise.
//!
//! ## Prompt lists
//!
//! With `part_prompts = "knowledge"` or `"generic"` the oracle behaves like an open-vocabulary
//! detector given a prompt list ([`super::candidates`]): each frame's tags are the canonical
//! labels of the objects visible in it (an ideal image tagger), the list is built from them, and
//! a visible part is only reported when the list asks for it
//! ([`super::candidates::match_part`]), under its own label or the prompt's text (`nightstand
//! knob`, or `handle` with the generic vocabulary). Parts nothing asks for are missed. The random
//! draws of a frame do not depend on the list, so two modes differ only by what the list does.
//! With `"all"` (the default) every part is reported as before.
//!
//! ## Semantic features
//!
//! By default a detection's semantic feature is a fixed pseudo-random vector per canonical label
//! ([`label_vector`], `semantic_dim` long) plus noise. With `semantic_source = "text_encoder"`
//! it is the all-MiniLM-L6-v2 embedding of the canonical label (384 long, from the profile's
//! `[onnx]` and `[text_encoder]`, which must be enabled) plus the same noise: labels that mean
//! similar things then get similar features, as a real region embedding would.

use std::sync::Arc;

use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::synthetic::{InstanceInfo, InstanceKind};
use op3dsg_ipc_types::NodeKind;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};

use super::candidates::{CandidateMode, PartCandidates, PromptList, match_part};
use super::{Detection, Detector, DetectorError, Mask, normalise};
use crate::knowledge::{ObjectId, PartId};

/// Largest erosion / dilation radius `validate` accepts, pixels.
const MAX_MORPH_RADIUS_PX: u32 = 32;
/// Largest false-positive mean `validate` accepts, per frame.
const MAX_FALSE_POSITIVES_PER_FRAME: f64 = 100.0;
/// Hard cap on false positives in one frame (guards the Poisson sampler's tail).
const MAX_FALSE_POSITIVES_DRAWN: u32 = 1000;
/// Length of the oracle's semantic features in both presets.
const SEMANTIC_DIM: usize = 64;
/// Largest semantic feature length `validate` accepts.
const MAX_SEMANTIC_DIM: usize = 4096;
/// Scores are clamped to `[MIN_SCORE, 1]`.
const MIN_SCORE: f64 = 0.05;

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
    /// vocabulary finds). See the module docs.
    pub part_prompts: CandidateMode,
    /// Where semantic features come from: `label_vector` (pseudo-random per label,
    /// `semantic_dim` long) or `text_encoder` (MiniLM embedding of the label, 384 long; needs
    /// `[text_encoder] enabled = true`).
    pub semantic_source: SemanticSource,
}

/// Where the oracle's semantic features come from (`detector.oracle.semantic_source`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SemanticSource {
    /// [`label_vector`]: a fixed pseudo-random unit vector per canonical label.
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
        }
    }

    /// The preset called `name` (`clean`, `realistic`).
    pub fn preset(name: &str) -> Option<Self> {
        match name {
            "clean" => Some(Self::clean()),
            "realistic" => Some(Self::realistic()),
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

/// Per-instance facts prepared once at construction.
#[derive(Debug, Clone)]
struct Prepared {
    kind: NodeKind,
    /// Index (into `instances`) of the parent, when it is known.
    parent: Option<usize>,
    /// Byte offset of the parent's label inside this part's label, at word boundaries.
    parent_label_at: Option<usize>,
    /// Part category of the label (set with a prompt list).
    part_category: Option<PartId>,
    /// Object category of the parent's label (set with a prompt list).
    parent_category: Option<ObjectId>,
    /// Normalised labels the detector may use for it (set with a prompt list).
    accepted_labels: Vec<String>,
}

/// Pixel statistics of one instance in the current frame.
#[derive(Debug, Clone, Copy)]
struct Stats {
    count: u32,
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
}

impl Stats {
    const EMPTY: Stats = Stats { count: 0, x0: u32::MAX, y0: u32::MAX, x1: 0, y1: 0 };
}

/// What happens to a detection's mask.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Morph {
    Erode(u32),
    Dilate(u32),
}

/// Sentinel of `OracleDetector::index_of_id` for ids that are no instance.
const NO_INSTANCE: u32 = u32::MAX;

/// The oracle detector of the synthetic world (see the module docs).
#[derive(Debug)]
pub struct OracleDetector {
    config: OracleConfig,
    instances: Vec<InstanceInfo>,
    prepared: Vec<Prepared>,
    /// Instance index by id (65 536 entries, built once).
    index_of_id: Vec<u32>,
    /// Distinct labels of the scene with their kind (false-positive labels).
    scene_labels: Vec<(String, NodeKind)>,
    /// Per instance, the semantic vector of its canonical label (empty when `semantic_dim = 0`).
    instance_vectors: Vec<Vec<f32>>,
    /// Per scene label, its semantic vector.
    scene_label_vectors: Vec<Vec<f32>>,
    worker_index: u32,
    /// Per-instance pixel statistics of the current frame (sized once).
    stats: Vec<Stats>,
    /// Valid depths of one instance, for its median (capacity grows to the image size once).
    depth_scratch: Vec<u16>,
    unknown_pixels_last: u64,
    unknown_pixels_total: u64,
    /// Prompt lists, when `part_prompts` is not `all`.
    candidates: Option<Arc<PartCandidates>>,
    /// The current frame's prompt list.
    prompt_list: PromptList,
    /// The current frame's tags (indices into `instances`).
    tag_scratch: Vec<usize>,
}

impl OracleDetector {
    /// A detector for the scene made of `instances`. `worker_index` is kept for logs only: the
    /// noise of a frame depends on `(config.seed, frame.seq)` alone, so outputs do not depend on
    /// which worker handles which frame.
    pub fn new(config: OracleConfig, instances: Vec<InstanceInfo>, worker_index: u32) -> Self {
        let mut index_of_id = vec![NO_INSTANCE; usize::from(u16::MAX) + 1];
        for (index, info) in instances.iter().enumerate() {
            // Id 0 is background; later duplicates lose to the first.
            if info.id != 0 && index_of_id[usize::from(info.id)] == NO_INSTANCE {
                index_of_id[usize::from(info.id)] = index as u32;
            }
        }
        let prepared = instances
            .iter()
            .map(|info| {
                let parent = info
                    .parent
                    .map(|id| index_of_id[usize::from(id)])
                    .filter(|index| *index != NO_INSTANCE)
                    .map(|index| index as usize);
                let parent_label_at = parent.and_then(|p| find_word(&info.label, &instances[p].label));
                Prepared {
                    kind: node_kind(info.kind),
                    parent,
                    parent_label_at,
                    part_category: None,
                    parent_category: None,
                    accepted_labels: Vec::new(),
                }
            })
            .collect();
        let mut scene_labels: Vec<(String, NodeKind)> = Vec::new();
        for info in &instances {
            if !scene_labels.iter().any(|(label, _)| *label == info.label) {
                scene_labels.push((info.label.clone(), node_kind(info.kind)));
            }
        }
        let stats = vec![Stats::EMPTY; instances.len()];
        let dim = config.semantic_dim;
        let instance_vectors = instances.iter().map(|info| label_vector(&info.label, dim)).collect();
        let scene_label_vectors = scene_labels.iter().map(|(label, _)| label_vector(label, dim)).collect();
        Self {
            config,
            instances,
            prepared,
            index_of_id,
            scene_labels,
            instance_vectors,
            scene_label_vectors,
            worker_index,
            stats,
            depth_scratch: Vec::new(),
            unknown_pixels_last: 0,
            unknown_pixels_total: 0,
            candidates: None,
            prompt_list: PromptList::default(),
            tag_scratch: Vec::new(),
        }
    }

    /// Reports parts only when the frame's prompt list from `candidates` asks for them (see the
    /// module docs); a [`CandidateMode::All`] list changes nothing.
    pub fn with_candidates(mut self, candidates: Arc<PartCandidates>) -> Self {
        if candidates.mode() == CandidateMode::All {
            return self;
        }
        let kb = candidates.knowledge();
        for (index, info) in self.instances.iter().enumerate() {
            let prepared = &mut self.prepared[index];
            if prepared.kind != NodeKind::Part {
                continue;
            }
            prepared.part_category = kb.resolve(&info.label).and_then(|r| r.part());
            prepared.parent_category = prepared.parent.and_then(|p| kb.object_category(&self.instances[p].label));
            prepared.accepted_labels =
                possible_labels(&self.instances, info).iter().map(|l| crate::knowledge::normalise(l)).collect();
        }
        self.candidates = Some(candidates);
        self
    }

    /// Uses `vectors` (canonical label → unit vector) as the semantic vectors of the labels it
    /// has; other labels keep theirs. For the text encoder's label embeddings.
    pub fn with_label_vectors(mut self, vectors: &std::collections::HashMap<String, Vec<f32>>) -> Self {
        for (info, v) in self.instances.iter().zip(&mut self.instance_vectors) {
            if let Some(embedding) = vectors.get(&info.label) {
                v.clone_from(embedding);
            }
        }
        for ((label, _), v) in self.scene_labels.iter().zip(&mut self.scene_label_vectors) {
            if let Some(embedding) = vectors.get(label) {
                v.clone_from(embedding);
            }
        }
        self
    }

    /// Builds the frame's prompt list from the objects visible in it.
    fn build_prompt_list(&mut self) {
        let Some(candidates) = &self.candidates else { return };
        self.tag_scratch.clear();
        for (index, s) in self.stats.iter().enumerate() {
            if s.count >= self.config.min_visible_px && self.prepared[index].kind == NodeKind::Object {
                self.tag_scratch.push(index);
            }
        }
        let tags: Vec<&str> = self.tag_scratch.iter().map(|&i| self.instances[i].label.as_str()).collect();
        candidates.prompts(&tags, &mut self.prompt_list);
    }

    /// Whether the frame's prompt list asks for instance `index`, and under which label
    /// (`Some(None)`: its own).
    fn asked_for(&self, index: usize) -> Option<Option<&str>> {
        let prepared = &self.prepared[index];
        if self.candidates.is_none() || prepared.kind == NodeKind::Object {
            return Some(None);
        }
        match_part(
            &self.prompt_list,
            &prepared.accepted_labels,
            prepared.part_category,
            prepared.parent_category,
            &self.instances[index].label,
        )
    }

    /// The configuration.
    pub fn config(&self) -> &OracleConfig {
        &self.config
    }

    /// The worker this detector belongs to.
    pub fn worker_index(&self) -> u32 {
        self.worker_index
    }

    /// Pixels of the last frame whose non-zero instance id is not among the known instances.
    pub fn unknown_instance_pixels(&self) -> u64 {
        self.unknown_pixels_last
    }

    /// Pixels with unknown instance ids over all frames so far.
    pub fn unknown_instance_pixels_total(&self) -> u64 {
        self.unknown_pixels_total
    }

    /// One pass over the id image: per-instance pixel counts and boxes, unknown-id pixels.
    fn gather_stats(&mut self, ids: &[u16], width: u32) {
        self.stats.fill(Stats::EMPTY);
        let mut unknown = 0u64;
        for (y, row) in ids.chunks_exact(width as usize).enumerate() {
            let y = y as u32;
            for (x, &id) in row.iter().enumerate() {
                if id == 0 {
                    continue;
                }
                let index = self.index_of_id[usize::from(id)];
                if index == NO_INSTANCE {
                    unknown += 1;
                    continue;
                }
                let s = &mut self.stats[index as usize];
                let x = x as u32;
                s.count += 1;
                s.x0 = s.x0.min(x);
                s.x1 = s.x1.max(x);
                s.y0 = s.y0.min(y);
                s.y1 = s.y1.max(y);
            }
        }
        self.unknown_pixels_last = unknown;
        self.unknown_pixels_total += unknown;
    }

    /// Median valid depth of instance `id` over its box, metres; `None` without valid depth.
    fn median_depth_m(&mut self, frame: &Frame, ids: &[u16], id: u16, s: Stats) -> Option<f64> {
        let width = frame.intrinsics.width as usize;
        self.depth_scratch.clear();
        for y in s.y0..=s.y1 {
            let span = y as usize * width + s.x0 as usize..=y as usize * width + s.x1 as usize;
            let depths = ids[span.clone()].iter().zip(&frame.depth[span]);
            self.depth_scratch.extend(depths.filter(|&(&i, &d)| i == id && d != 0).map(|(_, &d)| d));
        }
        if self.depth_scratch.is_empty() {
            return None;
        }
        let mid = self.depth_scratch.len() / 2;
        let (_, median, _) = self.depth_scratch.select_nth_unstable(mid);
        Some(f64::from(*median) / f64::from(frame.depth_units_per_m))
    }

    /// Miss probability of instance `index` with pixel statistics `s`.
    fn miss_probability(&mut self, frame: &Frame, ids: &[u16], index: usize, s: Stats) -> f64 {
        let c = &self.config;
        let mut p = match self.prepared[index].kind {
            NodeKind::Object => c.object_miss_rate,
            NodeKind::Part => c.part_miss_rate,
        };
        if c.small_area_px > 0 && s.count < c.small_area_px {
            p += c.small_miss_boost * (1.0 - f64::from(s.count) / f64::from(c.small_area_px));
        }
        if c.far_miss_boost > 0.0 {
            let far = c.far_distance_m;
            if let Some(d) = self.median_depth_m(frame, ids, self.instances[index].id, s)
                && d > far
            {
                p += self.config.far_miss_boost * ((d - far) / far).min(1.0);
            }
        }
        p.clamp(0.0, 1.0)
    }

    /// The label of a detection of instance `index`: canonical, or with probability
    /// `synonym_rate` one of its synonyms (own ones, and for parts the parent-based ones).
    fn label(&self, index: usize, rng: &mut ChaCha8Rng) -> String {
        let info = &self.instances[index];
        if self.config.synonym_rate <= 0.0 || !rng.random_bool(self.config.synonym_rate) {
            return info.label.clone();
        }
        let prepared = &self.prepared[index];
        let parent = prepared.parent.zip(prepared.parent_label_at).map(|(p, at)| (&self.instances[p], at));
        let own = info.synonyms.len();
        let inherited = parent.map_or(0, |(p, _)| p.synonyms.len());
        if own + inherited == 0 {
            return info.label.clone();
        }
        let pick = rng.random_range(0..own + inherited);
        if pick < own {
            return info.synonyms[pick].clone();
        }
        match parent {
            Some((p, at)) => {
                let synonym = &p.synonyms[pick - own];
                format!("{}{}{}", &info.label[..at], synonym, &info.label[at + p.label.len()..])
            }
            None => info.label.clone(),
        }
    }

    /// Draws how the mask of a detection is perturbed.
    fn draw_morph(&self, rng: &mut ChaCha8Rng) -> Option<Morph> {
        let (erode, dilate) = (self.config.mask_erode_px_max, self.config.mask_dilate_px_max);
        let morph = match (erode > 0, dilate > 0) {
            (false, false) => return None,
            (true, false) => Morph::Erode(rng.random_range(0..=erode)),
            (false, true) => Morph::Dilate(rng.random_range(0..=dilate)),
            (true, true) => {
                if rng.random_bool(0.5) {
                    Morph::Erode(rng.random_range(0..=erode))
                } else {
                    Morph::Dilate(rng.random_range(0..=dilate))
                }
            }
        };
        Some(morph)
    }

    /// A detection's semantic feature: the label vector plus noise, re-normalised.
    fn semantic_feature(&self, base: &[f32], rng: &mut ChaCha8Rng) -> Option<Vec<f32>> {
        if base.is_empty() {
            return None;
        }
        let scale = (self.config.semantic_noise / (base.len() as f64).sqrt()) as f32;
        if scale <= 0.0 {
            return Some(base.to_vec());
        }
        let mut v: Vec<f32> = base.iter().map(|b| b + scale * rng.sample::<f32, _>(StandardNormal)).collect();
        normalise(&mut v);
        Some(v)
    }

    /// A false-positive blob: an ellipse at a random place, clipped to the image.
    fn false_positive(&self, width: u32, height: u32, rng: &mut ChaCha8Rng) -> Option<Detection> {
        if self.scene_labels.is_empty() || width == 0 || height == 0 {
            return None;
        }
        let pick = rng.random_range(0..self.scene_labels.len());
        let (label, kind) = &self.scene_labels[pick];
        let short = width.min(height) as f64;
        let r_min = (short / 40.0).max(2.0);
        let r_max = (short / 8.0).max(r_min + 1.0);
        let rx = rng.random_range(r_min..r_max);
        let ry = rng.random_range(r_min..r_max);
        let cx = rng.random_range(0.0..f64::from(width));
        let cy = rng.random_range(0.0..f64::from(height));
        let x0 = (cx - rx).floor().max(0.0) as u32;
        let y0 = (cy - ry).floor().max(0.0) as u32;
        let x1 = ((cx + rx).ceil() as u32).min(width - 1);
        let y1 = ((cy + ry).ceil() as u32).min(height - 1);
        let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
        let mut data = vec![0u8; (w * h) as usize];
        for y in y0..=y1 {
            for x in x0..=x1 {
                let dx = (f64::from(x) + 0.5 - cx) / rx;
                let dy = (f64::from(y) + 0.5 - cy) / ry;
                if dx * dx + dy * dy <= 1.0 {
                    data[((y - y0) * w + (x - x0)) as usize] = 1;
                }
            }
        }
        let mask = tighten(Mask { x0, y0, width: w, height: h, data })?;
        let score = draw_score(self.config.false_positive_score_mean, self.config.score_std, rng);
        let semantic_feature = self.semantic_feature(&self.scene_label_vectors[pick], rng);
        Some(Detection {
            label: label.clone(),
            kind: *kind,
            score,
            mask,
            semantic_feature,
            ground_truth_instance: None,
        })
    }
}

impl Detector for OracleDetector {
    fn detect(&mut self, frame: &Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError> {
        out.clear();
        let Some(ids) = frame.instance_ids.as_deref() else {
            return Err(DetectorError::Frame {
                seq: frame.seq,
                reason: "frame has no instance ids: the oracle detector only works with the synthetic source".into(),
            });
        };
        let (width, height) = (frame.intrinsics.width, frame.intrinsics.height);
        let pixels = frame.intrinsics.pixel_count();
        if ids.len() != pixels || frame.depth.len() != pixels {
            return Err(DetectorError::Frame {
                seq: frame.seq,
                reason: format!(
                    "instance id image has {} and depth image {} pixels, intrinsics say {width}x{height}",
                    ids.len(),
                    frame.depth.len()
                ),
            });
        }
        if pixels == 0 {
            self.unknown_pixels_last = 0;
            return Ok(());
        }
        self.gather_stats(ids, width);
        self.build_prompt_list();
        let mut rng = ChaCha8Rng::seed_from_u64(frame_seed(self.config.seed, frame.seq));

        for index in 0..self.instances.len() {
            let s = self.stats[index];
            if s.count < self.config.min_visible_px {
                continue;
            }
            let miss = self.miss_probability(frame, ids, index, s);
            if miss > 0.0 && rng.random_bool(miss) {
                continue;
            }
            let label = self.label(index, &mut rng);
            let score = draw_score(self.config.score_mean, self.config.score_std, &mut rng);
            let morph = self.draw_morph(&mut rng);
            let id = self.instances[index].id;
            // Erosion may swallow a thin instance whole: then the detector saw nothing.
            let Some(mask) = instance_mask(ids, width, height, id, s, morph) else { continue };
            let semantic_feature = self.semantic_feature(&self.instance_vectors[index], &mut rng);
            // Decided after the draws, so the list changes nothing else in the frame.
            let label = match self.asked_for(index) {
                None => continue,
                Some(None) => label,
                Some(Some(prompt)) => prompt.to_owned(),
            };
            out.push(Detection {
                label,
                kind: self.prepared[index].kind,
                score,
                mask,
                semantic_feature,
                ground_truth_instance: Some(id),
            });
        }

        if self.config.false_positives_per_frame > 0.0 {
            let count = draw_poisson(self.config.false_positives_per_frame, &mut rng);
            for _ in 0..count {
                if let Some(detection) = self.false_positive(width, height, &mut rng) {
                    out.push(detection);
                }
            }
        }
        Ok(())
    }

    fn name(&self) -> &str {
        "oracle"
    }
}

/// Every label the oracle may give a detection of `instance` (one of `instances`): its
/// canonical label, its own synonyms, and for a part its label with the parent's label replaced
/// by each of the parent's synonyms (`cupboard handle` for `cabinet handle`), in that order,
/// without duplicates. Evaluation accepts these as a correct label; the test
/// `synonyms_follow_the_rate_and_the_instance_and_parent_lists` keeps it in step with
/// [`OracleDetector`].
pub fn possible_labels(instances: &[InstanceInfo], instance: &InstanceInfo) -> Vec<String> {
    let mut labels = vec![instance.label.clone()];
    let mut add = |label: String| {
        if !labels.contains(&label) {
            labels.push(label);
        }
    };
    for synonym in &instance.synonyms {
        add(synonym.clone());
    }
    // The first instance with the parent's id, as `OracleDetector::new` resolves it.
    let parent = instance.parent.filter(|id| *id != 0).and_then(|id| instances.iter().find(|i| i.id == id));
    if let Some(parent) = parent
        && let Some(at) = find_word(&instance.label, &parent.label)
    {
        for synonym in &parent.synonyms {
            add(format!("{}{}{}", &instance.label[..at], synonym, &instance.label[at + parent.label.len()..]));
        }
    }
    labels
}

fn node_kind(kind: InstanceKind) -> NodeKind {
    match kind {
        InstanceKind::Object => NodeKind::Object,
        InstanceKind::Part => NodeKind::Part,
    }
}

/// Byte offset of `word` inside `text` where it starts and ends at word boundaries (spaces or the
/// ends of `text`).
fn find_word(text: &str, word: &str) -> Option<usize> {
    if word.is_empty() {
        return None;
    }
    text.match_indices(word).map(|(at, _)| at).find(|&at| {
        let before = at == 0 || text[..at].ends_with(' ');
        let end = at + word.len();
        let after = end == text.len() || text[end..].starts_with(' ');
        before && after
    })
}

/// SplitMix64 finaliser.
fn mix64(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Seed of a frame's noise stream.
fn frame_seed(seed: u64, seq: u64) -> u64 {
    mix64(mix64(seed) ^ seq.wrapping_mul(0xD1B5_4A32_D192_ED03))
}

/// A standard normal draw (Box-Muller).
fn standard_normal(rng: &mut ChaCha8Rng) -> f64 {
    rng.sample(StandardNormal)
}

/// The unit semantic vector of `label` (`dim` entries; empty for 0): Gaussian entries from a
/// stream seeded by the FNV-1a hash of the label's text.
pub fn label_vector(label: &str, dim: usize) -> Vec<f32> {
    if dim == 0 {
        return Vec::new();
    }
    let hash = label.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3));
    let mut rng = ChaCha8Rng::seed_from_u64(hash);
    let mut v: Vec<f32> = (0..dim).map(|_| rng.sample::<f32, _>(StandardNormal)).collect();
    normalise(&mut v);
    v
}

/// `clamp(N(mean, std), 0.05, 1)`.
fn draw_score(mean: f64, std: f64, rng: &mut ChaCha8Rng) -> f32 {
    let value = if std > 0.0 { mean + std * standard_normal(rng) } else { mean };
    value.clamp(MIN_SCORE, 1.0) as f32
}

/// A Poisson draw of mean `lambda` (Knuth for small means, normal approximation beyond 30).
fn draw_poisson(lambda: f64, rng: &mut ChaCha8Rng) -> u32 {
    if lambda.is_nan() || lambda <= 0.0 {
        return 0;
    }
    if lambda > 30.0 {
        let value = (lambda + lambda.sqrt() * standard_normal(rng)).round().max(0.0);
        return (value as u32).min(MAX_FALSE_POSITIVES_DRAWN);
    }
    let limit = (-lambda).exp();
    let mut product = rng.random::<f64>();
    let mut count = 0;
    while product > limit && count < MAX_FALSE_POSITIVES_DRAWN {
        count += 1;
        product *= rng.random::<f64>();
    }
    count
}

/// The mask of instance `id` (pixel statistics `s`) in the `width` x `height` id image, eroded or
/// dilated by `morph` with a square structuring element, cropped to its tight box. Pixels beyond
/// the image edge do not erode (an instance cut by the border keeps its border pixels). `None`
/// when nothing is left.
fn instance_mask(ids: &[u16], width: u32, height: u32, id: u16, s: Stats, morph: Option<Morph>) -> Option<Mask> {
    let radius = match morph {
        Some(Morph::Erode(r) | Morph::Dilate(r)) => r,
        None => 0,
    };
    // Region: the instance box grown by the radius, clipped to the image.
    let x0 = s.x0.saturating_sub(radius);
    let y0 = s.y0.saturating_sub(radius);
    let x1 = s.x1.saturating_add(radius).min(width - 1);
    let y1 = s.y1.saturating_add(radius).min(height - 1);
    let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
    let mut data = vec![0u8; (w * h) as usize];
    for y in y0..=y1 {
        let src = (y * width) as usize;
        let dst = ((y - y0) * w) as usize;
        for x in x0..=x1 {
            data[dst + (x - x0) as usize] = u8::from(ids[src + x as usize] == id);
        }
    }
    if radius > 0 {
        let dilate = matches!(morph, Some(Morph::Dilate(_)));
        // Windows are clipped to the region, which the image edge clips: out-of-image pixels are
        // neutral for both operations.
        data = filter_separable(&data, w as usize, h as usize, radius as usize, dilate);
    }
    tighten(Mask { x0, y0, width: w, height: h, data })
}

/// Square min (erosion) or max (dilation) filter of radius `r`, as a row pass then a column pass.
fn filter_separable(data: &[u8], w: usize, h: usize, r: usize, dilate: bool) -> Vec<u8> {
    let reduce = |window: &mut dyn Iterator<Item = u8>| -> u8 {
        if dilate { window.max().unwrap_or(0) } else { window.min().unwrap_or(0) }
    };
    let mut rows = vec![0u8; w * h];
    for y in 0..h {
        let line = &data[y * w..(y + 1) * w];
        for x in 0..w {
            let (a, b) = (x.saturating_sub(r), (x + r).min(w - 1));
            rows[y * w + x] = reduce(&mut line[a..=b].iter().copied());
        }
    }
    let mut out = vec![0u8; w * h];
    for y in 0..h {
        let (a, b) = (y.saturating_sub(r), (y + r).min(h - 1));
        for x in 0..w {
            out[y * w + x] = reduce(&mut (a..=b).map(|yy| rows[yy * w + x]));
        }
    }
    out
}

/// Crops `mask` to the tight box of its inside pixels; `None` when it is empty.
fn tighten(mask: Mask) -> Option<Mask> {
    let (w, h) = (mask.width as usize, mask.height as usize);
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for y in 0..h {
        for x in 0..w {
            if mask.data[y * w + x] != 0 {
                x0 = x0.min(x);
                x1 = x1.max(x);
                y0 = y0.min(y);
                y1 = y1.max(y);
            }
        }
    }
    if x0 == usize::MAX {
        return None;
    }
    if (x0, y0, x1, y1) == (0, 0, w - 1, h - 1) {
        return Some(mask);
    }
    let (nw, nh) = (x1 - x0 + 1, y1 - y0 + 1);
    let mut data = Vec::with_capacity(nw * nh);
    for y in y0..=y1 {
        data.extend_from_slice(&mask.data[y * w + x0..=y * w + x1]);
    }
    Some(Mask { x0: mask.x0 + x0 as u32, y0: mask.y0 + y0 as u32, width: nw as u32, height: nh as u32, data })
}

#[cfg(test)]
mod tests {
    use super::*;
    use op3dsg_drivers::frame::Intrinsics;
    use std::collections::{HashMap, HashSet};

    fn intrinsics(width: u32, height: u32) -> Intrinsics {
        Intrinsics {
            width,
            height,
            fx: width as f32,
            fy: width as f32,
            cx: width as f32 / 2.0,
            cy: height as f32 / 2.0,
        }
    }

    fn info(id: u16, label: &str, kind: InstanceKind, parent: Option<u16>, synonyms: &[&str]) -> InstanceInfo {
        InstanceInfo {
            id,
            label: label.into(),
            kind,
            parent,
            box_min_m: glam::Vec3::ZERO,
            box_max_m: glam::Vec3::ONE,
            synonyms: synonyms.iter().map(|s| s.to_string()).collect(),
            material: "wood".into(),
        }
    }

    /// Paints `id` at `depth_m` over the rectangle `[x0, x0 + w) x [y0, y0 + h)`.
    fn paint(frame: &mut Frame, id: u16, x0: u32, y0: u32, w: u32, h: u32, depth_m: f32) {
        let width = frame.intrinsics.width;
        let ids = frame.instance_ids.as_mut().unwrap();
        for y in y0..y0 + h {
            for x in x0..x0 + w {
                let i = (y * width + x) as usize;
                ids[i] = id;
                frame.depth[i] = (depth_m * frame.depth_units_per_m) as u16;
            }
        }
    }

    fn no_noise() -> OracleConfig {
        OracleConfig { min_visible_px: 1, ..OracleConfig::clean() }
    }

    /// Runs `frames` frames (seq 0..frames) and returns all detections.
    fn run(detector: &mut OracleDetector, frame: &mut Frame, frames: u64) -> Vec<Vec<Detection>> {
        (0..frames)
            .map(|seq| {
                frame.seq = seq;
                let mut out = Vec::new();
                detector.detect(frame, &mut out).unwrap();
                out
            })
            .collect()
    }

    fn detection_rate(all: &[Vec<Detection>], id: u16) -> f64 {
        let hits = all.iter().filter(|d| d.iter().any(|d| d.ground_truth_instance == Some(id))).count();
        hits as f64 / all.len() as f64
    }

    /// A kitchen-like scene on a 640x480 frame.
    fn kitchen() -> (Frame, Vec<InstanceInfo>) {
        let mut frame = Frame::new(intrinsics(640, 480), true);
        let instances = vec![
            info(1, "cabinet", InstanceKind::Object, None, &["cupboard"]),
            info(2, "cabinet handle", InstanceKind::Part, Some(1), &[]),
            info(3, "stove", InstanceKind::Object, None, &[]),
            info(4, "stove knob", InstanceKind::Part, Some(3), &["dial"]),
            info(5, "light switch", InstanceKind::Object, None, &[]),
        ];
        paint(&mut frame, 1, 0, 0, 300, 400, 2.0);
        paint(&mut frame, 2, 250, 150, 10, 60, 1.95);
        paint(&mut frame, 3, 320, 200, 300, 280, 2.5);
        paint(&mut frame, 4, 400, 220, 12, 12, 2.4);
        paint(&mut frame, 5, 600, 10, 3, 3, 2.0); // 9 px: below min_visible_px
        (frame, instances)
    }

    fn cosine(a: &[f32], b: &[f32]) -> f32 {
        a.iter().zip(b).map(|(x, y)| x * y).sum()
    }

    #[test]
    fn semantic_features_are_noisy_label_vectors() {
        let v = label_vector("cabinet", 64);
        assert_eq!(v, label_vector("cabinet", 64), "deterministic");
        assert!((cosine(&v, &v) - 1.0).abs() < 1e-5, "unit length");
        assert!(cosine(&v, &label_vector("stove", 64)).abs() < 0.5, "different labels are far apart");
        assert!(label_vector("cabinet", 0).is_empty());

        let (frame, instances) = kitchen();
        let mut detector =
            OracleDetector::new(OracleConfig { semantic_noise: 0.3, ..OracleConfig::clean() }, instances, 0);
        let mut cosines = Vec::new();
        for seq in 0..50 {
            let mut f = frame.clone();
            f.seq = seq;
            let mut out = Vec::new();
            detector.detect(&f, &mut out).unwrap();
            for d in &out {
                let feature = d.semantic_feature.as_deref().unwrap();
                assert!((cosine(feature, feature) - 1.0).abs() < 1e-4);
                let label = detector.instances.iter().find(|i| Some(i.id) == d.ground_truth_instance).unwrap();
                cosines.push(cosine(feature, &label_vector(&label.label, SEMANTIC_DIM)));
            }
        }
        let mean = cosines.iter().sum::<f32>() / cosines.len() as f32;
        // E[cos] ≈ 1 / sqrt(1 + 0.3²) = 0.958.
        assert!((mean - 0.958).abs() < 0.02, "mean cosine {mean}");
        let off = OracleConfig { semantic_dim: 0, ..OracleConfig::clean() };
        let mut out = Vec::new();
        OracleDetector::new(off, detector.instances.clone(), 0).detect(&frame, &mut out).unwrap();
        assert!(out.iter().all(|d| d.semantic_feature.is_none()));
    }

    #[test]
    fn clean_preset_detects_every_visible_instance_exactly() {
        let (mut frame, instances) = kitchen();
        frame.seq = 7;
        let mut detector = OracleDetector::new(OracleConfig::clean(), instances.clone(), 0);
        assert_eq!(detector.name(), "oracle");
        let mut out = Vec::new();
        detector.detect(&frame, &mut out).unwrap();
        assert_eq!(out.len(), 4, "{out:?}");
        let ids = frame.instance_ids.as_ref().unwrap();
        for d in &out {
            let id = d.ground_truth_instance.unwrap();
            let inst = instances.iter().find(|i| i.id == id).unwrap();
            assert_eq!(d.label, inst.label);
            assert_eq!(d.kind, node_kind(inst.kind));
            assert_eq!(d.score, 1.0);
            // Clean: the feature is exactly the canonical label's vector.
            assert_eq!(d.semantic_feature.as_deref(), Some(label_vector(&inst.label, SEMANTIC_DIM).as_slice()));
            for y in 0..480 {
                for x in 0..640 {
                    assert_eq!(d.mask.contains(x, y), ids[(y * 640 + x) as usize] == id, "id {id} at ({x}, {y})");
                }
            }
            let area = ids.iter().filter(|v| **v == id).count();
            assert_eq!(d.mask.area(), area);
            assert_eq!(d.mask.data.len(), (d.mask.width * d.mask.height) as usize);
        }
        // The cabinet's box is tight although the handle cuts into it.
        let cabinet = out.iter().find(|d| d.ground_truth_instance == Some(1)).unwrap();
        assert_eq!((cabinet.mask.x0, cabinet.mask.y0, cabinet.mask.width, cabinet.mask.height), (0, 0, 300, 400));
        assert_eq!(detector.unknown_instance_pixels(), 0);
    }

    #[test]
    fn instances_below_min_visible_px_are_never_detected() {
        let mut frame = Frame::new(intrinsics(64, 48), true);
        paint(&mut frame, 1, 0, 0, 5, 5, 1.0); // 25 px
        paint(&mut frame, 2, 20, 20, 6, 5, 1.0); // 30 px
        let instances =
            vec![info(1, "knob", InstanceKind::Part, None, &[]), info(2, "button", InstanceKind::Part, None, &[])];
        let config = OracleConfig {
            part_miss_rate: 0.0,
            small_miss_boost: 0.0,
            far_miss_boost: 0.0,
            false_positives_per_frame: 0.0,
            ..OracleConfig::realistic()
        };
        let mut detector = OracleDetector::new(config, instances, 0);
        let all = run(&mut detector, &mut frame, 200);
        assert_eq!(detection_rate(&all, 1), 0.0);
        // Erosion can swallow nothing here (5x6 survives 2 px erosion), so the 30 px one is
        // always there.
        assert_eq!(detection_rate(&all, 2), 1.0);
    }

    #[test]
    fn miss_rates_match_configuration() {
        let mut frame = Frame::new(intrinsics(64, 48), true);
        let mut instances = Vec::new();
        for k in 0..4u16 {
            paint(&mut frame, 1 + k, k as u32 * 16, 0, 15, 20, 1.0);
            instances.push(info(1 + k, "box", InstanceKind::Object, None, &[]));
            paint(&mut frame, 5 + k, k as u32 * 16, 24, 15, 20, 1.0);
            instances.push(info(5 + k, "knob", InstanceKind::Part, None, &[]));
        }
        let config = OracleConfig {
            object_miss_rate: 0.1,
            part_miss_rate: 0.3,
            small_area_px: 100, // all are 300 px: no boost
            small_miss_boost: 0.5,
            far_distance_m: 3.0, // all at 1 m: no boost
            far_miss_boost: 0.5,
            ..no_noise()
        };
        let mut detector = OracleDetector::new(config, instances, 0);
        let all = run(&mut detector, &mut frame, 1000);
        let object_rate = (1..=4).map(|id| 1.0 - detection_rate(&all, id)).sum::<f64>() / 4.0;
        let part_rate = (5..=8).map(|id| 1.0 - detection_rate(&all, id)).sum::<f64>() / 4.0;
        // Standard errors: 0.0047 and 0.0072 over 4000 trials each.
        assert!((object_rate - 0.1).abs() < 0.025, "object miss rate {object_rate}");
        assert!((part_rate - 0.3).abs() < 0.035, "part miss rate {part_rate}");
    }

    #[test]
    fn small_and_far_parts_are_missed_more() {
        let mut frame = Frame::new(intrinsics(64, 48), true);
        paint(&mut frame, 1, 0, 0, 10, 10, 1.0); // small (100 px), near
        paint(&mut frame, 2, 12, 0, 30, 20, 1.0); // large (600 px), near
        paint(&mut frame, 3, 0, 24, 30, 20, 4.5); // large, far (4.5 m)
        let instances = vec![
            info(1, "knob", InstanceKind::Part, None, &[]),
            info(2, "knob", InstanceKind::Part, None, &[]),
            info(3, "knob", InstanceKind::Part, None, &[]),
        ];
        let config = OracleConfig {
            part_miss_rate: 0.1,
            small_area_px: 400,
            small_miss_boost: 0.4,
            far_distance_m: 3.0,
            far_miss_boost: 0.4,
            ..no_noise()
        };
        let mut detector = OracleDetector::new(config, instances, 0);
        let all = run(&mut detector, &mut frame, 2000);
        let small = 1.0 - detection_rate(&all, 1);
        let large = 1.0 - detection_rate(&all, 2);
        let far = 1.0 - detection_rate(&all, 3);
        // Expected: 0.1 + 0.4 * (1 - 100/400) = 0.4; 0.1; 0.1 + 0.4 * 0.5 = 0.3.
        assert!((small - 0.4).abs() < 0.04, "small miss rate {small}");
        assert!((large - 0.1).abs() < 0.03, "large miss rate {large}");
        assert!((far - 0.3).abs() < 0.04, "far miss rate {far}");
        assert!(small > large + 0.2 && far > large + 0.1);
    }

    #[test]
    fn synonyms_follow_the_rate_and_the_instance_and_parent_lists() {
        let mut frame = Frame::new(intrinsics(64, 48), true);
        paint(&mut frame, 1, 0, 0, 30, 40, 1.0);
        paint(&mut frame, 2, 10, 10, 5, 10, 1.0);
        paint(&mut frame, 3, 32, 0, 30, 40, 1.0);
        paint(&mut frame, 4, 40, 10, 8, 8, 1.0);
        let instances = vec![
            info(1, "cabinet", InstanceKind::Object, None, &["cupboard", "closet"]),
            info(2, "cabinet handle", InstanceKind::Part, Some(1), &[]),
            info(3, "stove", InstanceKind::Object, None, &[]),
            info(4, "stove knob", InstanceKind::Part, Some(3), &["dial"]),
        ];
        let config = OracleConfig { synonym_rate: 0.3, ..no_noise() };
        let mut detector = OracleDetector::new(config, instances.clone(), 0);
        let all = run(&mut detector, &mut frame, 2000);
        let mut labels: HashMap<u16, HashMap<String, usize>> = HashMap::new();
        for d in all.iter().flatten() {
            *labels.entry(d.ground_truth_instance.unwrap()).or_default().entry(d.label.clone()).or_default() += 1;
        }
        let allowed: HashMap<u16, Vec<&str>> = HashMap::from([
            (1, vec!["cabinet", "cupboard", "closet"]),
            (2, vec!["cabinet handle", "cupboard handle", "closet handle"]),
            (3, vec!["stove"]),
            (4, vec!["stove knob", "dial"]),
        ]);
        for (id, counts) in &labels {
            let possible = possible_labels(&instances, &instances[usize::from(*id) - 1]);
            assert_eq!(possible, allowed[id], "id {id}: possible_labels");
            let total: usize = counts.values().sum();
            assert_eq!(total, 2000);
            for label in counts.keys() {
                assert!(allowed[id].contains(&label.as_str()), "id {id}: unexpected label {label}");
            }
            let canonical = counts.get(allowed[id][0]).copied().unwrap_or(0);
            let rate = 1.0 - canonical as f64 / total as f64;
            let expected = if *id == 3 { 0.0 } else { 0.3 };
            assert!((rate - expected).abs() < 0.04, "id {id}: synonym rate {rate}");
            // Every synonym is used.
            assert_eq!(counts.len(), allowed[id].len(), "id {id}: {counts:?}");
        }
    }

    #[test]
    fn find_word_respects_word_boundaries() {
        assert_eq!(find_word("cabinet handle", "cabinet"), Some(0));
        assert_eq!(find_word("upper cabinet handle", "cabinet"), Some(6));
        assert_eq!(find_word("cabinetry handle", "cabinet"), None);
        assert_eq!(find_word("handle", ""), None);
    }

    #[test]
    fn erosion_and_dilation_of_a_square_are_exact() {
        let mut frame = Frame::new(intrinsics(64, 48), true);
        paint(&mut frame, 1, 20, 20, 10, 10, 1.0);
        let ids = frame.instance_ids.as_ref().unwrap();
        let s = Stats { count: 100, x0: 20, y0: 20, x1: 29, y1: 29 };
        let exact = instance_mask(ids, 64, 48, 1, s, None).unwrap();
        assert_eq!((exact.x0, exact.y0, exact.width, exact.height, exact.area()), (20, 20, 10, 10, 100));
        let eroded = instance_mask(ids, 64, 48, 1, s, Some(Morph::Erode(1))).unwrap();
        assert_eq!((eroded.x0, eroded.y0, eroded.width, eroded.height, eroded.area()), (21, 21, 8, 8, 64));
        let dilated = instance_mask(ids, 64, 48, 1, s, Some(Morph::Dilate(2))).unwrap();
        assert_eq!((dilated.x0, dilated.y0, dilated.width, dilated.height, dilated.area()), (18, 18, 14, 14, 196));
        assert!(instance_mask(ids, 64, 48, 1, s, Some(Morph::Erode(5))).is_none());
        // At the image corner, the border does not erode and dilation is clipped.
        let mut corner = Frame::new(intrinsics(64, 48), true);
        paint(&mut corner, 1, 0, 0, 10, 10, 1.0);
        let ids = corner.instance_ids.as_ref().unwrap();
        let s = Stats { count: 100, x0: 0, y0: 0, x1: 9, y1: 9 };
        let eroded = instance_mask(ids, 64, 48, 1, s, Some(Morph::Erode(1))).unwrap();
        assert_eq!((eroded.x0, eroded.y0, eroded.width, eroded.height), (0, 0, 9, 9));
        let dilated = instance_mask(ids, 64, 48, 1, s, Some(Morph::Dilate(1))).unwrap();
        assert_eq!((dilated.x0, dilated.y0, dilated.width, dilated.height), (0, 0, 11, 11));
    }

    #[test]
    fn configured_erosion_shrinks_and_dilation_grows_masks() {
        let mut frame = Frame::new(intrinsics(64, 48), true);
        paint(&mut frame, 1, 20, 20, 10, 10, 1.0);
        paint(&mut frame, 2, 30, 20, 10, 10, 1.0); // neighbour: dilation bleeds into it
        let instances =
            vec![info(1, "box", InstanceKind::Object, None, &[]), info(2, "box", InstanceKind::Object, None, &[])];
        let areas = |config: OracleConfig| -> HashSet<usize> {
            let mut detector = OracleDetector::new(config, instances.clone(), 0);
            run(&mut detector, &mut frame.clone(), 200)
                .iter()
                .flatten()
                .filter(|d| d.ground_truth_instance == Some(1))
                .map(|d| d.mask.area())
                .collect()
        };
        let eroded = areas(OracleConfig { mask_erode_px_max: 1, ..no_noise() });
        assert_eq!(eroded, HashSet::from([100, 64]));
        let dilated = areas(OracleConfig { mask_dilate_px_max: 2, ..no_noise() });
        assert_eq!(dilated, HashSet::from([100, 144, 196]));
        let both = areas(OracleConfig { mask_erode_px_max: 1, mask_dilate_px_max: 1, ..no_noise() });
        assert_eq!(both, HashSet::from([64, 100, 144]));
    }

    #[test]
    fn false_positives_follow_the_poisson_mean() {
        let mut frame = Frame::new(intrinsics(64, 48), true);
        paint(&mut frame, 1, 0, 0, 20, 20, 1.0);
        paint(&mut frame, 2, 30, 0, 8, 8, 1.0);
        let instances = vec![
            info(1, "cabinet", InstanceKind::Object, None, &[]),
            info(2, "cabinet handle", InstanceKind::Part, Some(1), &[]),
            info(3, "fridge", InstanceKind::Object, None, &[]), // not visible, still in the scene
        ];
        let config = OracleConfig { false_positives_per_frame: 0.7, score_std: 0.1, ..no_noise() };
        let mut detector = OracleDetector::new(config, instances, 0);
        let all = run(&mut detector, &mut frame, 2000);
        let counts: Vec<f64> =
            all.iter().map(|d| d.iter().filter(|d| d.ground_truth_instance.is_none()).count() as f64).collect();
        let mean = counts.iter().sum::<f64>() / counts.len() as f64;
        let variance = counts.iter().map(|c| (c - mean).powi(2)).sum::<f64>() / counts.len() as f64;
        // Standard error of the mean: sqrt(0.7 / 2000) = 0.019.
        assert!((mean - 0.7).abs() < 0.07, "mean false positives {mean}");
        assert!((variance - 0.7).abs() < 0.15, "variance {variance}");
        let fps: Vec<&Detection> = all.iter().flatten().filter(|d| d.ground_truth_instance.is_none()).collect();
        let labels: HashSet<&str> = fps.iter().map(|d| d.label.as_str()).collect();
        assert_eq!(labels, HashSet::from(["cabinet", "cabinet handle", "fridge"]));
        for d in &fps {
            assert!(d.mask.area() > 0 && d.mask.x0 + d.mask.width <= 64 && d.mask.y0 + d.mask.height <= 48);
            let expected_kind = if d.label == "cabinet handle" { NodeKind::Part } else { NodeKind::Object };
            assert_eq!(d.kind, expected_kind);
        }
        let fp_score = fps.iter().map(|d| f64::from(d.score)).sum::<f64>() / fps.len() as f64;
        assert!((fp_score - 0.35).abs() < 0.02, "false-positive score mean {fp_score}");
        // True detections are untouched by the false positives.
        assert_eq!(detection_rate(&all, 1), 1.0);
    }

    #[test]
    fn scores_follow_the_configured_distribution() {
        let mut frame = Frame::new(intrinsics(64, 48), true);
        for k in 0..4u16 {
            paint(&mut frame, 1 + k, k as u32 * 16, 0, 15, 40, 1.0);
        }
        let instances = (1..=4).map(|id| info(id, "box", InstanceKind::Object, None, &[])).collect();
        let config = OracleConfig { score_mean: 0.7, score_std: 0.1, ..no_noise() };
        let mut detector = OracleDetector::new(config, instances, 0);
        let scores: Vec<f64> =
            run(&mut detector, &mut frame, 1000).iter().flatten().map(|d| f64::from(d.score)).collect();
        assert_eq!(scores.len(), 4000);
        let mean = scores.iter().sum::<f64>() / scores.len() as f64;
        let std = (scores.iter().map(|s| (s - mean).powi(2)).sum::<f64>() / scores.len() as f64).sqrt();
        assert!((mean - 0.7).abs() < 0.01, "score mean {mean}");
        assert!((std - 0.1).abs() < 0.01, "score std {std}");
        assert!(scores.iter().all(|s| (0.05..=1.0).contains(s)));
    }

    #[test]
    fn output_is_a_pure_function_of_config_and_frame() {
        let (mut frame, instances) = kitchen();
        let config = OracleConfig { false_positives_per_frame: 2.0, seed: 42, ..OracleConfig::realistic() };
        let mut a = OracleDetector::new(config.clone(), instances.clone(), 0);
        let mut b = OracleDetector::new(config.clone(), instances.clone(), 3);
        let mut outputs = Vec::new();
        for seq in [5u64, 9, 5] {
            frame.seq = seq;
            let (mut out_a, mut out_b) = (Vec::new(), Vec::new());
            a.detect(&frame, &mut out_a).unwrap();
            b.detect(&frame, &mut out_b).unwrap();
            assert_eq!(out_a, out_b, "seq {seq}");
            outputs.push(out_a);
        }
        assert_eq!(outputs[0], outputs[2], "same frame twice");
        assert_ne!(outputs[0], outputs[1], "different frames draw different noise");
        // A different seed draws different noise.
        let mut c = OracleDetector::new(OracleConfig { seed: 43, ..config }, instances, 0);
        frame.seq = 5;
        let mut out_c = Vec::new();
        c.detect(&frame, &mut out_c).unwrap();
        assert_ne!(out_c, outputs[0]);
    }

    #[test]
    fn frames_without_instance_ids_are_an_error() {
        let mut frame = Frame::new(intrinsics(64, 48), false);
        frame.seq = 17;
        let mut detector = OracleDetector::new(OracleConfig::clean(), Vec::new(), 0);
        let mut out = vec![Detection {
            label: "stale".into(),
            kind: NodeKind::Object,
            score: 1.0,
            mask: Mask::default(),
            semantic_feature: None,
            ground_truth_instance: None,
        }];
        let error = detector.detect(&frame, &mut out).unwrap_err();
        assert!(matches!(error, DetectorError::Frame { seq: 17, .. }));
        let message = error.to_string();
        assert!(message.contains("frame 17") && message.contains("no instance ids"), "{message}");
        assert!(out.is_empty());
    }

    #[test]
    fn unknown_instance_ids_are_ignored_but_counted() {
        let mut frame = Frame::new(intrinsics(64, 48), true);
        paint(&mut frame, 1, 0, 0, 10, 10, 1.0);
        paint(&mut frame, 99, 20, 20, 5, 4, 1.0);
        let mut detector = OracleDetector::new(no_noise(), vec![info(1, "box", InstanceKind::Object, None, &[])], 0);
        let mut out = Vec::new();
        detector.detect(&frame, &mut out).unwrap();
        assert_eq!(out.len(), 1);
        assert_eq!(detector.unknown_instance_pixels(), 20);
        detector.detect(&frame, &mut out).unwrap();
        assert_eq!(out.len(), 1, "out is replaced, not appended to");
        assert_eq!(detector.unknown_instance_pixels_total(), 40);
    }

    #[test]
    fn validate_names_the_field() {
        assert_eq!(OracleConfig::clean().validate("detector.oracle"), Ok(()));
        assert_eq!(OracleConfig::realistic().validate("detector.oracle"), Ok(()));
        let bad = OracleConfig { part_miss_rate: 1.5, ..OracleConfig::realistic() };
        assert_eq!(
            bad.validate("detector.oracle"),
            Err("detector.oracle.part_miss_rate: must be within [0, 1], got 1.5".into())
        );
        let nan = OracleConfig { synonym_rate: f64::NAN, ..OracleConfig::realistic() };
        assert!(nan.validate("d").unwrap_err().starts_with("d.synonym_rate:"));
        let far = OracleConfig { far_distance_m: 0.0, ..OracleConfig::realistic() };
        assert!(far.validate("d").unwrap_err().starts_with("d.far_distance_m:"));
        let erode = OracleConfig { mask_erode_px_max: 1000, ..OracleConfig::realistic() };
        assert!(erode.validate("d").unwrap_err().starts_with("d.mask_erode_px_max:"));
        let fp = OracleConfig { false_positives_per_frame: -1.0, ..OracleConfig::realistic() };
        assert!(fp.validate("d").unwrap_err().starts_with("d.false_positives_per_frame:"));
        let visible = OracleConfig { min_visible_px: 0, ..OracleConfig::realistic() };
        assert!(visible.validate("").unwrap_err().starts_with("min_visible_px:"));
    }

    #[test]
    fn presets_and_serde() {
        assert_eq!(OracleConfig::preset("clean"), Some(OracleConfig::clean()));
        assert_eq!(OracleConfig::preset("realistic"), Some(OracleConfig::realistic()));
        assert_eq!(OracleConfig::preset("noisy"), None);
        assert_eq!(OracleConfig::default(), OracleConfig::realistic());
        let parsed: OracleConfig = toml::from_str("part_miss_rate = 0.2\nseed = 7").unwrap();
        assert_eq!(parsed, OracleConfig { part_miss_rate: 0.2, seed: 7, ..OracleConfig::realistic() });
        assert!(toml::from_str::<OracleConfig>("part_mis_rate = 0.2").is_err());
        let text = toml::to_string(&OracleConfig::clean()).unwrap();
        assert_eq!(toml::from_str::<OracleConfig>(&text).unwrap(), OracleConfig::clean());
    }

    #[test]
    fn realistic_preset_runs_on_a_full_frame() {
        let (mut frame, instances) = kitchen();
        let mut detector = OracleDetector::new(OracleConfig::realistic(), instances, 1);
        let all = run(&mut detector, &mut frame, 20);
        let detections: usize = all.iter().map(Vec::len).sum();
        assert!(detections > 40, "{detections}");
        assert!(all.iter().flatten().all(|d| d.mask.area() > 0 && (0.05..=1.0).contains(&d.score)));
        assert_eq!(detection_rate(&all, 5), 0.0);
    }

    fn labels_of(detector: &mut OracleDetector, frame: &Frame) -> Vec<(u16, String)> {
        let mut out = Vec::new();
        detector.detect(frame, &mut out).unwrap();
        out.iter().filter_map(|d| Some((d.ground_truth_instance?, d.label.clone()))).collect()
    }

    #[test]
    fn prompt_lists_decide_which_parts_are_reported_and_how() {
        use crate::knowledge::KnowledgeBase;
        let kb = Arc::new(KnowledgeBase::builtin().unwrap());
        let (frame, instances) = kitchen();
        let with = |mode| {
            OracleDetector::new(no_noise(), instances.clone(), 0)
                .with_candidates(Arc::new(PartCandidates::new(kb.clone(), mode)))
        };
        let all = labels_of(&mut OracleDetector::new(no_noise(), instances.clone(), 0), &frame);
        let knowledge = labels_of(&mut with(CandidateMode::Knowledge), &frame);
        let generic = labels_of(&mut with(CandidateMode::Generic), &frame);
        let label = |list: &[(u16, String)], id: u16| list.iter().find(|(i, _)| *i == id).map(|(_, l)| l.clone());
        // Objects are always reported; with the knowledge list every part under its own name.
        assert_eq!(knowledge, all);
        assert_eq!(label(&knowledge, 2).as_deref(), Some("cabinet handle"));
        assert_eq!(label(&knowledge, 4).as_deref(), Some("stove knob"));
        // The generic vocabulary finds them under generic names.
        assert_eq!(label(&generic, 2).as_deref(), Some("handle"));
        assert_eq!(label(&generic, 4).as_deref(), Some("knob"));
        assert_eq!(label(&generic, 1).as_deref(), Some("cabinet"));
        // Without the stove in view its knob is not asked for (the knob alone is visible).
        let mut no_stove = frame.clone();
        for id in no_stove.instance_ids.as_mut().unwrap().iter_mut().filter(|id| **id == 3) {
            *id = 0;
        }
        let knowledge = labels_of(&mut with(CandidateMode::Knowledge), &no_stove);
        assert_eq!(label(&knowledge, 4), None);
        assert_eq!(label(&knowledge, 2).as_deref(), Some("cabinet handle"));
        // "all" changes nothing.
        assert_eq!(labels_of(&mut with(CandidateMode::All), &frame), all);
    }

    #[test]
    fn label_vectors_can_be_replaced() {
        let (frame, instances) = kitchen();
        let mut vectors = HashMap::new();
        let mut v = vec![0.0f32; 8];
        v[3] = 1.0;
        vectors.insert("cabinet".to_owned(), v.clone());
        let mut detector = OracleDetector::new(no_noise(), instances, 0).with_label_vectors(&vectors);
        let mut out = Vec::new();
        detector.detect(&frame, &mut out).unwrap();
        let cabinet = out.iter().find(|d| d.ground_truth_instance == Some(1)).unwrap();
        assert_eq!(cabinet.semantic_feature.as_deref(), Some(v.as_slice()));
        let stove = out.iter().find(|d| d.ground_truth_instance == Some(3)).unwrap();
        assert_eq!(stove.semantic_feature.as_ref().map(Vec::len), Some(SEMANTIC_DIM));
    }
}
