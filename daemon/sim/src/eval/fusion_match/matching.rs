//! The matching itself: [`MatchCriteria`], and [`match_fusion`], which matches every fused node
//! to at most one ground-truth node, finds the ground-truth nodes it spans and whether it absorbed
//! detections of others, then scores every ground-truth node (eligible, matched, or why missed).

use glam::Vec3;
use op3dsg_ipc_types::NodeKind;
use op3dsg_runtime::graph::{GraphNode, SceneGraph};

use super::attribution::attribute_miss;
use super::{FusedOutcome, FusionMatchReport, GtNode, GtOutcome, KindReport, normalise_label};

/// Margins and thresholds of the matching (see the [`fusion_match`](super) docs for why these values).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MatchCriteria {
    /// A fused object matches when its centre is inside the ground-truth box grown by this,
    /// metres.
    pub object_centre_margin_m: f32,
    /// The same for parts, metres.
    pub part_centre_margin_m: f32,
    /// A fused object covers a ground-truth object whose box centre is inside the fused box
    /// grown by this, metres.
    pub object_cover_margin_m: f32,
    /// The same for parts, metres.
    pub part_cover_margin_m: f32,
    /// Ground-truth nodes visible in fewer keyframes are not scored.
    pub min_visible_keyframes: u32,
    /// The fusion's `min_observations`: fewer detections than this are attributed to it.
    pub min_observations: u32,
}

impl Default for MatchCriteria {
    fn default() -> Self {
        Self {
            object_centre_margin_m: 0.05,
            part_centre_margin_m: 0.02,
            object_cover_margin_m: 0.05,
            part_cover_margin_m: 0.01,
            min_visible_keyframes: 3,
            min_observations: 2,
        }
    }
}

impl MatchCriteria {
    /// [`object_centre_margin_m`](Self::object_centre_margin_m) or the part margin.
    pub(super) fn centre_margin(&self, kind: NodeKind) -> f32 {
        match kind {
            NodeKind::Object => self.object_centre_margin_m,
            NodeKind::Part => self.part_centre_margin_m,
        }
    }

    /// [`object_cover_margin_m`](Self::object_cover_margin_m) or the part margin.
    pub(super) fn cover_margin(&self, kind: NodeKind) -> f32 {
        match kind {
            NodeKind::Object => self.object_cover_margin_m,
            NodeKind::Part => self.part_cover_margin_m,
        }
    }
}

/// Whether `p` lies inside the box `min`..`max` grown by `margin`.
pub(super) fn inside(p: Vec3, min: Vec3, max: Vec3, margin: f32) -> bool {
    p.cmpge(min - Vec3::splat(margin)).all() && p.cmple(max + Vec3::splat(margin)).all()
}

/// Distance from `p` to the box (0 inside).
fn distance_to_box(p: Vec3, min: Vec3, max: Vec3) -> f32 {
    (min - p).max(p - max).max(Vec3::ZERO).length()
}

/// `counts[id]`, 0 when missing.
pub(super) fn count_at(counts: &[u32], id: u32) -> u32 {
    usize::try_from(id).ok().and_then(|i| counts.get(i)).copied().unwrap_or(0)
}

/// Matches `graph` against `gt`. `visible_keyframes[id]` and `detected_keyframes[id]` are the
/// batch runner's per-instance counts (indexed by ground-truth id; missing entries count 0).
pub fn match_fusion(
    graph: &SceneGraph,
    gt: &[GtNode],
    visible_keyframes: &[u32],
    detected_keyframes: &[u32],
    criteria: &MatchCriteria,
) -> FusionMatchReport {
    let mut report = FusionMatchReport {
        objects: KindReport::default(),
        parts: KindReport::default(),
        gt: Vec::with_capacity(gt.len()),
        fused: Vec::with_capacity(graph.nodes.len()),
    };

    // Fused → ground truth.
    let fused_labels: Vec<String> = graph.nodes.iter().map(|n| normalise_label(&n.label)).collect();
    for (node, label) in graph.nodes.iter().zip(&fused_labels) {
        let centre = Vec3::from(node.centre_m);
        let margin = criteria.centre_margin(node.kind);
        let mut best: Option<(f32, f32, usize)> = None;
        for (g, gt_node) in gt.iter().enumerate() {
            if gt_node.kind != node.kind
                || !gt_node.accepts(label)
                || !inside(centre, gt_node.box_min_m, gt_node.box_max_m, margin)
            {
                continue;
            }
            let key =
                (distance_to_box(centre, gt_node.box_min_m, gt_node.box_max_m), centre.distance(gt_node.centre()), g);
            if best.is_none_or(|b| (key.0, key.1) < (b.0, b.1)) {
                best = Some(key);
            }
        }
        let matched = best.map(|(_, _, g)| g);
        let spans = spanned(node, label, gt, matched, criteria);
        let absorbed = absorbed_others(node, gt, matched, detected_keyframes, criteria);
        report.fused.push(FusedOutcome {
            id: node.id,
            kind: node.kind,
            label: node.label.clone(),
            matched: matched.map(|g| gt[g].id),
            spans: spans.iter().map(|&g| gt[g].id).collect(),
            absorbed,
        });
        let visible = |g: usize| count_at(visible_keyframes, gt[g].id) >= criteria.min_visible_keyframes;
        let kind = report.kind_mut(node.kind);
        kind.fused_nodes += 1;
        match matched {
            Some(g) if visible(g) => kind.fused_matched_eligible += 1,
            Some(_) => kind.fused_matched_ineligible += 1,
            None => kind.false_positives += 1,
        }
        if spans.len() >= 2 && absorbed {
            kind.wrong_merge_nodes += 1;
            let first = gt[spans[0]].material.as_deref();
            if spans.iter().any(|&g| gt[g].material.as_deref() != first) {
                kind.wrong_merges_across_materials += 1;
            }
        }
    }

    // Ground truth → fused.
    for gt_node in gt {
        let visible = count_at(visible_keyframes, gt_node.id);
        let detected = count_at(detected_keyframes, gt_node.id);
        let eligible = visible >= criteria.min_visible_keyframes;
        let matched_by: Vec<u32> =
            report.fused.iter().filter(|f| f.matched == Some(gt_node.id)).map(|f| f.id).collect();
        let wrongly_merged = report.fused.iter().any(|f| f.is_wrong_merge() && f.spans.contains(&gt_node.id));
        let miss = (eligible && matched_by.is_empty())
            .then(|| attribute_miss(gt_node, detected, graph, &fused_labels, &report.fused, criteria));
        let kind = report.kind_mut(gt_node.kind);
        kind.gt_nodes += 1;
        kind.wrongly_merged_gt += usize::from(wrongly_merged);
        if eligible {
            kind.eligible += 1;
            kind.matched += usize::from(!matched_by.is_empty());
        }
        if let Some(reason) = miss {
            kind.misses.add(reason);
        }
        report.gt.push(GtOutcome {
            id: gt_node.id,
            kind: gt_node.kind,
            label: gt_node.label.clone(),
            visible_keyframes: visible,
            detected_keyframes: detected,
            eligible,
            matched_by,
            miss,
        });
    }
    report
}

/// Whether `node` fused clearly more detections (`observation_count`) than the keyframes its
/// instance was detected in: the ground-truth node it matches, or, unmatched, the most detected
/// ground-truth node of its kind it covers (whatever the label). "Clearly": by at least
/// `max(2, 10 %)`, so that a stray false positive does not count.
fn absorbed_others(
    node: &GraphNode,
    gt: &[GtNode],
    matched: Option<usize>,
    detected_keyframes: &[u32],
    criteria: &MatchCriteria,
) -> bool {
    let reference = match matched {
        Some(g) => Some(count_at(detected_keyframes, gt[g].id)),
        None => {
            let (lo, hi) = (Vec3::from(node.box_min_m), Vec3::from(node.box_max_m));
            let margin = criteria.cover_margin(node.kind);
            gt.iter()
                .filter(|g| g.kind == node.kind && inside(g.centre(), lo, hi, margin))
                .map(|g| count_at(detected_keyframes, g.id))
                .max()
        }
    };
    reference.is_some_and(|r| node.observation_count >= r + (r / 10).max(2))
}

/// Indices of the ground-truth nodes `node` covers or matches whose labels fit.
fn spanned(
    node: &GraphNode,
    label: &str,
    gt: &[GtNode],
    matched: Option<usize>,
    criteria: &MatchCriteria,
) -> Vec<usize> {
    let (lo, hi) = (Vec3::from(node.box_min_m), Vec3::from(node.box_max_m));
    let margin = criteria.cover_margin(node.kind);
    let mut spans: Vec<usize> = gt
        .iter()
        .enumerate()
        .filter(|(g, gt_node)| {
            gt_node.kind == node.kind
                && gt_node.accepts(label)
                && (Some(*g) == matched || inside(gt_node.centre(), lo, hi, margin))
        })
        .map(|(g, _)| g)
        .collect();
    if let Some(g) = matched
        && !spans.contains(&g)
    {
        spans.push(g);
    }
    spans
}
