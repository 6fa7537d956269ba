//! The pipeline in this process over a stepped replay of the ICL-NUIM sequence in
//! `../shared/data` (skipped with a message when absent, a failure in CI): frames enter only when stepped.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use op3dsg_runtime::pipeline::{Counters, Pipeline};

/// Watchdog of each wait (not a speed requirement).
const WATCHDOG: Duration = Duration::from_secs(60);

fn wait_for_frames(stats: &Counters, frames: u64) {
    let deadline = Instant::now() + WATCHDOG;
    while stats.capture.frames_captured.load(Ordering::Relaxed) < frames {
        assert!(Instant::now() < deadline, "timed out waiting for {frames} frames");
        std::thread::sleep(Duration::from_millis(10));
    }
}

#[test]
fn stepped_replay_lets_frames_in_one_step_at_a_time() {
    let Some(dir) = op3dsg_shared_data::shared_data("rgbd/icl_livingroom1") else { return };
    iceoryx2::prelude::set_log_level_from_env_or(iceoryx2::prelude::LogLevel::Error);
    let prefix = format!("op3dsg-test-replay-{}", std::process::id());
    let overrides = [
        "source.kind=replay".to_owned(),
        "source.rate_hz=0".to_owned(),
        format!("source.replay.path={:?}", dir.display().to_string()),
        "source.replay.mode=stepped".to_owned(),
        format!("ipc.prefix={prefix:?}"),
    ];
    let profile = op3dsg_sim::load_profile(None, &overrides).expect("profile").profile;
    let stop = Arc::new(AtomicBool::new(false));
    let pipeline = Pipeline::start(&profile, &op3dsg_sim::backends(), stop.clone()).expect("pipeline starts");
    let step = pipeline.step_control().expect("a stepped replay has a step control").clone();
    let stats = pipeline.counters().clone();

    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(stats.capture.frames_captured.load(Ordering::Relaxed), 0, "no frame before the first step");
    step.step(3);
    wait_for_frames(&stats, 3);
    std::thread::sleep(Duration::from_millis(300));
    assert_eq!(stats.capture.frames_captured.load(Ordering::Relaxed), 3, "no frame beyond the steps");
    step.step(2);
    wait_for_frames(&stats, 5);

    stop.store(true, Ordering::SeqCst);
    let summary = pipeline.wait().expect("orderly shutdown");
    assert_eq!(summary.frames, 5);
    assert!(summary.keyframes >= 1 && !summary.source_failed);
}
