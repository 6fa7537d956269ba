//! What a match says, for people and for tests: [`QualityTargets`] (the pass marks of a room),
//! the per-room table ([`table_header`], [`table_row`], [`TABLE_LEGEND`]) and the per-node
//! [`details`].

use std::fmt::Write as _;

use super::{FusionMatchReport, MissCounts, MissReason};

/// Pass marks for a room (`daemon/sim/tests/it/fusion_quality.rs`); a fusion must meet all of them.
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
