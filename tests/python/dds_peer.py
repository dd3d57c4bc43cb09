"""Independent DDS peer for tests/node_interop.rs, built on the PyPI `cyclonedds` package.

It plays a camera and a consumer at once:
  * publishes sensor_msgs/Image frames of a synthetic person on --image-topic and the same
    frames PNG-compressed as sensor_msgs/CompressedImage on --compressed-topic (best effort,
    keep last 5, like a camera driver's sensor-data QoS), every fifth one preceded by a frame
    with an inconsistent `step` that the node must reject and survive;
  * subscribes to the node's GaussianAvatar (--avatar-topic) and rendered Image
    (--render-topic) and checks their field layout, sizes and values.

It prints one line `RESULT ok ...` or `RESULT fail <reason>` and exits (0 on ok), at the latest
after --timeout seconds. ROS topic names map to DDS as `rt/<name without leading slash>`.
"""

import argparse
import struct
import sys
import time
import zlib

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant

import numpy as np
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic
from cyclonedds.util import duration


from ros_idl import Time, Header, Image, CompressedImage, Point, PointField, PointCloud2, GaussianAvatar


def png_rgb8(width, height, rgb):
    """A minimal PNG (8-bit RGB, no filter) of `rgb` bytes, written with zlib only."""
    def chunk(kind, body):
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))
    rows = b"".join(b"\x00" + rgb[y * width * 3:(y + 1) * width * 3] for y in range(height))
    return (b"\x89PNG\r\n\x1a\n"
            + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))


# Field order as in msg/msg/GaussianAvatar.msg.
FLOAT32, UINT16 = 7, 4
RGB_FIELDS = ["x", "y", "z", "scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2",
              "rot_3", "opacity", "r", "g", "b"]
SKIN_FIELDS = ["bone_0", "bone_1", "bone_2", "bone_3", "weight_0", "weight_1", "weight_2",
               "weight_3"]


def check_avatar(msg, expect_person, expect_gaussians):
    """Checks layout, sizes and values of a GaussianAvatar; returns None or the problem."""
    if msg.person_id != expect_person:
        return f"person_id {msg.person_id!r} != {expect_person!r}"
    if msg.revision < 1:
        return f"revision {msg.revision} < 1"
    if msg.sh_degree != 0:
        return f"sh_degree {msg.sh_degree}, expected 0"
    nb = len(msg.bone_names)
    if nb == 0 or len(msg.bone_parents) != nb or len(msg.bone_rest_positions) != nb:
        return f"skeleton sizes {nb}/{len(msg.bone_parents)}/{len(msg.bone_rest_positions)}"
    if msg.bone_parents[0] != -1 or any(not (-1 <= p < i) for i, p in enumerate(msg.bone_parents)):
        return f"bone_parents {list(msg.bone_parents)} are not parent-first"
    g = msg.gaussians
    if g.height != 1 or g.width != expect_gaussians:
        return f"gaussians {g.width}x{g.height}, expected {expect_gaussians}x1"
    if g.is_bigendian:
        return "gaussians are big endian"
    names = [f.name for f in g.fields]
    # Fields are found by name (their order is the offsets' business).
    if sorted(names) != sorted(RGB_FIELDS + SKIN_FIELDS):
        return f"fields {names}"
    if g.row_step != g.point_step * g.width or len(g.data) != g.row_step:
        return f"sizes: point_step {g.point_step}, row_step {g.row_step}, data {len(g.data)}"
    raw = np.frombuffer(bytes(g.data), dtype=np.uint8).reshape(g.width, g.point_step)
    cols = {}
    for f in g.fields:
        if f.count != 1:
            return f"field {f.name} count {f.count}"
        dt, size = {FLOAT32: ("<f4", 4), UINT16: ("<u2", 2)}.get(f.datatype, (None, 0))
        if dt is None:
            return f"field {f.name} datatype {f.datatype}"
        if f.offset + size > g.point_step:
            return f"field {f.name} offset {f.offset} past point_step {g.point_step}"
        cols[f.name] = raw[:, f.offset:f.offset + size].copy().view(dt).reshape(-1)
    floats = np.stack([cols[n] for n in RGB_FIELDS + SKIN_FIELDS[4:]])
    if not np.all(np.isfinite(floats)):
        return "non-finite float values"
    q = np.stack([cols[f"rot_{i}"] for i in range(4)])
    if np.max(np.abs(np.linalg.norm(q, axis=0) - 1)) > 1e-4:
        return "rotations are not unit quaternions"
    if np.any(np.stack([cols[f"scale_{i}"] for i in range(3)]) <= 0):
        return "non-positive scales"
    for n in ("opacity", "r", "g", "b"):
        if cols[n].min() < 0 or cols[n].max() > 1:
            return f"{n} outside [0, 1]"
    w = np.stack([cols[f"weight_{i}"] for i in range(4)])
    if np.any(w < 0) or np.max(np.abs(w.sum(axis=0) - 1)) > 1e-5:
        return "skin weights are negative or do not sum to 1"
    b = np.stack([cols[f"bone_{i}"] for i in range(4)])
    if b.max() >= nb:
        return f"bone index {b.max()} >= {nb} bones"
    return None


def person_frame(width, height, index):
    """rgb8 bytes of a synthetic person: grey background, a red-to-blue torso box, index-tinted."""
    buf = bytearray(width * height * 3)
    x0, x1 = width * 3 // 8, width * 5 // 8
    y0, y1 = height // 8, height * 7 // 8
    for y in range(height):
        row = y * width * 3
        for x in range(width):
            o = row + 3 * x
            if x0 <= x < x1 and y0 <= y < y1:
                t = (y - y0) / max(1, y1 - y0 - 1)
                buf[o] = int(255 * (1 - t))
                buf[o + 1] = index % 256
                buf[o + 2] = int(255 * t)
            else:
                buf[o] = buf[o + 1] = buf[o + 2] = 90
    return bytes(buf)


def stamp_now():
    t = time.time()
    return Time(sec=int(t), nanosec=int((t % 1) * 1e9))


def check_render(msg, expect_side):
    if msg.encoding != "rgb8":
        return f"render encoding {msg.encoding!r} is not rgb8"
    if msg.width != expect_side or msg.height != expect_side:
        return f"render size {msg.width}x{msg.height}, expected {expect_side}x{expect_side}"
    if msg.step != msg.width * 3:
        return f"render step {msg.step} != width*3"
    if len(msg.data) != msg.step * msg.height:
        return f"render data {len(msg.data)} bytes != step*height"
    return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--image-topic", required=True)
    ap.add_argument("--compressed-topic", required=True)
    ap.add_argument("--avatar-topic", required=True)
    ap.add_argument("--render-topic", required=True)
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--render-side", type=int, default=32)
    ap.add_argument("--gaussians", type=int, default=100)
    ap.add_argument("--person", default="person_0")
    ap.add_argument("--timeout", type=float, default=40.0)
    ap.add_argument("--first-frame", type=int, default=0,
                    help="index of the first frame sent (a peer that comes back sends new views)")
    ap.add_argument("--min-revisions", type=int, default=1,
                    help="distinct avatar revisions to receive, each higher than the last")
    ap.add_argument("--above-revision", type=int, default=0,
                    help="wait for a revision higher than this (a peer that comes back)")
    args = ap.parse_args()

    dp = DomainParticipant(args.domain)
    dds = lambda name: "rt/" + name.lstrip("/")
    camera_qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5))
    image_topic = Topic(dp, dds(args.image_topic), Image)
    writer = DataWriter(dp, image_topic, qos=camera_qos)
    compressed_writer = DataWriter(
        dp, Topic(dp, dds(args.compressed_topic), CompressedImage), qos=camera_qos)

    render_qos = Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(2))
    render_reader = DataReader(dp, Topic(dp, dds(args.render_topic), Image), qos=render_qos)

    avatar_qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)),
                     Policy.Durability.TransientLocal, Policy.History.KeepLast(1))
    avatar_reader = DataReader(dp, Topic(dp, dds(args.avatar_topic), GaussianAvatar),
                               qos=avatar_qos)

    deadline = time.monotonic() + args.timeout
    avatar_err = "no avatar received"
    avatar_ok = False
    revisions = []
    render_err = "no rendered frame received"
    render_ok = False
    sent = 0
    first_render_at = None
    start = time.monotonic()
    next_progress = start + 5.0
    while time.monotonic() < deadline:
        if time.monotonic() >= next_progress:
            # Progress on stderr (the test shows it): who matched whom so far.
            next_progress += 5.0
            print(f"peer: {time.monotonic() - start:.0f} s, sent {sent} frames; matched readers "
                  f"image {len(writer.get_matched_subscriptions())}, compressed "
                  f"{len(compressed_writer.get_matched_subscriptions())}; matched writers "
                  f"avatar {len(avatar_reader.get_matched_publications())}, render "
                  f"{len(render_reader.get_matched_publications())}; render: {render_err}; "
                  f"avatar: {avatar_err}", file=sys.stderr, flush=True)
        if sent % 5 == 0:
            bad = Image(
                header=Header(stamp=stamp_now(), frame_id="bad_step"),
                height=args.height, width=args.width, encoding="rgb8", is_bigendian=0,
                step=args.width * 3 - 1, data=person_frame(args.width, args.height, 0),
            )
            writer.write(bad)
        # Pixels first, stamp last: the stamp-to-arrival delay then measures transport.
        pixels = person_frame(args.width, args.height, args.first_frame + sent)
        png = png_rgb8(args.width, args.height, pixels)
        writer.write(Image(
            header=Header(stamp=stamp_now(), frame_id=f"frame_{args.first_frame + sent}"),
            height=args.height, width=args.width, encoding="rgb8", is_bigendian=0,
            step=args.width * 3, data=pixels,
        ))
        compressed_writer.write(CompressedImage(
            header=Header(stamp=stamp_now(), frame_id=f"frame_{args.first_frame + sent}"),
            format="rgb8; png compressed rgb8", data=png,
        ))
        sent += 1
        for msg in render_reader.take(N=10):
            if not isinstance(msg, Image):
                continue
            render_err = check_render(msg, args.render_side)
            render_ok = render_err is None
            if render_ok and first_render_at is None:
                first_render_at = time.monotonic() - start
        for msg in avatar_reader.take(N=4):
            if not isinstance(msg, GaussianAvatar):
                continue
            avatar_err = check_avatar(msg, args.person, args.gaussians)
            if avatar_err is None and (not revisions or msg.revision != revisions[-1]):
                if revisions and msg.revision < revisions[-1]:
                    print(f"RESULT fail avatar revision went back from {revisions[-1]} to "
                          f"{msg.revision}", flush=True)
                    return 1
                revisions.append(msg.revision)
            if avatar_err is None and len(revisions) < args.min_revisions:
                avatar_err = f"revisions so far {revisions}, waiting for {args.min_revisions}"
            elif avatar_err is None and revisions[-1] <= args.above_revision:
                avatar_err = (f"revisions so far {revisions}, waiting for one above "
                              f"{args.above_revision}")
            avatar_ok = avatar_err is None
        if render_ok and avatar_ok:
            break
        time.sleep(0.1)

    if not (render_ok and avatar_ok):
        print(f"RESULT fail render: {render_err}; avatar: {avatar_err} (sent {sent} frames)",
              flush=True)
        return 1
    print(f"RESULT ok frames_sent={sent} render_after_s={first_render_at:.2f} "
          f"avatar_gaussians={args.gaussians} revisions={revisions}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
