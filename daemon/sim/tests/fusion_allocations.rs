//! After warm-up, a fusion step allocates nothing: a counting global allocator around repeated
//! steps of a real 640x480 kitchen keyframe (the benchmark's workload, smaller map).

use std::alloc::System;

use op3dsg_runtime::fusion::Fusion;
use op3dsg_runtime::fusion::multiview::MultiViewFusion;
use op3dsg_sim::oracle::OracleConfig;
use op3dsg_sim::workload::Workload;
use stats_alloc::{INSTRUMENTED_SYSTEM, Region, StatsAlloc};

#[global_allocator]
static GLOBAL: &StatsAlloc<System> = &INSTRUMENTED_SYSTEM;

#[test]
fn a_warm_fusion_step_allocates_nothing() {
    let config = op3dsg_sim::load_profile(None, &[]).expect("built-in profile").profile.fusion;
    let workload = Workload::kitchen(3, 8, 45, OracleConfig::realistic());
    let step = workload.step(40);
    assert!(step.detections.len() >= 10, "a busy keyframe: {} detections", step.detections.len());
    let mut fusion = MultiViewFusion::new(config);
    let copies = workload.fill_map(&mut fusion, 300, 20);
    assert!(fusion.node_count() >= 100, "{} nodes from {copies} copies", fusion.node_count());
    // Warm-up: scratch buffers and the touched nodes reach their working sizes, and candidates of
    // the fill that are never seen again are pruned (after 30 keyframes; their slots go to the
    // free list, which grows once).
    for _ in 0..50 {
        fusion.integrate(&step.frame, &step.pose, &step.detections);
    }
    let region = Region::new(GLOBAL);
    for _ in 0..30 {
        fusion.integrate(&step.frame, &step.pose, &step.detections);
    }
    let change = region.change();
    assert_eq!(
        (change.allocations, change.reallocations),
        (0, 0),
        "30 warm steps of {} detections into {} nodes",
        step.detections.len(),
        fusion.node_count()
    );
}
