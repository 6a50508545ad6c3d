"""Cut a raw byte stream into MAVLink 1 and 2 packets, skipping and counting junk; read
a packet's header fields. The only header parser in the code base: the link, the tlog
records and analysis all use these rules.

A MAVLink 1 frame is 0xFE, length, seq, sysid, compid, msgid, payload, 2-byte checksum
(length + 8). A MAVLink 2 frame is 0xFD, length, incompat flags, compat flags, seq,
sysid, compid, 3-byte msgid, payload, checksum (length + 12), plus a 13-byte signature
when incompat flag 0x01 is set. Any other incompat flag is unknown to the protocol, so a
0xFD followed by one is not a frame start.

pymavlink's own `parse_buffer` (even with `robust_parsing`) drops a whole frame's worth
of bytes when a stray 0xFD/0xFE in garbage starts a false frame, which can swallow a
real packet behind it. Here a frame that fails its checksum costs one byte: the search
for the next start marker resumes right after the false one, as MAVLink routers do.
Decoding and checksums are pymavlink's (`MAVLink.decode`, through core.mavlink.fast_decode).
"""

from __future__ import annotations

from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.core.mavlink.fast_decode import FastDecoder

MAGIC_V1 = 0xFE
MAGIC_V2 = 0xFD
_SIGNED = 0x01  # MAVLINK_IFLAG_SIGNED
_MAX_BUFFER = 1 << 16  # a reader that falls this far behind is fed junk; drop it


@dataclass(slots=True)
class FramerCounters:
    garbage_bytes: int = 0  # bytes outside any packet
    bad_crc: int = 0  # frames whose checksum (or header) did not hold
    unknown_ids: int = 0  # well-formed packets of message ids our dialect lacks
    packets: int = 0  # good packets, known and unknown


class MavFramer:
    """Feed bytes in, get decoded pymavlink messages out (unknown ids included)."""

    def __init__(self) -> None:
        self._buf = bytearray()
        self._mav = FastDecoder()  # pymavlink's decode, cheaper for the plain messages
        self.counters = FramerCounters()

    @property
    def pending(self) -> int:
        """Bytes held waiting for the rest of a frame."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[mavlink.MAVLink_message]:
        buf = self._buf
        if not buf and data and frame_length(data) == len(data):
            # Nothing held back and `data` is one whole frame (a UDP datagram: the usual
            # case): decode it as it is. Anything else, a bad checksum or an unknown id
            # (whose inside is searched for a real packet) included, takes the general path.
            try:
                msg = self._mav.decode(bytearray(data))
            except mavlink.MAVError:
                pass
            else:
                if not isinstance(msg, mavlink.MAVLink_unknown):
                    self.counters.packets += 1
                    return [msg]
        buf += data
        if len(buf) > _MAX_BUFFER:  # cannot happen with real frames (max 280 bytes)
            self.counters.garbage_bytes += len(buf) - 280
            del buf[:-280]
        out: list[mavlink.MAVLink_message] = []
        while buf:
            start = _find_magic(buf)
            if start < 0:
                self.counters.garbage_bytes += len(buf)
                buf.clear()
                break
            if start:
                self.counters.garbage_bytes += start
                del buf[:start]
            total = frame_length(buf)
            if total is None or len(buf) < total:
                if total == -1:  # impossible header: not a frame start
                    self._skip_one()
                    continue
                break  # wait for more bytes
            try:
                msg = self._mav.decode(buf[:total])  # a copy: the message keeps it
            except mavlink.MAVError:
                self._skip_one()
                continue
            if isinstance(msg, mavlink.MAVLink_unknown):
                verdict = self._hides_real_packet(total)
                if verdict is None:
                    break  # a packet may start inside it: wait for its end to decide
                if verdict:
                    self._skip_one()
                    continue
                self.counters.unknown_ids += 1
            del buf[:total]
            self.counters.packets += 1
            out.append(msg)
        return out

    def _hides_real_packet(self, total: int) -> bool | None:
        """An unknown id has no checksum we can verify, so junk that starts with a
        marker can pass as one. Reject it if a verifiable packet starts inside it;
        None if such a packet may be there but has not fully arrived."""
        buf = self._buf
        j = _find_magic(buf, 1)
        undecided = False
        while 0 < j < total:
            length = frame_length(buf[j : j + 3])
            if length is None or (length > 0 and j + length > len(buf)):
                undecided = True
            elif length > 0:
                try:
                    inner = self._mav.decode(bytearray(buf[j : j + length]))
                except mavlink.MAVError:
                    pass
                else:
                    if not isinstance(inner, mavlink.MAVLink_unknown):
                        return True
            j = _find_magic(buf, j + 1)
        return None if undecided else False

    def _skip_one(self) -> None:
        self.counters.bad_crc += 1
        self.counters.garbage_bytes += 1
        del self._buf[:1]

    def reset(self) -> None:
        """Forget a partial frame (after a reconnect the stream starts afresh)."""
        self._buf.clear()


def _find_magic(buf: bytearray, start: int = 0) -> int:
    a = buf.find(MAGIC_V2, start)
    b = buf.find(MAGIC_V1, start)
    if a < 0:
        return b
    if b < 0:
        return a
    return min(a, b)


def frame_length(buf: bytes | bytearray) -> int | None:
    """Total frame length from the header at the start of `buf` (which starts with a
    marker): None if the header is incomplete, -1 if it is impossible (or no marker)."""
    if buf[0] == MAGIC_V1:
        if len(buf) < 2:
            return None
        return buf[1] + 8
    if buf[0] != MAGIC_V2:
        return -1
    if len(buf) < 3:
        return None
    incompat = buf[2]
    if incompat & ~_SIGNED:
        return -1
    return buf[1] + 12 + (13 if incompat & _SIGNED else 0)


def message_id(packet: bytes | bytearray) -> int:
    """The message id from a whole packet's header (v1: byte 5; v2: bytes 7-9,
    little-endian), without decoding the payload."""
    if packet[0] == MAGIC_V1:
        return packet[5]
    return packet[7] | (packet[8] << 8) | (packet[9] << 16)


def payload(packet: bytes | bytearray) -> bytes:
    """A whole packet's payload as it came: MAVLink 2 drops trailing zero bytes, so
    fields beyond its end (extension fields included) are 0; pymavlink's decoder knows
    only the fields of its own dialect version, the bytes keep the newer ones."""
    start = 6 if packet[0] == MAGIC_V1 else 10
    return bytes(packet[start : start + packet[1]])


def packet_version(msg: mavlink.MAVLink_message) -> int:
    """1 or 2: the wire format the packet came in."""
    return 1 if msg.get_msgbuf()[0] == MAGIC_V1 else 2
