"""pymavlink's `MAVLink.decode` for the messages a link mostly carries, at a third of its
cost: the same message objects, field for field.

pymavlink decodes every message generically: per packet it walks each field three
times in Python (reordering, strings, the constructor), builds two header objects and
copies the buffer twice, a large share of the link thread's work on a Pi
(docs/PERFORMANCE.md). For a message whose fields are
all scalars (no arrays, no strings: ATTITUDE, GLOBAL_POSITION_INT, LOCAL_POSITION_NED,
VFR_HUD, GPS_RAW_INT, RC_CHANNELS, SERVO_OUTPUT_RAW, SYS_STATUS, HEARTBEAT, ...) the
layout is fixed, so the decode is one unpack, one reordering in C and one dictionary
update, with the constant attributes pymavlink's constructor sets copied from a
prototype. Anything else goes to pymavlink itself, which then decides and raises as
always: arrays and strings, signed packets, unknown ids, a bad length or checksum.
tests/test_mavlink_framing.py compares both decoders on every message of the dialect.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from operator import itemgetter
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mavlink

_V1_HEADER = 6
_V2_HEADER = 10
# What pymavlink's decode sets per packet: not copied from the prototype (whose `_signed`
# False and `_link_id` None are what an unsigned packet, the only kind decoded here, has).
_PER_PACKET = frozenset(("_header", "_msgbuf", "_payload", "_crc"))


@dataclass(frozen=True, slots=True)
class _Layout:
    """How one message type's payload becomes its object."""

    cls: type[mavlink.MAVLink_message]
    unpack: Any  # struct.Struct.unpack of its wire order
    size: int  # the full payload's length (MAVLink 2 drops trailing zeros on the wire)
    in_field_order: Any  # wire order -> fieldnames order, one C call
    fieldnames: tuple[str, ...]
    constant: dict[str, Any]  # the attributes the constructor sets that no packet changes
    crc_extra: bytes


def _layout(cls: type[mavlink.MAVLink_message]) -> _Layout | None:
    """The layout of a message type whose fields are all scalars; None otherwise."""
    if any(n != 1 for n in cls.lengths) or "s" in cls.unpacker.format:
        return None
    fieldnames = tuple(cls.fieldnames)
    proto = cls(*([0] * len(fieldnames)))  # pymavlink's own constructor: its attributes
    constant = {
        k: v for k, v in vars(proto).items() if k not in _PER_PACKET and k not in fieldnames
    }
    order = cls.orders
    getter = itemgetter(*order) if len(order) > 1 else (lambda t, i=order[0]: (t[i],))
    return _Layout(
        cls=cls,
        unpack=cls.unpacker.unpack,
        size=cls.unpacker.size,
        in_field_order=getter,
        fieldnames=fieldnames,
        constant=constant,
        crc_extra=bytes((cls.crc_extra,)),
    )


_LAYOUTS: dict[int, _Layout] = {
    msg_id: layout
    for msg_id, cls in mavlink.mavlink_map.items()
    if (layout := _layout(cls)) is not None
}


# fastcrc's, where pymavlink found it
_MCRF4XX: Callable[[bytes, int], int] | None = getattr(mavlink, "mcrf4xx", None)


def _crc(data: bytes) -> int:
    """The X.25 checksum pymavlink computes (through fastcrc when it is installed)."""
    if _MCRF4XX is not None:
        return _MCRF4XX(data, 0xFFFF)
    crc: int = mavlink.x25crc(data).crc
    return crc


class FastDecoder:
    """`decode(buf)` as `mavlink.MAVLink(None).decode(buf)` returns and raises it."""

    def __init__(self) -> None:
        self._mav = mavlink.MAVLink(None)

    def decode(self, buf: bytearray) -> mavlink.MAVLink_message:
        msg = self._fast(buf)
        return msg if msg is not None else self._mav.decode(buf)

    def _fast(self, buf: bytearray) -> mavlink.MAVLink_message | None:
        n = len(buf)
        if n < _V1_HEADER + 2:
            return None
        if buf[0] == mavlink.PROTOCOL_MARKER_V2:
            if n < _V2_HEADER + 2 or buf[2] != 0:  # a flag: signed, or unknown to us
                return None
            head = _V2_HEADER
            msg_id = buf[7] | buf[8] << 8 | buf[9] << 16
            seq, sysid, compid, incompat, compat = buf[4], buf[5], buf[6], buf[2], buf[3]
        elif buf[0] == mavlink.PROTOCOL_MARKER_V1:
            head = _V1_HEADER
            msg_id = buf[5]
            seq, sysid, compid, incompat, compat = buf[2], buf[3], buf[4], 0, 0
        else:
            return None
        mlen = buf[1]
        layout = _LAYOUTS.get(msg_id)
        if layout is None or mlen != n - head - 2:
            return None
        crc = buf[n - 2] | buf[n - 1] << 8
        if crc != _crc(bytes(buf[1 : n - 2]) + layout.crc_extra):
            return None  # pymavlink raises its own MAVError for it
        payload = bytes(buf[head : n - 2])
        if mlen < layout.size:
            payload += bytes(layout.size - mlen)
        values = layout.in_field_order(layout.unpack(payload[: layout.size]))
        msg = object.__new__(layout.cls)
        attrs = msg.__dict__
        attrs.update(layout.constant)
        attrs.update(zip(layout.fieldnames, values))
        attrs["_msgbuf"] = buf
        attrs["_payload"] = buf[6 : n - 2]
        attrs["_crc"] = crc
        attrs["_header"] = mavlink.MAVLink_header(
            msg_id, incompat, compat, mlen, seq, sysid, compid
        )
        return msg
