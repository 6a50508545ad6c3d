"""A test vehicle that serves log files over the MAVLink log protocol, as ArduPilot does.

    with LogResponder({1: Path("arducopter.bin").read_bytes()}) as v:
        link = MavlinkLink(LinkSettings(source=v.station_source))

It is a `tests.mav_vehicle.MavVehicle` (heartbeat and telemetry at its rates, real
packets over a real socket) that also answers LOG_REQUEST_LIST with a LOG_ENTRY per log
(one entry of id 0 when it has none), LOG_REQUEST_DATA by sending LOG_DATA packets of
the range asked from its own thread (`rate_bps`: bytes a second, None as fast as the
socket takes them), stops on LOG_REQUEST_END or a newer request, and answers nothing for
a log it does not have (ArduPilot's way). `drop_after_bytes` and `drop_s`: once that many
log bytes went out, the link goes dead both ways for `drop_s` seconds (a radio fade),
and what was being sent is lost. `lose_every`: every that many LOG_DATA a packet of the
vehicle's goes missing on the way (its sequence number skips one, as the station sees a
loss). `log_protocol=False`: a vehicle that ignores it all.
"""

from __future__ import annotations

import threading
import time
from typing import Any, Self

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from tests.mav_vehicle import MavVehicle

CHUNK = 90


class LogResponder(MavVehicle):
    def __init__(
        self,
        logs: dict[int, bytes],
        *,
        time_utc: dict[int, int] | None = None,
        rate_bps: float | None = None,
        drop_after_bytes: int | None = None,
        drop_s: float = 0.0,
        log_protocol: bool = True,
        lose_every: int | None = None,
        **kwargs: Any,
    ) -> None:
        kwargs.setdefault("autopilot", "ardupilot")
        super().__init__(**kwargs)
        self.logs = dict(logs)
        self.time_utc = time_utc or {}
        self.rate_bps = rate_bps
        self.drop_after_bytes = drop_after_bytes
        self.drop_s = drop_s
        self.log_protocol = log_protocol
        self.lose_every = lose_every
        self.deaf_until = 0.0
        self.log_bytes_sent = 0
        self.data_requests: list[tuple[int, int, int]] = []  # (id, ofs, count) as asked
        self.list_requests = 0
        self.end_requests = 0
        self._transfer: tuple[int, int, int] | None = None  # (id, next ofs, end)
        self._transfer_lock = threading.Lock()
        self._wake = threading.Event()
        self._silenced = False

    def start(self) -> Self:
        super().start()
        t = threading.Thread(target=self._log_loop, name="log-responder", daemon=True)
        t.start()
        self._threads.append(t)
        return self

    @property
    def dropped(self) -> bool:
        return time.monotonic() < self.deaf_until

    def _handle(self, msg: mavlink.MAVLink_message) -> None:
        if self.dropped:
            return  # the fade takes what the station sends too
        kind = msg.get_type()
        if not kind.startswith("LOG_"):
            super()._handle(msg)
            return
        if not self.log_protocol or getattr(msg, "target_system", 0) not in (0, self.sysid):
            return
        if kind == "LOG_REQUEST_LIST":
            self.list_requests += 1
            ids = sorted(self.logs)
            if not ids:
                self.send_message(self.mav.log_entry_encode(0, 0, 0, 0, 0))
            for i in ids:
                if msg.start <= i <= msg.end:
                    utc = self.time_utc.get(i, 0)
                    entry = self.mav.log_entry_encode(i, len(ids), ids[-1], utc, len(self.logs[i]))
                    self.send_message(entry)
        elif kind == "LOG_REQUEST_DATA":
            self.data_requests.append((msg.id, msg.ofs, msg.count))
            with self._transfer_lock:
                self._transfer = None
                data = self.logs.get(msg.id)
                if data is None:
                    return
                if msg.ofs >= len(data):
                    self.send_message(self.mav.log_data_encode(msg.id, msg.ofs, 0, bytes(CHUNK)))
                    return
                self._transfer = (msg.id, msg.ofs, min(len(data), msg.ofs + msg.count))
            self._wake.set()
        elif kind == "LOG_REQUEST_END":
            self.end_requests += 1
            with self._transfer_lock:
                self._transfer = None

    def _log_loop(self) -> None:
        next_at = time.monotonic()
        while not self._stop.is_set():
            if self._silenced and not self.dropped:  # the fade is over: heard again
                self._silenced = self.silent = False
            with self._transfer_lock:
                transfer = self._transfer
            if transfer is None or self.dropped:
                self._wake.wait(0.02)
                self._wake.clear()
                continue
            log_id, ofs, end = transfer
            chunk = self.logs[log_id][ofs : min(ofs + CHUNK, end)]
            if self.rate_bps is not None:
                # Paced by the bytes on the wire (a LOG_DATA is 109 bytes in MAVLink 2).
                delay = next_at - time.monotonic()
                if delay > 0:
                    self._stop.wait(delay)
                next_at = max(next_at, time.monotonic() - 0.05) + 109 / self.rate_bps
            with self._transfer_lock:
                if self._transfer != transfer:
                    continue  # replaced or ended meanwhile
                self._transfer = (log_id, ofs + len(chunk), end) if ofs + len(chunk) < end else None
            self.send_message(
                self.mav.log_data_encode(log_id, ofs, len(chunk), chunk.ljust(CHUNK, b"\0"))
            )
            self.log_bytes_sent += len(chunk)
            if self.lose_every and (ofs // CHUNK) % self.lose_every == self.lose_every - 1:
                self.skip_seq(1)  # a packet of its own lost on the way (a full buffer)
            if self.drop_after_bytes is not None and self.log_bytes_sent >= self.drop_after_bytes:
                self.drop_after_bytes = None
                self.deaf_until = time.monotonic() + self.drop_s
                self.silent = True
                with self._transfer_lock:
                    self._transfer = None  # lost with the link
                self._silenced = True
