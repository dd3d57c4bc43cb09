"""rclpy peer (Fast DDS, the ROS 2 default) of tests/node_rclpy_compact.rs: subscribes to
lhmpp_msgs/CompactAvatar (--compact-topic) and lhmpp_msgs/GaussianAvatar (--full-topic), both
RELIABLE + TRANSIENT_LOCAL with the host's own net.core.rmem_max, and decodes the compact
avatar's blobs as msg/msg/CompactAvatar.msg describes them (gzip, LHCA and LHSK headers, one
skin row per Gaussian, bone indices within the skeleton).

Prints `RESULT ok ...` (the compact avatar's size, its Gaussians, whether the full avatar came
too) or `RESULT fail <reason>` and exits, at the latest after --timeout seconds.
"""

import argparse
import gzip
import struct
import time

import rclpy
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from lhmpp_msgs.msg import CompactAvatar, GaussianAvatar


def check(msg, person, gaussians):
    if msg.person_id != person or msg.revision < 1:
        return f"person {msg.person_id!r} revision {msg.revision}"
    raw = gzip.decompress(bytes(msg.gaussians))
    magic, version, fb, rot_bits, sh, n = struct.unpack_from("<4sBBBBI", raw)
    if magic != b"LHCA" or version != 1 or n != gaussians:
        return f"Gaussians blob {magic!r} v{version} with {n} Gaussians"
    if len(raw) != 12 + 20 * n:
        return f"Gaussians blob of {len(raw)} bytes for {n}"
    skin = gzip.decompress(bytes(msg.skin))
    magic, version, index_bytes, levels, _, m = struct.unpack_from("<4sBBBBI", skin)
    if magic != b"LHSK" or m != n or index_bytes != 1:
        return f"skin blob {magic!r} with {m} rows, {index_bytes}-byte indices"
    bones = skin[12:12 + 4 * n]
    if max(bones) >= len(msg.bone_names) or len(msg.bone_rest_positions) != 3 * len(msg.bone_names):
        return "skin bones outside the skeleton"
    return None


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--compact-topic", required=True)
    ap.add_argument("--full-topic", required=True)
    ap.add_argument("--person", default="person_0")
    ap.add_argument("--gaussians", type=int, required=True)
    ap.add_argument("--full-wait", type=float, default=10.0,
                    help="seconds the full avatar may take after the compact one")
    ap.add_argument("--timeout", type=float, default=120.0)
    args = ap.parse_args()

    rclpy.init()
    node = rclpy.create_node("lhmpp_compact_peer")
    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL,
                         history=HistoryPolicy.KEEP_LAST)
    state = {"compact": None, "compact_at": None, "full": None, "bad": None}

    def on_compact(msg):
        state["bad"] = state["bad"] or check(msg, args.person, args.gaussians)
        state["compact"] = msg
        state["compact_at"] = time.monotonic()

    def on_full(msg):
        state["full"] = (msg.gaussians.width, len(msg.gaussians.data))

    node.create_subscription(CompactAvatar, args.compact_topic, on_compact, latched)
    node.create_subscription(GaussianAvatar, args.full_topic, on_full, latched)
    rmem = open("/proc/sys/net/core/rmem_max").read().strip()
    deadline = time.monotonic() + args.timeout
    result = "RESULT fail no compact avatar before the timeout"
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
        if state["bad"]:
            result = f"RESULT fail {state['bad']}"
            break
        at = state["compact_at"]
        if at is not None and (state["full"] is not None or time.monotonic() - at > args.full_wait):
            msg = state["compact"]
            size = len(msg.gaussians) + len(msg.skin)
            full = ("received" if state["full"] else
                    f"not received within {args.full_wait:.0f} s of it")
            result = (f"RESULT ok compact avatar revision {msg.revision}: {args.gaussians} "
                      f"Gaussians in {size} blob bytes (Gaussians {len(msg.gaussians)}, skin "
                      f"{len(msg.skin)}), net.core.rmem_max {rmem}; the full GaussianAvatar "
                      f"{full}")
            break
    print(result, flush=True)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
