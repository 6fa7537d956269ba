//! The oracle detector: turns the synthetic renderer's per-pixel instance-id image into
//! detections with realistic, configurable noise (misses that grow for small and far instances,
//! synonym labels, eroded or dilated masks, false positives, noisy scores), so fusion, the graph
//! and evaluation run as if a real detector were in the loop.
//!
//! ## Ground truth
//!
//! The oracle reads ground truth only through the synthetic source's side channel, never from
//! the [`Frame`] (which carries what a camera would and nothing more): the instance ids of a
//! frame come from the [`InstanceIdChannel`] given with [`OracleDetector::with_instance_ids`],
//! and a frame the channel has no ids for (no channel, another source, a copy of a frame) is a
//! [`DetectorError::Frame`]. Which instance each detection came from is not part of the
//! [`Detection`] either: an [`InstanceLog`] given with [`OracleDetector::with_instance_log`]
//! holds, after each `detect`, the ground-truth instance of every output detection in order
//! (`None` for false positives), for evaluation.
//!
//! The noise of a frame is a pure function of `(config, frame)`: the random stream is seeded from
//! `hash(config.seed, frame.seq)`, so the output does not depend on which worker handles which
//! frame, and different frames (hence different workers) draw uncorrelated noise.
//!
//! ## Prompt lists
//!
//! With `part_prompts = "knowledge"` or `"generic"` the oracle behaves like an open-vocabulary
//! detector given a prompt list ([`op3dsg_runtime::perception::candidates`]): each frame's tags
//! are the canonical labels of the objects visible in it (an ideal image tagger), the list is
//! built from them, and a visible part is only reported when the list asks for it
//! ([`match_part`]), under its own label or the prompt's text (`nightstand knob`, or `handle`
//! with the generic vocabulary). Parts nothing asks for are missed. The random draws of a frame
//! do not depend on the list, so two modes differ only by what the list does. With `"all"` (the
//! default) every part is reported as before.
//!
//! ## Semantic features
//!
//! By default a detection's semantic feature is a fixed pseudo-random vector per canonical label
//! ([`label_vector`], `semantic_dim` long) plus noise. With `semantic_source = "text_encoder"`
//! it is the all-MiniLM-L6-v2 embedding of the canonical label (384 long, from the profile's
//! `[onnx]` and `[text_encoder]`, which must be enabled) plus the same noise: labels that mean
//! similar things then get similar features, as a real region embedding would.
//!
//! ## Files
//!
//! This file holds the detector; `config` its knobs and presets, `labels` the labels an
//! instance may be given, `masks` the pixel work on the id image, `noise` the random draws.

use std::sync::{Arc, Mutex, PoisonError};

use op3dsg_drivers::frame::Frame;
use op3dsg_ipc_types::NodeKind;
use op3dsg_runtime::knowledge::{ObjectId, PartId};
use op3dsg_runtime::perception::candidates::{CandidateMode, PartCandidates, PromptList, match_part};
use op3dsg_runtime::perception::{Detection, Detector, DetectorError};
use op3dsg_synthetic::{InstanceIdChannel, InstanceInfo};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

mod config;
mod draw;
mod field;
mod labels;
mod masks;
mod noise;
#[cfg(test)]
mod tests;

pub use config::{OracleConfig, SemanticSource};
pub use field::{BLEED_MIN_DEPTH_STEP_M, CONFUSION_MAX_NEIGHBOURS, CONFUSION_MIN_COSINE, ConfusionTable, PoseNoise};
pub use labels::possible_labels;
pub use noise::label_vector;

use labels::{find_word, node_kind};
use masks::{Stats, instance_mask};
use noise::{draw_poisson, draw_score, frame_seed};

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
    /// The labels a confusion may give it (set with a confusion table).
    confusions: Vec<String>,
}

/// Sentinel of `OracleDetector::index_of_id` for ids that are no instance.
const NO_INSTANCE: u32 = u32::MAX;

/// Provenance of an oracle's detections: after each [`Detector::detect`] of the
/// [`OracleDetector`] it was given to ([`OracleDetector::with_instance_log`]), the ground-truth
/// instance id of each output detection, in the order of the output (`None` for a false
/// positive). A failed `detect` leaves it empty. Cloning shares the log (the detector writes,
/// evaluation reads); the buffer is reused, so writing it does not allocate once it has grown to
/// the largest output.
#[derive(Clone, Debug, Default)]
pub struct InstanceLog(Arc<Mutex<Vec<Option<u16>>>>);

impl InstanceLog {
    /// An empty log.
    pub fn new() -> Self {
        Self::default()
    }

    /// A copy of the instance ids of the last `detect`'s detections.
    pub fn get(&self) -> Vec<Option<u16>> {
        self.with(<[Option<u16>]>::to_vec)
    }

    /// Runs `read` on the instance ids of the last `detect`'s detections, without copying them.
    pub fn with<R>(&self, read: impl FnOnce(&[Option<u16>]) -> R) -> R {
        read(&self.0.lock().unwrap_or_else(PoisonError::into_inner))
    }

    /// Replaces the contents with `ids`, reusing the buffer.
    fn set(&self, ids: &[Option<u16>]) {
        let mut log = self.0.lock().unwrap_or_else(PoisonError::into_inner);
        log.clear();
        log.extend_from_slice(ids);
    }
}

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
    /// Where the per-pixel instance ids of each frame come from (the synthetic source's side
    /// channel).
    instance_ids: Option<InstanceIdChannel>,
    /// Where the ground-truth instance of each detection goes.
    instance_log: Option<InstanceLog>,
    /// The ground-truth instance of each detection of the current frame (`None`: false
    /// positive), in output order; copied into `instance_log` (capacity grows once).
    provenance: Vec<Option<u16>>,
    /// Object names an image tagger may add by mistake (the knowledge base's; set with a
    /// prompt list).
    tag_vocabulary: Vec<String>,
    /// The current frame's extra (false) tags.
    extra_tags: Vec<String>,
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
                    confusions: Vec::new(),
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
            instance_ids: None,
            instance_log: None,
            provenance: Vec::new(),
            tag_vocabulary: Vec::new(),
            extra_tags: Vec::new(),
        }
    }

    /// Confuses labels with their neighbours in `table` at `confusion_rate` (see
    /// [`ConfusionTable`]): an object label becomes a neighbour of its label, a part label gets
    /// its part word (the label without the parent's) replaced by a neighbour of that word.
    pub fn with_confusions(mut self, table: &ConfusionTable) -> Self {
        for (index, info) in self.instances.iter().enumerate() {
            let prepared = &self.prepared[index];
            let confusions = match (prepared.kind, confusion_word(&self.instances, prepared, info)) {
                (NodeKind::Object, _) => table.neighbours(&info.label).iter().map(|(n, _)| n.clone()).collect(),
                (NodeKind::Part, Some((word, parent))) => table
                    .neighbours(&word)
                    .iter()
                    .map(|(n, _)| match &parent {
                        Some((parent, true)) => format!("{parent} {n}"),
                        Some((parent, false)) => format!("{n} {parent}"),
                        None => n.clone(),
                    })
                    .collect(),
                (NodeKind::Part, None) => Vec::new(),
            };
            self.prepared[index].confusions = confusions;
        }
        self
    }

    /// The labels a confusion may give instance `index` (for tests and reports).
    pub fn confusions_of(&self, index: usize) -> &[String] {
        &self.prepared[index].confusions
    }

    /// Reads the per-pixel instance ids of each frame from `channel`, the synthetic source's
    /// ground-truth side channel ([`op3dsg_synthetic::GroundTruth::instance_ids`]). Without it,
    /// or for a frame the channel has no ids for, `detect` fails.
    pub fn with_instance_ids(mut self, channel: InstanceIdChannel) -> Self {
        self.instance_ids = Some(channel);
        self
    }

    /// Records in `log`, after each `detect`, the ground-truth instance of each output detection
    /// (see [`InstanceLog`]).
    pub fn with_instance_log(mut self, log: InstanceLog) -> Self {
        self.instance_log = Some(log);
        self
    }

    /// Reports parts only when the frame's prompt list from `candidates` asks for them (see the
    /// module docs); a [`CandidateMode::All`] list changes nothing.
    pub fn with_candidates(mut self, candidates: Arc<PartCandidates>) -> Self {
        if candidates.mode() == CandidateMode::All {
            return self;
        }
        let kb = candidates.knowledge();
        self.tag_vocabulary = kb.objects().iter().map(|o| o.name.clone()).collect();
        for (index, info) in self.instances.iter().enumerate() {
            let prepared = &mut self.prepared[index];
            if prepared.kind != NodeKind::Part {
                continue;
            }
            prepared.part_category = kb.resolve(&info.label).and_then(|r| r.part());
            prepared.parent_category = prepared.parent.and_then(|p| kb.object_category(&self.instances[p].label));
            prepared.accepted_labels = possible_labels(&self.instances, info)
                .iter()
                .map(|l| op3dsg_runtime::knowledge::normalise(l))
                .collect();
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

    /// Builds the frame's prompt list from the objects visible in it, as the tagger reports
    /// them (`tag_miss_rate`, `tag_add_per_frame`, drawn from `field`).
    fn build_prompt_list(&mut self, field: &mut ChaCha8Rng) {
        let Some(candidates) = &self.candidates else { return };
        self.tag_scratch.clear();
        for (index, s) in self.stats.iter().enumerate() {
            if s.count >= self.config.min_visible_px && self.prepared[index].kind == NodeKind::Object {
                if self.config.tag_miss_rate > 0.0 && field.random_bool(self.config.tag_miss_rate) {
                    continue;
                }
                self.tag_scratch.push(index);
            }
        }
        self.extra_tags.clear();
        if self.config.tag_add_per_frame > 0.0 && !self.tag_vocabulary.is_empty() {
            for _ in 0..draw_poisson(self.config.tag_add_per_frame, field) {
                let pick = field.random_range(0..self.tag_vocabulary.len());
                self.extra_tags.push(self.tag_vocabulary[pick].clone());
            }
        }
        let mut tags: Vec<&str> = self.tag_scratch.iter().map(|&i| self.instances[i].label.as_str()).collect();
        tags.extend(self.extra_tags.iter().map(String::as_str));
        candidates.prompts(&tags, &mut self.prompt_list);
    }

    /// The current frame's tags as the tagger reported them (after `detect`; empty without a
    /// prompt list).
    pub fn last_tags(&self) -> Vec<String> {
        let mut tags: Vec<String> = self.tag_scratch.iter().map(|&i| self.instances[i].label.clone()).collect();
        tags.extend(self.extra_tags.iter().cloned());
        tags
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

    /// [`Detector::detect`] on `frame` with its instance ids `ids`: fills `out`, and
    /// `provenance` in step with it.
    fn detect_with_ids(&mut self, frame: &Frame, ids: &[u16], out: &mut Vec<Detection>) -> Result<(), DetectorError> {
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
        let mut field = ChaCha8Rng::seed_from_u64(frame_seed(self.config.seed ^ field::FIELD_STREAM, frame.seq));
        self.build_prompt_list(&mut field);
        let mut rng = ChaCha8Rng::seed_from_u64(frame_seed(self.config.seed, frame.seq));
        let first_true = out.len();

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
            let mut label = match self.asked_for(index) {
                None => continue,
                Some(None) => label,
                Some(Some(prompt)) => prompt.to_owned(),
            };
            // The field noise, from its own stream.
            let c = &self.config;
            let (confusion, kind_error, bleed, split) = (
                c.confusion_rate > 0.0 && field.random_bool(c.confusion_rate),
                c.kind_error_rate > 0.0 && field.random_bool(c.kind_error_rate),
                c.depth_bleed_rate > 0.0 && field.random_bool(c.depth_bleed_rate),
                c.split_rate > 0.0 && field.random_bool(c.split_rate),
            );
            let confusions = &self.prepared[index].confusions;
            if confusion && !confusions.is_empty() {
                label = confusions[field.random_range(0..confusions.len())].clone();
            }
            let mut kind = self.prepared[index].kind;
            if kind_error && kind == NodeKind::Part {
                kind = NodeKind::Object;
            }
            let mut mask = mask;
            if bleed {
                let radius = field.random_range(1..=self.config.depth_bleed_px.max(1));
                if let Some(median) = self.median_depth_m(frame, ids, id, s) {
                    let units = f64::from(frame.depth_units_per_m);
                    mask = field::bleed_mask(&mask, &frame.depth, width, height, units, median, radius);
                }
            }
            if split
                && self.prepared[index].kind == NodeKind::Object
                && let Some((a, b)) = field::split_mask(&mask)
            {
                let first = Detection {
                    label: label.clone(),
                    kind,
                    score,
                    mask: a,
                    semantic_feature: semantic_feature.clone(),
                };
                out.push(first);
                self.provenance.push(Some(id));
                mask = b;
            }
            out.push(Detection { label, kind, score, mask, semantic_feature });
            self.provenance.push(Some(id));
        }
        if self.config.merge_rate > 0.0 {
            self.merge_detections(out, first_true, &mut field);
        }

        if self.config.false_positives_per_frame > 0.0 {
            let count = draw_poisson(self.config.false_positives_per_frame, &mut rng);
            for _ in 0..count {
                if let Some(detection) = self.false_positive(width, height, &mut rng) {
                    out.push(detection);
                    self.provenance.push(None);
                }
            }
        }
        Ok(())
    }
}

/// The part word of a part's label and where its parent's label sits: `("knob", Some(("cabinet",
/// true)))` for `cabinet knob` (`true`: the parent comes first); `None` for an object.
fn confusion_word(
    instances: &[InstanceInfo],
    prepared: &Prepared,
    info: &InstanceInfo,
) -> Option<(String, Option<(String, bool)>)> {
    if prepared.kind != NodeKind::Part {
        return None;
    }
    match prepared.parent.zip(prepared.parent_label_at) {
        Some((p, at)) => {
            let parent = &instances[p].label;
            let (before, after) = (info.label[..at].trim(), info.label[at + parent.len()..].trim());
            match (before.is_empty(), after.is_empty()) {
                (true, false) => Some((after.to_owned(), Some((parent.clone(), true)))),
                (false, true) => Some((before.to_owned(), Some((parent.clone(), false)))),
                _ => Some((info.label.clone(), None)),
            }
        }
        None => Some((info.label.clone(), None)),
    }
}

/// The part words and object labels of `instances` a confusion table needs (`(word, is_part)`),
/// sorted and without duplicates.
pub fn confusion_words(instances: &[InstanceInfo]) -> Vec<(String, bool)> {
    let detector = OracleDetector::new(OracleConfig::clean(), instances.to_vec(), 0);
    let mut words: Vec<(String, bool)> = instances
        .iter()
        .zip(&detector.prepared)
        .map(|(info, prepared)| match confusion_word(instances, prepared, info) {
            Some((word, _)) => (word, true),
            None => (info.label.clone(), false),
        })
        .collect();
    words.sort();
    words.dedup();
    words
}

impl Detector for OracleDetector {
    fn detect(&mut self, frame: &Frame, out: &mut Vec<Detection>) -> Result<(), DetectorError> {
        out.clear();
        self.provenance.clear();
        // A handle of its own (an `Arc`), so the read below can borrow `self` mutably.
        let result = match self.instance_ids.clone() {
            None => Err(DetectorError::Frame {
                seq: frame.seq,
                reason: "frame has no instance ids: the oracle detector only works with the synthetic source \
                         (it was given no ground-truth channel)"
                    .into(),
            }),
            Some(channel) => {
                channel.with_ids(frame, |ids| self.detect_with_ids(frame, ids, out)).unwrap_or_else(|| {
                    Err(DetectorError::Frame {
                        seq: frame.seq,
                        reason: "frame has no instance ids: the oracle detector only works with the synthetic source \
                                 (the ground-truth channel holds none for this frame)"
                            .into(),
                    })
                })
            }
        };
        if result.is_err() {
            out.clear();
            self.provenance.clear();
        }
        if let Some(log) = &self.instance_log {
            log.set(&self.provenance);
        }
        result
    }

    fn name(&self) -> &str {
        "oracle"
    }
}
