#!/usr/bin/env python3
"""Runs one BlazePose .tflite network in LiteRT (its default XNNPACK CPU path) on a real photo
and writes a parity fixture: the input and every graph output, as safetensors.

The input is cut from IMAGE by --box x0,y0,x1,y1 (source pixels, any box; the whole frame by
default), letterboxed (aspect kept, centred, padded with black) to the network's square input
size with PIL's bilinear filter, and stored as `input` (U8, [1, H, W, 3]). The network sees
it as float32 in the range --range: `0,1` is x / 255, `-1,1` is x / 127.5 - 1 (both computed in
float32, so a reader rebuilds the network input bit for bit). Each graph output is stored as
F32 under its graph name. The metadata records the model file and its sha256, the image, its
sha256, the box, the range, the LiteRT version and --source / --licence notes.

Usage: reference.py --model M.tflite --image IMG [--box x0,y0,x1,y1] --range 0,1|-1,1
                    --out FIXTURE.safetensors [--source TEXT] [--licence TEXT]
"""

import argparse
import hashlib
import json
import os
import struct

import numpy as np
from PIL import Image


def letterbox(image, box, size):
    """The box of `image` scaled to fit a size×size square (aspect kept), centred on black."""
    crop = image.crop(box)
    scale = size / max(crop.width, crop.height)
    w, h = max(1, round(crop.width * scale)), max(1, round(crop.height * scale))
    resized = crop.resize((w, h), Image.BILINEAR)
    canvas = Image.new("RGB", (size, size))
    canvas.paste(resized, ((size - w) // 2, (size - h) // 2))
    return np.asarray(canvas, np.uint8)


def to_float(pixels, value_range):
    x = pixels.astype(np.float32)
    if value_range == "0,1":
        return x / np.float32(255.0)
    if value_range == "-1,1":
        return x / np.float32(127.5) - np.float32(1.0)
    raise SystemExit(f"--range {value_range}: expected 0,1 or -1,1")


def sha256(path):
    return hashlib.sha256(open(path, "rb").read()).hexdigest()


def write_safetensors(path, tensors, metadata):
    header = {"__metadata__": metadata}
    offset, blobs = 0, []
    for name, array in tensors:
        dtype = {np.uint8: "U8", np.float32: "F32"}[array.dtype.type]
        data = np.ascontiguousarray(array).tobytes()
        header[name] = {"dtype": dtype, "shape": list(array.shape),
                        "data_offsets": [offset, offset + len(data)]}
        offset += len(data)
        blobs.append(data)
    text = json.dumps(header, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 8)
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(text)))
        f.write(text)
        for b in blobs:
            f.write(b)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", required=True)
    ap.add_argument("--image", required=True)
    ap.add_argument("--box", help="x0,y0,x1,y1 in source pixels (default: the whole frame)")
    ap.add_argument("--range", required=True, dest="value_range")
    ap.add_argument("--out", required=True)
    ap.add_argument("--source", default="", help="where the image comes from")
    ap.add_argument("--licence", default="", help="the image's licence")
    a = ap.parse_args()

    from ai_edge_litert import __version__ as litert_version
    from ai_edge_litert.interpreter import Interpreter

    it = Interpreter(model_path=a.model, num_threads=1)
    it.allocate_tensors()
    (inp,) = it.get_input_details()
    _, h, w, _ = inp["shape"]
    if h != w:
        raise SystemExit(f"{a.model}: input {inp['shape']} is not square")
    image = Image.open(a.image).convert("RGB")
    box = tuple(int(v) for v in a.box.split(",")) if a.box else (0, 0, image.width, image.height)
    pixels = letterbox(image, box, int(h))[None]
    it.set_tensor(inp["index"], to_float(pixels, a.value_range))
    it.invoke()
    tensors = [("input", pixels)]
    for out in it.get_output_details():
        tensors.append((out["name"], it.get_tensor(out["index"]).astype(np.float32)))
    metadata = {
        "model": os.path.basename(a.model),
        "model_sha256": sha256(a.model),
        "image": os.path.basename(a.image),
        "image_sha256": sha256(a.image),
        "image_source": a.source,
        "image_licence": a.licence,
        "box": ",".join(map(str, box)),
        "resize": "crop box, letterbox to the input side (PIL bilinear), centred, black padding",
        "range": a.value_range,
        "input_formula": "x / 255" if a.value_range == "0,1" else "x / 127.5 - 1",
        "runtime": f"ai-edge-litert {litert_version}, Interpreter(num_threads=1), default delegate",
    }
    os.makedirs(os.path.dirname(os.path.abspath(a.out)), exist_ok=True)
    write_safetensors(a.out, tensors, metadata)
    print(f"{a.out}: {', '.join(f'{n} {list(t.shape)}' for n, t in tensors)}; "
          f"{os.path.getsize(a.out)} bytes")


if __name__ == "__main__":
    main()
