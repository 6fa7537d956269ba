//! Node and affordance retrieval: which predicted nodes of its kind overlap each ground-truth
//! node ([`box_overlap`]) and how well their labels rank its label, then node R@K (IoU > 0,
//! IoU >= 0.10, IoP >= 0.25) and affordance R@K.

use std::collections::HashSet;

use glam::Vec3;
use op3dsg_drivers::graph_json::GraphJson;

use super::evaluator::{EmbeddingCache, Scoring};
use super::{
    AffordanceMiss, AffordanceResult, K10, KS, NodeResult, RecallReport, STRICT_IOP, STRICT_IOU, affordance_phrase,
};
use crate::eval::fusion_match::{label_alternatives, normalise_label};

/// One predicted node paired with a ground-truth node of its kind whose box it overlaps.
#[derive(Debug, Clone, Copy)]
pub(super) struct Overlap {
    /// Index of the predicted node.
    pub(super) pred: usize,
    /// Best rank of the ground-truth label (over its alternatives) by similarity to the
    /// predicted label.
    pub(super) rank: usize,
    /// Box IoU.
    pub(super) iou: f32,
    /// Intersection over the predicted box's volume.
    pub(super) iop: f32,
}

/// Intersection volume, IoU and IoP (intersection over `pred`'s volume) of two boxes.
///
/// The boxes are the nodes' axis-aligned `box_min_m`/`box_max_m`, also for predictions that
/// carry a gravity-aligned oriented box (`obb` in the graph JSON): the ground truth this
/// evaluator reads (the synthetic scenes, the benchmark's axis-aligned annotations) carries no
/// orientation, and an IoU between an oriented prediction and an axis-aligned ground-truth box
/// would score the orientation against a box that has none. Ground truth with `obb` would call
/// for an oriented IoU here; none is read today.
pub fn box_overlap(pred_min: Vec3, pred_max: Vec3, gt_min: Vec3, gt_max: Vec3) -> (f32, f32, f32) {
    let size = |min: Vec3, max: Vec3| (max - min).max(Vec3::ZERO);
    let inter = size(pred_min.max(gt_min), pred_max.min(gt_max));
    let inter_volume = inter.x * inter.y * inter.z;
    let pred_volume = {
        let s = size(pred_min, pred_max);
        s.x * s.y * s.z
    };
    let gt_volume = {
        let s = size(gt_min, gt_max);
        s.x * s.y * s.z
    };
    let union = pred_volume + gt_volume - inter_volume;
    let iou = if union > 0.0 { inter_volume / union } else { 0.0 };
    let iop = if pred_volume > 0.0 { inter_volume / pred_volume } else { 0.0 };
    (inter_volume, iou, iop)
}

/// Per ground-truth node (in `gt` order), the predicted nodes of its kind whose boxes overlap it,
/// with the rank of its label in `node_vocabulary` by similarity to theirs.
pub(super) fn overlaps(
    cache: &EmbeddingCache,
    pred: &GraphJson,
    gt: &GraphJson,
    node_vocabulary: &[String],
) -> Vec<Vec<Overlap>> {
    let pred_labels: Vec<String> = pred.nodes.iter().map(|n| normalise_label(&n.label)).collect();
    let mut overlaps: Vec<Vec<Overlap>> = Vec::with_capacity(gt.nodes.len());
    for g in &gt.nodes {
        let alternatives: Vec<String> = label_alternatives(&g.label).collect();
        let mut list = Vec::new();
        for (pi, p) in pred.nodes.iter().enumerate() {
            if p.kind != g.kind {
                continue;
            }
            let (inter, iou, iop) = box_overlap(
                Vec3::from(p.box_min_m),
                Vec3::from(p.box_max_m),
                Vec3::from(g.box_min_m),
                Vec3::from(g.box_max_m),
            );
            if inter <= 0.0 {
                continue;
            }
            let rank = alternatives
                .iter()
                .map(|a| cache.rank(node_vocabulary, &pred_labels[pi], a))
                .min()
                .unwrap_or(usize::MAX);
            list.push(Overlap { pred: pi, rank, iou, iop });
        }
        overlaps.push(list);
    }
    overlaps
}

/// Best rank of a ground-truth node over its `overlaps` that `accept` admits.
fn best_rank(overlaps: &[Overlap], accept: impl Fn(&Overlap) -> bool) -> Option<usize> {
    overlaps.iter().filter(|o| accept(o)).map(|o| o.rank).min()
}

/// Predicted nodes (indices) retrieving, at K = `k`, the ground-truth node with `overlaps`.
pub(super) fn retrievers(overlaps: &[Overlap], k: usize) -> HashSet<usize> {
    overlaps.iter().filter(|o| o.rank <= k).map(|o| o.pred).collect()
}

/// Node R@K of the scored ground-truth nodes (objects, parts, overall; plain and strict), their
/// per-node results, and the predicted nodes that retrieve nothing.
pub(super) fn score_nodes(scoring: &Scoring<'_>, report: &mut RecallReport) {
    let (pred, gt, overlaps) = (scoring.pred, scoring.gt, &scoring.overlaps);
    let f = &mut report.figures;
    f.predicted_nodes = pred.nodes.len();
    let mut pred_used = vec![false; pred.nodes.len()];
    for (gi, g) in gt.nodes.iter().enumerate() {
        if !scoring.is_scored(g.id) {
            continue;
        }
        let any = best_rank(&overlaps[gi], |_| true);
        let iou10 = best_rank(&overlaps[gi], |o| o.iou >= STRICT_IOU);
        let iop25 = best_rank(&overlaps[gi], |o| o.iop >= STRICT_IOP);
        let (node, strict_iou, strict_iop) = match g.kind.as_str() {
            "object" => (&mut f.object, &mut f.object_iou10, &mut f.object_iop25),
            "part" => (&mut f.part, &mut f.part_iou10, &mut f.part_iop25),
            _ => continue,
        };
        node.count(any);
        strict_iou.count(iou10);
        strict_iop.count(iop25);
        f.overall.count(any);
        f.overall_iou10.count(iou10);
        f.overall_iop25.count(iop25);
        for o in overlaps[gi].iter().filter(|o| o.rank <= KS[K10]) {
            pred_used[o.pred] = true;
        }
        let best_overlap = overlaps[gi].iter().min_by_key(|o| o.rank);
        report.nodes.push(NodeResult {
            id: g.id,
            kind: g.kind.clone(),
            label: g.label.clone(),
            best_rank: best_overlap.map(|o| o.rank),
            best_predicted_label: best_overlap.map(|o| pred.nodes[o.pred].label.clone()),
            best_iou: best_overlap.map(|o| o.iou),
        });
    }
    f.predicted_unmatched = pred_used.iter().filter(|u| !**u).count();
}

/// Affordance R@K of the scored ground-truth nodes, with why each missed affordance is missed.
pub(super) fn score_affordances(scoring: &Scoring<'_>, report: &mut RecallReport) {
    for (gi, g) in scoring.gt.nodes.iter().enumerate() {
        if !scoring.is_scored(g.id) {
            continue;
        }
        for a in &g.affordances {
            let target = affordance_phrase(a);
            let mut best_rank: Option<usize> = None;
            for o in &scoring.overlaps[gi] {
                for pa in &scoring.pred.nodes[o.pred].affordances {
                    let rank = scoring.cache.rank(&scoring.vocabulary.affordances, &affordance_phrase(pa), &target);
                    best_rank = Some(best_rank.map_or(rank, |b| b.min(rank)));
                }
            }
            report.figures.affordance.count(best_rank);
            let miss = std::array::from_fn(|k| match best_rank {
                Some(r) if r <= KS[k] => None,
                _ if scoring.overlaps[gi].is_empty() => Some(AffordanceMiss::NoNode),
                _ => Some(AffordanceMiss::WrongAffordance),
            });
            report.affordances.push(AffordanceResult { node: g.id, affordance: a.clone(), miss });
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_overlap_figures() {
        let (inter, iou, iop) = box_overlap(Vec3::ZERO, Vec3::splat(1.0), Vec3::splat(0.5), Vec3::splat(1.5));
        assert!((inter - 0.125).abs() < 1e-6);
        assert!((iou - 0.125 / 1.875).abs() < 1e-6);
        assert!((iop - 0.125).abs() < 1e-6);
        // Touching faces: no volume.
        let (inter, iou, iop) = box_overlap(Vec3::ZERO, Vec3::splat(1.0), Vec3::new(1.0, 0.0, 0.0), Vec3::splat(2.0));
        assert_eq!((inter, iou, iop), (0.0, 0.0, 0.0));
        // A flat predicted box has no volume.
        let (_, iou, iop) = box_overlap(Vec3::ZERO, Vec3::new(1.0, 1.0, 0.0), Vec3::ZERO, Vec3::splat(1.0));
        assert_eq!((iou, iop), (0.0, 0.0));
    }
}
