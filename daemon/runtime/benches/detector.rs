//! YOLOX-nano detection cost on real frames (ICL-NUIM living room 1):
//! - `yolox/inference`: letterbox + one `session.run` of a single session (one intra-op thread),
//!   per frame; compare with `scripts/reference/yolox_reference.py 180 --time 200`, onnxruntime's
//!   Python API on the same model, input and thread count (session.run only);
//! - `yolox/detect`: the whole detector (inference, decoding, NMS, class map, masks from depth);
//! - then, printed: detection throughput (frames/s) of 1 and 2 worker threads, each owning its
//!   own session, sharing the first 60 frames of the sequence (as the daemon's worker pool does),
//!   whole frames and with `profiles/replay-icl.toml`'s 2x2 tiles;
//! - with `OP3DSG_REFERENCE_PYTHON` set to a Python command that has `onnxruntime` and `numpy`
//!   (e.g. `env PYTHONPATH=/tmp/ortpy python3`), onnxruntime's Python API timed on the very same
//!   pixels in the same run, between two Rust timings, and the speed ratio.
//!
//! `cargo bench -p op3dsg-runtime --bench detector` (needs `.models/` from
//! `./scripts/setup-models.sh` and the shared development data; prints why and does nothing
//! without them).

use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use criterion::{Criterion, criterion_group, criterion_main};
use op3dsg_drivers::frame::Frame;
use op3dsg_drivers::replay::{PlaybackMode, ReplayConfig, ReplaySource};
use op3dsg_drivers::source::{FrameSource, SourceStatus};
use op3dsg_runtime::onnx::{OnnxConfig, OnnxRuntime};
use op3dsg_runtime::perception::Detector;
use op3dsg_runtime::perception::yolox::{YoloxConfig, YoloxDetector, YoloxModel};

const THROUGHPUT_FRAMES: usize = 60;

fn shared() -> PathBuf {
    op3dsg_shared_data::shared_data_dir()
}

/// The Python reference's `session.run median X ms`, run on `rgb` (a raw 640x480x3 dump).
fn python_reference_ms(command: &str, rgb: &[u8]) -> Option<f64> {
    let dump = std::env::temp_dir().join(format!("op3dsg-bench-frame-{}.rgb", std::process::id()));
    std::fs::write(&dump, rgb).ok()?;
    let script = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../scripts/reference/yolox_reference.py");
    let mut words = command.split_whitespace();
    let output = std::process::Command::new(words.next()?)
        .args(words)
        .arg(&script)
        .args(["180", "--time", "200", "--rgb"])
        .arg(&dump)
        .output();
    let _ = std::fs::remove_file(&dump);
    let output = output.ok()?;
    let text = String::from_utf8_lossy(&output.stdout);
    let line = text.lines().find(|l| l.contains("session.run median"))?;
    let ms = line.split("session.run median ").nth(1)?.split(" ms").next()?.parse().ok();
    if ms.is_none() || !output.status.success() {
        println!("python reference failed: {}", String::from_utf8_lossy(&output.stderr));
    }
    ms
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
    let mut frame = Frame::new(source.intrinsics());
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
fn throughput(runtime: &OnnxRuntime, frames: &Arc<Vec<Frame>>, workers: usize, config: &YoloxConfig) -> f64 {
    let detectors: Vec<YoloxDetector> =
        (0..workers).map(|_| YoloxDetector::new(runtime, config).expect("YOLOX")).collect();
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
    let mut rust_inference_ms = || {
        let mut times: Vec<f64> = (0..203)
            .map(|_| {
                let t = Instant::now();
                model.infer(&frame.rgb, frame.intrinsics.width, frame.intrinsics.height).expect("infer");
                t.elapsed().as_secs_f64() * 1e3
            })
            .skip(3)
            .collect();
        times.sort_by(f64::total_cmp);
        (times[100], times[0])
    };
    let (median, min) = rust_inference_ms();
    println!("yolox inference (letterbox + run + copy out): median {median:.3} ms, min {min:.3} ms over 200");

    // The letterbox alone, to compare session.run with session.run.
    let mut input = Vec::new();
    let mut letterbox_ms: Vec<f64> = (0..200)
        .map(|_| {
            let t = Instant::now();
            op3dsg_runtime::perception::yolox::letterbox(
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
    let letterbox = letterbox_ms[100];
    println!("letterbox alone: median {letterbox:.3} ms; inference without it: about {:.3} ms", median - letterbox);
    if let Ok(command) = std::env::var("OP3DSG_REFERENCE_PYTHON") {
        match python_reference_ms(&command, &frame.rgb) {
            Some(python) => {
                let (again, _) = rust_inference_ms();
                let rust_run = (median.min(again) - letterbox).max(1e-6);
                println!(
                    "onnxruntime Python session.run median {python:.3} ms; ours (session.run, best of the two timings around it) {rust_run:.3} ms; our speed = {:.3} x Python's",
                    python / rust_run
                );
            }
            None => println!("OP3DSG_REFERENCE_PYTHON={command}: no timing from scripts/reference/yolox_reference.py"),
        }
    }
    println!(
        "load average now (2 shared cores): {}",
        std::fs::read_to_string("/proc/loadavg").unwrap_or_default().trim()
    );

    let sample: Arc<Vec<Frame>> = Arc::new(all.into_iter().take(THROUGHPUT_FRAMES).collect());
    let tiled = YoloxConfig { tiles: [2, 2], tile_overlap: 0.25, ..config() };
    for (name, config) in [("whole frame", config()), ("2x2 tiles + whole frame", tiled)] {
        for workers in [1, 2] {
            let fps = throughput(&runtime, &sample, workers, &config);
            println!("yolox detection throughput, {name}, {workers} worker(s), own session each: {fps:.1} frames/s");
        }
    }
}

criterion_group!(benches, bench_detector);
criterion_main!(benches);
