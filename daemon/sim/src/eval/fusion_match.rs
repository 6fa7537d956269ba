//! Matching fused nodes to ground-truth nodes, and what the match says about fusion.
//!
//! ## The criterion
//!
//! Nodes are compared within their kind (object with object, part with part), on their
//! axis-aligned world boxes and labels:
//!
//! - **Match.** A fused node matches a ground-truth node when its centre (the mean of its
//!   points, [`GraphNode::centre_m`]) lies inside the ground-truth box grown by a margin (5 cm for
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

use std::fmt::Write as _;

use glam::Vec3;
use op3dsg_drivers::graph_json::GraphJson;
use op3dsg_ipc_types::NodeKind;
use op3dsg_synthetic::{InstanceKind, Scene};

use crate::batch::BatchRun;
use crate::oracle::possible_labels;
use op3dsg_runtime::graph::{GraphNode, SceneGraph};

/// One ground-truth node as the matcher sees it.
#[derive(Debug, Clone, PartialEq)]
pub struct GtNode {
    /// Ground-truth id (the synthetic instance id).
    pub id: u32,
    /// Object or part.
    pub kind: NodeKind,
    /// The canonical label as written in the ground truth (may be `a / b`).
    pub label: String,
    /// Every label accepted for it, normalised (lower case, trimmed).
    pub accepted_labels: Vec<String>,
    /// Axis-aligned world box, metres.
    pub box_min_m: Vec3,
    /// Axis-aligned world box, metres.
    pub box_max_m: Vec3,
    /// Material name, when known (synthetic scenes).
    pub material: Option<String>,
}

/// Lower case, trimmed, inner whitespace collapsed.
pub fn normalise_label(label: &str) -> String {
    label.split_whitespace().collect::<Vec<_>>().join(" ").to_lowercase()
}

/// The alternatives of a ground-truth label written `a / b`, normalised.
pub fn label_alternatives(label: &str) -> impl Iterator<Item = String> + '_ {
    label.split('/').map(normalise_label).filter(|l| !l.is_empty())
}

fn push_unique(into: &mut Vec<String>, label: String) {
    if !into.contains(&label) {
        into.push(label);
    }
}

impl GtNode {
    /// Every instance of a synthetic scene, with the labels the oracle detector may use.
    pub fn from_scene(scene: &Scene) -> Vec<GtNode> {
        let instances = scene.instances();
        instances
            .iter()
            .map(|info| {
                let mut accepted_labels = Vec::new();
                for label in possible_labels(instances, info) {
                    for alternative in label_alternatives(&label) {
                        push_unique(&mut accepted_labels, alternative);
                    }
                }
                GtNode {
                    id: u32::from(info.id),
                    kind: match info.kind {
                        InstanceKind::Object => NodeKind::Object,
                        InstanceKind::Part => NodeKind::Part,
                    },
                    label: info.label.clone(),
                    accepted_labels,
                    box_min_m: info.box_min_m,
                    box_max_m: info.box_max_m,
                    material: Some(info.material.clone()),
                }
            })
            .collect()
    }

    /// The nodes of a ground-truth graph JSON (labels: the label and its `a / b` alternatives;
    /// nodes of another kind than `object` / `part` are skipped).
    pub fn from_graph_json(gt: &GraphJson) -> Vec<GtNode> {
        gt.nodes
            .iter()
            .filter_map(|node| {
                let kind = match node.kind.as_str() {
                    "object" => NodeKind::Object,
                    "part" => NodeKind::Part,
                    _ => return None,
                };
                let mut accepted_labels = Vec::new();
                for alternative in label_alternatives(&node.label) {
                    push_unique(&mut accepted_labels, alternative);
                }
                Some(GtNode {
                    id: node.id,
                    kind,
                    label: node.label.clone(),
                    accepted_labels,
                    box_min_m: Vec3::from(node.box_min_m),
                    box_max_m: Vec3::from(node.box_max_m),
                    material: None,
                })
            })
            .collect()
    }

    fn accepts(&self, normalised_label: &str) -> bool {
        self.accepted_labels.iter().any(|l| l == normalised_label)
    }

    fn centre(&self) -> Vec3 {
        (self.box_min_m + self.box_max_m) * 0.5
    }
}

/// Margins and thresholds of the matching (see the module docs for why these values).
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
    fn centre_margin(&self, kind: NodeKind) -> f32 {
        match kind {
            NodeKind::Object => self.object_centre_margin_m,
            NodeKind::Part => self.part_centre_margin_m,
        }
    }

    fn cover_margin(&self, kind: NodeKind) -> f32 {
        match kind {
            NodeKind::Object => self.object_cover_margin_m,
            NodeKind::Part => self.part_cover_margin_m,
        }
    }
}

/// Why an eligible ground-truth node has no matching fused node (see the module docs).
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
    fn add(&mut self, reason: MissReason) {
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

fn inside(p: Vec3, min: Vec3, max: Vec3, margin: f32) -> bool {
    p.cmpge(min - Vec3::splat(margin)).all() && p.cmple(max + Vec3::splat(margin)).all()
}

fn distance_to_box(p: Vec3, min: Vec3, max: Vec3) -> f32 {
    (min - p).max(p - max).max(Vec3::ZERO).length()
}

fn count_at(counts: &[u32], id: u32) -> u32 {
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
        let miss = (eligible && matched_by.is_empty()).then(|| {
            if detected == 0 {
                MissReason::NeverDetected
            } else if detected < criteria.min_observations {
                MissReason::TooFewDetections
            } else if swallowed(gt_node, graph, &report.fused, criteria) {
                MissReason::Merged
            } else if graph.nodes.iter().zip(&fused_labels).zip(&report.fused).any(|((node, label), outcome)| {
                outcome.matched.is_none()
                    && node.kind == gt_node.kind
                    && !gt_node.accepts(label)
                    && inside(
                        Vec3::from(node.centre_m),
                        gt_node.box_min_m,
                        gt_node.box_max_m,
                        criteria.centre_margin(node.kind),
                    )
            }) {
                MissReason::WrongLabel
            } else {
                MissReason::LostInFusion
            }
        });
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

/// Matches a batch run's final graph against its scene's ground truth with its own visibility
/// and detection counts (an empty ground truth when the source has none).
pub fn match_run(run: &BatchRun, criteria: &MatchCriteria) -> FusionMatchReport {
    let gt = run.scene.as_ref().map(GtNode::from_scene).unwrap_or_default();
    match_fusion(&run.graph, &gt, &run.visible_keyframes, &run.detected_keyframes, criteria)
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

/// Pass marks for a room (`daemon/tests/fusion_quality.rs`); a fusion must meet all of them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct QualityTargets {
    /// Least matched fraction of eligible objects.
    pub object_matched_min: f64,
    /// Least matched fraction of eligible parts.
    pub part_matched_min: f64,
    /// Largest object fragmentation.
    pub object_fragmentation_max: f64,
    /// Largest part fragmentation.
    pub part_fragmentation_max: f64,
}

impl Default for QualityTargets {
    fn default() -> Self {
        Self {
            object_matched_min: 0.90,
            part_matched_min: 0.80,
            object_fragmentation_max: 1.15,
            part_fragmentation_max: 1.25,
        }
    }
}

impl QualityTargets {
    /// The targets `report` misses, as text (empty when it meets them all).
    pub fn failures(&self, report: &FusionMatchReport) -> Vec<String> {
        let mut failures = Vec::new();
        for (name, kind, matched_min, fragmentation_max) in [
            ("objects", &report.objects, self.object_matched_min, self.object_fragmentation_max),
            ("parts", &report.parts, self.part_matched_min, self.part_fragmentation_max),
        ] {
            match kind.matched_fraction() {
                Some(f) if f >= matched_min => {}
                Some(f) => failures.push(format!("{name}: matched {:.2} % < {:.0} %", f * 100.0, matched_min * 100.0)),
                None => failures.push(format!("{name}: no eligible ground-truth node")),
            }
            if let Some(f) = kind.fragmentation()
                && f > fragmentation_max
            {
                failures.push(format!("{name}: fragmentation {f:.3} > {fragmentation_max:.2}"));
            }
        }
        failures
    }
}

fn percent(value: Option<f64>) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{:.1}", v * 100.0))
}

fn ratio(value: Option<f64>) -> String {
    value.map_or_else(|| "-".to_owned(), |v| format!("{v:.2}"))
}

/// Header of the per-room table ([`table_row`] gives its rows); ends with a newline.
pub fn table_header() -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<20} {:>4} | {:>4} {:>6} {:>5} {:>3} {:>3} | {:>4} {:>6} {:>5} {:>3} {:>3} {:>3} | {:>14} | {:>14}",
        "room",
        "kf",
        "obj",
        "match%",
        "frag",
        "fp",
        "wm",
        "part",
        "match%",
        "frag",
        "fp",
        "wm",
        "wmc",
        "obj miss",
        "part miss"
    );
    s
}

/// One row of the per-room table: keyframes, then for objects and parts the eligible count,
/// matched %, fragmentation, false positives, wrong-merge nodes (parts: and those across
/// materials), then the misses of each kind as never/few/merged/label/lost. Ends with a
/// newline.
pub fn table_row(name: &str, keyframes: u64, report: &FusionMatchReport) -> String {
    let misses = |m: &MissCounts| {
        format!("{}/{}/{}/{}/{}", m.never_detected, m.too_few_detections, m.merged, m.wrong_label, m.lost_in_fusion)
    };
    let (o, p) = (&report.objects, &report.parts);
    let mut s = String::new();
    let _ = writeln!(
        s,
        "{:<20} {:>4} | {:>4} {:>6} {:>5} {:>3} {:>3} | {:>4} {:>6} {:>5} {:>3} {:>3} {:>3} | {:>14} | {:>14}",
        name,
        keyframes,
        o.eligible,
        percent(o.matched_fraction()),
        ratio(o.fragmentation()),
        o.false_positives,
        o.wrong_merge_nodes,
        p.eligible,
        percent(p.matched_fraction()),
        ratio(p.fragmentation()),
        p.false_positives,
        p.wrong_merge_nodes,
        p.wrong_merges_across_materials,
        misses(&o.misses),
        misses(&p.misses),
    );
    s
}

/// What the table's short column names mean.
pub const TABLE_LEGEND: &str = "kf keyframes; obj/part eligible ground-truth nodes (visible in >= 3 keyframes); match% \
     eligible nodes matched; frag fused nodes per matched node; fp fused nodes matching nothing; wm wrong-merge nodes; \
     wmc of those across materials; miss never-detected/too-few-detections/merged/wrong-label/lost-in-fusion";

/// One line per missed eligible node, split node, wrong merge and false positive, for tuning.
pub fn details(report: &FusionMatchReport) -> String {
    let mut s = String::new();
    for g in report.gt.iter().filter(|g| g.miss.is_some()) {
        let _ = writeln!(
            s,
            "  miss  {:<6} {:>4} {:<22} visible {:>3} detected {:>3}: {}",
            g.kind.as_str(),
            g.id,
            g.label,
            g.visible_keyframes,
            g.detected_keyframes,
            g.miss.map_or("", MissReason::as_str)
        );
    }
    for g in report.gt.iter().filter(|g| g.matched_by.len() >= 2) {
        let _ = writeln!(
            s,
            "  split {:<6} {:>4} {:<22} into fused nodes {:?}",
            g.kind.as_str(),
            g.id,
            g.label,
            g.matched_by
        );
    }
    for f in report.fused.iter().filter(|f| f.is_wrong_merge()) {
        let _ = writeln!(
            s,
            "  merge {:<6} node {:>4} {:<22} spans ground truth {:?}",
            f.kind.as_str(),
            f.id,
            f.label,
            f.spans
        );
    }
    for f in report.fused.iter().filter(|f| f.matched.is_none()) {
        let _ = writeln!(s, "  fp    {:<6} node {:>4} {}", f.kind.as_str(), f.id, f.label);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gt(id: u32, kind: NodeKind, label: &str, lo: [f32; 3], hi: [f32; 3], material: &str) -> GtNode {
        GtNode {
            id,
            kind,
            label: label.into(),
            accepted_labels: label_alternatives(label).collect(),
            box_min_m: Vec3::from(lo),
            box_max_m: Vec3::from(hi),
            material: Some(material.into()),
        }
    }

    fn fused(id: u32, kind: NodeKind, label: &str, lo: [f32; 3], hi: [f32; 3]) -> GraphNode {
        GraphNode {
            id,
            kind,
            parent_id: None,
            label: label.into(),
            confidence: 1.0,
            centre_m: ((Vec3::from(lo) + Vec3::from(hi)) * 0.5).to_array(),
            box_min_m: lo,
            box_max_m: hi,
            observation_count: 3,
            affordance_bits: 0,
            last_seen_stamp_ns: 0,
        }
    }

    /// Three knobs 4.5 cm apart on a panel, a cabinet and a drawer.
    fn scene() -> Vec<GtNode> {
        let knob = |id, x: f32, material| {
            gt(id, NodeKind::Part, "knob", [x - 0.015, 0.0, 1.0], [x + 0.015, 0.025, 1.03], material)
        };
        let mut nodes = vec![
            gt(1, NodeKind::Object, "cabinet / cupboard", [0.0, 0.0, 0.0], [0.6, 0.6, 0.9], "wood"),
            gt(2, NodeKind::Object, "drawer", [0.6, 0.0, 0.0], [1.0, 0.6, 0.3], "wood"),
        ];
        nodes.push(knob(3, 2.0, "red plastic"));
        nodes.push(knob(4, 2.045, "blue plastic"));
        nodes.push(knob(5, 2.09, "red plastic"));
        nodes
    }

    #[test]
    fn perfect_fusion_scores_one() {
        let gt = scene();
        let graph = SceneGraph {
            nodes: vec![
                fused(10, NodeKind::Object, "cupboard", [0.02, 0.0, 0.02], [0.58, 0.6, 0.88]),
                fused(11, NodeKind::Object, "drawer", [0.62, 0.4, 0.0], [0.98, 0.6, 0.28]),
                fused(12, NodeKind::Part, "knob", [1.987, 0.018, 1.002], [2.013, 0.026, 1.028]),
                fused(13, NodeKind::Part, "knob", [2.032, 0.018, 1.002], [2.058, 0.026, 1.028]),
                fused(14, NodeKind::Part, "knob", [2.077, 0.018, 1.002], [2.103, 0.026, 1.028]),
            ],
            ..SceneGraph::default()
        };
        let visible = vec![0, 5, 5, 5, 5, 5];
        let r = match_fusion(&graph, &gt, &visible, &visible, &MatchCriteria::default());
        for kind in [&r.objects, &r.parts] {
            assert_eq!(kind.matched_fraction(), Some(1.0), "{r:#?}");
            assert_eq!(kind.fragmentation(), Some(1.0));
            assert_eq!((kind.false_positives, kind.wrong_merge_nodes, kind.misses.total()), (0, 0, 0));
        }
        assert_eq!(r.fused.iter().map(|f| f.matched).collect::<Vec<_>>(), [1, 2, 3, 4, 5].map(Some));
        assert!(QualityTargets::default().failures(&r).is_empty());
    }

    #[test]
    fn fragments_merges_false_positives_and_misses_are_told_apart() {
        let gt = scene();
        let graph = SceneGraph {
            nodes: vec![
                // The cabinet in two halves: fragmentation 2.
                fused(10, NodeKind::Object, "cabinet", [0.0, 0.0, 0.0], [0.3, 0.6, 0.9]),
                fused(11, NodeKind::Object, "cabinet", [0.3, 0.0, 0.0], [0.6, 0.6, 0.9]),
                // The drawer labelled as a stove: a false positive, and the drawer a wrong-label miss.
                fused(12, NodeKind::Object, "stove", [0.62, 0.4, 0.0], [0.98, 0.6, 0.28]),
                // Knobs 3 and 4 in one node, with both their detections (red and blue: across
                // materials); knob 5 alone.
                GraphNode {
                    observation_count: 18,
                    ..fused(13, NodeKind::Part, "knob", [1.985, 0.018, 1.0], [2.055, 0.026, 1.03])
                },
                fused(14, NodeKind::Part, "knob", [2.077, 0.018, 1.002], [2.103, 0.026, 1.028]),
                // A knob floating in the air.
                fused(15, NodeKind::Part, "knob", [3.0, 3.0, 1.0], [3.02, 3.02, 1.02]),
            ],
            ..SceneGraph::default()
        };
        let visible = vec![0, 9, 9, 9, 9, 9];
        let detected = vec![0, 9, 9, 9, 9, 9];
        let r = match_fusion(&graph, &gt, &visible, &detected, &MatchCriteria::default());
        assert_eq!(r.objects.eligible, 2);
        assert_eq!(r.objects.matched, 1);
        assert_eq!(r.objects.fragmentation(), Some(2.0));
        assert_eq!(r.objects.false_positives, 1);
        assert_eq!(r.objects.misses.wrong_label, 1);
        assert_eq!(r.parts.matched, 2);
        assert_eq!(r.parts.matched_fraction(), Some(2.0 / 3.0));
        assert_eq!(r.parts.false_positives, 1);
        assert_eq!(r.parts.wrong_merge_nodes, 1);
        assert_eq!(r.parts.wrong_merges_across_materials, 1);
        assert_eq!(r.parts.wrongly_merged_gt, 2);
        assert_eq!(r.parts.misses.merged, 1);
        let merged = r.fused.iter().find(|f| f.id == 13).unwrap();
        assert_eq!(merged.spans.len(), 2);
        let failures = QualityTargets::default().failures(&r);
        assert_eq!(failures.len(), 3, "{failures:?}");
        let table = table_header() + &table_row("test", 7, &r);
        assert!(table.contains("66.7"), "{table}");
        assert!(details(&r).contains("wrong label"));
    }

    /// A correct node whose box is bloated over its neighbour's centre (mask bleed, noise) is
    /// no wrong merge: it fused no more detections than its instance had.
    #[test]
    fn a_bloated_box_alone_is_no_wrong_merge() {
        let gt = scene();
        let graph = SceneGraph {
            nodes: vec![
                GraphNode {
                    centre_m: [2.0, 0.02, 1.015],
                    observation_count: 9,
                    ..fused(13, NodeKind::Part, "knob", [1.96, 0.0, 0.99], [2.04, 0.04, 1.04])
                },
                fused(14, NodeKind::Part, "knob", [2.032, 0.018, 1.002], [2.058, 0.026, 1.028]),
            ],
            ..SceneGraph::default()
        };
        let counts = vec![0, 0, 0, 9, 9, 9];
        let r = match_fusion(&graph, &gt, &counts, &counts, &MatchCriteria::default());
        assert_eq!(r.fused[0].spans.len(), 2, "the bloated box spans the neighbour's centre");
        assert_eq!((r.parts.wrong_merge_nodes, r.parts.wrongly_merged_gt), (0, 0));
        assert_eq!(r.parts.matched, 2);
        // Knob 5 is lost, not merged: nothing absorbed it.
        assert_eq!(r.parts.misses, MissCounts { lost_in_fusion: 1, ..Default::default() });
    }

    #[test]
    fn misses_are_attributed_to_detection_before_fusion() {
        let gt = scene();
        let graph = SceneGraph::default();
        // Id 1 never detected, 2 once, 3 three times, 4 and 5 not visible enough.
        let visible = vec![0, 9, 9, 9, 2, 0];
        let detected = vec![0, 0, 1, 3, 2, 0];
        let r = match_fusion(&graph, &gt, &visible, &detected, &MatchCriteria::default());
        assert_eq!(r.objects.misses, MissCounts { never_detected: 1, too_few_detections: 1, ..Default::default() });
        assert_eq!(r.parts.eligible, 1);
        assert_eq!(r.parts.misses, MissCounts { lost_in_fusion: 1, ..Default::default() });
        assert_eq!(r.parts.fragmentation(), None);
    }

    #[test]
    fn labels_accept_synonyms_and_alternatives() {
        let scene = op3dsg_synthetic::Scene::generate(op3dsg_synthetic::RoomKind::Kitchen, 1);
        let nodes = GtNode::from_scene(&scene);
        let handle = nodes.iter().find(|n| n.label == "cabinet handle").unwrap();
        assert!(handle.accepts("cupboard handle"), "{:?}", handle.accepted_labels);
        assert!(!handle.accepts("cabinet"));
        assert_eq!(normalise_label("  Cabinet   Handle "), "cabinet handle");
        assert_eq!(label_alternatives("tv / television").collect::<Vec<_>>(), ["tv", "television"]);
        let from_json = GtNode::from_graph_json(&scene.ground_truth());
        assert_eq!(from_json.len(), nodes.len());
        assert_eq!(from_json[0].box_min_m, nodes[0].box_min_m);
    }
}
