"""Trainer-only supervision of where the points look in the images.

The network the node runs has no camera path: its points find the image patches that show them
only through learnt attention, which a 2-core training budget does not teach from the render
and colour losses alone (the first default model attended mostly to the background and learnt
the average colour of each body part). Synthetic data knows the answer: `lhmpp synth-dataset`
records, per input view, the pixel of the preprocessed image where each anchor shows
(`anchor_pixels`, hidden anchors marked 65535). This module captures, in the last decoder PIT
block (level 0: one point row per anchor voxel), the attention logits of one head from the
points to the (merged) image tokens, and returns the cross-entropy that puts that head's
attention on the tokens showing the anchor in any view:

    loss = mean over anchors seen in >= 1 view of  -log sum_{m in shown(a)} softmax_m(q_a . k_m / sqrt(d))

The softmax runs over the image tokens only (how much the point attends to images at all is left
to the network). Nothing here changes the forward pass or the shipped weights' layout: the same
logits are recomputed from the block's own projections.
"""

import math

import torch
import torch.nn.functional as F

import lhmpp_torch

HIDDEN = 65535


class AttentionCapture:
    """Installs the capture on `model` (once): after each forward, `self.last` holds the
    supervised block's point queries and image keys of `head` and its token-merge plan."""

    def __init__(self, model, head=0):
        self.model = model
        self.head = head
        self.block = model.transformer.pi_transformer_dec[-1]
        self.last = None
        attn = self.block.attn
        capture = self

        def forward(x, c):
            b, n, d = x.shape

            def heads(t):
                return t.view(b, -1, attn.heads, d // attn.heads).transpose(1, 2)

            qx = attn.norm_q(heads(attn.to_q(x)))
            kc = attn.norm_added_k(heads(attn.add_k_proj(c)))
            q = torch.cat([qx, attn.norm_added_q(heads(attn.add_q_proj(c)))], 2)
            k = torch.cat([attn.norm_k(heads(attn.to_k(x))), kc], 2)
            v = torch.cat([heads(attn.to_v(x)), heads(attn.add_v_proj(c))], 2)
            out = F.scaled_dot_product_attention(q, k, v).transpose(1, 2).reshape(b, -1, d)
            x_out = attn.to_out[0](out[:, :n])
            c_out = None if attn.to_add_out is None else attn.to_add_out(out[:, n:])
            capture.last = {"q": qx[0, capture.head], "k": kc[0, capture.head],
                            "plan": capture._plan}
            return x_out, c_out

        attn.forward = forward
        self._plan = None
        original = lhmpp_torch.multi_modal_step

        def step(block, tokens, metric, points, temb, grid, ratio):
            if block is capture.block:
                v, n, _ = tokens.shape
                hw = n - lhmpp_torch.SPECIAL_TOKENS
                m = metric[:, lhmpp_torch.SPECIAL_TOKENS:].reshape(v * hw, metric.shape[2])
                capture._plan = lhmpp_torch.TokenMergePlan(m, grid[0], grid[1] * v, int(ratio * (v * hw)))
            return original(block, tokens, metric, points, temb, grid, ratio)

        lhmpp_torch.multi_modal_step = step

    def loss(self, sample, patch_size):
        """The cross-entropy above for the forward just run on `sample` (which must carry
        `anchor_pixels` [V, N, 2]); None when no anchor is seen."""
        cap = self.last
        px = sample["anchor_pixels"].to(torch.int64)
        v, n, _ = px.shape
        size = sample["images"].shape[-1]
        gw = size // patch_size
        hw = (sample["images"].shape[-2] // patch_size) * gw
        seen = px[..., 0] != HIDDEN
        token = torch.arange(v)[:, None] * hw + (px[..., 1] // patch_size) * gw + px[..., 0] // patch_size
        plan = cap["plan"]
        merged = token if plan is None or plan.identity else plan.unmerge_rows[token.clamp(0, v * hw - 1)]
        geo = self.model.geometry(sample["anchors"], sample["normals"])
        _, inverse = geo.levels[0].hilbert
        rows = inverse[geo.input_inverse]  # anchor -> its point row in the block
        q, k = cap["q"], cap["k"]
        logp = torch.log_softmax(q[rows] @ k.t() / math.sqrt(q.shape[-1]), -1)  # [N, M]
        target = torch.zeros_like(logp, dtype=torch.bool)
        a_idx = torch.arange(n)[None].expand(v, n)
        target[a_idx[seen], merged[seen]] = True
        valid = target.any(-1)
        if not valid.any():
            return None
        per = torch.logsumexp(logp.masked_fill(~target, float("-inf")), -1)
        return -per[valid].mean()
