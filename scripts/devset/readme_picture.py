"""The README's real-people picture: three dev-set people, each photo (cropped to the person)
beside our avatar from the front and from the side (`lhmpp avatar` turntable frames 0 and 2 of
8). Run by scripts/devset/readme-picture after it made the avatars.

    python readme_picture.py OUT.png NAME:PHOTO:MASK:AVATAR_DIR ...
"""

import sys

from PIL import Image, ImageChops, ImageDraw

H = 300  # row height


def crop_to_mask(photo, mask, margin=0.08):
    box = mask.point(lambda v: 255 if v >= 128 else 0).getbbox()
    if box is None:
        return photo
    w, h = box[2] - box[0], box[3] - box[1]
    m = int(margin * max(w, h))
    return photo.crop((max(box[0] - m, 0), max(box[1] - m, 0),
                       min(box[2] + m, photo.width), min(box[3] + m, photo.height)))


def fit(img, height):
    return img.resize((max(1, round(img.width * height / img.height)), height), Image.LANCZOS)


def trim_white(img):
    """`img` cropped to what is not (nearly) white."""
    ink = ImageChops.invert(img).convert("L").point(lambda v: 255 if v > 8 else 0)
    box = ink.getbbox()
    return img.crop(box) if box else img


def main():
    out, rows = sys.argv[1], sys.argv[2:]
    tiles = []
    for spec in rows:
        name, photo, mask, avatar = spec.split(":")
        p = Image.open(photo).convert("RGB")
        m = Image.open(mask).convert("L").resize(p.size)
        front = trim_white(Image.open(f"{avatar}/turntable/000.png").convert("RGB"))
        side = trim_white(Image.open(f"{avatar}/turntable/002.png").convert("RGB"))
        tiles.append((name, [fit(crop_to_mask(p, m), H), fit(front, H - 20), fit(side, H - 20)]))
    pad, label = 16, 36
    width = max(sum(t.width for t in imgs) + pad * (len(imgs) + 1) for _, imgs in tiles)
    sheet = Image.new("RGB", (width, len(tiles) * (H + label + pad) + pad), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    y = pad
    for name, imgs in tiles:
        x = pad
        draw.text((x, y), name, fill=(0, 0, 0))
        for k, img in enumerate(imgs):
            caption = ["photo", "ours, front", "ours, side"][k]
            draw.text((x, y + 16), caption, fill=(90, 90, 90))
            sheet.paste(img, (x, y + label + (H - img.height)))
            x += img.width + pad
        y += H + label + pad
    sheet.save(out)
    print(f"wrote {out} ({sheet.width}x{sheet.height})")


if __name__ == "__main__":
    main()
