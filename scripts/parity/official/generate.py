"""Runs the official LHM++ forward (the official modules, unchanged, through `shims.py`) on
seeded random weights and records everything our port needs to replay it:

  OUT/config.json        the official model config the modules were built from
  OUT/model.safetensors  the official state dict under its own names (f32; for --size small
                         f16-representable values stored as f16)
  OUT/io.safetensors     inputs, the recorded random draws, and the official outputs;
                         metadata `lhmpp.fixture` holds the widths as JSON

Usage (after scripts/parity/official/setup):

  target/officialenv/bin/python scripts/parity/official/generate.py \
      --official target/official-src --size small --out tests/fixtures/official/forward

`--size small` is the committed fixture (reduced DINOv2 and DPT widths, slim PTv3, small
patches so that every stage holds several attention patches); `--size 700m` is the released
LHMPP-700M widths (not committed). Tensor names: docs/model-forward.md.
"""

import argparse
import copy
import json
import math
import pathlib
import sys
import time

import numpy as np
import torch

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
import shims  # noqa: E402

HERE = pathlib.Path(__file__).resolve().parent
RELEASED = HERE.parents[2] / "tests" / "fixtures" / "official" / "config.json"


def small_config(cfg):
    """The released config at fixture widths (DINOv2 `dinov2_fixture14_reg`: 64 wide, 2 blocks)."""
    cfg["encoder_model_name"] = "dinov2_fixture14_reg"
    cfg["encoder_feat_dim"] = 64
    cfg["pcl_dim"] = 64
    cfg["transformer_dim"] = 64
    cfg["transformer_heads"] = 2
    td = cfg["transformer_decoder"]
    td["image_backbone"].update(embed_dim=64, num_heads=2)
    td["point_backbone"].update(
        enc_depths=[1, 2, 2, 2],
        enc_channels=[16, 32, 32, 64],
        enc_num_head=[2, 2, 4, 4],
        enc_patch_size=[64, 64, 32, 16],
        dec_depths=[2, 2, 2],
        dec_channels=[32, 32, 64],
        dec_num_head=[2, 2, 4],
        dec_patch_size=[64, 64, 32],
    )
    cfg["gs_query_dim"] = 32
    cfg["gs_mlp_network_config"]["n_neurons"] = 64
    cfg["neural_renderer"].update(enc_channels=32, img_dim=64)
    return cfg


SIZES = {
    # name: (config edit, DINOv2 widths, DPT widths, views, H, W, points, feature image H, W)
    "small": (small_config, (64, 2, 2), (16, (16, 32, 64, 64)), 2, 126, 98, 3000, 56, 42),
    "700m": (lambda c: c, None, None, 2, 840, 504, 24000, 588, 588),
}


def build(cfg, seed, half):
    from core.models.modeling_humana4o_lrm import ModelHumanA4OLRM

    torch.manual_seed(seed)
    model = ModelHumanA4OLRM(**{k: v for k, v in cfg.items() if k != "model_name"})
    model.eval()
    # Random weights that exercise every path (the official init zeroes the Gaussian heads
    # and the AdaLN modulations).
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for name, p in model.named_parameters():
            if p.dim() >= 2 and "weight" in name:
                fan_in = p[0].numel()
                p.copy_(torch.randn(p.shape, generator=g) / math.sqrt(fan_in))
            elif name.endswith("weight") and "norm" in name:
                p.copy_(1 + 0.1 * torch.randn(p.shape, generator=g))
            else:
                p.copy_(0.1 * torch.randn(p.shape, generator=g))
        sc = model.renderer.gs_net.out_layers["scaling"]
        sc.bias.add_(-4.0)
        sc.weight.mul_(0.5)
        if half:
            # f16-representable values: the file stores them as f16, exactly.
            for p in model.parameters():
                p.copy_(p.half().float())
    shims.spconv_train_mode(model)
    return model


def voxel_keys(coords, grid=0.01):
    """The official CenterShift + GridSample voxel of each point (float32 as ToPvPoints)."""
    c = coords.astype(np.float32).copy()
    lo, hi = c.min(0), c.max(0)
    shift = np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]], dtype=np.float32)
    c -= shift
    scaled = c / np.array(grid)
    cell = np.floor(scaled).astype(np.int64)
    return cell, scaled - cell


def make_points(n, rng):
    """A body-like cloud (a stack of ellipsoids) with normals: one representative per 1 cm
    voxel, about 10% exact duplicates (identical copies in a voxel make the official random
    representative irrelevant), and no point within 2% of a voxel face. Two corner points fix
    the bounding box so that CenterShift's shift is exactly (0, 0, 0)."""
    parts = [  # centre, radii
        ((0.0, 0.0, 0.95), (0.16, 0.11, 0.28)),
        ((0.0, 0.0, 1.35), (0.09, 0.09, 0.11)),
        ((-0.1, 0.0, 0.4), (0.07, 0.07, 0.33)),
        ((0.1, 0.0, 0.4), (0.07, 0.07, 0.33)),
        ((-0.32, 0.0, 1.0), (0.2, 0.05, 0.05)),
        ((0.32, 0.0, 1.0), (0.2, 0.05, 0.05)),
    ]
    m = int(n * 1.6)
    d = rng.normal(size=(m, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = np.array([parts[i % len(parts)][0] for i in range(m)])
    r = np.array([parts[i % len(parts)][1] for i in range(m)])
    pts = (c + d * r).astype(np.float32)
    g = d / r
    nrm = (g / np.linalg.norm(g, axis=1, keepdims=True)).astype(np.float32)
    corners = np.array([[-0.605, -0.605, 0.0], [0.605, 0.605, 1.6]], np.float32)
    cell, frac = voxel_keys(np.concatenate([corners, pts]))
    cell, frac = cell[2:], frac[2:]
    safe = np.all((frac > 0.02) & (frac < 0.98), axis=1)
    _, first = np.unique(cell, axis=0, return_index=True)
    keep = np.zeros(len(pts), bool)
    keep[first] = True
    keep &= safe
    keep &= np.cumsum(keep) <= int(n * 0.9) - 2
    pts = np.concatenate([corners, pts[keep]])
    nrm = np.concatenate([np.array([[0, 0, -1], [0, 0, 1]], np.float32), nrm[keep]])
    dup = rng.choice(len(pts), n - len(pts), replace=True)
    pts = np.concatenate([pts, pts[dup]])
    nrm = np.concatenate([nrm, nrm[dup]])
    order = rng.permutation(len(pts))
    pts, nrm = pts[order], nrm[order]
    cell, frac = voxel_keys(pts)
    _, inv = np.unique(cell, axis=0, return_inverse=True)
    for v in range(inv.max() + 1):
        members = pts[inv == v]
        assert np.all(members == members[0]), "a voxel holds two different points"
    return pts, nrm, int(inv.max() + 1)


def save_weights(state, out, shard_bytes=512 << 20):
    """`model.safetensors`, or shards `model-0000i-of-0000n.safetensors` with the hub index
    when the state dict is larger than `shard_bytes` (safetensors copies what it writes)."""
    from safetensors.torch import save_file

    total = sum(v.numel() * v.element_size() for v in state.values())
    if total <= shard_bytes:
        save_file(state, str(out / "model.safetensors"))
        return
    shards, cur, size = [], {}, 0
    for k, v in state.items():
        b = v.numel() * v.element_size()
        if cur and size + b > shard_bytes:
            shards.append(cur)
            cur, size = {}, 0
        cur[k] = v
        size += b
    shards.append(cur)
    weight_map = {}
    for i, shard in enumerate(shards):
        name = f"model-{i + 1:05d}-of-{len(shards):05d}.safetensors"
        save_file(shard, str(out / name))
        weight_map.update({k: name for k in shard})
    index = {"metadata": {"total_size": total}, "weight_map": weight_map}
    (out / "model.safetensors.index.json").write_text(json.dumps(index, indent=1) + "\n")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--official", required=True, help="checkout of the official code (core/)")
    ap.add_argument("--size", choices=sorted(SIZES), default="small")
    ap.add_argument("--out", required=True)
    ap.add_argument("--seed", type=int, default=21)
    ap.add_argument("--points", type=int, help="query points (default: per size)")
    ap.add_argument("--image", help="view size HxW (default: per size; multiples of 14)")
    ap.add_argument(
        "--patch-divisor",
        type=int,
        default=1,
        help="divide the PTv3 attention patch sizes by this (more patches per stage in less memory)",
    )
    ap.add_argument("--feature-image", help="feature image HxW (default: per size; multiples of 7)")
    ap.add_argument(
        "--threads", type=int, default=1, help="torch threads (spconv always runs on one)"
    )
    args = ap.parse_args()

    edit, dino, dpt, views, H, W, n, fh, fw = SIZES[args.size]
    n = args.points or n
    if args.image:
        H, W = map(int, args.image.split("x"))
    if args.feature_image:
        fh, fw = map(int, args.feature_image.split("x"))
    shims.install(args.official, dinov2_widths=dino, dpt_widths=dpt)
    shims.spconv_single_thread()
    torch.set_num_threads(args.threads)

    cfg = edit(json.loads(RELEASED.read_text()))
    pb = cfg["transformer_decoder"]["point_backbone"]
    for key in ("enc_patch_size", "dec_patch_size"):
        pb[key] = [p // args.patch_divisor for p in pb[key]]
    # The ArcFace identity net is a training loss (it loads its own weights file); off.
    cfg["use_face_id"] = False
    model = build(copy.deepcopy(cfg), args.seed, args.size == "small")  # it pops keys

    rng = np.random.default_rng(args.seed)
    pts, nrm, voxels = make_points(n, rng)
    n = len(pts)
    masks = {
        "is_rhand": rng.random(n) < 0.1,
        "is_lhand": rng.random(n) < 0.1,
        "is_upper_body": rng.random(n) < 0.3,
        "is_constrain_body": rng.random(n) < 0.5,
    }
    coords = torch.from_numpy(pts)
    normals = torch.from_numpy(nrm)
    mtorch = {k: torch.from_numpy(v) for k, v in masks.items()}
    images = torch.from_numpy(rng.random((views, 3, H, W), dtype=np.float32))
    feature_image = torch.from_numpy(
        rng.normal(size=(1, cfg["gs_query_dim"], fh, fw)).astype(np.float32)
    )

    skin = model.renderer.smplx_model
    skin.set_inputs(coords, normals, mtorch)
    shims.reset_record()
    model.transformer.random_generator = None
    torch.manual_seed(args.seed + 1)  # the state both draws start from
    with torch.no_grad():
        start = time.time()
        query_points, smplx = model.renderer.get_query_points(None, {}, device=coords.device)
        latent, img_feats, motion_emb, pos_emb = model.forward_latent_points(
            images[None],
            camera=None,
            query_points=query_points,
            ref_imgs_bool=torch.ones(1, views, dtype=torch.bool),
        )
        gs, _, _ = model.renderer.forward_gs(latent, query_points, smplx_data={})
        forward_s = time.time() - start
        start = time.time()
        rgb, mask = model.neural_renderer(
            img_feats, feature_image[None], motion_emb, fh, fw, pos_emb
        )
        neural_s = time.time() - start
    gs = gs[0]
    print(f"official forward {forward_s:.1f} s, neural renderer {neural_s:.1f} s", flush=True)

    def ours(t):
        # Official [1, V, H, W, c] -> ours [V, c, H, W].
        return t.reshape(-1, fh, fw, t.shape[-1]).permute(0, 3, 1, 2).contiguous()

    rec = shims.RECORD
    tome = rec["tome_destinations"]
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "config.json").write_text(json.dumps(cfg, indent=2) + "\n")
    from safetensors.torch import save_file

    params = {k for k, _ in model.named_parameters()}
    half = args.size == "small"  # the committed fixture: f16 values, stored as f16
    state = {
        k: (v.half() if half and k in params else v).contiguous()
        for k, v in model.state_dict().items()
        if v.dtype.is_floating_point
    }
    save_weights(state, out)
    tensors = {
        "images": images,
        "anchors": coords,
        "normals": normals,
        **mtorch,  # BOOL, as PyTorch writes masks
        "pooling_orders": torch.tensor(rec["pooling_orders"], dtype=torch.int64),
        "tome_destinations": torch.tensor(tome, dtype=torch.uint8),
        "feature_image": feature_image,
        "features": latent[0].contiguous(),
        "offsets": gs.offset_xyz.contiguous(),
        "scales": gs.scaling.contiguous(),
        "rotations": gs.rotation.contiguous(),
        "opacities": gs.opacity.contiguous(),
        "colors": gs.shs.reshape(n, 3).contiguous(),
        "neural_rgb": ours(rgb),
        "neural_mask": ours(mask),
    }
    meta = {
        "size": args.size,
        "seed": args.seed,
        "official_commit": (pathlib.Path(args.official) / ".commit").read_text().strip()
        if (pathlib.Path(args.official) / ".commit").exists()
        else "unknown",
        "torch": torch.__version__,
        "dinov2": {"embed_dim": dino[0], "depth": dino[1], "num_heads": dino[2]}
        if dino
        else None,
        "dpt": {"features": dpt[0], "out_channels": list(dpt[1])} if dpt else None,
        "image_size": [H, W],
        "views": views,
        "points": n,
        "voxels": voxels,
        "clip_scaling": float(model.renderer.gs_net.clip_scaling),
        "tome_grids": rec["tome_grids"],
        "forward_s": forward_s,
        "neural_renderer_s": neural_s,
        "threads": torch.get_num_threads(),
    }
    save_file(
        {k: v.contiguous() for k, v in tensors.items()},
        str(out / "io.safetensors"),
        metadata={"lhmpp.fixture": json.dumps(meta)},
    )
    print(json.dumps({k: meta[k] for k in ("points", "voxels", "forward_s", "neural_renderer_s")}))
    print("pooling orders", rec["pooling_orders"])
    print("ToMe draws", [len(d) for d in tome], "grids", rec["tome_grids"])
    print({k: tuple(v.shape) for k, v in tensors.items()})


if __name__ == "__main__":
    main()
