"""The session's one writer thread: bounded buffers in, files out, flushed every half second.

Producers (the cameras' capture threads, the link thread's packet listener, and the
session's rows, which it puts from this thread before each batch) only append to bounded
deques and never wait; when a buffer is full the item is refused and counted, never
silently lost. The thread writes frames before rows, so a row on disk never names a
frame that is not on disk yet, flushes (and fdatasyncs) the CSVs and the tlog at least
every `flush_interval_s`, and stops the session with a reason when free space falls
under `min_free_bytes` or a write fails.

Frames go to one append-only file per camera, `<camera>/frames.mjpeg` (the frame pack,
`companion.recording.frame_pack`): per batch one `writev` of its JPEGs, then its
frames.csv rows (with each frame's `offset` in the pack) straight to the OS, then the
telemetry rows that name those frames. A file per frame cost a file creation each, 60 a
second: most of this thread's CPU (kernel time), and journal writes on a Pi's SD card.
So after a kill every telemetry row on disk names a frame frames.csv lists, and only the
batch being written can have pack bytes without rows (recovery cuts them off).

The thread writes in batches, every `batch_interval_s` (0.5 s, the flush interval): a
producer does not wake it per item (60 frames, 30 rows and 140 packets a second were as
many wake-ups, each a futex call and a pass over every queue), only when its queue is
half full. The telemetry CSVs sit in their file buffers until the flush anyway, so a
batch as long as the flush interval loses nothing to a kill that the telemetry would not:
frames and telemetry alike, at most the last half second. Each batch costs the thread
its system calls (a writev per camera, frames.csv, the CSVs) and the GIL back after each,
so fewer, longer batches cost the thread less (benchmarks/pi_budget.py,
docs/PERFORMANCE.md). At each flush the packs
and frames.csv files are fdatasync'ed before telemetry.csv and the tlog, so a power cut
keeps them in the same order.
"""

from __future__ import annotations

import csv
import errno
import logging
import os
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from fpv_station.companion.recording import diskspace, layout
from fpv_station.companion.recording.rows import RowFormatter, Sample, message_rows
from fpv_station.companion.video_frame import Frame
from fpv_station.core.mavlink.tlog_records import encode_record

log = logging.getLogger(__name__)

# What the writer thread takes from its queues at once: frames by camera, rows, packets.
_Frames = dict[str, deque[Frame]]
_Rows = deque[Sample]
_Packets = deque[tuple[float, bytes]]


@dataclass
class WriterStats:
    rows_written: int = 0
    rows_dropped: int = 0
    packets_written: int = 0
    packets_dropped: int = 0
    frames_written: dict[str, int] = field(default_factory=dict)
    frames_dropped_queue: dict[str, int] = field(default_factory=dict)
    first_seq: dict[str, int] = field(default_factory=dict)
    last_seq: dict[str, int] = field(default_factory=dict)
    first_frame_mono: dict[str, float] = field(default_factory=dict)
    last_frame_mono: dict[str, float] = field(default_factory=dict)
    last_row_mono: float | None = None
    last_row_wall: float | None = None
    bytes_written: int = 0


@dataclass(frozen=True, slots=True)
class WriterLimits:
    row_queue: int = 2000
    frame_queue: int = 90  # per camera: 3 s at 30 fps
    packet_queue: int = 20000
    flush_interval_s: float = 0.5
    batch_interval_s: float = 0.5  # queued items wait at most this long for the thread
    min_free_bytes: int = 200 * 1024 * 1024


class SessionWriter:
    def __init__(
        self,
        folder: Path,
        formatter: RowFormatter,
        limits: WriterLimits = WriterLimits(),
        on_flush: Callable[[WriterStats], None] | None = None,
        on_failure: Callable[[str], None] | None = None,
        before_batch: Callable[[], None] | None = None,
    ) -> None:
        """`before_batch`: called in the thread before each batch is taken (a live
        session puts the rows of the instants up to now: companion.recording.session)."""
        self.folder = folder
        self.cameras = formatter.cameras
        self.formatter = formatter
        self.limits = limits
        self.stats = WriterStats(
            frames_written=dict.fromkeys(self.cameras, 0),
            frames_dropped_queue=dict.fromkeys(self.cameras, 0),
        )
        self.failure: str | None = None  # why writing stopped early, if it did
        self._on_flush = on_flush
        self._on_failure = on_failure
        self._before_batch = before_batch
        self._cond = threading.Condition()
        self._rows: deque[Sample] = deque()
        self._packets: deque[tuple[float, bytes]] = deque()
        self._frames: dict[str, deque[Frame]] = {c: deque() for c in self.cameras}
        self._closing = False
        self._thread = threading.Thread(target=self._run, name="recorder-writer", daemon=True)
        self._files: list[IO[Any]] = []
        try:
            self._open_files()
        except BaseException:  # EMFILE, a full disk: no descriptor may outlive the failed start
            self._close_files()
            raise

    # -- producers (any thread; never block) ---------------------------------------------

    def put_row(self, sample: Sample) -> bool:
        with self._cond:
            if self.failure is not None or len(self._rows) >= self.limits.row_queue:
                self.stats.rows_dropped += 1
                return False
            self._rows.append(sample)
            if len(self._rows) == self.limits.row_queue // 2:
                self._cond.notify_all()  # half full: the writer now, not at its next batch
        return True

    def put_frame(self, camera: str, frame: Frame) -> bool:
        with self._cond:
            q = self._frames[camera]
            if self.failure is not None or len(q) >= self.limits.frame_queue:
                self.stats.frames_dropped_queue[camera] += 1
                return False
            q.append(frame)
            if len(q) == self.limits.frame_queue // 2:
                self._cond.notify_all()  # half full: the writer now, not at its next batch
        return True

    def put_packet(self, t_wall: float, packet: bytes) -> bool:
        with self._cond:
            if self.failure is not None or len(self._packets) >= self.limits.packet_queue:
                self.stats.packets_dropped += 1
                return False
            self._packets.append((t_wall, packet))
            if len(self._packets) == self.limits.packet_queue // 2:
                self._cond.notify_all()  # half full: the writer now, not at its next batch
        return True

    def wait_for_room(self, timeout: float = 5.0) -> None:
        """For a producer that can wait (a replay or the twin on its own clock): return
        when no queue (rows, packets, a camera's frames) is half full, or after `timeout`."""
        with self._cond:
            self._cond.wait_for(
                lambda: self.failure is not None or self._closing or not self._half_full(),
                timeout,
            )

    # -- lifecycle -----------------------------------------------------------------------

    def start(self) -> None:
        self._thread.start()

    def write_now(self) -> None:
        """Write what is queued, on the caller's thread. For a producer that never starts
        the thread (a benchmark timing the rest apart) and calls this so the queues stay
        short."""
        with self._cond:
            taken = self._take()
        self._write_or_count(*taken)

    @property
    def native_id(self) -> int | None:
        return self._thread.native_id

    def close(self, patience_s: float = 10.0) -> None:
        """Write what is buffered, flush, close the files; returns when the thread is done.

        However long that takes: a card can stall a write for seconds, and closing the
        files under the thread would lose what it still holds, uncounted, and kill it on a
        closed file. A stall longer than `patience_s` is logged (again at each multiple);
        a disk that never answers is the service manager's to end (a kill, which the
        next start's recovery counts)."""
        with self._cond:
            self._closing = True
            self._cond.notify_all()  # the writer thread (and a producer waiting for room)
        waited = 0.0
        while self._thread.is_alive():
            self._thread.join(patience_s)
            if self._thread.is_alive():
                waited += patience_s
                log.warning("%s: the writer is still writing after %.1f s", self.folder, waited)
        self._close_files()

    # -- the thread ------------------------------------------------------------------------

    def _open_files(self) -> None:
        f = self.folder
        self._csv_file = self._kept(
            open(f / layout.TELEMETRY_CSV, "w", newline="", buffering=1 << 16)
        )
        self._csv_file.write(self.formatter.header_line())
        self._tlog = self._kept(open(f / layout.MAVLINK_TLOG, "wb", buffering=1 << 16))
        self._messages_file = self._kept(
            open(f / layout.MESSAGES_CSV, "w", newline="", buffering=1 << 12)
        )
        self._messages_csv = csv.writer(self._messages_file)
        self._messages_csv.writerow(layout.MESSAGE_COLUMNS)
        self._messages_seen: int | None = None  # the state's message count at the last row
        self._frames_csv = {}
        self._frames_csv_file = {}
        self._pack: dict[str, IO[bytes]] = {}
        self._pack_end: dict[str, int] = {}  # bytes in each pack: the next frame's offset
        for cam in self.cameras:
            (f / cam).mkdir(exist_ok=True)
            fc = self._kept(
                open(f / layout.frames_csv_relpath(cam), "w", newline="", buffering=1 << 14)
            )
            self._frames_csv_file[cam] = fc
            self._frames_csv[cam] = csv.writer(fc)
            self._frames_csv[cam].writerow(layout.FRAME_COLUMNS)
            # Unbuffered and O_APPEND: each batch is one writev straight to the file.
            self._pack[cam] = self._kept(
                open(f / layout.frames_pack_relpath(cam), "ab", buffering=0)
            )
            self._pack_end[cam] = 0
        self._flush_files()

    def _kept(self, file: IO[Any]) -> IO[Any]:
        """`file`, listed for closing as soon as it is open (a failed start closes it too)."""
        self._files.append(file)
        return file

    def _run(self) -> None:
        interval = self.limits.flush_interval_s
        next_flush = time.monotonic() + interval
        next_batch = time.monotonic() + self.limits.batch_interval_s
        while True:
            with self._cond:
                while not self._closing and not self._half_full():
                    wait_s = min(next_batch, next_flush) - time.monotonic()
                    if wait_s <= 0:
                        break
                    self._cond.wait(wait_s)
                next_batch = time.monotonic() + self.limits.batch_interval_s
                closing = self._closing
            if self._before_batch is not None:
                try:
                    self._before_batch()  # outside the lock: it puts rows
                except Exception:  # the frames and packets are written whatever it does
                    log.exception("%s: taking the batch's rows failed", self.folder)
            with self._cond:
                taken = self._take()
                self._cond.notify_all()  # room again for a producer in wait_for_room
            self._write_or_count(*taken)
            now = time.monotonic()
            if closing or now >= next_flush:
                next_flush = now + interval
                self._flush_and_check()
            if closing:
                with self._cond:
                    if not self._rows and not self._packets and not any(self._frames.values()):
                        return

    def _half_full(self) -> bool:
        """A queue that should not wait for the next batch (call holding `_cond`)."""
        lim = self.limits
        return (
            len(self._rows) >= lim.row_queue // 2
            or len(self._packets) >= lim.packet_queue // 2
            or any(len(q) >= lim.frame_queue // 2 for q in self._frames.values())
        )

    def _take(self) -> tuple[_Frames, _Rows, _Packets]:
        """Everything queued, leaving the queues empty (call holding `_cond`)."""
        rows, self._rows = self._rows, deque()
        packets, self._packets = self._packets, deque()
        frames = {c: q for c, q in self._frames.items() if q}
        for c in frames:
            self._frames[c] = deque()
        return frames, rows, packets

    def _write_or_count(self, frames: _Frames, rows: _Rows, packets: _Packets) -> None:
        if self.failure is None:
            try:
                self._write(frames, rows, packets)
            except OSError as exc:
                self._fail(_describe_os_error(exc))
                self._count_lost(frames, rows, packets)  # what the failed write left
        else:
            self._count_lost(frames, rows, packets)

    def _write(self, frames: _Frames, rows: _Rows, packets: _Packets) -> None:
        # The frames first (pack, then frames.csv rows, both out to the OS): the rows name
        # them, and a full CSV buffer reaches the OS in the middle of a batch, so rows
        # written first could be on disk (and left there by a kill) naming frames that are
        # not. The telemetry is written even when a frame's write fails: a broken camera
        # folder must not take the batch's rows and packets with it (the frames are
        # counted lost from where it failed).
        try:
            self._write_frames(frames)
        finally:
            self._write_telemetry(rows, packets)

    def _write_telemetry(self, rows: deque[Sample], packets: deque[tuple[float, bytes]]) -> None:
        st = self.stats
        if packets:
            data = b"".join(encode_record(t_wall, packet) for t_wall, packet in packets)
            self._tlog.write(data)
            st.packets_written += len(packets)
            st.bytes_written += len(data)
            packets.clear()
        while rows:
            sample = rows[0]
            self._csv_file.write(self.formatter.line(sample))
            if sample.state is not None:
                self._write_messages(sample)
            rows.popleft()
            st.rows_written += 1
            st.last_row_mono = sample.t_mono
            st.last_row_wall = sample.t_wall

    def _write_frames(self, frames: dict[str, deque[Frame]]) -> None:
        """Per camera: the batch's JPEGs to its pack in one writev, then their rows to
        frames.csv, flushed to the OS before the telemetry rows that name them. A frame
        counts as written once its row is out; a failure leaves the rest of the queue to
        be counted lost (and the pack's unlisted tail to the census)."""
        st = self.stats
        t0 = self.formatter.t0_mono
        for cam, q in frames.items():
            if not q:
                continue
            start = offset = self._pack_end[cam]
            _write_all(self._pack[cam].fileno(), [frame.jpeg for frame in q])
            rows = []
            for frame in q:
                size = len(frame.jpeg)
                rows.append(
                    (
                        frame.seq,
                        layout.frame_relpath(cam, frame.seq),
                        round(frame.t_mono - t0, 6),
                        round(frame.t_wall, 6),
                        frame.width,
                        frame.height,
                        size,
                        offset,
                    )
                )
                offset += size
            self._pack_end[cam] = offset
            self._frames_csv[cam].writerows(rows)
            self._frames_csv_file[cam].flush()
            st.frames_written[cam] += len(q)
            st.bytes_written += offset - start
            st.first_seq.setdefault(cam, q[0].seq)
            st.first_frame_mono.setdefault(cam, q[0].t_mono)
            st.last_seq[cam] = q[-1].seq
            st.last_frame_mono[cam] = q[-1].t_mono
            q.clear()

    def _write_messages(self, sample: Sample) -> None:
        """The vehicle's messages that arrived since the previous row (messages.csv)."""
        rows, self._messages_seen = message_rows(
            sample, self._messages_seen, self.formatter.t0_mono
        )
        self._messages_csv.writerows(rows)

    def _count_lost(self, frames: _Frames, rows: _Rows, packets: _Packets) -> None:
        with self._cond:
            for cam, q in frames.items():
                self.stats.frames_dropped_queue[cam] += len(q)
            self.stats.rows_dropped += len(rows)
            self.stats.packets_dropped += len(packets)
        for q in frames.values():
            q.clear()
        rows.clear()
        packets.clear()

    def _flush_and_check(self) -> None:
        if self.failure is None:
            try:
                self._flush_files()
            except OSError as exc:
                self._fail(_describe_os_error(exc))
        if self.failure is None:
            try:
                free = diskspace.free_bytes(self.folder)
            except OSError as exc:
                free = None
                log.warning("cannot probe free space of %s: %s", self.folder, exc)
            if free is not None and free < self.limits.min_free_bytes:
                self._fail(
                    f"disk full: {free / 1e6:.1f} MB free, under the "
                    f"{self.limits.min_free_bytes / 1e6:.0f} MB minimum"
                )
        if self._on_flush is not None:
            try:
                self._on_flush(self.stats)
            except Exception:  # a metadata write must not kill the writer
                log.exception("session metadata update failed")

    def _flush_files(self) -> None:
        for f in self._files:
            if not f.closed:
                f.flush()
        # fdatasync the append-only files so a power cut keeps them to the last flush: the
        # packs and their frames.csv first, so that the telemetry rows synced after them
        # name frames that are on disk.
        synced = [*self._pack.values(), *self._frames_csv_file.values()]
        for f in (*synced, self._csv_file, self._tlog):
            if not f.closed:
                _sync(f.fileno())

    def _fail(self, reason: str) -> None:
        if self.failure is not None:
            return
        self.failure = reason
        log.error("recording stopped: %s", reason)
        if self._on_failure is not None:
            try:
                self._on_failure(reason)
            except Exception:
                log.exception("recording failure callback failed")

    def _close_files(self) -> None:
        for f in self._files:
            try:
                f.close()
            except OSError as exc:  # the last flush of a full disk
                log.warning("closing %s: %s", getattr(f, "name", f), exc)


def _sync(fd: int) -> None:
    """fdatasync `fd`; a file that cannot be synced (EINVAL: a pipe, a special file) has
    nothing on a disk to keep."""
    try:
        os.fdatasync(fd)
    except OSError as exc:
        if exc.errno != errno.EINVAL:
            raise


def _write_all(fd: int, chunks: list[bytes]) -> None:
    """Append `chunks` to `fd` in one writev (one system call a batch, not one a frame);
    a short write (a signal, a nearly full disk) goes on with what is left."""
    for i in range(0, len(chunks), _IOV_MAX):
        part = chunks[i : i + _IOV_MAX]
        done = os.writev(fd, part)
        if done < sum(len(c) for c in part):
            view = memoryview(b"".join(part))[done:]
            while view:
                view = view[os.write(fd, view) :]


_IOV_MAX = 1024  # Linux's limit of buffers per writev (a batch is at most frame_queue)


def _describe_os_error(exc: OSError) -> str:
    if exc.errno in (errno.ENOSPC, errno.EDQUOT):
        return f"disk full: {exc.strerror}"
    return f"write error: {exc}"
