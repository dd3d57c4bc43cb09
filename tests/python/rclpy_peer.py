"""Real ROS 2 peer for tests/node_rclpy.rs: rclpy on Fast DDS (rmw_fastrtps_cpp, the ROS 2
default), with the lhmpp_msgs Python types that colcon generated from msg/ (scripts/build-msgs).

It plays cameras, a pose source and the consumers at once:
  * publishes sensor_msgs/Image (rgb8) on --image-topic and the same frames PNG-compressed as
    sensor_msgs/CompressedImage on --compressed-topic (reliable, as the issue's camera node),
    and lhmpp_msgs/BodyPose on --pose-topic;
  * subscribes to the rendered frames (--render-topic) twice, RELIABLE and BEST_EFFORT, to
    lhmpp_msgs/GaussianAvatar (--avatar-topic) and lhmpp_msgs/ReconstructionStatus
    (--status-topic), both RELIABLE + TRANSIENT_LOCAL.

Phases: feed cameras (pose A) until --min-revisions avatar revisions arrived and both frame
subscriptions got frames; stop the cameras and wait for the avatar to settle; hold pose A, then
pose B (root moved and turned), each for a while. Checks: revisions increase, Gaussians are
finite and as many as --gaussians, status is for the person, frames are rgb8 of the right size,
frames under one pose agree, and the last frames under A and B differ.

Prints one line `RESULT ok ...` or `RESULT fail <reason>` and exits (0 on ok), at the latest
after --timeout seconds.
"""

import argparse
import math
import struct
import sys
import time
import zlib

import numpy as np
import rclpy
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy)

from lhmpp_msgs.msg import BodyPose, GaussianAvatar, ReconstructionStatus
from sensor_msgs.msg import CompressedImage, Image, PointCloud2


def png_rgb8(width, height, rgb):
    """A minimal PNG (8-bit RGB, no filter) of `rgb` bytes, written with zlib only."""
    def chunk(kind, body):
        return (struct.pack(">I", len(body)) + kind + body
                + struct.pack(">I", zlib.crc32(kind + body) & 0xFFFFFFFF))
    rows = b"".join(b"\x00" + rgb[y * width * 3:(y + 1) * width * 3] for y in range(height))
    return (b"\x89PNG\r\n\x1a\n"
            + chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(rows)) + chunk(b"IEND", b""))


def person_frame(width, height, index):
    """rgb8 bytes of a synthetic person: grey background, a red-to-blue torso box, index-tinted."""
    img = np.full((height, width, 3), 90, dtype=np.uint8)
    x0, x1 = width * 3 // 8, width * 5 // 8
    y0, y1 = height // 8, height * 7 // 8
    t = np.linspace(0.0, 1.0, y1 - y0)[:, None]
    img[y0:y1, x0:x1, 0] = (255 * (1 - t)).astype(np.uint8)
    img[y0:y1, x0:x1, 1] = index % 256
    img[y0:y1, x0:x1, 2] = (255 * t).astype(np.uint8)
    return img.tobytes()


def gaussian_columns(avatar):
    """Float32 fields of the avatar's PointCloud2 by name (uint16 bone fields skipped)."""
    g = avatar.gaussians
    raw = np.frombuffer(bytes(g.data), dtype=np.uint8).reshape(g.width * g.height, g.point_step)
    cols = {}
    for f in g.fields:
        if f.datatype == 7:  # FLOAT32
            cols[f.name] = raw[:, f.offset:f.offset + 4].copy().view("<f4").reshape(-1)
    return cols


def check_avatar(avatar, person, gaussians):
    if avatar.person_id != person:
        return f"avatar person_id {avatar.person_id!r}"
    g = avatar.gaussians
    if g.width * g.height != gaussians:
        return f"{g.width * g.height} Gaussians, expected {gaussians}"
    if len(g.data) != g.row_step * g.height:
        return f"gaussians data {len(g.data)} bytes, row_step {g.row_step}"
    cols = gaussian_columns(avatar)
    for name in ("x", "y", "z", "opacity", "scale_0", "rot_0", "weight_0"):
        if name not in cols:
            return f"no float field {name} in {[f.name for f in g.fields]}"
    values = np.stack(list(cols.values()))
    if not np.all(np.isfinite(values)):
        return "non-finite Gaussian values"
    if len(avatar.bone_names) == 0 or len(avatar.bone_parents) != len(avatar.bone_names):
        return "no skeleton"
    return None


def check_preview(msg, gaussians, frame):
    """The preview cloud as RViz2's RGB8 transformer reads it: x y z float32 + packed rgb."""
    if msg.header.frame_id != frame:
        return f"preview frame_id {msg.header.frame_id!r}, expected {frame!r}"
    fields = {f.name: (f.offset, f.datatype, f.count) for f in msg.fields}
    for name in ("x", "y", "z", "rgb"):
        if name not in fields or fields[name][1] != 7 or fields[name][2] != 1:
            return f"preview field {name}: {fields.get(name)}"
    if msg.width * msg.height != gaussians or len(msg.data) != msg.row_step * msg.height:
        return f"preview {msg.width}x{msg.height} points, {len(msg.data)} bytes"
    raw = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(-1, msg.point_step)
    col = lambda n: raw[:, fields[n][0]:fields[n][0] + 4].copy().view("<f4").reshape(-1)
    xyz = np.stack([col("x"), col("y"), col("z")])
    if not np.all(np.isfinite(xyz)):
        return "preview points not finite"
    packed = raw[:, fields["rgb"][0]:fields["rgb"][0] + 4].copy().view("<u4").reshape(-1)
    if np.any(packed >> 24) or not np.any(packed):
        return "preview rgb is not packed 0x00RRGGBB"
    return None


def frame_array(msg, side):
    if msg.encoding != "rgb8" or msg.width != side or msg.height != side or msg.step != 3 * side:
        return None, f"frame {msg.width}x{msg.height} {msg.encoding} step {msg.step}"
    data = np.frombuffer(bytes(msg.data), dtype=np.uint8)
    if data.size != side * side * 3:
        return None, f"frame data {data.size} bytes"
    return data.reshape(side, side, 3).astype(np.float32), None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--image-topic", required=True)
    ap.add_argument("--compressed-topic", required=True)
    ap.add_argument("--pose-topic", required=True)
    ap.add_argument("--avatar-topic", required=True)
    ap.add_argument("--status-topic", required=True)
    ap.add_argument("--render-topic", required=True)
    ap.add_argument("--preview-topic", required=True)
    ap.add_argument("--preview-frame", default="lhmpp_avatar")
    ap.add_argument("--width", type=int, default=64)
    ap.add_argument("--height", type=int, default=96)
    ap.add_argument("--render-side", type=int, default=64)
    ap.add_argument("--gaussians", type=int, default=1024)
    ap.add_argument("--person", default="person_0")
    ap.add_argument("--min-revisions", type=int, default=2)
    ap.add_argument("--hold", type=float, default=2.0, help="seconds each pose is held")
    ap.add_argument("--timeout", type=float, default=120.0)
    args = ap.parse_args()

    rclpy.init()
    node = rclpy.create_node("lhmpp_rclpy_peer")
    reliable = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                          durability=DurabilityPolicy.VOLATILE, history=HistoryPolicy.KEEP_LAST)
    best_effort = QoSProfile(depth=10, reliability=ReliabilityPolicy.BEST_EFFORT,
                             durability=DurabilityPolicy.VOLATILE,
                             history=HistoryPolicy.KEEP_LAST)
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         history=HistoryPolicy.KEEP_LAST)
    image_pub = node.create_publisher(Image, args.image_topic, reliable)
    compressed_pub = node.create_publisher(CompressedImage, args.compressed_topic, reliable)
    pose_pub = node.create_publisher(BodyPose, args.pose_topic, reliable)

    state = {"frames": {"reliable": [], "best_effort": []}, "bad": None, "revisions": [],
             "avatar": None, "status": None, "pose": "A", "last_revision_at": None}

    def on_frame(kind):
        def cb(msg):
            arr, err = frame_array(msg, args.render_side)
            if err is not None:
                state["bad"] = state["bad"] or f"{kind} {err}"
                return
            state["frames"][kind].append((time.monotonic(), state["pose"], arr))
        return cb

    def on_avatar(msg):
        err = check_avatar(msg, args.person, args.gaussians)
        if err is not None:
            state["bad"] = state["bad"] or err
            return
        revs = state["revisions"]
        if revs and msg.revision <= revs[-1]:
            if msg.revision < revs[-1]:
                state["bad"] = state["bad"] or f"revision went back {revs[-1]} -> {msg.revision}"
            return
        revs.append(msg.revision)
        state["avatar"] = msg
        state["last_revision_at"] = time.monotonic()

    def on_status(msg):
        state["status"] = msg

    state["previews"] = []

    def on_preview(msg):
        err = check_preview(msg, args.gaussians, args.preview_frame)
        if err is not None:
            state["bad"] = state["bad"] or err
            return
        raw = np.frombuffer(bytes(msg.data), dtype=np.uint8).reshape(-1, msg.point_step)
        state["previews"].append((state["pose"], raw[:, :12].copy().view("<f4").reshape(-1, 3)))

    node.create_subscription(Image, args.render_topic, on_frame("reliable"), reliable)
    node.create_subscription(Image, args.render_topic, on_frame("best_effort"), best_effort)
    node.create_subscription(GaussianAvatar, args.avatar_topic, on_avatar, latched)
    node.create_subscription(ReconstructionStatus, args.status_topic, on_status, latched)
    # RViz2's PointCloud2 display default: reliable, volatile.
    node.create_subscription(PointCloud2, args.preview_topic, on_preview, reliable)

    def pose_msg(which):
        msg = BodyPose()
        msg.header.frame_id = "world"
        msg.person_id = args.person
        angle = 0.0 if which == "A" else math.pi / 2
        msg.root.rotation.w = math.cos(angle / 2)
        msg.root.rotation.y = math.sin(angle / 2)
        msg.root.translation.x = 0.0 if which == "A" else 0.25
        return msg

    def spin_for(seconds):
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            rclpy.spin_once(node, timeout_sec=0.02)

    def fail(reason):
        print(f"RESULT fail {reason}; sent raw={sent} compressed={sent} poses={poses}; "
              f"frames reliable={len(state['frames']['reliable'])} "
              f"best_effort={len(state['frames']['best_effort'])}; "
              f"revisions={state['revisions']}", flush=True)
        return 1

    start = time.monotonic()
    deadline = start + args.timeout
    sent = poses = 0
    # Phase 1: cameras and pose A until enough revisions and frames on both subscriptions.
    while True:
        if time.monotonic() > deadline:
            return fail("timed out feeding cameras")
        if state["bad"]:
            return fail(state["bad"])
        pixels = person_frame(args.width, args.height, sent)
        stamp = node.get_clock().now().to_msg()
        img = Image()
        img.header.stamp = stamp
        img.header.frame_id = f"frame_{sent}"
        img.height, img.width, img.encoding, img.step = args.height, args.width, "rgb8", args.width * 3
        img.data = pixels
        image_pub.publish(img)
        comp = CompressedImage()
        comp.header.stamp = stamp
        comp.header.frame_id = f"frame_{sent}"
        comp.format = "rgb8; png compressed rgb8"
        comp.data = png_rgb8(args.width, args.height, pixels)
        compressed_pub.publish(comp)
        sent += 1
        pose_pub.publish(pose_msg("A"))
        poses += 1
        spin_for(0.1)
        f = state["frames"]
        if (len(state["revisions"]) >= args.min_revisions and f["reliable"] and f["best_effort"]
                and state["status"] is not None):
            break
    feed_s = time.monotonic() - start
    # Phase 2: no more views; wait until no new revision for 1.5 s.
    while time.monotonic() - state["last_revision_at"] < 1.5:
        if time.monotonic() > deadline:
            return fail("avatar did not settle")
        pose_pub.publish(pose_msg("A"))
        poses += 1
        spin_for(0.1)
    # Phases 3 and 4: hold pose A, then pose B.
    held = {}
    for which in ("A", "B"):
        state["pose"] = which
        begin = time.monotonic()
        while time.monotonic() - begin < args.hold:
            pose_pub.publish(pose_msg(which))
            poses += 1
            spin_for(0.1)
        # Frames of the second half of the hold: the pose has surely reached the node.
        held[which] = [a for (t, p, a) in state["frames"]["reliable"]
                       if p == which and t > begin + args.hold / 2]
    if state["bad"]:
        return fail(state["bad"])
    if len(held["A"]) < 2 or len(held["B"]) < 1:
        return fail(f"frames under pose A {len(held['A'])}, pose B {len(held['B'])}")
    within_a = float(np.abs(held["A"][0] - held["A"][-1]).mean())
    a_vs_b = float(np.abs(held["A"][-1] - held["B"][-1]).mean())
    if within_a > 0.5:
        return fail(f"frames under one pose differ: mean |diff| {within_a:.3f}")
    if a_vs_b < 1.0:
        return fail(f"frames do not change with the pose: mean |diff| {a_vs_b:.3f}")
    pre_a = [p for (w, p) in state["previews"] if w == "A"]
    pre_b = [p for (w, p) in state["previews"] if w == "B"]
    if not pre_a or not pre_b:
        return fail(f"preview clouds under pose A {len(pre_a)}, pose B {len(pre_b)}")
    preview_shift = float(np.abs(pre_a[-1].mean(axis=0) - pre_b[-1].mean(axis=0)).max())
    if preview_shift < 0.05:
        return fail(f"preview does not follow the pose: centroid moved {preview_shift:.3f} m")
    status = state["status"]
    if status.person_id != args.person or status.revision < 1:
        return fail(f"status person {status.person_id!r} revision {status.revision}")
    revs = state["revisions"]
    print(f"RESULT ok sent raw={sent} compressed={sent} poses={poses}; "
          f"frames received reliable={len(state['frames']['reliable'])} "
          f"best_effort={len(state['frames']['best_effort'])}; revisions={revs}; "
          f"avatar gaussians={args.gaussians} finite; status revision={status.revision} "
          f"state={status.state} last_render_ms={status.last_render_ms:.1f}; "
          f"frame |diff| pose A/A={within_a:.3f} A/B={a_vs_b:.2f}; "
          f"preview clouds={len(state['previews'])} centroid shift A/B={preview_shift:.2f} m; "
          f"fed in {feed_s:.1f} s, total {time.monotonic() - start:.1f} s", flush=True)
    node.destroy_node()
    rclpy.shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
