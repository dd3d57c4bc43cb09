"""Writes one safetensors fixture per block: seeded random weights under the official
state-dict names, random inputs (`parity.input.*`), and the PyTorch f32 outputs
(`parity.output.*`). The metadata holds the block kind, its dimensions (`config`, JSON) and
PyTorch's own bf16-vs-f32 error per output (`torch_bf16`, JSON: max|a-b|/max|b|).

    python generate.py --out DIR [--size small|700m] [--device cpu|cuda] [--seed 0]

`small` is the CI set committed in tests/fixtures/parity (d=64, 2 heads); `700m` uses the
LHMPP-700M widths for single blocks (hundreds of MB: keep it out of the repository).
"""

import argparse
import ctypes
import copy
import json
import os

import struct

import torch

import reference as R

DTYPES = {torch.float32: "F32", torch.int64: "I64"}


def save_file(tensors, path, metadata):
    """Minimal safetensors writer (the GPU machine may lack the `safetensors` package):
    u64 header size, JSON header (dtype, shape, data_offsets; `__metadata__`), raw data."""
    header, blobs, offset = {"__metadata__": metadata}, [], 0
    for name in sorted(tensors):
        t = tensors[name].contiguous().cpu()
        raw = ctypes.string_at(t.data_ptr(), t.numel() * t.element_size())
        header[name] = {"dtype": DTYPES[t.dtype], "shape": list(t.shape),
                        "data_offsets": [offset, offset + len(raw)]}
        blobs.append(raw)
        offset += len(raw)
    head = json.dumps(header, separators=(",", ":")).encode()
    head += b" " * (-len(head) % 8)
    with open(path, "wb") as f:
        f.write(struct.pack("<Q", len(head)))
        f.write(head)
        for raw in blobs:
            f.write(raw)

SIZES = {
    "small": {
        "dino_block": dict(dim=64, heads=2, mlp_ratio=4.0, batch=2, tokens=17),
        "dino_encoder": dict(dim=64, depth=2, heads=2, patch=14, registers=4, grid=5,
                             mlp_ratio=4.0, batch=2, height=98, width=56),
        "frame_block": dict(dim=64, heads=2, mlp_ratio=4.0, rope_base=100.0, views=2, h=3, w=4),
        "joint_block": dict(pv=32, dim=64, heads=2, context_dim=64, points=40, image=30),
        "joint_block_pre_only": dict(pv=32, dim=64, heads=2, context_dim=64, points=40, image=30),
        "sparse_conv": dict(c_in=16, c_out=24, box=[10, 9, 8], occupancy=0.35),
        "gs_head": dict(q=32, n=64, hidden_layers=2, clip_scaling=0.05, max_step=1.0, points=100),
        "dpt": dict(c=8, patch=7, embed=64, features=16, oc=[8, 16, 32, 32], batch=1,
                    height=28, width=21),
        "ptv3_block": dict(c=32, heads=2, patch=64, mlp_ratio=4.0, order_index=2, box=[10, 9, 8],
                           occupancy=0.4),
        "dpt_pixelshuffle": dict(c=8, patch=7, embed=64, features=16, oc=[8, 16, 32, 32], batch=1,
                                 height=28, width=21, pixel_shuffle=2),
        "shape_head": dict(dim=64, target=10, trunk_depth=2, heads=2, mlp_ratio=4.0, iterations=4,
                           views=3, tokens=9),
        "dpt_shared": dict(c=8, patch=7, embed=32, features=16, oc=[8, 16, 32, 32], batch=1,
                           height=28, width=21, shared=True),
    },
    "700m": {
        "dino_block": dict(dim=1024, heads=16, mlp_ratio=4.0, batch=1, tokens=1 + 4 + 60 * 36),
        "dino_encoder": dict(dim=1024, depth=1, heads=16, patch=14, registers=4, grid=37,
                             mlp_ratio=4.0, batch=1, height=840, width=504),
        "frame_block": dict(dim=1024, heads=16, mlp_ratio=4.0, rope_base=100.0, views=2, h=60, w=36),
        "joint_block": dict(pv=512, dim=1024, heads=16, context_dim=1024, points=1686, image=2160),
        "joint_block_pre_only": dict(pv=128, dim=1024, heads=16, context_dim=1024, points=4096,
                                     image=2160),
        "sparse_conv": dict(c_in=128, c_out=128, box=[40, 40, 40], occupancy=0.1),
        "gs_head": dict(q=128, n=512, hidden_layers=2, clip_scaling=0.05, max_step=1.0, points=20000),
        "dpt": dict(c=128, patch=7, embed=1024, features=128, oc=[128, 256, 512, 512], batch=1,
                    height=140, width=84),
        "ptv3_block": dict(c=64, heads=4, patch=4096, mlp_ratio=4.0, order_index=3, box=[40, 40, 40],
                           occupancy=0.16),
        "dpt_pixelshuffle": dict(c=128, patch=7, embed=1024, features=128, oc=[128, 256, 512, 512],
                                 batch=1, height=140, width=84, pixel_shuffle=2),
        "shape_head": dict(dim=1024, target=10, trunk_depth=2, heads=16, mlp_ratio=4.0, iterations=4,
                           views=2, tokens=5 + 60 * 36),
        "dpt_shared": dict(c=128, patch=7, embed=1024, features=128, oc=[128, 256, 512, 512], batch=1,
                           height=140, width=84, shared=True),
    },
}

# Official prefixes of each block in the LHMPP-700M state dict.
PREFIX = {
    "dino_block": "encoder.model.blocks.0.",
    "dino_encoder": "encoder.model.",
    "frame_block": "transformer.image_backbone.frame_blocks.0.",
    "joint_block": "transformer.pi_transformer_enc.0.",
    "joint_block_pre_only": "transformer.pi_transformer_dec.2.",
    "sparse_conv": "transformer.point_backbone.enc.enc0.block0.cpe.0.",
    "ptv3_block": "transformer.point_backbone.enc.enc0.block0.",
    "gs_head": "renderer.",
    "dpt": "neural_renderer.",
    "dpt_pixelshuffle": "neural_renderer.",
    "shape_head": "shape_head.",
    "dpt_shared": "neural_renderer.",
}


def randomize(module, gen):
    """Weights that make every branch matter: fan-in scaled matrices, norms near 1, visible
    biases, LayerScale gammas in [0.5, 1.5] (not the 0.01 init, which would hide a branch)."""
    with torch.no_grad():
        for name, p in module.named_parameters():
            leaf = name.split(".")[-1]
            n = torch.randn(p.shape, generator=gen)
            if leaf == "weight" and p.dim() >= 2:
                v = n * R.gaussian_fan_in_std(p.shape)
            elif leaf == "weight":
                v = 1.0 + 0.2 * n
            elif leaf == "bias":
                v = 0.2 * n
            elif leaf == "gamma":
                v = 0.5 + torch.rand(p.shape, generator=gen)
            else:
                v = 0.5 * n
            p.copy_(v)


def random_voxels(box, occupancy, gen):
    """Distinct random cells of a box [N, 3] (int64), shuffled as after hashing."""
    bx, by, bz = box
    cells = torch.stack(torch.meshgrid(torch.arange(bx), torch.arange(by), torch.arange(bz),
                                       indexing="ij"), -1).reshape(-1, 3)
    grid = cells[torch.rand(cells.shape[0], generator=gen) < occupancy]
    return grid[torch.randperm(grid.shape[0], generator=gen)].to(torch.int64)


def build(kind, c, gen):
    """Module, inputs (dict) and a forward returning a dict of outputs."""
    rn = lambda *s: torch.randn(*s, generator=gen)  # noqa: E731
    if kind == "dino_block":
        m = R.DinoBlock(c["dim"], c["heads"], c["mlp_ratio"])
        inputs = {"x": rn(c["batch"], c["tokens"], c["dim"])}
        fwd = lambda m, i: {"y": m(i["x"])}  # noqa: E731
    elif kind == "dino_encoder":
        m = R.DinoEncoder(c["dim"], c["depth"], c["heads"], c["patch"], c["registers"], c["grid"],
                          c["mlp_ratio"])
        inputs = {"images": torch.rand(c["batch"], 3, c["height"], c["width"], generator=gen)}

        def fwd(m, i):
            cls, patches = m(i["images"])
            return {"cls": cls, "patch_tokens": patches}
    elif kind == "frame_block":
        m = R.FrameBlock(c["dim"], c["heads"], c["mlp_ratio"], c["rope_base"])
        inputs = {"x": rn(c["views"], 5 + c["h"] * c["w"], c["dim"])}

        def fwd(m, i):
            pos = R.rope_positions(c["h"], c["w"], 5, i["x"].device)
            y, metric = m(i["x"], pos)
            return {"y": y, "metric": metric}
    elif kind in ("joint_block", "joint_block_pre_only"):
        pre = kind == "joint_block_pre_only"
        m = R.JointBlock(c["pv"], c["dim"], c["heads"], c["context_dim"], pre)
        inputs = {
            "points": rn(c["points"], c["pv"]),
            "image": rn(c["image"], c["context_dim"]),
            "temb": rn(1, c["dim"]),
        }

        def fwd(m, i):
            p, img = m(i["points"][None], i["image"][None], i["temb"])
            out = {"points": p[0]}
            if img is not None:
                out["image"] = img[0]
            return out
    elif kind == "sparse_conv":
        m = R.SubMConv3d(c["c_in"], c["c_out"])
        grid = random_voxels(c["box"], c["occupancy"], gen)
        inputs = {"grid": grid, "x": rn(grid.shape[0], c["c_in"])}
        fwd = lambda m, i: {"y": m(i["x"], i["grid"])}  # noqa: E731
    elif kind == "ptv3_block":
        m = R.PtBlock(c["c"], c["heads"], c["patch"], c["mlp_ratio"], c["order_index"])
        grid = random_voxels(c["box"], c["occupancy"], gen)
        inputs = {"grid": grid, "x": rn(grid.shape[0], c["c"])}
        names = ["z", "z_trans", "hilbert", "hilbert_trans"]

        def fwd(m, i):
            orders = R.serialize(i["grid"].cpu())
            out = {"y": m(i["x"], i["grid"], orders)}
            out.update({f"order_{n}": o for n, (o, _) in zip(names, orders)})
            return out
    elif kind == "gs_head":
        m = R.GsHead(c["q"], c["n"], c["hidden_layers"], c["clip_scaling"], c["max_step"])
        inputs = {"features": rn(c["points"], c["q"]), "anchors": rn(c["points"], 3)}
        fwd = lambda m, i: m(i["features"], i["anchors"])  # noqa: E731
    elif kind in ("dpt", "dpt_pixelshuffle", "dpt_shared"):
        m = R.NeuralRenderer(c["c"], c["patch"], c["embed"], c["features"], c["oc"],
                             c.get("pixel_shuffle"), c.get("shared", False))
        inputs = {"features": rn(c["batch"], c["c"], c["height"], c["width"])}

        def fwd(m, i):
            rgb, mask = m(i["features"])
            return {"rgb": rgb, "mask": mask}
    elif kind == "shape_head":
        m = R.ShapeHead(c["dim"], c["target"], c["trunk_depth"], c["heads"], c["mlp_ratio"],
                        c["iterations"])
        inputs = {"tokens": rn(c["views"], c["tokens"], c["dim"])}

        def fwd(m, i):
            steps = m(i["tokens"])
            return {"betas": steps[-1:], "steps": steps}
    else:
        raise ValueError(kind)
    randomize(m, gen)
    if kind == "gs_head":
        with torch.no_grad():  # put the scale logits around the 0.05 clamp, not all above it
            m.gs_net.out_layers["scaling"].bias -= 4.0
    return m, inputs, fwd


def rel_err(a, b):
    a, b = a.double(), b.double()
    return ((a - b).abs().max() / b.abs().max().clamp_min(1e-30)).item()


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True)
    ap.add_argument("--size", default="small", choices=sorted(SIZES))
    ap.add_argument("--device", default="cpu")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--block", action="append", help="only these blocks (repeatable)")
    args = ap.parse_args()
    torch.backends.cuda.matmul.allow_tf32 = False
    torch.backends.cudnn.allow_tf32 = False
    dev = torch.device(args.device)
    os.makedirs(args.out, exist_ok=True)
    for idx, (kind, cfg) in enumerate(SIZES[args.size].items()):
        if args.block and kind not in args.block:
            continue
        gen = torch.Generator().manual_seed(args.seed * 1000 + idx)  # idx: append new blocks last
        m, inputs, fwd = build(kind, cfg, gen)
        m = m.to(dev).eval()
        ins = {k: v.to(dev) for k, v in inputs.items()}
        with torch.no_grad():
            outs = fwd(m, ins)
            m16 = copy.deepcopy(m).to(torch.bfloat16)  # Module.to works in place: keep m in f32
            ins16 = {k: (v.to(torch.bfloat16) if v.is_floating_point() else v) for k, v in ins.items()}
            outs16 = fwd(m16, ins16)
        bf16 = {k: rel_err(outs16[k].float(), outs[k]) for k in outs if outs[k].is_floating_point()}
        tensors = {PREFIX[kind] + k: v.detach().float().cpu().contiguous() for k, v in m.state_dict().items()}
        tensors.update({f"parity.input.{k}": v.cpu().contiguous() for k, v in inputs.items()})
        tensors.update({f"parity.output.{k}": (v.float() if v.is_floating_point() else v).cpu().contiguous()
                        for k, v in outs.items()})
        meta = {
            "block": kind,
            "config": json.dumps(cfg),
            "prefix": PREFIX[kind],
            "size": args.size,
            "seed": str(args.seed),
            "torch": torch.__version__,
            "torch_device": str(dev),
            "torch_bf16": json.dumps(bf16),
        }
        path = os.path.join(args.out, f"{kind}.safetensors")
        save_file(tensors, path, metadata=meta)
        n = sum(v.numel() for k, v in tensors.items() if not k.startswith("parity."))
        print(f"{path}: {n} parameters, outputs {sorted(outs)}, torch bf16 rel {bf16}")


if __name__ == "__main__":
    main()
