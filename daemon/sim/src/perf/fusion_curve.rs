//! Fusion cost against map size for `op3dsg bench perf`, and its PNG plot.
//!
//! The step and the maps are those of `cargo bench --bench fusion` (see
//! [`crate::workload`]): the busiest wide view of kitchen 3 with 40 detections (realistic
//! mask, label and score noise, no misses), integrated into one map grown through the asked sizes
//! from copies of the kitchen 20 m apart. Per size: 50 untimed steps (past the pruning horizon of
//! the fill's unconfirmed candidates), then the timed ones, on the calling thread.

use std::path::Path;
use std::time::Instant;

use anyhow::anyhow;
use op3dsg_ipc_types::NodeKind;
use serde::{Deserialize, Serialize};

use super::{Percentiles, PerfOptions};
use crate::oracle::OracleConfig;
use crate::plot::{draw_legend, draw_line_with_points, plot_err, register_font, save_png};
use crate::workload::Workload;

/// Untimed steps before the timed ones at each size.
pub const WARMUP_STEPS: usize = 50;
/// Detections in the step.
pub const STEP_DETECTIONS: usize = 40;
/// Copies of the kitchen a map may hold at most (a 64-wide grid 20 m apart).
const MAX_COPIES: usize = 100_000;

/// One map size of the curve.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FusionPoint {
    /// The size asked for.
    pub target_nodes: usize,
    /// Nodes in the map (confirmed and pending) when the steps ran.
    pub nodes: usize,
    /// Kitchen copies integrated so far.
    pub copies: usize,
    /// Heap the map holds, MiB.
    pub memory_mib: f64,
    /// One step's latency.
    pub step: Percentiles,
    /// The evidence step of `[fusion.change]` within it.
    #[serde(default)]
    pub evidence: Percentiles,
    /// One step's latency with change handling off, on the same map (steps on and off taken
    /// in turn).
    #[serde(default)]
    pub step_off: Percentiles,
}

/// The fusion section of the report.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FusionCurve {
    /// Detections in the step.
    pub detections: usize,
    /// Object detections among them.
    pub objects: usize,
    /// Part detections among them.
    pub parts: usize,
    /// Timed steps per size.
    pub steps: usize,
    /// Untimed steps per size.
    pub warmup_steps: usize,
    /// One point per size, smallest first.
    pub points: Vec<FusionPoint>,
}

/// Measures the fusion step at every size of `options.fusion_sizes` (the fusion settings come
/// from the profile and overrides of `options`).
pub fn fusion_curve(options: &PerfOptions) -> anyhow::Result<FusionCurve> {
    let profile = crate::load_profile(options.profile.as_deref(), &options.overrides)
        .map_err(|e| anyhow!("bad profile: {e}"))?
        .profile;
    let workload = Workload::kitchen(3, options.fusion_keyframes.max(1), 15, OracleConfig::realistic());
    let step = Workload::busy_step(3, STEP_DETECTIONS);
    let parts = step.detections.iter().filter(|d| d.kind == NodeKind::Part).count();

    let mut sizes = options.fusion_sizes.clone();
    sizes.sort_unstable();
    sizes.dedup();
    let mut fusion = op3dsg_runtime::fusion::build(&profile.fusion, profile.world.up_axis);
    let mut next_copy = 0;
    let mut points = Vec::new();
    for target in sizes {
        next_copy = workload.grow_map(fusion.as_mut(), next_copy, target, MAX_COPIES);
        for _ in 0..WARMUP_STEPS {
            fusion.integrate(&step.frame, &step.pose, &step.detections);
        }
        let steps = options.fusion_steps.max(1);
        let (mut on_ms, mut off_ms, mut evidence_ms) =
            (Vec::with_capacity(steps), Vec::with_capacity(steps), Vec::with_capacity(steps));
        let change = profile.fusion.change.enabled;
        for _ in 0..steps {
            for on in [true, false] {
                fusion.set_change_handling(on && change);
                let t = Instant::now();
                let report = fusion.integrate(&step.frame, &step.pose, &step.detections);
                let ms = t.elapsed().as_secs_f64() * 1e3;
                if on {
                    on_ms.push(ms);
                    evidence_ms.push(report.evidence_ns as f64 * 1e-6);
                } else {
                    off_ms.push(ms);
                }
            }
        }
        fusion.set_change_handling(change);
        let point = FusionPoint {
            target_nodes: target,
            nodes: fusion.node_count(),
            copies: next_copy,
            memory_mib: op3dsg_runtime::stats::mib(fusion.memory_bytes() as u64),
            step: Percentiles::from_samples_ms(&mut on_ms),
            evidence: Percentiles::from_samples_ms(&mut evidence_ms),
            step_off: Percentiles::from_samples_ms(&mut off_ms),
        };
        eprintln!(
            "bench perf:   map {:>6} nodes: step p50 {:.3} ms, p99 {:.3} ms (evidence p50 {:.3}, p99 {:.3}; change \
             handling off: p99 {:.3} ms)",
            point.nodes,
            point.step.p50_ms,
            point.step.p99_ms,
            point.evidence.p50_ms,
            point.evidence.p99_ms,
            point.step_off.p99_ms
        );
        points.push(point);
    }
    Ok(FusionCurve {
        detections: step.detections.len(),
        objects: step.detections.len() - parts,
        parts,
        steps: options.fusion_steps.max(1),
        warmup_steps: WARMUP_STEPS,
        points,
    })
}

/// Width and height of the plot, pixels.
pub const PLOT_SIZE: (u32, u32) = (1000, 600);

/// Which figure of a point a plotted series shows.
type Quantity = fn(&FusionPoint) -> f64;

/// Draws the curve (p50 and p99 of the step against map nodes, log x axis) into a PNG at `path`.
/// Text uses DejaVu Sans embedded in the binary, so no font needs to be installed.
pub fn plot_png(curve: &FusionCurve, path: &Path) -> anyhow::Result<()> {
    use plotters::prelude::*;
    register_font()?;
    if curve.points.is_empty() {
        return Err(anyhow!("no fusion measurements to plot"));
    }
    let (width, height) = PLOT_SIZE;
    let mut buffer = vec![0u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (width, height)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_err("background", e))?;
        let nodes = |p: &FusionPoint| p.nodes.max(1) as f64;
        let x_min = curve.points.iter().map(nodes).fold(f64::INFINITY, f64::min) / 1.5;
        let x_max = curve.points.iter().map(nodes).fold(0.0, f64::max) * 1.5;
        let y_max = curve.points.iter().map(|p| p.step.p99_ms).fold(0.0, f64::max).max(1e-3) * 1.2;
        let caption = format!(
            "Fusion step ({} detections: {} objects, {} parts) against map size",
            curve.detections, curve.objects, curve.parts
        );
        let mut chart = ChartBuilder::on(&root)
            .caption(caption, ("sans-serif", 24))
            .margin(20)
            .x_label_area_size(55)
            .y_label_area_size(75)
            .build_cartesian_2d((x_min..x_max).log_scale(), 0f64..y_max)
            .map_err(|e| plot_err("axes", e))?;
        chart
            .configure_mesh()
            .x_desc("map nodes (log scale)")
            .y_desc("step time, ms")
            .label_style(("sans-serif", 16))
            .axis_desc_style(("sans-serif", 18))
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| format!("{v:.2}"))
            .draw()
            .map_err(|e| plot_err("grid", e))?;
        let series: [(&str, RGBColor, Quantity); 2] =
            [("p50", BLUE, |p| p.step.p50_ms), ("p99", RED, |p| p.step.p99_ms)];
        for (name, colour, value) in series {
            let line: Vec<(f64, f64)> = curve.points.iter().map(|p| (nodes(p), value(p))).collect();
            draw_line_with_points(&mut chart, line, colour, format!("{name} of {} steps", curve.steps))?;
        }
        draw_legend(&mut chart, SeriesLabelPosition::LowerRight, 16)?;
        root.present().map_err(|e| plot_err("present", e))?;
    }
    save_png(buffer, (width, height), path, "plot")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plot_is_a_png_of_the_plot_size() {
        let point = |nodes: usize, p50: f64| FusionPoint {
            target_nodes: nodes,
            nodes,
            copies: 1,
            memory_mib: 1.0,
            step: Percentiles { count: 10, p50_ms: p50, p99_ms: p50 * 1.5, mean_ms: p50, max_ms: p50 * 2.0 },
            evidence: Percentiles::default(),
            step_off: Percentiles::default(),
        };
        let curve = FusionCurve {
            detections: 40,
            objects: 18,
            parts: 22,
            steps: 10,
            warmup_steps: 50,
            points: vec![point(100, 2.0), point(2_000, 2.1), point(20_000, 2.3)],
        };
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("fusion.png");
        plot_png(&curve, &path).unwrap();
        let image = image::open(&path).unwrap().to_rgb8();
        assert_eq!(image.dimensions(), PLOT_SIZE);
        // Text and lines: the plot is not blank.
        let non_white = image.pixels().filter(|p| p.0 != [255, 255, 255]).count();
        assert!(non_white > 5_000, "{non_white} drawn pixels");
        // Both series colours appear.
        assert!(image.pixels().any(|p| p.0 == [0, 0, 255]));
        assert!(image.pixels().any(|p| p.0 == [255, 0, 0]));
        let empty = FusionCurve { points: vec![], ..curve };
        assert!(plot_png(&empty, &path).is_err());
    }
}
