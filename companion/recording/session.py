"""One recording session: listeners on the state and camera slots, one writer thread.

Inputs are exactly the station's objects: the vehicle state `Latest[VehicleState]`, each
camera's `Latest[Frame]`, and raw packets pushed into `on_packet(t_wall, packet)` by the
link's thread. Every frame a camera publishes reaches the writer through `_offer_frame`,
called in the camera's capture thread by a publish listener on its slot (so a starved
event loop loses no frame); a frame is queued once, and gaps in sequence numbers are
counted as missed frames.

Telemetry rows sit on a fixed grid (`rate_hz` from the session's start), each with the
state and the frames that were newest at its instant. A live session keeps what each
slot held and since when: its state listener notes each state with the time it was
published, and each accepted frame carries its capture time (`Frame.t_mono`, the
station's monotonic clock, the session's). The writer thread, at each of its batches,
turns the instants up to now into rows (`_sample_due`): the same rows a thread waking at
every instant took, without its 30 wake-ups a second (docs/PERFORMANCE.md), and
each at its exact instant. A row names the newest frame captured at or before its
instant, never one captured after it, however late the threads run: frames are chosen by
their capture time, not by when they reached the session, and a row waits until every
camera has published a frame captured after its instant (or `FRAME_SETTLE_S` has passed:
a stalled camera does not hold the rows), so a frame still being encoded is not skipped.
What the slots held when the session's clock started is what its first rows name. A
source on its own clock (a replay) is sampled from its thread instead (`advance`).
"""

from __future__ import annotations

import asyncio
import functools
import logging
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fpv_station.companion.latest import Latest, Versioned
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.flags import QUALITY_THRESHOLDS
from fpv_station.companion.recording.meta import (
    Arming,
    CameraQuality,
    Demonstration,
    Missed,
    Quality,
    SessionClock,
    SessionMeta,
    SessionTask,
    write_meta,
)
from fpv_station.companion.recording.ondisk import apply_census, take_census
from fpv_station.companion.recording.quality import LinkLossTracker, SkewStats
from fpv_station.companion.recording.rows import FrameRef, RowFormatter, Sample
from fpv_station.companion.recording.session_clock import (
    DEFAULT_MAX_DISAGREE_S,
    choose_session_clock,
)
from fpv_station.companion.recording.store import create_session_dir, discard_session_dir
from fpv_station.companion.recording.writer import SessionWriter, WriterLimits, WriterStats
from fpv_station.companion.source_clock import SourceClock
from fpv_station.companion.system_clock import clock_synchronised
from fpv_station.companion.timesync import TimeSync
from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.companion.video_frame import Frame

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SessionConfig:
    rate_hz: float = 30.0
    limits: WriterLimits = WriterLimits()
    link_lost_s: float = 2.0
    source: str = "unknown"
    software_version: str = "unknown"
    settings: Mapping[str, Any] = field(default_factory=dict)
    camera_fps: Mapping[str, float | None] = field(default_factory=dict)
    meta_interval_s: float = 2.0
    clock_max_disagree_s: float = DEFAULT_MAX_DISAGREE_S
    # States a live session keeps between the writer's batches (0.5 s apart; about 40 s
    # of the link's 100 a second): a writer held up longer by its disk skips the rows it
    # cannot know, counted in telemetry_ticks_late.
    state_history: int = 4096


# The frames the writer accepted, per camera, that a live session keeps between the
# writer's batches (the writer's queue holds 90, so this is never reached).
FRAME_HISTORY = 1024
# How long a row waits for each camera to publish a frame captured after its instant
# (a camera publishes its frames in capture order, each after its encode), before it takes
# the newest frame there is: longer than an encode on a loaded Pi, short beside the
# writer's state history.
FRAME_SETTLE_S = 1.0


class _CameraTrack:
    """What the session knows about one camera's frames (guarded by its lock)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.first_seq: int | None = None  # first frame offered to the writer
        self.last_seq: int | None = None  # newest frame offered to the writer
        self.ref: FrameRef | None = None  # newest frame accepted by the writer
        self.missed = 0
        self.skew = SkewStats()
        # Frames accepted before the writer runs (the session's first moments), and
        # how many more it refused then, as its full queue would have.
        self.early: list[Frame] | None = []
        self.early_refused = 0
        # Live sessions: each accepted frame, in capture order, until a row's instant
        # passes its capture time (`row_ref`: the newest one at the last row's instant),
        # and the capture time of the newest frame the camera published while it delivers
        # frames (frames the writer refused included): no frame captured before it is to
        # come. None before its first frame and while it shows NO SIGNAL: rows do not
        # wait for it.
        self.published: deque[FrameRef] = deque(maxlen=FRAME_HISTORY)
        self.row_ref: FrameRef | None = None
        self.seen_mono: float | None = None


class RecordingSession:
    def __init__(
        self,
        root: Path,
        state: Latest[VehicleState],
        cameras: Mapping[str, Latest[Frame]],
        config: SessionConfig,
        trigger: str = "api",
        on_failure: Callable[[str, str], None] | None = None,
        clock: SourceClock | None = None,
        task: SessionTask | None = None,
        demonstration: Demonstration | None = None,
        recorded_until_wall: float | None = None,
        missed_reason: str | None = None,
        timesync: TimeSync | None = None,
    ) -> None:
        """`recorded_until_wall`: the end of the station's previous session, and
        `missed_reason` why none recorded since, for a session that starts in mid-flight
        (`SessionMeta.missed`)."""
        self.config = config
        self.trigger = trigger
        self.task = task  # the flight task chosen when the session started
        self.demonstration = demonstration  # who flew it, when flown as a demonstration
        self._timesync = timesync  # the vehicle's boot clock, measured by the link
        self._state = state
        self._camera_slots = dict(cameras)
        self.cameras: tuple[str, ...] = tuple(cameras)
        # A source on its own clock (a replay) is sampled in its time, by `advance` from
        # its thread; any other by the sampler thread on the station's clock.
        self.clock = clock or SourceClock()
        live = not self.clock.own
        self._tracks = {c: _CameraTrack() for c in self.cameras}
        self._stop_mono: float | None = None  # the last row's instant, once stopping
        self._frame_listeners: dict[str, Callable[[Frame], None]] = {}
        # Live sessions: each state published since the last row's instant, with when
        # (the slot listener `_note_state`, the link's thread), and the state at that
        # instant; `_states_lost_until`: the newest time a full history let go of.
        self._states: deque[tuple[float, VehicleState]] = deque(maxlen=config.state_history)
        self._states_lost_until: float | None = None
        # The listeners take every state and frame from before the clock starts: what
        # the slots hold then is what the first rows name (none of it from their future),
        # and nothing published while the files open is lost.
        # One bound method, added and removed: the slot removes a listener by identity,
        # and each `self._note_state` is a new object.
        self._state_listener: Callable[[VehicleState], None] = self._note_state
        if live:
            self._state.add_listener(self._state_listener)
        for cam, slot in self._camera_slots.items():
            listener = functools.partial(self._take_frame, cam)
            self._frame_listeners[cam] = listener
            slot.add_listener(listener)
            held_frame = slot.get()
            if held_frame is not None:
                self._offer_frame(cam, held_frame.value)
        held = self._state.get()
        self._row_state: VehicleState | None = held.value if live and held is not None else None
        self.t0_wall = self.clock.wall()
        self.t0_mono = self.clock.mono()
        self._next_sample = self.t0_mono
        self._missed = _missed(held, self.t0_mono, self.t0_wall, recorded_until_wall, missed_reason)
        self._station_synced = None if self.clock.own else clock_synchronised()
        naming = self._choose_clock()
        try:
            self.id, self.folder = create_session_dir(
                root, self.t0_wall + naming.offset_s, config.source
            )
        except BaseException:  # EMFILE, a full disk: the listeners go with the start
            self._drop_listeners()
            raise
        self._named_by = naming.used
        self._links = LinkLossTracker(self.t0_mono, config.link_lost_s)
        self._gaps = LinkLossTracker(self.t0_mono, QUALITY_THRESHOLDS.telemetry_gap_s)
        self._arming: Arming | None = None
        self._was_armed: bool | None = None
        self.ticks_late = 0  # row instants skipped: the writer fell behind the state history
        self.stop_reason: str | None = None
        self.end_wall: float | None = None
        self._on_failure = on_failure
        self._meta_lock = threading.Lock()
        self._next_meta_mono = 0.0
        formatter = RowFormatter(self.cameras, self.t0_mono)
        try:
            self.writer = SessionWriter(
                self.folder,
                formatter,
                config.limits,
                on_flush=self._on_flush,
                on_failure=self._writer_failed,
                before_batch=None if self.clock.own else self._sample_due,
            )
        except BaseException:
            # Nothing was recorded (EMFILE, a full disk): no empty folder may stay behind
            # as an "unreadable" session, one more at each of the recorder's retries.
            self._drop_listeners()
            discard_session_dir(self.folder, self.cameras)
            raise
        self._write_meta(layout.STATUS_RECORDING)

    # -- lifecycle -----------------------------------------------------------------------

    def start(self) -> None:
        """Start the writer, with the frames taken since before the clock started."""
        self.writer.start()
        for cam, track in self._tracks.items():
            with track.lock:
                early, track.early = track.early or [], None
                for frame in early:
                    self.writer.put_frame(cam, frame)  # an empty queue: room for each
                self.writer.stats.frames_dropped_queue[cam] += track.early_refused

    async def stop(self, reason: str) -> SessionMeta:
        """Stop sampling, write what is buffered, close the files, finalize session.json."""
        if self.stop_reason is None:
            self.stop_reason = reason
        self._end_sampling()
        self._drop_listeners()
        return await asyncio.to_thread(self._finish)

    def _end_sampling(self) -> None:
        if self._stop_mono is None:
            self._stop_mono = self.clock.mono()

    def _finish(self) -> SessionMeta:
        self.writer.close()
        self.end_wall = self.writer.stats.last_row_wall or self.clock.wall()
        if self.writer.failure is None:
            meta = self.meta(layout.STATUS_COMPLETE)
        else:
            # A failed write (a full disk) loses what the files' buffers held, which the
            # writer had counted: the report says what the files hold, and that it was cut.
            meta = self.meta(layout.STATUS_CUT_SHORT)
            try:
                census = take_census(self.folder, list(self.cameras), self.t0_wall)
            except OSError as exc:  # EIO, EMFILE: the writer's counts stand (no `recovery`)
                log.warning("cannot count the files of session %s: %s", self.id, exc)
            else:
                apply_census(meta, census, layout.utc_label())
        self._save(meta)
        return meta

    def frames_dropped(self) -> dict[str, int]:
        """Per camera: frames captured but not (going to be) on disk, so far."""
        queue = self.writer.stats.frames_dropped_queue
        return {c: self._tracks[c].missed + queue.get(c, 0) for c in self.cameras}

    def thread_ids(self) -> dict[str, int | None]:
        """Native ids of the session's threads (for CPU accounting in benchmarks)."""
        return {"writer": self.writer.native_id}

    # -- inputs ----------------------------------------------------------------------------

    def on_packet(self, t_wall: float, packet: bytes) -> None:
        """The link's packet listener (link thread): never blocks."""
        self.writer.put_packet(t_wall, packet)

    def _offer_frame(self, cam: str, frame: Frame) -> FrameRef | None:
        """Queue `frame` if it is new; returns the camera's newest accepted frame. A live
        session keeps an accepted frame for the rows of the instants from its capture."""
        track = self._tracks[cam]
        with track.lock:
            if track.last_seq is not None and frame.seq <= track.last_seq:
                return track.ref  # a frame already offered
            if not frame.signal:
                track.seen_mono = None  # a placeholder: the camera has nothing newer
                return track.ref
            if track.last_seq is not None:
                track.missed += frame.seq - track.last_seq - 1
            else:
                track.first_seq = frame.seq
            track.last_seq = frame.seq
            early = track.early
            if early is None:
                accepted = self.writer.put_frame(cam, frame)
            else:  # the writer is not running yet: held for it, within its queue's bound
                accepted = len(early) < self.config.limits.frame_queue
                if accepted:
                    early.append(frame)
                else:
                    track.early_refused += 1
            if accepted:
                track.ref = FrameRef(frame.seq, frame.t_mono, frame.t_wall)
                if not self.clock.own:
                    track.published.append(track.ref)
            # Last: the writer reads it without the lock, and a row it lets through must
            # find this frame among the published ones.
            track.seen_mono = frame.t_mono
            return track.ref

    def _take_frame(self, cam: str, frame: Frame) -> None:
        """The camera slot's publish listener (the capture thread): never blocks."""
        if self._stop_mono is not None:
            return
        try:
            self._offer_frame(cam, frame)
        except Exception:  # the camera's thread must go on whatever the recorder does
            log.exception("recording frame %s of %s failed", frame.seq, cam)

    def _note_state(self, state: VehicleState) -> None:
        """The state slot's publish listener (the link's thread), live sessions: the state
        and when, for the rows of the instants it holds for. Never blocks."""
        states = self._states
        if len(states) == states.maxlen:  # the writer is far behind: the oldest goes
            try:
                self._states_lost_until = states[0][0]
            except IndexError:  # the writer emptied it meanwhile: nothing goes
                pass
        states.append((time.monotonic(), state))

    def _drop_listeners(self) -> None:
        self._state.remove_listener(self._state_listener)
        for cam, listener in self._frame_listeners.items():
            self._camera_slots[cam].remove_listener(listener)
        self._frame_listeners.clear()

    # -- rows ----------------------------------------------------------------------------

    def _sample_due(self) -> None:
        """A live session's rows for every grid instant up to now whose frames are all
        known (up to the stop, once stopping), each with the state and frames that were
        newest at its instant. Called by the writer thread before each batch, so the rows
        are written with the frames they name."""
        period = 1.0 / self.config.rate_hz
        now = time.monotonic()
        end = self._stop_mono if self._stop_mono is not None else self._settled_until(now)
        wall_offset = time.time() - now
        while self._next_sample <= end:
            t = self._next_sample
            self._next_sample += period
            if self._state_lost_at(t):
                self.ticks_late += 1  # as a sampler that ran late: no row rather than a wrong one
                continue
            refs = tuple(self._frame_at(cam, t) for cam in self.cameras)
            try:
                self._row(t, t + wall_offset, self._state_at(t), refs)
            except Exception:  # one bad sample must not end the recording
                log.exception("telemetry sample failed")

    def _settled_until(self, now: float) -> float:
        """The newest instant whose frames are all known: every camera delivering frames
        has published one captured at or after it (one captured before it cannot come
        any more), or it is `FRAME_SETTLE_S` old."""
        settled = now
        for track in self._tracks.values():
            seen = track.seen_mono
            if seen is not None:
                settled = min(settled, max(seen, now - FRAME_SETTLE_S))
        return settled

    def _state_lost_at(self, t: float) -> bool:
        """The history let go of what may have held at `t` (the writer was stalled)."""
        if self._states_lost_until is None:
            return False
        if self._states and t < self._states[0][0]:
            return True
        self._states_lost_until = None
        return False

    def _state_at(self, t: float) -> VehicleState | None:
        """The newest state published at or before `t` (the last row's if none came since)."""
        states = self._states
        while states and states[0][0] <= t:
            self._row_state = states.popleft()[1]
        return self._row_state

    def _frame_at(self, cam: str, t: float) -> FrameRef | None:
        """The newest accepted frame of `cam` captured at or before `t`."""
        track = self._tracks[cam]
        published = track.published
        while published and published[0].t_mono <= t:
            track.row_ref = published.popleft()
        return track.row_ref

    def advance(self, t: float) -> None:
        """The source's clock reached `t`: the rows of every instant before it (source's
        thread; the state is the one that held until `t`). Waits while the writer is
        behind, so that a replay at full speed loses no row."""
        period = 1.0 / self.config.rate_hz
        while self._next_sample < t and self._stop_mono is None:
            self.writer.wait_for_room()
            try:
                self._sample(self._next_sample, self._next_sample)
            except Exception:
                log.exception("telemetry sample failed")
            self._next_sample += period

    def _sample(self, now_mono: float, now_wall: float) -> None:
        """The row of `now_mono` on a source's own clock: what the slots hold now."""
        versioned = self._state.get()
        state = versioned.value if versioned is not None else None
        refs: list[FrameRef | None] = []
        for cam in self.cameras:
            current = self._camera_slots[cam].get()
            ref = (
                self._offer_frame(cam, current.value)
                if current is not None
                else self._tracks[cam].ref
            )
            refs.append(ref)
        self._row(now_mono, now_wall, state, tuple(refs))

    def _row(
        self,
        now_mono: float,
        wall: float,
        state: VehicleState | None,
        refs: tuple[FrameRef | None, ...],
    ) -> None:
        for cam, ref in zip(self.cameras, refs, strict=True):
            if ref is not None:
                self._tracks[cam].skew.add(now_mono - ref.t_mono)
        self.writer.put_row(Sample(now_mono, wall, state, refs))
        # Link loss is about the autopilot: a radio's or another ground station's packets
        # keep arriving while the vehicle is silent, so only the autopilot's messages count.
        last_heard = state.last_heard_mono() if state is not None else None
        self._links.update(now_mono, last_heard)
        self._gaps.update(now_mono, last_heard)
        if state is not None:
            self._note_arming(state, now_mono)

    def _note_arming(self, state: VehicleState, now_mono: float) -> None:
        armed = state.heartbeat.armed
        alt = state.altitude
        if armed and alt.reference.startswith("arming") and alt.reference_alt_m is not None:
            if (
                self._arming is None
                or self._was_armed is False
                or self._arming.reference_alt_m != alt.reference_alt_m
                or self._arming.altitude_source != alt.source
            ):
                self._arming = Arming(
                    t_s=round(now_mono - self.t0_mono, 3),
                    reference_alt_m=alt.reference_alt_m,
                    home_lat_deg=alt.home_lat_deg,
                    home_lon_deg=alt.home_lon_deg,
                    altitude_source=alt.source,
                )
        self._was_armed = armed

    # -- metadata ------------------------------------------------------------------------------

    def _writer_failed(self, reason: str) -> None:
        if self.stop_reason is None:
            self.stop_reason = reason
        self._end_sampling()  # no rows after now; the owner finalizes through stop()
        if self._on_failure is not None:
            self._on_failure(self.id, reason)

    def _on_flush(self, stats: WriterStats) -> None:
        now = time.monotonic()
        if now >= self._next_meta_mono and not self.writer.failure:
            self._next_meta_mono = now + self.config.meta_interval_s
            self._write_meta(layout.STATUS_RECORDING)

    def _write_meta(self, status: str) -> None:
        self._save(self.meta(status))

    def _save(self, meta: SessionMeta) -> None:
        with self._meta_lock:
            try:
                write_meta(self.folder / layout.SESSION_JSON, meta)
            except OSError as exc:
                log.warning("cannot write %s: %s", self.folder / layout.SESSION_JSON, exc)

    def _choose_clock(self) -> SessionClock:
        """The session's UTC (companion.recording.session_clock). Chosen again at each
        session.json write: a GPS time first heard mid-session corrects the stamps."""
        current = self._state.get()
        return choose_session_clock(
            self.t0_wall,
            self.t0_mono,
            self._station_synced,
            current.value.utc if current is not None else None,
            replay=self.clock.own,
            max_disagree_s=self.config.clock_max_disagree_s,
        )

    def meta(self, status: str) -> SessionMeta:
        st = self.writer.stats
        boot = None if self._timesync is None else self._timesync.report().shifted(self.t0_mono)
        utc = self._choose_clock().model_copy(
            update={"named_by": self._named_by, "vehicle_boot": boot}
        )
        end_wall = self.end_wall if status != layout.STATUS_RECORDING else st.last_row_wall
        duration = None if end_wall is None else round(end_wall - self.t0_wall, 3)
        cams: dict[str, CameraQuality] = {}
        for cam in self.cameras:
            track = self._tracks[cam]
            written = st.frames_written.get(cam, 0)
            first, last = st.first_frame_mono.get(cam), st.last_frame_mono.get(cam)
            achieved = (
                round((written - 1) / (last - first), 3)
                if written > 1 and first is not None and last is not None and last > first
                else None
            )
            dropped_q = st.frames_dropped_queue.get(cam, 0)
            cams[cam] = CameraQuality(
                configured_fps=self.config.camera_fps.get(cam),
                achieved_fps=achieved,
                frames_captured=(
                    0
                    if track.first_seq is None or track.last_seq is None
                    else track.last_seq - track.first_seq + 1
                ),
                frames_written=written,
                frames_missed=track.missed,
                frames_dropped_queue=dropped_q,
                frames_dropped=track.missed + dropped_q,
                first_seq=st.first_seq.get(cam),
                last_seq=st.last_seq.get(cam),
                skew_max_s=_round(track.skew.max_s()),
                skew_p99_s=_round(track.skew.p99_s()),
            )
        span = (st.last_row_mono - self.t0_mono) if st.last_row_mono is not None else None
        quality = Quality(
            telemetry_rate_hz=self.config.rate_hz,
            telemetry_rows=st.rows_written,
            telemetry_achieved_hz=(
                round((st.rows_written - 1) / span, 3) if span and st.rows_written > 1 else None
            ),
            telemetry_rows_dropped=st.rows_dropped,
            telemetry_ticks_late=self.ticks_late,
            tlog_packets=st.packets_written,
            tlog_packets_dropped=st.packets_dropped,
            cameras=cams,
            link_loss=[iv.model_copy() for iv in self._links.intervals],
            telemetry_gap_s=self._gaps.lost_after_s,
            telemetry_gaps=[iv.model_copy() for iv in self._gaps.intervals],
        )
        return SessionMeta(
            id=self.id,
            status=status,
            stop_reason=self.stop_reason if status != layout.STATUS_RECORDING else None,
            start_wall=round(self.t0_wall, 6),
            start_utc=layout.utc_label(self.t0_wall + utc.offset_s),
            end_wall=None if end_wall is None else round(end_wall, 6),
            end_utc=None if end_wall is None else layout.utc_label(end_wall + utc.offset_s),
            duration_s=duration,
            source=self.config.source,
            cameras=list(self.cameras),
            software_version=self.config.software_version,
            settings=dict(self.config.settings),
            trigger=self.trigger,
            arming=self._arming,
            missed=self._missed,
            quality=quality,
            task=self.task,
            demonstration=self.demonstration,
            clock=utc,
        )


def _missed(
    held: Versioned[VehicleState] | None,
    t0_mono: float,
    t0_wall: float,
    recorded_until_wall: float | None,
    reason: str | None,
) -> Missed | None:
    """What the flight had before a session that starts with the vehicle armed."""
    heartbeat = held.value.heartbeat if held is not None else None
    if heartbeat is None or not heartbeat.armed or heartbeat.armed_since_mono is None:
        return None
    armed_s = max(0.0, t0_mono - heartbeat.armed_since_mono)
    unrecorded_s = armed_s
    if recorded_until_wall is not None:
        unrecorded_s = min(armed_s, max(0.0, t0_wall - recorded_until_wall))
    return Missed(
        armed_before_start_s=round(armed_s, 3),
        unrecorded_s=round(unrecorded_s, 3),
        reason=reason,
    )


def _round(v: float | None, nd: int = 6) -> float | None:
    return None if v is None else round(v, nd)
