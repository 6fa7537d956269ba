//! What the oracle draws for each instance it sees: whether it is missed, its label, its mask's
//! morphology, its semantic feature, merged neighbours and false positives.

use op3dsg_drivers::frame::Frame;
use op3dsg_ipc_types::NodeKind;
use op3dsg_runtime::embedding::normalise;
use op3dsg_runtime::perception::{Detection, Mask};
use rand::Rng;
use rand_chacha::ChaCha8Rng;
use rand_distr::StandardNormal;

use super::masks::{Morph, Stats, tighten};
use super::noise::draw_score;
use super::{NO_INSTANCE, OracleDetector, field};

impl OracleDetector {
    /// One pass over the id image: per-instance pixel counts and boxes, unknown-id pixels.
    pub(super) fn gather_stats(&mut self, ids: &[u16], width: u32) {
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
    pub(super) fn median_depth_m(&mut self, frame: &Frame, ids: &[u16], id: u16, s: Stats) -> Option<f64> {
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
    pub(super) fn miss_probability(&mut self, frame: &Frame, ids: &[u16], index: usize, s: Stats) -> f64 {
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
    pub(super) fn label(&self, index: usize, rng: &mut ChaCha8Rng) -> String {
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
    pub(super) fn draw_morph(&self, rng: &mut ChaCha8Rng) -> Option<Morph> {
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
    pub(super) fn semantic_feature(&self, base: &[f32], rng: &mut ChaCha8Rng) -> Option<Vec<f32>> {
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

    /// Merges, at `merge_rate`, each true detection from `first` on with the next one of the
    /// same kind whose box touches it (within 2 px): the union mask, the larger one's label,
    /// feature and provenance.
    pub(super) fn merge_detections(&mut self, out: &mut Vec<Detection>, first: usize, field: &mut ChaCha8Rng) {
        let mut i = first;
        while i < out.len() {
            if !field.random_bool(self.config.merge_rate) {
                i += 1;
                continue;
            }
            let partner = (i + 1..out.len()).find(|&j| {
                out[j].kind == out[i].kind
                    && self.provenance[j] != self.provenance[i]
                    && field::boxes_touch(&out[i].mask, &out[j].mask, 2)
            });
            if let Some(j) = partner {
                let other = out.remove(j);
                let other_provenance = self.provenance.remove(j);
                let union = field::union_mask(&out[i].mask, &other.mask);
                let area = |m: &Mask| m.data.iter().filter(|v| **v != 0).count();
                if area(&other.mask) > area(&out[i].mask) {
                    out[i] = other;
                    self.provenance[i] = other_provenance;
                }
                out[i].mask = union;
            }
            i += 1;
        }
    }

    /// A false-positive blob: an ellipse at a random place, clipped to the image.
    pub(super) fn false_positive(&self, width: u32, height: u32, rng: &mut ChaCha8Rng) -> Option<Detection> {
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
        Some(Detection { label: label.clone(), kind: *kind, score, mask, semantic_feature })
    }
}
