"""Writes one training sample's network input (`images` f32 [V,3,H,W] in [0,1], `anchors`,
`normals`) in the layout of `lhmpp model forward --input`, for the export gate.

    sample_input.py SHARD INDEX OUT.safetensors
"""

import sys

from safetensors import safe_open
from safetensors.torch import save_file

shard, k, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
with safe_open(shard, framework="pt") as f:
    images = f.get_tensor(f"{k}.images").float() / 255.0
    anchors = f.get_tensor(f"{k}.anchors")
    normals = f.get_tensor(f"{k}.normals")
save_file({"images": images.contiguous(), "anchors": anchors, "normals": normals}, out)
print(f"{out}: sample {k} of {shard}: {images.shape[0]} views, {anchors.shape[0]} anchors")
