"""Trains the `tiny` LHM++ of this repo on synthetic people (shards from `lhmpp synth-dataset`).

The network is the PyTorch twin of our Rust forward (lhmpp_torch.py, checked against our binary
by check_parity.py); losses follow the paper where they apply:
  - L1 colour and mask of the posed Gaussians splatted into target cameras (held-out views
    and one input view; splat_torch.py), lambda_rgb = 1, lambda_mask = 0.5;
  - direct L1 on the canonical colour of every anchor (synthetic ground truth);
  - ASAP (isotropic scales, lambda 20) and ACAP (offsets within 2 cm, lambda 5) regularisers.
AdamW, seeded, resumable (state.pt every --save-every steps), a progress line (step, loss,
steps/s, ETA), log.txt, loss.png and config.json beside the weights.

Data parallel on the CPU (`--workers`, default 2): each worker process runs one thread on its own
sample and the gradients are averaged every step (gloo all-reduce), so a step is a batch of
`--workers` people. On 2 cores two one-thread workers do 1.45x the samples/s of one two-thread
process: at these widths most ops are too small to split across threads.

Usage (scripts/train/run does all of it):
  python scripts/train/train.py --data target/dataset --out target/train [--steps N]
      [--max-minutes M] [--resume]
"""

import argparse
import json
import math
import os
import random
import sys
import time

import torch
import torch.nn.functional as F
from safetensors import safe_open

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import attention_supervision  # noqa: E402
import patch_supervision  # noqa: E402
import lhmpp_torch  # noqa: E402
import splat_torch  # noqa: E402


def load_shards(folder, names=None):
    """All samples of the shards `names` (default: every shard) in `folder`, as dicts of
    tensors (u8 images kept as u8)."""
    samples = []
    if names is None:
        names = sorted(f for f in os.listdir(folder) if f.endswith(".safetensors"))
    if not names:
        sys.exit(f"{folder}: no shard-*.safetensors (make them with `lhmpp synth-dataset`)")
    for name in names:
        path = os.path.join(folder, name)
        with safe_open(path, framework="pt") as f:
            meta = f.metadata() or {}
            if meta.get("format") != "lhmpp-training-shard-v1":
                sys.exit(f"{path}: not an lhmpp training shard (format {meta.get('format')!r})")
            seeds = [int(s) for s in meta["seeds"].split(",")]
            for k, seed in enumerate(seeds):
                s = {key: f.get_tensor(f"{k}.{key}") for key in (
                    "images", "anchors", "normals", "colors", "posed_anchors", "posed_rotations",
                    "target_rgb", "target_alpha", "target_intrinsics", "target_camera_from_world")}
                if f"{k}.anchor_pixels" in f.keys():
                    s["anchor_pixels"] = f.get_tensor(f"{k}.anchor_pixels").to(torch.int32)
                if f"{k}.anchor_surface" in f.keys():
                    s["anchor_surface"] = f.get_tensor(f"{k}.anchor_surface")
                s["seed"] = seed
                samples.append(s)
    return samples


PER_ANCHOR = ("anchors", "normals", "colors", "posed_anchors", "posed_rotations", "anchor_surface")


def subsample(s, n):
    """The sample with only its first `n` anchors (the anchors are drawn i.i.d., so a prefix is
    a uniform subset of the body surface)."""
    if n >= s["anchors"].shape[0]:
        return s
    out = dict(s)
    for k in PER_ANCHOR:
        if k in s:
            out[k] = s[k][:n]
    if "anchor_pixels" in s:
        out["anchor_pixels"] = s["anchor_pixels"][:, :n]
    return out


def white_views(s):
    """The sample with only its views on a white background (all four corners white), or
    None when it has none (for the first phase: no background to explain away)."""
    im = s["images"]
    corners = torch.stack([im[:, :, 0, 0], im[:, :, 0, -1], im[:, :, -1, 0], im[:, :, -1, -1]], 1)
    keep = (corners >= 250).flatten(1).all(1)
    if not keep.any():
        return None
    out = dict(s)
    out["images"] = im[keep]
    if "anchor_pixels" in s:
        out["anchor_pixels"] = s["anchor_pixels"][keep]
    return out


def colour_transform(rng):
    """A random 3x3 colour transform: a hue rotation about the grey axis (any angle), a
    saturation scale (0.6-1.4), per-channel gains (0.85-1.15) and a brightness (0.8-1.2)."""
    theta = rng.uniform(-math.pi, math.pi)
    axis = torch.ones(3) / math.sqrt(3.0)
    k = torch.tensor([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    rotation = torch.eye(3) + math.sin(theta) * k + (1.0 - math.cos(theta)) * (k @ k)
    grey = torch.full((3, 3), 1.0 / 3.0)
    saturation = rng.uniform(0.6, 1.4)
    mix = grey + saturation * (rotation - grey)
    gains = torch.diag(torch.tensor([rng.uniform(0.85, 1.15) for _ in range(3)]))
    return rng.uniform(0.8, 1.2) * gains @ mix


def colour_augment(s, rng):
    """The sample with one random colour transform (`colour_transform`) applied to the person's
    colours on both sides: the input views' pixels (background white stays white), the anchors'
    ground-truth colours and the person's pixels of the target renders (their white background
    kept), so the network learns to carry the colours it sees instead of a palette of likely
    ones."""
    m = colour_transform(rng)
    out = dict(s)
    images = s["images"].float() / 255.0
    white = (images >= 250.0 / 255.0).all(1, keepdim=True)
    moved = torch.einsum("ij,vjhw->vihw", m, images).clamp(0.0, 1.0)
    out["images"] = (torch.where(white, images, moved) * 255.0).round().to(torch.uint8)
    out["colors"] = (s["colors"] @ m.T).clamp(0.0, 1.0)
    rgb = s["target_rgb"].float() / 255.0
    alpha = (s["target_alpha"].float() / 255.0).unsqueeze(1)
    person = ((rgb - (1.0 - alpha)) / alpha.clamp_min(1e-3)).clamp(0.0, 1.0)
    person = torch.einsum("ij,tjhw->tihw", m, person).clamp(0.0, 1.0)
    out["target_rgb"] = ((alpha * person + (1.0 - alpha)) * 255.0).round().to(torch.uint8)
    return out


def open_gates(model):
    """Opens the gated branches of the fresh network: the PIT blocks' AdaLN-Zero gates start at
    1 instead of ~0 (bias of the gate chunks), the encoder's LayerScale at 1 and the frame
    blocks' at 0.5, so image content reaches the CLS token, the conditioning and the points
    from the first step instead of through branches scaled by 1e-1..1e-2."""
    with torch.no_grad():
        for blocks in (model.transformer.pi_transformer_enc, model.transformer.pi_transformer_dec):
            for b in blocks:
                for norm in (b.norm1, b.norm1_context):
                    lin = norm.linear
                    d = lin.bias.shape[0] // 6
                    if lin.bias.shape[0] == 6 * d:  # AdaLayerNormZero: shift, scale, gate, x2
                        lin.bias[2 * d:3 * d] = 1.0
                        lin.bias[5 * d:6 * d] = 1.0
        for name, p in model.named_parameters():
            if name.startswith("transformer.image_backbone.") and name.endswith(".gamma"):
                p.fill_(0.5)
            if name.startswith("encoder.model.blocks.") and name.endswith(".gamma"):
                p.fill_(1.0)


BANDS = (0.0, 0.1, 0.5, 0.8, 1.01)


def band_colors(s):
    """Mean ground-truth colour of the anchors in four height bands of the canonical body
    (shoes, trousers, shirt, head): the target of the conditioning probe, `[12]`."""
    y = s["anchors"][:, 1]
    h = (y - y.min()) / (y.max() - y.min()).clamp_min(1e-6)
    out = []
    for lo, hi in zip(BANDS[:-1], BANDS[1:]):
        sel = (h >= lo) & (h < hi)
        out.append(s["colors"][sel].mean(0) if sel.any() else torch.full((3,), 0.5))
    return torch.cat(out)


def offset_allowance(anchors, reach):
    """How far each anchor's Gaussian may sit from it before ACAP penalises the offset: `reach`
    = (torso, legs, head) in metres; legs below 55% of the body height (skirts, coat hems),
    head above 85% (hair)."""
    y = anchors[:, 1]
    h = (y - y.min()) / (y.max() - y.min()).clamp_min(1e-6)
    torso, legs, head = reach
    allow = torch.full_like(y, torso)
    allow = torch.where(h < 0.55, torch.full_like(y, legs), allow)
    return torch.where(h > 0.85, torch.full_like(y, head), allow)


def losses(model, s, weights, probe=None, attention=None, patch=None, encoder=None, reach=(0.02, 0.02, 0.02)):
    """The training losses of one sample: a dict of scalar tensors (and `total`).

    With `probe` (a trainer-only linear map, not part of the shipped network), the conditioning
    vector temb (mean over views of motion_embed_mlp(CLS), which modulates every PIT block) is
    also asked to predict the person's band colours: it makes the image encoder's global token
    carry the clothing colours, which the points then read through their AdaLN modulation.

    With `attention` (an attention_supervision.AttentionCapture) and a sample that carries
    `anchor_pixels`, one head of the last PIT block is asked to attend to the image tokens that
    show each anchor (trainer only; `attn`).

    With `patch` (a patch_supervision.PatchHead), `encoder` (its EncoderCapture) and a sample
    that carries `patch_targets`, the encoder's patch tokens are asked for the colour and
    canonical position of the anchors each patch shows (trainer only; `patch`)."""
    images = s["images"].float() / 255.0
    out = model(images, s["anchors"], s["normals"])
    means, quats = splat_torch.pose_gaussians(out, s["posed_anchors"], s["posed_rotations"])
    rgb_l, mask_l = 0.0, 0.0
    targets = s["target_rgb"].shape[0]
    size = s["target_rgb"].shape[-1]
    for t in range(targets):
        rgb, alpha = splat_torch.render(
            means, quats, out["scales"], out["opacities"], out["colors"],
            s["target_intrinsics"][t], s["target_camera_from_world"][t], size)
        rgb_l = rgb_l + (rgb - s["target_rgb"][t].float() / 255.0).abs().mean()
        mask_l = mask_l + (alpha - s["target_alpha"][t].float() / 255.0).abs().mean()
    rgb_l, mask_l = rgb_l / targets, mask_l / targets
    color = (out["colors"] - s["colors"]).abs().mean()
    sc = out["scales"]
    asap = ((sc - sc.mean(-1, keepdim=True)) ** 2).sum(-1).mean()
    acap = F.relu(out["offsets"].norm(dim=-1) - offset_allowance(s["anchors"], reach)).mean()
    parts = {"rgb": rgb_l, "mask": mask_l, "color": color, "asap": asap, "acap": acap}
    if weights.get("surface", 0.0) > 0 and "anchor_surface" in s:
        # Dressed samples: each Gaussian on the outermost surface over its anchor (the garment).
        position = s["anchors"] + out["offsets"]
        parts["surface"] = (position - s["anchor_surface"]).abs().sum(-1).mean()
    if attention is not None and "anchor_pixels" in s:
        attn = attention.loss(s, model.cfg["encoder"]["patch_size"])
        if attn is not None:
            parts["attn"] = attn
    if patch is not None and "patch_targets" in s:
        target, shown = s["patch_targets"]
        p = patch.loss(encoder.last[1], target, shown)
        if p is not None:
            parts["patch"] = p
    if probe is not None:
        cls = encoder.last[0] if encoder is not None else model.encode(images)[0]
        temb = model.motion_embed_mlp(cls).mean(0)
        parts["probe"] = (torch.sigmoid(probe(temb)) - band_colors(s)).abs().mean()
    parts["total"] = sum(weights[k] * v for k, v in parts.items())
    return parts


def lr_at(progress, peak, warmup):
    """Linear warm-up over the first `warmup` of the run, then cosine decay to 1e-5 (both in
    run fractions, so a time-budgeted run decays on time)."""
    if progress < warmup:
        return peak * max(progress, 1e-3) / warmup
    t = (progress - warmup) / max(1e-9, 1 - warmup)
    return 1e-5 + 0.5 * (peak - 1e-5) * (1 + math.cos(math.pi * min(1.0, t)))


def plot(history, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = [h["step"] for h in history]
    fig, ax = plt.subplots(figsize=(8, 4.5))
    for key in ("total", "rgb", "mask", "color", "attn", "patch"):
        if not any(key in h for h in history):
            continue
        ys = [h.get(key, 0.0) for h in history]
        # Smoothed over 50 steps so the trend shows through the per-sample noise.
        k = 50
        sm = [sum(ys[max(0, i - k + 1): i + 1]) / len(ys[max(0, i - k + 1): i + 1]) for i in range(len(ys))]
        ax.plot(steps, sm, label=key)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("loss (50-step mean)")
    ax.set_title("lhmpp tiny on synthetic people")
    ax.legend()
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def fmt_time(seconds):
    seconds = int(max(0, seconds))
    return f"{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}"


# Scalars reduced across workers every step, in this order (missing ones count as 0).
LOSS_KEYS = ("total", "rgb", "mask", "color", "asap", "acap", "probe", "attn", "patch", "surface")


def parse_args():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", required=True, help="folder of shards from `lhmpp synth-dataset`")
    ap.add_argument("--out", required=True, help="run folder (state, log, plot, weights)")
    ap.add_argument("--config", default=None, help="network config JSON (default: the tiny preset dump in --out)")
    ap.add_argument("--init", default=None, help="initial weights (safetensors, our layout)")
    ap.add_argument("--steps", type=int, default=6000)
    ap.add_argument("--max-minutes", type=float, default=0.0, help="stop (and save) after this long")
    ap.add_argument("--lr", type=float, default=1e-3)
    ap.add_argument("--warmup", type=int, default=200)
    ap.add_argument("--weight-decay", type=float, default=0.01)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--workers", type=int, default=2,
                    help="data-parallel worker processes (one sample each per step, gradients averaged)")
    ap.add_argument("--threads", type=int, default=0,
                    help="threads per worker (default: the CPU count divided by --workers)")
    ap.add_argument("--save-every", type=int, default=200)
    ap.add_argument("--resume", action="store_true")
    ap.add_argument("--white-first", type=float, default=0.0,
                    help="until this fraction of the run, use only the views on white")
    ap.add_argument("--probe", action="store_true",
                    help="auxiliary loss: a linear probe on temb predicts the band colours")
    ap.add_argument("--attention", type=float, default=0.0,
                    help="weight of the attention supervision (needs shards with anchor_pixels)")
    ap.add_argument("--patch", type=float, default=0.0,
                    help="weight of the patch supervision (needs shards with anchor_pixels)")
    ap.add_argument("--surface", type=float, default=0.0,
                    help="weight of the L1 between each Gaussian's canonical position and the "
                         "outermost surface over its anchor (dressed samples' anchor_surface)")
    ap.add_argument("--reach", default="0.02,0.02,0.02",
                    help="offsets ACAP leaves unpenalised, metres: torso,legs,head (legs below "
                         "55%% of the height: skirts and coat hems; head above 85%%: hair)")
    ap.add_argument("--colour-aug", type=float, default=0.0,
                    help="fraction of samples whose person colours (inputs and every colour "
                         "target alike) go through a random colour transform")
    ap.add_argument("--open-gates", action="store_true",
                    help="open the PIT gates and frame-block LayerScale of the initial weights")
    ap.add_argument("--points-schedule", default="",
                    help="anchors per phase, e.g. 1024:0.4,2048:0.65,4096:1 (fractions of the "
                         "run: of --max-minutes when set, else of --steps)")
    ap.add_argument("--geometry-cache-mb", type=float, default=3000.0,
                    help="memory per worker for the cached point geometry of the samples")
    args = ap.parse_args()
    if args.workers < 1:
        sys.exit("--workers must be at least 1")
    if args.threads <= 0:
        args.threads = max(1, (os.cpu_count() or 1) // args.workers)
    return args


def free_port():
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def main():
    args = parse_args()
    if args.workers == 1:
        worker(0, args, None)
    else:
        import torch.multiprocessing as mp

        mp.spawn(worker, args=(args, free_port()), nprocs=args.workers, join=True)


def shard_folder_for(rank, world, folder):
    """The shard files worker `rank` of `world` trains on: every world-th shard (all of them
    when there are fewer shards than workers), so the workers hold disjoint people."""
    names = sorted(f for f in os.listdir(folder) if f.endswith(".safetensors"))
    if len(names) < world:
        return names
    return names[rank::world]


def worker(rank, args, port):
    import torch.distributed as dist

    world = args.workers
    if world > 1:
        os.environ["MASTER_ADDR"] = "127.0.0.1"
        os.environ["MASTER_PORT"] = str(port)
        dist.init_process_group("gloo", rank=rank, world_size=world)
    lead = rank == 0
    torch.set_num_threads(args.threads)
    os.makedirs(args.out, exist_ok=True)
    weights = {"rgb": 1.0, "mask": 0.5, "color": 1.0, "asap": 20.0, "acap": 5.0, "probe": 1.0,
               "attn": args.attention, "patch": args.patch, "surface": args.surface}
    reach = tuple(float(v) for v in args.reach.split(","))
    state_path = os.path.join(args.out, "state.pt")
    log = open(os.path.join(args.out, "log.txt"), "a") if lead else None

    def say(line):
        if lead:
            print(line, flush=True)
            log.write(line + "\n")
            log.flush()

    samples = load_shards(args.data, shard_folder_for(rank, world, args.data))
    seeds = [s["seed"] for s in samples]
    cfg_path = args.config or args.init
    if not cfg_path:
        sys.exit("--config or --init is required (the network config)")
    if args.init:
        model = lhmpp_torch.load_checkpoint(args.init, cfg=args.config)
    else:
        model = lhmpp_torch.LhmppTorch.from_config_json(cfg_path)
    if args.open_gates and not (args.resume and os.path.exists(state_path)):
        open_gates(model)
    schedule = []
    for part in filter(None, args.points_schedule.split(",")):
        n, until = part.split(":")
        schedule.append((int(n), float(until)))
    params = [p for p in model.parameters() if p.requires_grad]
    decay = [p for p in params if p.dim() >= 2]
    no_decay = [p for p in params if p.dim() < 2]
    opt = torch.optim.AdamW(
        [{"params": decay, "weight_decay": args.weight_decay}, {"params": no_decay, "weight_decay": 0.0}],
        lr=args.lr, betas=(0.9, 0.99))
    attention = attention_supervision.AttentionCapture(model) if args.attention > 0 else None
    if attention is not None and not any("anchor_pixels" in x for x in samples):
        sys.exit(f"--attention: no shard in {args.data} has anchor_pixels (remake it with `lhmpp synth-dataset`)")
    if args.patch > 0 and not any("anchor_pixels" in x for x in samples):
        sys.exit(f"--patch: no shard in {args.data} has anchor_pixels (remake it with `lhmpp synth-dataset`)")
    encoder = patch_supervision.EncoderCapture(model)
    patch_size = model.cfg["encoder"]["patch_size"]
    # The same seed on every worker: the trainer-only heads start identical everywhere.
    torch.manual_seed(args.seed)
    aux = torch.nn.ModuleDict()
    if args.probe:
        aux["probe"] = torch.nn.Linear(model.cfg["transformer"]["transformer_dim"], 12)
    if args.patch > 0:
        aux["patch"] = patch_supervision.PatchHead(model.cfg["encoder"]["embed_dim"])
    probe, patch = aux["probe"] if args.probe else None, aux["patch"] if args.patch > 0 else None
    aux_opt = torch.optim.AdamW(aux.parameters(), lr=args.lr) if len(aux) else None
    synced = params + list(aux.parameters())
    step, history, elapsed_before = 0, [], 0.0
    if args.resume and os.path.exists(state_path):
        st = torch.load(state_path, weights_only=False)
        model.load_state_dict(st["model"])
        opt.load_state_dict(st["optimizer"])
        step, history, elapsed_before = st["step"], st["history"], st.get("elapsed", 0.0)
        if aux_opt is not None and "aux" in st:
            aux.load_state_dict(st["aux"])
            aux_opt.load_state_dict(st["aux_optimizer"])
        say(f"resumed at step {step} from {state_path}")
    # Each worker draws its own people; a resumed run draws from where it stopped.
    random.seed(f"{args.seed}/{rank}/{step}")
    all_seeds = seeds
    if world > 1:
        gathered = [None] * world
        dist.all_gather_object(gathered, seeds)
        all_seeds = [s for g in gathered for s in g]
    config = {
        "data": os.path.abspath(args.data), "samples": len(all_seeds),
        "seeds": f"{min(all_seeds)}..{max(all_seeds) + 1}", "steps": args.steps, "lr": args.lr,
        "warmup": args.warmup, "weight_decay": args.weight_decay, "seed": args.seed,
        "workers": world, "threads_per_worker": args.threads, "batch": world,
        "loss_weights": weights, "open_gates": args.open_gates,
        "white_first": args.white_first, "probe": args.probe, "attention": args.attention,
        "patch": args.patch, "colour_aug": args.colour_aug, "surface": args.surface,
        "reach": args.reach,
        "init": os.path.abspath(args.init) if args.init else None,
        "points_schedule": args.points_schedule, "max_minutes": args.max_minutes, "optimizer": "AdamW(0.9, 0.99)",
        "torch": torch.__version__,
        "parameters": sum(p.numel() for p in params),
    }
    if lead:
        with open(os.path.join(args.out, "config.json"), "w") as f:
            json.dump(config, f, indent=2)
    say(f"training {config['parameters']} parameters on {len(all_seeds)} samples "
        f"(seeds {config['seeds']}), {args.steps} steps, {world} worker(s) x {args.threads} thread(s)")

    def save():
        extra = {} if aux_opt is None else {"aux": aux.state_dict(),
                                            "aux_optimizer": aux_opt.state_dict()}
        torch.save({**extra, "model": model.state_dict(), "optimizer": opt.state_dict(), "step": step,
                    "history": history, "elapsed": elapsed_before + time.time() - t0},
                   state_path + ".tmp")
        os.replace(state_path + ".tmp", state_path)
        plot(history, os.path.join(args.out, "loss.png"))

    def draw(progress, points):
        """A random sample of this worker's people, as the phase of the run wants it."""
        while True:
            s = samples[random.randrange(len(samples))]
            if progress < args.white_first:
                s = white_views(s)
                if s is None:
                    continue
            if args.colour_aug > 0 and random.random() < args.colour_aug:
                s = colour_augment(s, random)
            if patch is not None and "anchor_pixels" in s:
                s = dict(s)
                s["patch_targets"] = patch_supervision.patch_targets(s, patch_size)
            return subsample(s, points) if points else s

    t0 = time.time()
    start_step = step
    model.train()
    while step < args.steps:
        # The lead worker's clock decides the phase and the stop, for every worker.
        elapsed = elapsed_before + time.time() - t0
        progress = step / args.steps
        if args.max_minutes:
            progress = max(progress, elapsed / (60 * args.max_minutes))
        stop = bool(args.max_minutes) and elapsed > 60 * args.max_minutes
        if world > 1:
            clock = torch.tensor([progress, float(stop)], dtype=torch.float64)
            dist.broadcast(clock, 0)
            progress, stop = float(clock[0]), bool(clock[1] > 0)
        if stop:
            say(f"time budget of {args.max_minutes} min reached at step {step}")
            break
        points = next((n for n, until in schedule if progress < until), None)
        # Geometry per sample is cached (it depends only on the anchors): as much as fits
        # (measured: 2.9 MB per sample at 1,024 anchors, 8.1 MB at 4,096).
        model.geometry_cache_size = max(64, int(args.geometry_cache_mb * 1e6 / (2900 * (points or 4096))))
        s = draw(progress, points)
        for g in opt.param_groups:
            g["lr"] = lr_at(progress, args.lr, args.warmup / args.steps)
        parts = losses(model, s, weights, probe, attention, patch, encoder, reach)
        opt.zero_grad(set_to_none=True)
        if aux_opt is not None:
            aux_opt.zero_grad(set_to_none=True)
        parts["total"].backward()
        scalars = torch.tensor([float(parts[k].detach()) if k in parts else 0.0 for k in LOSS_KEYS],
                               dtype=torch.float32)
        if world > 1:
            # One all-reduce of every gradient and the loss scalars: the mean over the batch.
            grads = [p.grad if p.grad is not None else torch.zeros_like(p) for p in synced]
            flat = torch.cat([g.reshape(-1) for g in grads] + [scalars])
            dist.all_reduce(flat)
            flat /= world
            offset = 0
            for p in synced:
                n = p.numel()
                p.grad = flat[offset:offset + n].view_as(p).clone()
                offset += n
            scalars = flat[offset:]
        torch.nn.utils.clip_grad_norm_(params, 1.0)
        opt.step()
        if aux_opt is not None:
            aux_opt.step()
        step += 1
        mean_parts = {k: float(v) for k, v in zip(LOSS_KEYS, scalars) if k in parts}
        history.append({"step": step, "points": s["anchors"].shape[0], **mean_parts})
        if lead and (step % 10 == 0 or step == args.steps):
            rate = (step - start_step) / max(1e-9, time.time() - t0)
            eta = (args.steps - step) / max(rate, 1e-9)
            if args.max_minutes:
                eta = min(eta, 60 * args.max_minutes - (elapsed_before + time.time() - t0))
            recent = history[-50:]
            mean = {k: sum(h.get(k, 0.0) for h in recent) / len(recent) for k in mean_parts}
            probe_text = f" probe {mean['probe']:.4f}" if "probe" in mean else ""
            if "attn" in mean:
                probe_text += f" attn {mean['attn']:.3f}"
            if "patch" in mean:
                probe_text += f" patch {mean['patch']:.4f}"
            if "surface" in mean:
                probe_text += f" surface {mean['surface']:.4f}"
            say(f"step {step}/{args.steps}  {s['anchors'].shape[0]} pts  lr {opt.param_groups[0]['lr']:.2e}  loss {mean['total']:.4f} (rgb {mean['rgb']:.4f} "
                f"mask {mean['mask']:.4f} color {mean['color']:.4f} asap {mean['asap']:.2e} "
                f"acap {mean['acap']:.2e}{probe_text})  {rate:.2f} steps/s ({rate * world:.2f} samples/s)  ETA {fmt_time(eta)}")
        if lead and step % args.save_every == 0:
            save()
    if lead:
        save()
        model.eval()
        lhmpp_torch.save_checkpoint(model, os.path.join(args.out, "model.safetensors"))
        say(f"saved {os.path.join(args.out, 'model.safetensors')} at step {step} "
            f"({fmt_time(elapsed_before + time.time() - t0)} of training)")
    if world > 1:
        dist.destroy_process_group()


if __name__ == "__main__":
    main()
