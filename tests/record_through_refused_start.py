"""A station whose recording cannot start when the vehicle arms (no descriptor left), and
that records the flight once descriptors are back.

    python -m tests.record_through_refused_start SESSIONS_DIR
Lowers RLIMIT_NOFILE, serves a real station (uvicorn, the link over UDP to the test
vehicle, recording on arming), takes every free descriptor, arms the vehicle and keeps the
descriptors for REFUSED_S, reading /api/health and /api/status over a connection opened
before; then gives them back, waits for the recording and disarms. Lines:
"REFUSED health=<status> not_recording=<bool> reasons=<json>" (while starved),
"STARTED <id> trigger=<trigger> after=<s>" (or "NOT STARTED"), "HEALTH <status>" (once recording),
"STOPPED <reason>", "DONE".
"""

from __future__ import annotations

import json
import os
import resource
import sys
import time
from pathlib import Path

import httpx

from fpv_station.server.app import create_app
from tests.helpers import run_uvicorn, station_settings, wait_until
from tests.mav_vehicle import MavVehicle
from tests.recording_fakes import starve

REFUSED_S = 3.0  # armed and starved this long: the retry is refused a few times


def main(root: Path) -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (256, 256))  # the station may not raise it
    hog: list[int] = []
    with MavVehicle("udp") as vehicle:
        settings = station_settings(
            vehicle.station_source,
            root,
            **{"recording.auto_record_on_arm": True, "recording.post_disarm_tail_s": 0.5},
        )
        app = create_app(settings)
        with run_uvicorn(app) as base, httpx.Client(base_url=base, timeout=10) as client:
            station = app.state.station
            got = lambda: client.get("/api/status").json()  # noqa: E731
            # The connection the starved station is read over: opened now, kept alive.
            assert wait_until(lambda: got()["state"] is not None, 20), "no vehicle state"
            starve(hog)
            vehicle.arm()
            deadline = time.monotonic() + REFUSED_S
            health: dict = {}
            status: dict = {}
            while time.monotonic() < deadline:
                starve(hog)
                health = client.get("/api/health").json()
                status = got()
                time.sleep(0.3)  # well inside the keep-alive timeout
            print(
                f"REFUSED health={health['status']} "
                f"not_recording={status['recording']['not_recording']} "
                f"reasons={json.dumps(health['reasons'])}",
                flush=True,
            )
            for fd in hog:
                os.close(fd)
            hog.clear()
            released = time.monotonic()
            # A hang guard: the retry tries every second while armed.
            if wait_until(lambda: station.recorder.session is not None, 5.0):
                session = station.recorder.session
                after = time.monotonic() - released  # for people: no test asserts it
                print(f"STARTED {session.id} trigger={session.trigger}", end="")
                print(f" after={after:.2f}s", flush=True)
            else:
                print("NOT STARTED", flush=True)
            print(f"HEALTH {client.get('/api/health').json()['status']}", flush=True)
            time.sleep(1.0)
            vehicle.disarm()
            if wait_until(lambda: station.recorder.session is None, 10.0):
                print(f"STOPPED {station.recorder.last_stop.reason}", flush=True)
    print("DONE", flush=True)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
