#!/usr/bin/env python3
"""Writes daemon/tests/data/open_vocab_fixture.onnx: a tiny ONNX graph with the input and
output contract of an open-vocabulary detector (daemon/runtime/src/perception/open_vocab.rs), whose
answers are known, for the adapter's tests.

    pip install --target /tmp/onnxpy onnx==1.17.0 numpy
    PYTHONPATH=/tmp/onnxpy python3 scripts/reference/open_vocab_fixture.py

Inputs:  images [1, 3, 64, 64] float (RGB, 0..1), text_embeddings [P, D] float (P >= 2).
Outputs: boxes [3, 4] (x0, y0, x1, y1 in input pixels), scores [3], prompt_index [3] (int64),
         similarity [3, P], masks [3, 16, 16] (probabilities over the whole input),
         region_embeddings [3, D].

The three "regions" carry the embeddings of prompts 1, 0 and 1 (gathered from the text input)
scaled into scores by the constant confidences 0.9, 0.6 and 0.2, so region n answers prompt
1, 0, 1 with score = confidence x |e|^2 (= confidence for unit-length embeddings). Box 0's mask
covers only the top half of its box (a mask is not a box); the others fill their boxes.
"""
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OUT = Path(__file__).resolve().parents[2] / "daemon/tests/data/open_vocab_fixture.onnx"

boxes = np.array([[8, 8, 24, 40], [30, 10, 60, 30], [40, 40, 44, 44]], dtype=np.float32)
masks = np.zeros((3, 16, 16), dtype=np.float32)
for n, (x0, y0, x1, y1) in enumerate(boxes.astype(int) // 4):
    masks[n, y0:y1, x0:x1] = 0.95
masks[0, (8 + 40) // 8:, :] = 0.05  # box 0: only rows 8..24 of the input (its top half)

nodes = [
    helper.make_node("Gather", ["text_embeddings", "region_prompt"], ["region_embeddings"], axis=0),
    helper.make_node("Transpose", ["text_embeddings"], ["text_t"], perm=[1, 0]),
    helper.make_node("MatMul", ["region_embeddings", "text_t"], ["cosine"]),
    helper.make_node("Mul", ["cosine", "confidence"], ["similarity"]),
    helper.make_node("ReduceMax", ["similarity"], ["scores"], axes=[1], keepdims=0),
    helper.make_node("ArgMax", ["similarity"], ["prompt_index"], axis=1, keepdims=0),
    # The image takes part (so the runtime cannot drop the input): boxes + 0 * mean(image).
    helper.make_node("ReduceMean", ["images"], ["image_mean"], keepdims=0),
    helper.make_node("Mul", ["image_mean", "zero"], ["image_zero"]),
    helper.make_node("Add", ["box_constants", "image_zero"], ["boxes"]),
    helper.make_node("Identity", ["mask_constants"], ["masks"]),
]
initialisers = [
    numpy_helper.from_array(np.array([1, 0, 1], dtype=np.int64), "region_prompt"),
    numpy_helper.from_array(np.array([[0.9], [0.6], [0.2]], dtype=np.float32), "confidence"),
    numpy_helper.from_array(np.array(0.0, dtype=np.float32), "zero"),
    numpy_helper.from_array(boxes, "box_constants"),
    numpy_helper.from_array(masks, "mask_constants"),
]
graph = helper.make_graph(
    nodes,
    "open_vocab_fixture",
    [
        helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 64, 64]),
        helper.make_tensor_value_info("text_embeddings", TensorProto.FLOAT, ["P", "D"]),
    ],
    [
        helper.make_tensor_value_info("boxes", TensorProto.FLOAT, [3, 4]),
        helper.make_tensor_value_info("scores", TensorProto.FLOAT, [3]),
        helper.make_tensor_value_info("prompt_index", TensorProto.INT64, [3]),
        helper.make_tensor_value_info("similarity", TensorProto.FLOAT, [3, "P"]),
        helper.make_tensor_value_info("masks", TensorProto.FLOAT, [3, 16, 16]),
        helper.make_tensor_value_info("region_embeddings", TensorProto.FLOAT, [3, "D"]),
    ],
    initialisers,
)
model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="op3dsg")
model.ir_version = 8
onnx.checker.check_model(model)
OUT.parent.mkdir(parents=True, exist_ok=True)
onnx.save(model, OUT)
print(f"wrote {OUT} ({OUT.stat().st_size} bytes)")
