"""Times the PyTorch twin: forward (no grad) and forward+backward (loss = sum of the outputs'
mean L1) per view count, on --threads CPU threads.

    bench_torch.py --checkpoint FILE --input IN.safetensors [--views 4,8] [--threads 2] [--reps 5]

IN holds `images` (at least max(--views) views) and `anchors`/`normals` (check_parity.py
writes one). The point geometry is built once before timing (it is cached per anchor set).
"""

import argparse
import os
import statistics
import sys
import time

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import lhmpp_torch as LT  # noqa: E402


def timed(fn, reps):
    fn()  # warm-up
    ts = []
    for _ in range(reps):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts), min(ts)


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--input", required=True)
    ap.add_argument("--views", default="4,8")
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--reps", type=int, default=5)
    args = ap.parse_args()
    from safetensors.torch import load_file

    torch.set_num_threads(args.threads)
    model = LT.load_checkpoint(args.checkpoint)
    inp = load_file(args.input)
    a, n = inp["anchors"], inp["normals"]
    t = time.perf_counter()
    geo = model.geometry(a, n)
    print(f"point geometry (once per anchor set): {time.perf_counter() - t:.3f} s, voxels {geo.summary()}")
    print(f"| views | anchors | forward (s) | forward+backward (s) |  threads {args.threads}, median (min) of {args.reps}")
    for v in [int(x) for x in args.views.split(",")]:
        images = inp["images"][:v]
        if images.shape[0] < v:
            images = images.repeat((v + images.shape[0] - 1) // images.shape[0], 1, 1, 1)[:v]

        def fwd():
            with torch.no_grad():
                model(images, a, n)

        def fwd_bwd():
            model.zero_grad(set_to_none=True)
            out = model(images, a, n)
            sum(out[k].abs().mean() for k in LT.OUTPUT_NAMES).backward()

        f = timed(fwd, args.reps)
        fb = timed(fwd_bwd, args.reps)
        print(f"| {v:>5} | {a.shape[0]:>7} | {f[0]:.3f} ({f[1]:.3f}) | {fb[0]:.3f} ({fb[1]:.3f}) |")


if __name__ == "__main__":
    main()
