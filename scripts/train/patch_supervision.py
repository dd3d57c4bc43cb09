"""Trainer-only supervision of what the image tokens carry.

Trained from scratch on a 2-core budget, the tiny encoder does not learn on its own to put the
person's colours into its tokens: an encoder-only experiment (a 2-layer, 64-wide DINOv2 trained
to predict six body-region colours from its CLS token, 1,000 people, 7,800 steps) stayed at the
error of predicting the average person (test L1 0.155 against 0.155), and a linear probe on the
tokens of the first trained default read colours barely better than the mean. The points can
only copy what the tokens hold. Synthetic data knows, for every patch of every input view, which
anchors it shows (`anchor_pixels` from `lhmpp synth-dataset`), so this module adds a linear head
on the encoder's patch tokens that predicts, per patch, the mean canonical colour and the mean
canonical position of the anchors the patch shows, with an L1 loss over the patches that show
any. With it the same encoder-only experiment reached a patch colour L1 of 0.05 and a region
colour L1 of 0.11 in the same steps. The head is not part of the shipped network: the forward
pass and the checkpoint layout are unchanged.
"""

import torch
import torch.nn as nn

HIDDEN = 65535
# Canonical positions are centred on the anchors' mean and divided by this (metres), so the
# position targets are about as large as the colours.
POSITION_SCALE = 0.5


def patch_targets(sample, patch_size):
    """Per view and patch of the encoder input: the mean colour and centred canonical position
    of the anchors the patch shows, `[V, h*w, 6]`, and which patches show any, `[V, h*w]`.
    Uses every anchor of the sample (call it before anchors are subsampled)."""
    px = sample["anchor_pixels"].to(torch.int64)
    v, n, _ = px.shape
    height, width = sample["images"].shape[-2:]
    gh, gw = height // patch_size, width // patch_size
    seen = (px[..., 0] != HIDDEN) & (px[..., 0] < gw * patch_size) & (px[..., 1] < gh * patch_size)
    cell = (px[..., 1] // patch_size) * gw + px[..., 0] // patch_size
    flat = (torch.arange(v)[:, None] * (gh * gw) + cell)[seen]
    anchors = sample["anchors"].float()
    values = torch.cat([sample["colors"].float(), (anchors - anchors.mean(0)) / POSITION_SCALE], 1)
    values = values[None].expand(v, n, 6)[seen]
    sums = torch.zeros(v * gh * gw, 6).index_add(0, flat, values)
    count = torch.zeros(v * gh * gw).index_add(0, flat, torch.ones(flat.shape[0]))
    target = (sums / count.clamp_min(1.0)[:, None]).reshape(v, gh * gw, 6)
    return target, (count > 0).reshape(v, gh * gw)


class EncoderCapture:
    """Keeps the encoder's last output `(cls [V, C], patches [V, h*w, C])` of each forward, so
    trainer-only heads read the tokens of the pass that is being trained (no second pass)."""

    def __init__(self, model):
        self.last = None
        model.encoder.model.register_forward_hook(self._keep)

    def _keep(self, _module, _inputs, output):
        self.last = output


class PatchHead(nn.Module):
    """The trainer-only linear head: patch token -> (colour, centred canonical position)."""

    def __init__(self, dim):
        super().__init__()
        self.linear = nn.Linear(dim, 6)

    def loss(self, patches, target, shown):
        """L1 between the head's prediction and the targets over the patches that show an
        anchor; None when none does."""
        if not shown.any():
            return None
        pred = self.linear(patches)
        return (pred[shown] - target[shown]).abs().mean()
