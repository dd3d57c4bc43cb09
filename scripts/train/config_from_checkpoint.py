"""Prints the network config JSON stored in one of our checkpoints' metadata (`lhmpp.config`)."""

import json
import sys

from safetensors import safe_open

with safe_open(sys.argv[1], framework="pt") as f:
    meta = f.metadata() or {}
if "lhmpp.config" not in meta:
    sys.exit(f"{sys.argv[1]}: no lhmpp.config in the metadata")
print(json.dumps(json.loads(meta["lhmpp.config"]), indent=2))
