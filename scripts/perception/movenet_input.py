#!/usr/bin/env python3
"""Letterboxes a photo into a square MoveNet input (black bars, centred; Pillow's bilinear
resampling, antialiased when shrinking) and writes it as a binary PPM for
reference_movenet.mjs.

Usage: movenet_input.py IMAGE SIDE OUT.ppm   (SIDE a multiple of 32)
"""

import sys

from PIL import Image


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    path, side, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    if side <= 0 or side % 32:
        sys.exit(f"movenet_input.py: side {side} is not a positive multiple of 32")
    im = Image.open(path).convert("RGB")
    long = max(im.size)
    square = Image.new("RGB", (long, long))
    square.paste(im, ((long - im.width) // 2, (long - im.height) // 2))
    square.resize((side, side), Image.BILINEAR).save(out, format="PPM")


if __name__ == "__main__":
    main()
