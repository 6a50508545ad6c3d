"""A PX4 ULog writer: the file format PX4's logger writes to its SD card.

A file is the 16-byte header (magic, version 1, start time in µs since boot), a flag-bits
message, the definitions (one format per topic, information key/values) and then the
data section: one subscription per topic and its samples, each stamped in µs since boot
with the timestamp as its first field. Fields are packed without padding, as PX4's
formats declare them (https://docs.px4.io/main/en/dev_log/ulog_file_format.html);
pyulog and PX4's own tools read what this writes.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from typing import BinaryIO

ULOG_MAGIC = b"ULog\x01\x12\x35"
_VERSION = 1
_STRUCT_CODES = {
    "uint8_t": "B",
    "int8_t": "b",
    "uint16_t": "H",
    "int16_t": "h",
    "uint32_t": "I",
    "int32_t": "i",
    "uint64_t": "Q",
    "int64_t": "q",
    "float": "f",
    "double": "d",
    "bool": "?",
}


@dataclass(frozen=True)
class Topic:
    """One logged topic: its PX4 name and its fields after `uint64_t timestamp`, each as
    (type, name) with arrays written `float[3]`."""

    name: str
    fields: tuple[tuple[str, str], ...]
    _struct: struct.Struct = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        codes = ["<Q"]
        for kind, _ in self.fields:
            base, _, rest = kind.partition("[")
            count = rest.rstrip("]") if rest else ""
            codes.append(f"{count}{_STRUCT_CODES[base]}")
        object.__setattr__(self, "_struct", struct.Struct("".join(codes)))

    @property
    def format(self) -> bytes:
        body = ";".join(f"{kind} {name}" for kind, name in self.fields)
        return f"{self.name}:uint64_t timestamp;{body};".encode()

    def pack(self, timestamp_us: int, values: tuple) -> bytes:
        return self._struct.pack(timestamp_us, *values)


class ULogWriter:
    """Writes a ULog to `f` (opened binary). Every topic and information key is given at
    construction: ULog wants all definitions before the first data message."""

    def __init__(
        self, f: BinaryIO, start_us: int, topics: list[Topic], info: dict[str, str]
    ) -> None:
        self._f = f
        f.write(ULOG_MAGIC + bytes([_VERSION]) + struct.pack("<Q", start_us))
        # Flag bits: no compatible or incompatible flags, no appended data.
        self._message(b"B", bytes(16) + bytes(24))
        for topic in topics:
            self._message(b"F", topic.format)
        for key, value in info.items():
            raw = value.encode()
            key_field = f"char[{len(raw)}] {key}".encode()
            self._message(b"I", bytes([len(key_field)]) + key_field + raw)
        self._ids: dict[str, int] = {}
        for msg_id, topic in enumerate(topics):
            self._ids[topic.name] = msg_id
            self._message(b"A", struct.pack("<BH", 0, msg_id) + topic.name.encode())
        self._topics = {t.name: t for t in topics}

    def write(self, topic: str, timestamp_us: int, *values: object) -> None:
        """One sample of `topic`: its fields' values in their declared order, arrays
        spread (three floats for a `float[3]`)."""
        t = self._topics[topic]
        self._message(b"D", struct.pack("<H", self._ids[topic]) + t.pack(timestamp_us, values))

    def log_text(self, timestamp_us: int, text: str, level: int = 6) -> None:
        """A logged string (PX4's 'L' message; level as syslog: 6 info, 4 warning)."""
        self._message(b"L", struct.pack("<BQ", ord("0") + level, timestamp_us) + text.encode())

    def _message(self, kind: bytes, payload: bytes) -> None:
        self._f.write(struct.pack("<H", len(payload)) + kind + payload)
