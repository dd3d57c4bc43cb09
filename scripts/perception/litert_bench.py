#!/usr/bin/env python3
"""Times MediaPipe's BlazePose .tflite networks in LiteRT (the XNNPACK CPU delegate, as
MediaPipe runs them) at given thread counts; prints the same table as
`lhmpp bench perception` (network, threads, median and min milliseconds).

Usage: litert_bench.py [--dir target/perception] [--threads 1,2] [--runs 50] [--warmup 5]
                       [--only detector,lite,full,heavy]
"""

import argparse
import os
import time

import numpy as np
from ai_edge_litert.interpreter import Interpreter

FILES = {
    "detector": ("pose_detection.tflite", True),
    "lite": ("pose_landmark_lite.tflite", False),
    "full": ("pose_landmark_full.tflite", False),
    "heavy": ("pose_landmark_heavy.tflite", False),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--dir", default="target/perception")
    ap.add_argument("--threads", default="1,2")
    ap.add_argument("--runs", type=int, default=50)
    ap.add_argument("--warmup", type=int, default=5)
    ap.add_argument("--only", default="detector,lite,full,heavy")
    a = ap.parse_args()
    print(f"# LiteRT (XNNPACK): {a.runs} timed runs after {a.warmup} warm-up runs")
    print(f"{'network':<10} {'threads':>7} {'median_ms':>10} {'min_ms':>10}")
    rng = np.random.default_rng(0)
    for threads in [int(t) for t in a.threads.split(",")]:
        for name in a.only.split(","):
            path = os.path.join(a.dir, FILES[name][0])
            it = Interpreter(model_path=path, num_threads=threads)
            it.allocate_tensors()
            d = it.get_input_details()[0]
            x = rng.random(d["shape"], dtype=np.float32)
            if FILES[name][1]:
                x = x * 2 - 1
            times = []
            for i in range(a.warmup + a.runs):
                it.set_tensor(d["index"], x)
                t = time.perf_counter()
                it.invoke()
                if i >= a.warmup:
                    times.append(time.perf_counter() - t)
            print(f"{name:<10} {threads:>7} {np.median(times) * 1e3:>10.2f} {min(times) * 1e3:>10.2f}",
                  flush=True)


if __name__ == "__main__":
    main()
