"""The .tlog format (QGroundControl, MAVProxy): records of an 8-byte big-endian Unix time
in microseconds followed by one raw MAVLink packet.

A log cut off by a power loss ends in a partial record; `read_tlog` reports it through
`TlogReader.truncated` instead of failing, and everything before it still plays.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from companion.mav_framer import MAGIC_V1, MAGIC_V2

_TIME = struct.Struct(">Q")


def encode_record(t_wall_s: float, packet: bytes) -> bytes:
    return _TIME.pack(int(t_wall_s * 1e6)) + packet


def write_record(f: BinaryIO, t_wall_s: float, packet: bytes) -> None:
    f.write(encode_record(t_wall_s, packet))


def _packet_length(head: bytes) -> int | None:
    """Packet length from its first three bytes, None if they do not start a packet."""
    if head[0] == MAGIC_V1:
        return head[1] + 8
    if head[0] == MAGIC_V2:
        return head[1] + 12 + (13 if head[2] & 0x01 else 0)
    return None


@dataclass
class TlogReader:
    """Iterate `(t_wall_s, packet)` records; counts a truncated tail and junk bytes."""

    path: Path
    truncated: int = 0
    skipped_bytes: int = 0

    def __iter__(self) -> Iterator[tuple[float, bytes]]:
        with open(self.path, "rb") as f:
            while True:
                head = f.read(_TIME.size + 3)
                if not head:
                    return
                if len(head) < _TIME.size + 3:
                    self.truncated += 1
                    return
                length = _packet_length(head[_TIME.size :])
                if length is None:
                    # Not a record boundary (a corrupted log): step one byte and look again.
                    self.skipped_bytes += 1
                    f.seek(-(len(head) - 1), 1)
                    continue
                rest = f.read(length - 3)
                if len(rest) < length - 3:
                    self.truncated += 1
                    return
                (t_us,) = _TIME.unpack(head[: _TIME.size])
                yield t_us / 1e6, head[_TIME.size :] + rest
