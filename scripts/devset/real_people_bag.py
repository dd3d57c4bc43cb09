"""Pose2Sim's Demo_MultiPerson (BSD-3-Clause) as a rosbag2-layout MCAP bag the node replays:
four calibrated cameras, /tf_static with each optical frame in `world`, and per frame and camera
`/<cam>/camera_info` and `/<cam>/image_raw/compressed` (the JPEGs given).

    python real_people_bag.py JPEG_DIR CALIB.qca.txt OUT_BAG_DIR

JPEG_DIR holds jpg1..jpg4 (one folder per camera, the same file names in each, in time order,
`--scale` of the video's size). Needs numpy and rosbags (target/pyenv has both).

The calibration is Qualisys' (`Calib.qca.txt`): per camera a position in millimetres and a
rotation whose rows are the camera's axes in the world (z up, the floor at z = 0), focal lengths
and principal point in 1/64 pixel. The optical frame (+Z forward, +Y down the image) is those
axes turned half a turn about the first (`diag(1, -1, -1)`): with it the room's origin falls
inside all four images with a point 1.7 m above it above it on screen, and a nose seen by two
cameras, triangulated, lands within 9-51 px of the nose the other two see (no lens distortion
modelled); every other axis order puts the origin outside an image or behind a camera. The
node's world has +Y up and the floor at y = 0, so the world is turned a quarter turn about x.
"""

import argparse
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

TS = get_typestore(Stores.ROS2_HUMBLE)
T = TS.types
QUALISYS_TO_OPTICAL = np.diag([1.0, -1.0, -1.0])
Z_UP_TO_Y_UP = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])
START_NS = 1_700_000_000 * 10**9


def quaternion(m):
    """(x, y, z, w) of a rotation matrix."""
    w = np.sqrt(max(0.0, 1 + m[0, 0] + m[1, 1] + m[2, 2])) / 2
    x = np.copysign(np.sqrt(max(0.0, 1 + m[0, 0] - m[1, 1] - m[2, 2])) / 2, m[2, 1] - m[1, 2])
    y = np.copysign(np.sqrt(max(0.0, 1 - m[0, 0] + m[1, 1] - m[2, 2])) / 2, m[0, 2] - m[2, 0])
    z = np.copysign(np.sqrt(max(0.0, 1 - m[0, 0] - m[1, 1] + m[2, 2])) / 2, m[1, 0] - m[0, 1])
    return T["geometry_msgs/msg/Quaternion"](x=float(x), y=float(y), z=float(z), w=float(w))


def cameras(calib, scale):
    """Per camera: name, (fx, fy, cx, cy) at `scale`, world-from-optical rotation, position."""
    out = []
    for i, cam in enumerate(ET.parse(calib).getroot().findall("cameras/camera")):
        t, k = cam.find("transform").attrib, cam.find("intrinsic").attrib
        rows = np.array([[float(t[f"r{a}{b}"]) for b in (1, 2, 3)] for a in (1, 2, 3)])
        position = np.array([float(t["x"]), float(t["y"]), float(t["z"])]) / 1000
        intrinsics = tuple(float(k[key]) / 64 * scale
                           for key in ("focalLengthU", "focalLengthV", "centerPointU", "centerPointV"))
        rotation = Z_UP_TO_Y_UP @ (QUALISYS_TO_OPTICAL @ rows).T
        out.append((f"cam{i}", intrinsics, rotation, Z_UP_TO_Y_UP @ position))
    return out


def stamp(ns):
    return T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("jpegs", type=Path)
    ap.add_argument("calib")
    ap.add_argument("out", type=Path)
    ap.add_argument("--scale", type=float, default=0.5)
    ap.add_argument("--fps", type=float, default=30.0)
    ap.add_argument("--size", default="544x960", help="the JPEGs' WIDTHxHEIGHT")
    a = ap.parse_args()
    width, height = (int(v) for v in a.size.split("x"))
    rig = cameras(a.calib, a.scale)
    header = T["std_msgs/msg/Header"]
    period = int(1e9 / a.fps)
    with Writer(a.out, version=8, storage_plugin=StoragePlugin.MCAP) as w:
        tf = w.add_connection("/tf_static", "tf2_msgs/msg/TFMessage", typestore=TS)
        topics = {name: (w.add_connection(f"/{name}/camera_info", "sensor_msgs/msg/CameraInfo", typestore=TS),
                         w.add_connection(f"/{name}/image_raw/compressed", "sensor_msgs/msg/CompressedImage",
                                          typestore=TS))
                  for name, *_ in rig}
        transforms = [T["geometry_msgs/msg/TransformStamped"](
            header=header(stamp=stamp(START_NS), frame_id="world"), child_frame_id=f"{name}_optical_frame",
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=float(p[0]), y=float(p[1]), z=float(p[2])),
                rotation=quaternion(r)))
            for name, _, r, p in rig]
        w.write(tf, START_NS, TS.serialize_cdr(T["tf2_msgs/msg/TFMessage"](transforms=transforms),
                                               "tf2_msgs/msg/TFMessage"))
        frames = sorted((a.jpegs / "jpg1").glob("*.jpg"))
        for f, frame in enumerate(frames):
            for c, (name, (fx, fy, cx, cy), _, _) in enumerate(rig):
                t = START_NS + period * (f + 1) + 1_000_000 * c  # triggered together, 1 ms apart
                h = header(stamp=stamp(t), frame_id=f"{name}_optical_frame")
                info = T["sensor_msgs/msg/CameraInfo"](
                    header=h, height=height, width=width, distortion_model="plumb_bob", d=np.zeros(5),
                    k=np.array([fx, 0, cx, 0, fy, cy, 0, 0, 1.0]), r=np.eye(3).flatten(),
                    p=np.array([fx, 0, cx, 0, 0, fy, cy, 0, 0, 0, 1.0, 0]), binning_x=0, binning_y=0,
                    roi=T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0,
                                                              do_rectify=False))
                w.write(topics[name][0], t, TS.serialize_cdr(info, "sensor_msgs/msg/CameraInfo"))
                jpeg = (a.jpegs / f"jpg{c + 1}" / frame.name).read_bytes()
                image = T["sensor_msgs/msg/CompressedImage"](header=h, format="jpeg",
                                                             data=np.frombuffer(jpeg, dtype=np.uint8))
                w.write(topics[name][1], t, TS.serialize_cdr(image, "sensor_msgs/msg/CompressedImage"))
    print(f"wrote {a.out}: {len(frames)} frames x {len(rig)} cameras")


if __name__ == "__main__":
    main()
