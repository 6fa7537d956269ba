//! YOLOX-nano in Rust against onnxruntime's Python API on the same frame
//! (`scripts/reference/yolox_reference.py`, output pasted below): same decoded pixels, same
//! letterbox input, same raw output rows, same boxes and scores after decoding and NMS.
//!
//! Needs `.models/` (ONNX Runtime; `./scripts/setup-models.sh`) and the shared development data
//! (`../shared/data/models/yolox_nano/`, `../shared/data/rgbd/icl_livingroom1/`); without the
//! shared data the tests print why and pass without checking.

use std::path::PathBuf;

use op3dsg_runtime::onnx::{ExecutionProvider, OnnxConfig, OnnxRuntime};
use op3dsg_runtime::perception::yolox::{YoloxConfig, YoloxModel, coco_classes, letterbox, postprocess};

fn shared() -> PathBuf {
    op3dsg_shared_data::shared_data_dir()
}

fn model_path() -> PathBuf {
    shared().join("models/yolox_nano/yolox_nano.onnx")
}

fn frame_path(index: u32) -> PathBuf {
    shared().join(format!("rgbd/icl_livingroom1/rgb/{index:05}.jpg"))
}

/// Whether the model and the frames are there (in CI a missing file fails the test).
fn available() -> bool {
    op3dsg_shared_data::shared_data("models/yolox_nano/yolox_nano.onnx").is_some()
        && op3dsg_shared_data::shared_data("rgbd/icl_livingroom1/rgb/00180.jpg").is_some()
}

/// Decodes a frame exactly as the replay source does (the `image` crate's JPEG decoder, whose
/// pixels differ slightly from PIL's libjpeg). With `YOLOX_REFERENCE_RGB_OUT=file` set, the
/// pixels are also written there, for `yolox_reference.py --rgb file`.
fn rgb(index: u32) -> Vec<u8> {
    let pixels = image::open(frame_path(index)).expect("decodes").to_rgb8().into_raw();
    if let Some(out) = std::env::var_os("YOLOX_REFERENCE_RGB_OUT") {
        std::fs::write(out, &pixels).expect("writes the pixel dump");
    }
    pixels
}

// YOLOX_REFERENCE_RGB_OUT=/tmp/frame180.rgb cargo test -p op3dsg-runtime --test it yolox::, then
// PYTHONPATH=/tmp/ortpy python3 scripts/reference/yolox_reference.py 180 --rgb /tmp/frame180.rgb
// (onnxruntime 1.31.1):
// # frame 180: rgb byte sum 162981271
// # letterbox r = np.float32(0.65), input sum = 83657774.0
// # raw rows of the kept anchors: (anchor, first 6 values)
// #   3452: [0.41144993901252747, 0.038589805364608765, 1.6950289011001587, 1.865971326828003, 0.8507084250450134, 2.8908252716064453e-06]
// #   3440: [-0.6390081644058228, 1.0564253330230713, 1.7027125358581543, 1.8757340908050537, 0.7405076026916504, 1.6361474990844727e-05]
// // (class, score, [x0, y0, x1, y1]) from scripts/reference/yolox_reference.py
//     (59, 0.6273113, [230.7962, 88.9839, 498.9466, 407.1235]), // bed, anchor 3452
//     (56, 0.5023745, [227.278, 88.3014, 497.4966, 409.5621]), // chair, anchor 3440
// (PIL's own JPEG decoding of the frame gives a byte sum of 162977234 and scores 0.6245 / 0.5111.)
const FRAME: u32 = 180;
const RGB_BYTE_SUM: u64 = 162_981_271;
const INPUT_SUM: f64 = 83_657_774.0;
const RAW_ROWS: [(usize, [f32; 6]); 2] = [
    (3452, [0.411_449_94, 0.038_589_805, 1.695_028_9, 1.865_971_3, 0.850_708_4, 2.890_825_3e-6]),
    (3440, [-0.639_008_16, 1.056_425_3, 1.702_712_5, 1.875_734_1, 0.740_507_6, 1.636_147_5e-5]),
];
// (class, score, [x0, y0, x1, y1]) at thresholds 0.3 (score) and 0.45 (IoU).
const BOXES: [(usize, f32, [f32; 4]); 2] = [
    (59, 0.627_311_3, [230.7962, 88.9839, 498.9466, 407.1235]), // bed, anchor 3452
    (56, 0.502_374_5, [227.278, 88.3014, 497.4966, 409.5621]),  // chair, anchor 3440
];

#[test]
fn decoded_pixels_and_letterbox_match_the_python_reference() {
    if !available() {
        return;
    }
    let pixels = rgb(FRAME);
    assert_eq!(pixels.len(), 640 * 480 * 3);
    let sum: u64 = pixels.iter().map(|&v| u64::from(v)).sum();
    assert_eq!(sum, RGB_BYTE_SUM, "not the pixels the reference ran on");
    let mut input = Vec::new();
    let r = letterbox(&pixels, 640, 480, 416, &mut input);
    assert_eq!(r, 0.65);
    let input_sum: f64 = input.iter().map(|&v| f64::from(v)).sum();
    assert_eq!(input_sum, INPUT_SUM);
}

#[test]
fn yolox_matches_onnxruntime_python_on_an_icl_frame() {
    if !available() {
        return;
    }
    let runtime = OnnxRuntime::init(&OnnxConfig::default()).expect("ONNX Runtime (run ./scripts/setup-models.sh)");
    let config = YoloxConfig { model_path: model_path(), ..YoloxConfig::default() };
    let mut model = YoloxModel::new(&runtime, &config).expect("model loads");
    let pixels = rgb(FRAME);
    let r = model.infer(&pixels, 640, 480).unwrap();
    let raw = model.raw_output();
    assert_eq!(raw.len(), 3549 * 85);
    for (anchor, values) in RAW_ROWS {
        for (k, &v) in values.iter().enumerate() {
            let got = raw[anchor * 85 + k];
            assert!((got - v).abs() <= 1e-5 * v.abs().max(1.0), "anchor {anchor} value {k}: {got} vs {v}");
        }
    }
    let boxes = postprocess(raw, 416, 80, r, config.score_threshold, config.nms_iou_threshold, config.max_detections);
    let classes = coco_classes();
    let got: Vec<_> = boxes.iter().map(|b| (classes[b.class], b.score, b.bbox)).collect();
    assert_eq!(boxes.len(), BOXES.len(), "{got:?}");
    for (b, (class, score, bbox)) in boxes.iter().zip(BOXES) {
        assert_eq!(b.class, class, "{got:?}");
        assert!((b.score - score).abs() < 1e-5, "{got:?}");
        for (got_k, want_k) in b.bbox.iter().zip(bbox) {
            assert!((got_k - want_k).abs() < 1e-3, "{got:?}");
        }
    }
    // The same through the one-call path.
    let again = model.detect_boxes(&pixels, 640, 480, 0.3, 0.45, 100).unwrap();
    assert_eq!(again, boxes);
}

#[test]
fn a_missing_model_says_which_key_and_what_to_run() {
    let Ok(runtime) = OnnxRuntime::init(&OnnxConfig::default()) else {
        println!("skipped: no ONNX Runtime in .models/");
        return;
    };
    let config = YoloxConfig { model_path: PathBuf::from("/no/such/yolox.onnx"), ..YoloxConfig::default() };
    let err = YoloxModel::new(&runtime, &config).unwrap_err().to_string();
    assert!(err.contains("/no/such/yolox.onnx") && err.contains("detector.yolox.model_path"), "{err}");
    assert!(err.contains("YOLOX-nano") && !err.contains("setup-models.sh"), "says where the model comes from: {err}");
}

#[test]
fn an_unavailable_execution_provider_falls_back_to_the_cpu() {
    if !available() {
        return;
    }
    // The PyPI `onnxruntime` library in .models/ has neither CUDA nor OpenVINO, and this build
    // may lack the cargo features too: either way the session runs on the CPU, with a warning,
    // and detects exactly as a CPU session does.
    let runtime = OnnxRuntime::init(&OnnxConfig::default()).expect("ONNX Runtime");
    let pixels = rgb(FRAME);
    for provider in [ExecutionProvider::Cuda, ExecutionProvider::Openvino] {
        let config =
            YoloxConfig { model_path: model_path(), execution_provider: Some(provider), ..YoloxConfig::default() };
        let mut model = YoloxModel::new(&runtime, &config).expect("loads on the CPU instead");
        assert_eq!(model.provider(), ExecutionProvider::Cpu, "{provider:?}");
        let boxes = model.detect_boxes(&pixels, 640, 480, 0.3, 0.45, 100).unwrap();
        assert_eq!(boxes.len(), BOXES.len(), "{provider:?}: {boxes:?}");
    }
}

#[test]
fn a_sam_mask_decoder_replaces_the_depth_masks() {
    if !available() {
        return;
    }
    let standins = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../.models/standins");
    let decoder = op3dsg_runtime::perception::mask_decoder::MaskDecoderConfig {
        encoder_path: standins.join("sam_encoder.onnx"),
        decoder_path: standins.join("sam_decoder.onnx"),
        ..Default::default()
    };
    assert!(decoder.decoder_path.is_file(), "run ./scripts/setup-standins.sh");
    let runtime = OnnxRuntime::init(&OnnxConfig::default()).expect("ONNX Runtime (run ./scripts/setup-models.sh)");
    let mut class_map = std::collections::BTreeMap::new();
    for class in coco_classes() {
        class_map.insert((*class).to_owned(), (*class).to_owned());
    }
    let config =
        YoloxConfig { model_path: model_path(), class_map, mask_decoder: Some(decoder), ..YoloxConfig::default() };
    let mut detector = op3dsg_runtime::perception::yolox::YoloxDetector::new(&runtime, &config).expect("loads");
    let intrinsics =
        op3dsg_drivers::frame::Intrinsics { width: 640, height: 480, fx: 481.2, fy: 480.0, cx: 319.5, cy: 239.5 };
    let mut frame = op3dsg_drivers::frame::Frame::new(intrinsics);
    frame.rgb = rgb(FRAME);
    // No depth at all: depth masks would give nothing; the stand-in decoder answers the top
    // half of each box it is prompted with.
    let mut out = Vec::new();
    op3dsg_runtime::perception::Detector::detect(&mut detector, &frame, &mut out).unwrap();
    assert!(!out.is_empty());
    // A calibration maps the published scores (the threshold stays on the raw ones).
    let calibration = op3dsg_runtime::perception::ScoreCalibration {
        kind: op3dsg_runtime::perception::CalibrationKind::Affine,
        a: 0.5,
        b: 0.5,
    };
    let calibrated = YoloxConfig { calibration, ..config.clone() };
    let mut detector = op3dsg_runtime::perception::yolox::YoloxDetector::new(&runtime, &calibrated).expect("loads");
    let mut lifted = Vec::new();
    op3dsg_runtime::perception::Detector::detect(&mut detector, &frame, &mut lifted).unwrap();
    assert_eq!(lifted.len(), out.len());
    for (raw, cal) in out.iter().zip(&lifted) {
        assert!((cal.score - (0.5 * raw.score + 0.5)).abs() < 1e-6, "{} {}", raw.score, cal.score);
    }
    for d in &out {
        let m = &d.mask;
        // The stand-in cuts at the float box; the pixel box rounds outwards: a pixel of slack.
        let half = f64::from(m.width * m.height) / 2.0;
        let area = m.area() as f64;
        let slack = f64::from(m.width + m.height) * 1.5;
        assert!((area - half).abs() <= slack, "{}: area {area}, half the box {half}", d.label);
        let cx = m.x0 + m.width / 2;
        assert!(m.contains(cx, m.y0 + 1) && !m.contains(cx, m.y0 + m.height - 1), "{}", d.label);
    }
}
