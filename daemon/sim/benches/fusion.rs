//! One fusion step — 40 detections (objects and parts) of a real 640x480 kitchen keyframe — into
//! maps of about 100, 2,000 and 20,000 nodes, on one thread.
//!
//! `taskset -c 0 cargo bench -p op3dsg-sim --bench fusion` prints, per map size, the median
//! and p99 of 500 timed steps, the heap allocations per step after warm-up (counted by a global
//! allocator), and the ratio of the 20,000-node step to the 100-node step; criterion's own
//! report follows.

use std::alloc::System;
use std::time::Instant;

use criterion::{Criterion, criterion_group, criterion_main};
use op3dsg_ipc_types::NodeKind;
use op3dsg_runtime::fusion::multiview::MultiViewFusion;
use op3dsg_runtime::fusion::{Fusion, FusionConfig};
use op3dsg_sim::oracle::OracleConfig;
use op3dsg_sim::workload::Workload;
use stats_alloc::{INSTRUMENTED_SYSTEM, Region, StatsAlloc};

#[global_allocator]
static GLOBAL: &StatsAlloc<System> = &INSTRUMENTED_SYSTEM;

const SIZES: [usize; 3] = [100, 2_000, 20_000];
const TIMED_STEPS: usize = 500;

fn config() -> FusionConfig {
    op3dsg_sim::load_profile(None, &[]).expect("built-in profile").profile.fusion
}

fn percentile(sorted: &[f64], q: f64) -> f64 {
    sorted[((sorted.len() - 1) as f64 * q).round() as usize]
}

fn bench_fusion(c: &mut Criterion) {
    // The map: realistic keyframes along kitchen 3's path. The step: the busiest wide view of
    // that kitchen, detected with the realistic preset's mask, label and score noise but no
    // misses or false positives (so that 40 detections fit in one 640x480 view).
    let workload = Workload::kitchen(3, 30, 15, OracleConfig::realistic());
    let step = Workload::busy_step(3, 40);
    let parts = step.detections.iter().filter(|d| d.kind == NodeKind::Part).count();
    let mask_px: usize = step.detections.iter().map(|d| d.mask.area()).sum();
    eprintln!(
        "fusion step: {} detections ({} objects, {parts} parts), {mask_px} mask pixels, 640x480",
        step.detections.len(),
        step.detections.len() - parts
    );
    let mut medians = Vec::new();
    let mut group = c.benchmark_group("fusion step, 40 detections");
    group.sample_size(50);
    for target in SIZES {
        let mut fusion = MultiViewFusion::new(config());
        let copies = workload.fill_map(&mut fusion, target, 1000);
        // Warm-up past the pruning horizon (30 keyframes) of the fill's stale candidates.
        for _ in 0..50 {
            fusion.integrate(&step.frame, &step.pose, &step.detections);
        }
        let region = Region::new(GLOBAL);
        for _ in 0..50 {
            fusion.integrate(&step.frame, &step.pose, &step.detections);
        }
        let allocations = region.change().allocations as f64 / 50.0;
        let mut times: Vec<f64> = (0..TIMED_STEPS)
            .map(|_| {
                let t = Instant::now();
                fusion.integrate(&step.frame, &step.pose, &step.detections);
                t.elapsed().as_secs_f64() * 1e3
            })
            .collect();
        times.sort_by(f64::total_cmp);
        let (median, p99) = (percentile(&times, 0.5), percentile(&times, 0.99));
        medians.push(median);
        eprintln!(
            "map {:>6} nodes ({copies} kitchen copies, {:.1} MiB): median {median:.3} ms, p99 {p99:.3} ms, \
             {allocations:.2} allocations/step",
            fusion.node_count(),
            op3dsg_runtime::stats::mib(fusion.memory_bytes() as u64)
        );
        group.bench_function(format!("{} nodes", fusion.node_count()), |b| {
            b.iter(|| fusion.integrate(&step.frame, &step.pose, &step.detections))
        });
    }
    group.finish();
    eprintln!("ratio 20,000-node / 100-node median step: {:.2}", medians[2] / medians[0]);
}

criterion_group!(benches, bench_fusion);
criterion_main!(benches);
