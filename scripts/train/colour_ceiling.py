"""How much an input view says about each anchor's colour, at the encoder's patch grid.

For every anchor that an input view shows (`anchor_pixels` of `lhmpp synth-dataset`), compares
the anchor's true canonical colour with three guesses and prints their mean L1 (over the
channels, then over the views that see the anchor, then over anchors and people):

- the colour of the anchor's own pixel in the preprocessed input (what an ideal reader gets);
- the mean colour of the encoder patch (patch_size × patch_size) holding that pixel (what a
  token's average gives, if the points only average token values);
- the person's mean colour (what a network that ignores the images can do at best).

    python scripts/train/colour_ceiling.py target/train/dataset-px [--patch 14] [--people 40]
"""

import argparse
import glob
import os

import torch
from safetensors import safe_open


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data", help="folder of shards from `lhmpp synth-dataset`")
    ap.add_argument("--patch", type=int, default=14, help="encoder patch size in pixels")
    ap.add_argument("--people", type=int, default=40, help="people to measure")
    args = ap.parse_args()
    sums = {"pixel": 0.0, "patch": 0.0, "person": 0.0}
    anchors_seen = 0
    people = 0
    fill = []
    for path in sorted(glob.glob(os.path.join(args.data, "shard-*.safetensors"))):
        with safe_open(path, framework="pt") as f:
            keys = sorted({k.split(".")[0] for k in f.keys()}, key=int)
            for k in keys:
                if people >= args.people:
                    break
                if f"{k}.anchor_pixels" not in f.keys():
                    raise SystemExit(f"{path}: no anchor_pixels (made by an older synth-dataset)")
                images = f.get_tensor(f"{k}.images").float() / 255.0  # [V,3,H,W]
                px = f.get_tensor(f"{k}.anchor_pixels").to(torch.int64)  # [V,N,2]
                colors = f.get_tensor(f"{k}.colors")  # [N,3]
                v, _, h, w = images.shape
                p = args.patch
                gh, gw = h // p, w // p
                cropped = images[:, :, : gh * p, : gw * p]
                patch_mean = cropped.reshape(v, 3, gh, p, gw, p).mean(dim=(3, 5))  # [V,3,gh,gw]
                visible = px[..., 0] != 65535  # [V,N]
                x = px[..., 0].clamp(max=w - 1)
                y = px[..., 1].clamp(max=h - 1)
                vi = torch.arange(v)[:, None].expand_as(x)
                pixel = images[vi, :, y, x]  # [V,N,3]
                patch = patch_mean[vi, :, (y // p).clamp(max=gh - 1), (x // p).clamp(max=gw - 1)]
                person = colors.mean(0)
                seen = visible.sum(0)  # [N]
                keep = seen > 0
                for name, guess in (("pixel", pixel), ("patch", patch)):
                    err = (guess - colors[None]).abs().mean(-1) * visible  # [V,N]
                    sums[name] += (err.sum(0)[keep] / seen[keep]).sum().item()
                sums["person"] += (person[None] - colors[keep]).abs().mean(-1).sum().item()
                anchors_seen += int(keep.sum())
                rows = visible.any(1)
                ys = px[..., 1][visible]
                if rows.any() and ys.numel():
                    fill.append((ys.max() - ys.min()).item() / h)
                people += 1
        if people >= args.people:
            break
    if anchors_seen == 0:
        raise SystemExit("no visible anchor")
    print(f"{people} people, {anchors_seen} visible anchors, input {h}x{w}, patch {args.patch}")
    print(f"person's height in the input: {100 * sum(fill) / len(fill):.0f}% of the rows")
    for name in ("pixel", "patch", "person"):
        print(f"  {name:7s} L1 {sums[name] / anchors_seen:.3f}")


if __name__ == "__main__":
    main()
