"""Extracts the dev set's frames from the downloaded wheels (see scripts/devset/install)."""

import io
import sys
import zipfile
from pathlib import Path

import imageio.v3 as iio

# (wheel prefix, member, output stem, frame indices); video frames are 0-based.
VIDEOS = [
    ("pose2sim", f"Pose2Sim/Demo_SinglePerson/videos/cam0{c}.mp4", f"pose2sim/single_cam{c}", (10, 40, 70))
    for c in range(1, 5)
] + [
    ("pose2sim", f"Pose2Sim/Demo_MultiPerson/videos/cam0{c}.mp4", f"pose2sim/multi_cam{c}", (30,))
    for c in range(1, 5)
] + [("sports2d", "Sports2D/Demo/demo.mp4", "sports2d/demo", (40, 120, 200))]

STILLS = [
    ("ultralytics", "ultralytics/assets/bus.jpg", "ultralytics/bus.jpg"),
    ("ultralytics", "ultralytics/assets/zidane.jpg", "ultralytics/zidane.jpg"),
]

SOURCES = """# Dev set sources (installed by scripts/devset/install; not committed)

| files | package (PyPI) | licence | what |
| --- | --- | --- | --- |
| pose2sim/single_* | pose2sim 0.10.49, Pose2Sim/Demo_SinglePerson/videos | BSD-3-Clause, (c) 2022 perfanalytics | one person, 4 synchronised cameras |
| pose2sim/multi_* | pose2sim 0.10.49, Pose2Sim/Demo_MultiPerson/videos | BSD-3-Clause, (c) 2022 perfanalytics | two people, 4 cameras |
| sports2d/* | sports2d 0.8.34, Sports2D/Demo/demo.mp4 | BSD-3-Clause, (c) 2022 perfanalytics | people outdoors |
| ultralytics/* | ultralytics 8.4.190, ultralytics/assets | AGPL-3.0 | a street with a bus; two men in suits |
"""


def wheel(dir_: Path, prefix: str) -> zipfile.ZipFile:
    (path,) = sorted(dir_.glob(f"wheels/{prefix}-*.whl"))
    return zipfile.ZipFile(path)


def main() -> None:
    out = Path(sys.argv[1])
    for prefix, member, stem, frames in VIDEOS:
        data = wheel(out, prefix).read(member)
        wanted = set(frames)
        for i, frame in enumerate(iio.imiter(io.BytesIO(data), extension=".mp4", plugin="FFMPEG")):
            if i in wanted:
                target = out / f"{stem}_f{i:03d}.png"
                target.parent.mkdir(parents=True, exist_ok=True)
                iio.imwrite(target, frame)
            if i >= max(frames):
                break
    for prefix, member, name in STILLS:
        target = out / name
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes(wheel(out, prefix).read(member))
    (out / "SOURCES.md").write_text(SOURCES)
    hand_masks(out)


def hand_masks(out: Path) -> None:
    """Rasterises scripts/devset/hand_masks/*.json into target/devset/hand_masks/*.png."""
    import json

    from PIL import Image, ImageDraw

    here = Path(__file__).parent / "hand_masks"
    (out / "hand_masks").mkdir(exist_ok=True)
    for spec in sorted(here.glob("*.json")):
        p = json.loads(spec.read_text())
        photo = Image.open(out / p["image"])
        (dx, dy), s = p["offset"], p["scale"]
        points = [(x * s + dx, y * s + dy) for x, y in p["polygon"]]
        mask = Image.new("L", photo.size, 0)
        ImageDraw.Draw(mask).polygon(points, fill=255)
        mask.save(out / "hand_masks" / f"{spec.stem}.png")


if __name__ == "__main__":
    main()
