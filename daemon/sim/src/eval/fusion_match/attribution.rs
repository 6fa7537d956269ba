//! Which stage lost a missed node: for an eligible ground-truth node no fused node matches, the
//! first of never detected, too few detections, merged into another, wrong label, lost in fusion
//! that explains it (the rules are in the [`fusion_match`](super) docs).

use glam::Vec3;
use op3dsg_runtime::graph::SceneGraph;

use super::matching::inside;
use super::{FusedOutcome, GtNode, MatchCriteria};

/// Why an eligible ground-truth node has no matching fused node (see the [`fusion_match`](super) docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum MissReason {
    /// The detector never reported it.
    NeverDetected,
    /// Reported in fewer keyframes than `min_observations`.
    TooFewDetections,
    /// A fused node that absorbed detections of others covers it and is not matched to it.
    Merged,
    /// A fused node lies on it with a label it does not accept.
    WrongLabel,
    /// Detected often enough, yet no fused node lies on it.
    LostInFusion,
}

impl MissReason {
    /// Short text for tables.
    pub fn as_str(self) -> &'static str {
        match self {
            MissReason::NeverDetected => "never detected",
            MissReason::TooFewDetections => "too few detections",
            MissReason::WrongLabel => "wrong label",
            MissReason::Merged => "merged into another",
            MissReason::LostInFusion => "lost in fusion",
        }
    }
}

/// Misses per reason.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct MissCounts {
    /// [`MissReason::NeverDetected`].
    pub never_detected: usize,
    /// [`MissReason::TooFewDetections`].
    pub too_few_detections: usize,
    /// [`MissReason::Merged`].
    pub merged: usize,
    /// [`MissReason::WrongLabel`].
    pub wrong_label: usize,
    /// [`MissReason::LostInFusion`].
    pub lost_in_fusion: usize,
}

impl MissCounts {
    /// Counts one more miss for `reason`.
    pub(super) fn add(&mut self, reason: MissReason) {
        match reason {
            MissReason::NeverDetected => self.never_detected += 1,
            MissReason::TooFewDetections => self.too_few_detections += 1,
            MissReason::WrongLabel => self.wrong_label += 1,
            MissReason::Merged => self.merged += 1,
            MissReason::LostInFusion => self.lost_in_fusion += 1,
        }
    }

    /// All misses.
    pub fn total(&self) -> usize {
        self.never_detected + self.too_few_detections + self.wrong_label + self.merged + self.lost_in_fusion
    }
}

/// Why the eligible, unmatched `gt_node`, detected in `detected_keyframes` keyframes, is missed:
/// the first stage that explains it. `fused_labels` and `fused` are the normalised labels and
/// outcomes of `graph`'s nodes, in graph order.
pub(super) fn attribute_miss(
    gt_node: &GtNode,
    detected_keyframes: u32,
    graph: &SceneGraph,
    fused_labels: &[String],
    fused: &[FusedOutcome],
    criteria: &MatchCriteria,
) -> MissReason {
    if detected_keyframes == 0 {
        MissReason::NeverDetected
    } else if detected_keyframes < criteria.min_observations {
        MissReason::TooFewDetections
    } else if swallowed(gt_node, graph, fused, criteria) {
        MissReason::Merged
    } else if labelled_wrongly(gt_node, graph, fused_labels, fused, criteria) {
        MissReason::WrongLabel
    } else {
        MissReason::LostInFusion
    }
}

/// Whether a fused node of `gt_node`'s kind covers it (whatever the node's label), is not
/// matched to it, and fused more detections than its own instance had (it absorbed others').
fn swallowed(gt_node: &GtNode, graph: &SceneGraph, fused: &[FusedOutcome], criteria: &MatchCriteria) -> bool {
    let margin = criteria.cover_margin(gt_node.kind);
    graph.nodes.iter().zip(fused).any(|(node, outcome)| {
        node.kind == gt_node.kind
            && outcome.absorbed
            && outcome.matched != Some(gt_node.id)
            && inside(gt_node.centre(), Vec3::from(node.box_min_m), Vec3::from(node.box_max_m), margin)
    })
}

/// Whether a fused node of `gt_node`'s kind that matches nothing has its centre on it (its box
/// grown by the centre margin) with a label it does not accept.
fn labelled_wrongly(
    gt_node: &GtNode,
    graph: &SceneGraph,
    fused_labels: &[String],
    fused: &[FusedOutcome],
    criteria: &MatchCriteria,
) -> bool {
    graph.nodes.iter().zip(fused_labels).zip(fused).any(|((node, label), outcome)| {
        outcome.matched.is_none()
            && node.kind == gt_node.kind
            && !gt_node.accepts(label)
            && inside(
                Vec3::from(node.centre_m),
                gt_node.box_min_m,
                gt_node.box_max_m,
                criteria.centre_margin(node.kind),
            )
    })
}
