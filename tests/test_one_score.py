"""The trial the station scores at disarm is the trial every later read gives: the REST
analysis, `fpv-station analyze` and the sessions page, to the last bit, for a session
whose vehicle clock was measured (session.json `clock.vehicle_boot`, TIMESYNC)."""

from __future__ import annotations

import json
from pathlib import Path

import httpx

from fpv_station.analysis.report import analyze_paths
from fpv_station.analysis.trial_score import score_and_store
from fpv_station.companion.recording import layout
from fpv_station.companion.recording.meta import SessionMeta, session_task
from fpv_station.core.scene import load_scene
from fpv_station.server.app import create_app
from fpv_station.server.cli import main as cli_main
from tests import synthetic as syn
from tests.helpers import run_uvicorn, station_settings

SESSION = "20261122T060000Z_sim"
WALL_T0 = 1.7e9
# The vehicle's clock, measured: it runs 0.2 % fast against the station's, so its samples
# arrive up to a few hundredths of a second after they were made (within one GPS period).
BOOT = {"method": "timesync", "reason": "measured", "offset_s": 0.0, "drift_ppm": -2000.0}


def _session(root: Path, session_id: str, boot: dict | None) -> Path:
    """A finished hover session of task 1, as the recorder leaves it at disarm."""
    scene = load_scene(None)
    task = session_task(scene, None, scene.task(1))
    clock = {
        "used": "station",
        "reason": "the station's clock is synchronised",
        "station_start_wall": WALL_T0,
        "max_disagree_s": 2.0,
        "vehicle_boot": boot,
    }
    meta = SessionMeta(
        id=session_id,
        status=layout.STATUS_COMPLETE,
        start_wall=WALL_T0,
        start_utc=layout.utc_label(WALL_T0),
        source="sim",
        trigger="arm",
        task=task,
        clock=clock,
    )
    folder = syn.write_session(syn.hover_flight(), root / session_id, wall_t0=WALL_T0)
    (folder / layout.SESSION_JSON).write_text(json.dumps(meta.model_dump(mode="json")))
    return folder


def _figures(result: dict) -> dict:
    return {k: v for k, v in result.items() if k != "source"}


def test_the_score_at_disarm_is_what_rest_the_cli_and_the_sessions_page_give(tmp_path):
    root = tmp_path / "sessions"
    folder = _session(root, SESSION, BOOT)
    # The measured clock decides the figures: the same flight timed by arrival differs.
    unmeasured = analyze_paths([_session(tmp_path / "other", SESSION, None)], "hover")
    by_arrival = unmeasured.results[0].to_dict()

    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    score = score_and_store(folder, SessionMeta.model_validate(meta).task)  # the disarm hook's
    assert score.ok, score.reason
    scored = score.result
    assert scored["source"] == SESSION and scored["trial_time_s"] != by_arrival["trial_time_s"]

    app = create_app(station_settings("none", root))
    with run_uvicorn(app) as base:
        r = httpx.get(
            f"{base}/api/sessions/{SESSION}/analysis", params={"task": "hover"}, timeout=60
        )
        listed = httpx.get(f"{base}/api/sessions", timeout=30).json()
    assert r.status_code == 200, r.text
    rest = r.json()["results"]
    assert len(rest) == 1 and _figures(rest[0]) == _figures(scored)  # every figure, every bit

    # The CLI on the session, and on its rows alone.
    for i, path in enumerate((folder, folder / layout.TELEMETRY_CSV)):
        out = tmp_path / f"cli{i}"
        assert cli_main(["analyze", "--task", "hover", str(path), "--out", str(out)]) == 0
        cli = json.loads((out / "hover_table.json").read_text())["results"]
        assert len(cli) == 1 and _figures(cli[0]) == _figures(scored), path.name

    row = next(s for s in listed if s["id"] == SESSION)
    assert row["score"]["ok"] and _figures(row["score"]["result"]) == _figures(scored)
