"""Packet loss per MAVLink stream, counted from sequence numbers as `mavloss` does.

Every sender on a link, one (sysid, compid) pair, numbers its packets 0..255 in turn;
a gap of n before a packet means n packets of that sender were lost. Senders share a
link but never a counter: the autopilot, a SiK telemetry radio (51/68), other ground
stations each count on their own, so loss is kept per stream and the autopilot's is
the figure that says whether the vehicle is heard.

A repeated number is a duplicate, never 255 losses: a SiK radio sends RADIO and
RADIO_STATUS under one number, and a router may deliver a packet twice. That is the one
place we differ from pymavlink's `mavloss`, which counts a repeat as 255 lost (it leaves
the radio out instead).
"""

from __future__ import annotations

from dataclasses import dataclass

MAX_STREAMS = 64  # a hostile or broken sender cannot grow the table without bound
RADIO_IDS = (51, 68)  # SiK firmware's own sysid ('3') and compid ('D', TELEMETRY_RADIO)


@dataclass(frozen=True, slots=True)
class StreamLoss:
    """One sender's figures since the link started (`/api/status` link.streams)."""

    sysid: int
    compid: int
    role: str  # "autopilot", "radio", "gcs" or "other"
    packets: int  # received, duplicates included
    lost: int  # missing sequence numbers
    duplicates: int  # packets that repeated the previous sequence number
    loss_ratio: float  # lost / (lost + packets)


class _Counter:
    __slots__ = ("packets", "lost", "duplicates", "last_seq")

    def __init__(self) -> None:
        self.packets = 0
        self.lost = 0
        self.duplicates = 0
        self.last_seq: int | None = None


class StreamLossCounter:
    """Fed by one thread (the link's); `report()` returns immutable figures."""

    def __init__(self) -> None:
        self._streams: dict[tuple[int, int], _Counter] = {}
        self._gcs: set[tuple[int, int]] = set()
        self.untracked = 0  # packets of senders beyond MAX_STREAMS

    def on_packet(self, sysid: int, compid: int, seq: int) -> None:
        key = (sysid, compid)
        c = self._streams.get(key)
        if c is None:
            if len(self._streams) >= MAX_STREAMS:
                self.untracked += 1
                return
            c = self._streams[key] = _Counter()
        c.packets += 1
        last = c.last_seq
        if last is not None:
            if seq == last:
                c.duplicates += 1
            else:
                c.lost += (seq - last - 1) % 256
        c.last_seq = seq

    def note_gcs(self, sysid: int, compid: int) -> None:
        """A HEARTBEAT said this sender is a ground station."""
        self._gcs.add((sysid, compid))

    def restart(self) -> None:
        """A new connection starts new sequences; the counts so far stay."""
        for c in self._streams.values():
            c.last_seq = None

    def report(self, autopilot: tuple[int, int] | None) -> tuple[StreamLoss, ...]:
        """Every stream, most packets first; `autopilot` is the followed vehicle."""
        out = [
            self._figures(key, c, self._role(key, autopilot)) for key, c in self._streams.items()
        ]
        out.sort(key=lambda s: -s.packets)
        return tuple(out)

    def _role(self, key: tuple[int, int], autopilot: tuple[int, int] | None) -> str:
        if key == autopilot:
            return "autopilot"
        if key == RADIO_IDS:
            return "radio"
        if key in self._gcs:
            return "gcs"
        return "other"

    @staticmethod
    def _figures(key: tuple[int, int], c: _Counter, role: str) -> StreamLoss:
        return StreamLoss(
            sysid=key[0],
            compid=key[1],
            role=role,
            packets=c.packets,
            lost=c.lost,
            duplicates=c.duplicates,
            loss_ratio=round(c.lost / (c.lost + c.packets), 6) if c.packets else 0.0,
        )
