//! Noise curves of `op3dsg bench quality --curves`: the full row's R@3 per column against pose
//! drift and against category confusion, one benchmark run per point on the run's own preset
//! with only that knob changed.
//!
//! | curve | knob | levels |
//! |---|---|---|
//! | pose drift | `pose_drift_fraction` = level, `pose_drift_deg_per_m` = [`HEADING_DEG_PER_M_PER_FRACTION`] x level (2 % ↔ 0.5 °/m); jitter as the preset | 0, 1, 2, 5 % of distance travelled |
//! | confusion | `confusion_rate` = level | 0, 10, 20, 30 % of detections |
//!
//! Each point runs every scene again (rendering, detection, fusion, reasoning and the other
//! rows), so the curves multiply the run time by about the number of points; they are not part
//! of the CI-sized run.

use std::path::Path;

use anyhow::anyhow;
use op3dsg_runtime::config::Profile;
use serde::Serialize;

use super::benchmark::{self, QualityReport};
use super::recall::{K3, PhraseEmbedder};
use crate::backends::{oracle_config, set_oracle_config};

/// Pose drift levels, as fractions of the distance travelled.
pub const DRIFT_LEVELS: [f64; 4] = [0.0, 0.01, 0.02, 0.05];
/// Confusion rates.
pub const CONFUSION_LEVELS: [f64; 4] = [0.0, 0.1, 0.2, 0.3];
/// Heading drift per metre that goes with a translation drift fraction, degrees per metre per
/// unit fraction (25: 2 % of distance goes with 0.5 °/m).
pub const HEADING_DEG_PER_M_PER_FRACTION: f64 = 25.0;
/// The columns of a curve point, in order.
pub const COLUMNS: [&str; 5] = ["object", "part", "affordance", "functional", "spatial"];

/// One point of a curve.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct CurvePoint {
    /// The knob's level (a fraction).
    pub level: f64,
    /// The full row's R@3 per [`COLUMNS`] entry, percent (`None`: no items).
    pub r3: [Option<f64>; 5],
}

/// One curve.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Curve {
    /// What varies (`pose drift`, `confusion`).
    pub name: String,
    /// The knob(s) set per point.
    pub knob: String,
    /// The points, in level order.
    pub points: Vec<CurvePoint>,
}

/// The curves of one run.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Curves {
    /// Pose drift, then confusion.
    pub curves: Vec<Curve>,
}

fn full_r3(report: &QualityReport) -> [Option<f64>; 5] {
    report
        .rows
        .first()
        .map_or([None; 5], |(_, f)| [f.object, f.part, f.affordance, f.functional, f.spatial].map(|r| r.percent(K3)))
}

/// Runs the curves on `base` (its `[detector.oracle]` is the starting point): `scenes` scenes per
/// point on `threads` threads, scored with `embedder`. `progress` gets a line per point.
pub fn run(
    base: &Profile,
    scenes: usize,
    threads: usize,
    embedder: &mut dyn PhraseEmbedder,
    progress: &(dyn Fn(&str) + Sync),
) -> Result<Curves, String> {
    let oracle = oracle_config(base).map_err(|e| e.to_string())?;
    let mut curves = Vec::new();
    type Set = fn(&mut crate::oracle::OracleConfig, f64);
    let specs: [(&str, &str, &[f64], Set); 2] = [
        ("pose drift", "pose_drift_fraction, pose_drift_deg_per_m = 25 x fraction", &DRIFT_LEVELS, |o, v| {
            o.pose_drift_fraction = v;
            o.pose_drift_deg_per_m = HEADING_DEG_PER_M_PER_FRACTION * v;
        }),
        ("confusion", "confusion_rate", &CONFUSION_LEVELS, |o, v| o.confusion_rate = v),
    ];
    for (name, knob, levels, set) in specs {
        let mut points = Vec::new();
        for &level in levels {
            let mut profile = base.clone();
            let mut config = oracle.clone();
            set(&mut config, level);
            set_oracle_config(&mut profile, &config);
            let quiet = |_: &str| {};
            let runs = benchmark::run_scenes(&profile, scenes, threads, &quiet)?;
            let report = benchmark::score(&runs, embedder)?;
            points.push(CurvePoint { level, r3: full_r3(&report) });
            progress(&format!("{name} {:.0} %", level * 100.0));
        }
        curves.push(Curve { name: name.to_owned(), knob: knob.to_owned(), points });
    }
    Ok(Curves { curves })
}

fn cell(v: Option<f64>) -> String {
    v.map_or_else(|| "-".to_owned(), |v| format!("{v:.1}"))
}

/// The curves as a text table (one block per curve, a line per level).
pub fn text(curves: &Curves) -> String {
    let mut out = String::from("noise curves: full row R@3 per column against one knob (the others as the preset)\n");
    for curve in &curves.curves {
        out.push_str(&format!("{} ({}):\n", curve.name, curve.knob));
        out.push_str(&format!("  {:>8}", "level"));
        for c in COLUMNS {
            out.push_str(&format!(" {c:>11}"));
        }
        out.push('\n');
        for p in &curve.points {
            out.push_str(&format!("  {:>7.0}%", p.level * 100.0));
            for v in p.r3 {
                out.push_str(&format!(" {:>11}", cell(v)));
            }
            out.push('\n');
        }
    }
    out
}

/// The curves as Markdown tables.
pub fn markdown(curves: &Curves) -> String {
    let mut out = String::new();
    for curve in &curves.curves {
        out.push_str(&format!("\n{} (`{}`), full row R@3:\n\n| level |", curve.name, curve.knob));
        for c in COLUMNS {
            out.push_str(&format!(" {c} |"));
        }
        out.push_str("\n|---:|");
        out.push_str(&"---:|".repeat(COLUMNS.len()));
        out.push('\n');
        for p in &curve.points {
            out.push_str(&format!("| {:.0} % |", p.level * 100.0));
            for v in p.r3 {
                out.push_str(&format!(" {} |", cell(v)));
            }
            out.push('\n');
        }
    }
    out
}

/// Width and height of the curves' PNG, pixels.
pub const PLOT_SIZE: (u32, u32) = (1200, 520);

/// Draws the curves side by side (R@3 per column against the level) into a PNG at `path`. Text
/// uses DejaVu Sans embedded in the binary (the `dejavu` crate), so no font need be installed.
pub fn plot_png(curves: &Curves, path: &Path) -> anyhow::Result<()> {
    use crate::plot::{draw_legend, draw_line_with_points, plot_err};
    use plotters::prelude::*;
    crate::plot::register_font()?;
    if curves.curves.iter().all(|c| c.points.is_empty()) {
        return Err(anyhow!("no curve points to plot"));
    }
    let (width, height) = PLOT_SIZE;
    let mut buffer = vec![0u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err("background", e))?;
        let panels = root.split_evenly((1, curves.curves.len().max(1)));
        let colours = [BLUE, RED, GREEN, MAGENTA, BLACK];
        for (curve, panel) in curves.curves.iter().zip(&panels) {
            let x_max = curve.points.iter().map(|p| p.level * 100.0).fold(1.0, f64::max);
            let mut chart = ChartBuilder::on(panel)
                .caption(format!("full row R@3 against {}", curve.name), ("sans-serif", 22))
                .margin(15)
                .x_label_area_size(45)
                .y_label_area_size(55)
                .build_cartesian_2d(0f64..x_max * 1.05, 0f64..100.0)
                .map_err(|e| plot_err("axes", e))?;
            chart
                .configure_mesh()
                .x_desc(format!("{}, %", curve.name))
                .y_desc("R@3, %")
                .label_style(("sans-serif", 15))
                .axis_desc_style(("sans-serif", 16))
                .draw()
                .map_err(|e| plot_err("grid", e))?;
            for (column, (name, colour)) in COLUMNS.iter().zip(colours).enumerate() {
                let line: Vec<(f64, f64)> =
                    curve.points.iter().filter_map(|p| p.r3[column].map(|v| (p.level * 100.0, v))).collect();
                draw_line_with_points(&mut chart, line, colour, (*name).to_owned())?;
            }
            draw_legend(&mut chart, SeriesLabelPosition::LowerLeft, 15)?;
        }
        root.present().map_err(|e| plot_err("present", e))?;
    }
    crate::plot::save_png(buffer, (width, height), path, "curves plot")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Curves {
        let point = |level: f64, base: f64| CurvePoint {
            level,
            r3: [Some(base), Some(base - 5.0), None, Some(base - 10.0), Some(base - 20.0)],
        };
        Curves {
            curves: vec![
                Curve {
                    name: "pose drift".into(),
                    knob: "pose_drift_fraction".into(),
                    points: DRIFT_LEVELS.iter().map(|&l| point(l, 95.0 - 300.0 * l)).collect(),
                },
                Curve {
                    name: "confusion".into(),
                    knob: "confusion_rate".into(),
                    points: CONFUSION_LEVELS.iter().map(|&l| point(l, 95.0 - 50.0 * l)).collect(),
                },
            ],
        }
    }

    #[test]
    fn text_and_markdown_have_a_line_per_level() {
        let curves = sample();
        let text = text(&curves);
        assert!(text.contains("      5%") && text.contains("     30%"), "{text}");
        assert!(text.contains("     80.0"), "{text}");
        let md = markdown(&curves);
        assert_eq!(md.lines().filter(|l| l.starts_with("| ") && l.contains(" % |")).count(), 8, "{md}");
        assert!(md.contains("| 2 % | 89.0 | 84.0 | - | 79.0 | 69.0 |"), "{md}");
    }

    #[test]
    fn plot_is_a_png_of_the_plot_size() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("curves.png");
        plot_png(&sample(), &path).unwrap();
        let image = image::open(&path).unwrap().to_rgb8();
        assert_eq!(image.dimensions(), PLOT_SIZE);
        let coloured = image.pixels().filter(|p| p.0[2] > 200 && p.0[0] < 80).count();
        assert!(coloured > 200, "the blue line is drawn ({coloured} px)");
        assert!(plot_png(&Curves::default(), &path).is_err());
    }
}
