"""The station on the digital twin records a scripted take-off / hover / land.

The twin's scripted pilot flies task 1 (climb to 4 m, hold 10 s, land) with the same
sticks a person gives; recording starts on arming and stops after the post-disarm tail.
"""

import csv
import json

import numpy as np
import pytest

from fpv_station.analysis.track import load_session_dir
from fpv_station.companion.link import MavlinkLink
from fpv_station.companion.link_settings import LinkSettings
from fpv_station.companion.recording import layout
from tests.helpers import wait_until
from tests.recording_fakes import recorded_frames
from tests.twin_flights import recorded_twin_flight

RATE_HZ = 30.0


def test_twin_hover_flight_is_recorded_in_sync(tmp_path):
    with recorded_twin_flight(tmp_path, 1, {"recording.rate_hz": RATE_HZ}) as flight:
        fps = {n: cam.config.fps for n, cam in flight.station.cameras.items()}
        last = flight.station.recorder.last_stop
    assert last.reason == "disarmed"
    folder = tmp_path / last.id
    meta = json.loads((folder / layout.SESSION_JSON).read_text())
    assert meta["status"] == "complete" and meta["trigger"] == "arm"
    assert meta["source"] == "sim" and meta["arming"]["reference_alt_m"] is not None
    assert meta["settings"]["twin"]["seed"] == 0  # how the flight was made, for datasets

    with open(folder / layout.TELEMETRY_CSV, newline="") as f:
        rows = list(csv.DictReader(f))
    t = np.array([float(r["t_s"]) for r in rows])
    # The flight: climb, 10 s held, landing. No upper bound: the twin flies in real time
    # and a loaded box stretches it; the stop is the disarm's (`last.reason` above).
    assert t[-1] > 15, t[-1]
    assert abs(np.median(np.diff(t)) - 1 / RATE_HZ) < 0.002
    # Rows on the configured grid; instants whose state is not known (the writer held
    # up past the state history) are skipped and counted, not bunched.
    late = meta["quality"]["telemetry_ticks_late"]
    dropped = meta["quality"]["telemetry_rows_dropped"]
    assert len(rows) + late + dropped == pytest.approx(t[-1] * RATE_HZ + 1, abs=3)
    # Most instants are rows: the floor is half, as for every rate check (a starved CI box
    # at load 13 gave 640 of 821 instants; the exact account is the line above).
    assert len(rows) >= 0.5 * t[-1] * RATE_HZ
    rel_alt = np.array([float(r["altitude.relative_alt_m"] or "nan") for r in rows])
    assert np.nanmax(rel_alt) == pytest.approx(4.0, abs=0.4)  # arming-relative
    assert {r["altitude.reference"] for r in rows} == {"arming"}
    # What the vehicle said during the flight, on the session clock (messages.csv).
    with open(folder / layout.MESSAGES_CSV, newline="") as f:
        said = list(csv.DictReader(f))
    assert tuple(said[0]) == layout.MESSAGE_COLUMNS if said else False
    landing = [m for m in said if m["kind"] == "statustext" and "landing" in m["text"]]
    assert landing and 0 < float(landing[-1]["t_s"]) <= t[-1] + 0.5
    assert all(m["t_wall"] and 0 <= int(m["severity"]) <= 7 for m in said)
    assert abs(rel_alt[-1]) < 0.5  # landed again
    armed = np.array([r["heartbeat.armed"] == "1" for r in rows])
    assert armed[0] and not armed[-1]
    rc_throttle = np.array([int(r["rc.pwm_us.2"] or 0) for r in rows])
    assert rc_throttle.max() > 1600 and rc_throttle.min() < 1400  # the pilot's sticks

    for cam in layout.CAMERAS:
        refs = {r[f"{cam}.file"] for r in rows if r[f"{cam}.file"]}
        on_disk = recorded_frames(folder, cam)
        assert refs <= on_disk.keys()  # every frame named is on disk
        q = meta["quality"]["cameras"][cam]
        frames = list(csv.DictReader(open(folder / layout.frames_csv_relpath(cam))))
        assert q["frames_written"] == len(frames) == len(on_disk)
        assert all(len(on_disk[fr["file"]]) == int(fr["bytes"]) for fr in frames)
        assert all(j[:2] == b"\xff\xd8" and j[-2:] == b"\xff\xd9" for j in on_disk.values())
        # Each row names the newest frame captured at or before its instant, however
        # unevenly the twin (rendering on the same loaded CPU) delivers them: never one
        # from the row's future (no negative skew), never an older one.
        t_cap = np.array([float(fr["t_s"]) for fr in frames])
        seqs = [int(fr["seq"]) for fr in frames]
        # (The files round times to the microsecond: a frame within one of the row's
        # instant may be either side of it.)
        newest = np.searchsorted(t_cap, t + 1e-6, side="right")
        surely = np.searchsorted(t_cap, t - 1e-6, side="right")
        for r, k, k_sure in zip(rows, newest, surely):
            want = {str(seqs[i - 1]) if i else "" for i in range(k_sure, k + 1)}
            assert r[f"{cam}.seq"] in want, (cam, r["t_s"], r[f"{cam}.seq"], want)
            assert not r[f"{cam}.seq"] or float(r[f"{cam}.skew_s"]) >= 0, (cam, r["t_s"])
        assert len(refs) > 50, len(refs)
        # That rule, checked row by row above, is the recorder's whole promise. The skew
        # is the named frame's age at the row; how large it is is the twin's delivery,
        # uneven on a loaded box, so it is printed, not bounded.
        t_of = dict(zip(seqs, t_cap, strict=True))
        for r, t_row in zip(rows, t, strict=True):
            if r[f"{cam}.seq"]:
                age = t_row - t_of[int(r[f"{cam}.seq"])]
                assert float(r[f"{cam}.skew_s"]) == pytest.approx(age, abs=2e-6), (cam, r)
        period = 1.0 / fps[cam]
        skews = np.array([float(r[f"{cam}.skew_s"]) for r in rows if r[f"{cam}.seq"]])
        print(
            f"{cam}: skew median {np.median(skews) * 1e3:.1f} ms, p99 "
            f"{q['skew_p99_s'] * 1e3:.1f} ms, frame period {period * 1e3:.1f} ms"
        )

    # Analysis reads the session as recorded.
    track = load_session_dir(folder)
    assert len(track) > 50 and np.nanmax(track.relative_alt_m) == pytest.approx(4.0, abs=0.4)

    # The tlog replays through the station's replay: source to the same flight.
    link = MavlinkLink(LinkSettings(source=f"replay:{folder / layout.MAVLINK_TLOG}?speed=0"))
    alts = []
    link.add_packet_listener(lambda _t, _p: None)
    link.start()
    try:

        def done():
            v = link.state.get()
            if v is not None and v.value.altitude.relative_alt_m is not None:
                alts.append(v.value.altitude.relative_alt_m)
            return link.health().replay_done

        assert wait_until(done, timeout=20, interval=0.001)
        assert link.health().truncated_records == 0
        final = link.state.get().value
        assert final.heartbeat.armed is False and final.heartbeat.autopilot == "px4"
    finally:
        link.stop()
