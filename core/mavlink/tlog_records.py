"""The .tlog format (QGroundControl, MAVProxy, our recorder): records of an 8-byte
big-endian Unix time in microseconds followed by one raw MAVLink packet.

A record's length is its packet's, read from the packet header by `framing.frame_length`
(MAVLink 1 and 2 mixed, signed packets). A log cut off by a power loss ends in a partial
record; `TlogReader` counts it in `truncated` instead of failing, and everything before
it still plays. Bytes that do not start a record (a corrupted log) are stepped over one
at a time and counted in `skipped_bytes`. Checksums are left to the decoder.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from core.mavlink.framing import frame_length

_TIME = struct.Struct(">Q")
_HEAD = 3  # packet bytes needed to know its length (v2: marker, length, incompat flags)


def encode_record(t_wall_s: float, packet: bytes) -> bytes:
    return _TIME.pack(int(t_wall_s * 1e6)) + packet


def write_record(f: BinaryIO, t_wall_s: float, packet: bytes) -> None:
    f.write(encode_record(t_wall_s, packet))


@dataclass
class TlogReader:
    """Iterate `(t_wall_s, packet)` records; counts a truncated tail and junk bytes."""

    path: Path
    truncated: int = 0
    skipped_bytes: int = 0

    def __iter__(self) -> Iterator[tuple[float, bytes]]:
        with open(self.path, "rb") as f:
            while True:
                head = f.read(_TIME.size + _HEAD)
                if not head:
                    return
                if len(head) < _TIME.size + _HEAD:
                    self.truncated += 1
                    return
                length = frame_length(head[_TIME.size :])
                if length is None or length < 0:
                    # Not a record boundary (a corrupted log): step one byte and look again.
                    self.skipped_bytes += 1
                    f.seek(-(len(head) - 1), 1)
                    continue
                rest = f.read(length - _HEAD)
                if len(rest) < length - _HEAD:
                    self.truncated += 1
                    return
                (t_us,) = _TIME.unpack(head[: _TIME.size])
                yield t_us / 1e6, head[_TIME.size :] + rest
