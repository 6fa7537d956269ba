#!/usr/bin/env python3
"""Reference values for the Rust text encoder (daemon/runtime/src/onnx/text_encoder.rs).

Runs the same files the daemon uses (.models/, from ./scripts/setup-models.sh) through
onnxruntime's Python API: all-MiniLM-L6-v2 int8, tokenizer.json with padding to the longest
label in the batch and truncation to 128 tokens, mean pooling with the attention mask, L2
normalisation. Prints the cosine similarities the Rust tests assert, the first embedding values
of one label, and per-label times for 1, 16 and 64 labels per call (compare with
`cargo bench -p op3dsg-runtime --bench text_encoder`).

Not part of the build or of CI. Needs the Python packages outside the system, e.g.:

    python3 -m pip install --target /tmp/ortpy onnxruntime==1.31.1 tokenizers numpy
    PYTHONPATH=/tmp/ortpy python3 scripts/reference/text_encoder_reference.py [--threads N]
"""

import argparse
import pathlib
import time

import numpy as np
import onnxruntime as ort
from tokenizers import Tokenizer

ROOT = pathlib.Path(__file__).resolve().parents[2]
MODELS = ROOT / ".models" / "minilm"

PAIRS = [
    ("red chair", "crimson seat"),
    ("red chair", "red chair"),
    ("cabinet handle", "drawer handle"),
    ("cabinet handle", "bathtub"),
    ("refrigerator", "fridge"),
    ("light switch", "power outlet"),
    ("door knob", "banana"),
]

# The bench's labels (daemon/benches/text_encoder.rs has the same list).
LABELS = [
    "chair", "table", "sofa", "bed", "cabinet", "drawer", "door", "window", "refrigerator",
    "microwave", "oven", "stove", "sink", "faucet", "toilet", "bathtub", "shower", "mirror",
    "lamp", "television", "remote control", "bookshelf", "book", "plant", "vase", "cup", "mug",
    "bottle", "bowl", "plate", "knife", "fork", "spoon", "pan", "pot", "kettle", "toaster",
    "dishwasher", "washing machine", "towel", "pillow", "blanket", "curtain", "rug", "clock",
    "picture frame", "laptop", "keyboard", "monitor", "desk", "trash can", "cabinet handle",
    "drawer handle", "door knob", "light switch", "power outlet", "stove knob", "oven door handle",
    "refrigerator handle", "faucet handle", "toilet flush button", "window latch",
    "microwave button", "remote control button",
]
assert len(LABELS) == 64


def make_session(threads: int) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    return ort.InferenceSession(str(MODELS / "model.onnx"), options, providers=["CPUExecutionProvider"])


def make_tokenizer(max_len: int = 128) -> Tokenizer:
    tok = Tokenizer.from_file(str(MODELS / "tokenizer.json"))
    tok.enable_truncation(max_length=max_len)
    tok.enable_padding(pad_id=0, pad_token="[PAD]")  # to the longest in the batch
    return tok


def encode(session, tok, labels):
    encodings = tok.encode_batch(labels)
    ids = np.array([e.ids for e in encodings], dtype=np.int64)
    mask = np.array([e.attention_mask for e in encodings], dtype=np.int64)
    types = np.array([e.type_ids for e in encodings], dtype=np.int64)
    (hidden,) = session.run(["last_hidden_state"], {"input_ids": ids, "attention_mask": mask, "token_type_ids": types})
    weights = mask[:, :, None].astype(np.float32)
    pooled = (hidden * weights).sum(axis=1) / np.maximum(weights.sum(axis=1), 1e-9)
    return pooled / np.maximum(np.linalg.norm(pooled, axis=1, keepdims=True), 1e-12)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--threads", type=int, default=1, help="intra-op threads (the profile's default is 1)")
    args = parser.parse_args()
    session = make_session(args.threads)
    tok = make_tokenizer()

    print(f"onnxruntime {ort.__version__}, intra_op_num_threads={args.threads}")
    print("cosine similarities (each label encoded alone):")
    for a, b in PAIRS:
        ea, eb = encode(session, tok, [a]), encode(session, tok, [b])
        print(f"  cos({a!r}, {b!r}) = {float(ea[0] @ eb[0]):.6f}")

    single = encode(session, tok, ["red chair"])[0]
    print("'red chair' first 8 values:", ", ".join(f"{v:.6f}" for v in single[:8]))
    print("'red chair' tokens:", tok.encode("red chair").ids)

    alone = np.stack([encode(session, tok, [label])[0] for label in LABELS])
    batched = encode(session, tok, LABELS)
    print(f"batch of 64 vs one at a time: max |diff| = {np.abs(alone - batched).max():.2e}, "
          f"min cos = {float((alone * batched).sum(axis=1).min()):.6f}")

    print("per-label time (tokenise + run + pool), median of repeated calls:")
    for n in (1, 16, 64):
        labels = LABELS[:n]
        encode(session, tok, labels)  # warm-up
        reps = max(20, 640 // n)
        times = []
        for _ in range(reps):
            start = time.perf_counter()
            encode(session, tok, labels)
            times.append(time.perf_counter() - start)
        per_call = float(np.median(times))
        print(f"  {n:2d} labels/call: {per_call * 1e3:8.3f} ms/call, {per_call / n * 1e3:7.3f} ms/label")


if __name__ == "__main__":
    main()
