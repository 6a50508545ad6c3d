"""A trial's score says whether it counts: a twin flight that crashes into an obstacle
and one that lands off its pad are scored `valid: false` with the reason in words, by
the station on disarm and by the REST analysis alike; no message a client can read
names the server's folders."""

from __future__ import annotations

import json

import httpx
import numpy as np
import pytest

from fpv_station.analysis.tasks import TaskParams, analyze
from fpv_station.analysis.trial_score import score_session
from fpv_station.companion.recording.meta import SessionTask
from fpv_station.server.app import create_app
from fpv_station.server.settings import load_settings
from fpv_station.twin.pilot import Leg
from tests import synthetic as syn
from tests.helpers import run_uvicorn, wait_until
from tests.twin_flights import NO_CAMERAS, recorded_twin_flight


def _choose(task_id: int):
    def choose(base: str) -> None:
        r = httpx.post(f"{base}/api/task", json={"task_id": task_id}, timeout=5)
        assert r.status_code == 200, r.text

    return choose


def _scored(base: str) -> dict:
    assert wait_until(lambda: httpx.get(f"{base}/api/task").json()["last_score"], 60)
    return httpx.get(f"{base}/api/task").json()["last_score"]


def _rest(base: str, session_id: str, task: str) -> dict:
    r = httpx.get(f"{base}/api/sessions/{session_id}/analysis", params={"task": task}, timeout=60)
    assert r.status_code == 200, r.text
    return r.json()["results"][0]


@pytest.mark.timeout(240)
def test_a_crash_into_obstacle_1_is_not_a_valid_trial(tmp_path):
    # Task 2 (A to B) flown at 2 m, below the obstacles' 3 m: straight into obstacle 1.
    legs = [Leg("arm"), Leg("climb", alt_m=2.0), Leg("goto", (-7.0, 0.0), 2.0)]
    with recorded_twin_flight(
        tmp_path, 2, NO_CAMERAS, before_flight=_choose(2), legs=legs, crash=True
    ) as flight:
        score = _scored(flight.base_url)
        rest = _rest(flight.base_url, flight.session_id, "a-to-b")
    assert score["ok"], score  # it was measured ...
    result = score["result"]
    assert result["valid"] is False  # ... and it does not count
    assert any("crash" in r and "obstacle" in r for r in result["invalid_reasons"]), result
    assert result["landing_pad"] == "landing" and result["landing_accuracy_m"] > 20
    assert rest["valid"] is False and rest["invalid_reasons"] == result["invalid_reasons"]
    assert result["source"] == flight.session_id and str(tmp_path) not in str(score)


@pytest.mark.timeout(240)
def test_a_landing_off_the_pad_is_not_a_valid_trial(tmp_path):
    # Task 1 flown to the letter, then landed 2.7 m east of the start pad's centre.
    legs = [
        Leg("arm"),
        Leg("climb", alt_m=4.0),
        Leg("hold", alt_m=4.0, seconds=10.5),
        Leg("goto", (-17.3, 0.0), 4.0, tolerance_m=0.2),
        Leg("land"),
    ]
    with recorded_twin_flight(tmp_path, 1, NO_CAMERAS, before_flight=_choose(1), legs=legs) as f:
        twin = f.station.twin
        pad = twin.scene.pad("start")
        # Where it really landed: the pilot's goto stops within its tolerance and the
        # descent drifts, more so when the twin is starved of CPU.
        landed_off_m = float(np.hypot(*(twin.pose().pos_enu_m[:2] - pad.xy_m)))
        score = _scored(f.base_url)
        rest = _rest(f.base_url, f.session_id, "hover")
    result = score["result"]
    assert score["ok"] and result["valid"] is False, score
    assert result["landing_pad"] == "start"
    assert landed_off_m > pad.size_m  # clearly off the pad
    assert result["landing_accuracy_m"] == pytest.approx(landed_off_m, abs=0.3)
    (reason,) = result["invalid_reasons"]
    assert "landed off pad 'start'" in reason and "m from its centre" in reason
    assert rest["valid"] is False and rest["landing_accuracy_m"] == result["landing_accuracy_m"]


def test_no_message_names_a_server_folder(tmp_path):
    """Every text a client reads about a session: REST errors, skipped flights, a result's
    source and a score's reason name the session, not where the server keeps it."""
    root = tmp_path / "deep" / "sessions"
    low = "20261122T040000Z_udp"  # a hover that never reaches 4 m
    nofix = "20261122T041000Z_udp"
    syn.write_session(syn.hover_flight(height_m=2.0), root / low, meta={"id": low})
    syn.write_session(syn.hover_flight(), root / nofix, fix_type=0)
    # Scored by an older station, which kept its folders in the score's texts.
    old = "20261122T042000Z_sim"
    folder = str(root / old)
    score = {
        "task": "hover",
        "ok": True,
        "scored_utc": "2026-11-22T04:21:00+00:00",
        "reason": f"'{folder}': noted",
        "result": {"source": folder, "valid": True},
    }
    meta = {"id": old, "start_wall": 1.7e9, "start_utc": "2026-11-22T04:20:00Z", "score": score}
    syn.write_session(syn.hover_flight(), root / old, meta=meta)
    overrides = {
        "link.source": "none",
        "recording.sessions_dir": str(root),
        "recording.auto_record_on_arm": False,
        "recording.min_free_mb": 0,
    }
    texts = []
    with run_uvicorn(create_app(load_settings(environ={}, overrides=overrides))) as base:
        for sid, task in ((low, "hover"), (nofix, "hover"), (low, "a-to-b")):
            r = httpx.get(f"{base}/api/sessions/{sid}/analysis", params={"task": task}, timeout=60)
            assert r.status_code == 422, r.text
            texts.append(r.json()["error_msg"])
        r = httpx.get(f"{base}/api/sessions/{low}/analysis/birdseye.png?task=hover", timeout=60)
        texts.append(r.json()["error_msg"])
        listed = httpx.get(f"{base}/api/sessions", timeout=30)
        detail = httpx.get(f"{base}/api/sessions/{old}", timeout=30)
        texts += [listed.text, json.dumps(detail.json()["meta"]["score"])]
        assert old in listed.text and detail.json()["meta"]["score"]["result"]["source"] == old
    assert "never reached 4 m" in texts[0] and low in texts[0]
    task = SessionTask(id=1, name="hover", analysis="hover", scene="s", start_pad="start",
                       end_pad="start", altitude_m=4.0, hold_s=10.0)  # fmt: skip
    score = score_session(root / low, task)
    assert not score.ok and "never reached" in score.reason
    texts.append(score.reason)
    for text in texts:
        assert str(tmp_path) not in text and "/deep/" not in text, text


def test_a_good_trial_is_valid_and_says_how_far_it_landed(tmp_path):
    """The library's view of a clean hover on a field: valid, landed on the pad."""
    from fpv_station.analysis.field_layout import FieldLayout, Pad
    from fpv_station.analysis.flight_frame import align_track
    from fpv_station.analysis.track import load_track

    flight = syn.hover_flight()
    folder = syn.write_session(flight, tmp_path / "s", meta={"source": "sim"})
    lat, lon = flight.point_llh(0.0, 0.0)
    field = FieldLayout(home=(lat, lon, 0.0), pads=(Pad("start", 0.0, 0.0), Pad("b", 30.0, 0.0)))
    a = align_track(load_track(folder), field=field)
    r = analyze(a, "hover", TaskParams())
    assert r.valid and r.invalid_reasons == ()
    assert r.landing_pad == "start" and r.landing_accuracy_m == pytest.approx(
        0.3, abs=0.1
    )  # the circle
    off = analyze(a, "hover", TaskParams(), landing_pad="b")
    assert not off.valid and "landed off pad 'b'" in off.invalid_reasons[0]
    crashed = analyze(a, "hover", TaskParams(), crashes=[(12.0, "CRASH: obstacle")])
    assert crashed.invalid_reasons == ("the vehicle reported a crash at 12.0 s (CRASH: obstacle)",)
