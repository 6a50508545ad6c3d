"""The .tlog format (QGroundControl, MAVProxy, our recorder): records of an 8-byte
big-endian Unix time in microseconds followed by one raw MAVLink packet.

A record's length is its packet's, read from the packet header by `framing.frame_length`
(MAVLink 1 and 2 mixed, signed packets). A log cut off by a power loss ends in a partial
record; `TlogReader` counts it in `truncated` instead of failing, and everything before
it still plays. Bytes that do not start a record (a corrupted log) are stepped over one
at a time and counted in `skipped_bytes`. Checksums are left to the decoder.

A record's time is the writer's wall clock, and one file can hold several recordings
(MAVProxy appends to a log, logs get concatenated): where the time steps back by more
than `STEP_BACK_MIN_S`, another recording begins. `TlogReader.records()` and
`segments()` number these segments and list the steps in `clock_steps`; within a segment
the time never goes back (a smaller step back, a wall clock set back by its time service,
is held at the time before it and counted in `held_back`). Every reader of a flight
(replay, analysis, export) reads a segment as one recording on one clock: neither frozen
at the last time before the step nor interleaved with the recording before it.
"""

from __future__ import annotations

import struct
from collections.abc import Iterator
from dataclasses import dataclass, field
from itertools import groupby
from operator import attrgetter
from pathlib import Path
from typing import BinaryIO

from fpv_station.core.mavlink.framing import frame_length

_TIME = struct.Struct(">Q")
_HEAD = 3  # packet bytes needed to know its length (v2: marker, length, incompat flags)
# A step back larger than this is another recording: a time service corrects a wall
# clock by well under a second, a recording joined to another one goes back minutes.
STEP_BACK_MIN_S = 1.0


def encode_record(t_wall_s: float, packet: bytes) -> bytes:
    return _TIME.pack(int(t_wall_s * 1e6)) + packet


def write_record(f: BinaryIO, t_wall_s: float, packet: bytes) -> None:
    f.write(encode_record(t_wall_s, packet))


@dataclass(frozen=True, slots=True)
class ClockStep:
    """Where a log's clock went back: another recording starts at record `record`."""

    record: int  # index of the new segment's first record in the file
    segment: int  # the new segment's number (the first segment is 0)
    from_s: float  # the newest time before the step
    to_s: float  # the new segment's first time


@dataclass(frozen=True, slots=True)
class TlogRecord:
    segment: int
    t_wall_s: float  # never before the previous record's time in the same segment
    packet: bytes


@dataclass
class TlogReader:
    """Iterate `(t_wall_s, packet)` records as written; counts a truncated tail and junk
    bytes. `records()` and `segments()` read them as recordings on their own clocks."""

    path: Path
    truncated: int = 0
    skipped_bytes: int = 0
    held_back: int = 0  # records whose small step back was held at the time before it
    clock_steps: list[ClockStep] = field(default_factory=list)

    def segments(self) -> Iterator[tuple[int, Iterator[tuple[float, bytes]]]]:
        """`(segment, records)` for each recording in the file, in order; `records`
        yields `(t_wall_s, packet)` and is read before the next segment is asked for
        (as `itertools.groupby`'s groups)."""
        for segment, group in groupby(self.records(), key=attrgetter("segment")):
            yield segment, ((r.t_wall_s, r.packet) for r in group)

    def records(self) -> Iterator[TlogRecord]:
        """Every record with its segment: a new one where the time steps back by more
        than STEP_BACK_MIN_S (listed in `clock_steps`)."""
        self.clock_steps, self.held_back = [], 0
        segment, newest = 0, None
        for index, (t, packet) in enumerate(self):
            if newest is not None and t < newest:
                if newest - t > STEP_BACK_MIN_S:
                    segment += 1
                    self.clock_steps.append(ClockStep(index, segment, newest, t))
                else:
                    self.held_back += 1
                    t = newest
            newest = t
            yield TlogRecord(segment, t, packet)

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
