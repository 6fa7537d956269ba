//! The text encoder on the real model: all-MiniLM-L6-v2 int8 through ONNX Runtime 1.31, against
//! the values onnxruntime's Python API gives for the same files
//! (`scripts/reference/text_encoder_reference.py`, output pasted below).
//!
//! These tests need `.models/` (`./scripts/test.sh` runs `./scripts/setup-models.sh` first).
//! Without it they fail with the error that says to run it; they never skip.

use op3dsg_runtime::embedding::{EMBEDDING_DIM, Embedding, cosine};
use op3dsg_runtime::onnx::text_encoder::{TextEncoder, TextEncoderConfig};
use op3dsg_runtime::onnx::{OnnxConfig, OnnxError, OnnxRuntime};

// scripts/reference/text_encoder_reference.py, onnxruntime 1.31.1, each label encoded alone:
//   cos('red chair', 'crimson seat') = 0.582892
//   cos('red chair', 'red chair') = 1.000000
//   cos('cabinet handle', 'drawer handle') = 0.741729
//   cos('cabinet handle', 'bathtub') = 0.214736
//   cos('refrigerator', 'fridge') = 0.964549
//   cos('light switch', 'power outlet') = 0.299602
//   cos('door knob', 'banana') = 0.269354
// 'red chair' first 8 values: 0.001113, 0.003523, -0.088530, 0.043037, -0.024631, 0.037394, 0.117901, -0.023510
// batch of 64 vs one at a time: max |diff| = 0.00e+00
const REFERENCE_COSINES: [(&str, &str, f32); 7] = [
    ("red chair", "crimson seat", 0.582892),
    ("red chair", "red chair", 1.0),
    ("cabinet handle", "drawer handle", 0.741729),
    ("cabinet handle", "bathtub", 0.214736),
    ("refrigerator", "fridge", 0.964549),
    ("light switch", "power outlet", 0.299602),
    ("door knob", "banana", 0.269354),
];
const RED_CHAIR_FIRST_8: [f32; 8] = [0.001113, 0.003523, -0.088530, 0.043037, -0.024631, 0.037394, 0.117901, -0.023510];

const LABELS: [&str; 12] = [
    "chair",
    "cabinet handle",
    "drawer handle",
    "refrigerator",
    "toilet flush button",
    "oven door handle",
    "a",
    "light switch",
    "picture frame",
    "remote control button",
    "bathtub",
    "stove knob",
];

fn runtime() -> OnnxRuntime {
    OnnxRuntime::init(&OnnxConfig::default()).unwrap_or_else(|e| panic!("{e}"))
}

fn encoder_with(config: TextEncoderConfig) -> TextEncoder {
    TextEncoder::new(&runtime(), &config).unwrap_or_else(|e| panic!("{e}"))
}

fn encoder() -> TextEncoder {
    encoder_with(TextEncoderConfig { enabled: true, ..TextEncoderConfig::default() })
}

fn max_abs_diff(a: &Embedding, b: &Embedding) -> f32 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f32::max)
}

fn norm(a: &Embedding) -> f32 {
    a.iter().map(|v| v * v).sum::<f32>().sqrt()
}

#[test]
fn cosines_match_onnxruntime_python() {
    let mut encoder = encoder();
    for (a, b, expected) in REFERENCE_COSINES {
        encoder.clear_cache();
        let ea = encoder.encode(a).unwrap_or_else(|e| panic!("{e}"));
        let eb = encoder.encode(b).unwrap_or_else(|e| panic!("{e}"));
        let got = cosine(&ea, &eb);
        eprintln!("cos({a:?}, {b:?}) = {got:.6} (Python {expected:.6})");
        assert!((got - expected).abs() < 1e-3, "cos({a:?}, {b:?}) = {got}, Python gave {expected}");
    }
}

#[test]
fn red_chair_and_crimson_seat_are_close_and_handles_are_closer_than_a_bathtub() {
    let mut encoder = encoder();
    let e = encoder
        .encode_batch(&["red chair", "crimson seat", "cabinet handle", "drawer handle", "bathtub"])
        .unwrap_or_else(|e| panic!("{e}"));
    let chair_seat = cosine(&e[0], &e[1]);
    assert!((chair_seat - 0.59).abs() < 0.02, "cos(red chair, crimson seat) = {chair_seat}");
    assert!(cosine(&e[2], &e[3]) > cosine(&e[2], &e[4]) + 0.3);
    assert!((cosine(&e[0], &e[0]) - 1.0).abs() < 1e-5);
}

#[test]
fn embedding_values_match_onnxruntime_python() {
    let mut encoder = encoder();
    let e = encoder.encode("red chair").unwrap_or_else(|e| panic!("{e}"));
    for (i, (got, want)) in e.iter().zip(RED_CHAIR_FIRST_8).enumerate() {
        assert!((got - want).abs() < 1e-4, "value {i}: {got}, Python gave {want}");
    }
    assert!((norm(&e) - 1.0).abs() < 1e-5);
}

#[test]
fn batch_gives_the_same_embeddings_as_one_at_a_time() {
    let mut encoder = encoder();
    let mut batched = Vec::new();
    encoder.encode_uncached_into(&LABELS, &mut batched).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(batched.len(), LABELS.len());
    let mut single = Vec::new();
    for (label, from_batch) in LABELS.iter().zip(&batched) {
        encoder.encode_uncached_into(&[label], &mut single).unwrap_or_else(|e| panic!("{e}"));
        let diff = max_abs_diff(&single[0], from_batch);
        // Padding is masked out, so only float rounding may differ (Python measured 0).
        assert!(diff < 1e-5, "{label:?}: batch and single differ by {diff}");
        assert!((norm(from_batch) - 1.0).abs() < 1e-5, "{label:?} not unit length");
    }
}

#[test]
fn cache_answers_repeats_without_running_the_model() {
    let mut encoder = encoder();
    let first = encoder.encode_batch(&["sink", "faucet", "sink", "faucet handle"]).unwrap_or_else(|e| panic!("{e}"));
    let stats = encoder.cache_stats();
    assert_eq!((stats.misses, stats.hits, stats.entries), (3, 1, 3), "{stats:?}");
    assert_eq!(first[0], first[2], "a repeat within the batch gets the same embedding");

    let again = encoder.encode_batch(&["faucet handle", "sink", "faucet", "mirror"]).unwrap_or_else(|e| panic!("{e}"));
    let stats = encoder.cache_stats();
    assert_eq!((stats.misses, stats.hits, stats.entries), (4, 4, 4), "{stats:?}");
    assert_eq!(again[0], first[3]);
    assert_eq!(again[1], first[0]);
    assert_eq!(again[2], first[1]);
    assert_eq!(encoder.encode("mirror").unwrap_or_else(|e| panic!("{e}")), again[3]);
    assert_eq!(encoder.cache_stats().hits, 5);

    // What the cache returns is what the model gives.
    let mut fresh = Vec::new();
    encoder.encode_uncached_into(&["faucet handle"], &mut fresh).unwrap_or_else(|e| panic!("{e}"));
    assert!(max_abs_diff(&fresh[0], &first[3]) < 1e-6);
}

#[test]
fn a_full_cache_is_emptied_and_counted() {
    let mut encoder = encoder_with(TextEncoderConfig { enabled: true, cache_capacity: 2, ..Default::default() });
    encoder.encode_batch(&["cup", "mug", "bowl"]).unwrap_or_else(|e| panic!("{e}"));
    let stats = encoder.cache_stats();
    assert_eq!((stats.misses, stats.clears, stats.entries), (3, 1, 1), "{stats:?}");

    let mut uncached = encoder_with(TextEncoderConfig { enabled: true, cache_capacity: 0, ..Default::default() });
    uncached.encode_batch(&["cup", "cup"]).unwrap_or_else(|e| panic!("{e}"));
    uncached.encode("cup").unwrap_or_else(|e| panic!("{e}"));
    let stats = uncached.cache_stats();
    assert_eq!((stats.misses, stats.entries), (2, 0), "{stats:?}");
}

#[test]
fn long_empty_and_odd_labels_encode_to_unit_vectors() {
    let long = "handle ".repeat(400);
    let mut encoder = encoder_with(TextEncoderConfig { enabled: true, max_sequence_length: 16, ..Default::default() });
    let labels = [long.as_str(), "", "Kühlschrank-Griff (links) #2", "🙂"];
    let embeddings = encoder.encode_batch(&labels).unwrap_or_else(|e| panic!("{e}"));
    for (label, e) in labels.iter().zip(&embeddings) {
        assert!((norm(e) - 1.0).abs() < 1e-5, "{label:?}: norm {}", norm(e));
        assert!(e.iter().all(|v| v.is_finite()));
    }
    // Truncated to 16 tokens: the same as a label of 14 words (plus [CLS] and [SEP]).
    let fourteen = "handle ".repeat(14);
    let short = encoder.encode(&fourteen).unwrap_or_else(|e| panic!("{e}"));
    assert!(max_abs_diff(&short, &embeddings[0]) < 1e-5);
}

#[test]
fn more_labels_than_one_model_call_takes() {
    let labels: Vec<String> = (0..150).map(|i| format!("object number {i}")).collect();
    let refs: Vec<&str> = labels.iter().map(String::as_str).collect();
    let mut encoder = encoder();
    let all = encoder.encode_batch(&refs).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(all.len(), 150);
    let one = encoder.encode("object number 149").unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(one, all[149]);
    assert_eq!(encoder.cache_stats().misses, 150);
}

#[test]
fn the_encoder_moves_to_its_worker_thread() {
    let mut encoder = encoder();
    let handle = std::thread::Builder::new()
        .name("op3dsg-test-encoder".into())
        .spawn(move || encoder.encode("kettle").map(|e| e.len()))
        .unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(handle.join().expect("worker panicked").unwrap_or_else(|e| panic!("{e}")), EMBEDDING_DIM);
}

#[test]
fn a_missing_model_names_the_file_and_the_setup_script() {
    let config = TextEncoderConfig { model_path: "no/such/model.onnx".into(), ..TextEncoderConfig::default() };
    let err = TextEncoder::new(&runtime(), &config).unwrap_err();
    assert!(matches!(err, OnnxError::FileMissing { .. }), "{err:?}");
    let text = err.to_string();
    assert!(text.starts_with("text encoder model (all-MiniLM-L6-v2 ONNX) not found: looked for "), "{text}");
    assert!(text.contains("no/such/model.onnx"), "{text}");
    assert!(text.contains("run ./scripts/setup-models.sh"), "{text}");
    assert!(text.contains("text_encoder.model_path"), "{text}");

    let config = TextEncoderConfig { tokenizer_path: "/no/such/tokenizer.json".into(), ..TextEncoderConfig::default() };
    let text = TextEncoder::new(&runtime(), &config).unwrap_err().to_string();
    assert!(text.contains("looked for /no/such/tokenizer.json;"), "{text}");
}

#[test]
fn a_file_that_is_not_a_model_is_an_error_naming_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let fake = dir.path().join("model.onnx");
    std::fs::write(&fake, b"not a model").expect("write");
    let config = TextEncoderConfig { model_path: fake.clone(), ..TextEncoderConfig::default() };
    let err = TextEncoder::new(&runtime(), &config).unwrap_err();
    assert!(matches!(err, OnnxError::Ort { .. }), "{err:?}");
    assert!(err.to_string().contains(&fake.display().to_string()), "{err}");
}
