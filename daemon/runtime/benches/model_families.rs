//! CPU cost of the open-vocabulary detector on a real-size YOLO-World-S stand-in
//! (`.models/standins/yolo_world_s_like.onnx`, written by `./scripts/setup-standins.sh` with
//! `scripts/reference/yolo_world_s_like.py`: YOLOv8-S's convolution stack at 640 x 640 with the
//! text-contrastive head, random weights, 11.35 M parameters, 14.8 GMACs): the whole `detect`
//! (letterbox of a 640 x 480 frame, one `session.run`, decoding of 8400 x P scores, NMS, masks
//! from depth) for 20 prompts, with 1 and 2 ONNX Runtime intra-op threads. The prompts' CLIP
//! features are computed once at start (the CLIP text stand-in), as on the robot.
//!
//! Then the region encoder on a real-size CLIP ViT-B/32 stand-in (below).
//!
//! `cargo bench -p op3dsg-runtime --bench model_families` (needs `./scripts/setup-models.sh` and
//! `./scripts/setup-standins.sh`; prints what to run and does nothing without them).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use criterion::{Criterion, criterion_group, criterion_main};
use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_runtime::knowledge::KnowledgeBase;
use op3dsg_runtime::onnx::clip_text::ClipTextConfig;
use op3dsg_runtime::onnx::text_encoder::TextEncoderConfig;
use op3dsg_runtime::onnx::{OnnxConfig, OnnxRuntime};
use op3dsg_runtime::perception::Detector;
use op3dsg_runtime::perception::candidates::CandidateMode;
use op3dsg_runtime::perception::open_vocab::{Family, OpenVocabConfig, OpenVocabDetector, PromptConfig};

const PROMPTS: [&str; 20] = [
    "chair",
    "table",
    "sofa",
    "cabinet",
    "drawer",
    "door",
    "refrigerator",
    "sink",
    "tv",
    "bed",
    "shelf",
    "lamp",
    "window",
    "curtain",
    "plant",
    "vase",
    "book",
    "cup",
    "bottle",
    "pillow",
];

fn standins() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../.models/standins")
}

fn frame() -> Frame {
    let intrinsics = Intrinsics { width: 640, height: 480, fx: 480.0, fy: 480.0, cx: 320.0, cy: 240.0 };
    let mut frame = Frame::new(intrinsics);
    frame.rgb.iter_mut().enumerate().for_each(|(i, v)| *v = ((i * 7) % 251) as u8);
    frame.depth.iter_mut().enumerate().for_each(|(i, d)| *d = 1000 + (i % 640) as u16);
    frame
}

fn bench(c: &mut Criterion) {
    let model = standins().join("yolo_world_s_like.onnx");
    let clip = standins().join("clip_text.onnx");
    if !model.is_file() || !clip.is_file() {
        println!("{} missing: run ./scripts/setup-models.sh && ./scripts/setup-standins.sh", model.display());
        return;
    }
    let runtime = match OnnxRuntime::init(&OnnxConfig::default()) {
        Ok(r) => r,
        Err(e) => {
            println!("{e}");
            return;
        }
    };
    let frame = frame();
    let mut group = c.benchmark_group("yolo_world_s_like");
    group.sample_size(10).measurement_time(Duration::from_secs(12)).warm_up_time(Duration::from_secs(3));
    for threads in [1usize, 2] {
        let config = OpenVocabConfig {
            family: Family::YoloWorld,
            model_path: model.clone(),
            clip: ClipTextConfig { model_path: clip.clone(), ..ClipTextConfig::default() },
            prompts: PromptConfig {
                objects: PROMPTS.iter().map(|p| (*p).to_owned()).collect(),
                part_prompts: CandidateMode::All,
                ..PromptConfig::default()
            },
            score_threshold: 0.05,
            intra_op_threads: threads,
            ..OpenVocabConfig::default()
        };
        let knowledge = Arc::new(KnowledgeBase::builtin().expect("built-in knowledge base"));
        let mut detector = match OpenVocabDetector::new(&runtime, &config, knowledge, &TextEncoderConfig::default()) {
            Ok(d) => d,
            Err(e) => {
                println!("{e}");
                return;
            }
        };
        let mut out = Vec::new();
        group.bench_function(format!("detect_20_prompts_{threads}_threads"), |b| {
            b.iter(|| detector.detect(&frame, &mut out).expect("detects"))
        });
    }
    group.finish();
    region_encoder(c, &runtime, &frame);
}

/// The region encoder on a real-size CLIP ViT-B/32 stand-in (`clip_vit_b32_like.onnx`, written
/// on demand by `scripts/reference/clip_vit_b32_like.py`: 87.8 M parameters, 4.4 GMACs): one
/// detection's crop (a 120 x 160 mask box with 20 pixels of padding), letterboxed to 224 x 224,
/// one `session.run`, normalised. Fusion pays this once per detection.
fn region_encoder(c: &mut Criterion, runtime: &OnnxRuntime, frame: &Frame) {
    use op3dsg_runtime::perception::Mask;
    use op3dsg_runtime::perception::region_encoder::{RegionEncoder, RegionEncoderConfig};
    let model = standins().join("clip_vit_b32_like.onnx");
    if !model.is_file() {
        println!(
            "{} missing: run .venv/bin/python scripts/reference/clip_vit_b32_like.py (350 MB) for the region encoder's cost",
            model.display()
        );
        return;
    }
    let mask = Mask { x0: 200, y0: 150, width: 160, height: 120, data: vec![1; 160 * 120] };
    let mut group = c.benchmark_group("clip_vit_b32_like");
    group.sample_size(10).measurement_time(Duration::from_secs(10)).warm_up_time(Duration::from_secs(3));
    for threads in [1usize, 2] {
        let config =
            RegionEncoderConfig { path: model.clone(), intra_op_threads: threads, ..RegionEncoderConfig::default() };
        let mut encoder = match RegionEncoder::new(runtime, &config, "detector.region_encoder") {
            Ok(e) => e,
            Err(e) => {
                println!("{e}");
                return;
            }
        };
        group.bench_function(format!("encode_one_crop_{threads}_threads"), |b| {
            b.iter(|| encoder.encode(frame, &mask).expect("encodes").expect("a feature"))
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
