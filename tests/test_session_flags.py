"""Quality flags of recorded sessions (companion/recording/flags.py) on real session
folders: one the station records while the twin crashes, and folders on disk whose
session.json and messages.csv carry the problems a user must see (and the small ones
that must not be flagged). Then the sessions page in real headless chromium."""

from __future__ import annotations

import csv
import json
import time
from collections.abc import Sequence

import httpx
import pytest
from playwright.sync_api import expect
from websockets.sync.client import connect

from fpv_station.companion.recording import layout
from fpv_station.companion.recording.flags import QUALITY_THRESHOLDS, session_flags
from fpv_station.companion.recording.meta import (
    CameraQuality,
    LinkLoss,
    Quality,
    Recovery,
    SessionMeta,
)
from fpv_station.server.app import create_app
from tests.helpers import chromium, run_uvicorn, station_settings, wait_until

START = 1_790_000_000.0  # 2026-09-21


def write_session(
    root,
    n: int,
    *,
    status: str = layout.STATUS_COMPLETE,
    duration_s: float = 100.0,
    dropped: dict[str, int] | None = None,
    link_loss: list[LinkLoss] | None = None,
    gaps: list[LinkLoss] | None = None,
    said: Sequence[tuple[float, int, str]] = (),
    recovered: bool = False,
    stop_reason: str | None = None,
) -> str:
    """A session folder as the recorder leaves it: session.json and messages.csv."""
    sid = layout.session_id_for(START + 600 * n, "sim")
    folder = root / sid
    folder.mkdir(parents=True)
    cams = {
        cam: CameraQuality(
            frames_captured=600, frames_written=600 - k, frames_missed=k, frames_dropped=k
        )
        for cam, k in (dropped or {"front": 0, "bottom": 0}).items()
    }
    quality = Quality(
        telemetry_rate_hz=30.0,
        telemetry_rows=3000,
        cameras=cams,
        link_loss=link_loss or [],
        **({} if gaps is None else {"telemetry_gap_s": 1.0, "telemetry_gaps": gaps}),
    )
    meta = SessionMeta(
        id=sid,
        status=status,
        stop_reason=stop_reason,
        start_wall=START + 600 * n,
        start_utc=layout.utc_label(START + 600 * n),
        end_wall=START + 600 * n + duration_s,
        duration_s=duration_s,
        source="sim",
        quality=quality,
        recovery=Recovery(utc=layout.utc_label(START)) if recovered else None,
    )
    data = meta.model_dump(mode="json")
    if gaps is None:  # written before the recorder kept telemetry gaps
        del data["quality"]["telemetry_gaps"], data["quality"]["telemetry_gap_s"]
    (folder / layout.SESSION_JSON).write_text(json.dumps(data))
    with open(folder / layout.MESSAGES_CSV, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(layout.MESSAGE_COLUMNS)
        for t_s, severity, text in said:
            w.writerow((t_s, START + t_s, severity, "statustext", text, "", ""))
        w.writerow((50.0, START + 50, 4, "command_ack", "COMPONENT_ARM_DISARM: DENIED", 400, 2))
    return sid


def kinds(meta_dir, sid) -> list[str]:
    meta = SessionMeta.model_validate_json((meta_dir / sid / layout.SESSION_JSON).read_bytes())
    return [f.kind for f in session_flags(meta, meta_dir / sid)]


def test_flags_name_real_problems_not_small_ones(tmp_path):
    assert QUALITY_THRESHOLDS.telemetry_gap_s == 1.0
    clean = write_session(
        tmp_path,
        0,
        dropped={"front": 1, "bottom": 29},  # 0.2 % and 4.8 %
        link_loss=[LinkLoss(start_s=10.0, end_s=12.5)],  # 2.5 % of the session
        gaps=[LinkLoss(start_s=10.0, end_s=12.5)],
        said=[(3.0, 6, "Takeoff detected"), (90.0, 4, "Landing detected")],
    )
    assert kinds(tmp_path, clean) == ["telemetry_gap"]  # 2.5 s without the autopilot
    quiet = write_session(tmp_path, 1, dropped={"front": 1}, gaps=[])
    assert kinds(tmp_path, quiet) == []
    bad = write_session(
        tmp_path,
        2,
        dropped={"front": 0, "bottom": 60},  # 10 %
        link_loss=[LinkLoss(start_s=20.0, end_s=28.0), LinkLoss(start_s=95.0)],  # 13 s
        gaps=[LinkLoss(start_s=20.0, end_s=28.0), LinkLoss(start_s=95.0)],
        said=[(40.0, 2, "CRASH: ground impact"), (30.0, 2, "Failsafe enabled: no RC")],
    )
    meta = SessionMeta.model_validate_json((tmp_path / bad / layout.SESSION_JSON).read_bytes())
    flags = {f.kind: f.reason for f in session_flags(meta, tmp_path / bad)}
    assert set(flags) == {"crash", "failsafe", "telemetry_gap", "link_loss", "dropped_frames"}
    assert "CRASH: ground impact (at 40.0 s)" in flags["crash"]
    assert "2 telemetry gaps over 1 s (longest 8.0 s" in flags["telemetry_gap"]
    assert "13.0 s, 13 % of the session (over 10 %)" in flags["link_loss"]
    assert "bottom: 60 of 600 frames dropped, 10 % (over 5 %)" == flags["dropped_frames"]
    # A session from before telemetry gaps were kept: its link-loss intervals stand in.
    old = write_session(tmp_path, 3, link_loss=[LinkLoss(start_s=5.0, end_s=7.0)])
    assert kinds(tmp_path, old) == ["telemetry_gap"]


def test_sessions_page_shows_status_crash_and_flags(tmp_path):
    root = tmp_path / "sessions"
    clean = write_session(root, 0, dropped={"front": 1, "bottom": 0}, gaps=[])
    crashed = write_session(
        root, 1, gaps=[], said=[(42.5, 2, "CRASH: obstacle"), (42.6, 4, "disarmed after crash")]
    )
    recovered = write_session(
        root, 2, status=layout.STATUS_INTERRUPTED, recovered=True, dropped={"front": 100}, gaps=[]
    )
    cut = write_session(root, 3, status=layout.STATUS_CUT_SHORT, stop_reason="disk full", gaps=[])
    settings = station_settings("none", root)
    with run_uvicorn(create_app(settings)) as base:
        listed = {s["id"]: s for s in httpx.get(f"{base}/api/sessions").json()}
        assert listed[clean]["flags"] == []
        assert [f["kind"] for f in listed[crashed]["flags"]] == ["crash"]
        assert listed[recovered]["recovered"] is True
        with chromium() as browser:
            page = browser.new_page()
            page.goto(f"{base}/sessions.html")
            row = lambda sid: page.locator(f'#sessions tr[data-id="{sid}"]')  # noqa: E731
            expect(row(clean).locator("td.status")).to_have_text("complete", timeout=30_000)
            expect(row(clean).locator("td.quality-ok")).to_contain_text("ok")  # 1 frame: fine
            expect(row(crashed)).to_have_class("crashed")
            expect(row(crashed).locator("td.status")).to_have_text("complete CRASHED")
            expect(row(crashed).locator("li[data-flag=crash]")).to_contain_text(
                "CRASH: obstacle (at 42.5 s)"
            )
            expect(row(recovered).locator("td.status")).to_have_text("recovered")
            expect(row(recovered).locator("li[data-flag=dropped_frames]")).to_contain_text(
                "front: 100 of 600 frames dropped, 17 % (over 5 %)"
            )
            expect(row(cut).locator("td.status")).to_have_text("cut short")
            assert row(cut).locator("td.status").get_attribute("title") == "disk full"


@pytest.mark.timeout(180)
def test_a_twin_crash_is_recorded_and_flagged(tmp_path):
    """The station records a flight (auto-record on arming) in which the twin falls out of
    the sky: the session is flagged as a crash with the twin's own words."""
    settings = station_settings(
        "sim",
        tmp_path,
        **{"twin.realtime_factor": 2.0, "recording.auto_record_on_arm": True},
    )
    app = create_app(settings)
    with run_uvicorn(app) as base, connect(base.replace("http", "ws") + "/ws/control") as ws:
        station = app.state.station
        assert wait_until(
            lambda: station.state.get() and station.state.get().value.gps.fix_type == 3, 15
        )
        json.loads(ws.recv(timeout=5))  # hello
        ws.send(json.dumps({"type": "arm"}))
        assert json.loads(ws.recv(timeout=5))["ok"] is True

        def hold(sticks: dict, until, timeout: float) -> None:
            deadline = time.monotonic() + timeout
            while not until():
                ws.send(json.dumps({"type": "sticks", **sticks}))
                time.sleep(0.02)
                assert time.monotonic() < deadline

        hold(
            {"roll": 0, "pitch": 0, "yaw": 0, "throttle": 1.0},
            lambda: station.twin.pose().pos_enu_m[2] > 8.0,
            30,
        )
        ws.send(json.dumps({"type": "mode", "mode": "STABILIZED"}))
        # Throttle cut at 8 m in Stabilized: the twin falls and hits the ground.
        armed = lambda: station.state.get().value.heartbeat.armed  # noqa: E731
        hold({"roll": 0, "pitch": 0, "yaw": 0, "throttle": 0.0}, lambda: not armed(), 30)

        def flagged():
            reply = httpx.get(f"{base}/api/sessions", timeout=30)
            if reply.status_code != 200:
                return None  # a loaded station may answer busy: ask again
            listed = reply.json()
            done = [s for s in listed if not s["recording_now"] and s["status"] == "complete"]
            return done and done[0]

        session = wait_until(flagged, 60)  # a hang guard
        assert session, httpx.get(f"{base}/api/sessions").json()
        crash = [f for f in session["flags"] if f["kind"] == "crash"]
        assert crash and "CRASH: ground impact" in crash[0]["reason"], session["flags"]
