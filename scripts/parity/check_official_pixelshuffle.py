"""Checks the PixelShuffle (or LHMPPS `dpt_shared`) parity fixture against the official
MLPPixelShuffleDPTHead (or DPTHead) itself.

    python check_official_pixelshuffle.py --official DIR FIXTURE

DIR holds the official sources (see official_keys.py; not ours to commit). The official head is
built like `PatchMLPPixelShuffleDPT4DecoderOnly.build_decoder` (four "layers" = four channel
groups of the patchify tokens, `intermediate_layer_idx` [0, 1, 2, 3]), loaded with the fixture's
`neural_renderer.dense_predictor.*` weights and run on the fixture's features after the same
patchify (`(hh ph) (ww pw) -> (hh ww) (ph pw c)`, Linear without bias). Prints max abs / rel of
its RGB and mask against the fixture's outputs (the reference in reference.py).
"""

import argparse
import json
import os
import sys

import torch
from safetensors.torch import load_file
from safetensors import safe_open


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--official", required=True)
    ap.add_argument("fixture")
    args = ap.parse_args()
    sys.path.insert(0, os.path.abspath(args.official))
    from core.models.heads.dpt_head import DPTHead
    from core.models.heads.mlp_head import MLPPixelShuffleDPTHead

    t = load_file(args.fixture)
    with safe_open(args.fixture, "pt") as f:
        cfg = json.loads(f.metadata()["config"])
    p, embed = cfg["patch"], cfg["embed"]
    shared = cfg.get("shared", False)
    if shared:  # PatchDPTDecoderOnly.build_decoder at depth 1
        head = DPTHead(dim_in=embed, patch_size=p, features=cfg["features"],
                       out_channels=cfg["oc"], intermediate_layer_idx=[0, 0, 0, 0])
    else:
        head = MLPPixelShuffleDPTHead(dim_in=embed // 4, patch_size=p, features=cfg["features"],
                                      out_channels=cfg["oc"], intermediate_layer_idx=[0, 1, 2, 3],
                                      pixel_shuffle_factor=cfg["pixel_shuffle"])
    prefix = "neural_renderer.dense_predictor."
    head.load_state_dict({k[len(prefix):]: v for k, v in t.items() if k.startswith(prefix)})
    head.eval()
    x = t["parity.input.features"]
    b, c, H, W = x.shape
    tok = x.reshape(b, c, H // p, p, W // p, p).permute(0, 2, 4, 3, 5, 1).reshape(b, -1, p * p * c)
    tok = tok @ t["neural_renderer.patchify.1.weight"].T
    groups = [tok.unsqueeze(0)] if shared else [g.unsqueeze(0) for g in torch.chunk(tok, 4, dim=-1)]
    with torch.no_grad():
        rgb, mask = head(groups, H, W)  # [1, B, H, W, 3], [1, B, H, W, 1]
    rgb = rgb[0].permute(0, 3, 1, 2)
    mask = mask[0].permute(0, 3, 1, 2)
    for name, ours in (("rgb", rgb), ("mask", mask)):
        ref = t[f"parity.output.{name}"]
        d = (ours.double() - ref.double()).abs().max().item()
        rel = d / ref.double().abs().max().item()
        print(f"official {type(head).__name__} vs reference.py, {name}: max abs {d:.3e}, max rel {rel:.3e}")


if __name__ == "__main__":
    main()
