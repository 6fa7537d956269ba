//! Matching fused nodes to ground-truth nodes, and what the match says about fusion.
//!
//! ## The criterion
//!
//! Nodes are compared within their kind (object with object, part with part), on their
//! axis-aligned world boxes and labels:
//!
//! - **Match.** A fused node matches a ground-truth node when its centre (the mean of its
//!   points, [`GraphNode::centre_m`](op3dsg_runtime::graph::GraphNode::centre_m)) lies inside the ground-truth box grown by a margin (5 cm for
//!   objects, 2 cm for parts, [`MatchCriteria`]) **and** its label is one the ground truth
//!   accepts (below). When several ground-truth nodes qualify, the one whose box is nearest to
//!   the centre wins (then the nearest box centre), so a fused node matches at most one.
//!
//!   Why not IoU: parts are 2–10 cm and a fused part box is built from the surface the camera
//!   saw, so it is often a few millimetres thick while the ground-truth box is the whole knob;
//!   their IoU swings with depth noise and mask dilation (2 px is 3–6 mm at 1–2 m), and a
//!   correct fragment of a large object has a small IoU too. The centre of the observed points
//!   is stable under both and lies on the instance's surface, i.e. inside its box; the margin
//!   absorbs noise, mask bleed and voxelisation, and stays below the 1–8 cm gaps between
//!   neighbouring parts so that the nearest-box rule decides between neighbours.
//! - **Cover.** A fused node covers a ground-truth node when the ground-truth box centre lies
//!   inside the fused box grown by a smaller margin (5 cm objects, 1 cm parts). A node that
//!   swallowed two neighbours spans both centres, but so may a correct node: fused boxes are
//!   unions of noisy points (mask dilation onto the surface around a knob, depth noise at 2 m)
//!   and a 3 cm knob's box is often 7–8 cm wide. So geometry alone does not convict.
//! - **Absorbed.** A fused node absorbed detections of others when its `observation_count`
//!   (detections fused into it) exceeds, by at least `max(2, 10 %)`, the number of keyframes in
//!   which the detector reported the instance it matches (or, when it matches none, the most
//!   detected instance it covers): the detector reports an instance at most once per keyframe,
//!   so a node made of one instance cannot have more. This needs the batch runner's per-instance
//!   detection counts, which the oracle's ground-truth ids make exact.
//! - **Labels.** A label is accepted when, lower-cased and trimmed, it equals the ground-truth
//!   label, one of its `a / b` alternatives, or a label the detector is known to use for it:
//!   the instance's synonyms and, for parts, the label with the parent's label replaced by a
//!   parent synonym (`cupboard handle`), exactly as
//!   [`possible_labels`](crate::oracle::possible_labels) lists them.
//!
//! ## The figures (per kind)
//!
//! - **Eligible**: ground-truth nodes visible in at least `min_visible_keyframes` (3) keyframes
//!   (see [`crate::batch::VisibilityThresholds`]); nodes seen less are not scored.
//! - **Matched fraction**: eligible nodes matched by at least one fused node / eligible nodes.
//! - **Fragmentation**: fused nodes matched to eligible nodes / matched eligible nodes (1 is
//!   ideal; 1.5 means every other instance is split in two).
//! - **False positives**: fused nodes that match no ground-truth node at all (wrong place or
//!   wrong label). Fused nodes matched to a non-eligible node are counted apart.
//! - **Wrong merges**: fused nodes that absorbed detections of others and cover, or match, two
//!   or more ground-truth nodes their label fits (two knobs in one node), and the ground-truth
//!   nodes they span; the ones whose spanned nodes differ in material are counted apart (what
//!   colour features should fix).
//! - **Misses**: each unmatched eligible node is attributed to the first stage that explains it:
//!   1. *never detected* — the detector never reported it;
//!   2. *too few detections* — reported in fewer keyframes than `fusion.min_observations`, so a
//!      correct node would still be held back;
//!   3. *merged* — a fused node of its kind that absorbed detections of others covers it
//!      (whatever the node's label) and is not matched to it (a sink swallowed by the cabinet
//!      under it, two drawers fused into one);
//!   4. *wrong label* — an unmatched fused node of its kind sits on it with a label it does not
//!      accept;
//!   5. *lost in fusion* — detected often enough, yet no fused node lies on it.
//!
//! ## The code
//!
//! | module | what |
//! |---|---|
//! | `labels` | label normalisation, `a / b` alternatives, the labels a ground-truth node accepts |
//! | `ground_truth` | [`GtNode`]: the ground-truth nodes of a synthetic scene or a ground-truth graph JSON |
//! | `matching` | [`MatchCriteria`] and [`match_fusion`]: fused → ground truth, covers, absorbed detections, wrong merges |
//! | `attribution` | [`MissReason`]: which stage lost each missed eligible node |
//! | `report` | [`QualityTargets`] and the text tables ([`table_header`], [`table_row`], [`details`]) |
//!
//! This module holds the report types and [`match_run`].

use op3dsg_ipc_types::NodeKind;

use crate::batch::BatchRun;

mod attribution;
mod ground_truth;
mod labels;
mod matching;
mod report;
#[cfg(test)]
mod tests;

pub use attribution::{MissCounts, MissReason};
pub use ground_truth::GtNode;
pub use labels::{label_alternatives, normalise_label};
pub use matching::{MatchCriteria, match_fusion};
pub use report::{QualityTargets, TABLE_LEGEND, details, table_header, table_row};

/// The figures of one node kind.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct KindReport {
    /// Ground-truth nodes of this kind.
    pub gt_nodes: usize,
    /// Of those, visible in enough keyframes to be scored.
    pub eligible: usize,
    /// Eligible nodes matched by at least one fused node.
    pub matched: usize,
    /// Fused nodes of this kind.
    pub fused_nodes: usize,
    /// Fused nodes matched to an eligible ground-truth node.
    pub fused_matched_eligible: usize,
    /// Fused nodes matched to a ground-truth node that is not eligible.
    pub fused_matched_ineligible: usize,
    /// Fused nodes matching no ground-truth node.
    pub false_positives: usize,
    /// Fused nodes that absorbed detections of others and span two or more ground-truth nodes
    /// their label fits.
    pub wrong_merge_nodes: usize,
    /// Of those, the ones whose ground-truth nodes are of different materials.
    pub wrong_merges_across_materials: usize,
    /// Distinct ground-truth nodes involved in wrong merges.
    pub wrongly_merged_gt: usize,
    /// Unmatched eligible nodes by reason.
    pub misses: MissCounts,
}

impl KindReport {
    /// `matched / eligible`; `None` without eligible nodes.
    pub fn matched_fraction(&self) -> Option<f64> {
        (self.eligible > 0).then(|| self.matched as f64 / self.eligible as f64)
    }

    /// `fused_matched_eligible / matched`; `None` when nothing matched.
    pub fn fragmentation(&self) -> Option<f64> {
        (self.matched > 0).then(|| self.fused_matched_eligible as f64 / self.matched as f64)
    }
}

/// What became of one ground-truth node.
#[derive(Debug, Clone, PartialEq)]
pub struct GtOutcome {
    /// Ground-truth id.
    pub id: u32,
    /// Object or part.
    pub kind: NodeKind,
    /// Ground-truth label.
    pub label: String,
    /// Keyframes it was visible in.
    pub visible_keyframes: u32,
    /// Keyframes it was detected in.
    pub detected_keyframes: u32,
    /// Scored at all.
    pub eligible: bool,
    /// Ids of the fused nodes matched to it.
    pub matched_by: Vec<u32>,
    /// Why it is missed (eligible, unmatched nodes only).
    pub miss: Option<MissReason>,
}

/// What one fused node was matched to.
#[derive(Debug, Clone, PartialEq)]
pub struct FusedOutcome {
    /// Fused node id.
    pub id: u32,
    /// Object or part.
    pub kind: NodeKind,
    /// Its voted label.
    pub label: String,
    /// The ground-truth node it matches.
    pub matched: Option<u32>,
    /// Ground-truth nodes it covers or matches whose labels fit.
    pub spans: Vec<u32>,
    /// It fused clearly more detections than its instance had: it absorbed detections of
    /// others (see the module docs).
    pub absorbed: bool,
}

impl FusedOutcome {
    /// Spans two or more ground-truth nodes and absorbed detections of others.
    pub fn is_wrong_merge(&self) -> bool {
        self.absorbed && self.spans.len() >= 2
    }
}

/// The result of [`match_fusion`].
#[derive(Debug, Clone, PartialEq)]
pub struct FusionMatchReport {
    /// Object figures.
    pub objects: KindReport,
    /// Part figures.
    pub parts: KindReport,
    /// Per ground-truth node, in ground-truth order.
    pub gt: Vec<GtOutcome>,
    /// Per fused node, in graph order.
    pub fused: Vec<FusedOutcome>,
}

impl FusionMatchReport {
    /// The figures of `kind`.
    pub fn kind(&self, kind: NodeKind) -> &KindReport {
        match kind {
            NodeKind::Object => &self.objects,
            NodeKind::Part => &self.parts,
        }
    }

    fn kind_mut(&mut self, kind: NodeKind) -> &mut KindReport {
        match kind {
            NodeKind::Object => &mut self.objects,
            NodeKind::Part => &mut self.parts,
        }
    }
}

/// Matches a batch run's final graph against its scene's ground truth with its own visibility
/// and detection counts (an empty ground truth when the source has none).
pub fn match_run(run: &BatchRun, criteria: &MatchCriteria) -> FusionMatchReport {
    let gt = run.scene.as_ref().map(GtNode::from_scene).unwrap_or_default();
    match_fusion(&run.graph, &gt, &run.visible_keyframes, &run.detected_keyframes, criteria)
}
