"""Shows that the parity check can fail. Each mutation puts one plausible porting mistake
into the PyTorch reference, regenerates that block's fixture into a temporary folder and runs
`lhmpp model parity` on it; a mistake is caught when some output goes over 1e-4.

    python scripts/parity/sensitivity.py [--bin target/release/lhmpp]

Exits non-zero when a mutation marked detectable is not caught. `ff_norm_eps` (LayerNorm eps
1e-6 instead of 1e-5 before the feed-forward) is listed to show the resolution of the 1e-4
limit: it moves the outputs by a few 1e-6 only.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile

import torch
import torch.nn.functional as F

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import generate as G  # noqa: E402
import reference as R  # noqa: E402


def joint_no_double_add():
    block_fwd = R.JointBlock.forward

    def fwd(self, points, image, temb):
        seen = {}
        hook = self.ff_context.register_forward_hook(lambda m, i, o: seen.update(f=o))
        p, c = block_fwd(self, points, image, temb)
        hook.remove()
        return p, c - seen["f"]  # take the second `c + f` back out

    R.JointBlock.forward = fwd


def adaln_continuous_shift_scale():
    def fwd(self, x, temb):
        shift, scale = self.linear(F.silu(temb)).chunk(2, 1)
        return F.layer_norm(x, x.shape[-1:], eps=1e-6) * (1 + scale[:, None]) + shift[:, None]

    R.AdaLayerNormContinuous.forward = fwd


def ff_gelu_exact():
    R.FeedForward.forward = lambda self, x: self.net[2](F.gelu(self.net[0].proj(x)))


def ff_norm_eps():
    orig = R.JointBlock.__init__

    def init(self, *a, **k):
        orig(self, *a, **k)
        self.eps = 1e-6

    R.JointBlock.__init__ = init


def conv_weight_flipped():
    orig = R.SubMConv3d.forward

    def fwd(self, feats, grid):
        w = self.weight.data.clone()
        self.weight.data = w.flip(1, 2, 3)
        out = orig(self, feats, grid)
        self.weight.data = w
        return out

    R.SubMConv3d.forward = fwd


def conv_kernel_axes_zyx():
    orig = R.SubMConv3d.forward

    def fwd(self, feats, grid):
        w = self.weight.data.clone()
        self.weight.data = w.permute(0, 3, 2, 1, 4).contiguous()
        out = orig(self, feats, grid)
        self.weight.data = w
        return out

    R.SubMConv3d.forward = fwd


def rope_x_first():
    orig = R.Rope2D.forward
    R.Rope2D.forward = lambda self, t, pos: orig(self, t, pos.flip(-1))


def metric_before_rope():
    orig = R.Rope2D.forward
    seen = {}

    def rope(self, t, pos):
        seen.setdefault("calls", []).append(t)
        return orig(self, t, pos)

    attn_fwd = R.FrameAttention.forward

    def fwd(self, x, pos):
        seen.clear()
        out, _ = attn_fwd(self, x, pos)
        return out, seen["calls"][1].mean(dim=1)  # the keys before RoPE

    R.Rope2D.forward = rope
    R.FrameAttention.forward = fwd


def pos_embed_without_antialias():
    orig = F.interpolate

    def interp(*a, **k):
        k.pop("antialias", None)
        return orig(*a, **k)

    R.F.interpolate = interp


def dpt_tokens_channel_first():
    def fwd(self, feats):
        b, c, H, W = feats.shape
        p = self.patch
        hh, ww = H // p, W // p
        tok = feats.reshape(b, c, hh, p, ww, p).permute(0, 2, 4, 1, 3, 5).reshape(b, hh * ww, p * p * c)
        out = torch.sigmoid(self.dense_predictor(self.patchify(tok).chunk(4, dim=-1), hh, ww, H, W))
        return out[:, :3], out[:, 3:]

    R.NeuralRenderer.forward = fwd


def hilbert_without_gray_decode():
    orig = R.hilbert_code

    def code(g, depth):
        b = orig(g, depth)
        return b ^ (b >> 1)  # binary -> Gray: undoes the decode

    R.hilbert_code = code


def gs_scale_unclamped():
    orig = R.GsHead.forward

    def fwd(self, feats, anchors):
        clip, self.clip = self.clip, float("inf")
        out = orig(self, feats, anchors)
        self.clip = clip
        return out

    R.GsHead.forward = fwd


# name: (block, detectable, mistake)
MUTATIONS = {
    "joint_no_double_add": ("joint_block", True, joint_no_double_add),
    "adaln_continuous_shift_scale": ("joint_block_pre_only", True, adaln_continuous_shift_scale),
    "ff_gelu_exact": ("joint_block", True, ff_gelu_exact),
    "ff_norm_eps": ("joint_block", False, ff_norm_eps),
    "conv_weight_flipped": ("sparse_conv", True, conv_weight_flipped),
    "conv_kernel_axes_zyx": ("sparse_conv", True, conv_kernel_axes_zyx),
    "rope_x_first": ("frame_block", True, rope_x_first),
    "metric_before_rope": ("frame_block", True, metric_before_rope),
    "pos_embed_without_antialias": ("dino_encoder", True, pos_embed_without_antialias),
    "dpt_tokens_channel_first": ("dpt", True, dpt_tokens_channel_first),
    "hilbert_without_gray_decode": ("ptv3_block", True, hilbert_without_gray_decode),
    "gs_scale_unclamped": ("gs_head", True, gs_scale_unclamped),
}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--bin", default="target/release/lhmpp")
    ap.add_argument("--apply", help=argparse.SUPPRESS)
    ap.add_argument("--out", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.apply:  # child: one mutation, one fixture
        block, _, mistake = MUTATIONS[args.apply]
        mistake()
        sys.argv = ["generate.py", "--out", args.out, "--block", block]
        G.main()
        return
    missed = []
    with tempfile.TemporaryDirectory() as tmp:
        print(f"{'mutation':<30} {'block':<22} {'worst output':<20} {'max rel':>10}  caught", flush=True)
        for name, (block, detectable, _) in MUTATIONS.items():
            out = os.path.join(tmp, name)
            subprocess.run([sys.executable, __file__, "--apply", name, "--out", out], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            res = subprocess.run([args.bin, "model", "parity", "--json", "--fixtures", out],
                                 check=True, capture_output=True, text=True)
            rows = json.loads(res.stdout)
            worst = max(rows, key=lambda r: r["max_rel"])
            caught = any(not r["pass"] for r in rows)
            print(f"{name:<30} {block:<22} {worst['output']:<20} {worst['max_rel']:>10.3e}  "
                  f"{'yes' if caught else 'no'}{'' if detectable else ' (below the 1e-4 resolution)'}", flush=True)
            if detectable and not caught:
                missed.append(name)
    if missed:
        sys.exit(f"not caught: {', '.join(missed)}")


if __name__ == "__main__":
    main()
