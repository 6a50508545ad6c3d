"""One trial per flight: a session or log holding several take-off and
landing cycles gives one row per flight, labelled, and `flight` / `--flight N` picks one.
Two sorties 3 s apart (less than the 5 s post-disarm tail) make one session from the
real `replay:` source and recorder; its analysis over REST and the CLI on the log split it."""

from __future__ import annotations

import subprocess
import sys

import httpx
import pytest

from fpv_station.server.app import create_app
from tests import shaped_tlog
from tests.helpers import run_uvicorn, station_settings, wait_until
from tests.known_flights import JOINED_SORTIES, JOINED_SORTIES_END_S, two_sorties


@pytest.fixture(scope="module")
def joined_tlog(tmp_path_factory):
    flight = two_sorties(JOINED_SORTIES, end_s=JOINED_SORTIES_END_S)
    return shaped_tlog.vehicle_flight(flight).write(tmp_path_factory.mktemp("j") / "joined.tlog")


@pytest.mark.timeout(120)
def test_a_session_joining_two_flights_gives_one_row_each(joined_tlog, tmp_path):
    settings = station_settings(
        f"replay:{joined_tlog}?speed=max", tmp_path, **{"recording.auto_record_on_arm": True}
    )
    with run_uvicorn(create_app(settings)) as base:
        get = lambda url: httpx.get(f"{base}{url}", timeout=30)  # noqa: E731
        assert wait_until(lambda: get("/api/status").json()["link"]["replay_done"], 60)
        assert wait_until(lambda: not get("/api/recording").json()["recording"], 10)
        (session,) = get("/api/sessions").json()  # the tail joined the two flights
        url = f"/api/sessions/{session['id']}/analysis?task=a-to-b"
        table = get(url).json()
        one = get(f"{url}&flight=2").json()
        missing = get(f"{url}&flight=3")
    rows = table["results"]
    assert [r["flight"] for r in rows] == [1, 2]
    assert [r["label"] for r in rows] == [f"{session['id']} flight {n}" for n in (1, 2)]
    for r, (arm, _) in zip(rows, JOINED_SORTIES):
        assert r["trial_time_s"] == pytest.approx(10.0, abs=0.3)  # not 26 s, first to last
        # take-off 1.5 s after arming, on the session's clock (which starts at arming 1)
        assert r["takeoff_s"] - rows[0]["takeoff_s"] == pytest.approx(
            arm - JOINED_SORTIES[0][0], abs=0.1
        )
        assert r["path_length_m"] == pytest.approx(12.0 + 2 * 2.5, abs=1.5)  # above 0.5 m
    assert [r["flight"] for r in one["results"]] == [2]
    assert one["results"][0]["trial_time_s"] == rows[1]["trial_time_s"]
    assert missing.status_code == 422 and "no flight 3" in missing.json()["error_msg"]


def test_cli_flight_picks_one(joined_tlog, tmp_path):
    def analyze(*extra: str) -> subprocess.CompletedProcess:
        cmd = [
            sys.executable,
            "-m",
            "fpv_station.server",
            "analyze",
            str(joined_tlog),
            "--task",
            "a-to-b",
        ]
        cmd += ["--no-scene", "--out", str(tmp_path), *extra]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=120)

    every = analyze()
    assert every.returncode == 0, every.stderr
    assert "joined flight 1" in every.stdout and "joined flight 2" in every.stdout
    second = analyze("--flight", "2")
    assert second.returncode == 0, second.stderr
    assert "joined flight 2" in second.stdout and "flight 1" not in second.stdout
    bad = analyze("--flight", "0")
    assert bad.returncode == 2 and "counts from 1" in bad.stderr
