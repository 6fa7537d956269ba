#!/usr/bin/env python3
"""Writes the stand-in models: tiny ONNX graphs with exactly the tensor names, shapes and dtypes
of the exports users bring for each model family the open-vocabulary detector adapter supports
(daemon/runtime/src/perception/open_vocab.rs, docs/models.md "Bringing your own models"), with answers
known in advance, so every adapter is tested through ONNX Runtime without the real weights.

    .venv/bin/python scripts/reference/model_standins.py [--out .models/standins]

(PyPI `onnx`, `numpy`, `ftfy`, `regex` from scripts/python-requirements.txt; the CLIP BPE files
from ./scripts/setup-models.sh.) ./scripts/setup-standins.sh runs it for the tests. Writes:

yolo_world.onnx   the YOLO-World export that takes text features (YOLO-World's easydeploy
                  DeployModel with postprocess, without NMS; e.g. wkentaro/yolo-world-onnx
                  export_onnx.py):
                    in  images         float32 [1, 3, 640, 640]  RGB 0..1, letterboxed, pad 114
                        text_features  float32 [1, N, 512]       L2-normalised CLIP text features
                    out scores         float32 [1, A, N]         per-class scores, post-sigmoid
                        boxes          float32 [1, A, 4]         x0 y0 x1 y1, network pixels
                  A = 4 here. Region a carries the text feature of prompt [1, 0, 1, 0][a], so its
                  score for that prompt is conf[a] |t|^2 = conf[a] = 0.9, 0.7, 0.2, 0.65; region 3
                  overlaps region 1 (same prompt) by IoU 0.8, so NMS drops it.
owl.onnx          the OWLv2 / OWL-ViT export of Hugging Face optimum (`optimum-cli export onnx
                  --model google/owlv2-base-patch16-ensemble --task zero-shot-object-detection`):
                    in  input_ids      int64   [P, 16]           CLIP BPE, <|startoftext|> .. <|endoftext|>, 0-padded
                        pixel_values   float32 [1, 3, 960, 960]  RGB, CLIP mean/std, padded bottom/right
                        attention_mask int64   [P, 16]
                    out logits         float32 [1, A, P]         raw (a sigmoid gives the score)
                        pred_boxes     float32 [1, A, 4]         cx cy w h, normalised to the input
                  A = 3. Region a answers the prompt whose first token is the CLIP token of
                  OWL_WORDS[a] ("stove", "cabinet", "tv"), with logit 2, 1, -1 (scores 0.881,
                  0.731, 0.269); every other prompt gets -6. So the labels come out right only
                  when the Rust side tokenises exactly as CLIP does.
clip_text.onnx    the CLIP text encoder (e.g. the textual half of open_clip ViT-B/32 exported with
                  torch.onnx.export, or Hugging Face CLIPTextModelWithProjection):
                    in  input_ids      int64   [N, 77]
                    out text_embeds    float32 [N, 512]          not normalised
                  text_embeds[n] = sum over tokens t != 0 of TABLE[t mod 512] (TABLE seeded below).
sam_encoder.onnx  a SAM-family image encoder (SAM / MobileSAM / EfficientSAM-style exports):
                    in  images            float32 [1, 3, 1024, 1024]  RGB, SAM mean/std (0..255), longest side 1024, padded bottom/right
                    out image_embeddings  float32 [1, 256, 64, 64]
sam_decoder.onnx  the SAM prompt decoder as segment-anything's scripts/export_onnx_model.py
                  writes it (--return-single-mask):
                    in  image_embeddings float32 [1, 256, 64, 64], point_coords float32 [1, K, 2]
                        (input pixels), point_labels float32 [1, K] (box corners 2, 3; padding -1),
                        mask_input float32 [1, 1, 256, 256], has_mask_input float32 [1],
                        orig_im_size float32 [2] (H, W)
                    out masks float32 [1, 1, H, W] (logits at the image size), iou_predictions
                        float32 [1, 1], low_res_masks float32 [1, 1, 256, 256]
                  The mask is the top half of the prompt box (logit 5 inside, -5 outside), so a
                  decoder mask differs from the box and from a depth mask.
efficient_sam_encoder.onnx, efficient_sam_decoder.onnx
                  EfficientSAM as its export_to_onnx.py writes it:
                    encoder in  batched_images  float32 [1, 3, H, W]  RGB 0..1 (normalised inside)
                            out image_embeddings float32 [1, 256, 64, 64]
                    decoder in  image_embeddings, batched_point_coords float32 [1, 1, K, 2]
                                (image pixels), batched_point_labels float32 [1, 1, K],
                                orig_im_size int64 [2] (H, W)
                            out output_masks float32 [1, 1, 3, H, W], iou_predictions float32 [1, 1, 3]
                  Candidate 0 is the whole box, 1 its left half, 2 its top half (logit 5 inside,
                  -5 outside); predicted IoUs 0.5, 0.9, 0.7, so the left half is the answer, and
                  only when the corners went in unscaled.
clip_image.onnx   a CLIP image encoder, the region encoder's model (Hugging Face
                  CLIPVisionModelWithProjection or open_clip encode_image through
                  torch.onnx.export):
                    in  pixel_values   float32 [B, 3, 224, 224]  RGB, CLIP mean/std on 0..1
                    out image_embeds   float32 [B, 512]          not normalised
                  image_embeds[b, j] = the mean of input plane j mod 3 over the image: a crop of
                  one colour (r, g, b) embeds as (r', g', b', r', g', b', ...), its normalised
                  values repeated, so the crop, the resize and the normalisation are checked.
tagger.onnx       an image tagger (RAM / RAM++ traced with torch.onnx.export, before its sigmoid),
tagger_tags.txt   with its tag list (one per line, in output order):
                    in  images         float32 [1, 3, 384, 384]  RGB, ImageNet mean/std on 0..1
                    out logits         float32 [1, 5]
                  Tags TAGGER_TAGS. From the mean normalised planes R', G', B' of the image:
                  cabinet 6 (R' - B'), stove 6 (B' - R'), tv -5, lamp +5, room +6. So a red image
                  is tagged cabinet, lamp, room; a blue one stove, lamp, room; tv never.
expected.json     the answers: CLIP tokens of a few prompts from open_clip's own tokenizer
                  (.models/clip/open_clip_tokenizer.py), the stand-in CLIP embedding of each
                  prompt computed here with numpy, and the regions' constants.
"""
import argparse
import importlib.util
import json
import sys
import types
from pathlib import Path

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

ROOT = Path(__file__).resolve().parents[2]
PROMPTS = ["stove", "cabinet", "tv", "cabinet handle", "light switch", "TV  Stand", "a photo of a red chair!", "don't"]
OWL_WORDS = ["stove", "cabinet", "tv"]
TAGGER_TAGS = ["cabinet", "stove", "tv", "lamp", "room"]
CLIP_DIM = 512
CONTEXT = 77
OWL_CONTEXT = 16


def reference_tokenizer():
    """open_clip's SimpleTokenizer, loaded from the file of the open_clip_torch wheel. Its module
    imports torch for type hints only; `encode` is plain Python, so a stub stands in."""
    path = ROOT / ".models/clip/open_clip_tokenizer.py"
    if not path.is_file():
        sys.exit(f"{path} missing: run ./scripts/setup-models.sh")
    torch = types.ModuleType("torch")
    torch.LongTensor = torch.Tensor = object
    sys.modules.setdefault("torch", torch)
    spec = importlib.util.spec_from_file_location("open_clip_tokenizer", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module.SimpleTokenizer(bpe_path=str(ROOT / ".models/clip/bpe_simple_vocab_16e6.txt.gz"))


def save(model, path):
    model.ir_version = 8
    onnx.checker.check_model(model)
    onnx.save(model, path)
    print(f"wrote {path} ({path.stat().st_size} bytes)")


def model(nodes, name, inputs, outputs, initialisers):
    graph = helper.make_graph(nodes, name, inputs, outputs, initialisers)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)], producer_name="op3dsg")


def image_zero(image, prefix):
    """Nodes making 0 * mean(image): the image takes part, so the runtime keeps the input."""
    return [
        helper.make_node("ReduceMean", [image], [f"{prefix}_mean"], keepdims=0),
        helper.make_node("Mul", [f"{prefix}_mean", "zero"], [f"{prefix}_zero"]),
    ]


def yolo_world(out):
    boxes = np.array([[[80, 60, 240, 300], [300, 100, 500, 260], [600, 600, 630, 630], [310, 110, 500, 250]]], np.float32)
    nodes = [
        helper.make_node("Squeeze", ["text_features", "axis0"], ["text"]),
        helper.make_node("Gather", ["text", "region_prompt"], ["region_features"], axis=0),
        helper.make_node("Transpose", ["text"], ["text_t"], perm=[1, 0]),
        helper.make_node("MatMul", ["region_features", "text_t"], ["similarity"]),
        helper.make_node("Mul", ["similarity", "confidence"], ["region_scores"]),
        helper.make_node("Unsqueeze", ["region_scores", "axis0"], ["scores"]),
        *image_zero("images", "image"),
        helper.make_node("Add", ["box_constants", "image_zero"], ["boxes"]),
    ]
    initialisers = [
        numpy_helper.from_array(np.array([0], np.int64), "axis0"),
        numpy_helper.from_array(np.array([1, 0, 1, 0], np.int64), "region_prompt"),
        numpy_helper.from_array(np.array([[0.9], [0.7], [0.2], [0.65]], np.float32), "confidence"),
        numpy_helper.from_array(np.array(0.0, np.float32), "zero"),
        numpy_helper.from_array(boxes, "box_constants"),
    ]
    save(
        model(
            nodes,
            "yolo_world_standin",
            [
                helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 640, 640]),
                helper.make_tensor_value_info("text_features", TensorProto.FLOAT, [1, "N", CLIP_DIM]),
            ],
            [
                helper.make_tensor_value_info("scores", TensorProto.FLOAT, [1, 4, "N"]),
                helper.make_tensor_value_info("boxes", TensorProto.FLOAT, [1, 4, 4]),
            ],
            initialisers,
        ),
        out / "yolo_world.onnx",
    )
    return {"boxes": boxes[0].tolist(), "region_prompt": [1, 0, 1, 0], "confidence": [0.9, 0.7, 0.2, 0.65]}


def owl(out, tokenizer):
    targets = np.array([[tokenizer.encode(w)[0]] for w in OWL_WORDS], np.int64)  # [A, 1]
    strength = np.array([[2.0], [1.0], [-1.0]], np.float32)
    boxes = np.array([[[0.25, 0.2, 0.1, 0.1], [0.5, 0.3, 0.2, 0.1], [0.8, 0.8, 0.1, 0.1]]], np.float32)
    nodes = [
        helper.make_node("Gather", ["input_ids", "one"], ["first_token"], axis=1),  # [P]
        helper.make_node("Gather", ["attention_mask", "one"], ["first_mask"], axis=1),
        helper.make_node("Equal", ["first_token", "targets"], ["match"]),  # [A, P]
        helper.make_node("Cast", ["match"], ["match_f"], to=TensorProto.FLOAT),
        helper.make_node("Cast", ["first_mask"], ["mask_f"], to=TensorProto.FLOAT),
        helper.make_node("Mul", ["match_f", "mask_f"], ["hit"]),
        helper.make_node("Add", ["strength", "six"], ["lift"]),
        helper.make_node("Mul", ["hit", "lift"], ["lifted"]),
        helper.make_node("Sub", ["lifted", "six"], ["region_logits"]),
        helper.make_node("Unsqueeze", ["region_logits", "axis0"], ["logits"]),
        *image_zero("pixel_values", "image"),
        helper.make_node("Add", ["box_constants", "image_zero"], ["pred_boxes"]),
    ]
    initialisers = [
        numpy_helper.from_array(np.array(1, np.int64), "one"),
        numpy_helper.from_array(np.array([0], np.int64), "axis0"),
        numpy_helper.from_array(targets, "targets"),
        numpy_helper.from_array(strength, "strength"),
        numpy_helper.from_array(np.array(6.0, np.float32), "six"),
        numpy_helper.from_array(np.array(0.0, np.float32), "zero"),
        numpy_helper.from_array(boxes, "box_constants"),
    ]
    save(
        model(
            nodes,
            "owl_standin",
            [
                helper.make_tensor_value_info("input_ids", TensorProto.INT64, ["P", OWL_CONTEXT]),
                helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, [1, 3, 960, 960]),
                helper.make_tensor_value_info("attention_mask", TensorProto.INT64, ["P", OWL_CONTEXT]),
            ],
            [
                helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, 3, "P"]),
                helper.make_tensor_value_info("pred_boxes", TensorProto.FLOAT, [1, 3, 4]),
            ],
            initialisers,
        ),
        out / "owl.onnx",
    )
    return {"words": OWL_WORDS, "target_tokens": targets[:, 0].tolist(), "logit": strength[:, 0].tolist(), "pred_boxes": boxes[0].tolist()}


def clip_text(out, tokenizer):
    table = np.random.default_rng(18).standard_normal((CLIP_DIM, CLIP_DIM)).astype(np.float32)
    nodes = [
        helper.make_node("Mod", ["input_ids", "dim"], ["row"]),
        helper.make_node("Gather", ["table", "row"], ["token_features"], axis=0),  # [N, 77, 512]
        helper.make_node("Not", ["is_pad"], ["is_token"]),
        helper.make_node("Cast", ["is_token"], ["token_weight"], to=TensorProto.FLOAT),
        helper.make_node("Unsqueeze", ["token_weight", "axis2"], ["weight"]),
        helper.make_node("Equal", ["input_ids", "zero_id"], ["is_pad"]),
        helper.make_node("Mul", ["token_features", "weight"], ["weighted"]),
        helper.make_node("ReduceSum", ["weighted", "axis1"], ["text_embeds"], keepdims=0),
    ]
    # Topological order for the checker.
    nodes = [nodes[0], nodes[1], nodes[5], nodes[2], nodes[3], nodes[4], nodes[6], nodes[7]]
    initialisers = [
        numpy_helper.from_array(np.array(CLIP_DIM, np.int64), "dim"),
        numpy_helper.from_array(np.array(0, np.int64), "zero_id"),
        numpy_helper.from_array(np.array([2], np.int64), "axis2"),
        numpy_helper.from_array(np.array([1], np.int64), "axis1"),
        numpy_helper.from_array(table, "table"),
    ]
    save(
        model(
            nodes,
            "clip_text_standin",
            [helper.make_tensor_value_info("input_ids", TensorProto.INT64, ["N", CONTEXT])],
            [helper.make_tensor_value_info("text_embeds", TensorProto.FLOAT, ["N", CLIP_DIM])],
            initialisers,
        ),
        out / "clip_text.onnx",
    )
    tokens, embeddings = {}, {}
    for prompt in PROMPTS + OWL_WORDS:
        ids = [tokenizer.sot_token_id] + tokenizer.encode(prompt) + [tokenizer.eot_token_id]
        tokens[prompt] = ids
        e = sum(table[t % CLIP_DIM] for t in ids if t != 0)
        embeddings[prompt] = (e / np.linalg.norm(e)).tolist()
    return {"tokens": tokens, "clip_text_normalised": embeddings}


def pixel_centres(col, row):
    """Nodes giving the pixel centres cy4 (shape `col`) and cx4 (shape `row`) of an H x W image."""
    n = helper.make_node
    return [
        n("Range", ["zero", "H", "one"], ["ry"]),
        n("Range", ["zero", "W", "one"], ["rx"]),
        n("Add", ["ry", "half"], ["cy"]),
        n("Add", ["rx", "half"], ["cx"]),
        n("Reshape", ["cy", col], ["cy4"]),
        n("Reshape", ["cx", row], ["cx4"]),
    ]


def in_rect(out, x0, x1, y0, y1):
    """Nodes giving `out`: whether each pixel centre lies in [x0, x1) x [y0, y1)."""
    n = helper.make_node
    return [
        n("GreaterOrEqual", ["cy4", y0], [f"{out}_top"]),
        n("Less", ["cy4", y1], [f"{out}_bottom"]),
        n("GreaterOrEqual", ["cx4", x0], [f"{out}_left"]),
        n("Less", ["cx4", x1], [f"{out}_right"]),
        n("And", [f"{out}_top", f"{out}_bottom"], [f"{out}_rows"]),
        n("And", [f"{out}_left", f"{out}_right"], [f"{out}_cols"]),
        n("And", [f"{out}_rows", f"{out}_cols"], [out]),
    ]


def sam(out):
    nodes = [
        helper.make_node("AveragePool", ["images"], ["pooled"], kernel_shape=[16, 16], strides=[16, 16]),  # [1, 3, 64, 64]
        helper.make_node("ReduceMean", ["pooled"], ["grey"], axes=[1], keepdims=1),  # [1, 1, 64, 64]
        helper.make_node("Expand", ["grey", "embedding_shape"], ["image_embeddings"]),
    ]
    save(
        model(
            nodes,
            "sam_encoder_standin",
            [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 1024, 1024])],
            [helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, 64, 64])],
            [numpy_helper.from_array(np.array([1, 256, 64, 64], np.int64), "embedding_shape")],
        ),
        out / "sam_encoder.onnx",
    )
    scalars = {"zero": 0.0, "one": 1.0, "half": 0.5, "two": 2.0, "side": 1024.0, "inside": 5.0, "outside": -5.0}
    inits = [numpy_helper.from_array(np.array(v, np.float32), k) for k, v in scalars.items()]
    inits += [numpy_helper.from_array(np.array(i, np.int64), f"i{i}") for i in range(2)]
    inits += [numpy_helper.from_array(np.array([[0.9]], np.float32), "iou"), numpy_helper.from_array(np.zeros((1, 1, 256, 256), np.float32), "low_res")]
    inits += [numpy_helper.from_array(np.array([1, 1, -1, 1], np.int64), "col"), numpy_helper.from_array(np.array([1, 1, 1, -1], np.int64), "row")]
    n = helper.make_node
    nodes = [
        # Image size and the resize factor s = 1024 / max(H, W).
        n("Gather", ["orig_im_size", "i0"], ["H"], axis=0),
        n("Gather", ["orig_im_size", "i1"], ["W"], axis=0),
        n("Max", ["H", "W"], ["long"]),
        n("Div", ["side", "long"], ["s"]),
        # The box corners (labels 2 and 3 are the first two points here), in image pixels.
        n("Squeeze", ["point_coords", "i0_1d"], ["points"]),  # [K, 2]
        n("Gather", ["points", "i0"], ["p0"], axis=0),
        n("Gather", ["points", "i1"], ["p1"], axis=0),
        n("Div", ["p0", "s"], ["q0"]),
        n("Div", ["p1", "s"], ["q1"]),
        n("Gather", ["q0", "i0"], ["x0"], axis=0),
        n("Gather", ["q0", "i1"], ["y0"], axis=0),
        n("Gather", ["q1", "i0"], ["x1"], axis=0),
        n("Gather", ["q1", "i1"], ["y1"], axis=0),
        n("Add", ["y0", "y1"], ["ysum"]),
        n("Div", ["ysum", "two"], ["ymid"]),
        *pixel_centres("col", "row"),  # [1, 1, H, 1], [1, 1, 1, W]
        *in_rect("in_box", "x0", "x1", "y0", "ymid"),  # [1, 1, H, W]: the box's top half
        n("Where", ["in_box", "inside", "outside"], ["raw_masks"]),
        # Every input takes part (so the runtime keeps them all).
        n("ReduceMean", ["image_embeddings"], ["e_mean"], keepdims=0),
        n("ReduceMean", ["mask_input"], ["m_mean"], keepdims=0),
        n("ReduceSum", ["point_labels"], ["l_sum"], keepdims=0),
        n("ReduceSum", ["has_mask_input"], ["h_sum"], keepdims=0),
        n("Add", ["e_mean", "m_mean"], ["t1"]),
        n("Add", ["t1", "l_sum"], ["t2"]),
        n("Add", ["t2", "h_sum"], ["t3"]),
        n("Mul", ["t3", "zero"], ["t0"]),
        n("Add", ["raw_masks", "t0"], ["masks"]),
        n("Identity", ["iou"], ["iou_predictions"]),
        n("Identity", ["low_res"], ["low_res_masks"]),
    ]
    inits.append(numpy_helper.from_array(np.array([0], np.int64), "i0_1d"))
    save(
        model(
            nodes,
            "sam_decoder_standin",
            [
                helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, 64, 64]),
                helper.make_tensor_value_info("point_coords", TensorProto.FLOAT, [1, "K", 2]),
                helper.make_tensor_value_info("point_labels", TensorProto.FLOAT, [1, "K"]),
                helper.make_tensor_value_info("mask_input", TensorProto.FLOAT, [1, 1, 256, 256]),
                helper.make_tensor_value_info("has_mask_input", TensorProto.FLOAT, [1]),
                helper.make_tensor_value_info("orig_im_size", TensorProto.FLOAT, [2]),
            ],
            [
                helper.make_tensor_value_info("masks", TensorProto.FLOAT, [1, 1, "H", "W"]),
                helper.make_tensor_value_info("iou_predictions", TensorProto.FLOAT, [1, 1]),
                helper.make_tensor_value_info("low_res_masks", TensorProto.FLOAT, [1, 1, 256, 256]),
            ],
            inits,
        ),
        out / "sam_decoder.onnx",
    )


def efficient_sam(out):
    nodes = [
        helper.make_node("ReduceMean", ["batched_images"], ["grey"], axes=[1, 2, 3], keepdims=1),  # [1, 1, 1, 1]
        helper.make_node("Expand", ["grey", "embedding_shape"], ["image_embeddings"]),
    ]
    save(
        model(
            nodes,
            "efficient_sam_encoder_standin",
            [helper.make_tensor_value_info("batched_images", TensorProto.FLOAT, [1, 3, "height", "width"])],
            [helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, 64, 64])],
            [numpy_helper.from_array(np.array([1, 256, 64, 64], np.int64), "embedding_shape")],
        ),
        out / "efficient_sam_encoder.onnx",
    )
    scalars = {"zero": 0.0, "one": 1.0, "half": 0.5, "two": 2.0, "inside": 5.0, "outside": -5.0}
    inits = [numpy_helper.from_array(np.array(v, np.float32), k) for k, v in scalars.items()]
    ints = {"ones2": [1, 1], "ones4": [1, 1, 1, 1], "axis0": [0], "from0": [0], "to2": [2], "four": [4], "squeeze_axes": [0, 1]}
    inits += [numpy_helper.from_array(np.array(v, np.int64), k) for k, v in ints.items()]
    inits += [numpy_helper.from_array(np.array([1, 1, 1, -1, 1], np.int64), "col5"), numpy_helper.from_array(np.array([1, 1, 1, 1, -1], np.int64), "row5")]
    inits += [numpy_helper.from_array(np.array([[[0.5, 0.9, 0.7]]], np.float32), "candidate_iou")]
    n = helper.make_node
    nodes = [
        # Splits rather than pairs of Gathers: ONNX Runtime's GatherSliceToSplitFusion fails on
        # the pairs in this graph ("Attempt to replace the existing tensor").
        n("Cast", ["orig_im_size"], ["size"], to=TensorProto.FLOAT),
        n("Split", ["size", "ones2"], ["H1", "W1"], axis=0),
        n("Squeeze", ["H1", "axis0"], ["H"]),
        n("Squeeze", ["W1", "axis0"], ["W"]),
        n("Squeeze", ["batched_point_coords", "squeeze_axes"], ["points"]),  # [K, 2], image pixels
        n("Slice", ["points", "from0", "to2", "axis0"], ["corners"]),  # [2, 2]: the box corners
        n("Reshape", ["corners", "four"], ["xyxy"]),  # [4]
        n("Split", ["xyxy", "ones4"], ["x0_1", "y0_1", "x1_1", "y1_1"], axis=0),
        n("Squeeze", ["x0_1", "axis0"], ["x0"]),
        n("Squeeze", ["y0_1", "axis0"], ["y0"]),
        n("Squeeze", ["x1_1", "axis0"], ["x1"]),
        n("Squeeze", ["y1_1", "axis0"], ["y1"]),
        n("Add", ["x0", "x1"], ["xsum"]),
        n("Div", ["xsum", "two"], ["xmid"]),
        n("Add", ["y0", "y1"], ["ysum"]),
        n("Div", ["ysum", "two"], ["ymid"]),
        *pixel_centres("col5", "row5"),  # [1, 1, 1, H, 1], [1, 1, 1, 1, W]
        *in_rect("in_box", "x0", "x1", "y0", "y1"),  # [1, 1, 1, H, W]
        *in_rect("in_left", "x0", "xmid", "y0", "y1"),
        *in_rect("in_top", "x0", "x1", "y0", "ymid"),
        n("Where", ["in_box", "inside", "outside"], ["m0"]),  # [1, 1, 1, H, W]
        n("Where", ["in_left", "inside", "outside"], ["m1"]),
        n("Where", ["in_top", "inside", "outside"], ["m2"]),
        n("Concat", ["m0", "m1", "m2"], ["raw"], axis=2),  # [1, 1, 3, H, W]
        # Every input takes part (so the runtime keeps them all).
        n("ReduceMean", ["image_embeddings"], ["e_mean"], keepdims=0),
        n("ReduceSum", ["batched_point_labels"], ["l_sum"], keepdims=0),
        n("Add", ["e_mean", "l_sum"], ["t1"]),
        n("Mul", ["t1", "zero"], ["t0"]),
        n("Add", ["raw", "t0"], ["output_masks"]),
        n("Identity", ["candidate_iou"], ["iou_predictions"]),
    ]
    save(
        model(
            nodes,
            "efficient_sam_decoder_standin",
            [
                helper.make_tensor_value_info("image_embeddings", TensorProto.FLOAT, [1, 256, 64, 64]),
                helper.make_tensor_value_info("batched_point_coords", TensorProto.FLOAT, [1, 1, "K", 2]),
                helper.make_tensor_value_info("batched_point_labels", TensorProto.FLOAT, [1, 1, "K"]),
                helper.make_tensor_value_info("orig_im_size", TensorProto.INT64, [2]),
            ],
            [
                helper.make_tensor_value_info("output_masks", TensorProto.FLOAT, [1, 1, 3, "H", "W"]),
                helper.make_tensor_value_info("iou_predictions", TensorProto.FLOAT, [1, 1, 3]),
            ],
            inits,
        ),
        out / "efficient_sam_decoder.onnx",
    )


def clip_image(out):
    project = np.zeros((3, CLIP_DIM), np.float32)
    project[np.arange(CLIP_DIM) % 3, np.arange(CLIP_DIM)] = 1.0
    nodes = [
        helper.make_node("ReduceMean", ["pixel_values"], ["channel_means"], axes=[2, 3], keepdims=0),  # [B, 3]
        helper.make_node("MatMul", ["channel_means", "project"], ["image_embeds"]),  # [B, 512]
    ]
    save(
        model(
            nodes,
            "clip_image_standin",
            [helper.make_tensor_value_info("pixel_values", TensorProto.FLOAT, ["B", 3, 224, 224])],
            [helper.make_tensor_value_info("image_embeds", TensorProto.FLOAT, ["B", CLIP_DIM])],
            [numpy_helper.from_array(project, "project")],
        ),
        out / "clip_image.onnx",
    )


def tagger(out):
    weights = np.zeros((3, len(TAGGER_TAGS)), np.float32)
    weights[0, 0], weights[2, 0] = 6.0, -6.0  # cabinet: red over blue
    weights[0, 1], weights[2, 1] = -6.0, 6.0  # stove: blue over red
    bias = np.array([0.0, 0.0, -5.0, 5.0, 6.0], np.float32)
    nodes = [
        helper.make_node("ReduceMean", ["images"], ["channel_means"], axes=[2, 3], keepdims=0),  # [1, 3]
        helper.make_node("MatMul", ["channel_means", "weights"], ["scaled"]),
        helper.make_node("Add", ["scaled", "bias"], ["logits"]),
    ]
    save(
        model(
            nodes,
            "tagger_standin",
            [helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, 384, 384])],
            [helper.make_tensor_value_info("logits", TensorProto.FLOAT, [1, len(TAGGER_TAGS)])],
            [numpy_helper.from_array(weights, "weights"), numpy_helper.from_array(bias, "bias")],
        ),
        out / "tagger.onnx",
    )
    (out / "tagger_tags.txt").write_text("".join(f"{t}\n" for t in TAGGER_TAGS))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", type=Path, default=ROOT / ".models/standins")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    tokenizer = reference_tokenizer()
    expected = {"yolo_world": yolo_world(args.out), "owl": owl(args.out, tokenizer), **clip_text(args.out, tokenizer)}
    sam(args.out)
    efficient_sam(args.out)
    clip_image(args.out)
    tagger(args.out)
    (args.out / "expected.json").write_text(json.dumps(expected, indent=1))
    print(f"wrote {args.out / 'expected.json'}")


if __name__ == "__main__":
    main()
