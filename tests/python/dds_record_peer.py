"""DDS publisher for tests/record_*.rs, built on the PyPI `cyclonedds` package.

Waits until a reader (the `lhmpp record` process) matches both topics, then publishes
sensor_msgs/Image frames on --image-topic (reliable, keep all) and one lhmpp_msgs/BodyPose on
--pose-topic. Frame i is --width x --height mono8 with frame_id `frame_<i>` and pixel j equal
to (7 * i + j) % 256. With --count N it sends N frames, waits for their acknowledgement and
prints `SENT N`; with --count 0 it streams frames every --period seconds until --timeout,
printing `SENT <frames so far>` after each. Prints `FAIL <reason>` and exits 1 on a timeout.
ROS topic names map to DDS as `rt/<name without leading slash>`.
"""

import argparse
import sys
import time

from cyclonedds.core import Policy, Qos
from cyclonedds.domain import DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.topic import Topic
from cyclonedds.util import duration


from ros_idl import Time, Header, Image, Vector3, Quaternion, Transform, BodyPose


def frame(i, width, height):
    data = bytes((7 * i + j) % 256 for j in range(width * height))
    return Image(header=Header(stamp=Time(sec=1_700_000_000 + i, nanosec=0), frame_id=f"frame_{i}"),
                 height=height, width=width, encoding="mono8", is_bigendian=0, step=width,
                 data=data)


def pose():
    return BodyPose(
        header=Header(stamp=Time(sec=1_700_000_000, nanosec=500), frame_id="world"),
        person_id="person_0",
        bone_names=["spine", "head"],
        rotations=[Quaternion(0.0, 0.0, 0.0, 1.0), Quaternion(0.0, 0.6, 0.0, 0.8)],
        root=Transform(translation=Vector3(0.5, 0.0, -1.25), rotation=Quaternion(0.0, 0.0, 0.0, 1.0)),
    )


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--domain", type=int, required=True)
    ap.add_argument("--image-topic", required=True)
    ap.add_argument("--pose-topic", required=True)
    ap.add_argument("--count", type=int, default=10)
    ap.add_argument("--width", type=int, default=32)
    ap.add_argument("--height", type=int, default=24)
    ap.add_argument("--period", type=float, default=0.02)
    ap.add_argument("--timeout", type=float, default=30.0)
    args = ap.parse_args()

    deadline = time.monotonic() + args.timeout
    dp = DomainParticipant(args.domain)
    dds = lambda name: "rt/" + name.lstrip("/")
    qos = Qos(Policy.Reliability.Reliable(duration(seconds=1)), Policy.History.KeepAll)
    images = DataWriter(dp, Topic(dp, dds(args.image_topic), Image), qos=qos)
    poses = DataWriter(dp, Topic(dp, dds(args.pose_topic), BodyPose), qos=qos)
    while not (images.get_matched_subscriptions() and poses.get_matched_subscriptions()):
        if time.monotonic() > deadline:
            print("FAIL no reader matched", flush=True)
            return 1
        time.sleep(0.05)
    time.sleep(0.3)  # let the reader finish matching our writers too

    poses.write(pose())
    i = 0
    while args.count == 0 or i < args.count:
        if time.monotonic() > deadline:
            if args.count == 0:
                return 0
            print(f"FAIL timeout after {i} frames", flush=True)
            return 1
        images.write(frame(i, args.width, args.height))
        i += 1
        if args.count == 0:
            print(f"SENT {i}", flush=True)
        time.sleep(args.period)
    images.wait_for_acks(duration(seconds=10))
    poses.wait_for_acks(duration(seconds=10))
    print(f"SENT {i}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
