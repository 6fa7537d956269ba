//! Text encoder cost: 1, 16 and 64 labels per call through all-MiniLM-L6-v2 int8 (tokenise,
//! run, pool, normalise; the cache bypassed), and a call answered from the cache. Criterion's
//! throughput is in labels, so its "elem/s" is labels per second; the per-label time is printed
//! after each group. Needs `.models/` (`./scripts/setup-models.sh`).
//!
//! `cargo bench -p op3dsg-runtime --bench text_encoder`
//! (compare: `scripts/reference/text_encoder_reference.py`, onnxruntime's Python API on the
//! same labels and thread count)

use std::time::{Duration, Instant};

use criterion::{BenchmarkId, Criterion, Throughput, criterion_group, criterion_main};
use op3dsg_runtime::onnx::text_encoder::{TextEncoder, TextEncoderConfig};
use op3dsg_runtime::onnx::{OnnxConfig, OnnxRuntime};

/// The same 64 labels as the Python reference script.
const LABELS: [&str; 64] = [
    "chair",
    "table",
    "sofa",
    "bed",
    "cabinet",
    "drawer",
    "door",
    "window",
    "refrigerator",
    "microwave",
    "oven",
    "stove",
    "sink",
    "faucet",
    "toilet",
    "bathtub",
    "shower",
    "mirror",
    "lamp",
    "television",
    "remote control",
    "bookshelf",
    "book",
    "plant",
    "vase",
    "cup",
    "mug",
    "bottle",
    "bowl",
    "plate",
    "knife",
    "fork",
    "spoon",
    "pan",
    "pot",
    "kettle",
    "toaster",
    "dishwasher",
    "washing machine",
    "towel",
    "pillow",
    "blanket",
    "curtain",
    "rug",
    "clock",
    "picture frame",
    "laptop",
    "keyboard",
    "monitor",
    "desk",
    "trash can",
    "cabinet handle",
    "drawer handle",
    "door knob",
    "light switch",
    "power outlet",
    "stove knob",
    "oven door handle",
    "refrigerator handle",
    "faucet handle",
    "toilet flush button",
    "window latch",
    "microwave button",
    "remote control button",
];

fn encoder() -> TextEncoder {
    let runtime = OnnxRuntime::init(&OnnxConfig::default()).unwrap_or_else(|e| panic!("{e}"));
    TextEncoder::new(&runtime, &TextEncoderConfig { enabled: true, ..TextEncoderConfig::default() })
        .unwrap_or_else(|e| panic!("{e}"))
}

fn bench_text_encoder(c: &mut Criterion) {
    let mut encoder = encoder();
    let mut out = Vec::with_capacity(LABELS.len());

    let mut group = c.benchmark_group("text_encoder_model");
    group.measurement_time(Duration::from_secs(4)).sample_size(20);
    for n in [1usize, 16, 64] {
        let labels = &LABELS[..n];
        group.throughput(Throughput::Elements(n as u64));
        group.bench_with_input(BenchmarkId::new("labels_per_call", n), &n, |b, _| {
            b.iter(|| encoder.encode_uncached_into(labels, &mut out).unwrap_or_else(|e| panic!("{e}")));
        });
    }
    group.finish();

    // A plain median over repeated calls, printed per label (criterion's own report gives
    // per-call time and labels/s).
    for n in [1usize, 16, 64] {
        let labels = &LABELS[..n];
        let reps = (640 / n).max(20);
        let mut times: Vec<f64> = (0..reps)
            .map(|_| {
                let start = Instant::now();
                encoder.encode_uncached_into(labels, &mut out).unwrap_or_else(|e| panic!("{e}"));
                start.elapsed().as_secs_f64()
            })
            .collect();
        times.sort_by(f64::total_cmp);
        let median = times[times.len() / 2];
        println!(
            "text_encoder {n:2} labels/call: {:8.3} ms/call, {:7.3} ms/label (median of {reps})",
            median * 1e3,
            median * 1e3 / n as f64
        );
    }

    let mut group = c.benchmark_group("text_encoder_cached");
    encoder.encode_batch_into(&LABELS, &mut out).unwrap_or_else(|e| panic!("{e}"));
    group.throughput(Throughput::Elements(LABELS.len() as u64));
    group.bench_function("64_labels_all_hits", |b| {
        b.iter(|| encoder.encode_batch_into(&LABELS, &mut out).unwrap_or_else(|e| panic!("{e}")));
    });
    group.finish();
}

criterion_group!(benches, bench_text_encoder);
criterion_main!(benches);
