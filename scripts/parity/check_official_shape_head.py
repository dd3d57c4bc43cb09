"""Checks the shape-head parity fixture against the official ShapeHead itself.

    python check_official_shape_head.py --official DIR FIXTURE

DIR holds the official sources (see official_keys.py; not ours to commit). The official
`ShapeHead` is built with the fixture's widths, loaded with its `shape_head.*` weights and run
through `forward_from_sequence` (pose token 0, mean over views) on the fixture's tokens. Prints
max abs / rel of every step's prediction against the fixture's outputs (the reference in
reference.py).
"""

import argparse
import json
import os
import sys

import torch
from safetensors import safe_open
from safetensors.torch import load_file


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--official", required=True)
    ap.add_argument("fixture")
    args = ap.parse_args()
    sys.path.insert(0, os.path.abspath(args.official))
    from core.models.vggt.heads.shape_head import ShapeHead

    t = load_file(args.fixture)
    with safe_open(args.fixture, "pt") as f:
        c = json.loads(f.metadata()["config"])
    head = ShapeHead(dim_in=c["dim"], target_dim=c["target"], trunk_depth=c["trunk_depth"],
                     num_heads=c["heads"], mlp_ratio=c["mlp_ratio"], init_values=0.01)
    head.load_state_dict({k[len("shape_head."):]: v for k, v in t.items()
                          if k.startswith("shape_head.")})
    head.eval()
    with torch.no_grad():
        steps = head.forward_from_sequence(t["parity.input.tokens"][None], shape_token_idx=0,
                                           num_iterations=c["iterations"])
    ours = torch.cat(steps, dim=0)
    ref = t["parity.output.steps"]
    d = (ours.double() - ref.double()).abs().max().item()
    print(f"official ShapeHead vs reference.py, steps: max abs {d:.3e}, "
          f"max rel {d / ref.double().abs().max().item():.3e}")


if __name__ == "__main__":
    main()
