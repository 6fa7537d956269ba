//! The benchmark's printed report.

use std::collections::BTreeMap;

use super::report::r3_of;
use std::fmt::Write as _;

use super::{LOCO_ROWS, Loco, QualityReport, REFERENCE_MIX, TARGETS_R3};
use crate::eval::agreement::{self};
use crate::eval::recall::{K3, K5, K10, Recall, RecallFigures};
use op3dsg_runtime::knowledge::fallback::FallbackCounts;

fn pct(r: &Recall, k: usize) -> String {
    r.percent(k).map_or_else(|| "-".to_owned(), |p| format!("{p:.1}"))
}

/// The row's cells: object, part, overall, affordance R@3 R@5; functional, spatial R@3 R@5;
/// associated R@3 R@5 R@10.
fn cells(f: &RecallFigures) -> Vec<String> {
    let mut c = Vec::new();
    for r in [&f.object, &f.part, &f.overall, &f.affordance, &f.functional, &f.spatial] {
        c.push(pct(r, K3));
        c.push(pct(r, K5));
    }
    for k in [K3, K5, K10] {
        c.push(pct(&f.associated, k));
    }
    c
}

const HEADER: [&str; 15] = [
    "Obj R@3",
    "Obj R@5",
    "Part R@3",
    "Part R@5",
    "All R@3",
    "All R@5",
    "Aff R@3",
    "Aff R@5",
    "Func R@3",
    "Func R@5",
    "Spat R@3",
    "Spat R@5",
    "Assoc R@3",
    "Assoc R@5",
    "Assoc R@10",
];

/// Which full-row targets are missed: `(metric, R@3 percent, target)`.
pub fn missed_targets(report: &QualityReport) -> Vec<(&'static str, f64, f64)> {
    let Some((_, f)) = report.rows.first() else { return Vec::new() };
    let values = [&f.object, &f.part, &f.affordance, &f.functional, &f.spatial];
    TARGETS_R3
        .iter()
        .zip(values)
        .filter_map(|((name, target), r)| {
            let value = r.percent(K3).unwrap_or(0.0);
            (value < *target).then_some((*name, value, *target))
        })
        .collect()
}

fn sorted(map: &BTreeMap<String, usize>) -> String {
    let mut v: Vec<(&String, &usize)> = map.iter().collect();
    v.sort_by(|a, b| b.1.cmp(a.1).then(a.0.cmp(b.0)));
    if v.is_empty() {
        return "none".to_owned();
    }
    v.iter().map(|(k, n)| format!("{k} {n}")).collect::<Vec<_>>().join(", ")
}

/// The text report: table, strict node recall, items, losses, targets, mix.
pub fn text(report: &QualityReport) -> String {
    let mut s = String::new();
    let _ = write!(s, "{:<26}", "row");
    for h in HEADER {
        let _ = write!(s, " {h:>10}");
    }
    s.push('\n');
    for (name, f) in &report.rows {
        let _ = write!(s, "{name:<26}");
        for c in cells(f) {
            let _ = write!(s, " {c:>10}");
        }
        s.push('\n');
    }
    if let Some((_, f)) = report.rows.first() {
        let _ = writeln!(
            s,
            "\nfull, strict R@3: object IoU>=0.10 {} IoP>=0.25 {} | part IoU>=0.10 {} IoP>=0.25 {} | overall IoU>=0.10 {} \
             IoP>=0.25 {}",
            pct(&f.object_iou10, K3),
            pct(&f.object_iop25, K3),
            pct(&f.part_iou10, K3),
            pct(&f.part_iop25, K3),
            pct(&f.overall_iou10, K3),
            pct(&f.overall_iop25, K3)
        );
        let _ = writeln!(
            s,
            "items: {} objects, {} parts, {} affordances, {} functional, {} spatial triplets, {} associated pairs; \
             {} predicted nodes, {} retrieve nothing at R@10; {} vocabulary labels",
            f.object.total,
            f.part.total,
            f.affordance.total,
            f.functional.total,
            f.spatial.total,
            f.associated.total,
            f.predicted_nodes,
            f.predicted_unmatched,
            report.vocabulary_labels
        );
    }
    let _ = writeln!(s, "coverage: {}", report.coverage.text());
    let l = &report.losses;
    let _ = writeln!(s, "\nwhere the full row loses recall at R@3:");
    let _ = writeln!(s, "  object nodes: {}", sorted(&l.object));
    let _ = writeln!(s, "  part nodes: {}", sorted(&l.part));
    let _ = writeln!(s, "  affordances: {}", sorted(&l.affordance));
    let _ = writeln!(s, "  functional triplets: {}", sorted(&l.functional));
    let _ = writeln!(s, "  spatial triplets: {}", sorted(&l.spatial));
    let _ = writeln!(s, "  missed nodes by label: {}", sorted(&l.node_labels));
    let _ = writeln!(s, "  missed triplets by relation: {}", sorted(&l.relations));
    let missed = missed_targets(report);
    if missed.is_empty() {
        let _ = writeln!(s, "\ntargets (full, R@3): all met");
    } else {
        let list: Vec<String> = missed.iter().map(|(n, v, t)| format!("{n} {v:.1} < {t:.0}")).collect();
        let _ = writeln!(s, "\ntargets (full, R@3) missed: {}", list.join("; "));
    }
    s.push_str(&loco_text(&report.loco));
    s.push_str(&agreement::text(&report.agreement));
    s.push_str(&mix_text(&report.mix));
    s
}

fn cell(v: Option<f64>) -> String {
    v.map_or_else(|| "-".to_owned(), |p| format!("{p:.1}"))
}

const LOCO_HEADER: [&str; 5] = ["Obj R@3", "Part R@3", "Aff R@3", "Func R@3", "Spat R@3"];

/// The leave-one-category-out table: per variant, pooled and mean over categories.
fn loco_lines(loco: &Loco) -> Vec<(String, Vec<String>)> {
    let mut lines = Vec::new();
    for (v, name) in LOCO_ROWS.iter().enumerate() {
        if let Some(f) = loco.pooled.get(v) {
            lines.push((format!("{name} (pooled)"), r3_of(f).map(cell).to_vec()));
        }
    }
    for (v, name) in LOCO_ROWS.iter().enumerate() {
        if let Some(m) = loco.mean_r3.get(v) {
            lines.push((format!("{name} (mean over categories)"), m.map(cell).to_vec()));
        }
    }
    lines
}

fn fallback_text(c: &[FallbackCounts; 2]) -> String {
    let one = |c: &FallbackCounts| {
        format!(
            "{} nodes given their nearest category by embedding, {} parts reasoned as on the nearest category that \
             has them, {} parts by the part-label rule, {} nodes unresolved",
            c.by_embedding, c.parts_by_embedding, c.by_part_rule, c.unresolved
        )
    };
    format!("on the fused graphs {}; on the ground-truth nodes {}", one(&c[0]), one(&c[1]))
}

/// The leave-one-category-out block of the text report.
pub fn loco_text(loco: &Loco) -> String {
    let mut s = format!(
        "\nleave one category out ({} categories; items involving the category, in the scenes that contain it; a mean \
         is over the categories with items in its column):\n",
        loco.categories.len()
    );
    let _ = write!(s, "{:<48}", "variant");
    for h in LOCO_HEADER {
        let _ = write!(s, " {h:>9}");
    }
    s.push('\n');
    for (name, cells) in loco_lines(loco) {
        let _ = write!(s, "{name:<48}");
        for c in cells {
            let _ = write!(s, " {c:>9}");
        }
        s.push('\n');
    }
    let _ = writeln!(s, "  fallbacks: {}", fallback_text(&loco.fallback));
    let _ = writeln!(
        s,
        "  per category (as: its nearest known category by embedding), full -> leave one out (fused graph), R@3 aff / func:"
    );
    for c in &loco.categories {
        let [full, left] = [&c.figures[0], &c.figures[1]];
        let _ = writeln!(
            s,
            "    {:<22} {:<28} {} scenes, {} aff, {} func: aff {} -> {}, func {} -> {}; GT nodes func {} -> {}",
            c.category,
            c.nearest.as_ref().map_or_else(|| "(nothing near)".to_owned(), |(n, cos)| format!("(as {n}, {cos:.2})")),
            c.scenes,
            full.affordance.total,
            full.functional.total,
            cell(full.affordance.percent(K3)),
            cell(left.affordance.percent(K3)),
            cell(full.functional.percent(K3)),
            cell(left.functional.percent(K3)),
            cell(c.figures[2].functional.percent(K3)),
            cell(c.figures[3].functional.percent(K3)),
        );
    }
    s
}

/// The leave-one-category-out table in Markdown.
pub fn loco_markdown(loco: &Loco) -> String {
    let mut s = String::from("| leave one category out |");
    for h in LOCO_HEADER {
        let _ = write!(s, " {h} |");
    }
    s.push_str("\n|---|");
    for _ in LOCO_HEADER {
        s.push_str("---:|");
    }
    s.push('\n');
    for (name, cells) in loco_lines(loco) {
        let _ = writeln!(s, "| {name} | {} |", cells.join(" | "));
    }
    let _ = writeln!(s, "\nFallbacks of the reasoner without the category: {}.", fallback_text(&loco.fallback));
    s
}

/// The functional-relation mix next to the benchmark's, percent.
pub fn mix_text(mix: &BTreeMap<String, u32>) -> String {
    let total: u32 = mix.values().sum();
    let (f_total, s_total) = (230.0, 195.0);
    let mut s = format!(
        "\nfunctional relations: {:<44} {:>12} {:>12} {:>12}\n",
        "relation", "synthetic %", "FunGraph3D %", "SceneFun3D %"
    );
    for (relation, f, sf) in REFERENCE_MIX {
        let ours = mix.get(relation).copied().unwrap_or(0);
        let _ = writeln!(
            s,
            "                      {:<44} {:>12} {:>12.1} {:>12.1}",
            relation,
            format!("{:.1} ({ours})", 100.0 * f64::from(ours) / f64::from(total.max(1))),
            100.0 * f64::from(f) / f_total,
            100.0 * f64::from(sf) / s_total
        );
    }
    let _ = writeln!(s, "                      {:<44} {:>12}", "total edges", total);
    s
}

/// The Markdown table (and the strict figures) for docs/benchmarks.md.
pub fn markdown(report: &QualityReport) -> String {
    let mut s = String::from("| row |");
    for h in HEADER {
        let _ = write!(s, " {h} |");
    }
    s.push_str("\n|---|");
    for _ in HEADER {
        s.push_str("---:|");
    }
    s.push('\n');
    for (name, f) in &report.rows {
        let _ = write!(s, "| {name} |");
        for c in cells(f) {
            let _ = write!(s, " {c} |");
        }
        s.push('\n');
    }
    if let Some((_, f)) = report.rows.first() {
        let _ = writeln!(
            s,
            "\nStrict node R@3 (full): object {} / {}, part {} / {}, overall {} / {} (IoU ≥ 0.10 / IoP ≥ 0.25).",
            pct(&f.object_iou10, K3),
            pct(&f.object_iop25, K3),
            pct(&f.part_iou10, K3),
            pct(&f.part_iop25, K3),
            pct(&f.overall_iou10, K3),
            pct(&f.overall_iop25, K3)
        );
    }
    let _ = writeln!(s, "\nCoverage: {}.", report.coverage.text());
    s.push('\n');
    s.push_str(&loco_markdown(&report.loco));
    let a = &report.agreement;
    let share = |x: &agreement::Share| x.percent().map_or_else(|| "-".to_owned(), |p| format!("{p:.1} %"));
    let _ = writeln!(
        s,
        "\nGround truth vs knowledge base (reasoner on ground-truth nodes): functional triplets {} of {} agree ({}), \
         affordance sets {} of {} ({}); on the rooms' deviations {} / {}.",
        a.functional.agree,
        a.functional.total,
        share(&a.functional),
        a.affordance.agree,
        a.affordance.total,
        share(&a.affordance),
        share(&a.functional_deviations),
        share(&a.affordance_deviations)
    );
    s
}
