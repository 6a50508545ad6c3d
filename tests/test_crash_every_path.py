"""A crash reads the same from every file of a flight: an ArduCopter hover that says
"Crash: Disarming" mid-flight is recorded by a real station (a shaped tlog replayed into
it), then scored from the session folder, from the session's zip as the station serves
it, and from its mavlink.tlog copied away from the session: all three say the trial is
not valid, for the same crash, with the same figures."""

from __future__ import annotations

import shutil

import httpx
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.analysis.report import analyze_paths
from tests import shaped_tlog
from tests import synthetic as syn
from tests.replayed import replayed_station

CRASH_S = 20.0  # into the hover (armed at 1 s, 4 m reached by 7 s, landing from 31 s)
CRASH_TEXT = "Crash: Disarming"


def crashed_hover(path):
    log = shaped_tlog.vehicle_flight(syn.hover_flight(), mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA)
    ap = log.sender(1, 1)
    ap.mav.seq = 0
    log.emit(
        ap, CRASH_S, ap.mav.statustext_encode(mavlink.MAV_SEVERITY_EMERGENCY, CRASH_TEXT.encode())
    )
    return log.write(path)


@pytest.mark.timeout(180)
def test_a_crash_is_scored_from_the_folder_the_zip_and_the_tlog(tmp_path):
    sessions = tmp_path / "sessions"
    with replayed_station(crashed_hover(tmp_path / "flight.tlog"), sessions) as base:
        (session,) = httpx.get(f"{base}/api/sessions", timeout=30).json()
        sid = session["id"]
        reply = httpx.get(f"{base}/api/sessions/{sid}/download", timeout=60)
        assert reply.status_code == 200
    folder = sessions / sid
    zipped = tmp_path / f"{sid}.zip"
    zipped.write_bytes(reply.content)
    bare = tmp_path / "bare" / "flight.tlog"  # a tlog on its own: no session beside it
    bare.parent.mkdir()
    shutil.copy(folder / "mavlink.tlog", bare)

    results = {
        name: analyze_paths([path], "hover", scene=False).results[0]
        for name, path in (("folder", folder), ("zip", zipped), ("tlog", bare))
    }
    for name, r in results.items():
        assert not r.valid, name
        (reason,) = r.invalid_reasons
        assert "reported a crash" in reason and CRASH_TEXT in reason, (name, reason)
    folder_r = results["folder"]
    for name in ("zip", "tlog"):
        r = results[name]
        assert r.trial_time_s == pytest.approx(folder_r.trial_time_s, rel=0.01), name
        assert r.hover_distance_m == pytest.approx(folder_r.hover_distance_m, rel=0.01, abs=0.01)
    # The zip is the folder's own files: the very same reason, to the crash's time.
    assert results["zip"].invalid_reasons == folder_r.invalid_reasons
