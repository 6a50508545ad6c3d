"""A twin flight through the real station ends with the twin's own ULog in its session:
fetched over the MAVLink log protocol after the disarm, recorded in session.json, its
span on the session clock; and the REST and page paths to it."""

from __future__ import annotations

import json
from pathlib import Path

import httpx
import numpy as np
import pytest
from pyulog import ULog

from fpv_station.twin.pilot import Leg
from tests.helpers import chromium, wait_until
from tests.twin_flights import NO_CAMERAS, recorded_twin_flight

LEGS = [Leg("arm"), Leg("climb", alt_m=2.0), Leg("hold", alt_m=2.0, seconds=2.0), Leg("land")]


def _onboard(folder: Path) -> dict | None:
    meta = json.loads((folder / "session.json").read_text())
    return meta.get("onboard_log")


# A flight in real time, then a download (and a browser): minutes on a loaded CI box,
# where the twin's loop, which sends the log, gets a slice of a core (10 kB/s seen).
@pytest.mark.timeout(600)
def test_twin_flight_ends_with_its_ulog_in_the_session(tmp_path: Path) -> None:
    with recorded_twin_flight(tmp_path, 1, NO_CAMERAS, legs=LEGS) as flight:
        assert flight.stop_reason == "disarmed"
        assert wait_until(lambda: _onboard(flight.folder) is not None, 300), httpx.get(
            f"{flight.base_url}/api/onboard_log"
        ).json()
        entry = _onboard(flight.folder)
        assert entry is not None
        status = httpx.get(f"{flight.base_url}/api/onboard_log").json()
        twin_logs = flight.station.twin.flight_log.logs
        served = twin_logs[-1].path.read_bytes()
    assert entry["state"] == "complete", entry
    assert entry["complete"] is True and entry["file"] == "onboard.ulg"
    got = flight.folder / "onboard.ulg"
    assert got.read_bytes() == served
    assert entry["bytes"] == len(served) and entry["download_s"] > 0
    assert status["state"] == "complete" and status["session"] == flight.session_id
    assert status["received_bytes"] == status["size_bytes"] == len(served)

    # The log's IMU is at the physics rate, and its span lies on the session clock
    # where the flight is: the log starts at arming, the session when the station hears
    # the armed HEARTBEAT (1 Hz, and later still when a loaded machine delays the twin),
    # so a little before the session's start; it ends at the disarm, before the
    # session's tail. (On the twin's boot clock the log would start seconds after the
    # twin's boot, waiting for a GPS fix: the mapping is what puts it near 0.)
    imu = next(d for d in ULog(str(got)).data_list if d.name == "sensor_combined")
    t = imu.data["timestamp"] * 1e-6
    assert (len(t) - 1) / (t[-1] - t[0]) >= 249.0
    assert entry["clock"] in ("delay", "timesync")
    meta = json.loads((flight.folder / "session.json").read_text())
    aligned = meta["onboard_alignment"]  # analysis.onboard_log's reading of it
    assert entry["t_s"] == [aligned["start_s"], aligned["end_s"]]
    rows = np.genfromtxt(flight.folder / "telemetry.csv", delimiter=",", names=True)
    t0, t1 = entry["t_s"]
    assert t[0] > 2.0 and -10.0 < t0 <= 0.5, (t[0], t0)
    assert t0 < t1 <= rows["t_s"][-1]


@pytest.mark.timeout(600)
def test_fetch_on_request_and_its_errors(tmp_path: Path) -> None:
    """The REST path: asked for one session's log after the flight (the automatic
    fetch off); a log id the vehicle does not have ends in a clear state; without the
    control token nothing starts. Then the sessions page: its fetch button starts the
    download, its row shows the progress and then the file."""
    overrides = {
        **NO_CAMERAS,
        "onboard_log.after_disarm": False,
        "onboard_log.give_up_s": 200.0,
        "server.token": "secret",
    }
    with recorded_twin_flight(tmp_path, 1, overrides, legs=LEGS) as flight:
        base, sid = flight.base_url, flight.session_id
        url = f"{base}/api/sessions/{sid}/onboard_log"
        assert httpx.get(f"{base}/api/onboard_log").json()["state"] == "idle"
        assert httpx.post(url).status_code == 401
        auth = {"Authorization": "Bearer secret"}
        r = httpx.post(url, json={"log_id": 99}, headers=auth)
        assert r.status_code == 200, r.text
        assert wait_until(lambda: _onboard(flight.folder) is not None, 60)
        entry = _onboard(flight.folder)
        assert entry is not None and entry["state"] == "no_log"
        assert "log 99 is not on the vehicle" in entry["message"]

        bad = httpx.post(f"{base}/api/sessions/nope/onboard_log", headers=auth)
        assert bad.status_code == 400 and bad.json()["error"]

        from playwright.sync_api import expect

        # The twin holds the log's bytes back until the page has shown the download
        # under way (the station asks again meanwhile, within onboard_log.give_up_s).
        logs = flight.station.twin.vehicle.logs
        burst, logs.burst = logs.burst, 0
        with chromium() as browser:
            page = browser.new_page()
            page.on("dialog", lambda d: d.accept("secret"))  # the control token prompt
            page.goto(f"{base}/sessions.html")
            row = page.locator(f'tr[data-id="{sid}"] td.onboard')
            expect(row).to_contain_text("no log")
            row.locator("button.fetch-onboard").click()
            expect(row.locator("progress")).to_be_visible(timeout=60_000)
            logs.burst = burst  # and on
            expect(row.locator("a")).to_have_text("onboard.ulg", timeout=300_000)
            expect(row).not_to_contain_text("incomplete")
        entry = _onboard(flight.folder)
        assert entry is not None and entry["state"] == "complete"
    assert (flight.folder / "onboard.ulg").stat().st_size == entry["bytes"]
