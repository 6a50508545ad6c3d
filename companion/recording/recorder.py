"""The recording service: start and stop sessions, by request or on arm/disarm.

    recorder = Recorder(sessions_dir, state, {"front": cam.frames, ...}, options)
    link.add_packet_listener(recorder.on_packet)
    await recorder.open(spawn)          # marks cut-off sessions, starts the arm watcher
    await recorder.start("rest"); await recorder.stop("requested")
    await recorder.aclose()

One session at a time. A session stopped by the writer (disk full, write error) is
finalized here with the writer's reason, which stays visible in `status().last_stop`.
While the vehicle is armed, a session that failed is started again, and so is one whose
start was refused (no descriptor, a full disk), for as long as the vehicle stays armed;
the session that starts late says how much of the flight it missed (`SessionMeta.missed`).

A source on its own clock (a replay, `companion.source_clock`) drives the recorder from
its thread: rows at each instant of its time, arming and the post-disarm tail in its
seconds, and its end closing the session (`stop_reason` "source ended"); the replay waits
while a session starts or stops, so the sessions are the same at any replay speed.
"""

from __future__ import annotations

import asyncio
import logging
import time
from collections.abc import Callable, Coroutine, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from fpv_station.companion.latest import Latest, Wakeup
from fpv_station.companion.recording import diskspace
from fpv_station.companion.recording.meta import Demonstration, SessionMeta, SessionTask
from fpv_station.companion.recording.recovery import mark_interrupted
from fpv_station.companion.recording.session import RecordingSession, SessionConfig
from fpv_station.companion.recording.store import SessionStore
from fpv_station.companion.source_clock import SourceClock
from fpv_station.companion.timesync import TimeSync
from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.companion.video_frame import Frame
from fpv_station.core.spawn import Spawn

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RecorderOptions:
    session: SessionConfig = field(default_factory=SessionConfig)
    auto_record_on_arm: bool = True
    post_disarm_tail_s: float = 5.0


@dataclass(frozen=True)
class LastStop:
    id: str
    reason: str
    end_wall: float


@dataclass(frozen=True)
class RecordingStatus:
    recording: bool
    id: str | None = None
    trigger: str | None = None
    start_wall: float | None = None
    elapsed_s: float | None = None
    telemetry_rows: int = 0
    frames_written: dict[str, int] = field(default_factory=dict)
    frames_dropped: dict[str, int] = field(default_factory=dict)
    auto_record_on_arm: bool = True
    stopping_at_wall: float | None = None  # end of the post-disarm tail, when pending
    last_stop: LastStop | None = None
    last_error: str | None = None  # why the last start failed, if it did
    # Seconds the vehicle has been armed with no session recording (None: disarmed, or
    # recording), and whether that is longer than a start takes: the flight is not being
    # recorded, and the pages say NOT RECORDING.
    armed_unrecorded_s: float | None = None
    not_recording: bool = False


RETRY_MIN_S = 1.0  # the retry's first wait, and its wait after a refused start
RETRY_MAX_S = 30.0
# Armed this long with no session is a flight not being recorded: a start takes tens of
# milliseconds, so an arming's own start never shows as one.
NOT_RECORDING_AFTER_S = 1.0
# Sessions the recorder started by itself for a flight (arming, or again after a failed
# write while armed): disarming ends them. One started by hand is stopped by hand.
FLIGHT_TRIGGERS = ("arm", "retry")


class RecorderError(Exception):
    """A session could not start; the message says why and what to do."""


class Recorder:
    def __init__(
        self,
        sessions_dir: Path,
        state: Latest[VehicleState],
        cameras: Mapping[str, Latest[Frame]],
        options: RecorderOptions = RecorderOptions(),
        clock: SourceClock | None = None,
        timesync: TimeSync | None = None,
    ) -> None:
        self.store = SessionStore(sessions_dir)
        self.clock = clock or SourceClock()
        self.timesync = timesync  # the link's measure of the vehicle's clock, for session.json
        self.state = state
        self.cameras = dict(cameras)
        self.options = options
        self.session: RecordingSession | None = None
        self._finalizing: RecordingSession | None = None  # stopped, files being closed
        self.last_stop: LastStop | None = None
        self.last_error: str | None = None
        self._lock = asyncio.Lock()
        # The flight task written into each new session (server.trials sets it).
        self.task: SessionTask | None = None
        # Who flies the next session as a demonstration (server.demo_mode sets it).
        self.demonstration: Demonstration | None = None
        # Called on the event loop with each finished session (its final metadata and
        # folder); must not block (server.trials spawns the scoring off the loop).
        self.session_end_hooks: list[Callable[[SessionMeta, Path], None]] = []
        self._spawn: Spawn | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._tail: asyncio.TimerHandle | None = None
        self._tail_deadline_wall: float | None = None
        self._closed = False
        # Why the last session was cut short by a write failure (EMFILE, EIO, disk full),
        # until a new session starts; the station's health reports it (degraded).
        self.failure: str | None = None
        self._retrying = False
        self._retry_delay = RETRY_MIN_S  # the retry's first wait (_failed, _retry)
        self._stopped_mono: float | None = None  # when the last session stopped (source clock)
        self._was_armed: bool | None = None  # source-clock arm watching (its thread)
        # Live arm watching: the state slot's listener (the link's thread) notes the armed
        # flag of each state and wakes `_watch_arming` only when it changes.
        self._armed_seen: bool | None = None
        self._armed_changed = Wakeup()
        # One bound method, added and removed (the slot removes a listener by identity).
        self._armed_listener: Callable[[VehicleState], None] = self._note_armed
        self._tail_due: float | None = None  # end of the tail, source clock

    # -- service lifecycle ---------------------------------------------------------------

    async def open(self, spawn: Spawn | None = None) -> list[str]:
        """Mark cut-off sessions interrupted and watch arming; returns the marked ids."""
        self._loop = asyncio.get_running_loop()
        self._spawn = spawn or (lambda name, coro: asyncio.get_running_loop().create_task(coro))
        marked = await asyncio.to_thread(mark_interrupted, self.store)
        if self.clock.own:
            self.clock.add_listener(self._on_source_time)
        elif self.options.auto_record_on_arm:
            self.state.add_listener(self._armed_listener)
            self._spawn("recorder-arm-watch", self._watch_arming())
        return marked

    async def aclose(self) -> None:
        self._closed = True
        self.state.remove_listener(self._armed_listener)
        self._armed_changed.wake()  # the arm watcher ends
        await self.stop("shutdown")

    # -- control -------------------------------------------------------------------------

    @property
    def recording_id(self) -> str | None:
        """The session being written (also while its files are being closed)."""
        s = self.session or self._finalizing
        return s.id if s is not None else None

    async def start(self, trigger: str = "api") -> RecordingStatus:
        """Start a session unless one runs (then it keeps running); returns the status."""
        async with self._lock:
            self._cancel_tail()
            if self.session is None and not self._closed:
                try:
                    session = await asyncio.to_thread(self._new_session, trigger)
                except (OSError, RecorderError) as exc:
                    if str(exc) != self.last_error:  # not once a second while retried
                        log.error("recording did not start: %s", exc)
                    self.last_error = str(exc)
                    raise RecorderError(str(exc)) from None
                session.start()
                self.session = session
                self.last_error = None
                self.failure = None
                log.info("recording session %s started (%s)", session.id, trigger)
        return self.status()

    def _new_session(self, trigger: str) -> RecordingSession:
        if not self.clock.started:  # a session is in its source's time: none yet
            raise RecorderError("The replay has not started yet; start recording in a moment.")
        root = self.store.root
        need = self.options.session.limits.min_free_bytes
        try:
            root.mkdir(parents=True, exist_ok=True)
            free = diskspace.free_bytes(root)
        except OSError as exc:
            raise RecorderError(f"Cannot record in '{root}': {exc.strerror or exc}.") from None
        if free < need:
            raise RecorderError(
                f"disk full: {free / 1e6:.1f} MB free in '{root}', under the "
                f"{need / 1e6:.0f} MB minimum; free some space (delete old sessions)."
            )
        try:
            return RecordingSession(
                root,
                self.state,
                self.cameras,
                self.options.session,
                trigger,
                self._on_writer_failure,
                self.clock,
                task=self.task,
                demonstration=self.demonstration,
                timesync=self.timesync,
                recorded_until_wall=self.last_stop.end_wall if self.last_stop else None,
                # why the flight went unrecorded until this retry (a stale one otherwise)
                missed_reason=(self.last_error or self.failure) if trigger == "retry" else None,
            )
        except OSError as exc:
            raise RecorderError(
                f"Cannot create a session in '{root}': {exc.strerror or exc}."
            ) from None

    async def stop(self, reason: str = "requested", only_id: str | None = None) -> RecordingStatus:
        """Stop the running session (only if its id is `only_id`, when given); finalize it."""
        async with self._lock:
            if only_id is not None and self.recording_id != only_id:
                return self.status()
            self._cancel_tail()
            session, self.session = self.session, None
            if session is not None:
                # Visible at once (the status never shows "stopped" without a reason);
                # the end time is refined once the files are closed.
                self.last_stop = LastStop(session.id, session.stop_reason or reason, time.time())
                self._finalizing = session
                try:
                    meta = await session.stop(reason)
                finally:
                    self._finalizing = None
                self.last_stop = LastStop(
                    session.id, meta.stop_reason or reason, meta.end_wall or time.time()
                )
                self._stopped_mono = self.clock.mono()
                log.info("recording session %s stopped: %s", session.id, meta.stop_reason)
                for hook in self.session_end_hooks:
                    try:
                        hook(meta, session.folder)
                    except Exception:  # a consumer's bug must not break stopping
                        log.exception("session-end hook %r failed", hook)
        return self.status()

    def on_packet(self, t_wall: float, packet: bytes) -> None:
        """The link's packet listener (link thread); a no-op while not recording."""
        session = self.session
        if session is not None:
            session.on_packet(t_wall, packet)

    def armed_unrecorded_s(self) -> float | None:
        """Seconds the vehicle has been armed with no session recording: since its first
        HEARTBEAT saying armed, or since the last session stopped if later. None while
        disarmed or recording."""
        if self.session is not None:
            return None
        got = self.state.get()
        heartbeat = got.value.heartbeat if got is not None else None
        if heartbeat is None or not heartbeat.armed:
            return None
        now = self.clock.mono()
        since = heartbeat.armed_since_mono if heartbeat.armed_since_mono is not None else now
        if self._stopped_mono is not None:
            since = max(since, self._stopped_mono)
        return round(max(0.0, now - since), 3)

    def status(self) -> RecordingStatus:
        s = self.session
        if s is None:
            unrecorded = self.armed_unrecorded_s()
            return RecordingStatus(
                recording=False,
                auto_record_on_arm=self.options.auto_record_on_arm,
                last_stop=self.last_stop,
                last_error=self.last_error,
                armed_unrecorded_s=unrecorded,
                not_recording=unrecorded is not None and unrecorded >= NOT_RECORDING_AFTER_S,
            )
        stats = s.writer.stats
        return RecordingStatus(
            recording=True,
            id=s.id,
            trigger=s.trigger,
            start_wall=s.t0_wall,
            elapsed_s=round(s.clock.mono() - s.t0_mono, 3),
            telemetry_rows=stats.rows_written,
            frames_written=dict(stats.frames_written),
            frames_dropped=s.frames_dropped(),
            auto_record_on_arm=self.options.auto_record_on_arm,
            stopping_at_wall=self._tail_deadline_wall,
            last_stop=self.last_stop,
        )

    # -- automatic recording ---------------------------------------------------------------

    def _note_armed(self, state: VehicleState) -> None:
        """The state slot's listener, in the link's thread for each of its 100-odd states a
        second: a comparison, and a hop to the event loop only when the armed flag changed,
        not a wake-up of the loop per state for a flag that changes twice a flight."""
        armed = bool(state.heartbeat.armed)
        if armed is not self._armed_seen:
            self._armed_seen = armed
            self._armed_changed.wake()

    async def _watch_arming(self) -> None:
        """Start a session when the vehicle arms, and stop it `post_disarm_tail_s` after it
        disarms (if arming started it). A station started over an armed vehicle starts
        recording at once."""
        was_armed: bool | None = None
        while not self._closed:
            self._armed_changed.clear()
            got = self.state.get()
            armed = got is not None and bool(got.value.heartbeat.armed)
            if armed and was_armed is not True:
                try:
                    await self.start("arm")
                except RecorderError:  # logged, and shown in status().last_error
                    self._keep_trying(refused=True)
            elif not armed and was_armed is True:
                self._schedule_tail()
            was_armed = armed
            await self._armed_changed.wait()

    def _on_source_time(self, t: float | None) -> None:
        """The source's clock moved to `t` (None: it ended); in the source's thread."""
        if self._closed or self._loop is None:
            return
        session = self.session
        if t is None:
            if session is not None:
                self._wait_for(self.stop("source ended", only_id=session.id))
            return
        if session is not None:
            session.advance(t)
        if not self.options.auto_record_on_arm:
            return
        got = self.state.get()
        armed = bool(got.value.heartbeat.armed) if got is not None else False
        if armed and self._was_armed is not True:
            self._tail_due = None
            if not self._wait_for(self.start("arm")):
                self._loop.call_soon_threadsafe(self._keep_trying, True)
        elif not armed and self._was_armed is True:
            if session is not None and session.trigger in FLIGHT_TRIGGERS:
                self._tail_due = t + self.options.post_disarm_tail_s
                self._tail_deadline_wall = self._tail_due  # the log's time, as the session's
        self._was_armed = armed
        if self._tail_due is not None and t >= self._tail_due and self.session is not None:
            self._tail_due = self._tail_deadline_wall = None
            self._wait_for(self.stop("disarmed", only_id=self.session.id))

    def _wait_for(self, coro: Coroutine[Any, Any, Any]) -> bool:
        """Run `coro` on the event loop and wait for it (from the source's thread); False
        if it failed."""
        assert self._loop is not None
        try:
            asyncio.run_coroutine_threadsafe(coro, self._loop).result(timeout=30.0)
        except RecorderError:
            return False  # logged, and shown in status().last_error
        except Exception:
            log.exception("recording start/stop on the source's clock failed")
            return False
        return True

    def _schedule_tail(self) -> None:
        session = self.session
        if session is None or session.trigger not in FLIGHT_TRIGGERS or self._tail is not None:
            return  # a session started by hand is stopped by hand
        tail_s = self.options.post_disarm_tail_s
        self._tail_deadline_wall = time.time() + tail_s
        self._tail = asyncio.get_running_loop().call_later(
            tail_s, self._spawn_stop, "disarmed", session.id
        )

    def _cancel_tail(self) -> None:
        if self._tail is not None:
            self._tail.cancel()
            self._tail = None
            self._tail_deadline_wall = None

    def _spawn_stop(self, reason: str, session_id: str) -> None:
        assert self._spawn is not None
        try:
            self._spawn(f"recorder-stop-{session_id}", self.stop(reason, only_id=session_id))
        except RuntimeError:
            log.exception("cannot schedule the recording stop")

    def _on_writer_failure(self, session_id: str, reason: str) -> None:
        """From the writer thread: finalize the session on the event loop, then try again
        (the cause is often passing: descriptors, a flaky card, space being freed)."""
        loop = self._loop
        if loop is None:
            return
        try:
            loop.call_soon_threadsafe(self._failed, reason, session_id)
        except RuntimeError:  # the loop is closed: shutdown finalizes
            pass

    def _failed(self, reason: str, session_id: str) -> None:
        self.failure = reason
        s = self.session
        again = (
            s is not None
            and s.id == session_id
            and s.trigger == "retry"
            and s.clock.mono() - s.t0_mono < RETRY_MAX_S
        )
        # A session the retry started that failed again soon: the cause has not passed,
        # and the wait goes on growing (not a new session folder every second of a flight).
        if not again:
            self._retry_delay = RETRY_MIN_S  # a new failure: its cause may pass soon
        self._spawn_stop(reason, session_id)
        self._keep_trying()

    def _keep_trying(self, refused: bool = False) -> None:
        """A session failed, or (`refused`) the arming's start was: retry while armed (on
        the event loop). A refused arming is a new cause: the first wait is the shortest."""
        if refused:
            self._retry_delay = RETRY_MIN_S
        if not self._retrying and self._spawn is not None and not self._closed:
            self._retrying = True
            self._spawn("recorder-retry", self._retry())

    async def _retry(self) -> None:
        """While the vehicle is armed and no session runs, start one again. A refused start
        (no descriptor, a full disk) leaves nothing behind and is tried again every
        `RETRY_MIN_S`: each second armed unrecorded is a second of flight lost. A session
        that started and failed is retried after 1 s, then doubling to 30 s across
        sessions that fail again within 30 s of their start (not a new session folder
        every second of a flight). Once disarmed the next arming starts a session itself;
        the failure stays shown."""
        delay = self._retry_delay
        wait = delay
        try:
            while not self._closed and (self.failure is not None or self.last_error is not None):
                await asyncio.sleep(wait)
                got = self.state.get()
                armed = got is not None and bool(got.value.heartbeat.armed)
                if self.session is not None or not armed or not self.options.auto_record_on_arm:
                    return
                cause = self.failure or self.last_error  # a start that works clears both
                try:
                    await self.start("retry")
                except RecorderError:
                    wait = RETRY_MIN_S  # logged and in last_error until a start works
                    continue
                # Where the next wait starts if this session fails again soon.
                self._retry_delay = min(delay * 2, RETRY_MAX_S)
                log.info("recording resumed after: %s", cause)
                return
        finally:
            self._retrying = False
