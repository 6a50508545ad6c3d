"""The flight task on the pilot page, in headless Chromium against a real station: the
task chosen survives the station's restart (a new station on the same sessions folder),
and the restarted station's page shows the procedure, the top-view map and the score of
the last trial whole, without scrolling, at a laptop's 1280x720, goggles' 1920x1080 and
a phone upright, beside a front camera at least 0.6 of the width on the laptop and
goggles (the paper's large front view), a bottom camera at least 0.3 of it and the
flight state. On a phone on its side both cameras and the
task's essentials (its choice, map, steps and verdict) are seen whole. The score is the
station's own scoring of a session (server.trials) of a trial that crashed, touched an
obstacle and landed off the pad: invalid for three reasons, its landing accuracy and
which figures are better lower."""

from __future__ import annotations

import datetime as dt
import json

import httpx
import pytest
from playwright.sync_api import expect

from fpv_station.analysis.trial_score import score_and_store
from fpv_station.companion.recording.meta import session_task
from fpv_station.core.scene import load_scene
from tests import synthetic as syn
from tests.helpers import PICTURE_WIDTH
from tests.stations import no_link_station

TOKEN = "task-fit-token"
SIZES = {
    "laptop": {"viewport": {"width": 1280, "height": 720}},
    "goggles": {"viewport": {"width": 1920, "height": 1080}},
    "phone-portrait": {
        "viewport": {"width": 390, "height": 844},
        "is_mobile": True,
        "has_touch": True,
        "device_scale_factor": 2,
    },
    "phone-landscape": {
        "viewport": {"width": 844, "height": 390},
        "is_mobile": True,
        "has_touch": True,
        "device_scale_factor": 2,
    },
}

# Each element's box: on the screen at the first scroll position, and what is drawn at its
# corners and centre is the element itself (nothing covers it, no scrolling box clips it).
SEEN_WHOLE = """(ids) => ids.map((id) => {
  const e = document.getElementById(id);
  if (!e) return [id, 'missing'];
  const r = e.getBoundingClientRect();
  if (r.width < 4 || r.height < 4) return [id, 'empty'];
  if (r.left < 0 || r.top < 0 || r.right > innerWidth + 0.5 || r.bottom > innerHeight + 0.5)
    return [id, `off-screen ${r.left},${r.top},${r.right},${r.bottom} of ${innerWidth}x${innerHeight}`];
  const points = [[r.left + 2, r.top + 2], [r.right - 2, r.top + 2], [r.left + 2, r.bottom - 2],
    [r.right - 2, r.bottom - 2], [(r.left + r.right) / 2, (r.top + r.bottom) / 2]];
  for (const [x, y] of points) {
    const hit = document.elementFromPoint(x, y);
    if (!hit || !(hit === e || e.contains(hit)))
      return [id, `covered at ${x},${y} by ${hit ? hit.outerHTML.slice(0, 80) : 'nothing'}`];
  }
  return [id, 'ok'];
})"""


def crashed_a_to_b_session(root):
    """A recorded A-to-B trial with the vehicle's crash report, flown too low over the
    obstacles and landed short of the pad, chosen as task 2 of the station's field and
    scored by the station's own scoring."""
    scene = load_scene(None)
    task = session_task(scene, None, scene.task(2))
    now = dt.datetime.now(dt.UTC)
    sid = now.strftime("%Y%m%dT%H%M%SZ") + "_sim"
    meta = {
        "id": sid,
        "source": "sim",
        "start_wall": now.timestamp(),
        "start_utc": now.isoformat(timespec="seconds"),
        "task": task.model_dump(mode="json"),
    }
    flight = syn.a_to_b_flight(length_m=36.0, height_m=2.0)
    folder = syn.write_session(flight, root / sid, wall_t0=now.timestamp(), meta=meta)
    crash_at = float(flight.t_s[len(flight.t_s) // 2])
    (folder / "messages.csv").write_text(
        f"t_s,t_wall,severity,kind,text\n{crash_at:.3f},,2,statustext,CRASH: obstacle\n"
    )
    score = score_and_store(folder, task)
    assert score.ok and score.result["valid"] is False, score
    assert len(score.result["invalid_reasons"]) == 3, score.result["invalid_reasons"]
    return score


@pytest.mark.timeout(240)
def test_task_survives_a_restart_and_its_panel_fits_every_screen(tmp_path, browser):
    root = tmp_path / "sessions"
    score = crashed_a_to_b_session(root)
    auth = {"Authorization": f"Bearer {TOKEN}"}

    def restarted():
        """The station (`serve --source none --token`, its 3D panel on) on the same
        sessions folder, started again: (its base URL, the app)."""
        panel = {"viser.enabled": True, "viser.port": 0}
        return no_link_station(root, **{"server.token": TOKEN, **panel})

    with restarted() as (base, _):
        assert httpx.get(f"{base}/api/task").json()["selected"] is None
        reply = httpx.post(f"{base}/api/task", json={"task_id": 2}, headers=auth)
        assert reply.status_code == 200, reply.text
    with restarted() as (base, _):
        task = httpx.get(f"{base}/api/task").json()
        assert task["selected"]["id"] == 2, task["selected"]
        assert task["last_score"]["result"]["valid"] is False  # the newest of today's trials
        for name, options in SIZES.items():
            context = browser.new_context(**options)
            try:
                page = context.new_page()
                page.goto(f"{base}/")
                expect(page.locator("#task-select")).to_have_value("2")
                result = page.locator("#task-result")
                expect(result).to_have_attribute("data-valid", "false")
                expect(result).to_contain_text("Invalid")
                accuracy = score.result["landing_accuracy_m"]
                expect(result).to_contain_text(f"landed from pad landing {accuracy:.3f} m")
                lower = result.locator("[data-field='lateral_deviation_m']")
                assert lower.get_attribute("title") == "lower is better"
                invalid = page.locator("#task-invalid")
                for reason in ("reported a crash", "touched an obstacle", "landed off pad"):
                    expect(invalid).to_contain_text(reason)
                expect(page.locator("#task-procedure li")).to_have_count(4)
                if name == "phone-landscape":
                    shown = ["task-select", "task-map", "task-steps", "task-result"]
                    shown += ["front-view", "bottom-view"]
                else:
                    shown = ["task-procedure", "task-map", "task-score"]
                seen = dict(page.evaluate(SEEN_WHOLE, shown))
                assert seen == dict.fromkeys(seen, "ok"), (name, seen)
                if name in ("laptop", "goggles"):
                    picture, width = page.evaluate(PICTURE_WIDTH, "front-view")
                    assert picture >= 0.6 * width, (name, picture, width)
                    bottom, _ = page.evaluate(PICTURE_WIDTH, "bottom-view")
                    assert bottom >= 0.3 * width, (name, bottom, width)
                    views = ["front-view", "bottom-view", "flight-state"]
                    seen = dict(page.evaluate(SEEN_WHOLE, views))
                    assert seen == dict.fromkeys(seen, "ok"), (name, seen)
            finally:
                context.close()
    # The choice is a file of the sessions folder, beside the sessions it goes into.
    saved = json.loads((root / "chosen_task.json").read_text())
    assert saved["task_id"] == 2
    # Set to none, it stays none.
    with restarted() as (base, _):
        reply = httpx.post(f"{base}/api/task", json={"task_id": None}, headers=auth)
        assert reply.status_code == 200, reply.text
    with restarted() as (base, _):
        assert httpx.get(f"{base}/api/task").json()["selected"] is None
