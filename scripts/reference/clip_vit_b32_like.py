#!/usr/bin/env python3
"""Writes a real-size stand-in of CLIP ViT-B/32's image encoder for measuring the region
encoder's CPU cost (not for accuracy): the layers and widths of OpenAI's ViT-B/32 visual tower
(32 x 32 patches of a 224 x 224 image, 49 patch tokens and a class token, width 768, 12 layers
of 12-head attention and a 3072-wide QuickGELU MLP, pre- and post-LayerNorm, projection to
512) with random weights: 87.8 M parameters, 4.4 GMACs, so it costs what the real model costs
on the same runtime. The file is about 350 MB, so the test set-up does not write it; the
benchmark that uses it says how to.

Same tensors as the real export and as `.models/standins/clip_image.onnx`:
  in  pixel_values float32 [1, 3, 224, 224]
  out image_embeds float32 [1, 512]

    .venv/bin/python scripts/reference/clip_vit_b32_like.py [--out .models/standins/clip_vit_b32_like.onnx]
"""
import argparse
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper
from stand_in_graph import Graph

ROOT = Path(__file__).resolve().parents[2]
WIDTH, LAYERS, HEADS, MLP, PATCH, SIDE, EMBED = 768, 12, 12, 3072, 32, 224, 512
TOKENS = (SIDE // PATCH) ** 2 + 1
GRAPH = Graph(seed=32)
rng, nodes, inits, macs = GRAPH.rng, GRAPH.nodes, GRAPH.inits, GRAPH.macs
name, const = GRAPH.name, GRAPH.const


def op(kind, inputs, **attrs):
    out = name(kind.lower())
    nodes.append(helper.make_node(kind, inputs, [out], **attrs))
    return out


def weight(*shape):
    return (rng.standard_normal(shape) * (1.0 / np.sqrt(shape[0]))).astype(np.float32)


def linear(x, c1, c2, rows=TOKENS):
    macs[0] += rows * c1 * c2
    return op("Add", [op("MatMul", [x, const(weight(c1, c2), "w")]), const(np.zeros(c2, np.float32), "b")])


def layer_norm(x):
    return op(
        "LayerNormalization",
        [x, const(np.ones(WIDTH, np.float32), "g"), const(np.zeros(WIDTH, np.float32), "beta")],
        axis=-1,
        epsilon=1e-5,
    )


def heads(x):
    """[1, T, W] -> [1, H, T, W / H]."""
    return op("Transpose", [op("Reshape", [x, const(np.array([1, TOKENS, HEADS, WIDTH // HEADS], np.int64))])], perm=[0, 2, 1, 3])


def block(x):
    h = layer_norm(x)
    q, k, v = (heads(linear(h, WIDTH, WIDTH)) for _ in range(3))
    scores = op("Mul", [op("MatMul", [q, op("Transpose", [k], perm=[0, 1, 3, 2])]), const(np.float32(1.0 / np.sqrt(WIDTH // HEADS)))])
    macs[0] += 2 * TOKENS * TOKENS * WIDTH
    attended = op("MatMul", [op("Softmax", [scores], axis=-1), v])
    merged = op("Reshape", [op("Transpose", [attended], perm=[0, 2, 1, 3]), const(np.array([1, TOKENS, WIDTH], np.int64))])
    x = op("Add", [x, linear(merged, WIDTH, WIDTH)])
    h = linear(layer_norm(x), WIDTH, MLP)
    h = op("Mul", [h, op("Sigmoid", [op("Mul", [h, const(np.float32(1.702))])])])  # QuickGELU
    return op("Add", [x, linear(h, MLP, WIDTH)])


def build():
    grid = SIDE // PATCH
    patches = op("Conv", ["pixel_values", const(weight(WIDTH, 3, PATCH, PATCH) / 40.0, "patch")], kernel_shape=[PATCH, PATCH], strides=[PATCH, PATCH])
    macs[0] += WIDTH * 3 * PATCH * PATCH * grid * grid
    tokens = op("Transpose", [op("Reshape", [patches, const(np.array([1, WIDTH, grid * grid], np.int64))])], perm=[0, 2, 1])
    x = op("Concat", [const(rng.standard_normal((1, 1, WIDTH)).astype(np.float32), "cls"), tokens], axis=1)
    x = layer_norm(op("Add", [x, const(rng.standard_normal((1, TOKENS, WIDTH)).astype(np.float32) * 0.02, "pos")]))
    for _ in range(LAYERS):
        x = block(x)
    cls = layer_norm(op("Gather", [x, const(np.array(0, np.int64))], axis=1))  # [1, W]
    macs[0] += WIDTH * EMBED
    nodes.append(helper.make_node("MatMul", [cls, const(weight(WIDTH, EMBED), "proj")], ["image_embeds"]))
    graph = helper.make_graph(
        nodes,
        "clip_vit_b32_like",
        [helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, [1, 3, SIDE, SIDE])],
        [helper.make_tensor_value_info("image_embeds", TensorProto.FLOAT, [1, EMBED])],
        inits,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="op3dsg")
    model.ir_version = 8  # what ONNX Runtime 1.31 reads (opset 17 needs IR 8)
    return model


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / ".models/standins/clip_vit_b32_like.onnx")
    args = parser.parse_args()
    model = build()
    onnx.checker.check_model(model)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    onnx.save(model, args.out)
    params = sum(int(np.prod(i.dims)) for i in model.graph.initializer)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.1f} MB, {params / 1e6:.2f} M parameters, {macs[0] / 1e9:.2f} GMACs at {SIDE} x {SIDE})")


if __name__ == "__main__":
    main()
