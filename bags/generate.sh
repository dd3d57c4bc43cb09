#!/usr/bin/env bash
# Regenerates the committed bag fixtures with `lhmpp synth` (deterministic per seed).
set -euo pipefail
cd "$(dirname "$0")/.."
lhmpp=${LHMPP:-target/release/lhmpp}
"$lhmpp" synth --seed 0 --views 4 --heldout 2 --size 256 -o bags/demo.mcap
"$lhmpp" synth --seed 1 --views 8 --heldout 4 --size 192 --pose 20 -o bags/eval_seed1.mcap
