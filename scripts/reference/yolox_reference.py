#!/usr/bin/env python3
"""Reference for daemon/runtime/tests/it/yolox.rs: YOLOX-nano with onnxruntime's Python API.

Runs the model on one ICL-NUIM frame with exactly the letterbox of
daemon/runtime/src/perception/yolox.rs (float32 bilinear with half-pixel centres, rounded, BGR,
top-left, pad 114), decodes the grids, thresholds obj * cls, suppresses per class, and prints
the final boxes and a few raw output values in a form pasted into the Rust test. Also times
the per-frame inference (session.run only, one intra-op thread, like the Rust bench).

    pip install --target /tmp/ortpy onnxruntime==1.31.1 numpy pillow
    PYTHONPATH=/tmp/ortpy python3 scripts/reference/yolox_reference.py [frame_index] [--time N]

The RGB pixels come from a raw dump (`--rgb file.rgb`, 640x480x3 bytes, what the Rust JPEG
decoder gives; the test writes it when asked) or else from PIL's JPEG decoder.
"""
import sys
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort

ROOT = Path(__file__).resolve().parents[2]
SHARED = ROOT.parent / "shared"
MODEL = SHARED / "data/models/yolox_nano/yolox_nano.onnx"
SEQ = SHARED / "data/rgbd/icl_livingroom1"
CLASSES = (ROOT / "daemon/data/models/yolox_nano/coco_classes.txt").read_text().split("\n")
SIZE = 416
SCORE_THR = np.float32(0.3)
NMS_THR = np.float32(0.45)
f32 = np.float32


def letterbox(rgb):
    h, w, _ = rgb.shape
    r = min(f32(SIZE) / f32(h), f32(SIZE) / f32(w))
    new_w = min(max(int(f32(w) * r), 1), SIZE)
    new_h = min(max(int(f32(h) * r), 1), SIZE)
    sx = np.maximum((np.arange(new_w, dtype=f32) + f32(0.5)) * (f32(w) / f32(new_w)) - f32(0.5), f32(0))
    sy = np.maximum((np.arange(new_h, dtype=f32) + f32(0.5)) * (f32(h) / f32(new_h)) - f32(0.5), f32(0))
    x0 = np.minimum(np.floor(sx).astype(np.int64), w - 1)
    y0 = np.minimum(np.floor(sy).astype(np.int64), h - 1)
    fx = (sx - x0.astype(f32)).astype(f32)[None, :, None]
    fy = (sy - y0.astype(f32)).astype(f32)[:, None, None]
    x1 = np.minimum(x0 + 1, w - 1)
    y1 = np.minimum(y0 + 1, h - 1)
    img = rgb.astype(f32)
    p00 = img[y0][:, x0]
    p01 = img[y0][:, x1]
    p10 = img[y1][:, x0]
    p11 = img[y1][:, x1]
    top = p00 + (p01 - p00) * fx
    bottom = p10 + (p11 - p10) * fx
    v = np.floor(top + (bottom - top) * fy + f32(0.5)).astype(f32)  # round half away from zero (v >= 0)
    out = np.full((3, SIZE, SIZE), f32(114.0), dtype=f32)
    out[:, :new_h, :new_w] = v[:, :, ::-1].transpose(2, 0, 1)  # RGB -> BGR planes
    return out[None], r


def iou(a, b):
    iw = max(min(a[2], b[2]) - max(a[0], b[0]), f32(0))
    ih = max(min(a[3], b[3]) - max(a[1], b[1]), f32(0))
    inter = f32(iw * ih)
    area = lambda x: max(x[2] - x[0], f32(0)) * max(x[3] - x[1], f32(0))
    union = area(a) + area(b) - inter
    return inter / union if union > 0 else f32(0)


def postprocess(raw, r):
    cands = []
    row = 0
    for stride in (8, 16, 32):
        g = SIZE // stride
        st = f32(stride)
        for gy in range(g):
            for gx in range(g):
                v = raw[row]
                row += 1
                if v[4] <= SCORE_THR:
                    continue
                cx = (v[0] + f32(gx)) * st
                cy = (v[1] + f32(gy)) * st
                bw = np.exp(v[2]) * st
                bh = np.exp(v[3]) * st
                box = [(cx - bw / f32(2)) / r, (cy - bh / f32(2)) / r, (cx + bw / f32(2)) / r, (cy + bh / f32(2)) / r]
                for c in range(raw.shape[1] - 5):
                    s = v[4] * v[5 + c]
                    if s > SCORE_THR:
                        cands.append((box, s, c, row - 1))
    cands.sort(key=lambda t: (-t[1], t[2]))  # stable: ties keep anchor order
    kept = []
    for c in cands:
        if any(k[2] == c[2] and iou(k[0], c[0]) > NMS_THR for k in kept):
            continue
        kept.append(c)
    return kept


def main():
    args = sys.argv[1:]
    frame = int(args[0]) if args and not args[0].startswith("--") else 0
    runs = int(args[args.index("--time") + 1]) if "--time" in args else 0
    if "--rgb" in args:
        rgb = np.fromfile(args[args.index("--rgb") + 1], dtype=np.uint8).reshape(480, 640, 3)
    else:
        from PIL import Image
        rgb = np.asarray(Image.open(SEQ / f"rgb/{frame:05d}.jpg").convert("RGB"))
    print(f"# frame {frame}: rgb byte sum {int(rgb.astype(np.uint64).sum())}")
    x, r = letterbox(rgb)
    print(f"# letterbox r = {r!r}, input sum = {float(x.astype(np.float64).sum())}")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = 1
    opts.inter_op_num_threads = 1
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    sess = ort.InferenceSession(str(MODEL), opts, providers=["CPUExecutionProvider"])
    raw = sess.run(None, {"images": x})[0][0]
    kept = postprocess(raw, r)
    print("# raw rows of the kept anchors: (anchor, first 6 values)")
    for box, s, c, anchor in kept:
        print(f"#   {anchor}: {[float(v) for v in raw[anchor][:6]]}")
    print("// (class, score, [x0, y0, x1, y1]) from scripts/reference/yolox_reference.py")
    for box, s, c, anchor in kept:
        print(f"    ({c}, {float(s):.7}, [{', '.join(f'{float(b):.4f}' for b in box)}]), // {CLASSES[c]}, anchor {anchor}")
    if runs:
        for _ in range(3):
            sess.run(None, {"images": x})
        times = []
        for _ in range(runs):
            t = time.perf_counter()
            sess.run(None, {"images": x})
            times.append(time.perf_counter() - t)
        times.sort()
        print(f"# onnxruntime Python {ort.__version__}: session.run median {1e3 * times[len(times) // 2]:.3f} ms, "
              f"min {1e3 * times[0]:.3f} ms over {runs} runs (1 intra-op thread)")


if __name__ == "__main__":
    main()
