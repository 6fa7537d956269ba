//! The printed report of `op3dsg bench change`: one table per run, a row per preset and side.

use std::fmt::Write as _;

use super::WITHIN_KEYFRAMES;
use super::score::{PresetReport, percent};

/// Goal: removals and moves reflected within [`WITHIN_KEYFRAMES`] of first sight, percent, by
/// preset.
pub const WITHIN_GOALS: [(&str, f64); 2] = [("realistic", 95.0), ("field", 90.0)];
/// Goal: unchanged nodes removed, percent at most.
pub const UNCHANGED_GOAL_PERCENT: f64 = 1.0;

fn ratio((n, of): (usize, usize)) -> String {
    format!("{:.1} % ({n}/{of})", percent(n, of))
}

/// The report: a Markdown table (on and off per preset), then each goal met or missed.
pub fn text(reports: &[PresetReport]) -> String {
    let mut out = String::new();
    let _ = writeln!(
        out,
        "| preset | change handling | removals reflected | moves reflected | moves linked | additions found | \
         within {WITHIN_KEYFRAMES} keyframes of first sight | keyframes to update p50 / p90 | unchanged removed | \
         ghosts at end | occluder control hit | depth-hole control hit |"
    );
    let _ = writeln!(out, "|---|---|---|---|---|---|---|---|---|---|---|---|");
    for r in reports {
        let (within, seen) = r.within();
        let delays = r.delay_percentiles().map_or("-".to_owned(), |(p50, p90)| format!("{p50} / {p90}"));
        let (removed, unchanged) = r.unchanged_removed();
        let (add_on, add_off, adds) = r.additions();
        let ghosts = r.ghosts();
        let _ = writeln!(
            out,
            "| {} | on | {} | {} | {} | {} | {} | {delays} | {:.2} % ({removed}/{unchanged}) | {} | {} | {} |",
            r.preset,
            ratio(r.reflected(Some("removed"), 0)),
            ratio(r.reflected(Some("moved"), 0)),
            ratio(r.linked(0)),
            ratio((add_on, adds)),
            ratio((within, seen)),
            percent(removed as usize, unchanged as usize),
            ghosts[0],
            ratio(r.controls("occluder")),
            ratio(r.controls("depth hole")),
        );
        let _ = writeln!(
            out,
            "| {} | off | {} | {} | {} | {} | - | - | 0 | {} | - | - |",
            r.preset,
            ratio(r.reflected(Some("removed"), 1)),
            ratio(r.reflected(Some("moved"), 1)),
            ratio(r.linked(1)),
            ratio((add_off, adds)),
            ghosts[1],
        );
    }
    let _ = writeln!(out);
    for r in reports {
        let scenes = r.scenes.len();
        let keyframes: u64 = r.scenes.iter().map(|s| s.keyframes).sum();
        let events = r.scenes.iter().fold([0; 3], |a, s| [a[0] + s.events[0], a[1] + s.events[1], a[2] + s.events[2]]);
        let after: u32 = r.scenes.iter().map(|s| s.unchanged_removed_after).sum();
        let (unseen, unseen_reflected) = r.not_seen_again();
        let fusion = r.scenes.iter().fold([0.0; 2], |a, s| [a[0] + s.fusion_s[0], a[1] + s.fusion_s[1]]);
        let per_keyframe = |s: f64| 1e3 * s / keyframes.max(1) as f64;
        let _ = writeln!(
            out,
            "{}: {scenes} scenes, {keyframes} keyframes; {} removals and moves scored (mapped before the change and \
             their old place seen again within 3 m); left out: {} not mapped before, {unseen} not seen again within 3 \
             m ({unseen_reflected} of them reflected anyway); events {} appeared, {} removed, {} moved; unchanged \
             removed after the change (under the far-depth control): {after}; fusion per keyframe (mean) {:.2} ms \
             on, {:.2} ms off (x{:.2})",
            r.preset,
            r.mapped(None).len(),
            r.not_mapped(),
            events[0],
            events[1],
            events[2],
            per_keyframe(fusion[0]),
            per_keyframe(fusion[1]),
            fusion[0] / fusion[1].max(1e-9),
        );
    }
    for r in reports {
        for (goal, met, got) in goals(r) {
            let _ = writeln!(out, "goal {}: {goal}: {got}: {}", r.preset, if met { "met" } else { "MISSED" });
        }
    }
    out
}

/// The goals of one preset: (goal, met, figure).
fn goals(r: &PresetReport) -> Vec<(String, bool, String)> {
    let (removed, unchanged) = r.unchanged_removed();
    let unchanged_percent = percent(removed as usize, unchanged as usize);
    let mut goals = vec![(
        format!("unchanged removed <= {UNCHANGED_GOAL_PERCENT} %"),
        unchanged_percent <= UNCHANGED_GOAL_PERCENT,
        format!("{unchanged_percent:.2} %"),
    )];
    for kind in ["occluder", "depth hole"] {
        let (hit, of) = r.controls(kind);
        goals.push((format!("no {kind} control hit"), hit == 0, format!("{hit} of {of}")));
    }
    if let Some((_, goal)) = WITHIN_GOALS.iter().find(|(p, _)| *p == r.preset) {
        let (within, seen) = r.within();
        let got = percent(within, seen);
        goals.push((format!("within {WITHIN_KEYFRAMES} keyframes >= {goal} %"), got >= *goal, format!("{got:.1} %")));
    }
    goals
}

/// Whether every goal of `reports` is met.
pub fn goals_met(reports: &[PresetReport]) -> bool {
    reports.iter().flat_map(goals).all(|(_, met, _)| met)
}
