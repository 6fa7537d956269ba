#!/usr/bin/env python3
"""Writes a real-size stand-in of YOLO-World-S for measuring CPU cost (not for accuracy): the
convolution stack of YOLOv8-S (the backbone, PAN neck and decoupled head YOLO-World-S is built
on: widths 32..512, C2f depths 1, 2, 2, 1, SPPF) at 640 x 640 with batch norm folded, the
text-contrastive classification head (per-scale 512-d region embeddings, L2-normalised, dot
text features), DFL box decoding over the 8400 anchors, with random weights. It leaves out
YOLO-World's text-guided neck attention (C2fAttn max-sigmoid attention, image-pooling
attention), a few percent of the FLOPs, so its cost is a lower bound of the real model's.

Same tensors as the real export and as `.models/standins/yolo_world.onnx`:
  in  images float32 [1, 3, 640, 640], text_features float32 [1, N, 512]
  out scores float32 [1, 8400, N] (sigmoid), boxes float32 [1, 8400, 4] (x0 y0 x1 y1, pixels)

    .venv/bin/python scripts/reference/yolo_world_s_like.py [--out .models/standins/yolo_world_s_like.onnx]
"""
import argparse
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper
from stand_in_graph import Graph

ROOT = Path(__file__).resolve().parents[2]
GRAPH = Graph(seed=7)
rng, nodes, inits, macs = GRAPH.rng, GRAPH.nodes, GRAPH.inits, GRAPH.macs
name, const = GRAPH.name, GRAPH.const


def conv(x, c1, c2, hw, k=1, s=1, act=True):
    """Conv (+ folded BN bias) + SiLU; hw = input spatial size. Returns (name, out hw)."""
    w = (rng.standard_normal((c2, c1, k, k)) * np.sqrt(2.0 / (c1 * k * k))).astype(np.float32)
    b = (rng.standard_normal(c2) * 0.01).astype(np.float32)
    y = name("conv")
    nodes.append(helper.make_node("Conv", [x, const(w, "w"), const(b, "b")], [y], kernel_shape=[k, k], strides=[s, s], pads=[k // 2] * 4))
    out_hw = hw // s
    macs[0] += c1 * c2 * k * k * out_hw * out_hw
    if not act:
        return y, out_hw
    sig = name("sig")
    z = name("silu")
    nodes.append(helper.make_node("Sigmoid", [y], [sig]))
    nodes.append(helper.make_node("Mul", [y, sig], [z]))
    return z, out_hw


def c2f(x, c1, c2, hw, n, shortcut):
    c = c2 // 2
    y, _ = conv(x, c1, 2 * c, hw)
    a, b = name("split"), name("split")
    nodes.append(helper.make_node("Split", [y, const(np.array([c, c], np.int64), "s")], [a, b], axis=1))
    parts = [a, b]
    last = b
    for _ in range(n):
        t, _ = conv(last, c, c, hw, 3)
        t, _ = conv(t, c, c, hw, 3)
        if shortcut:
            u = name("add")
            nodes.append(helper.make_node("Add", [last, t], [u]))
            t = u
        parts.append(t)
        last = t
    cat = name("cat")
    nodes.append(helper.make_node("Concat", parts, [cat], axis=1))
    return conv(cat, (2 + n) * c, c2, hw)[0]


def sppf(x, c1, c2, hw):
    c_ = c1 // 2
    y, _ = conv(x, c1, c_, hw)
    pools = [y]
    for _ in range(3):
        p = name("pool")
        nodes.append(helper.make_node("MaxPool", [pools[-1]], [p], kernel_shape=[5, 5], pads=[2] * 4, strides=[1, 1]))
        pools.append(p)
    cat = name("cat")
    nodes.append(helper.make_node("Concat", pools, [cat], axis=1))
    return conv(cat, 4 * c_, c2, hw)[0]


def up(x):
    y = name("up")
    nodes.append(helper.make_node("Resize", [x, "", const(np.array([1, 1, 2, 2], np.float32), "scales")], [y], mode="nearest"))
    return y


def cat(a, b):
    y = name("cat")
    nodes.append(helper.make_node("Concat", [a, b], [y], axis=1))
    return y


def build():
    x, hw = conv("images", 3, 32, 640, 3, 2)  # 320
    x, hw = conv(x, 32, 64, hw, 3, 2)  # 160
    x = c2f(x, 64, 64, hw, 1, True)
    x, hw = conv(x, 64, 128, hw, 3, 2)  # 80
    p3 = c2f(x, 128, 128, hw, 2, True)
    x, hw = conv(p3, 128, 256, hw, 3, 2)  # 40
    p4 = c2f(x, 256, 256, hw, 2, True)
    x, hw = conv(p4, 256, 512, hw, 3, 2)  # 20
    x = c2f(x, 512, 512, hw, 1, True)
    p5 = sppf(x, 512, 512, 20)
    n4 = c2f(cat(up(p5), p4), 768, 256, 40, 1, False)
    n3 = c2f(cat(up(n4), p3), 384, 128, 80, 1, False)
    d4, _ = conv(n3, 128, 128, 80, 3, 2)
    n4b = c2f(cat(d4, n4), 384, 256, 40, 1, False)
    d5, _ = conv(n4b, 256, 256, 40, 3, 2)
    n5b = c2f(cat(d5, p5), 768, 512, 20, 1, False)

    text = name("text")  # [1, N, 512] -> [N, 512]... kept batched for MatMul
    nodes.append(helper.make_node("Identity", ["text_features"], [text]))
    scores, dists, anchors, strides = [], [], [], []
    for feat, c, hw, stride in [(n3, 128, 80, 8), (n4b, 256, 40, 16), (n5b, 512, 20, 32)]:
        b, _ = conv(feat, c, 64, hw, 3)
        b, _ = conv(b, 64, 64, hw, 3)
        b, _ = conv(b, 64, 64, hw, 1, act=False)  # [1, 64, h, w]
        e, _ = conv(feat, c, 128, hw, 3)
        e, _ = conv(e, 128, 128, hw, 3)
        e, _ = conv(e, 128, 512, hw, 1, act=False)  # [1, 512, h, w]
        flat = name("flat")
        nodes.append(helper.make_node("Reshape", [e, const(np.array([1, 512, hw * hw], np.int64), "shape")], [flat]))
        norm = name("norm")
        nodes.append(helper.make_node("LpNormalization", [flat], [norm], axis=1, p=2))
        logit = name("logit")
        nodes.append(helper.make_node("MatMul", [text, norm], [logit]))  # [1, N, hw]
        macs[0] += 512 * hw * hw  # per prompt
        scaled = name("scaled")
        nodes.append(helper.make_node("Mul", [logit, const(np.array(10.0, np.float32), "scale")], [scaled]))
        biased = name("biased")
        nodes.append(helper.make_node("Add", [scaled, const(np.array(-10.0, np.float32), "bias")], [biased]))
        scores.append(biased)
        d = name("dist")
        nodes.append(helper.make_node("Reshape", [b, const(np.array([1, 4, 16, hw * hw], np.int64), "shape")], [d]))
        dists.append(d)
        ys, xs = np.meshgrid(np.arange(hw) + 0.5, np.arange(hw) + 0.5, indexing="ij")
        anchors.append(np.stack([xs.ravel(), ys.ravel()]) * stride)
        strides.append(np.full(hw * hw, stride, np.float32))
    all_scores = name("all_scores")
    nodes.append(helper.make_node("Concat", scores, [all_scores], axis=2))  # [1, N, 8400]
    t = name("t")
    nodes.append(helper.make_node("Transpose", [all_scores], [t], perm=[0, 2, 1]))
    nodes.append(helper.make_node("Sigmoid", [t], ["scores"]))
    all_d = name("all_d")
    nodes.append(helper.make_node("Concat", dists, [all_d], axis=3))  # [1, 4, 16, 8400]
    soft = name("soft")
    nodes.append(helper.make_node("Softmax", [all_d], [soft], axis=2))
    proj = name("proj")
    nodes.append(helper.make_node("Transpose", [soft], [proj], perm=[0, 1, 3, 2]))  # [1, 4, 8400, 16]
    dist = name("dist")
    nodes.append(helper.make_node("MatMul", [proj, const(np.arange(16, dtype=np.float32).reshape(16, 1), "arange")], [dist]))
    dist2 = name("dist2")
    nodes.append(helper.make_node("Reshape", [dist, const(np.array([1, 4, 8400], np.int64), "shape")], [dist2]))
    scaled = name("scaled")
    nodes.append(helper.make_node("Mul", [dist2, const(np.concatenate(strides)[None, None, :], "strides")], [scaled]))
    lt, rb = name("lt"), name("rb")
    nodes.append(helper.make_node("Split", [scaled, const(np.array([2, 2], np.int64), "s")], [lt, rb], axis=1))
    anchor = const(np.concatenate(anchors, axis=1)[None].astype(np.float32), "anchors")  # [1, 2, 8400]
    x0, x1 = name("x0"), name("x1")
    nodes.append(helper.make_node("Sub", [anchor, lt], [x0]))
    nodes.append(helper.make_node("Add", [anchor, rb], [x1]))
    xyxy = name("xyxy")
    nodes.append(helper.make_node("Concat", [x0, x1], [xyxy], axis=1))
    nodes.append(helper.make_node("Transpose", [xyxy], ["boxes"], perm=[0, 2, 1]))


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--out", type=Path, default=ROOT / ".models/standins/yolo_world_s_like.onnx")
    args = parser.parse_args()
    build()
    graph = helper.make_graph(
        nodes,
        "yolo_world_s_like",
        [
            helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 640, 640]),
            helper.make_tensor_value_info("text_features", TensorProto.FLOAT, [1, "N", 512]),
        ],
        [
            helper.make_tensor_value_info("scores", TensorProto.FLOAT, [1, 8400, "N"]),
            helper.make_tensor_value_info("boxes", TensorProto.FLOAT, [1, 8400, 4]),
        ],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="op3dsg")
    model.ir_version = 8
    onnx.checker.check_model(model)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, args.out)
    params = sum(int(np.prod(i.dims)) for i in inits)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB, {params / 1e6:.2f} M parameters, "
          f"{macs[0] / 1e9:.2f} GMACs at 640 x 640 and one prompt)")


if __name__ == "__main__":
    main()
