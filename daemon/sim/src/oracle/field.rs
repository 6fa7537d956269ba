//! Perception as it is on a robot (the `field` preset's knobs): the confusion table between
//! similar categories ([`ConfusionTable`]), split / merged / depth-bleeding masks, and the pose
//! drift and jitter of a visual-inertial odometry ([`PoseNoise`]).
//!
//! These draws come from a random stream of their own per frame (`frame_seed(seed ^
//! FIELD_STREAM, seq)`), so turning a knob on leaves every other draw of the frame unchanged:
//! with all of them at 0 the oracle gives exactly the `realistic` preset's detections.

use std::collections::HashMap;

use glam::{DQuat, DVec3};
use op3dsg_drivers::pose::Isometry;
use op3dsg_runtime::knowledge::{Category, KnowledgeBase};
use op3dsg_runtime::perception::Mask;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::masks::tighten;

/// Xored into the seed of the field noise's stream.
pub(super) const FIELD_STREAM: u64 = 0x6669_656c_645f_6e7a;
/// Smallest cosine between a label's and a neighbour's embedding for the two to be confusable.
pub const CONFUSION_MIN_COSINE: f32 = 0.5;
/// At most this many confusable neighbours per label.
pub const CONFUSION_MAX_NEIGHBOURS: usize = 3;
/// A pixel is background for the depth bleed when it is at least this far behind the
/// instance's median depth (or has no depth), metres.
pub const BLEED_MIN_DEPTH_STEP_M: f64 = 0.15;

/// Embeds texts: one unit vector per text, in order.
pub type EmbedFn<'a> = dyn FnMut(&[&str]) -> Result<Vec<Vec<f32>>, String> + 'a;

/// Per label word, the labels a detector may confuse it with, nearest first (see
/// [`OracleConfig::confusion_rate`](super::OracleConfig::confusion_rate)).
///
/// Object labels are compared with the knowledge base's object category names, part words (a
/// part label without its parent's label: `knob` of `cabinet knob`) with its part category
/// names, by cosine of their text embeddings; a candidate is kept when its cosine is at least
/// [`CONFUSION_MIN_COSINE`], it is not the label's own category (by the knowledge base's
/// resolution, so the base's synonyms are not confusions), and it is among the
/// [`CONFUSION_MAX_NEIGHBOURS`] nearest. The ground truth's synonym lists play no part.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ConfusionTable {
    neighbours: HashMap<String, Vec<(String, f32)>>,
}

impl ConfusionTable {
    /// A table given directly (label word → neighbours with their cosines).
    pub fn from_neighbours(neighbours: HashMap<String, Vec<(String, f32)>>) -> Self {
        Self { neighbours }
    }

    /// Builds the table for `words` (`(word, is_part)`) with `embed` (unit vectors, one per text,
    /// in order) against `kb`'s category names.
    pub fn build(kb: &KnowledgeBase, words: &[(String, bool)], embed: &mut EmbedFn<'_>) -> Result<Self, String> {
        let objects: Vec<&str> = kb.objects().iter().map(|o| o.name.as_str()).collect();
        let parts: Vec<&str> = kb.parts().iter().map(|p| p.name.as_str()).collect();
        let object_vectors = embed(&objects)?;
        let part_vectors = embed(&parts)?;
        let texts: Vec<&str> = words.iter().map(|(w, _)| w.as_str()).collect();
        let word_vectors = embed(&texts)?;
        let mut neighbours = HashMap::new();
        for ((word, is_part), v) in words.iter().zip(&word_vectors) {
            let own = kb.resolve(word).map(|r| r.category);
            let (names, vectors) = if *is_part { (&parts, &part_vectors) } else { (&objects, &object_vectors) };
            let mut near: Vec<(String, f32)> = names
                .iter()
                .zip(vectors)
                .filter(|(name, _)| {
                    let category = kb.resolve(name).map(|r| r.category);
                    **name != word.as_str()
                        && (own.is_none() || category != own)
                        && category_kind_ok(category, *is_part)
                })
                .map(|(name, u)| ((*name).to_owned(), cosine(v, u)))
                .filter(|(_, c)| *c >= CONFUSION_MIN_COSINE)
                .collect();
            near.sort_by(|a, b| b.1.total_cmp(&a.1).then_with(|| a.0.cmp(&b.0)));
            near.truncate(CONFUSION_MAX_NEIGHBOURS);
            if !near.is_empty() {
                neighbours.insert(word.clone(), near);
            }
        }
        Ok(Self { neighbours })
    }

    /// The neighbours of `word`, nearest first (empty when none).
    pub fn neighbours(&self, word: &str) -> &[(String, f32)] {
        self.neighbours.get(word).map_or(&[], Vec::as_slice)
    }

    /// Label words with at least one neighbour, sorted, with their neighbours (for reports).
    pub fn entries(&self) -> Vec<(&str, &[(String, f32)])> {
        let mut out: Vec<_> = self.neighbours.iter().map(|(k, v)| (k.as_str(), v.as_slice())).collect();
        out.sort_by(|a, b| a.0.cmp(b.0));
        out
    }
}

fn category_kind_ok(category: Option<Category>, is_part: bool) -> bool {
    match category {
        Some(Category::Part(_)) => is_part,
        Some(Category::Object(_)) => !is_part,
        None => true,
    }
}

fn cosine(a: &[f32], b: &[f32]) -> f32 {
    let dot: f32 = a.iter().zip(b).map(|(x, y)| x * y).sum();
    let na: f32 = a.iter().map(|x| x * x).sum::<f32>().sqrt();
    let nb: f32 = b.iter().map(|x| x * x).sum::<f32>().sqrt();
    if na > 0.0 && nb > 0.0 { dot / (na * nb) } else { 0.0 }
}

/// `mask` cut in two across its longer side at its pixel median (`None` when one half would
/// be empty).
pub(super) fn split_mask(mask: &Mask) -> Option<(Mask, Mask)> {
    let (w, h) = (mask.width as usize, mask.height as usize);
    let along_x = w >= h;
    // The median coordinate of the inside pixels along the longer side.
    let mut coords: Vec<usize> = Vec::new();
    for y in 0..h {
        for x in 0..w {
            if mask.data[y * w + x] != 0 {
                coords.push(if along_x { x } else { y });
            }
        }
    }
    if coords.len() < 2 {
        return None;
    }
    let mid = coords.len() / 2;
    let (_, cut, _) = coords.select_nth_unstable(mid);
    let cut = *cut;
    let half = |first: bool| {
        let mut data = mask.data.clone();
        for y in 0..h {
            for x in 0..w {
                let c = if along_x { x } else { y };
                if (c < cut) != first {
                    data[y * w + x] = 0;
                }
            }
        }
        tighten(Mask { data, ..mask.clone() })
    };
    Some((half(true)?, half(false)?))
}

/// Whether the boxes of `a` and `b` overlap when grown by `margin` pixels.
pub(super) fn boxes_touch(a: &Mask, b: &Mask, margin: u32) -> bool {
    let (ax1, ay1) = (a.x0 + a.width + margin, a.y0 + a.height + margin);
    let (bx1, by1) = (b.x0 + b.width + margin, b.y0 + b.height + margin);
    a.x0 < bx1 && b.x0 < ax1 && a.y0 < by1 && b.y0 < ay1
}

/// The union of two masks.
pub(super) fn union_mask(a: &Mask, b: &Mask) -> Mask {
    let x0 = a.x0.min(b.x0);
    let y0 = a.y0.min(b.y0);
    let x1 = (a.x0 + a.width).max(b.x0 + b.width);
    let y1 = (a.y0 + a.height).max(b.y0 + b.height);
    let (w, h) = (x1 - x0, y1 - y0);
    let mut data = vec![0u8; (w * h) as usize];
    for m in [a, b] {
        for y in 0..m.height {
            for x in 0..m.width {
                if m.data[(y * m.width + x) as usize] != 0 {
                    data[((y + m.y0 - y0) * w + (x + m.x0 - x0)) as usize] = 1;
                }
            }
        }
    }
    Mask { x0, y0, width: w, height: h, data }
}

/// `mask` grown by `radius` pixels (square element) into pixels that are background at a depth
/// edge: depth 0 or at least [`BLEED_MIN_DEPTH_STEP_M`] behind `median_m` (`depth` in
/// `units_per_m`, `width` x `height`).
pub(super) fn bleed_mask(
    mask: &Mask,
    depth: &[u16],
    width: u32,
    height: u32,
    units_per_m: f64,
    median_m: f64,
    radius: u32,
) -> Mask {
    let x0 = mask.x0.saturating_sub(radius);
    let y0 = mask.y0.saturating_sub(radius);
    let x1 = (mask.x0 + mask.width - 1 + radius).min(width - 1);
    let y1 = (mask.y0 + mask.height - 1 + radius).min(height - 1);
    let (w, h) = (x1 - x0 + 1, y1 - y0 + 1);
    let inside = |x: u32, y: u32| {
        x >= mask.x0
            && y >= mask.y0
            && x < mask.x0 + mask.width
            && y < mask.y0 + mask.height
            && mask.data[((y - mask.y0) * mask.width + (x - mask.x0)) as usize] != 0
    };
    let far = median_m + BLEED_MIN_DEPTH_STEP_M;
    let mut data = vec![0u8; (w * h) as usize];
    let r = radius as i64;
    for y in y0..=y1 {
        for x in x0..=x1 {
            let value = if inside(x, y) {
                true
            } else {
                let d = depth[(y * width + x) as usize];
                let background = d == 0 || f64::from(d) / units_per_m >= far;
                background
                    && (-r..=r).any(|dy| {
                        (-r..=r).any(|dx| {
                            let (xx, yy) = (i64::from(x) + dx, i64::from(y) + dy);
                            xx >= 0 && yy >= 0 && inside(xx as u32, yy as u32)
                        })
                    })
            };
            data[((y - y0) * w + (x - x0)) as usize] = u8::from(value);
        }
    }
    Mask { x0, y0, width: w, height: h, data }
}

/// The pose noise of one batch run: a drift that walks with the distance travelled and a
/// per-keyframe jitter (see [`OracleConfig::pose_drift_fraction`](super::OracleConfig)).
/// Deterministic: the draws follow `seed` and the order of the keyframes.
#[derive(Debug, Clone)]
pub struct PoseNoise {
    drift_fraction: f64,
    drift_rad_per_m: f64,
    jitter_m: f64,
    jitter_rad: f64,
    rng: ChaCha8Rng,
    /// Where the last keyframe truly was, and the first one (the centre of the heading drift).
    last: Option<DVec3>,
    origin: DVec3,
    /// Direction the translation drift currently walks in (unit).
    direction: DVec3,
    /// +1 or -1: the heading drift's sign.
    heading_sign: f64,
    translation_error: DVec3,
    heading_error_rad: f64,
    travelled_m: f64,
}

impl PoseNoise {
    /// Pose noise of `config`, `None` when it has none.
    pub fn new(config: &super::OracleConfig) -> Option<Self> {
        if !config.has_pose_noise() {
            return None;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(super::noise::frame_seed(config.seed ^ FIELD_STREAM, u64::MAX));
        let direction = random_unit(&mut rng);
        let heading_sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
        Some(Self {
            drift_fraction: config.pose_drift_fraction,
            drift_rad_per_m: config.pose_drift_deg_per_m.to_radians(),
            jitter_m: config.pose_jitter_m,
            jitter_rad: config.pose_jitter_deg.to_radians(),
            rng,
            last: None,
            origin: DVec3::ZERO,
            direction,
            heading_sign,
            translation_error: DVec3::ZERO,
            heading_error_rad: 0.0,
            travelled_m: 0.0,
        })
    }

    /// The pose fusion is given for a keyframe truly at `truth` (keyframes in order).
    pub fn apply(&mut self, truth: &Isometry) -> Isometry {
        let position = truth.translation;
        match self.last {
            None => self.origin = position,
            Some(last) => {
                let step = (position - last).length();
                self.travelled_m += step;
                // The drift direction wanders by about 0.3 rad per metre.
                let wander = DVec3::new(self.normal(), self.normal(), self.normal()) * 0.3 * step.sqrt();
                self.direction = (self.direction + wander).try_normalize().unwrap_or(self.direction);
                self.translation_error += self.direction * self.drift_fraction * step;
                self.heading_error_rad += self.heading_sign * self.drift_rad_per_m * step;
            }
        }
        self.last = Some(position);
        let heading = DQuat::from_rotation_z(self.heading_error_rad);
        let mut rotation = heading * truth.rotation;
        let mut translation = heading * (position - self.origin) + self.origin + self.translation_error;
        if self.jitter_m > 0.0 {
            translation += DVec3::new(self.normal(), self.normal(), self.normal()) * self.jitter_m;
        }
        if self.jitter_rad > 0.0 {
            let axis = random_unit(&mut self.rng);
            let angle = self.normal() * self.jitter_rad;
            rotation = DQuat::from_axis_angle(axis, angle) * rotation;
        }
        Isometry { rotation: rotation.normalize(), translation }
    }

    /// Distance travelled so far, metres.
    pub fn travelled_m(&self) -> f64 {
        self.travelled_m
    }

    /// The drift's translation error so far (jitter excluded), metres.
    pub fn drift_m(&self) -> f64 {
        self.translation_error.length()
    }

    /// The drift's heading error so far, degrees (signed).
    pub fn heading_error_deg(&self) -> f64 {
        self.heading_error_rad.to_degrees()
    }

    fn normal(&mut self) -> f64 {
        self.rng.sample(StandardNormal)
    }
}

fn random_unit(rng: &mut ChaCha8Rng) -> DVec3 {
    loop {
        let v = DVec3::new(rng.sample(StandardNormal), rng.sample(StandardNormal), rng.sample(StandardNormal));
        if let Some(u) = v.try_normalize() {
            return u;
        }
    }
}
