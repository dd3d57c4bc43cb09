#!/usr/bin/env python3
"""Writes a copy of an MCAP bag with one chunk damaged, for the reliability checks.

Usage: target/pyenv/bin/python scripts/damage-bag.py IN OUT [--chunk N]
           [--kind crc|compression|data|length] [--cut-summary]

Chunks are found with the `mcap` package's summary reader (installed in target/pyenv by
scripts/setup-test-deps). --chunk: index of the chunk in file order (default: the middle one).
--kind: crc flips a byte of the chunk's uncompressed CRC, compression renames its compression,
data overwrites 24 bytes in its middle, length makes its record length larger than the file.
--cut-summary: also cut the file at its data end (no summary, no footer), as a recorder killed
while closing leaves it. Prints the damaged chunk's byte range and the file size written.
"""

import argparse
import struct
import sys
from pathlib import Path

from mcap.reader import make_reader


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("input", type=Path)
    ap.add_argument("output", type=Path)
    ap.add_argument("--chunk", type=int)
    ap.add_argument("--kind", choices=["crc", "compression", "data", "length"], default="crc")
    ap.add_argument("--cut-summary", action="store_true")
    args = ap.parse_args()
    if args.input.resolve() == args.output.resolve():
        sys.exit("damage-bag: OUT must not be IN")
    data = bytearray(args.input.read_bytes())
    with open(args.input, "rb") as f:
        summary = make_reader(f).get_summary()
    chunks = sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset)
    if not chunks:
        sys.exit(f"damage-bag: {args.input} has no chunk index")
    n = len(chunks) // 2 if args.chunk is None else args.chunk
    chunk = chunks[n]
    start, length = chunk.chunk_start_offset, chunk.chunk_length
    body = start + 9  # opcode and record length
    if args.kind == "crc":
        data[body + 24] ^= 0x5A  # after start time, end time and uncompressed size
    elif args.kind == "compression":
        name_len = struct.unpack_from("<I", data, body + 28)[0]
        data[body + 32 + name_len - 1] ^= 0x20
    elif args.kind == "data":
        middle = start + length // 2
        data[middle : middle + 24] = b"\xaa" * 24
    else:
        struct.pack_into("<Q", data, start + 1, len(data) * 2)
    if args.cut_summary:
        # The footer's summary start; the data end record (13 bytes) is just before it.
        summary_start = struct.unpack_from("<Q", data, len(data) - 8 - 20)[0]
        data = data[: summary_start - 13]
    args.output.write_bytes(data)
    print(f"damaged chunk {n} of {len(chunks)} ({args.kind}): bytes {start}..{start + length}, "
          f"{chunk.message_end_time - chunk.message_start_time} ns of messages; "
          f"wrote {len(data)} bytes to {args.output}")


if __name__ == "__main__":
    main()
