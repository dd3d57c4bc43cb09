"""A folder of one camera's JPEG frames (in name order) as a rosbag2-layout MCAP bag the node
replays: `/cam0/image_raw/compressed` at `--fps`, stamped from 1.7e9 s. No calibration.

    python video_bag.py JPEG_DIR OUT_BAG_DIR [--fps 30] [--frames N]

Needs numpy and rosbags (target/pyenv has both).
"""

import argparse
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
START_NS = 1_700_000_000 * 10**9


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("jpegs", type=Path)
    ap.add_argument("out", type=Path)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--frames", type=int, default=0, help="only the first N frames (0: all)")
    a = ap.parse_args()
    period = int(1e9 / a.fps)
    frames = sorted(a.jpegs.glob("*.jpg"))
    if a.frames > 0:
        frames = frames[: a.frames]
    with Writer(a.out, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        topic = w.add_connection("/cam0/image_raw/compressed", "sensor_msgs/msg/CompressedImage",
                                 typestore=TS)
        for f, frame in enumerate(frames):
            t = START_NS + period * (f + 1)
            h = T["std_msgs/msg/Header"](
                stamp=T["builtin_interfaces/msg/Time"](sec=t // 10**9, nanosec=t % 10**9),
                frame_id="cam0_optical_frame")
            image = T["sensor_msgs/msg/CompressedImage"](
                header=h, format="jpeg", data=np.frombuffer(frame.read_bytes(), dtype=np.uint8))
            w.write(topic, t, TS.serialize_cdr(image, "sensor_msgs/msg/CompressedImage"))
    print(f"wrote {a.out}: {len(frames)} frames at {a.fps} fps")


if __name__ == "__main__":
    main()
