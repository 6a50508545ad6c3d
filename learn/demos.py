"""Synthetic demonstrations: the twin's scripted pilot flies a task K times, faster than
real time, and each flight is recorded as an ordinary session.

Everything goes the way the station records a real flight: the twin sends real MAVLink
over a loopback UDP socket, the link's framer and `StateTracker` make the vehicle state
from those bytes, and the recorder's `RecordingSession` writes telemetry.csv, the tlog,
the camera frames and session.json (with the flown task, as the pilot page's choice is
written into a recorded session, and `demonstration` saying the scripted pilot flew it),
and the flight is scored as the station scores a trial at the disarm
(`analysis.trial_score`), so a selection of sessions treats both alike. Only the clock differs: the twin runs on its own (sim)
clock, and the session is recorded on it as a replayed log is (`wall = start + sim time`).

Pilot variability, seeded per flight: a reaction lag (sticks reach the vehicle
`lag_s` late), stick noise (Gaussian, per stick), and small path errors (each waypoint
and the hover height off by a few tens of centimetres).
"""

from __future__ import annotations

import asyncio
import socket
from collections import deque
from dataclasses import dataclass, field, replace
from pathlib import Path

import cv2
import numpy as np

from fpv_station.analysis.trial_score import score_and_store
from fpv_station.companion.latest import Latest
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import PILOT_SCRIPTED, Demonstration, session_task
from fpv_station.companion.recording.session import RecordingSession, SessionConfig
from fpv_station.companion.recording.writer import WriterLimits
from fpv_station.companion.source_clock import SourceClock
from fpv_station.companion.state_tracker import StateTracker
from fpv_station.companion.vehicle_state import VehicleState
from fpv_station.companion.video_frame import Frame
from fpv_station.core.mavlink.framing import MavFramer
from fpv_station.core.scene import Scene, SceneStart, load_scene
from fpv_station.twin.dynamics import Wind
from fpv_station.twin.pilot import Leg, Observation, Pilot, task_plan
from fpv_station.twin.runner import Twin
from fpv_station.twin.sim import SimConfig

TICK_S = 0.02  # the pilot's 50 Hz, as the pilot page sends sticks
GPS_WARMUP_S = 2.5  # on the pad, disarmed, until the GPS has a fix
TAIL_S = 2.0  # recorded after the disarm, as the recorder's post-disarm tail
WALL_T0 = 1.79e9  # 2026-09: the demonstrations' wall clock starts here, flight k at +1 h k


@dataclass(frozen=True)
class Variability:
    lag_s: tuple[float, float] = (0.05, 0.25)  # reaction lag, uniform per flight
    stick_noise: float = 0.03  # std of the noise added to each stick
    path_error_m: float = 0.3  # std of each waypoint's offset (and of the hover height)


@dataclass(frozen=True)
class DemoConfig:
    task_id: int = 1
    rate_hz: float = 30.0  # telemetry rows
    cameras: bool = False
    camera_names: tuple[str, ...] = layout.CAMERAS  # the cameras recorded, with `cameras`
    camera_fps: float = 15.0
    jpeg_quality: int = 80
    timeout_s: float = 300.0
    variability: Variability = Variability()
    hold_s: float | None = None  # task 1: hover this long instead of the task's hold (long flights)
    # The twin's wind and start, as `TwinEnv`'s reset options ({"wind": ..., "start": ...});
    # empty: the scene's.
    env_options: dict = field(default_factory=dict)


def noisy_plan(scene: Scene, task_id: int, rng: np.random.Generator, err_m: float) -> list[Leg]:
    """The task's legs with each waypoint and cruise height off by a little, as a person's."""
    legs = []
    for leg in task_plan(scene, task_id):
        if leg.kind == "goto" and leg.xy_m is not None and leg.tolerance_m > 0.5:
            dx, dy = rng.normal(0.0, err_m, 2)
            leg = replace(leg, xy_m=(leg.xy_m[0] + dx, leg.xy_m[1] + dy))
        if leg.kind in ("climb", "hold") and leg.alt_m > 0:
            leg = replace(
                leg, alt_m=float(leg.alt_m + np.clip(rng.normal(0, err_m / 3), -0.2, 0.2))
            )
        legs.append(leg)
    return legs


def fly_demo(
    root: Path,
    seed: int,
    config: DemoConfig = DemoConfig(),
    scene: Scene | None = None,
    attempt: tuple[int, int, str] | None = None,
) -> Path:
    """Fly one demonstration and record it as a session under `root`, tagged `scripted`
    and scored as the station scores a trial at the disarm; returns its folder.
    `attempt`: (k, of n, run) within a batch; None: a run of its own."""
    scene = scene or load_scene()
    task = scene.task(config.task_id)
    recorded_task = session_task(scene, None, task)
    rng = np.random.default_rng(seed)
    v = config.variability
    lag_ticks = int(round(rng.uniform(*v.lag_s) / TICK_S))
    legs = noisy_plan(scene, config.task_id, rng, v.path_error_m)
    if config.hold_s is not None:
        legs = [replace(leg, seconds=config.hold_s) if leg.kind == "hold" else leg for leg in legs]
    pilot = Pilot(legs)
    cams = config.camera_names if config.cameras else ()
    wall0 = WALL_T0 + 3600.0 * seed
    k, n, run = attempt or (1, 1, layout.utc_label(wall0))
    # The recorder records the twin as it records a replayed log: on the source's own
    # clock (the sim's, from wall0), its rows and frames sampled from this thread.
    clock = SourceClock(own=True)
    clock.advance(wall0)
    state: Latest[VehicleState] = Latest()
    slots: dict[str, Latest[Frame]] = {c: Latest() for c in cams}
    session = RecordingSession(
        Path(root),
        state,
        slots,
        SessionConfig(
            rate_hz=config.rate_hz,
            limits=WriterLimits(min_free_bytes=0),
            source="sim",
            settings={
                "demo": {
                    "task": config.task_id,
                    "seed": seed,
                    "lag_s": lag_ticks * TICK_S,
                    **config.env_options,
                }
            },
            camera_fps=dict.fromkeys(cams, config.camera_fps),
        ),
        trigger="demos",
        clock=clock,
        task=recorded_task,
        demonstration=Demonstration(
            kind=PILOT_SCRIPTED, pilot=PILOT_SCRIPTED, run=run, attempt=k, attempts=n
        ),
    )
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.setblocking(False)
    twin = Twin(
        scene,
        sim_config(seed, config.env_options),
        mavlink=f"udpout:127.0.0.1:{rx.getsockname()[1]}",
        flight_log=False,  # the session is the record; nobody asks the twin for its logs
    )
    t0 = twin.sim.t_s
    framer, tracker = MavFramer(), StateTracker()
    seqs = dict.fromkeys(cams, 0)
    sticks: deque[tuple[float, float, float, float]] = deque([(0.0, 0.0, 0.0, 0.0)] * lag_ticks)
    next_frame = t0
    disarmed_at: float | None = None
    reason = "error"
    session.start()
    try:
        while True:
            now = twin.sim.t_s
            elapsed = now - t0
            t = wall0 + elapsed
            clock.advance(t)
            session.advance(t)  # the rows of the instants before `t`
            changed = False
            while True:  # what the twin sent during the last step, as the link reads it
                try:
                    data = rx.recv(65535)
                except BlockingIOError:
                    break
                for msg in framer.feed(data):
                    session.on_packet(t, bytes(msg.get_msgbuf()))
                    changed |= tracker.update(msg, t)
            if changed:
                state.publish(tracker.state)
            if cams and now >= next_frame - 1e-9:
                next_frame += 1.0 / config.camera_fps
                for cam in cams:
                    bgr = twin.render(cam)
                    ok, jpeg = cv2.imencode(
                        ".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, config.jpeg_quality]
                    )
                    seqs[cam] += 1
                    h, w = bgr.shape[:2]
                    slots[cam].publish(Frame(cam, seqs[cam], jpeg.tobytes(), w, h, t, t))
                session.writer.wait_for_room()  # faster than real time, yet no frame lost

            armed = bool(twin.sim.commander.armed[0])
            if twin.sim.state.crash[0]:
                reason = "crash"
                break
            if elapsed > config.timeout_s:
                reason = "timeout"
                break
            if elapsed >= GPS_WARMUP_S and not pilot.done:
                pose = twin.pose()
                yaw = float(np.arctan2(pose.R_world_body[1, 0], pose.R_world_body[0, 0]))
                obs = Observation(pose.t_s, pose.pos_enu_m, pose.vel_enu_mps, yaw, armed)
                stick = np.array(pilot.update(obs), float)
                stick[:3] += rng.normal(0.0, v.stick_noise, 3) * (np.abs(stick[:3]) > 0)
                sticks.append(tuple(np.clip(stick, [-1, -1, -1, 0], 1)))
                twin.set_sticks(*sticks.popleft())
            elif pilot.done:
                twin.set_sticks(0.0, 0.0, 0.0, 0.0)
                if disarmed_at is None and not armed:
                    disarmed_at = now
                if disarmed_at is not None and now - disarmed_at >= TAIL_S:
                    reason = "disarmed"
                    break
            twin.step_for(TICK_S)
    finally:
        if twin.vehicle is not None:
            twin.vehicle.close()
        rx.close()
        # The recorder's own stop: the last rows, the files closed, session.json final.
        asyncio.run(session.stop(reason))
    score_and_store(session.folder, recorded_task)
    return session.folder


def sim_config(seed: int, env_options: dict) -> SimConfig:
    """The twin's configuration for a flight with `TwinEnv`'s reset options."""
    start = env_options.get("start")
    return SimConfig(
        seed=seed,
        wind=Wind.parse(env_options.get("wind")),
        start=SceneStart.model_validate(start) if start is not None else None,
    )


def fly_demos(
    root: Path, count: int, seed: int = 0, config: DemoConfig = DemoConfig(), progress=None
) -> list[Path]:
    """`count` demonstrations with seeds `seed`, `seed + 1`, ..."""
    scene = load_scene()
    run = layout.utc_label(WALL_T0 + 3600.0 * seed)
    out = []
    for k in range(count):
        out.append(fly_demo(root, seed + k, config, scene, (k + 1, count, run)))
        if progress is not None:
            progress(k + 1, count)
    return out
