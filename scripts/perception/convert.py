#!/usr/bin/env python3
"""Converts one MediaPipe BlazePose .tflite network into the safetensors file that
`lhmpp::perception::network::Network` loads.

The TFLite graph stores its weights as float16 constants that DEQUANTIZE ops widen to float32
(the person detector also stores most 1x1 weights sparse, behind DENSIFY ops). The converter
resolves both: every DEQUANTIZE output becomes a constant weight tensor holding the float16
values bit for bit (widening float16 to float32 is exact, so nothing is rounded), and the
remaining ops form the graph. Weights a DENSIFY op densified (mostly zeros) are stored as their
non-zero float16 values plus a bit mask of where they sit (`storage: "bitmask"`), which the
loader expands to the same dense tensor: this keeps the embedded detector at a third of its
dense size. Integer operands (PAD's paddings, RESHAPE's shape, RESIZE_BILINEAR's size) become op
options.

The graph goes into the safetensors `__metadata__` as JSON (key `graph`): the graph inputs and
outputs (name, shape), every activation tensor's shape, every weight's shape and storage, and
the ops in execution order (type, input and output tensor names, options). Alongside it:
`format`, `format_version`, `source_file`, `source_sha256` and `licence`.

Usage: convert.py INPUT.tflite OUTPUT.safetensors [--no-verify]
By default the densified weights are checked against LiteRT's own DENSIFY/DEQUANTIZE outputs.
"""

import argparse
import hashlib
import json
import os
import struct
import sys

import numpy as np
import tflite

FORMAT = "lhmpp-perception-graph"
FORMAT_VERSION = "1"
LICENCE = (
    "MediaPipe BlazePose model (c) Google LLC, Apache License 2.0 "
    "(https://www.apache.org/licenses/LICENSE-2.0); from the npm package "
    "@mediapipe/pose@0.5.1675469404; converted from TFLite to safetensors "
    "(format conversion only, weights unchanged)"
)

OP_NAMES = {v: k for k, v in tflite.BuiltinOperator.__dict__.items() if not k.startswith("_")}
TENSOR_TYPES = {v: k for k, v in tflite.TensorType.__dict__.items() if not k.startswith("_")}
ACTIVATIONS = {0: "NONE", 1: "RELU", 2: "RELU_N1_TO_1", 3: "RELU6", 4: "TANH", 5: "SIGN_BIT"}
PADDINGS = {0: "SAME", 1: "VALID"}


def fail(msg):
    sys.exit(f"convert.py: {msg}")


class Graph:
    """The TFLite model's single subgraph with helpers to read tensors and options."""

    def __init__(self, buf):
        self.buf = buf
        self.model = tflite.Model.GetRootAsModel(buf, 0)
        if self.model.SubgraphsLength() != 1:
            fail(f"{self.model.SubgraphsLength()} subgraphs, expected 1")
        self.g = self.model.Subgraphs(0)
        names = [self.g.Tensors(i).Name().decode() for i in range(self.g.TensorsLength())]
        seen = {}
        self.names = []
        for i, n in enumerate(names):
            # TFLite does not promise unique names; make them unique but stable
            if n in seen:
                n = f"{n}#{i}"
            seen[n] = i
            self.names.append(n)

    def op_type(self, op):
        code = self.model.OperatorCodes(op.OpcodeIndex())
        return OP_NAMES[max(code.BuiltinCode(), code.DeprecatedBuiltinCode())]

    def shape(self, i):
        t = self.g.Tensors(i)
        return [int(d) for d in t.ShapeAsNumpy()] if t.ShapeLength() else []

    def raw(self, i):
        t = self.g.Tensors(i)
        return self.model.Buffers(t.Buffer()).DataAsNumpy().tobytes()

    def constant(self, i, dtype):
        t = self.g.Tensors(i)
        want = {np.int32: "INT32", np.float16: "FLOAT16"}[dtype]
        if TENSOR_TYPES[t.Type()] != want:
            fail(f"tensor {self.names[i]} is {TENSOR_TYPES[t.Type()]}, expected {want}")
        return np.frombuffer(self.raw(i), dtype)


def sparse_index_vector(meta, field):
    """A CSR segments or indices vector of a DimensionMetadata as int64 (None if its type is
    not one of TFLite's Int32/Uint16/Uint8 vectors)."""
    kinds = {
        tflite.SparseIndexVector.Int32Vector: tflite.Int32Vector,
        tflite.SparseIndexVector.Uint16Vector: tflite.Uint16Vector,
        tflite.SparseIndexVector.Uint8Vector: tflite.Uint8Vector,
    }
    cls = kinds.get(getattr(meta, field + "Type")())
    table = getattr(meta, field)()
    if cls is None or table is None:
        return None
    vec = cls()
    vec.Init(table.Bytes, table.Pos)
    return np.asarray(vec.ValuesAsNumpy(), np.int64)


def densify(graph, i):
    """The dense float16 array of sparse constant tensor `i` (TFLite's sparsity format:
    DENSE and SPARSE_CSR dimensions in traversal order, no block map)."""
    t = graph.g.Tensors(i)
    sp = t.Sparsity()
    shape = graph.shape(i)
    if sp.BlockMapLength() or sp.DimMetadataLength() != len(shape):
        fail(f"{graph.names[i]}: block-sparse tensors are not supported")
    order = [int(x) for x in sp.TraversalOrderAsNumpy()]
    values = graph.constant(i, np.float16)
    dims = []
    for level in range(sp.DimMetadataLength()):
        m = sp.DimMetadata(level)
        if m.Format() == 0:
            dims.append(("dense", m.DenseSize(), None, None))
        else:
            seg, idx = sparse_index_vector(m, "ArraySegments"), sparse_index_vector(m, "ArrayIndices")
            if seg is None or idx is None:
                fail(f"{graph.names[i]}: CSR segments or indices of an unsupported type")
            dims.append(("csr", None, seg, idx))
    traversed = np.zeros([shape[d] for d in order], np.float16)

    def fill(level, prev, coords):
        kind, n, seg, idx = dims[level]
        last = level == len(dims) - 1
        if kind == "dense":
            if last:
                traversed[tuple(coords)] = values[prev * n:(prev + 1) * n]
                return
            for c in range(n):
                fill(level + 1, prev * n + c, coords + [c])
        else:
            lo, hi = int(seg[prev]), int(seg[prev + 1])
            if last:
                traversed[tuple(coords)][idx[lo:hi]] = values[lo:hi]
                return
            for j in range(lo, hi):
                fill(level + 1, j, coords + [int(idx[j])])

    fill(0, 0, [])
    return np.transpose(traversed, np.argsort(order))


def options(graph, op, kind):
    o = op.BuiltinOptions()
    if kind in ("CONV_2D", "DEPTHWISE_CONV_2D"):
        x = tflite.Conv2DOptions() if kind == "CONV_2D" else tflite.DepthwiseConv2DOptions()
        x.Init(o.Bytes, o.Pos)
        out = {
            "stride": [x.StrideH(), x.StrideW()],
            "padding": PADDINGS[x.Padding()],
            "activation": ACTIVATIONS[x.FusedActivationFunction()],
            "dilation": [x.DilationHFactor(), x.DilationWFactor()],
        }
        if kind == "DEPTHWISE_CONV_2D":
            out["depth_multiplier"] = x.DepthMultiplier()
        return out
    if kind == "ADD":
        x = tflite.AddOptions()
        x.Init(o.Bytes, o.Pos)
        return {"activation": ACTIVATIONS[x.FusedActivationFunction()]}
    if kind == "MAX_POOL_2D":
        x = tflite.Pool2DOptions()
        x.Init(o.Bytes, o.Pos)
        return {
            "stride": [x.StrideH(), x.StrideW()],
            "filter": [x.FilterHeight(), x.FilterWidth()],
            "padding": PADDINGS[x.Padding()],
            "activation": ACTIVATIONS[x.FusedActivationFunction()],
        }
    if kind == "RESIZE_BILINEAR":
        x = tflite.ResizeBilinearOptions()
        x.Init(o.Bytes, o.Pos)
        size = graph.constant(op.Inputs(1), np.int32).tolist()
        return {
            "align_corners": bool(x.AlignCorners()),
            "half_pixel_centers": bool(x.HalfPixelCenters()),
            "size": size,
        }
    if kind == "CONCATENATION":
        x = tflite.ConcatenationOptions()
        x.Init(o.Bytes, o.Pos)
        return {"axis": x.Axis(), "activation": ACTIVATIONS[x.FusedActivationFunction()]}
    if kind == "DEPTH_TO_SPACE":
        x = tflite.DepthToSpaceOptions()
        x.Init(o.Bytes, o.Pos)
        return {"block_size": x.BlockSize()}
    if kind == "PAD":
        return {"paddings": graph.constant(op.Inputs(1), np.int32).reshape(-1, 2).tolist()}
    if kind == "RESHAPE":
        return {"shape": graph.constant(op.Inputs(1), np.int32).tolist()}
    if kind == "LOGISTIC":
        return {}
    fail(f"op {kind} is not supported by the converter")


# Inputs that are integer operands folded into the options above.
FOLDED_INPUTS = {"PAD": [1], "RESHAPE": [1], "RESIZE_BILINEAR": [1]}


def convert(path):
    buf = open(path, "rb").read()
    graph = Graph(buf)
    g = graph.g
    weights = {}  # tensor index -> (dense float16 array, sparse?)
    produced_by_densify = {}
    ops = []
    for k in range(g.OperatorsLength()):
        op = g.Operators(k)
        kind = graph.op_type(op)
        ins = [int(j) for j in op.InputsAsNumpy()]
        outs = [int(j) for j in op.OutputsAsNumpy()]
        if kind == "DENSIFY":
            produced_by_densify[outs[0]] = densify(graph, ins[0])
            continue
        if kind == "DEQUANTIZE":
            src = ins[0]
            if src in produced_by_densify:
                weights[outs[0]] = (produced_by_densify[src], True)
            else:
                weights[outs[0]] = (graph.constant(src, np.float16).reshape(graph.shape(src)), False)
            if list(weights[outs[0]][0].shape) != graph.shape(outs[0]):
                fail(f"{graph.names[outs[0]]}: dequantized shape differs from its source")
            continue
        folded = FOLDED_INPUTS.get(kind, [])
        data_inputs = [j for n, j in enumerate(ins) if n not in folded and j >= 0]
        ops.append({
            "type": kind,
            "inputs": [graph.names[j] for j in data_inputs],
            "outputs": [graph.names[j] for j in outs],
            "options": options(graph, op, kind),
            "_in": data_inputs,
            "_out": outs,
        })
    tensors = {}
    for op in ops:
        for j in op["_in"] + op["_out"]:
            if j in weights:
                continue
            if graph.model.Buffers(g.Tensors(j).Buffer()).DataLength() > 0:
                fail(f"op {op['type']} reads constant {graph.names[j]} that is not a weight")
            if TENSOR_TYPES[g.Tensors(j).Type()] != "FLOAT32":
                fail(f"activation {graph.names[j]} is {TENSOR_TYPES[g.Tensors(j).Type()]}")
            tensors[graph.names[j]] = graph.shape(j)
        del op["_in"], op["_out"]
    io = lambda idx: [{"name": graph.names[j], "shape": graph.shape(j)} for j in idx]
    meta_graph = {
        "inputs": io(g.InputsAsNumpy()),
        "outputs": io(g.OutputsAsNumpy()),
        "tensors": tensors,
        "weights": {
            graph.names[j]: {"shape": list(a.shape), "storage": "bitmask" if sparse else "dense"}
            for j, (a, sparse) in weights.items()
        },
        "ops": ops,
    }
    return graph, weights, meta_graph


def verify(path, graph, weights):
    """Checks the resolved weights against LiteRT's DENSIFY/DEQUANTIZE outputs."""
    from ai_edge_litert.interpreter import Interpreter, OpResolverType

    it = Interpreter(
        model_path=path,
        experimental_op_resolver_type=OpResolverType.BUILTIN_WITHOUT_DEFAULT_DELEGATES,
        experimental_preserve_all_tensors=True,
    )
    it.allocate_tensors()
    d = it.get_input_details()[0]
    it.set_tensor(d["index"], np.zeros(d["shape"], np.float32))
    it.invoke()
    for j, (a, _) in weights.items():
        want = it.get_tensor(j)
        if not np.array_equal(want, a.astype(np.float32)):
            fail(f"{graph.names[j]}: resolved weight differs from LiteRT's")


def write_safetensors(out, graph, weights, meta_graph, source_name, source_sha):
    entries = []  # (name, dtype, shape, bytes)
    for j, (a, sparse) in weights.items():
        name = graph.names[j]
        if sparse:
            flat = a.reshape(-1)
            mask = flat.view(np.uint16) != 0  # keeps a -0.0 (bit pattern) too
            entries.append((name + ".values", "F16", [int(mask.sum())], flat[mask].tobytes()))
            bits = np.packbits(mask, bitorder="little")
            entries.append((name + ".mask", "U8", [int(bits.size)], bits.tobytes()))
        else:
            entries.append((name, "F16", list(a.shape), np.ascontiguousarray(a).tobytes()))
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
    for name, dtype, shape, data in entries:
        header[name] = {"dtype": dtype, "shape": shape, "data_offsets": [offset, offset + len(data)]}
        offset += len(data)
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    tmp = out + ".tmp"
    with open(tmp, "wb") as f:
        f.write(struct.pack("<Q", len(text)))
        f.write(text)
        for _, _, _, data in entries:
            f.write(data)
    os.replace(tmp, out)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("input")
    ap.add_argument("output")
    ap.add_argument("--no-verify", action="store_true", help="skip the check against LiteRT")
    a = ap.parse_args()
    buf = open(a.input, "rb").read()
    sha = hashlib.sha256(buf).hexdigest()
    graph, weights, meta_graph = convert(a.input)
    if not a.no_verify:
        verify(a.input, graph, weights)
    os.makedirs(os.path.dirname(os.path.abspath(a.output)), exist_ok=True)
    write_safetensors(a.output, graph, weights, meta_graph, os.path.basename(a.input), sha)
    n = sum(w.size for w, _ in weights.values())
    print(f"{a.output}: {len(meta_graph['ops'])} ops, {len(weights)} weights ({n} values), "
          f"{os.path.getsize(a.output)} bytes, source sha256 {sha}")


if __name__ == "__main__":
    main()
