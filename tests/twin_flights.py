"""A recorded flight of the station on the digital twin, for the end-to-end tests.

`recorded_twin_flight` starts a real station (`--source sim`, real uvicorn, real MAVLink
over loopback) that auto-records into `sessions_dir`, lets the twin's scripted pilot fly
one of the scene's tasks, and yields once the recorder has closed the session.
`task_page_on_the_twin` opens such a station's pilot page on a task, for a test to fly.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from fpv_station.core.scene import DEFAULT_SCENE, load_scene
from fpv_station.server.app import create_app
from fpv_station.server.settings import load_settings
from fpv_station.twin.pilot import Leg, Pilot, fly_twin, task_plan
from tests.helpers import run_uvicorn, wait_until


@dataclass
class RecordedFlight:
    base_url: str
    station: Any  # server.station.Station, still running
    session_id: str
    stop_reason: str
    folder: Path


# The twin writes no ULog of its own (a sample every physics step) and the station asks
# for none after the disarm (a download over the link): CPU a page test does not need.
NO_ONBOARD_LOG = {"twin.flight_log": False, "onboard_log.after_disarm": False}

# The twin renders no camera: two renders and JPEG encodes at 30 fps take about half a
# core that a test of telemetry, recording rows or a page's panels does not need.
NO_CAMERAS = {"cameras.front.spec": "none", "cameras.bottom.spec": "none"}
# Small, slow cameras: for a test whose cameras must be there (views, readouts, recorded
# frames on the session clock) but whose pictures nobody reads.
SMALL_CAMERAS = {
    f"cameras.{c}.{k}": v
    for c in ("front", "bottom")
    for k, v in {"width": 160, "height": 120, "fps": 10.0}.items()
}


def twin_station_settings(sessions_dir: Path, overrides: dict[str, Any] | None = None):
    """A `--source sim` station recording into `sessions_dir`, with a short tail."""
    return load_settings(
        None,
        {
            "link.source": "sim",
            "viser.enabled": False,
            "recording.sessions_dir": str(sessions_dir),
            "recording.post_disarm_tail_s": 1.0,
            "recording.min_free_mb": 0,
            **(overrides or {}),
        },
        environ={},
    )


@contextlib.contextmanager
def recorded_twin_flight(
    sessions_dir: Path,
    task_id: int,
    overrides: dict[str, Any] | None = None,
    timeout_s: float = 120.0,
    before_flight: Callable[[str], None] | None = None,
    legs: list[Leg] | None = None,
    crash: bool = False,
) -> Iterator[RecordedFlight]:
    """`before_flight(base_url)` runs once the station is up; `legs` replace the task's
    scripted plan (an aborted trial, say); `crash`: the plan must end in a crash (the
    twin then disarms in the air) instead of being flown to its end."""
    app = create_app(twin_station_settings(sessions_dir, overrides))
    with run_uvicorn(app) as base:
        station = app.state.station
        assert wait_until(lambda: station.state.current().altitude.reference == "first_fix", 20)
        if before_flight is not None:
            before_flight(base)
        legs = list(legs) if legs is not None else task_plan(station.twin.scene, task_id)
        # A pilot waits on the pad a moment after arming. It matters here: recording
        # starts when the station sees the armed HEARTBEAT (1 Hz), so a take-off within
        # that second would be missing from the session.
        assert legs[0].kind == "arm"
        legs.insert(1, Leg("hold", alt_m=0.0, seconds=1.5))
        pilot = Pilot(legs)
        fly_twin(station.twin, pilot, timeout_s=timeout_s)
        if crash:
            assert station.twin.sim.state.crash[0] and not pilot.done, pilot.log
        else:
            assert pilot.done, pilot.log
        # Landed: the commander disarms 2 s later, then the 1 s tail ends the session.
        assert wait_until(
            lambda: (
                station.recorder.last_stop is not None and station.recorder.recording_id is None
            ),
            20,
        )
        last = station.recorder.last_stop
        yield RecordedFlight(base, station, last.id, last.reason, Path(sessions_dir) / last.id)


def field_with_hold(folder: Path, hold_s: float) -> Path:
    """The built-in field as a scene file in `folder`, its task 1 holding the height for
    `hold_s` instead: a page test flies the same procedure with a shorter wait (the page
    counts the hold on the wall clock, so a faster twin would not shorten it)."""
    text = DEFAULT_SCENE.read_text()
    default = f"hold_s = {load_scene().task(1).hold_s}"
    assert text.count(default) == 1, default
    path = Path(folder) / f"field-hold-{hold_s:g}s.toml"
    path.write_text(text.replace(default, f"hold_s = {hold_s}"))
    assert load_scene(path).task(1).hold_s == hold_s
    return path


@contextlib.contextmanager
def task_page_on_the_twin(
    browser, sessions_dir: Path, task_id: int, scene: Path | None = None
) -> Iterator[tuple[Any, str, Any]]:
    """A station on the twin (no cameras; `scene`: its scene file, else the built-in
    field) and its pilot page in Chromium with task `task_id` chosen, once the task's map
    shows the vehicle: (the app, its base URL, the page). The twin keeps no flight log
    of its own (NO_ONBOARD_LOG): what a page shows does not come from it."""
    overrides: dict[str, Any] = {**NO_CAMERAS, **NO_ONBOARD_LOG}
    if scene is not None:
        overrides["twin.scene"] = str(scene)
    app = create_app(twin_station_settings(sessions_dir, overrides))
    with run_uvicorn(app) as base:
        page = browser.new_page(viewport={"width": 1280, "height": 800})
        page.goto(f"{base}/")
        page.locator(f"#task-select option[value='{task_id}']").wait_for(state="attached")
        page.locator("#task-select").select_option(str(task_id))
        page.wait_for_function("document.getElementById('task-map').dataset.vehicle")
        try:
            yield app, base, page
        finally:
            page.context.close()
