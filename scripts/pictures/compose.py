"""Lays out the labelled pictures of scripts/pictures/make from the node's outputs."""

import sys
from pathlib import Path

from PIL import Image, ImageDraw, ImageFont

ROW = 300  # tile height, pixels
LABEL = 34  # label band height, pixels


def font(size=18):
    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow without FreeType
        return ImageFont.load_default()


def tile(image, label, height=ROW):
    """`image` scaled to `height`, with `label` in a band above it."""
    image = image.convert("RGB")
    image = image.resize((max(1, round(image.width * height / image.height)), height))
    text = int(ImageDraw.Draw(image).textlength(label, font=font())) + 12
    canvas = Image.new("RGB", (max(image.width, text), height + LABEL), "white")
    canvas.paste(image, ((canvas.width - image.width) // 2, LABEL))
    draw = ImageDraw.Draw(canvas)
    draw.text((6, 7), label, fill=(20, 20, 20), font=font())
    return canvas


def row(tiles, gap=8):
    width = sum(t.width for t in tiles) + gap * (len(tiles) - 1)
    canvas = Image.new("RGB", (width, max(t.height for t in tiles)), "white")
    x = 0
    for t in tiles:
        canvas.paste(t, (x, 0))
        x += t.width + gap
    return canvas


def column(rows, gap=12, title=None):
    width = max(r.width for r in rows)
    if title:
        width = max(width, int(ImageDraw.Draw(rows[0]).textlength(title, font=font(22))) + 12)
    top = 40 if title else 0
    height = sum(r.height for r in rows) + gap * (len(rows) - 1) + top
    canvas = Image.new("RGB", (width, height), "white")
    if title:
        ImageDraw.Draw(canvas).text((6, 8), title, fill=(0, 0, 0), font=font(22))
    y = top
    for r in rows:
        canvas.paste(r, (0, y))
        y += r.height + gap
    return canvas


def crop_to_mask(image, mask, margin=0.15):
    box = mask.convert("L").point(lambda v: 255 if v >= 128 else 0).getbbox()
    if box is None:
        return image
    x0, y0, x1, y1 = box
    m = int(margin * max(x1 - x0, y1 - y0))
    return image.crop((max(0, x0 - m), max(0, y0 - m), min(image.width, x1 + m), min(image.height, y1 + m)))


def crop_to_content(render, margin=0.08):
    """A render cropped to what is not white background."""
    rgb = render.convert("RGB")
    ink = rgb.point(lambda v: 255 if v < 245 else 0).convert("L").getbbox()
    if ink is None:
        return rgb
    x0, y0, x1, y1 = ink
    m = int(margin * max(x1 - x0, y1 - y0))
    return rgb.crop((max(0, x0 - m), max(0, y0 - m), min(rgb.width, x1 + m), min(rgb.height, y1 + m)))


def perception(out, target):
    out = Path(out)
    s2d_mask = Image.open(out / "s2d_camera/masks/demo_f120_mask.png")
    s2d = row([
        tile(crop_to_mask(Image.open(out / "s2d_camera/masks/demo_f120_overlay.png"), s2d_mask),
             "input photo + perception (mask, skeleton)"),
        tile(Image.open(out / "s2d_camera/posed_demo_f120.png"), "ours, camera-only: photo's pose"),
        tile(Image.open(out / "s2d_camera/turntable/000.png"), "ours, camera-only: front"),
        tile(Image.open(out / "s2d_camera/turntable/001.png"), "side"),
        tile(Image.open(out / "s2d_hand/turntable/000.png"), "ours, hand mask: front"),
        tile(Image.open(out / "s2d_hand/turntable/001.png"), "side"),
    ])
    p2s_tiles = []
    for c in range(1, 5):
        mask = Image.open(out / f"p2s_camera/masks/single_cam{c}_f040_mask.png")
        overlay = Image.open(out / f"p2s_camera/masks/single_cam{c}_f040_overlay.png")
        p2s_tiles.append(tile(crop_to_mask(overlay, mask), f"input camera {c}"))
    p2s_tiles += [
        tile(Image.open(out / "p2s_camera/turntable/000.png"), "ours, 4 views: front"),
        tile(Image.open(out / "p2s_camera/turntable/001.png"), "side"),
        tile(Image.open(out / "p2s_camera/turntable/002.png"), "back"),
    ]
    picture = column(
        [s2d, row(p2s_tiles)],
        title="Camera-only perception on real photos (Sports2D, Pose2Sim demo frames, BSD-3): "
        "no mask topic, no segmentation node",
    )
    picture.save(target)


def live_pose(out, target):
    from mcap_ros2.reader import read_ros2_messages

    out = Path(out)
    frames = [
        Image.frombytes("RGB", (m.ros_msg.width, m.ros_msg.height), bytes(m.ros_msg.data))
        for m in read_ros2_messages("bags/moving_person.mcap", topics=["/cam0/image_raw"])
    ]
    pairs = []
    for i in (6, 18, 30, 42):
        rendered = Image.open(out / f"camera_only/frames/person_0_cam0_{i:03d}.png")
        pairs.append(row([
            tile(frames[i], f"input frame {i}", height=240),
            tile(rendered, "avatar, camera pose", height=240),
        ], gap=2))
    column(
        [row(pairs[:2], gap=24), row(pairs[2:], gap=24)],
        title="Live pose from one camera (bags/moving_person.mcap): the avatar moves as the person does",
    ).save(target)


def overview(out, target):
    """The README's first picture: one camera frame in, perception's mask and skeleton, the
    avatar from three sides, and frames rendered in new poses."""
    out = Path(out)
    mask = Image.open(out / "s2d_camera/masks/demo_f120_mask.png")
    photo = Image.open("target/devset/sports2d/demo_f120.png")
    overlay = Image.open(out / "s2d_camera/masks/demo_f120_overlay.png")
    tiles = [
        tile(crop_to_mask(photo, mask), "1. input: one camera frame"),
        tile(crop_to_mask(overlay, mask), "2. perception: mask + pose"),
        tile(crop_to_content(Image.open(out / "s2d_camera/turntable/000.png")), "3. avatar: front"),
        tile(crop_to_content(Image.open(out / "s2d_camera/turntable/001.png")), "side"),
        tile(crop_to_content(Image.open(out / "s2d_camera/turntable/002.png")), "back"),
        tile(crop_to_content(Image.open(out / "s2d_camera/walk/000.png")), "4. rendered, new pose"),
    ]
    column(
        [row(tiles)],
        title="A camera frame in, a Gaussian avatar out (real photo: Sports2D demo, BSD-3)",
    ).save(target)


def people(out, target):
    """Several people in one real frame: perception's masks, skeletons and person ids."""
    out = Path(out)
    frame = Image.open(out / "people/multi_cam1_f030_people.png")
    column(
        [row([tile(frame, "lhmpp perceive --people: masks, skeletons, person ids, MoveNet scores",
                   height=900)])],
        title="Several people in one frame (Pose2Sim demo, BSD-3)",
    ).save(target)


def tracked(out, target):
    """Two synthetic people tracked by the node (launch_configs/people.yaml): a camera frame
    with each person's mask tinted by the id the tracker gave it, and each person's avatar from
    the front and the back."""
    out = Path(out)
    frames = sorted((out / "tracked_frames").glob("*_cam0.png"))
    overlay = Image.open(frames[len(frames) // 5])  # before they cross
    overlay = overlay.crop((0, 0, overlay.width // 2, overlay.height))
    tiles = [tile(overlay, "camera frame: tracked ids")]
    for person in ["person_0", "person_1"]:
        renders = out / "tracked" / f"render_{person}"
        for view, side in [("f0000_v00.png", "front"), ("f0000_v02.png", "back")]:
            tiles.append(tile(crop_to_content(Image.open(renders / view)), f"{person}, {side}"))
    column([row(tiles)], title="several people: one avatar per tracked person").save(target)


def real_tracked(out, target):
    """Two real people in four calibrated cameras (Pose2Sim Demo_MultiPerson, BSD-3) tracked
    by the node: one frame of each camera with each person's mask tinted by the id the tracker
    gave it, and each tracked id's avatar from the front and the side."""
    out = Path(out)
    frame = 25  # of 50: both people in every camera
    tiles = []
    for cam in range(4):
        (path,) = sorted((out / "frames").glob(f"*_{4 * frame + cam:04d}_cam{cam}.png"))
        overlay = Image.open(path)
        tiles.append(tile(overlay.crop((0, 0, overlay.width // 2, overlay.height)), f"cam{cam}", height=420))
    avatars = []
    for person in sorted(p.name[len("render_"):] for p in out.glob("node/render_person_*")):
        renders = out / "node" / f"render_{person}"
        for view, side in [("f0000_v00.png", "front"), ("f0000_v01.png", "side")]:
            avatars.append(tile(crop_to_content(Image.open(renders / view)), f"{person}, {side}", height=300))
    column([row(tiles), row(avatars)],
           title="two real people in four calibrated cameras: the node's ids, one per person across the "
                 "cameras, and each id's avatar (person_2: the lab's anatomical skeleton)"
           ).save(target)


def one_person(out, target):
    """One person followed in a wide real view (Sports2D's demo clip, BSD-3) by the node's
    one-person mode: two frames with the followed person's mask and landmarks (MoveNet found
    them; the landmarks' crop followed them), and the avatar the node made of the clip's first
    140 frames from the front and the side."""
    out = Path(out)
    tiles = []
    for frame in (40, 120):
        (path,) = sorted((out / "frames").glob(f"*_{frame:04d}_cam0.png"))
        tiles.append(tile(Image.open(path), f"frame {frame} of 230, 640x360", height=360))
    renders = out / "node" / "render"
    for view, side in [("f0000_v00.png", "front"), ("f0000_v01.png", "side")]:
        tiles.append(tile(crop_to_content(Image.open(renders / view)), f"avatar, {side}", height=360))
    column([row(tiles)],
           title="one person followed in a wide outdoor view (real video): mask and landmarks of the "
                 "person followed, and the avatar the node made of them").save(target)


def refined_photo(out, target):
    """Real photos (the Pose2Sim man's four cameras, BSD-3) beside the avatar in each photo's
    pose before and after it was fitted to them (lhmpp avatar --no-refine / --refine)."""
    out = Path(out)
    rows = []
    for c in (1, 3):
        stem = f"single_cam{c}_f040"
        mask = Image.open(out / f"p2s_plain/masks/{stem}_mask.png")
        photo = Image.open(out / f"p2s_plain/masks/{stem}_overlay.png")
        rows.append(row([
            tile(crop_to_mask(photo, mask), f"photo, camera {c} (with perception)"),
            tile(crop_to_content(Image.open(out / f"p2s_plain/posed_{stem}.png")),
                 "avatar, network + photo colours"),
            tile(crop_to_content(Image.open(out / f"p2s_refined/posed_{stem}.png")),
                 "avatar, refined to the photos"),
        ]))
    rows.append(row([
        tile(Image.open(out / "p2s_plain/turntable/000.png"), "before: front"),
        tile(Image.open(out / "p2s_plain/turntable/002.png"), "before: back"),
        tile(Image.open(out / "p2s_refined/turntable/000.png"), "refined: front"),
        tile(Image.open(out / "p2s_refined/turntable/002.png"), "refined: back"),
    ]))
    column(rows, title="lhmpp avatar on four real photos (Pose2Sim, BSD-3): before and after "
                       "--refine, each render in the photo's pose from the front").save(target)


if __name__ == "__main__":
    kind, out, target = sys.argv[1:4]
    {
        "perception": perception,
        "live-pose": live_pose,
        "overview": overview,
        "people": people,
        "tracked": tracked,
        "real-tracked": real_tracked,
        "one-person": one_person,
        "refined-photo": refined_photo,
    }[kind](out, target)
