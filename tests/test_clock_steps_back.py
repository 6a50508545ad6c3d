"""A telemetry log whose clock steps back: three recordings joined in one file, the
second starting 523 s and the third 488 s before the end of the one before (a real
tlog's shape). Each recording is read on its own clock: the record layer numbers them
as segments, and a replay through the real `replay:` source into a real server records
one session per recording, each ended by its own disarming (a frozen clock never ends
one), in its recording's own time."""

from __future__ import annotations

import httpx
import numpy as np
import pytest

from fpv_station.core.mavlink.tlog_records import STEP_BACK_MIN_S, TlogReader, encode_record
from tests import shaped_tlog
from tests.known_flights import (
    HOP_ARMED_S,
    JOINED_STEPS_BACK_S,
    JOINED_T0,
    hop_recording,
    recording_starts,
)
from tests.replayed import replayed_station


@pytest.fixture(scope="module")
def joined(tmp_path_factory):
    logs = [shaped_tlog.vehicle_flight(hop_recording(), t0=t0) for t0 in recording_starts()]
    path = tmp_path_factory.mktemp("joined") / "joined.tlog"
    return shaped_tlog.write_joined(path, *logs), [len(log.records) for log in logs]


def test_records_are_numbered_by_recording_and_each_runs_forward(joined):
    path, counts = joined
    reader = TlogReader(path)
    seen = []
    for segment, records in reader.segments():
        times = [t for t, _ in records]
        seen.append((segment, len(times)))
        assert np.all(np.diff(times) >= 0), segment
        assert times[0] == pytest.approx(recording_starts()[segment], abs=0.01)
    assert seen == list(enumerate(counts))
    steps = [round(s.from_s - s.to_s) for s in reader.clock_steps]
    assert steps == [round(b - 0.02) for b in JOINED_STEPS_BACK_S]  # back from the last record
    assert [s.segment for s in reader.clock_steps] == [1, 2]
    assert [s.record for s in reader.clock_steps] == [counts[0], counts[0] + counts[1]]
    assert sum(1 for _ in TlogReader(path)) == sum(counts)  # as written, all of it


def test_a_small_step_back_is_held_not_a_new_recording(tmp_path):
    """A wall clock slewed back by its time service: the same recording, its time held."""
    packet = (
        shaped_tlog.Shaper()
        .sender(1, 1)
        .pack(shaped_tlog.heartbeat(shaped_tlog.Sender(1, 1, False).mav))
    )
    times = [JOINED_T0, JOINED_T0 + 1.0, JOINED_T0 + 1.0 - STEP_BACK_MIN_S / 2, JOINED_T0 + 1.2]
    path = tmp_path / "slewed.tlog"
    path.write_bytes(b"".join(encode_record(t, packet) for t in times))
    reader = TlogReader(path)
    records = list(reader.records())
    assert [r.segment for r in records] == [0, 0, 0, 0]
    assert [r.t_wall_s for r in records] == pytest.approx(
        [JOINED_T0, JOINED_T0 + 1.0, JOINED_T0 + 1.0, JOINED_T0 + 1.2]
    )
    assert reader.held_back == 1 and reader.clock_steps == []


@pytest.mark.timeout(300)
@pytest.mark.parametrize("speed", ["max", "20"])
def test_replay_records_one_session_per_recording_each_ended_by_its_disarming(
    joined, speed, tmp_path
):
    path, _ = joined
    with replayed_station(path, tmp_path / "sessions", speed, timeout=200) as base:
        sessions = httpx.get(f"{base}/api/sessions", timeout=30).json()
        sessions.sort(key=lambda s: s["start_wall"])
        link = httpx.get(f"{base}/api/status", timeout=30).json()["link"]
    assert link["clock_steps_back"] == 2
    # Before: one session, started at the first arming, never stopped by a disarming.
    assert [s["stop_reason"] for s in sessions] == ["disarmed"] * 3
    for s, t0 in zip(sessions, sorted(recording_starts())):
        # In its own recording's time: from its arming to 5 s after its disarming.
        assert s["start_wall"] - t0 == pytest.approx(HOP_ARMED_S[0], abs=1.1)
        assert s["end_wall"] - t0 == pytest.approx(HOP_ARMED_S[1] + 5.0, abs=1.1)
        assert s["telemetry_rows"] == pytest.approx(30 * s["duration_s"], abs=5)
