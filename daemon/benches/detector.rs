//! YOLOX-nano detection cost on real frames (ICL-NUIM living room 1):
//! - `yolox/inference`: letterbox + one `session.run` of a single session (one intra-op thread),
//!   per frame; compare with `scripts/reference/yolox_reference.py 180 --time 200`, onnxruntime's
//!   Python API on the same model, input and thread count (session.run only);
//! - `yolox/detect`: the whole detector (inference, decoding, NMS, class map, masks from depth);
//! - then, printed: detection throughput (frames/s) of 1 and 2 worker threads, each owning its
//!   own session, sharing the first 60 frames of the sequence (as the daemon's worker pool does).
//!
//! `cargo bench -p op3dsg-daemon --bench detector` (needs `.models/` from
//! `./scripts/setup-models.sh` and the shared development data; prints why and does nothing
//! without them).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use op3dsg_daemon::onnx::{OnnxConfig, OnnxRuntime};
use op3dsg_daemon::perception::Detector;
use op3dsg_daemon::perception::yolox::{YoloxConfig, YoloxDetector, YoloxModel};
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::replay::{PlaybackMode, ReplayConfig, ReplaySource};
use op3dsg_drivers::source::{FrameSource, SourceStatus};

const THROUGHPUT_FRAMES: usize = 60;

fn shared() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data")
}

fn config() -> YoloxConfig {
    let mut config =
        YoloxConfig { model_path: shared().join("models/yolox_nano/yolox_nano.onnx"), ..YoloxConfig::default() };
    for class in ["chair", "sofa", "tvmonitor", "vase", "pottedplant", "diningtable", "bed"] {
        config.class_map.insert(class.to_owned(), class.to_owned());
    }
    config
}

fn frames(count: usize) -> Vec<Frame> {
    let mut replay = ReplayConfig::new(shared().join("rgbd/icl_livingroom1"));
    replay.mode = PlaybackMode::Fast;
    let mut source = ReplaySource::new(&replay).expect("replay source");
    let mut out = Vec::with_capacity(count);
    let mut frame = Frame::new(source.intrinsics(), false);
    while out.len() < count {
        match source.next_frame(&mut frame).expect("frame") {
            SourceStatus::Frame => out.push(frame.clone()),
            SourceStatus::Pending => continue,
            SourceStatus::EndOfStream => break,
        }
    }
    out
}

/// Frames per second of `workers` threads, each with its own detector, over `frames`.
fn throughput(runtime: &OnnxRuntime, frames: &Arc<Vec<Frame>>, workers: usize) -> f64 {
    let detectors: Vec<YoloxDetector> =
        (0..workers).map(|_| YoloxDetector::new(runtime, &config()).expect("YOLOX")).collect();
    let next = Arc::new(AtomicUsize::new(0));
    let started = Instant::now();
    let handles: Vec<_> = detectors
        .into_iter()
        .enumerate()
        .map(|(i, mut detector)| {
            let frames = Arc::clone(frames);
            let next = Arc::clone(&next);
            std::thread::Builder::new()
                .name(format!("bench-detect-{i}"))
                .spawn(move || {
                    let mut out = Vec::new();
                    loop {
                        let k = next.fetch_add(1, Ordering::Relaxed);
                        let Some(frame) = frames.get(k) else { break };
                        detector.detect(frame, &mut out).expect("detect");
                    }
                })
                .expect("thread")
        })
        .collect();
    for handle in handles {
        handle.join().expect("worker");
    }
    frames.len() as f64 / started.elapsed().as_secs_f64()
}

fn bench_detector(c: &mut Criterion) {
    if !shared().join("models/yolox_nano/yolox_nano.onnx").is_file() {
        println!("skipped: the shared data ({}) is absent", shared().display());
        return;
    }
    let runtime = OnnxRuntime::init(&OnnxConfig::default()).expect("ONNX Runtime (run ./scripts/setup-models.sh)");
    let all = frames(181);
    let frame = all.last().expect("frame 180").clone();

    let mut group = c.benchmark_group("yolox");
    group.measurement_time(Duration::from_secs(5)).sample_size(50);
    let mut model = YoloxModel::new(&runtime, &config()).expect("YOLOX");
    group.bench_function("inference", |b| {
        b.iter(|| model.infer(&frame.rgb, frame.intrinsics.width, frame.intrinsics.height).expect("infer"))
    });
    let mut detector = YoloxDetector::new(&runtime, &config()).expect("YOLOX");
    let mut out = Vec::new();
    group.bench_function("detect", |b| b.iter(|| detector.detect(&frame, &mut out).expect("detect")));
    group.finish();

    // session.run alone, timed like the Python script (median of 200 after 3 warm-up runs).
    let mut times: Vec<f64> = (0..203)
        .map(|_| {
            let t = Instant::now();
            model.infer(&frame.rgb, frame.intrinsics.width, frame.intrinsics.height).expect("infer");
            t.elapsed().as_secs_f64() * 1e3
        })
        .skip(3)
        .collect();
    times.sort_by(f64::total_cmp);
    println!(
        "yolox inference (letterbox + run + copy out): median {:.3} ms, min {:.3} ms over 200",
        times[100], times[0]
    );

    // The letterbox alone, to compare session.run with session.run.
    let mut input = Vec::new();
    let mut letterbox_ms: Vec<f64> = (0..200)
        .map(|_| {
            let t = Instant::now();
            op3dsg_daemon::perception::yolox::letterbox(
                &frame.rgb,
                frame.intrinsics.width,
                frame.intrinsics.height,
                416,
                &mut input,
            );
            t.elapsed().as_secs_f64() * 1e3
        })
        .collect();
    letterbox_ms.sort_by(f64::total_cmp);
    println!(
        "letterbox alone: median {:.3} ms; inference without it: about {:.3} ms",
        letterbox_ms[100],
        times[100] - letterbox_ms[100]
    );
    println!(
        "load average now (2 shared cores): {}",
        std::fs::read_to_string("/proc/loadavg").unwrap_or_default().trim()
    );

    let sample: Arc<Vec<Frame>> = Arc::new(all.into_iter().take(THROUGHPUT_FRAMES).collect());
    for workers in [1, 2] {
        let fps = throughput(&runtime, &sample, workers);
        println!("yolox detection throughput, {workers} worker(s), own session each: {fps:.1} frames/s");
    }
}

criterion_group!(benches, bench_detector);
criterion_main!(benches);
