"""PyTorch twin of the whole LHM++ forward pass of our Rust network (`Lhmpp::reconstruct` in
src/model/lhmpp.rs), for training on the CPU and shipping weights back to the Rust node.

The blocks are the parity-checked twins of scripts/parity/reference.py (DINOv2 encoder, VGGT
frame block, SD3 joint block, PTv3 block, Gaussian head, DPT renderer); this file adds the glue,
mirrored from the Rust:

- `lhmpp.rs`: fuse (encoder PIT levels interleaved with the frame blocks, decoder levels with
  the last keys metric), point_step (points in the level's Hilbert order around each joint
  block), multi_modal_step (special tokens stripped, ToMe merge over the `h x w*V` grid, joint
  block, unmerge, special tokens re-attached);
- `token_merge.rs`: ToMe bipartite matching with top-left destinations of each 2x2 cell; the
  plan is computed without grad from the keys metric, merge (mean) and unmerge (copy) are
  differentiable gathers;
- `frame_block.rs`: pose/register special tokens (variant 0 for view 0, 1 for the others);
- `point/*`: CenterShift, 1 cm GridSample keeping the first point of each voxel, stem
  Linear+LN+GELU, GridPooling (Linear, max over the cluster, LN, GELU), GridUnpooling
  (proj + proj_skip), serialized patch attention with PTv3 padding, submanifold conv;
- `gs_head.rs`: the Gaussian head (via reference.GsHead).

The submanifold 3x3x3 conv is a gather over a 27-neighbour table (numerically the dense
conv3d of reference.py, much faster). Every discrete structure that depends only on the
anchors and normals (grid sample, serializations, neighbour tables, pooling clusters, patch
gathers, Hilbert orders) is computed once per point set and cached (key: hash of the arrays).

State-dict keys are our checkpoint's (the official LHM++ names), so
`model.load_state_dict(safetensors.torch.load_file(ckpt))` loads a file written by
`lhmpp model init` (strict), and `save_checkpoint` writes one our Rust loader accepts.

    from lhmpp_torch import LhmppTorch, load_checkpoint, save_checkpoint
    model = load_checkpoint("tiny.safetensors")          # config from the file's metadata
    out = model(images, anchors, normals)                # dict of tensors, differentiable
    save_checkpoint(model, "trained.safetensors")
"""

import collections
import hashlib
import json
import math
import os
import sys

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "parity"))
import reference as R  # noqa: E402

META_PRESET = "lhmpp.preset"
META_CONFIG = "lhmpp.config"
SPECIAL_TOKENS = 5
TOME_STRIDE = 2
OUTPUT_NAMES = ("features", "colors", "scales", "rotations", "opacities", "offsets", "positions")


# --------------------------------------------------------------------------------------------
# Config


def read_config(src):
    """LhmppConfig as a dict from: a dict, a JSON string, a `.json` file, or a safetensors
    checkpoint (the `lhmpp.config` metadata our `model init` / `save_checkpoint` write)."""
    if isinstance(src, dict):
        return json.loads(json.dumps(src))
    src = str(src)
    if os.path.exists(src):
        if src.endswith(".safetensors"):
            from safetensors import safe_open

            with safe_open(src, framework="pt") as f:
                meta = f.metadata() or {}
            if META_CONFIG not in meta:
                raise ValueError(f"{src}: no `{META_CONFIG}` in the safetensors metadata")
            return json.loads(meta[META_CONFIG])
        with open(src) as f:
            return json.load(f)
    return json.loads(src)


# --------------------------------------------------------------------------------------------
# Discrete geometry (numpy, no grad), mirrored from src/model/point/{grid,serialization}.rs


def pack_cells(g):
    """Sortable key of non-negative cells [M, 3] (x most significant), as grid::pack_cell."""
    g = g.astype(np.int64)
    return (g[:, 0] << 42) | (g[:, 1] << 21) | g[:, 2]


def center_shift(coords):
    """CenterShift(apply_z=True) in f32: x, y centred on the bounding box, min z to 0."""
    lo, hi = coords.min(0), coords.max(0)
    shift = np.array([(lo[0] + hi[0]) / np.float32(2), (lo[1] + hi[1]) / np.float32(2), lo[2]],
                     dtype=np.float32)
    return (coords - shift).astype(np.float32)


def cluster_cells(grid):
    """Unique cells sorted lexicographically, member -> cell map, lowest member per cell and
    the members grouped by cell (ascending inside a cell), as grid::cluster_cells."""
    keys = pack_cells(grid)
    _, heads, cluster = np.unique(keys, return_index=True, return_inverse=True)
    cluster = cluster.reshape(-1)
    members = np.argsort(cluster, kind="stable")
    counts = np.bincount(cluster, minlength=len(heads))
    return grid[heads], cluster, heads, members, counts


def grid_sample(shifted, grid_size):
    """GridSample: floor(c / grid_size) - min, first point of each voxel kept."""
    cells = np.floor(shifted / np.float32(grid_size)).astype(np.int64)
    g = cells - cells.min(0)
    grid, cluster, heads, _, _ = cluster_cells(g)
    return grid, heads, cluster


def serialization_depth(grid):
    return int(grid.max() + 1).bit_length()


def serialize_order(grid, kind, depth):
    """Sequence position -> point for one order (`Z`, `ZTrans`, `Hilbert`, `HilbertTrans`)."""
    g = torch.from_numpy(grid.astype(np.int64))
    if kind in ("ZTrans", "HilbertTrans"):
        g = g[:, [1, 0, 2]]
    code = R.morton_code(g) if kind in ("Z", "ZTrans") else R.hilbert_code(g, depth)
    order = torch.argsort(code, stable=True)
    inverse = torch.empty_like(order)
    inverse[order] = torch.arange(order.shape[0])
    return order, inverse


def neighbour_table(grid):
    """[M, 27] row of the active neighbour at each kernel offset (kx, ky, kz in {-1,0,1},
    index (dx+1)*9 + (dy+1)*3 + (dz+1)), M (a zero row) where there is none."""
    m = grid.shape[0]
    keys = pack_cells(grid)
    order = np.argsort(keys, kind="stable")
    sorted_keys = keys[order]
    table = np.full((m, 27), m, dtype=np.int64)
    g = grid.astype(np.int64)
    for k in range(27):
        o = np.array([k // 9 - 1, (k // 3) % 3 - 1, k % 3 - 1], dtype=np.int64)
        n = g + o
        valid = np.all((n >= 0) & (n < (1 << 21)), axis=1)
        nk = pack_cells(np.where(valid[:, None], n, 0))
        pos = np.clip(np.searchsorted(sorted_keys, nk), 0, m - 1)
        hit = valid & (sorted_keys[pos] == nk)
        table[hit, k] = order[pos[hit]]
    return torch.from_numpy(table)


def patch_padding(n, k):
    """PTv3 padding: slot -> position in the order; the last patch's tail repeats the previous
    patch's slots (block::patch_padding)."""
    n_pad = n if n <= k else -(-n // k) * k
    pad = np.arange(n_pad, dtype=np.int64)
    if n_pad != n:
        r = n % k
        for s in range(n_pad - k + r, n_pad):
            pad[s] = pad[s - k]
    return pad


class Level:
    """Geometry of one point level: cells, serializations, neighbour table, patch gathers."""

    def __init__(self, grid, orders):
        self.grid = grid
        self.n = grid.shape[0]
        depth = serialization_depth(grid)
        self.order_kinds = list(orders)
        self.orders = [serialize_order(grid, kind, depth) for kind in orders]
        if "Hilbert" in self.order_kinds:
            self.hilbert = self.orders[self.order_kinds.index("Hilbert")]
        else:
            self.hilbert = serialize_order(grid, "Hilbert", depth)
        self.neighbours = neighbour_table(grid)
        self.neighbours_back = neighbour_backward_table(self.neighbours)
        self._patches = {}

    def patch_gather(self, order_index, patch):
        """(row gather [n_pad] into the level, patch length K, inverse [n], order [n]) for
        one block."""
        key = (order_index, patch)
        if key not in self._patches:
            order, inverse = self.orders[order_index]
            pad = torch.from_numpy(patch_padding(self.n, patch)).to(order.device)
            k = max(min(patch, self.n), 1)
            self._patches[key] = (order[pad], k, inverse, order)
        return self._patches[key]


class Pooling:
    """Index side of one GridPooling step: padded member table and parent -> cluster map."""

    def __init__(self, parent_grid, stride):
        cells, cluster, _, members, counts = cluster_cells(parent_grid // stride)
        width = max(int(counts.max()), 1)
        ptr = np.concatenate([[0], np.cumsum(counts)])
        j = np.arange(width)[None, :]
        idx = ptr[:-1, None] + np.minimum(j, counts[:, None] - 1)
        self.cells = cells
        self.table = torch.from_numpy(members[idx].astype(np.int64))  # [clusters, width]
        self.cluster = torch.from_numpy(cluster.astype(np.int64))


class PointGeometry:
    """Everything discrete about one (anchors, normals) set: the stem input, input -> voxel
    map, the level geometries and pooling steps."""

    def __init__(self, anchors, normals, cfg):
        pb = cfg["point_backbone"]
        a = np.ascontiguousarray(anchors, dtype=np.float32)
        nrm = np.ascontiguousarray(normals, dtype=np.float32)
        shifted = center_shift(a)
        grid, keep, inverse = grid_sample(shifted, pb["grid_size"])
        self.feat6 = torch.from_numpy(np.concatenate([shifted[keep], nrm[keep]], axis=1))
        self.input_inverse = torch.from_numpy(inverse.astype(np.int64))
        self.levels = [Level(grid, pb["order"])]
        self.pools = [None]
        for l in range(1, len(pb["enc_channels"])):
            pool = Pooling(self.levels[-1].grid, pb["stride"][l - 1])
            self.pools.append(pool)
            self.levels.append(Level(pool.cells, pb["order"]))

    def summary(self):
        """Voxels per level."""
        return [lv.n for lv in self.levels]

    def to(self, device):
        """Moves every index tensor to `device` (in place; returns self)."""
        device = torch.device(device)
        if getattr(self, "device", torch.device("cpu")) == device:
            return self
        mv = lambda t: t.to(device)  # noqa: E731
        self.feat6, self.input_inverse = mv(self.feat6), mv(self.input_inverse)
        for lv in self.levels:
            lv.orders = [(mv(o), mv(i)) for o, i in lv.orders]
            lv.hilbert = tuple(mv(t) for t in lv.hilbert)
            lv.neighbours, lv.neighbours_back = mv(lv.neighbours), mv(lv.neighbours_back)
            lv._patches = {}
        for pool in self.pools[1:]:
            pool.table, pool.cluster = mv(pool.table), mv(pool.cluster)
        self.device = device
        return self


def geometry_key(anchors, normals):
    h = hashlib.sha1()
    for t in (anchors, normals):
        arr = np.ascontiguousarray(t.detach().cpu().numpy() if torch.is_tensor(t) else t,
                                   dtype=np.float32)
        h.update(str(arr.shape).encode())
        h.update(arr.tobytes())
    return h.hexdigest()


# --------------------------------------------------------------------------------------------
# Row gathers with gather-only backward passes (torch's generic index backward is a serial
# scatter-add; these structures know their inverse)


class _Permute(torch.autograd.Function):
    """y = x[perm] for a permutation; dx = dy[inv]."""

    @staticmethod
    def forward(ctx, x, perm, inv):
        ctx.save_for_backward(inv)
        return x.index_select(0, perm)

    @staticmethod
    def backward(ctx, g):
        (inv,) = ctx.saved_tensors
        return g.index_select(0, inv), None, None


def permute_rows(x, perm, inv):
    return _Permute.apply(x, perm, inv)


class _PatchGather(torch.autograd.Function):
    """y = x[order[pad]] ([n_pad] rows, the tail repeating earlier slots); dx gathers dy's
    first n slots back through `inverse` and adds the tail."""

    @staticmethod
    def forward(ctx, x, gather, inverse):
        ctx.save_for_backward(gather, inverse)
        return x.index_select(0, gather)

    @staticmethod
    def backward(ctx, g):
        gather, inverse = ctx.saved_tensors
        n = inverse.shape[0]
        dx = g.index_select(0, inverse)
        if g.shape[0] > n:
            dx = dx.index_add(0, gather[n:], g[n:])
        return dx, None, None


class _PatchScatterBack(torch.autograd.Function):
    """y = z[inverse] (the n real slots of the padded sequence, back in point order);
    dz = [dy[order]; 0 for the padded tail]."""

    @staticmethod
    def forward(ctx, z, inverse, order):
        ctx.save_for_backward(order)
        ctx.n_pad = z.shape[0]
        return z.index_select(0, inverse)

    @staticmethod
    def backward(ctx, g):
        (order,) = ctx.saved_tensors
        dz = g.index_select(0, order)
        if ctx.n_pad > dz.shape[0]:
            dz = torch.cat([dz, dz.new_zeros(ctx.n_pad - dz.shape[0], dz.shape[1])], 0)
        return dz, None, None


class _NeighbourGather(torch.autograd.Function):
    """y[p, k] = x[nbr[p, k]] (x padded with a zero row at M): [M, 27, C]. The submanifold
    neighbour relation is symmetric (nbr[p, k] = q <=> nbr[q, 26 - k] = p), so
    dx[q] = sum_k dy[nbr[q, 26 - k], k]: a gather again."""

    @staticmethod
    def forward(ctx, x, nbr, flat_back):
        ctx.save_for_backward(flat_back)
        m, c = x.shape
        xp = torch.cat([x, x.new_zeros(1, c)], 0)
        return F.embedding(nbr, xp)

    @staticmethod
    def backward(ctx, g):
        (flat_back,) = ctx.saved_tensors
        m, k, c = g.shape
        gp = torch.cat([g.reshape(m * k, c), g.new_zeros(1, c)], 0)
        return F.embedding(flat_back, gp).sum(1), None, None


def neighbour_backward_table(nbr):
    """Rows of dy (flattened [M*27], M*27 = zero row) that sum into each dx row, [M, 27]."""
    m = nbr.shape[0]
    flip = nbr.flip(1)  # offset 26 - k
    k = torch.arange(27).expand(m, 27)
    return torch.where(flip < m, flip * 27 + k, torch.full_like(flip, m * 27))


# --------------------------------------------------------------------------------------------
# Point backbone modules (transformer.point_backbone.*)


class GatherSubMConv3d(R.SubMConv3d):
    """Submanifold 3x3x3 conv over a neighbour table (same weight layout [out, kx, ky, kz, in]
    and result as the dense reference): out = b + concat_k x[nbr[:, k]] @ W_k."""

    def forward(self, feats, level):
        c_out, c_in = self.weight.shape[0], self.weight.shape[-1]
        g = _NeighbourGather.apply(feats, level.neighbours, level.neighbours_back)
        w = self.weight.reshape(c_out, 27 * c_in)
        return torch.addmm(self.bias, g.reshape(feats.shape[0], 27 * c_in), w.t())


class FastPatchAttention(R.PatchAttention):
    """PTv3 SerializedAttention with the level's cached patch gather and SDPA."""

    def forward(self, x, level, order_index):
        n, c = x.shape
        gather, k, inverse, order = level.patch_gather(order_index, self.patch)
        h = self.heads
        qkv = _PatchGather.apply(self.qkv(x), gather, inverse)
        qkv = qkv.reshape(-1, k, 3, h, c // h).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(qkv[0], qkv[1], qkv[2])
        out = _PatchScatterBack.apply(out.transpose(1, 2).reshape(-1, c), inverse, order)
        return self.proj(out)


class FastPtBlock(R.PtBlock):
    def __init__(self, c, heads, patch, mlp_ratio, order_index):
        super().__init__(c, heads, patch, mlp_ratio, order_index)
        self.cpe[0] = GatherSubMConv3d(c, c)
        attn = FastPatchAttention(c, heads, patch)
        self.attn = attn

    def forward(self, x, level):
        x = x + self.cpe[2](self.cpe[1](self.cpe[0](x, level)))
        oi = self.order_index % len(level.orders)
        x = x + self.attn(self.norm1[0](x), level, oi)
        return x + self.mlp[0](self.norm2[0](x))


def _linear_norm(c_in, c_out):
    return nn.ModuleList([nn.Linear(c_in, c_out), nn.LayerNorm(c_out, eps=1e-5)])


class GridPooling(nn.Module):
    def __init__(self, c_in, c_out):
        super().__init__()
        self.proj = nn.Linear(c_in, c_out)
        self.norm = nn.ModuleList([nn.LayerNorm(c_out, eps=1e-5)])

    def forward(self, x, pool):
        y = self.proj(x)[pool.table]  # [clusters, width, C]
        y = y.max(1).values if pool.table.shape[1] > 1 else y[:, 0]
        return F.gelu(self.norm[0](y))


class GridUnpooling(nn.Module):
    def __init__(self, c_in, c_skip, c_out):
        super().__init__()
        self.proj = _linear_norm(c_in, c_out)
        self.proj_skip = _linear_norm(c_skip, c_out)

    def forward(self, child, parent, cluster):
        skip = F.gelu(self.proj_skip[1](self.proj_skip[0](parent)))
        up = F.gelu(self.proj[1](self.proj[0](child)))
        return skip + up[cluster]


class PointBackbone(nn.Module):
    """Sonata PTv3 (`transformer.point_backbone`), staged like src/model/point/mod.rs."""

    def __init__(self, pb):
        super().__init__()
        self.cfg = pb
        levels = len(pb["enc_channels"])
        n_orders = max(len(pb["order"]), 1)

        def blocks(owner, depth, c, heads, patch):
            for i in range(depth):
                setattr(owner, f"block{i}", FastPtBlock(c, heads, patch, pb["mlp_ratio"], i % n_orders))

        self.embedding = nn.Module()
        self.embedding.stem = nn.Module()
        self.embedding.stem.linear = nn.Linear(pb["in_channels"], pb["enc_channels"][0])
        self.embedding.stem.norm = nn.LayerNorm(pb["enc_channels"][0], eps=1e-5)
        self.enc = nn.Module()
        for l in range(levels):
            m = nn.Module()
            c = pb["enc_channels"][l]
            if l > 0:
                m.down = GridPooling(pb["enc_channels"][l - 1], c)
            blocks(m, pb["enc_depths"][l], c, pb["enc_num_head"][l], pb["enc_patch_size"][l])
            setattr(self.enc, f"enc{l}", m)
        self.dec = nn.Module()
        for l in range(levels - 1):
            m = nn.Module()
            c_in = pb["enc_channels"][levels - 1] if l + 2 == levels else pb["dec_channels"][l + 1]
            c = pb["dec_channels"][l]
            m.up = GridUnpooling(c_in, pb["enc_channels"][l], c)
            blocks(m, pb["dec_depths"][l], c, pb["dec_num_head"][l], pb["dec_patch_size"][l])
            setattr(self.dec, f"dec{l}", m)

    def _blocks(self, m, depth):
        return [getattr(m, f"block{i}") for i in range(depth)]

    def embed(self, geo):
        s = self.embedding.stem
        feat6 = geo.feat6.to(s.linear.weight.dtype)
        return {"feat": F.gelu(s.norm(s.linear(feat6))), "level": 0, "parents": []}

    def encoder_stage(self, l, state, geo):
        pb = self.cfg
        m = getattr(self.enc, f"enc{l}")
        feat = state["feat"]
        if l > 0:
            state["parents"].append(feat)
            feat = m.down(feat, geo.pools[l])
            state["level"] = l
        level = geo.levels[state["level"]]
        for b in self._blocks(m, pb["enc_depths"][l]):
            feat = b(feat, level)
        state["feat"] = feat
        return state

    def decoder_stage(self, l, state, geo):
        pb = self.cfg
        m = getattr(self.dec, f"dec{l}")
        parent = state["parents"].pop()
        feat = m.up(state["feat"], parent, geo.pools[l + 1].cluster)
        state["level"] = l
        level = geo.levels[l]
        for b in self._blocks(m, pb["dec_depths"][l]):
            feat = b(feat, level)
        state["feat"] = feat
        return state


# --------------------------------------------------------------------------------------------
# Image side: special tokens + frame blocks (transformer.image_backbone.*)


class ImageBackbone(nn.Module):
    def __init__(self, enc, ib):
        super().__init__()
        c = enc["embed_dim"]
        self.pose_token = nn.Parameter(torch.zeros(1, 2, 1, c))
        self.register_token = nn.Parameter(torch.zeros(1, 2, enc["num_register_tokens"], c))
        self.frame_blocks = nn.ModuleList(
            R.FrameBlock(c, ib["num_heads"], ib["mlp_ratio"], ib["rope_base"]) for _ in range(ib["depth"])
        )
        if not ib["qk_norm"]:
            for b in self.frame_blocks:
                b.attn.q_norm = nn.Identity()
                b.attn.k_norm = nn.Identity()

    def with_special_tokens(self, patches):
        v, _, c = patches.shape
        special = torch.cat([self.pose_token, self.register_token], 2)[0]  # [2, 5, C]
        s = special.shape[1]
        specials = torch.cat([special[:1], special[1:2].expand(v - 1, s, c)], 0)
        return torch.cat([specials.to(patches.dtype), patches], 1)


# --------------------------------------------------------------------------------------------
# ToMe (src/model/token_merge.rs)


class TokenMergePlan:
    """Bipartite soft matching on `metric [N, D]` seen as an `h x w` grid, destinations the
    top-left token of each 2x2 cell; `r` most similar sources merged (mean) into their best
    destination. Built without grad; merge/unmerge are differentiable gathers."""

    def __init__(self, metric, h, w, r):
        n = metric.shape[0]
        assert n == h * w, f"{n} tokens do not form a {h}x{w} grid"
        ys, xs = np.divmod(np.arange(n), w)
        hsy, wsx = h // TOME_STRIDE, w // TOME_STRIDE
        is_dst = (ys < hsy * TOME_STRIDE) & (xs < wsx * TOME_STRIDE) & (ys % TOME_STRIDE == 0) & (xs % TOME_STRIDE == 0)
        b_idx = np.nonzero(is_dst)[0]
        a_idx = np.nonzero(~is_dst)[0]
        r = min(r, len(a_idx))
        self.identity = r == 0 or len(b_idx) == 0
        if self.identity:
            return
        dev = metric.device
        with torch.no_grad():
            m = metric.detach().float()
            m = m / m.pow(2).sum(-1, keepdim=True).sqrt()
            a = m[torch.from_numpy(a_idx).to(dev)]
            b = m[torch.from_numpy(b_idx).to(dev)]
            scores = a @ b.t()
            node_max, node_idx = scores.max(-1)
            edge = torch.argsort(node_max, descending=True, stable=True).cpu().numpy()
            node_idx = node_idx.cpu().numpy()
        src_e, unm_e = edge[:r], edge[r:]
        unm = a_idx[unm_e]
        src = a_idx[src_e]
        src_to_dst = node_idx[src_e]
        counts = np.ones(len(b_idx), dtype=np.float32)
        np.add.at(counts, src_to_dst, 1.0)
        unmerge = np.zeros(n, dtype=np.int64)
        unmerge[unm] = np.arange(len(unm))
        unmerge[b_idx] = len(unm) + np.arange(len(b_idx))
        unmerge[src] = len(unm) + src_to_dst
        t = lambda v: torch.from_numpy(np.ascontiguousarray(v, dtype=np.int64)).to(dev)  # noqa: E731
        self.unm_rows, self.dst_rows, self.src_rows = t(unm), t(b_idx), t(src)
        self.src_to_dst = t(src_to_dst)
        self.dst_inv_count = torch.from_numpy((np.float32(1.0) / counts)[:, None]).to(dev)
        self.unmerge_rows = t(unmerge)

    def merge(self, x):
        if self.identity:
            return x
        dst = x[self.dst_rows].index_add(0, self.src_to_dst, x[self.src_rows])
        return torch.cat([x[self.unm_rows], dst * self.dst_inv_count.to(x.dtype)], 0)

    def unmerge(self, y):
        return y if self.identity else y[self.unmerge_rows]


def multi_modal_step(block, tokens, metric, points, temb, grid, ratio):
    """lhmpp::multi_modal_step: tokens [V, 5+hw, C], metric [V, 5+hw, D], points [N, pv]."""
    v, n, c = tokens.shape
    hw = n - SPECIAL_TOKENS
    image = tokens[:, SPECIAL_TOKENS:].reshape(v * hw, c)
    m = metric[:, SPECIAL_TOKENS:].reshape(v * hw, metric.shape[2])
    r = int(ratio * (v * hw))
    plan = TokenMergePlan(m, grid[0], grid[1] * v, r)
    merged = plan.merge(image)
    new_points, new_image = block(points[None], merged[None], temb)
    new_points = new_points[0]
    if new_image is None:
        return new_points, tokens
    img = plan.unmerge(new_image[0]).reshape(v, hw, c)
    return new_points, torch.cat([tokens[:, :SPECIAL_TOKENS], img], 1)


# --------------------------------------------------------------------------------------------
# The whole network


class LhmppTorch(nn.Module):
    """Twin of `Lhmpp` (src/model/lhmpp.rs) for a config dict (serde dump of LhmppConfig).

    forward(images [V, 3, H, W] in [0, 1], anchors [N, 3], normals [N, 3]) -> dict of
    `features [N, q]` (fused per-point features, GS-head input), `colors [N, 3]`,
    `scales [N, 3]`, `rotations [N, 4]` (w, x, y, z), `opacities [N, 1]`, `offsets [N, 3]`,
    `positions [N, 3]` (= anchors + offsets)."""

    def __init__(self, cfg, neural_renderer=True, geometry_cache_size=512):
        super().__init__()
        cfg = read_config(cfg)
        self.cfg = cfg
        e, ib, tr, pb, gs = cfg["encoder"], cfg["image_backbone"], cfg["transformer"], cfg["point_backbone"], cfg["gs_head"]
        d, ctx = tr["transformer_dim"], e["embed_dim"]
        self.encoder = nn.Module()
        self.encoder.model = R.DinoEncoder(e["embed_dim"], e["depth"], e["num_heads"], e["patch_size"],
                                           e["num_register_tokens"], e["pos_embed_grid"], e["mlp_ratio"],
                                           e["layer_norm_eps"])
        self.transformer = nn.Module()
        self.transformer.image_backbone = ImageBackbone(e, ib)
        enc_pv = pb["enc_channels"][1:]
        dec_pv = pb["dec_channels"][::-1]
        self.transformer.pi_transformer_enc = nn.ModuleList(
            R.JointBlock(pv, d, tr["transformer_heads"], ctx, False) for pv in enc_pv)
        self.transformer.pi_transformer_dec = nn.ModuleList(
            R.JointBlock(pv, d, tr["transformer_heads"], ctx, j + 1 == len(dec_pv)) for j, pv in enumerate(dec_pv))
        self.transformer.outnorm = nn.LayerNorm(gs["gs_query_dim"], eps=1e-5)
        self.transformer.point_backbone = PointBackbone(pb)
        self.motion_embed_mlp = nn.Sequential(nn.Linear(ctx, tr["motion_embed_hidden"]), nn.SiLU(),
                                              nn.Linear(tr["motion_embed_hidden"], d))
        if not gs["use_rgb"]:
            raise NotImplementedError("gs_head.use_rgb = false (SH colours)")
        self.renderer = R.GsHead(gs["gs_query_dim"], gs["n_neurons"], gs["n_hidden_layers"],
                                 gs["clip_scaling"], gs["xyz_offset_max_step"])
        if neural_renderer:
            nr = cfg["neural_renderer"]
            self.neural_renderer = R.NeuralRenderer(nr["in_channels"], nr["patch_size"], nr["embed_dim"],
                                                    nr["features"], list(nr["out_channels"]))
        self._geometry = collections.OrderedDict()  # LRU of PointGeometry per anchor set
        self.geometry_cache_size = geometry_cache_size

    @classmethod
    def from_config_json(cls, path_or_dict, **kw):
        """Builds the network from a config: dict, JSON string, `.json` file or a checkpoint's
        metadata. Its weights are PyTorch's default init, not ours: to train from scratch, load
        the weights of `lhmpp model init` (load_checkpoint)."""
        return cls(read_config(path_or_dict), **kw)

    # -- caches ---------------------------------------------------------------------------

    def geometry(self, anchors, normals, device=None):
        """The cached PointGeometry of one (anchors, normals) set (index tensors on `device`,
        default: the model's)."""
        key = geometry_key(anchors, normals)
        geo = self._geometry.get(key)
        if geo is None:
            a = anchors.detach().cpu().numpy() if torch.is_tensor(anchors) else anchors
            n = normals.detach().cpu().numpy() if torch.is_tensor(normals) else normals
            geo = PointGeometry(a, n, self.cfg)
            self._geometry[key] = geo
            while len(self._geometry) > max(self.geometry_cache_size, 1):
                self._geometry.popitem(last=False)
        else:
            self._geometry.move_to_end(key)
        return geo.to(device if device is not None else self.transformer.outnorm.weight.device)

    def clear_geometry_cache(self):
        """Drops every cached PointGeometry."""
        self._geometry.clear()

    # -- forward --------------------------------------------------------------------------

    def encode(self, images):
        """DINOv2 over all views at once: (cls [V, C], patch tokens [V, h*w, C])."""
        return self.encoder.model(images)

    def fuse(self, images, anchors, normals):
        """lhmpp::fuse: the encoder-decoder PIT -> per-input-point features [N, q]."""
        cfg = self.cfg
        p = cfg["encoder"]["patch_size"]
        grid = (images.shape[2] // p, images.shape[3] // p)
        ratio = cfg["transformer"]["merge_ratio"]
        t = self.transformer
        pbk = t.point_backbone
        geo = self.geometry(anchors, normals)
        cls, patches = self.encode(images)
        temb = self.motion_embed_mlp(cls).mean(0, keepdim=True)
        tokens = t.image_backbone.with_special_tokens(patches)
        pos = R.rope_positions(grid[0], grid[1], SPECIAL_TOKENS, tokens.device)
        state = pbk.embed(geo)
        state = pbk.encoder_stage(0, state, geo)
        metric = None
        for i, block in enumerate(t.pi_transformer_enc):
            state = pbk.encoder_stage(i + 1, state, geo)
            tk, metric = t.image_backbone.frame_blocks[i](tokens, pos)
            state["feat"], tokens = self._point_step(block, state, geo, tk, metric, temb, grid, ratio)
        levels = len(t.pi_transformer_dec)
        for j, block in enumerate(t.pi_transformer_dec):
            state = pbk.decoder_stage(levels - 1 - j, state, geo)
            state["feat"], tokens = self._point_step(block, state, geo, tokens, metric, temb, grid, ratio)
        feat = t.outnorm(state["feat"])
        return feat.index_select(0, geo.input_inverse)

    @staticmethod
    def _point_step(block, state, geo, tokens, metric, temb, grid, ratio):
        order, inverse = geo.levels[state["level"]].hilbert
        points = permute_rows(state["feat"], order, inverse)
        points, tokens = multi_modal_step(block, tokens, metric, points, temb, grid, ratio)
        return permute_rows(points, inverse, order), tokens

    def forward(self, images, anchors, normals):
        """images [V, 3, H, W] in [0, 1], anchors [N, 3], normals [N, 3] -> dict of the GS-head
        outputs (OUTPUT_NAMES) for the N anchors; differentiable in the weights."""
        anchors_t = torch.as_tensor(anchors, dtype=torch.float32)
        feat = self.fuse(images, anchors, normals)
        out = dict(self.renderer(feat, anchors_t.to(feat.device)))
        out["features"] = feat
        return out


# --------------------------------------------------------------------------------------------
# Checkpoints


def state_dict_f32(model):
    return {k: v.detach().float().cpu().contiguous() for k, v in model.state_dict().items()}


def save_checkpoint(model, path, cfg=None, base=None):
    """Writes `model`'s weights as f32 safetensors in our checkpoint layout, with the preset
    name and config JSON in the metadata (as `lhmpp model init`), for `model.checkpoint`.
    Tensors the model lacks (`neural_renderer.*` of a model built with
    neural_renderer=False) are copied from the checkpoint `base`; our loader needs them all."""
    from safetensors.torch import load_file, save_file

    cfg = read_config(cfg if cfg is not None else model.cfg)
    tensors = state_dict_f32(model)
    if base is not None:
        for k, v in load_file(str(base)).items():
            tensors.setdefault(k, v.float().contiguous())
    if not any(k.startswith("neural_renderer.") for k in tensors):
        raise ValueError("no neural_renderer.* tensors: pass base= (e.g. the init checkpoint)")
    meta = {META_PRESET: cfg["preset"], META_CONFIG: json.dumps(cfg, separators=(",", ":"))}
    save_file(tensors, str(path), metadata=meta)


def load_checkpoint(path, cfg=None, neural_renderer=True, strict=True):
    """Builds LhmppTorch from the checkpoint's metadata config (or `cfg`) and loads it."""
    from safetensors.torch import load_file

    model = LhmppTorch(read_config(cfg if cfg is not None else path), neural_renderer=neural_renderer)
    sd = load_file(str(path))
    if not neural_renderer:
        sd = {k: v for k, v in sd.items() if not k.startswith("neural_renderer.")}
    model.load_state_dict(sd, strict=strict)
    return model
