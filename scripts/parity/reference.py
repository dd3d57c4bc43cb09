"""PyTorch reference blocks of the LHM++ network, written from the official definitions
summarised in shared/reference/lhmpp-official.md (sections 1.3 b, e, f, i and 1.4), not from
our Rust code. Parameter names match the official state dict below each block's prefix.

Blocks: DINOv2 ViT block and the whole encoder (register tokens, antialiased bicubic
pos-embed interpolation), the VGGT frame block (qk LayerNorm, 2D RoPE base 100, returns the
token-merging metric), the SD3 joint-attention block (AdaLN-Zero, AdaLN-Continuous when
context_pre_only, RMSNorm on q/k, double-added context feed-forward), the submanifold sparse
3x3x3 convolution (dense conv3d over the occupied voxels, spconv weight layout
[out, kx, ky, kz, in]), the Gaussian head and the 7x7-patch DPT neural renderer.
"""

import math

import torch
import torch.nn as nn
import torch.nn.functional as F


# --------------------------------------------------------------------------------------------
# DINOv2 with registers (encoder.model.*)


class LayerScale(nn.Module):
    def __init__(self, dim):
        super().__init__()
        self.gamma = nn.Parameter(torch.ones(dim))

    def forward(self, x):
        return x * self.gamma


class Mlp(nn.Module):
    """fc1 -> exact GELU -> fc2."""

    def __init__(self, dim, hidden):
        super().__init__()
        self.fc1 = nn.Linear(dim, hidden)
        self.fc2 = nn.Linear(hidden, dim)

    def forward(self, x):
        return self.fc2(F.gelu(self.fc1(x)))


class VitAttention(nn.Module):
    def __init__(self, dim, heads):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x):
        b, n, c = x.shape
        qkv = self.qkv(x).reshape(b, n, 3, self.heads, c // self.heads).permute(2, 0, 3, 1, 4)
        out = F.scaled_dot_product_attention(qkv[0], qkv[1], qkv[2])
        return self.proj(out.transpose(1, 2).reshape(b, n, c))


class DinoBlock(nn.Module):
    """Pre-norm ViT block with LayerScale (LayerNorm eps 1e-6)."""

    def __init__(self, dim, heads, mlp_ratio=4.0, eps=1e-6):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim, eps=eps)
        self.attn = VitAttention(dim, heads)
        self.ls1 = LayerScale(dim)
        self.norm2 = nn.LayerNorm(dim, eps=eps)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.ls2 = LayerScale(dim)

    def forward(self, x):
        x = x + self.ls1(self.attn(self.norm1(x)))
        return x + self.ls2(self.mlp(self.norm2(x)))


class PatchEmbed(nn.Module):
    def __init__(self, patch, dim):
        super().__init__()
        self.proj = nn.Conv2d(3, dim, kernel_size=patch, stride=patch)

    def forward(self, x):
        return self.proj(x).flatten(2).transpose(1, 2)


class DinoEncoder(nn.Module):
    """dinov2_vitXX14_reg: CLS + pos-embed (bicubic, antialias, to the input grid), then the
    register tokens after CLS; returns (final-norm CLS, final-norm patch tokens)."""

    def __init__(self, dim, depth, heads, patch, registers, grid, mlp_ratio=4.0, eps=1e-6):
        super().__init__()
        self.patch = patch
        self.grid = grid
        self.registers = registers
        self.cls_token = nn.Parameter(torch.zeros(1, 1, dim))
        self.pos_embed = nn.Parameter(torch.zeros(1, 1 + grid * grid, dim))
        self.register_tokens = nn.Parameter(torch.zeros(1, registers, dim))
        self.patch_embed = PatchEmbed(patch, dim)
        self.blocks = nn.ModuleList(DinoBlock(dim, heads, mlp_ratio, eps) for _ in range(depth))
        self.norm = nn.LayerNorm(dim, eps=eps)

    def interpolate_pos_encoding(self, h, w):
        pos = self.pos_embed.float()
        cls_pos, patch_pos = pos[:, :1], pos[:, 1:]
        dim = pos.shape[-1]
        if (h, w) != (self.grid, self.grid):
            patch_pos = F.interpolate(
                patch_pos.reshape(1, self.grid, self.grid, dim).permute(0, 3, 1, 2),
                size=(h, w),
                mode="bicubic",
                antialias=True,
            )
            patch_pos = patch_pos.permute(0, 2, 3, 1).reshape(1, h * w, dim)
        return torch.cat([cls_pos, patch_pos], dim=1).to(self.pos_embed.dtype)

    def forward(self, images):
        b, _, hh, ww = images.shape
        h, w = hh // self.patch, ww // self.patch
        x = self.patch_embed(images)
        x = torch.cat([self.cls_token.expand(b, -1, -1), x], dim=1)
        x = x + self.interpolate_pos_encoding(h, w)
        x = torch.cat([x[:, :1], self.register_tokens.expand(b, -1, -1), x[:, 1:]], dim=1)
        for blk in self.blocks:
            x = blk(x)
        x = self.norm(x)
        return x[:, 0], x[:, 1 + self.registers :]


# --------------------------------------------------------------------------------------------
# VGGT frame block (transformer.image_backbone.frame_blocks.*)


def rope_positions(h, w, special, device):
    """(y+1, x+1) for the patch grid, (0, 0) for the special tokens: [special + h*w, 2]."""
    ys, xs = torch.meshgrid(torch.arange(h), torch.arange(w), indexing="ij")
    grid = torch.stack([ys.reshape(-1), xs.reshape(-1)], dim=-1) + 1
    return torch.cat([torch.zeros(special, 2, dtype=torch.long), grid], 0).to(device)


class Rope2D(nn.Module):
    """VGGT RotaryPositionEmbedding2D: the head dim is split into a y half and an x half; each
    half is rotated with rotate-half and frequencies base^(-2i/d)."""

    def __init__(self, base=100.0):
        super().__init__()
        self.base = base

    def _rope_1d(self, t, pos, dim):
        inv_freq = 1.0 / (self.base ** (torch.arange(0, dim, 2, device=t.device).float() / dim))
        angles = pos.float()[:, None] * inv_freq[None, :]
        angles = torch.cat([angles, angles], dim=-1).to(t.dtype)
        cos, sin = angles.cos(), angles.sin()
        t1, t2 = t[..., : dim // 2], t[..., dim // 2 :]
        rotated = torch.cat([-t2, t1], dim=-1)
        return t * cos + rotated * sin

    def forward(self, t, pos):
        d = t.shape[-1] // 2
        y, x = t.chunk(2, dim=-1)
        return torch.cat([self._rope_1d(y, pos[:, 0], d), self._rope_1d(x, pos[:, 1], d)], dim=-1)


class FrameAttention(nn.Module):
    def __init__(self, dim, heads, rope_base):
        super().__init__()
        self.heads = heads
        hd = dim // heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.q_norm = nn.LayerNorm(hd)
        self.k_norm = nn.LayerNorm(hd)
        self.proj = nn.Linear(dim, dim)
        self.rope = Rope2D(rope_base)

    def forward(self, x, pos):
        b, n, c = x.shape
        qkv = self.qkv(x).reshape(b, n, 3, self.heads, c // self.heads).permute(2, 0, 3, 1, 4)
        q, k, v = qkv[0], qkv[1], qkv[2]
        q, k = self.q_norm(q), self.k_norm(k)
        q, k = self.rope(q, pos), self.rope(k, pos)
        metric = k.mean(dim=1)
        out = F.scaled_dot_product_attention(q, k, v)
        return self.proj(out.transpose(1, 2).reshape(b, n, c)), metric


class FrameBlock(nn.Module):
    """VGGT Block (LayerNorm eps 1e-5, exact GELU MLP, LayerScale) that also returns the keys
    metric (mean over heads of the post-norm, post-RoPE keys)."""

    def __init__(self, dim, heads, mlp_ratio=4.0, rope_base=100.0):
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.attn = FrameAttention(dim, heads, rope_base)
        self.ls1 = LayerScale(dim)
        self.norm2 = nn.LayerNorm(dim)
        self.mlp = Mlp(dim, int(dim * mlp_ratio))
        self.ls2 = LayerScale(dim)

    def forward(self, x, pos):
        a, metric = self.attn(self.norm1(x), pos)
        x = x + self.ls1(a)
        return x + self.ls2(self.mlp(self.norm2(x))), metric


# --------------------------------------------------------------------------------------------
# SD3 joint-attention PIT block (transformer.pi_transformer_{enc,dec}.*)


class FeedForward(nn.Module):
    """diffusers FeedForward with gelu-approximate: net.0.proj -> GELU(tanh) -> net.2."""

    def __init__(self, dim, inner, out):
        super().__init__()
        proj = nn.Module()
        proj.proj = nn.Linear(dim, inner)
        self.net = nn.ModuleList([proj, nn.Dropout(0.0), nn.Linear(inner, out)])

    def forward(self, x):
        return self.net[2](F.gelu(self.net[0].proj(x), approximate="tanh"))


class AdaLayerNormZero(nn.Module):
    """linear(silu(temb)) -> shift, scale, gate (msa), shift, scale, gate (mlp); LN eps 1e-6."""

    def __init__(self, dim):
        super().__init__()
        self.linear = nn.Linear(dim, 6 * dim)

    def forward(self, x, temb):
        shift, scale, gate, shift_mlp, scale_mlp, gate_mlp = self.linear(F.silu(temb)).chunk(6, 1)
        nx = F.layer_norm(x, x.shape[-1:], eps=1e-6) * (1 + scale[:, None]) + shift[:, None]
        return nx, gate, shift_mlp, scale_mlp, gate_mlp


class AdaLayerNormContinuous(nn.Module):
    """linear(silu(temb)) -> scale, shift (that order); LN eps 1e-6, no affine."""

    def __init__(self, dim):
        super().__init__()
        self.linear = nn.Linear(dim, 2 * dim)

    def forward(self, x, temb):
        scale, shift = self.linear(F.silu(temb)).chunk(2, 1)
        return F.layer_norm(x, x.shape[-1:], eps=1e-6) * (1 + scale[:, None]) + shift[:, None]


class RMSNorm(nn.Module):
    def __init__(self, dim, eps=1e-5):
        super().__init__()
        self.eps = eps
        self.weight = nn.Parameter(torch.ones(dim))

    def forward(self, x):
        var = x.float().pow(2).mean(-1, keepdim=True)
        return (x.float() * torch.rsqrt(var + self.eps)).to(x.dtype) * self.weight


class JointAttention(nn.Module):
    """diffusers Attention + JointAttnProcessor2_0 with rms_norm qk-norm: sequence [x; c]."""

    def __init__(self, dim, heads, pre_only):
        super().__init__()
        self.heads = heads
        hd = dim // heads
        for name in ["to_q", "to_k", "to_v", "add_q_proj", "add_k_proj", "add_v_proj"]:
            setattr(self, name, nn.Linear(dim, dim))
        for name in ["norm_q", "norm_k", "norm_added_q", "norm_added_k"]:
            setattr(self, name, RMSNorm(hd))
        self.to_out = nn.ModuleList([nn.Linear(dim, dim), nn.Dropout(0.0)])
        self.to_add_out = None if pre_only else nn.Linear(dim, dim)

    def forward(self, x, c):
        b, n, d = x.shape

        def heads(t):
            return t.view(b, -1, self.heads, d // self.heads).transpose(1, 2)

        q = torch.cat([self.norm_q(heads(self.to_q(x))), self.norm_added_q(heads(self.add_q_proj(c)))], 2)
        k = torch.cat([self.norm_k(heads(self.to_k(x))), self.norm_added_k(heads(self.add_k_proj(c)))], 2)
        v = torch.cat([heads(self.to_v(x)), heads(self.add_v_proj(c))], 2)
        out = F.scaled_dot_product_attention(q, k, v).transpose(1, 2).reshape(b, -1, d)
        x_out = self.to_out[0](out[:, :n])
        c_out = None if self.to_add_out is None else self.to_add_out(out[:, n:])
        return x_out, c_out


class JointBlock(nn.Module):
    """SD3PMMJointTransformerBlock: points (pv) and image tokens (context_dim) are projected to
    dim, run one SD3 joint block conditioned on temb, and points are projected back."""

    def __init__(self, pv, dim, heads, context_dim, pre_only, eps=1e-5):
        super().__init__()
        self.pre_only = pre_only
        self.eps = eps
        self.ff_proj = FeedForward(pv, 4 * pv, dim)
        self.ff_context_proj = FeedForward(context_dim, 4 * pv, dim)
        self.norm1 = AdaLayerNormZero(dim)
        self.norm1_context = AdaLayerNormContinuous(dim) if pre_only else AdaLayerNormZero(dim)
        self.attn = JointAttention(dim, heads, pre_only)
        self.ff = FeedForward(dim, 4 * dim, dim)
        self.ff_context = None if pre_only else FeedForward(dim, 4 * dim, dim)
        self.inv_ff_proj = FeedForward(dim, 4 * dim, pv)

    def forward(self, points, image, temb):
        x = self.ff_proj(points)
        c = self.ff_context_proj(image)
        nx, g_msa, sh_mlp, sc_mlp, g_mlp = self.norm1(x, temb)
        if self.pre_only:
            nc = self.norm1_context(c, temb)
        else:
            nc, cg_msa, csh_mlp, csc_mlp, cg_mlp = self.norm1_context(c, temb)
        out_x, out_c = self.attn(nx, nc)
        x = x + g_msa[:, None] * out_x
        nx2 = F.layer_norm(x, x.shape[-1:], eps=self.eps) * (1 + sc_mlp[:, None]) + sh_mlp[:, None]
        x = x + g_mlp[:, None] * self.ff(nx2)
        if self.pre_only:
            c = None
        else:
            c = c + cg_msa[:, None] * out_c
            nc2 = F.layer_norm(c, c.shape[-1:], eps=self.eps) * (1 + csc_mlp[:, None]) + csh_mlp[:, None]
            f = self.ff_context(nc2)
            c = c + cg_mlp[:, None] * f
            c = c + f  # the official double add
        return self.inv_ff_proj(x), c


class MotionEmbed(nn.Module):
    """motion_embed_mlp: Linear, SiLU, Linear; temb = mean over views."""

    def __init__(self, dim, hidden, out):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(dim, hidden), nn.SiLU(), nn.Linear(hidden, out))

    def forward(self, cls):
        return self.net(cls).mean(0, keepdim=True)


# --------------------------------------------------------------------------------------------
# Submanifold sparse 3x3x3 conv (transformer.point_backbone.*.cpe.0)


class SubMConv3d(nn.Module):
    """spconv SubMConv3d(kernel 3) with the spconv 2.x KRSC weight [out, kx, ky, kz, in].
    Reference: scatter the active voxels into a dense volume, dense conv3d (cross-correlation,
    padding 1), read back at the active voxels (inactive sites stay zero, as in submanifold)."""

    def __init__(self, c_in, c_out):
        super().__init__()
        self.weight = nn.Parameter(torch.zeros(c_out, 3, 3, 3, c_in))
        self.bias = nn.Parameter(torch.zeros(c_out))

    def forward(self, feats, grid):
        size = (grid.max(0).values + 1).tolist()
        vol = feats.new_zeros(1, feats.shape[1], *size)
        vol[0, :, grid[:, 0], grid[:, 1], grid[:, 2]] = feats.t()
        w = self.weight.permute(0, 4, 1, 2, 3)  # [out, in, kx, ky, kz]
        out = F.conv3d(vol, w, self.bias, padding=1)
        return out[0, :, grid[:, 0], grid[:, 1], grid[:, 2]].t()


# --------------------------------------------------------------------------------------------
# PTv3 serialization and block (transformer.point_backbone.{enc,dec}.*.block{i})


def morton_code(g):
    """Z-order of grid cells [N, 3] (int64): bit i of x -> 3i+2, of y -> 3i+1, of z -> 3i."""
    code = torch.zeros(g.shape[0], dtype=torch.int64)
    for i in range(21):
        code |= ((g[:, 0] >> i) & 1) << (3 * i + 2)
        code |= ((g[:, 1] >> i) & 1) << (3 * i + 1)
        code |= ((g[:, 2] >> i) & 1) << (3 * i)
    return code


def hilbert_code(g, depth):
    """Skilling's transform on MSB-first bit planes, interleave bit-major / dim-minor, then
    Gray decode (prefix XOR) and pack MSB first."""
    n = g.shape[0]
    bits = torch.stack([(g >> (depth - 1 - b)) & 1 for b in range(depth)], dim=-1).bool()
    for bit in range(depth):
        for d in range(3):
            m = bits[:, d, bit].clone()[:, None]
            bits[:, 0, bit + 1 :] ^= m
            t = ~m & (bits[:, 0, bit + 1 :] ^ bits[:, d, bit + 1 :])
            bits[:, d, bit + 1 :] ^= t
            bits[:, 0, bit + 1 :] ^= t
    gray = bits.transpose(1, 2).reshape(n, 3 * depth).to(torch.int64)
    binary = torch.cumsum(gray, dim=1) % 2
    weights = torch.tensor([1 << (3 * depth - 1 - i) for i in range(3 * depth)], dtype=torch.int64)
    return (binary * weights).sum(1)


def serialize(grid):
    """The official order list [z, z-trans, hilbert, hilbert-trans] as (order, inverse) pairs;
    depth = bit_length(max(grid) + 1)."""
    depth = int(grid.max() + 1).bit_length()
    trans = grid[:, [1, 0, 2]]
    codes = [morton_code(grid), morton_code(trans), hilbert_code(grid, depth), hilbert_code(trans, depth)]
    out = []
    for code in codes:
        order = torch.argsort(code)
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(order.shape[0])
        out.append((order, inverse))
    return out


class PatchAttention(nn.Module):
    """PTv3 SerializedAttention (no RPE): patches of K consecutive points of the order, the
    tail of the last patch padded with the previous patch's slots."""

    def __init__(self, c, heads, patch):
        super().__init__()
        self.heads, self.patch = heads, patch
        self.qkv = nn.Linear(c, 3 * c)
        self.proj = nn.Linear(c, c)

    def forward(self, x, order, inverse):
        n, c = x.shape
        k = min(n, self.patch)
        n_pad = n if n <= self.patch else -(-n // self.patch) * self.patch
        pad = torch.arange(n_pad)
        if n_pad != n:
            r = n % self.patch
            pad[n_pad - self.patch + r : n_pad] = pad[n_pad - 2 * self.patch + r : n_pad - self.patch].clone()
        qkv = self.qkv(x)[order[pad]]
        q, kk, v = qkv.reshape(-1, k, 3, self.heads, c // self.heads).permute(2, 0, 3, 1, 4)
        attn = torch.softmax((q * (c // self.heads) ** -0.5) @ kk.transpose(-2, -1), dim=-1)
        feat = (attn @ v).transpose(1, 2).reshape(-1, c)
        return self.proj(feat[inverse])


class PtMlp(nn.Module):
    def __init__(self, c, hidden):
        super().__init__()
        self.fc1 = nn.Linear(c, hidden)
        self.fc2 = nn.Linear(hidden, c)

    def forward(self, x):
        return self.fc2(F.gelu(self.fc1(x)))


class PtBlock(nn.Module):
    """Sonata Block, pre-norm: x += cpe(x) [SubMConv3d, Linear, LayerNorm];
    x += attn(norm1 x); x += mlp(norm2 x)."""

    def __init__(self, c, heads, patch, mlp_ratio, order_index):
        super().__init__()
        self.order_index = order_index
        self.cpe = nn.ModuleList([SubMConv3d(c, c), nn.Linear(c, c), nn.LayerNorm(c)])
        self.norm1 = nn.ModuleList([nn.LayerNorm(c)])
        self.attn = PatchAttention(c, heads, patch)
        self.norm2 = nn.ModuleList([nn.LayerNorm(c)])
        self.mlp = nn.ModuleList([PtMlp(c, int(c * mlp_ratio))])

    def forward(self, x, grid, orders):
        x = x + self.cpe[2](self.cpe[1](self.cpe[0](x, grid)))
        order, inverse = orders[self.order_index % len(orders)]
        x = x + self.attn(self.norm1[0](x), order.to(x.device), inverse.to(x.device))
        return x + self.mlp[0](self.norm2[0](x))


# --------------------------------------------------------------------------------------------
# Gaussian head (renderer.*)


class GsHead(nn.Module):
    """mlp_net (Linear, SiLU, ..., Linear) + out_layers with the official activations."""

    def __init__(self, q, n, hidden_layers, clip_scaling, max_step):
        super().__init__()
        self.clip = clip_scaling
        self.max_step = max_step
        layers = [nn.Linear(q, n), nn.SiLU()]
        for _ in range(hidden_layers - 1):
            layers += [nn.Linear(n, n), nn.SiLU()]
        layers.append(nn.Linear(n, q))
        self.mlp_net = nn.Module()
        self.mlp_net.layers = nn.Sequential(*layers)
        self.gs_net = nn.Module()
        self.gs_net.out_layers = nn.ModuleDict(
            {
                "shs": nn.Linear(q, 3),
                "scaling": nn.Linear(q, 3),
                "xyz": nn.Linear(q, 3),
                "opacity": nn.Linear(q, 1),
                "rotation": nn.Linear(q, 4),
            }
        )
        self.background_embedding = nn.Parameter(torch.zeros(3, q))

    def forward(self, feats, anchors):
        x = self.mlp_net.layers(feats)
        o = self.gs_net.out_layers
        offsets = (torch.sigmoid(o["xyz"](x)) - 0.5) * self.max_step
        return {
            "colors": torch.sigmoid(o["shs"](x)),
            "scales": torch.exp(o["scaling"](x)).clamp(0.0, self.clip),
            "offsets": offsets,
            "positions": anchors + offsets,
            "opacities": torch.sigmoid(o["opacity"](x)),
            "rotations": F.normalize(o["rotation"](x), dim=-1),
        }


# --------------------------------------------------------------------------------------------
# Neural renderer: patchify 7x7 + VGGT DPTHead (neural_renderer.*)


def make_sincos(dim, pos, omega_0=100.0):
    omega = torch.arange(dim // 2, dtype=torch.float64, device=pos.device) / (dim / 2.0)
    omega = 1.0 / omega_0**omega
    out = pos.reshape(-1).double()[:, None] * omega[None]
    return torch.cat([out.sin(), out.cos()], dim=1).float()


def uv_pos_embed(channels, h, w, aspect, ratio, device, dtype):
    """VGGT create_uv_grid + position_grid_to_embed, times ratio: [1, C, h, w]."""
    diag = (aspect**2 + 1.0) ** 0.5
    span_x, span_y = aspect / diag, 1.0 / diag
    xs = torch.linspace(-span_x * (w - 1) / w, span_x * (w - 1) / w, w, device=device)
    ys = torch.linspace(-span_y * (h - 1) / h, span_y * (h - 1) / h, h, device=device)
    uu, vv = torch.meshgrid(xs, ys, indexing="xy")  # [h, w]
    emb = torch.cat([make_sincos(channels // 2, uu), make_sincos(channels // 2, vv)], dim=-1)
    return (emb.view(h, w, channels) * ratio).permute(2, 0, 1)[None].to(dtype)


class ResidualConvUnit(nn.Module):
    def __init__(self, f):
        super().__init__()
        self.conv1 = nn.Conv2d(f, f, 3, padding=1)
        self.conv2 = nn.Conv2d(f, f, 3, padding=1)

    def forward(self, x):
        x = F.relu(x)  # the official ReLU is in place: the skip adds the rectified input
        return self.conv2(F.relu(self.conv1(x))) + x


class FusionBlock(nn.Module):
    def __init__(self, f, has_residual):
        super().__init__()
        if has_residual:
            self.resConfUnit1 = ResidualConvUnit(f)
        self.resConfUnit2 = ResidualConvUnit(f)
        self.out_conv = nn.Conv2d(f, f, 1)

    def forward(self, x, skip=None, size=None):
        if skip is not None:
            x = x + self.resConfUnit1(skip)
        x = self.resConfUnit2(x)
        if size is None:
            size = (x.shape[2] * 2, x.shape[3] * 2)
        x = F.interpolate(x, size=size, mode="bilinear", align_corners=True)
        return self.out_conv(x)


class DptHead(nn.Module):
    def __init__(self, dim_in, features, oc):
        super().__init__()
        self.norm = nn.LayerNorm(dim_in)
        self.projects = nn.ModuleList(nn.Conv2d(dim_in, c, 1) for c in oc)
        self.resize_layers = nn.ModuleList(
            [
                nn.ConvTranspose2d(oc[0], oc[0], 4, stride=4),
                nn.ConvTranspose2d(oc[1], oc[1], 2, stride=2),
                nn.Identity(),
                nn.Conv2d(oc[3], oc[3], 3, stride=2, padding=1),
            ]
        )
        s = nn.Module()
        for i in range(4):
            setattr(s, f"layer{i + 1}_rn", nn.Conv2d(oc[i], features, 3, padding=1, bias=False))
            setattr(s, f"refinenet{i + 1}", FusionBlock(features, has_residual=i != 3))
        s.output_conv1 = nn.Conv2d(features, features // 2, 3, padding=1)
        s.output_conv2 = nn.Sequential(
            nn.Conv2d(features // 2, 32, 3, padding=1), nn.ReLU(), nn.Conv2d(32, 4, 1)
        )
        self.scratch = s

    def forward(self, groups, hh, ww, H, W):
        aspect = W / H
        feats = []
        for i, g in enumerate(groups):
            x = self.norm(g)
            x = x.permute(0, 2, 1).reshape(x.shape[0], x.shape[-1], hh, ww)
            x = self.projects[i](x)
            x = x + uv_pos_embed(x.shape[1], hh, ww, aspect, 0.1, x.device, x.dtype)
            feats.append(self.resize_layers[i](x))
        s = self.scratch
        rn = [getattr(s, f"layer{i + 1}_rn")(f) for i, f in enumerate(feats)]
        out = s.refinenet4(rn[3], size=rn[2].shape[2:])
        out = s.refinenet3(out, rn[2], size=rn[1].shape[2:])
        out = s.refinenet2(out, rn[1], size=rn[0].shape[2:])
        out = s.refinenet1(out, rn[0])
        out = s.output_conv1(out)
        out = F.interpolate(out, size=(H, W), mode="bilinear", align_corners=True)
        out = out + uv_pos_embed(out.shape[1], H, W, aspect, 0.1, out.device, out.dtype)
        return s.output_conv2(out)


class PixelShuffleHead(nn.Module):
    """MLPPixelShuffleDPTHead (LHMPP-700M-PixelShuffle): the DPTHead front and refinenet4..2,
    then, instead of refinenet1 and the output convolutions,
    out = refinenet2(..) + l1_residual_fuse(layer1_rn) -> refinenet1_ps_mlp (1x1 to 4*u*u)
    -> pixel_shuffle(u) -> bilinear (align_corners) to (H, W). No position embedding after the
    fusion. Logits out (the caller applies the sigmoid)."""

    def __init__(self, dim_in, features, oc, u):
        super().__init__()
        self.u = u
        self.norm = nn.LayerNorm(dim_in)
        self.projects = nn.ModuleList(nn.Conv2d(dim_in, c, 1) for c in oc)
        self.resize_layers = nn.ModuleList(
            [
                nn.ConvTranspose2d(oc[0], oc[0], 4, stride=4),
                nn.ConvTranspose2d(oc[1], oc[1], 2, stride=2),
                nn.Identity(),
                nn.Conv2d(oc[3], oc[3], 3, stride=2, padding=1),
            ]
        )
        s = nn.Module()
        for i in range(4):
            setattr(s, f"layer{i + 1}_rn", nn.Conv2d(oc[i], features, 3, padding=1, bias=False))
        for i in (2, 3, 4):
            setattr(s, f"refinenet{i}", FusionBlock(features, has_residual=i != 4))
        self.scratch = s
        self.l1_residual_fuse = nn.Conv2d(features, features, 1)
        self.refinenet1_ps_mlp = nn.Conv2d(features, 4 * u * u, 1)

    def forward(self, groups, hh, ww, H, W):
        aspect = W / H
        feats = []
        for i, g in enumerate(groups):
            x = self.norm(g)
            x = x.permute(0, 2, 1).reshape(x.shape[0], x.shape[-1], hh, ww)
            x = self.projects[i](x)
            x = x + uv_pos_embed(x.shape[1], hh, ww, aspect, 0.1, x.device, x.dtype)
            feats.append(self.resize_layers[i](x))
        s = self.scratch
        rn = [getattr(s, f"layer{i + 1}_rn")(f) for i, f in enumerate(feats)]
        out = s.refinenet4(rn[3], size=rn[2].shape[2:])
        out = s.refinenet3(out, rn[2], size=rn[1].shape[2:])
        out = s.refinenet2(out, rn[1], size=rn[0].shape[2:])
        out = out + self.l1_residual_fuse(rn[0])
        out = self.refinenet1_ps_mlp(out)
        # pixel shuffle written out: [B, C*u*u, h, w] -> [B, C, h*u, w*u],
        # out[c, y*u + i, x*u + j] = in[c*u*u + i*u + j, y, x]
        b, cu, h, w = out.shape
        u = self.u
        out = out.reshape(b, cu // (u * u), u, u, h, w).permute(0, 1, 4, 2, 5, 3)
        out = out.reshape(b, cu // (u * u), h * u, w * u)
        return F.interpolate(out, size=(H, W), mode="bilinear", align_corners=True)


class NeuralRenderer(nn.Module):
    """PatchDPT4DecoderOnly: (hh 7)(ww 7) patches, token order (ph, pw, c), Linear without
    bias, 4 channel groups -> DPTHead -> sigmoid -> RGB + mask. With `pixel_shuffle` = u:
    PatchMLPPixelShuffleDPT4DecoderOnly, the same patchify feeding PixelShuffleHead. With
    `shared`: PatchDPTDecoderOnly at depth 1 (LHMPPS-700M), the whole tokens feed all four
    DPT inputs (dim_in = embed)."""

    def __init__(self, c, patch, embed, features, oc, pixel_shuffle=None, shared=False):
        super().__init__()
        self.patch = patch
        self.shared = shared
        self.patchify = nn.Sequential(nn.Identity(), nn.Linear(patch * patch * c, embed, bias=False))
        if shared:
            self.dense_predictor = DptHead(embed, features, oc)
        elif pixel_shuffle is None:
            self.dense_predictor = DptHead(embed // 4, features, oc)
        else:
            self.dense_predictor = PixelShuffleHead(embed // 4, features, oc, pixel_shuffle)

    def forward(self, feats):
        b, c, H, W = feats.shape
        p = self.patch
        hh, ww = H // p, W // p
        tok = feats.reshape(b, c, hh, p, ww, p).permute(0, 2, 4, 3, 5, 1).reshape(b, hh * ww, p * p * c)
        tok = self.patchify(tok)
        groups = [tok] * 4 if self.shared else tok.chunk(4, dim=-1)
        out = torch.sigmoid(self.dense_predictor(groups, hh, ww, H, W))
        return out[:, :3], out[:, 3:]


# --------------------------------------------------------------------------------------------
# Betas head of the GS-supervised releases (shape_head.*)


class ShapeHead(nn.Module):
    """ShapeHead (LHMPP-700M-PixelShuffle / -SMPLX-FREE): token_norm; num_iterations times:
    cond = embed_shape(empty_shape_tokens) the first time, embed_shape(pred) after;
    shift, scale, gate = shapeLN_modulation(cond) (SiLU then Linear C -> 3C);
    h = gate * (LN_noaffine_1e-6(x) * (1 + scale) + shift) + x; trunk of pre-norm ViT blocks with
    LayerScale (LayerNorm eps 1e-5, no qk norm, no RoPE); pred += shape_branch(trunk_norm(h))
    (Linear C -> C/2, exact GELU, Linear -> T). The input is the pose token (index 0) of every
    view after the PIT, averaged over the views."""

    def __init__(self, dim, target, trunk_depth, heads, mlp_ratio, iterations):
        super().__init__()
        self.iterations = iterations
        self.trunk_blocks = nn.ModuleList(
            DinoBlock(dim, heads, mlp_ratio, eps=1e-5) for _ in range(trunk_depth))
        self.token_norm = nn.LayerNorm(dim)
        self.trunk_norm = nn.LayerNorm(dim)
        self.empty_shape_tokens = nn.Parameter(torch.zeros(1, 1, target))
        self.embed_shape = nn.Linear(target, dim)
        self.shapeLN_modulation = nn.Sequential(nn.SiLU(), nn.Linear(dim, 3 * dim))
        self.shape_branch = Mlp(dim, dim // 2)
        self.shape_branch.fc2 = nn.Linear(dim // 2, target)

    def forward(self, tokens):
        """tokens [V, P, C] -> every step's prediction [iterations, T] (the last: the betas)."""
        x = self.token_norm(tokens[:, 0].mean(dim=0)[None, None])  # [1, 1, C]
        normed = F.layer_norm(x, x.shape[-1:], eps=1e-6)
        pred, steps = None, []
        for _ in range(self.iterations):
            cond = self.embed_shape(self.empty_shape_tokens if pred is None else pred)
            shift, scale, gate = self.shapeLN_modulation(cond).chunk(3, dim=-1)
            h = gate * (normed * (1 + scale) + shift) + x
            for block in self.trunk_blocks:
                h = block(h)
            delta = self.shape_branch(self.trunk_norm(h))
            pred = delta if pred is None else pred + delta
            steps.append(pred[0, 0])
        return torch.stack(steps)


def gaussian_fan_in_std(shape):
    fan_in = math.prod(shape[1:]) if len(shape) > 1 else shape[0]
    return 1.0 / math.sqrt(max(fan_in, 1))
