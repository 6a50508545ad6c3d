"""The twin's side of the MAVLink log protocol, as PX4 and ArduPilot serve their SD cards.

LOG_REQUEST_LIST is answered with one LOG_ENTRY per finished log in the range asked
(ids from 1; with no logs one entry of id 0 and num_logs 0, as both autopilots send).
LOG_REQUEST_DATA starts sending the bytes [ofs, ofs + count) of a log as LOG_DATA
packets of 90 bytes, a bounded number per poll so that the telemetry between them keeps
its rates; a newer request replaces the one being sent and LOG_REQUEST_END stops it. A
request at or past the end gets one LOG_DATA with count 0 (the end); one for a log that
does not exist gets nothing, as ArduPilot does, so a client must give up by itself.
LOG_ERASE deletes the finished logs. Everything runs in the twin's thread.
"""

from __future__ import annotations

import logging
from typing import BinaryIO

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.twin.flight_log import FlightLogger, LogFile

log = logging.getLogger(__name__)

LOG_MESSAGES = frozenset({"LOG_REQUEST_LIST", "LOG_REQUEST_DATA", "LOG_REQUEST_END", "LOG_ERASE"})
CHUNK_BYTES = 90  # LOG_DATA's data field
# LOG_DATA packets sent per poll of the vehicle (100 a second in real time): with the
# telemetry's few packets per poll, this keeps a UDP receive buffer from overflowing.
DEFAULT_BURST = 24


class LogServer:
    def __init__(
        self, mav: mavlink.MAVLink, logger: FlightLogger, burst: int = DEFAULT_BURST
    ) -> None:
        self.mav = mav
        self.logger = logger
        self.burst = burst
        self._entry: LogFile | None = None
        self._file: BinaryIO | None = None
        self._ofs = 0
        self._end = 0
        self.sent_packets = 0

    def handle(self, msg: mavlink.MAVLink_message) -> None:
        kind = msg.get_type()
        if kind == "LOG_REQUEST_LIST":
            self._list(msg.start, msg.end)
        elif kind == "LOG_REQUEST_DATA":
            self._request(msg.id, msg.ofs, msg.count)
        elif kind == "LOG_REQUEST_END":
            self._stop()
        elif kind == "LOG_ERASE":
            self._stop()
            self.logger.erase()

    def poll(self) -> None:
        """Send the next packets of the transfer under way, at most `burst`."""
        if self._file is None or self._entry is None:
            return
        for _ in range(self.burst):
            if self._ofs >= self._end:
                self._stop()
                return
            n = min(CHUNK_BYTES, self._end - self._ofs)
            try:
                self._file.seek(self._ofs)
                data = self._file.read(n)
            except OSError as exc:
                log.warning("twin log %d: %s", self._entry.id, exc)
                self._stop()
                return
            if not data:
                self._stop()
                return
            self.mav.log_data_send(
                self._entry.id, self._ofs, len(data), data.ljust(CHUNK_BYTES, b"\0")
            )
            self.sent_packets += 1
            self._ofs += len(data)

    def close(self) -> None:
        self._stop()

    def _list(self, start: int, end: int) -> None:
        logs = self.logger.logs
        if not logs:
            self.mav.log_entry_send(0, 0, 0, 0, 0)
            return
        last = logs[-1].id
        for entry in logs:
            if start <= entry.id <= min(end, last):
                self.mav.log_entry_send(entry.id, len(logs), last, entry.time_utc, entry.size_bytes)

    def _request(self, log_id: int, ofs: int, count: int) -> None:
        self._stop()
        entry = next((e for e in self.logger.logs if e.id == log_id), None)
        if entry is None:
            return
        if ofs >= entry.size_bytes:
            self.mav.log_data_send(log_id, ofs, 0, bytes(CHUNK_BYTES))
            return
        try:
            self._file = entry.path.open("rb")
        except OSError as exc:
            log.warning("twin log %d: %s", log_id, exc)
            return
        self._entry = entry
        self._ofs = ofs
        self._end = min(entry.size_bytes, ofs + count)

    def _stop(self) -> None:
        if self._file is not None:
            self._file.close()
        self._file = None
        self._entry = None
