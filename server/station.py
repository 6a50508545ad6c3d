"""The running station: every service the app serves from, built in the app's lifespan.

Nothing here opens hardware at import time; `open_station` builds the services from
the settings, starts them in dependency order and stops them in reverse.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import anyio

from fpv_station.companion.latest import Latest
from fpv_station.companion.link import MavlinkLink
from fpv_station.companion.recording.recorder import Recorder
from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.server.analysis_worker import AnalysisWorker
from fpv_station.server.client_limits import ClientCap, ClientLimits, raise_nofile_limit
from fpv_station.server.demo_mode import DemoMode
from fpv_station.server.exports import Exports
from fpv_station.server.memory_trim import MemoryTrimmer, glibc_malloc_trim
from fpv_station.server.onboard_logs import OnboardLogs
from fpv_station.server.pilot import Pilot
from fpv_station.server.settings import Settings
from fpv_station.server.tasks import TaskSupervisor
from fpv_station.server.telemetry_json import SharedStateJson
from fpv_station.server.telemetry_pump import TelemetryPump
from fpv_station.server.trials import Trials, station_scene
from fpv_station.server.video_fanout import FrameFanout

if TYPE_CHECKING:  # built lazily in open_station: importing them costs start-up time
    from fpv_station.companion.cameras.capture import Camera
    from fpv_station.server.trajectory3d.replay_scene import Replay3D
    from fpv_station.server.trajectory3d.service import Trajectory3D
    from fpv_station.twin.runner import Twin


log = logging.getLogger(__name__)


@dataclass
class Station:
    settings: Settings
    tasks: TaskSupervisor = field(default_factory=TaskSupervisor)
    # The vehicle link (None for source "none") and its state slot. For "none" the slot
    # stays empty, so consumers need no special case: they simply never get a state.
    link: MavlinkLink | None = None
    state: Latest[VehicleState] = field(default_factory=Latest)
    telemetry_json: SharedStateJson = field(default_factory=SharedStateJson)
    # One pump for every /ws/telemetry client (server/telemetry_pump.py); made in
    # open_station once the state slot is chosen.
    telemetry: TelemetryPump = field(init=False)
    recorder: Recorder | None = None
    # front and bottom; readers use `.frames` (a Latest[Frame])
    cameras: dict[str, Camera] = field(default_factory=dict)
    # The live 3D panel (None with --no-3d): it keeps the trail from the start; its viser
    # server and the replay's (replay3d) start on the first visit (start_3d_panels).
    trajectory3d: Trajectory3D | None = None
    replay3d: Replay3D | None = None  # the replay's viser panel; None until then
    panels_3d_lock: asyncio.Lock = field(default_factory=asyncio.Lock)
    panels_3d_closed: bool = False  # stopped with the station: a late visit starts nothing
    # One MJPEG fan-out per camera, shared by all its viewers (server.video_fanout).
    video_fanouts: dict[str, FrameFanout] = field(default_factory=dict)
    twin: Twin | None = None  # the digital twin when link.source is "sim"
    pilot: Pilot | None = None  # who has the twin's sticks (/ws/control), one at a time
    # One trial scoring at a time (numpy, in a thread: a score is never refused, unlike
    # a REST request to the busy worker below). Made in open_station: an anyio limiter
    # belongs to the running event loop.
    analysis_limiter: anyio.CapacityLimiter | None = None
    # REST analyses and figures: a worker process, bounded and cached (analysis_worker.py).
    analysis_worker: AnalysisWorker = field(default_factory=AnalysisWorker)
    trials: Trials | None = None  # the flight task chosen and its trials' scores
    demo: DemoMode | None = None  # a pilot's run of demonstration attempts (demo_mode.py)
    exports: Exports | None = None  # selected sessions exported to a dataset (exports.py)
    memory_trimmer: MemoryTrimmer | None = None  # None where malloc_trim is off or absent
    # The autopilot's own log of each flight, fetched into its session (server.onboard_logs).
    onboard_logs: OnboardLogs | None = None
    # Caps on streaming clients, fitted under the descriptor limit (server/client_limits.py).
    client_limits: ClientLimits = field(
        default_factory=lambda: ClientLimits(ClientCap("websocket", 200), ClientCap("video", 40))
    )

    def end_streams(self) -> None:
        """The server is shutting down: end every MJPEG stream after its current part
        (WebSockets are closed by uvicorn itself, with 1012)."""
        for fanout in self.video_fanouts.values():
            fanout.close()


@contextlib.asynccontextmanager
async def open_station(settings: Settings) -> AsyncIterator[Station]:
    station = Station(settings=settings)
    station.analysis_limiter = anyio.CapacityLimiter(1)
    srv = settings.server
    station.client_limits = ClientLimits.fitted(
        srv.max_ws_clients,
        srv.max_video_clients,
        srv.fd_reserve,
        raise_nofile_limit(),
        max_3d=srv.max_3d_viewers if settings.viser.enabled else 0,
    )
    async with contextlib.AsyncExitStack() as stack:
        stack.push_async_callback(station.tasks.aclose)
        stack.callback(station.analysis_worker.close)

        # -- vehicle link ----------------------------------------------------------
        source = settings.link.source.strip()
        if source == "sim":
            # The embedded twin vehicle, reached by a MavlinkLink over a loopback socket,
            # exactly as a real vehicle below (server/twin_link.py).
            from fpv_station.server.twin_link import open_twin_link

            station.twin, station.link = open_twin_link(settings, stack)
            station.state = station.link.state
        elif source != "none":
            link = MavlinkLink(settings.link)
            if not link.clock.own:  # a replay starts below, once its recorder listens
                link.start()
            stack.callback(link.stop)
            station.link = link
            station.state = link.state

        if (vehicle_link := station.link) is not None:
            station.tasks.watch("mavlink link thread", lambda: vehicle_link.crashed)
            station.telemetry_json.clock = vehicle_link.clock  # a replay's ages: its time

        if settings.server.malloc_trim_s > 0 and (trim := glibc_malloc_trim()) is not None:
            station.memory_trimmer = MemoryTrimmer(settings.server.malloc_trim_s, trim)
            station.tasks.spawn("malloc-trim", station.memory_trimmer.run())

        # -- telemetry: one pump for the WebSocket clients, running while any is there
        station.telemetry = TelemetryPump(
            station.state, station.telemetry_json, station.tasks.spawn
        )

        # -- cameras (after the twin, whose renderer the sim cameras use) ------------
        await _open_cameras(station, stack)

        # -- recorder (after the link and cameras it records) -----------------------
        station.recorder = await _open_recorder(station, stack)
        if station.link is not None and not station.link.running and station.link.clock.own:
            # A replay on its own clock: at full speed it would be over before the recorder
            # listened (companion/source_clock.py).
            station.link.start()
            # Serve once the log gave its first time: a session is in the log's time.
            await asyncio.to_thread(station.link.clock.wait_started, 2.0)

        # -- flight tasks: chosen for the sessions, scored when they end -------------
        scene, scene_file, is_field = station_scene(settings)  # bad file: logged, default
        station.trials = Trials(
            scene,
            scene_file,
            is_field,
            station.recorder,
            station.tasks.spawn,
            station.analysis_limiter,
        )
        station.demo = DemoMode(station.trials, station.recorder, station.tasks.spawn)
        station.exports = Exports(station.recorder.store, station.tasks.spawn)

        # -- the autopilot's own log, fetched after each flight (before the link stops)
        station.onboard_logs = OnboardLogs(
            settings.onboard_log, station.link, station.recorder, station.tasks.spawn
        )
        stack.push_async_callback(asyncio.to_thread, station.onboard_logs.close)

        # -- 3D trajectory panel (after the link whose state it draws) ----------------
        if settings.viser.enabled:
            _open_trajectory3d(station, stack)
        yield station


async def _open_recorder(station: Station, stack: contextlib.AsyncExitStack) -> Recorder:
    from fpv_station.server.recorder_setup import open_recorder

    cams = station.cameras
    return await open_recorder(
        station.settings,
        stack,
        station.tasks.spawn,
        station.state,
        {name: cam.frames for name, cam in cams.items()},
        {name: cam.config.fps for name, cam in cams.items()},
        station.link,
    )


async def _open_cameras(station: Station, stack: contextlib.AsyncExitStack) -> None:
    """Front and bottom cameras; after the twin, whose renderer the sim cameras use."""
    from fpv_station.companion.cameras.rig import (
        CAMERA_NAMES,
        build_camera,
        start_cameras,
        stop_cameras,
    )

    cams = station.settings.cameras
    for name in CAMERA_NAMES:
        station.cameras[name] = build_camera(
            name,
            getattr(cams, name),
            link_source=station.settings.link.source,
            renderer=lambda: station.twin,  # set by open_twin_link for source "sim", else None
            stall_s=cams.stall_s,
            retry_min_s=cams.retry_min_s,
            retry_max_s=cams.retry_max_s,
        )
    for name, camera in station.cameras.items():
        station.video_fanouts[name] = FrameFanout(name, camera.frames, station.tasks.spawn)
    start_cameras(station.cameras.values())
    stack.push_async_callback(asyncio.to_thread, stop_cameras, list(station.cameras.values()))


def _open_trajectory3d(station: Station, stack: contextlib.AsyncExitStack) -> None:
    from fpv_station.server.trajectory3d.service import Trajectory3D

    s = station.settings
    # The station's one field (server.trials.station_scene, loaded once): drawn when it is
    # the field being flown; a real flight without a scene file gets a plain ground grid.
    trials = station.trials
    field = trials.scene if trials is not None and trials.is_field else None
    station.trajectory3d = Trajectory3D(s.viser, station.state, field=field)
    stack.push_async_callback(_stop_3d_panels, station)
    # The task draws into the viser server: it ends before the server stops (the stack
    # unwinds last in, first out).
    task = station.tasks.spawn("trajectory3d", station.trajectory3d.run())
    stack.push_async_callback(station.tasks.cancel, task)


async def start_3d_panels(station: Station) -> None:
    """Start the live panel's viser server and the replay's, once: on the first visit
    (GET /api/viser, PUT /api/replay3d). Until then the station serves without viser,
    about 12 MB and 0.3 s of start-up less (docs/PERFORMANCE.md)."""
    live = station.trajectory3d
    if live is None:
        return
    async with station.panels_3d_lock:
        if station.panels_3d_closed:
            return
        if live.server is None:
            await asyncio.to_thread(live.start)  # viser binds and spawns its thread
        if station.replay3d is None:
            # The replay's own viser server, with the same field (replay_scene.py).
            from fpv_station.server.trajectory3d.replay_scene import Replay3D

            s = station.settings
            replay = Replay3D(s.viser, field=live.field)
            await asyncio.to_thread(replay.start)
            station.replay3d = replay


async def _stop_3d_panels(station: Station) -> None:
    # viser's stop joins its thread: keep that wait off the event loop.
    async with station.panels_3d_lock:
        station.panels_3d_closed = True
        for panel in (station.replay3d, station.trajectory3d):
            if panel is not None:
                await asyncio.to_thread(panel.stop)
