"""The autopilot's own flight log, fetched over the MAVLink log protocol.

The station asks for the list (LOG_REQUEST_LIST, answered by one LOG_ENTRY per log),
picks the log that covers the flight and asks for its bytes a window at a time
(LOG_REQUEST_DATA from the first byte still missing; answered by LOG_DATA packets of 90
bytes each), until every byte of the listed size is in, then says LOG_REQUEST_END. The
window starts small, grows up to `window_bytes` after each window that came in whole
while the link lost none of the autopilot's packets (their sequence numbers), and
halves, with a pause, when the link lost some: the download gives way to the flight
state. A window lost on the way (a radio fade, a dropped link) is asked for again from
its first missing byte after `request_timeout_s` without data, at the same size: a
window cut short says nothing about loss, as its lost packet may be among those not yet
sent. After `give_up_s` without one new byte the download stops as incomplete.
Only one window is outstanding, so what the vehicle sends for us is bounded, and its
telemetry goes on between our windows and beside them (docs/PERFORMANCE.md measures
it). A vehicle that does not answer the list, has no logs, or does not have the log
asked for ends in a state that says so, never in a wait.

Threads: the link's packet listener (its reader thread) only picks LOG_ENTRY and
LOG_DATA of the followed autopilot by their header and puts the raw packets into a
bounded queue; one download thread (`onboard-log`) decodes them, writes the bytes at
their offsets into the session folder (blocking I/O, off the event loop) and sends its
requests through `link.send`. Its progress is published through a `Latest` (the one
thread-to-asyncio hand-off): the sessions page and REST read it.

The file is `onboard.ulg` for a PX4 ULog and `onboard.bin` for an ArduPilot DataFlash
log (by the file's first bytes; `onboard.log` for neither), written as `onboard.part`
while it comes in.
"""

from __future__ import annotations

import logging
import os
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal, Protocol

from pydantic import Field
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.latest import Latest
from fpv_station.core.mavlink.framing import MAGIC_V1, message_id
from fpv_station.core.settings_section import Section

log = logging.getLogger(__name__)

CHUNK_BYTES = 90  # LOG_DATA's data field
ULOG_MAGIC = b"ULog\x01\x12\x35"
DATAFLASH_MAGIC = b"\xa3\x95"
PART_NAME = "onboard.part"
_LOG_IDS = frozenset({mavlink.MAVLINK_MSG_ID_LOG_ENTRY, mavlink.MAVLINK_MSG_ID_LOG_DATA})
# Packets between the listener and the download thread: a window's worth and more; a
# packet that finds it full is dropped, counted, and its bytes asked for again.
_QUEUE_PACKETS = 1024
_LIST_TRIES = 3
# The request window, in LOG_DATA packets: where it starts and grows by, its least, and
# the longest pause after a window in which the link lost packets.
_START_CHUNKS = 32
_MIN_CHUNKS = 4
_MAX_PAUSE_S = 1.0
# A log's start (LOG_ENTRY time_utc) may lie this far after the flight's end and still be
# its log: the vehicle's GPS clock against the station's.
CLOCK_SLACK_S = 60.0

State = Literal[
    "idle", "listing", "downloading", "complete", "incomplete", "no_log", "failed", "cancelled"
]
FINAL_STATES = frozenset({"complete", "incomplete", "no_log", "failed", "cancelled"})


class OnboardLogSettings(Section):
    """Fetching the autopilot's own flight log into the session (`[onboard_log]`)."""

    after_disarm: bool = Field(
        True,
        description="After each disarm, download the autopilot's log of the flight into "
        "its session folder (onboard.bin or onboard.ulg); it can always be asked for from "
        "the sessions page or over REST.",
    )
    window_bytes: int = Field(
        CHUNK_BYTES * 128,
        ge=CHUNK_BYTES,
        le=CHUNK_BYTES * 4096,
        description="The most bytes asked for per LOG_REQUEST_DATA (the window grows to "
        "it while the link loses nothing): the most the vehicle sends for us at once, so "
        "its telemetry keeps its place on the link.",
    )
    request_timeout_s: float = Field(
        1.0,
        gt=0,
        le=30.0,
        description="Without data for this long, ask again for the window's missing bytes "
        "(and for the list: a LOG_REQUEST_LIST unanswered).",
    )
    give_up_s: float = Field(
        30.0,
        gt=0,
        description="Without one new byte for this long (a link that stays down), stop: "
        "the session keeps what came, marked incomplete.",
    )
    max_bytes: int = Field(
        2 * 1024**3,
        gt=0,
        description="A log larger than this is not downloaded (the disk of a small computer).",
    )


@dataclass(frozen=True)
class LogEntry:
    """One log on the vehicle, as LOG_ENTRY lists it."""

    id: int
    time_utc: int  # its start, UTC seconds; 0 when the vehicle had no clock
    size_bytes: int


@dataclass(frozen=True)
class DownloadStatus:
    """Where a download stands; published after every change of note."""

    state: State = "idle"
    session: str | None = None
    log_id: int | None = None
    size_bytes: int = 0
    received_bytes: int = 0
    file: str | None = None
    message: str = ""
    download_s: float = 0.0
    re_requests: int = 0
    dropped_packets: int = 0
    lost_packets: int = 0  # the vehicle's packets the link lost meanwhile (sequence gaps)
    logs_listed: int = 0

    @property
    def done(self) -> bool:
        return self.state in FINAL_STATES


class LinkLike(Protocol):
    def send(self, msg: mavlink.MAVLink_message) -> None: ...
    def add_packet_listener(self, cb: Callable[[float, bytes], None]) -> None: ...
    def remove_packet_listener(self, cb: Callable[[float, bytes], None]) -> None: ...

    @property
    def mav(self) -> mavlink.MAVLink: ...


def log_file_name(head: bytes) -> str:
    """The session file name for a log whose first bytes are `head`."""
    if head.startswith(ULOG_MAGIC):
        return "onboard.ulg"
    if head.startswith(DATAFLASH_MAGIC):
        return "onboard.bin"
    return "onboard.log"


def choose_log(entries: list[LogEntry], flight_end_utc: float | None) -> LogEntry | None:
    """The log of the flight that ended at `flight_end_utc` (UTC seconds; None: the one
    that just ended): the newest log that started before it ended. A log without a start
    time (the vehicle had no clock) counts as started before; with `flight_end_utc`
    None the newest log is the flight's, as both autopilots start a log at arming (or at
    boot) and the flight just ended."""
    logs = sorted((e for e in entries if e.size_bytes > 0), key=lambda e: e.id)
    if flight_end_utc is None:
        return logs[-1] if logs else None
    before = [e for e in logs if e.time_utc == 0 or e.time_utc <= flight_end_utc + CLOCK_SLACK_S]
    return before[-1] if before else None


@dataclass
class _Ranges:
    """Which 90-byte chunks of the log are in."""

    size: int
    have: bytearray = field(init=False)
    received: int = 0

    def __post_init__(self) -> None:
        self.have = bytearray((self.size + CHUNK_BYTES - 1) // CHUNK_BYTES)

    def add(self, ofs: int, count: int) -> bool:
        """Mark [ofs, ofs + count) as in; True if it brought a new chunk."""
        if ofs % CHUNK_BYTES or count <= 0:
            return False
        i = ofs // CHUNK_BYTES
        if i >= len(self.have) or self.have[i]:
            return False
        expected = min(CHUNK_BYTES, self.size - ofs)
        if count < expected:
            return False  # a short chunk inside the log: asked for again
        self.have[i] = 1
        self.received += expected
        return True

    def first_missing(self, start: int = 0) -> int | None:
        i = self.have.find(0, start)
        return None if i < 0 else i

    def missing_run(self, first: int, max_chunks: int) -> int:
        """Chunks missing from `first` on, up to `max_chunks`."""
        end = self.have.find(1, first, first + max_chunks)
        return (end if end >= 0 else min(len(self.have), first + max_chunks)) - first

    @property
    def complete(self) -> bool:
        return self.received == self.size


class LogDownload:
    """Downloads one log of the autopilot `target` into `folder`; `start()` runs it in its
    own thread, `status` publishes its progress, `cancel()` ends it early."""

    def __init__(
        self,
        link: LinkLike,
        target: tuple[int, int],
        folder: Path,
        settings: OnboardLogSettings,
        *,
        session: str | None = None,
        log_id: int | None = None,
        flight_end_utc: float | None = None,
    ) -> None:
        self.link = link
        self.target = target
        self.folder = folder
        self.settings = settings
        self.log_id = log_id  # None: the log that covers the flight
        self.flight_end_utc = flight_end_utc
        self.status: Latest[DownloadStatus] = Latest(DownloadStatus(session=session))
        self._queue: queue.Queue[bytes] = queue.Queue(_QUEUE_PACKETS)
        self._cancel = threading.Event()
        self._thread: threading.Thread | None = None
        self._decoder = mavlink.MAVLink(None)
        self._dropped = 0
        self._last_seq: int | None = None
        self.lost_packets = 0  # the autopilot's packets the link lost during the download

    # -- any thread -------------------------------------------------------------------

    def start(self) -> None:
        if self._thread is not None:
            raise RuntimeError("this download has started already")
        self.link.add_packet_listener(self._on_packet)
        self._thread = threading.Thread(target=self._run, name="onboard-log", daemon=True)
        self._thread.start()

    def cancel(self) -> None:
        self._cancel.set()

    def join(self, timeout: float | None = None) -> None:
        if self._thread is not None:
            self._thread.join(timeout)

    @property
    def running(self) -> bool:
        return self._thread is not None and self._thread.is_alive()

    # -- the link's thread ------------------------------------------------------------

    def _on_packet(self, t_wall: float, packet: bytes) -> None:
        # Sender and sequence: bytes 3, 4 and 2 of a MAVLink 1 header, 5, 6 and 4 of a
        # MAVLink 2 one.
        v1 = packet[0] == MAGIC_V1
        if packet[3 if v1 else 5] != self.target[0]:
            return
        if packet[4 if v1 else 6] == self.target[1]:
            # The autopilot's packets lost on the way (telemetry and ours alike): the
            # download thread backs off when the link drops what the vehicle sends.
            seq = packet[2 if v1 else 4]
            if self._last_seq is not None:
                gap = (seq - self._last_seq - 1) & 0xFF
                if gap < 128:  # more is a packet repeated or reordered, not lost
                    self.lost_packets += gap
            self._last_seq = seq
        if message_id(packet) not in _LOG_IDS:
            return
        try:
            self._queue.put_nowait(packet)
        except queue.Full:
            self._dropped += 1

    # -- the download thread ----------------------------------------------------------

    def _publish(self, **changes: Any) -> DownloadStatus:
        status = replace(
            self.status.current(),
            dropped_packets=self._dropped,
            lost_packets=self.lost_packets,
            **changes,
        )
        self.status.publish(status)
        return status

    def _run(self) -> None:
        t0 = time.monotonic()
        try:
            self._download(t0)
        except Exception as exc:  # a bug or a full disk must show in the status, not vanish
            log.exception("onboard log download failed")
            self._publish(
                state="failed",
                message=f"{type(exc).__name__}: {exc}",
                download_s=round(time.monotonic() - t0, 3),
            )
        finally:
            self.link.remove_packet_listener(self._on_packet)
            try:
                self.link.send(self.link.mav.log_request_end_encode(*self.target))
            except Exception:  # the link is stopping: nothing to end
                pass

    def _next(self, timeout: float) -> mavlink.MAVLink_message | None:
        try:
            packet = self._queue.get(timeout=timeout)
        except queue.Empty:
            return None
        try:
            return self._decoder.decode(bytearray(packet))
        except mavlink.MAVError:
            return None

    def _download(self, t0: float) -> DownloadStatus:
        self._publish(state="listing", message="asking the vehicle for its logs")
        entries = self._list()
        if self._cancel.is_set():
            return self._publish(state="cancelled", message="cancelled")
        if entries is None:
            return self._publish(
                state="failed",
                message=f"the vehicle did not answer LOG_REQUEST_LIST ({_LIST_TRIES} tries)",
                download_s=round(time.monotonic() - t0, 3),
            )
        listed = len(entries)
        if self.log_id is not None:
            entry = next((e for e in entries if e.id == self.log_id), None)
            if entry is None:
                ids = ", ".join(str(e.id) for e in entries) or "none"
                return self._publish(
                    state="no_log",
                    logs_listed=listed,
                    message=f"log {self.log_id} is not on the vehicle (it lists: {ids})",
                )
        else:
            entry = choose_log(entries, self.flight_end_utc)
            if entry is None:
                why = "the vehicle has no logs" if not entries else "no log covers the flight"
                return self._publish(state="no_log", logs_listed=listed, message=why)
        if entry.size_bytes > self.settings.max_bytes:
            return self._publish(
                state="failed",
                log_id=entry.id,
                size_bytes=entry.size_bytes,
                logs_listed=listed,
                message=f"log {entry.id} has {entry.size_bytes} bytes, more than "
                f"onboard_log.max_bytes ({self.settings.max_bytes})",
            )
        self._publish(
            state="downloading",
            log_id=entry.id,
            size_bytes=entry.size_bytes,
            logs_listed=listed,
            message=f"downloading log {entry.id}",
        )
        return self._fetch(entry, t0)

    def _list(self) -> list[LogEntry] | None:
        mav = self.link.mav
        entries: dict[int, LogEntry] = {}
        expected: int | None = None
        for _ in range(_LIST_TRIES):
            self.link.send(mav.log_request_list_encode(*self.target, 0, 0xFFFF))
            deadline = time.monotonic() + self.settings.request_timeout_s
            while not self._cancel.is_set():
                msg = self._next(max(deadline - time.monotonic(), 0.0))
                if msg is None:
                    break
                if msg.get_type() != "LOG_ENTRY":
                    continue
                expected = msg.num_logs
                if msg.num_logs > 0 and msg.id > 0:
                    entries[msg.id] = LogEntry(msg.id, msg.time_utc, msg.size)
                if len(entries) >= expected:
                    return sorted(entries.values(), key=lambda e: e.id)
                deadline = time.monotonic() + self.settings.request_timeout_s
            if self._cancel.is_set():
                return []
            if expected is not None:  # some entries lost on the way: what came will do
                return sorted(entries.values(), key=lambda e: e.id)
        return None

    def _fetch(self, entry: LogEntry, t0: float) -> DownloadStatus:
        s = self.settings
        self.folder.mkdir(parents=True, exist_ok=True)
        part = self.folder / PART_NAME
        ranges = _Ranges(entry.size_bytes)
        max_chunks = max(1, s.window_bytes // CHUNK_BYTES)
        # The window grows after one that came in whole with nothing lost, and halves when
        # the link loses the vehicle's packets (a receive buffer overflowing, a radio
        # full), pausing as long as the window took: the flight state's packets go first.
        window_chunks = min(max_chunks, _START_CHUNKS)
        mav = self.link.mav
        fd = os.open(part, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        re_requests = 0
        head = b""
        try:
            os.ftruncate(fd, entry.size_bytes)
            last_new = time.monotonic()
            next_publish = 0.0
            while not ranges.complete and not self._cancel.is_set():
                first = ranges.first_missing()
                assert first is not None
                chunks = ranges.missing_run(first, window_chunks)
                ofs = first * CHUNK_BYTES
                count = min(chunks * CHUNK_BYTES, entry.size_bytes - ofs)
                window_end = ofs + count
                # Counted before the request goes out: the link's thread may take in the
                # whole window (and count its losses) before this thread runs again.
                window_t0 = time.monotonic()
                lost_before = self.lost_packets
                self.link.send(mav.log_request_data_encode(*self.target, entry.id, ofs, count))
                deadline = window_t0 + s.request_timeout_s
                progressed = whole = False
                while not self._cancel.is_set():
                    msg = self._next(max(deadline - time.monotonic(), 0.0))
                    if msg is None:
                        break  # the window's rest is late or lost: ask again
                    if msg.get_type() != "LOG_DATA" or msg.id != entry.id:
                        continue
                    if msg.count == 0 and msg.ofs < entry.size_bytes:
                        return self._ended(
                            entry,
                            ranges,
                            t0,
                            re_requests,
                            f"the vehicle's log ends at byte {msg.ofs}, before its listed size",
                        )
                    n = min(msg.count, CHUNK_BYTES, max(entry.size_bytes - msg.ofs, 0))
                    if n > 0 and ranges.add(msg.ofs, n):
                        data = bytes(msg.data[:n])
                        os.pwrite(fd, data, msg.ofs)
                        if msg.ofs == 0:
                            head = data
                        progressed = True
                        last_new = time.monotonic()
                        deadline = last_new + s.request_timeout_s
                    now = time.monotonic()
                    if now >= next_publish:
                        next_publish = now + 0.2
                        self._publish(received_bytes=ranges.received, re_requests=re_requests)
                    nxt = ranges.first_missing(first)
                    if nxt is None or nxt * CHUNK_BYTES >= window_end:
                        whole = True
                        break  # the window is in: the next one
                if ranges.complete or self._cancel.is_set():
                    break
                if self.lost_packets > lost_before:
                    window_chunks = max(_MIN_CHUNKS, window_chunks // 2)
                    self._cancel.wait(min(time.monotonic() - window_t0, _MAX_PAUSE_S))
                elif whole:
                    window_chunks = min(max_chunks, window_chunks + _START_CHUNKS)
                nxt = ranges.first_missing(first)
                if not progressed or (nxt is not None and nxt * CHUNK_BYTES < window_end):
                    re_requests += 1
                if time.monotonic() - last_new > s.give_up_s:
                    os.fsync(fd)
                    return self._ended(
                        entry,
                        ranges,
                        t0,
                        re_requests,
                        f"no data for {s.give_up_s:.0f} s: the link did not come back",
                    )
            os.fsync(fd)
        finally:
            os.close(fd)
        if self._cancel.is_set() and not ranges.complete:
            return self._ended(entry, ranges, t0, re_requests, "cancelled", state="cancelled")
        name = log_file_name(head or _read_head(part))
        final = self.folder / name
        os.replace(part, final)
        size = final.stat().st_size
        ok = size == entry.size_bytes
        return self._publish(
            state="complete" if ok else "incomplete",
            received_bytes=ranges.received,
            file=name,
            re_requests=re_requests,
            download_s=round(time.monotonic() - t0, 3),
            message=f"log {entry.id}: {size} bytes"
            + ("" if ok else f", listed {entry.size_bytes}"),
        )

    def _ended(
        self,
        entry: LogEntry,
        ranges: _Ranges,
        t0: float,
        re_requests: int,
        why: str,
        state: State = "incomplete",
    ) -> DownloadStatus:
        """Stopped before every byte came: keep what came under the log's name (a
        partial log still reads up to its gaps), marked incomplete."""
        part = self.folder / PART_NAME
        name: str | None = None
        if ranges.received > 0 and part.exists():
            name = log_file_name(_read_head(part))
            os.replace(part, self.folder / name)
        else:
            part.unlink(missing_ok=True)
        return self._publish(
            state=state,
            received_bytes=ranges.received,
            file=name,
            re_requests=re_requests,
            download_s=round(time.monotonic() - t0, 3),
            message=f"log {entry.id}: {ranges.received} of {entry.size_bytes} bytes; {why}",
        )


def _read_head(path: Path) -> bytes:
    with path.open("rb") as f:
        return f.read(len(ULOG_MAGIC))
