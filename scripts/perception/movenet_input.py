#!/usr/bin/env python3
"""Letterboxes a photo into a MoveNet input (the photo centred in the smallest rectangle of the
input's aspect around it, black bars; Pillow's bilinear resampling, antialiased when shrinking)
and writes it as a binary PPM for reference_movenet.mjs.

Usage: movenet_input.py IMAGE SIZE OUT.ppm   (SIZE: SIDE or HEIGHTxWIDTH, multiples of 32)
"""

import sys

from PIL import Image


def main():
    if len(sys.argv) != 4:
        sys.exit(__doc__)
    path, size, out = sys.argv[1:]
    h, _, w = size.partition("x")
    h, w = int(h), int(w or h)
    if h <= 0 or w <= 0 or h % 32 or w % 32:
        sys.exit(f"movenet_input.py: size {size} is not made of positive multiples of 32")
    im = Image.open(path).convert("RGB")
    bw = max(im.width, round(im.height * w / h))
    bh = max(im.height, round(im.width * h / w))
    boxed = Image.new("RGB", (bw, bh))
    boxed.paste(im, ((bw - im.width) // 2, (bh - im.height) // 2))
    boxed.resize((w, h), Image.BILINEAR).save(out, format="PPM")


if __name__ == "__main__":
    main()
