"""The station with a real MAVLink link over UDP: recording starts on arming, stops after
the post-disarm tail, notes link loss, and its tlog replays through the `replay:` source."""

import csv
import json
import time

import httpx
import numpy as np
import pytest

from fpv_station.companion.link import MavlinkLink
from fpv_station.companion.link_settings import LinkSettings
from fpv_station.companion.recording import layout
from fpv_station.server.app import create_app
from fpv_station.server.settings import load_settings
from tests.helpers import run_uvicorn, wait_until
from tests.mav_vehicle import MavVehicle


def test_arm_records_disarm_stops_and_tlog_replays(tmp_path):
    root = tmp_path / "sessions"
    with MavVehicle("udp") as v:
        settings = load_settings(
            environ={},
            overrides={
                "link.source": v.station_source,
                "link.link_lost_s": 0.5,
                "viser.enabled": False,
                "recording.sessions_dir": str(root),
                "recording.rate_hz": 50,
                "recording.post_disarm_tail_s": 0.8,
                "recording.min_free_mb": 0,
            },
        )
        with run_uvicorn(create_app(settings)) as base:
            status = lambda: httpx.get(f"{base}/api/recording").json()  # noqa: E731
            time.sleep(1.0)  # first fix: the pilot altitude gets a reference
            assert status()["recording"] is False
            v.arm()
            assert wait_until(lambda: status()["recording"], timeout=5)
            assert status()["trigger"] == "arm"
            for _ in range(10):  # climb 4 m, above home as an autopilot reports it
                v.alt_m += 0.4
                v.relative_alt_m += 0.4
                time.sleep(0.1)
            time.sleep(0.5)
            v.silent = True  # out of range for a while
            time.sleep(1.2)
            v.silent = False
            time.sleep(0.8)
            v.disarm()
            assert wait_until(lambda: not status()["recording"], timeout=5)
            last = status()["last_stop"]
            assert last["reason"] == "disarmed"
    folder = root / last["id"]
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["status"] == "complete" and meta["source"] == v.station_source
    assert meta["settings"]["recording"]["rate_hz"] == 50 and "twin" not in meta["settings"]
    assert meta["settings"]["cameras"]["front"]["fps"] == 30.0
    assert meta["arming"]["reference_alt_m"] == pytest.approx(180.0)
    assert meta["arming"]["home_lat_deg"] == pytest.approx(43.0021)
    losses = meta["quality"]["link_loss"]
    assert len(losses) == 1 and losses[0]["end_s"] is not None
    assert 0.8 < losses[0]["end_s"] - losses[0]["start_s"] < 2.0

    with open(folder / layout.TELEMETRY_CSV, newline="") as f:
        rows = list(csv.DictReader(f))
    t = np.array([float(r["t_s"]) for r in rows])
    assert abs(np.median(np.diff(t)) - 1 / 50) < 0.002
    rel_alt = np.array([float(r["altitude.relative_alt_m"] or "nan") for r in rows])
    assert np.nanmax(rel_alt) == pytest.approx(4.0, abs=0.05)  # arming-relative
    assert rows[0]["heartbeat.armed"] == "1" and rows[-1]["heartbeat.armed"] == "0"
    # The post-disarm tail (0.8 s) is recorded: it starts once the disarmed state is seen,
    # so the disarmed rows span at least the tail, less one row period.
    armed = np.array([r["heartbeat.armed"] == "1" for r in rows])
    disarmed_from = t[np.flatnonzero(armed)[-1] + 1]
    assert t[-1] - disarmed_from >= 0.8 - 1 / 50 - 1e-6, (disarmed_from, t[-1])
    assert rows[-1]["heartbeat.mode"] == "POSCTL" and rows[-1]["rc.pwm_us.0"] == "1500"

    # The tlog plays back through the station's own replay source.
    tlog = folder / layout.MAVLINK_TLOG
    replayed = []
    link = MavlinkLink(LinkSettings(source=f"replay:{tlog}?speed=0"))
    link.add_packet_listener(lambda t_wall, pkt: replayed.append(pkt))
    link.start()
    try:
        assert wait_until(lambda: link.health().replay_done, timeout=10)
        assert len(replayed) == meta["quality"]["tlog_packets"] > 100
        assert link.health().truncated_records == 0
        st = link.state.get().value
        assert st.global_position.alt_m == pytest.approx(184.0, abs=0.05)
        assert st.heartbeat.armed is False
    finally:
        link.stop()
