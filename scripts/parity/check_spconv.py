"""Checks the sparse-conv fixture's dense reference against spconv itself (when installed):
builds spconv's SubMConv3d with the fixture's `[out, kx, ky, kz, in]` weight, runs it on the
fixture's voxels and prints max abs / max rel error against `parity.output.y`.

    python check_spconv.py tests/fixtures/parity/sparse_conv.safetensors
"""

import sys

import spconv.pytorch as spconv
import torch
from safetensors import safe_open


def main(path):
    f = safe_open(path, "pt")
    prefix = f.metadata()["prefix"]
    w, b = f.get_tensor(prefix + "weight"), f.get_tensor(prefix + "bias")
    grid, x, want = (f.get_tensor(f"parity.{k}") for k in ("input.grid", "input.x", "output.y"))
    c_out, c_in = w.shape[0], w.shape[-1]
    conv = spconv.SubMConv3d(c_in, c_out, 3, bias=True, indice_key="subm0")
    print(f"spconv weight shape {tuple(conv.weight.shape)} algo {conv.algo}")
    with torch.no_grad():
        if tuple(conv.weight.shape) == tuple(w.shape):  # KRSC [out, kx, ky, kz, in]
            conv.weight.copy_(w)
        else:  # Native RSKC [kx, ky, kz, in, out]
            conv.weight.copy_(w.permute(1, 2, 3, 4, 0))
        conv.bias.copy_(b)
    coords = torch.cat([torch.zeros(grid.shape[0], 1, dtype=torch.int32), grid.int()], 1)
    shape = (grid.max(0).values + 1).tolist()
    st = spconv.SparseConvTensor(x, coords, shape, batch_size=1)
    with torch.no_grad():
        got = conv(st)
    # spconv keeps the input order for submanifold convs; match rows by coordinates anyway.
    order = {tuple(c.tolist()): i for i, c in enumerate(got.indices[:, 1:])}
    rows = torch.tensor([order[tuple(c.tolist())] for c in grid.int()])
    y = got.features[rows]
    err = (y - want).abs().max().item()
    print(f"spconv vs reference: max abs {err:.3e}, max rel {err / want.abs().max().item():.3e}")


if __name__ == "__main__":
    main(sys.argv[1])
