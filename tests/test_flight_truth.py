"""What the station reports must match the vehicle: shaped tlogs (tests/shaped_tlog.py)
replayed through the real `replay:` source into a real server, read over HTTP, and
compared with the truth each log was written from and with pymavlink's own tools."""

from __future__ import annotations

import json

import httpx
import pytest

from fpv_station.companion.recording import layout
from fpv_station.server.app import create_app
from tests import shaped_tlog
from tests.helpers import run_uvicorn, station_settings, wait_until
from tests.replayed import by_stream, mavloss, replay_status


@pytest.mark.timeout(120)
def test_loss_per_stream_with_a_sik_radio_matches_the_truth_and_mavloss(tmp_path):
    log = shaped_tlog.sik_radio_link()
    path = log.write(tmp_path / "sik.tlog")
    truth = log.truth[(1, 1)]
    assert truth.lost > 200  # random loss plus a 1.8 s fade: a real log's shape

    link = replay_status(path)["link"]
    streams = by_stream(link)
    # The headline is the autopilot's loss, not the radio's repeated numbers.
    assert link["autopilot_sysid"] == 1 and link["autopilot_compid"] == 1
    assert link["lost_packets"] == pytest.approx(truth.lost, abs=2)  # a lost tail is unseen
    assert abs(link["loss_ratio"] - truth.loss_ratio) < 0.001
    assert streams[(1, 1)]["role"] == "autopilot"
    radio = streams[(51, 68)]
    assert radio["role"] == "radio" and radio["lost"] == 0
    assert radio["duplicates"] == log.truth[(51, 68)].duplicates > 100
    for gcs in ((255, 190), (255, 0)):
        assert streams[gcs]["role"] == "gcs" and streams[gcs]["lost"] == 0

    # Within one percentage point of pymavlink's mavloss on the same file, per stream and
    # over every stream but the radio (which mavloss leaves out).
    ref = mavloss(path)
    assert abs(100 * link["loss_ratio"] - ref.get((1, 1), ref["total"])) < 1.0
    others = [s for k, s in streams.items() if k != (51, 68)]
    lost = sum(s["lost"] for s in others)
    total = 100 * lost / (lost + sum(s["packets"] for s in others))
    assert abs(total - ref["total"]) < 1.0


def test_no_battery_monitor_is_unknown_not_zero_volts(tmp_path):
    path = shaped_tlog.no_battery_monitor().write(tmp_path / "nobatt.tlog")
    battery = replay_status(path)["state"]["battery"]
    assert battery["t_mono"] is not None  # SYS_STATUS was heard
    assert battery["voltage_v"] is None


@pytest.mark.timeout(120)
def test_session_link_loss_is_the_autopilots_silence(tmp_path):
    """45 s without the autopilot while the radio and a GCS talk on: one link-loss interval
    of 45 s in the session, as /api/status showed link_lost."""
    speed = 10  # the replay's pace; the session is recorded in the log's time
    log = shaped_tlog.silent_vehicle()
    path = log.write(tmp_path / "silent.tlog")
    settings = station_settings(f"replay:{path}?speed={speed}", tmp_path / "sessions")
    with run_uvicorn(create_app(settings)) as base:
        assert httpx.post(f"{base}/api/recording/start").status_code == 200
        status = lambda: httpx.get(f"{base}/api/status").json()  # noqa: E731
        assert wait_until(lambda: status()["link"]["link_lost"], timeout=20)
        assert wait_until(lambda: status()["link"]["replay_done"], timeout=30)
        session = httpx.post(f"{base}/api/recording/stop").json()["last_stop"]["id"]
    meta = json.loads((tmp_path / "sessions" / session / layout.SESSION_JSON).read_text())
    losses = meta["quality"]["link_loss"]
    assert len(losses) == 1, losses
    silence_log_s = losses[0]["end_s"] - losses[0]["start_s"]
    assert silence_log_s == pytest.approx(45.0, abs=2.0)
