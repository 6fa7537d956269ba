//! The open-vocabulary detector adapter through ONNX Runtime on a model with the documented
//! contract and known answers (`daemon/tests/data/open_vocab_fixture.onnx`, written by
//! `scripts/reference/open_vocab_fixture.py`): prompts encoded by the real MiniLM text encoder,
//! boxes mapped back through the letterbox, prompt indices to labels and kinds, masks from the
//! model's mask output, region embeddings as semantic features; the `[N, P]` score variant; and
//! a model that does not match the profile's contract is refused with the key that is wrong.
//!
//! Needs `.models/` (`./scripts/setup-models.sh`).

use std::path::PathBuf;
use std::sync::Arc;

use op3dsg_drivers::frame::{Frame, Intrinsics};
use op3dsg_ipc_types::NodeKind;
use op3dsg_runtime::knowledge::KnowledgeBase;
use op3dsg_runtime::onnx::text_encoder::{TextEncoder, TextEncoderConfig};
use op3dsg_runtime::onnx::{OnnxConfig, OnnxRuntime};
use op3dsg_runtime::perception::candidates::CandidateMode;
use op3dsg_runtime::perception::image_input::ImageInput;
use op3dsg_runtime::perception::open_vocab::{OpenVocabConfig, OpenVocabDetector, OutputNames, PromptConfig};
use op3dsg_runtime::perception::{Detection, Detector};

fn fixture() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/data/open_vocab_fixture.onnx")
}

fn encoder_config() -> TextEncoderConfig {
    TextEncoderConfig { enabled: true, ..TextEncoderConfig::default() }
}

fn config() -> OpenVocabConfig {
    OpenVocabConfig {
        model_path: fixture(),
        input: ImageInput { width: 64, height: 64, ..ImageInput::default() },
        outputs: OutputNames {
            masks: Some("masks".into()),
            region_embeddings: Some("region_embeddings".into()),
            ..OutputNames::default()
        },
        prompts: PromptConfig {
            objects: vec!["cabinet".into(), "stove".into()],
            part_prompts: CandidateMode::All,
            ..PromptConfig::default()
        },
        ..OpenVocabConfig::default()
    }
}

/// A 128 x 96 frame (letterboxed at r = 0.5 into the 64 x 64 input), no depth.
fn frame() -> Frame {
    let intrinsics = Intrinsics { width: 128, height: 96, fx: 100.0, fy: 100.0, cx: 64.0, cy: 48.0 };
    let mut frame = Frame::new(intrinsics);
    frame.rgb.iter_mut().enumerate().for_each(|(i, v)| *v = (i % 251) as u8);
    frame
}

fn detect(config: &OpenVocabConfig) -> (Vec<Detection>, OpenVocabDetector) {
    let runtime = OnnxRuntime::init(&OnnxConfig::default()).expect("ONNX Runtime (run ./scripts/setup-models.sh)");
    let knowledge = Arc::new(KnowledgeBase::builtin().expect("built-in knowledge base"));
    let mut detector = OpenVocabDetector::new(&runtime, config, knowledge, &encoder_config()).expect("loads");
    let mut out = Vec::new();
    detector.detect(&frame(), &mut out).expect("detects");
    (out, detector)
}

#[test]
fn regions_become_labelled_masked_detections_in_image_pixels() {
    let (out, _) = detect(&config());
    // Regions answer prompts 1, 0, 1 with scores 0.9, 0.6, 0.2; 0.2 is under the threshold.
    assert_eq!(out.len(), 2, "{out:?}");
    let (stove, cabinet) = (&out[0], &out[1]);
    assert_eq!((stove.label.as_str(), stove.kind), ("stove", NodeKind::Object));
    assert_eq!((cabinet.label.as_str(), cabinet.kind), ("cabinet", NodeKind::Object));
    assert!(
        (stove.score - 0.9).abs() < 1e-4 && (cabinet.score - 0.6).abs() < 1e-4,
        "{} {}",
        stove.score,
        cabinet.score
    );
    // Box 0, input [8, 8, 24, 40] → image [16, 16, 48, 80]; its mask is the box's top half.
    let m = &stove.mask;
    assert_eq!((m.x0, m.y0, m.width, m.height), (16, 16, 32, 64));
    assert_eq!(m.area(), 32 * 32);
    assert!(m.contains(16, 16) && m.contains(47, 47) && !m.contains(20, 48));
    // Box 1, input [30, 10, 60, 30] → image [60, 20, 120, 60]; the mask (cells of 8 image
    // pixels) covers image rows 16..56 of it.
    let m = &cabinet.mask;
    assert_eq!((m.x0, m.y0, m.width, m.height), (60, 20, 60, 40));
    assert_eq!(m.area(), 60 * 36);
    // Region embeddings are the prompts' own embeddings here: the semantic feature of the
    // stove detection is MiniLM's embedding of "stove".
    let mut encoder = TextEncoder::new(&OnnxRuntime::init(&OnnxConfig::default()).unwrap(), &encoder_config()).unwrap();
    let expected = encoder.encode("stove").unwrap();
    let feature = stove.semantic_feature.as_ref().expect("region embedding");
    let cosine: f32 = feature.iter().zip(expected.iter()).map(|(a, b)| a * b).sum();
    assert!(cosine > 0.9999, "cosine {cosine}");
}

#[test]
fn a_score_matrix_is_decoded_like_scores_with_prompt_indices() {
    let mut matrix = config();
    matrix.outputs.scores = "similarity".into();
    matrix.outputs.prompt_index = None;
    let (a, _) = detect(&config());
    let (b, _) = detect(&matrix);
    let summary = |d: &[Detection]| {
        d.iter().map(|d| (d.label.clone(), (d.score * 1e4).round(), d.mask.area())).collect::<Vec<_>>()
    };
    assert_eq!(summary(&a), summary(&b));
}

#[test]
fn knowledge_guided_parts_extend_the_prompts_the_model_sees() {
    let mut guided = config();
    guided.prompts.part_prompts = CandidateMode::Knowledge;
    let (out, detector) = detect(&guided);
    let texts: Vec<&str> = detector.prompts().iter().map(|p| p.text.as_str()).collect();
    assert!(texts.contains(&"cabinet handle") && texts.contains(&"stove knob"), "{texts:?}");
    let generated =
        detector.prompts().iter().filter(|p| p.text.starts_with("cabinet ") || p.text.starts_with("stove "));
    assert!(generated.clone().count() >= 3 && generated.clone().all(|p| p.kind == NodeKind::Part));
    // The model still answers prompts 1 and 0 (the objects).
    assert_eq!(out.iter().map(|d| d.label.as_str()).collect::<Vec<_>>(), ["stove", "cabinet"]);
}

#[test]
fn a_model_that_breaks_the_contract_is_refused_naming_the_key() {
    let runtime = OnnxRuntime::init(&OnnxConfig::default()).expect("ONNX Runtime");
    let knowledge = Arc::new(KnowledgeBase::builtin().unwrap());
    let mut wrong = config();
    wrong.outputs.boxes = "detections".into();
    let err = OpenVocabDetector::new(&runtime, &wrong, knowledge.clone(), &encoder_config()).unwrap_err().to_string();
    assert!(err.contains("\"detections\"") && err.contains("detector.open_vocab.outputs.boxes"), "{err}");
    assert!(
        err.contains("open_vocab_fixture.onnx") && err.contains("\"region_embeddings\""),
        "lists the outputs: {err}"
    );

    let mut wrong = config();
    wrong.input.name = "pixel_values".into();
    let err = OpenVocabDetector::new(&runtime, &wrong, knowledge.clone(), &encoder_config()).unwrap_err().to_string();
    assert!(err.contains("detector.open_vocab.input.name"), "{err}");

    let err =
        OpenVocabDetector::new(&runtime, &config(), knowledge, &TextEncoderConfig::default()).unwrap_err().to_string();
    assert!(err.contains("text_encoder.enabled"), "{err}");
}

#[test]
fn the_detector_plugs_into_the_daemon_by_profile_alone() {
    // A profile file naming the model, its contract and prompts, run through the batch runner
    // (which opens detectors exactly as the daemon does) on the synthetic kitchen.
    let dir = tempfile::tempdir().unwrap();
    let profile_path = dir.path().join("open-vocab.toml");
    std::fs::write(
        &profile_path,
        format!(
            r#"
[source]
rate_hz = 0.0
[source.synthetic]
frame_count = 12

[detector]
kind = "open_vocab"
workers = 1

[detector.open_vocab]
model_path = "{model}"
prompts = {{ objects = ["cabinet", "stove"], part_prompts = "knowledge" }}
input = {{ width = 64, height = 64, colour_order = "rgb", resize = "letterbox", scale = 0.00392157 }}
outputs = {{ boxes = "boxes", scores = "scores", prompt_index = "prompt_index", masks = "masks", region_embeddings = "region_embeddings" }}

[text_encoder]
enabled = true
"#,
            model = fixture().display()
        ),
    )
    .unwrap();
    let profile = op3dsg_sim::load_profile(Some(&profile_path), &[]).expect("profile").profile;
    let run = op3dsg_sim::batch::run(&profile, &op3dsg_sim::batch::VisibilityThresholds::default()).expect("runs");
    println!("{} keyframes, {} detections, {} nodes", run.keyframes, run.detections, run.graph.nodes.len());
    assert_eq!(run.detector_errors, 0);
    assert_eq!(run.detections, 2 * run.keyframes, "two regions above threshold per keyframe");
    assert!(run.keyframes >= 2);
}
