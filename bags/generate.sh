#!/usr/bin/env bash
# Regenerates the committed bag fixtures with `lhmpp synth` and `lhmpp synth-motion`
# (deterministic per seed).
set -euo pipefail
cd "$(dirname "$0")/.."
lhmpp=${LHMPP:-target/release/lhmpp}
# The demo person publishes its body shape (launch_configs/demo.yaml subscribes to it).
"$lhmpp" synth --seed 0 --views 4 --heldout 2 --size 256 --publish-shape -o bags/demo.mcap
"$lhmpp" synth --seed 1 --views 8 --heldout 4 --size 192 --pose 20 -o bags/eval_seed1.mcap
# The default model's regression fixture (tests/model_default_quality.rs): an evaluation person
# (seed 2, never trained on) with its body shape.
"$lhmpp" synth --seed 2 --views 4 --heldout 2 --size 128 --pose random --publish-shape -o bags/eval_seed2.mcap
"$lhmpp" synth-motion --seed 5 --frames 48 --fps 12 --cameras 1 --width 320 --height 240 -o bags/moving_person.mcap
