#!/usr/bin/env python3
"""Independent check of a bag written by lhmpp's BagWriter.

Usage: check_bag.py BAG_DIR EXPECTED_JSON

BAG_DIR is a rosbag2 bag directory (metadata.yaml and one .mcap file).

Opens BAG with two readers that share no code with lhmpp: the `mcap` + `mcap_ros2`
packages (DecoderFactory: decodes CDR from the ros2msg schemas stored in the bag) and
`rosbags.highlevel.AnyReader` (its own CDR decoder; message types registered from the same
stored definitions). Every message is decoded by both; the field values listed in
EXPECTED_JSON ({topic: {"type": ..., "count": n, "fields": {"dotted.path": value}}}) are
checked on the first message of each topic. Prints one line per check and exits non-zero on
the first mismatch.
"""

import json
import math
import sys
from pathlib import Path


def get_path(msg, dotted):
    value = msg
    for part in dotted.split("."):
        if part.isdigit():
            value = value[int(part)]
        else:
            value = getattr(value, part)
    return value


def same(actual, expected):
    if isinstance(expected, float):
        return math.isclose(float(actual), expected, rel_tol=1e-6, abs_tol=1e-9)
    if isinstance(expected, list):
        actual = list(actual)
        return len(actual) == len(expected) and all(same(a, e) for a, e in zip(actual, expected))
    if isinstance(expected, bool):
        return bool(actual) == expected
    return actual == expected


def check_fields(reader_name, topic, msg, fields):
    for dotted, expected in fields.items():
        actual = get_path(msg, dotted)
        if hasattr(actual, "tolist"):
            actual = actual.tolist()
        if isinstance(actual, (bytes, bytearray, memoryview)):
            actual = list(bytes(actual))
        if not same(actual, expected):
            sys.exit(f"{reader_name}: {topic}.{dotted} = {actual!r}, expected {expected!r}")


def check_mcap_ros2(bag, expected):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    counts = {}
    with open(bag, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        header = reader.get_header()
        if header.profile != "ros2":
            sys.exit(f"mcap: profile {header.profile!r}, expected 'ros2'")
        for schema, channel, message, decoded in reader.iter_decoded_messages():
            topic = channel.topic
            if schema.encoding != "ros2msg" or channel.message_encoding != "cdr":
                sys.exit(f"mcap: {topic}: encodings {schema.encoding}/{channel.message_encoding}")
            if "offered_qos_profiles" not in channel.metadata:
                sys.exit(f"mcap: {topic}: no offered_qos_profiles metadata")
            want = expected.get(topic)
            if want is None:
                sys.exit(f"mcap: unexpected topic {topic}")
            if schema.name != want["type"]:
                sys.exit(f"mcap: {topic}: schema {schema.name}, expected {want['type']}")
            if counts.get(topic, 0) == 0:
                check_fields("mcap_ros2", topic, decoded, want["fields"])
            counts[topic] = counts.get(topic, 0) + 1
        summary = reader.get_summary()
        compressions = {c.compression for c in summary.chunk_indexes}
        metadata = {m.name for m in reader.iter_metadata()}
    for topic, want in expected.items():
        if counts.get(topic, 0) != want["count"]:
            sys.exit(f"mcap: {topic}: {counts.get(topic, 0)} messages, expected {want['count']}")
    if "rosbag2" not in metadata:
        sys.exit("mcap: no rosbag2 metadata record")
    print(f"mcap_ros2: decoded {sum(counts.values())} messages on {len(counts)} topics, "
          f"chunk compression {sorted(compressions)}, metadata records {sorted(metadata)}")


def check_rosbags(bag, expected):
    from rosbags.highlevel import AnyReader

    counts = {}
    with AnyReader([Path(bag)]) as reader:
        for connection, _timestamp, rawdata in reader.messages():
            topic = connection.topic
            msg = reader.deserialize(rawdata, connection.msgtype)
            want = expected[topic]
            if connection.msgtype != want["type"]:
                sys.exit(f"rosbags: {topic}: type {connection.msgtype}, expected {want['type']}")
            if counts.get(topic, 0) == 0:
                check_fields("rosbags", topic, msg, want["fields"])
            counts[topic] = counts.get(topic, 0) + 1
    for topic, want in expected.items():
        if counts.get(topic, 0) != want["count"]:
            sys.exit(f"rosbags: {topic}: {counts.get(topic, 0)} messages, expected {want['count']}")
    print(f"rosbags AnyReader: decoded {sum(counts.values())} messages on {len(counts)} topics")


def main():
    bag_dir, expected_path = Path(sys.argv[1]), sys.argv[2]
    expected = json.loads(Path(expected_path).read_text())
    mcap_files = sorted(bag_dir.glob("*.mcap"))
    if len(mcap_files) != 1:
        sys.exit(f"{bag_dir}: expected one .mcap file, found {mcap_files}")
    check_mcap_ros2(mcap_files[0], expected)
    check_rosbags(bag_dir, expected)
    print("OK")


if __name__ == "__main__":
    main()
