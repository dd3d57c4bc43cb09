"""Compares `lhmpp model forward` outputs with the official outputs of a generated
`io.safetensors` (scripts/parity/official/generate.py):

  python scripts/parity/official/compare.py DIR/io.safetensors OURS.safetensors

Prints output | max abs | max rel = max|ours − official| / max|official| | limit, and exits 1
when an output exceeds the limit (1e-4).
"""

import sys

from safetensors.torch import load_file

OUTPUTS = ["features", "offsets", "scales", "rotations", "opacities", "colors",
           "neural_rgb", "neural_mask"]
LIMIT = 1e-4


def main():
    official, ours = load_file(sys.argv[1]), load_file(sys.argv[2])
    print("output | max abs | max rel | limit")
    worst = 0.0
    for name in OUTPUTS:
        if name not in official or name not in ours:
            continue
        a, b = ours[name].float(), official[name].float()
        assert a.shape == b.shape, (name, a.shape, b.shape)
        d = (a - b).abs().max().item()
        r = d / b.abs().max().item()
        worst = max(worst, r)
        print(f"{name} | {d:.2e} | {r:.2e} | {LIMIT:.0e}")
    sys.exit(0 if worst <= LIMIT else 1)


if __name__ == "__main__":
    main()
