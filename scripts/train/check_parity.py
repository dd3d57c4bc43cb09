"""Whole-network parity: the PyTorch twin (lhmpp_torch.py) against our binary
(`lhmpp model forward`) on the same checkpoint and inputs.

    check_parity.py --checkpoint FILE [--input IN.safetensors] [--bin target/release/lhmpp]
                    [--tol 1e-4] [--views 4] [--points 4096] [--train-steps K --lr LR]
                    [--randomize SEED]

Prints, per output tensor, max |ours - torch| / max |torch|, and exits 1 when any exceeds
--tol. Without --input it makes a deterministic input: --views images of the config's size in
[0, 1] (seeded) and the node's body anchors (`lhmpp model forward --dump-anchors`: MakeHuman
template, --points, seed 1). With --train-steps, K steps of SGD on the sum of the outputs' L1
are applied to the weights first; the result is written with save_checkpoint and that file is
compared instead (trained, non-init weights). With --randomize, every weight is first redrawn
as scripts/parity/generate.py does (fan-in matrices, norms near 1, visible biases, LayerScale
0.5..1.5: no branch hidden by a small init), then saved and compared the same way.
"""

import argparse
import os
import subprocess
import sys
import tempfile

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import lhmpp_torch as LT  # noqa: E402


def make_input(path, cfg, bin_path, views, points, seed, workdir):
    from safetensors.torch import load_file, save_file

    anchors_file = os.path.join(workdir, "anchors.safetensors")
    subprocess.run([bin_path, "model", "forward", "--dump-anchors", "--points", str(points),
                    "--seed", "1", "-o", anchors_file], check=True, stdout=subprocess.DEVNULL)
    a = load_file(anchors_file)
    gen = torch.Generator().manual_seed(seed)
    images = torch.rand(views, 3, cfg["image_height"], cfg["image_width"], generator=gen)
    save_file({"images": images, "anchors": a["anchors"], "normals": a["normals"]}, path)


def l1_loss(out):
    return sum(out[k].abs().mean() for k in LT.OUTPUT_NAMES)


def train(model, inputs, steps, lr):
    opt = torch.optim.SGD(model.parameters(), lr=lr)
    before = {k: v.detach().clone() for k, v in model.state_dict().items()}
    for step in range(steps):
        opt.zero_grad()
        loss = l1_loss(model(inputs["images"], inputs["anchors"], inputs["normals"]))
        loss.backward()
        opt.step()
        print(f"  sgd step {step}: loss {loss.item():.6f}")
    after = model.state_dict()
    delta = sum((after[k] - before[k]).double().pow(2).sum() for k in before).sqrt().item()
    norm = sum(before[k].double().pow(2).sum() for k in before).sqrt().item()
    biggest = max((after[k] - before[k]).abs().max().item() for k in before)
    print(f"  weights moved: |dw| / |w| = {delta / norm:.3g}, largest |dw| = {biggest:.3g}")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--input")
    ap.add_argument("--bin", default="target/release/lhmpp")
    ap.add_argument("--tol", type=float, default=1e-4)
    ap.add_argument("--views", type=int, default=4)
    ap.add_argument("--points", type=int, default=4096)
    ap.add_argument("--image-seed", type=int, default=0)
    ap.add_argument("--randomize", type=int, help="redraw all weights with this seed first")
    ap.add_argument("--train-steps", type=int, default=0)
    ap.add_argument("--lr", type=float, default=0.05)
    ap.add_argument("--workdir", help="keep the intermediate files here (default: a temp dir)")
    ap.add_argument("--threads", type=int, default=2)
    args = ap.parse_args()
    from safetensors.torch import load_file

    torch.set_num_threads(args.threads)
    workdir = args.workdir or tempfile.mkdtemp(prefix="lhmpp_parity_")
    os.makedirs(workdir, exist_ok=True)
    model = LT.load_checkpoint(args.checkpoint)
    cfg = model.cfg
    inp = args.input
    if inp is None:
        inp = os.path.join(workdir, "input.safetensors")
        make_input(inp, cfg, args.bin, args.views, args.points, args.image_seed, workdir)
    inputs = load_file(inp)
    ckpt = args.checkpoint
    if args.randomize is not None:
        sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "parity"))
        import generate

        generate.randomize(model, torch.Generator().manual_seed(args.randomize))
        with torch.no_grad():  # scale logits around the clamp, as generate.py's GS head
            model.renderer.gs_net.out_layers["scaling"].bias -= 4.0
    if args.train_steps:
        train(model, inputs, args.train_steps, args.lr)
    if args.randomize is not None or args.train_steps:
        ckpt = os.path.join(workdir, "trained.safetensors")
        LT.save_checkpoint(model, ckpt)
        model = LT.load_checkpoint(ckpt)  # round trip through the file the binary reads
    with torch.no_grad():
        ref = model(inputs["images"], inputs["anchors"], inputs["normals"])
    out_file = os.path.join(workdir, "ours.safetensors")
    run = subprocess.run([args.bin, "model", "forward", "--checkpoint", ckpt, "--input", inp,
                          "-o", out_file], check=True, capture_output=True, text=True)
    print(run.stdout.strip())
    ours = load_file(out_file)
    geo = model.geometry(inputs["anchors"], inputs["normals"])
    v = inputs["images"].shape[0]
    print(f"checkpoint {ckpt}: {v} views, {inputs['anchors'].shape[0]} anchors, voxels per level "
          f"{geo.summary()}")
    print(f"| {'output':<10} | {'shape':<12} | {'max |torch|':>11} | {'max abs diff':>12} | {'rel':>9} |")
    worst = 0.0
    for k in LT.OUTPUT_NAMES:
        a, b = ours[k].double(), ref[k].double()
        if a.shape != b.shape:
            print(f"| {k:<10} | shape mismatch ours {tuple(a.shape)} torch {tuple(b.shape)}")
            worst = float("inf")
            continue
        scale = b.abs().max().item()
        diff = (a - b).abs().max().item()
        rel = diff / max(scale, 1e-30)
        worst = max(worst, rel)
        print(f"| {k:<10} | {str(tuple(b.shape)):<12} | {scale:>11.4g} | {diff:>12.3e} | {rel:>9.2e} |")
    ok = worst <= args.tol
    print(f"worst relative error {worst:.3e} (tol {args.tol:g}): {'OK' if ok else 'FAIL'}")
    sys.exit(0 if ok else 1)


if __name__ == "__main__":
    main()
