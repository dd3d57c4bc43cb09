"""bf16 against f32 on the same weights and inputs, ours beside PyTorch's: how far each
framework's bf16 forward lands from its own f32 forward.

    target/torchenv/bin/python scripts/parity/bf16_accuracy.py [--checkpoint FILE]
        [--views 2] [--points 4096] [--bin target/release/lhmpp] [--threads 2]

The checkpoint defaults to the embedded default (assets/model/lhmpp-tiny-synthetic.safetensors);
the input is made as scripts/train/check_parity.py makes it (seeded images in [0, 1], the node's
anchors). PyTorch runs the twin of our forward (scripts/train/lhmpp_torch.py) with parameters and
inputs cast to torch.bfloat16; ours runs `lhmpp model forward --dtype bf16`. Prints, per Gaussian
attribute, |bf16 - f32| relative to the f32 output's range (max - min): the worst element and
the RMS, for both, and ours f32 against PyTorch f32 as a check that the two forwards agree.
"""

import argparse
import os
import subprocess
import sys
import tempfile

import torch

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(HERE, "..", "train"))
import check_parity  # noqa: E402
import lhmpp_torch as LT  # noqa: E402

ATTRIBUTES = ("positions", "scales", "rotations", "opacities", "colors")


def relative(a, b):
    """(worst, rms) of |a - b| over the range of b."""
    a, b = a.double(), b.double()
    span = (b.max() - b.min()).item()
    d = (a - b).abs()
    return d.max().item() / span, d.pow(2).mean().sqrt().item() / span


def ours(bin_path, ckpt, inp, dtype, workdir):
    out = os.path.join(workdir, f"ours-{dtype}.safetensors")
    run = subprocess.run([bin_path, "model", "forward", "--checkpoint", ckpt, "--input", inp,
                          "--dtype", dtype, "-o", out], check=True, capture_output=True, text=True)
    print(f"  ours {dtype}: {run.stdout.strip()}")
    from safetensors.torch import load_file

    return load_file(out)


def main():
    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    root = os.path.join(HERE, "..", "..")
    ap.add_argument("--checkpoint",
                    default=os.path.join(root, "assets/model/lhmpp-tiny-synthetic.safetensors"))
    ap.add_argument("--bin", default=os.path.join(root, "target/release/lhmpp"))
    ap.add_argument("--views", type=int, default=2)
    ap.add_argument("--points", type=int, default=4096)
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    from safetensors.torch import load_file

    torch.set_num_threads(args.threads)
    workdir = tempfile.mkdtemp(prefix="lhmpp_bf16_")
    model = LT.load_checkpoint(args.checkpoint)
    inp = os.path.join(workdir, "input.safetensors")
    check_parity.make_input(inp, model.cfg, args.bin, args.views, args.points, 0, workdir)
    x = load_file(inp)
    with torch.no_grad():
        t32 = model(x["images"], x["anchors"], x["normals"])
        m16 = model.to(torch.bfloat16)
        t16 = m16(x["images"].to(torch.bfloat16), x["anchors"], x["normals"])
    o32 = ours(args.bin, args.checkpoint, inp, "f32", workdir)
    o16 = ours(args.bin, args.checkpoint, inp, "bf16", workdir)
    print(f"checkpoint {args.checkpoint}: {args.views} views "
          f"{model.cfg['image_height']}x{model.cfg['image_width']}, {args.points} anchors; "
          "|bf16 - f32| / range of the f32 output, worst element (RMS)")
    print("| attribute | PyTorch bf16 vs PyTorch f32 | ours bf16 vs ours f32 | ours f32 vs PyTorch f32 |")
    print("| --- | ---: | ---: | ---: |")
    for k in ATTRIBUTES:
        pt = relative(t16[k].float(), t32[k])
        us = relative(o16[k], o32[k])
        agree = relative(o32[k], t32[k])
        print(f"| {k} | {pt[0]:.2e} ({pt[1]:.1e}) | {us[0]:.2e} ({us[1]:.1e}) | "
              f"{agree[0]:.1e} |")


if __name__ == "__main__":
    main()
