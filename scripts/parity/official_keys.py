"""Key lists of the GS-supervised LHM++ releases, made by instantiating the official modules.

    python official_keys.py --official DIR --variant pixelshuffle|smplx-free|lhmpps --out FILE.tsv

DIR is a folder holding the official Python sources (not ours to commit), laid out as in the
official repository:
  core/models/heads/{dpt_head,head_act,head_utils}.py      (aigc3d/LHM-plusplus and forks)
  core/models/heads/mlp_head.py                             (MLPPixelShuffleDPTHead, fork
                                                             AtlantixJJ/LHM-plusplus@be7f294)
  core/models/vggt/heads/shape_head.py, core/models/vggt/layers/*.py
                                                            (ShapeHead, fork KuroTaiga/LHM_pp@1f479d4)
The other parts of both releases are the LHMPP-700M modules at the same widths, whose key list
(tests/fixtures/lhmpp_700m_state_dict_keys.tsv) was made by instantiating the full official
model. This script swaps in what differs, from the official classes themselves:
  pixelshuffle: neural_renderer.dense_predictor.* = MLPPixelShuffleDPTHead(dim_in=1024 // 4,
                patch_size=7, pixel_shuffle_factor=2) (PatchMLPPixelShuffleDPT4DecoderOnly.build_decoder)
  pixelshuffle, smplx-free:
                shape_head.* = ShapeHead(dim_in=1024, target_dim=10, trunk_depth=2, num_heads=16,
                mlp_ratio=4.0, init_values=0.01) (the `shape_head` block of both configs)
  lhmpps:       neural_renderer.dense_predictor.* = DPTHead(dim_in=1024, patch_size=7,
                intermediate_layer_idx=[0, 0, 0, 0]) (PatchDPTDecoderOnly.build_decoder, depth 1,
                configs/train/LHMPP-any-view-DPTS.yaml); its one unused SD3 block
                (neural_renderer.transformer_block.0, context_pre_only, diffusers) is not listed
"""

import argparse
import os
import sys


def rows(prefix, module):
    return [(prefix + k, list(v.shape)) for k, v in module.state_dict().items()]


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--official", required=True)
    ap.add_argument("--variant", required=True, choices=["pixelshuffle", "smplx-free", "lhmpps"])
    ap.add_argument("--base", default=os.path.join(os.path.dirname(__file__), "../../tests/fixtures/lhmpp_700m_state_dict_keys.tsv"))
    ap.add_argument("--out", required=True)
    args = ap.parse_args()
    sys.path.insert(0, os.path.abspath(args.official))
    from core.models.vggt.heads.shape_head import ShapeHead

    base = []
    with open(args.base) as f:
        for line in f:
            name, shape = line.rstrip("\n").split("\t")
            base.append((name, [int(d) for d in shape.strip("[]").split(",") if d.strip()]))
    out = base
    if args.variant == "pixelshuffle":
        from core.models.heads.mlp_head import MLPPixelShuffleDPTHead

        head = MLPPixelShuffleDPTHead(dim_in=1024 // 4, patch_size=7,
                                      intermediate_layer_idx=[0, 1, 2, 3], pixel_shuffle_factor=2)
        prefix = "neural_renderer.dense_predictor."
        out = [r for r in base if not r[0].startswith(prefix)] + rows(prefix, head)
    if args.variant == "lhmpps":
        from core.models.heads.dpt_head import DPTHead

        head = DPTHead(dim_in=1024, patch_size=7, intermediate_layer_idx=[0, 0, 0, 0])
        prefix = "neural_renderer.dense_predictor."
        out = [r for r in base if not r[0].startswith(prefix)
               and not r[0].startswith("neural_renderer.transformer_block.")] + rows(prefix, head)
    else:
        shape = ShapeHead(dim_in=1024, target_dim=10, trunk_depth=2, num_heads=16, mlp_ratio=4.0,
                          init_values=0.01)
        out = out + rows("shape_head.", shape)
    with open(args.out, "w") as f:
        for name, dims in out:
            f.write(f"{name}\t[{', '.join(str(d) for d in dims)}]\n")
    print(f"{args.out}: {len(out)} tensors, "
          f"{sum(__import__('math').prod(d) for _, d in out)} values")


if __name__ == "__main__":
    main()
