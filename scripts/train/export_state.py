"""Exports the weights of a training run's saved state (state.pt, written every --save-every
steps) as a checkpoint, so a run can be scored while it goes on:

    python scripts/train/export_state.py RUN_DIR OUT.safetensors [--config network.json]

The network config is RUN_DIR/network.json, else the --config given, else the config in
RUN_DIR/config.json's --init checkpoint.
"""

import argparse
import json
import os
import sys

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import lhmpp_torch  # noqa: E402


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", help="training run folder (holds state.pt)")
    ap.add_argument("out", help="checkpoint to write")
    ap.add_argument("--config", default=None, help="network config JSON")
    args = ap.parse_args()
    cfg = args.config
    if cfg is None and os.path.exists(os.path.join(args.run, "network.json")):
        cfg = os.path.join(args.run, "network.json")
    if cfg is None:
        run_cfg = json.load(open(os.path.join(args.run, "config.json")))
        cfg = run_cfg.get("config") or run_cfg.get("init")
    if cfg is None:
        sys.exit("no network config: pass --config")
    state = torch.load(os.path.join(args.run, "state.pt"), map_location="cpu", weights_only=False)
    model = lhmpp_torch.LhmppTorch.from_config_json(cfg)
    model.load_state_dict(state["model"])
    lhmpp_torch.save_checkpoint(model, args.out)
    print(f"{args.out}: step {state['step']}")


if __name__ == "__main__":
    main()
