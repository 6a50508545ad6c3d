"""A replay runs on its own clock: sessions recorded from it are
in the log's time (rows, times, the post-disarm tail), so they and their analysis are the
same at any replay speed; and a replay that ends while armed closes its session.

One shaped log (tests/shaped_tlog.vehicle_flight) with two sorties 10 s apart (the tail
is 5 s of the log, 0.25 s of wall time at x20) and the log ending while still armed, is
replayed through the real `replay:` source into a real server recording on arming, at
x4, x20 and as fast as it goes; sessions and analyses are read over HTTP."""

from __future__ import annotations

import pytest

from fpv_station.core.mavlink.tlog_records import TlogReader
from fpv_station.server.app import create_app
from tests import shaped_tlog
from tests.helpers import run_uvicorn, station_settings
from tests.known_flights import TWO_SORTIES_END_S, two_sorties
from tests.replayed import replayed_sessions


@pytest.fixture(scope="module")
def sorties_tlog(tmp_path_factory):
    return shaped_tlog.vehicle_flight(two_sorties()).write(
        tmp_path_factory.mktemp("sorties") / "sorties.tlog"
    )


@pytest.mark.timeout(300)
def test_sessions_from_a_replay_are_the_same_at_any_speed(sorties_tlog, tmp_path):
    # Each speed is checked against the log's truth and against the others. Not x1: it
    # takes the log's 37 s of wall time, and there the wall's clock and the log's agree,
    # so it would hide what the other speeds find.
    runs = {
        speed: replayed_sessions(sorties_tlog, speed, tmp_path / speed)
        for speed in ("4", "20", "max")
    }
    log_t0 = next(iter(TlogReader(sorties_tlog)))[0]
    for speed, sessions in runs.items():
        # One session per sortie: the 5 s tail is the log's 5 s at every speed.
        assert [s["stop_reason"] for s in sessions] == ["disarmed", "source ended"], speed
        first, second = sessions
        # In the log's time: starts at the arming, ends 5 s after disarming / at the end.
        assert first["start_wall"] - log_t0 == pytest.approx(1.0, abs=1.1), speed
        assert first["duration_s"] == pytest.approx(
            14.0 + 5.0 - first["start_wall"] + log_t0, abs=0.2
        )
        assert second["end_wall"] - log_t0 == pytest.approx(TWO_SORTIES_END_S, abs=0.2), speed
        for s in sessions:
            assert s["telemetry_rows"] == pytest.approx(30 * s["duration_s"], abs=3), speed
            r = s["result"]
            assert r["trial_time_s"] == pytest.approx(10.0, abs=0.3), speed  # 0.5 m up and down
            assert r["max_speed_mps"] == pytest.approx(2.0, abs=0.3), speed
            # Rates in the log's seconds: ATTITUDE is 50 Hz of the vehicle's, at any speed.
            assert s["rates_hz"]["ATTITUDE"] == pytest.approx(50.0, rel=0.05), speed
    for k in range(2):
        base = runs["4"][k]["result"]["trial_time_s"]
        for speed in ("20", "max"):
            assert runs[speed][k]["result"]["trial_time_s"] == pytest.approx(base, rel=0.01)


def test_a_replays_telemetry_ages_are_in_the_logs_time(sorties_tlog, tmp_path):
    """The pages' ages are `t_server_mono - t_mono` of a group; a replay stamps its groups
    with the log's time, so the message's server time is the log's too. On the station's
    clock every age came out hugely negative (shown as 0: never stale, every message
    kept on the OSD)."""
    import json

    from websockets.sync.client import connect

    log_t0 = next(iter(TlogReader(sorties_tlog)))[0]
    settings = station_settings(f"replay:{sorties_tlog}?speed=4", tmp_path)
    with run_uvicorn(create_app(settings)) as base:
        with connect(base.replace("http", "ws") + "/ws/telemetry", open_timeout=10) as ws:
            for _ in range(20):
                msg = json.loads(ws.recv(timeout=10))
                now = msg["t_server_mono"]
                assert log_t0 <= now <= log_t0 + TWO_SORTIES_END_S + 1
                if msg["state"]["heartbeat"]["t_mono"] is None:
                    continue  # before the log's first heartbeat
                age = now - msg["state"]["heartbeat"]["t_mono"]
                assert 0 <= age < 5.0, age  # heartbeats come every log second
                assert abs(msg["t_server"] - now) < 1.0  # the log's wall time
