"""One reader of a flight: a session analyses the same from its telemetry.csv and from its
mavlink.tlog, for a twin flight of each of the paper's tasks, through `fpv-station
analyze`. The tlog is replayed through the link's `StateTracker` into the recorder's rows
(`analysis.recording`), so the two can differ only by what the link did not see.

The flights are the twin's demonstrations (`learn.demos`: the twin flown faster than real
time, its MAVLink read by the link's framer and tracker and written by the recorder's
writer). Their tlogs also carry a second vehicle on the same channel (another autopilot,
disarmed, heard from the twin's first second on), as a shared radio channel or a ground
station forwarding another vehicle puts it there; the tracker follows the first autopilot
it heard, so the telemetry.csv recorded without those packets is what the link would have
recorded with them.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from fpv_station.analysis.flights import track_flights
from fpv_station.analysis.track import load_track
from fpv_station.core.mavlink.tlog_records import TlogReader, encode_record
from fpv_station.learn.demos import DemoConfig
from fpv_station.server.cli import main as cli_main
from tests import shaped_tlog
from tests import synthetic as syn
from tests.demo_flights import shared_demo

TASKS = {1: "hover", 2: "a-to-b", 3: "obstacle", 4: "figure8"}


def add_second_vehicle(tlog: Path) -> int:
    """Interleave 1 Hz HEARTBEATs of a disarmed ArduCopter (system 2) from the twin's
    first HEARTBEAT on; returns how many."""
    other = mav.MAVLink(None, srcSystem=2, srcComponent=1)
    out = bytearray()
    next_hb: float | None = None
    added = 0
    for t, packet in TlogReader(tlog):
        if next_hb is None and packet[7 if packet[0] == 0xFD else 5] == 0:  # HEARTBEAT
            next_hb = t + 0.5
        while next_hb is not None and t >= next_hb:
            hb = other.heartbeat_encode(
                mav.MAV_TYPE_QUADROTOR,
                mav.MAV_AUTOPILOT_ARDUPILOTMEGA,
                mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                0,
                mav.MAV_STATE_STANDBY,
            )
            out += encode_record(next_hb, hb.pack(other))
            next_hb += 1.0
            added += 1
        out += encode_record(t, packet)
    tlog.write_bytes(bytes(out))
    return added


def twin_flight(tmp_path_factory, root: Path, task_id: int) -> Path:
    """A copy under `root` of the task's demo (flown once for the run, `shared_demo`),
    its tlog with the second vehicle."""
    flown = shared_demo(tmp_path_factory, task_id, DemoConfig(task_id=task_id))
    folder = root / flown.name
    shutil.copytree(flown, folder)
    # Recorded as the recorder records: with the task it flew, as a pilot's choice is.
    meta = json.loads((folder / "session.json").read_text())
    assert meta["task"]["id"] == task_id and meta["status"] == "complete"
    assert add_second_vehicle(folder / "mavlink.tlog") > 10
    return folder


def analyze(path: Path, task: str, out: Path) -> tuple[list[str], list[dict]]:
    """The table's figures (its columns) and its rows, as `fpv-station analyze` wrote them."""
    assert cli_main(["analyze", str(path), "--task", task, "--out", str(out)]) == 0
    table = json.loads((out / f"{task}_table.json").read_text())
    return [c["field"] for c in table["columns"]], table["results"]


@pytest.mark.timeout(300)  # a figure 8 flown and analysed twice: ~10 s of CPU, more at load 8
@pytest.mark.parametrize("task_id", sorted(TASKS))
def test_a_session_analyses_the_same_from_its_csv_and_its_tlog(task_id, tmp_path, tmp_path_factory):
    task = TASKS[task_id]
    folder = twin_flight(tmp_path_factory, tmp_path / "sessions", task_id)
    figures, from_csv = analyze(folder, task, tmp_path / "csv")
    _, from_tlog = analyze(folder / "mavlink.tlog", task, tmp_path / "tlog")
    assert len(from_csv) == len(from_tlog) == 1  # one flight, however it is read
    csv, tlog = from_csv[0], from_tlog[0]
    assert csv["source"] == str(folder) and tlog["source"] == str(folder / "mavlink.tlog")
    assert csv["platform"] == tlog["platform"] == "twin"  # the session's own tlog: its meta
    assert {"trial_time_s", "path_length_m", "height_deviation_m", "obstacle_contacts"} <= set(
        figures
    )
    for k in figures:
        assert isinstance(csv[k], (int, float)), k
        assert tlog[k] == pytest.approx(csv[k], rel=0.01, abs=1e-6), k
    # Where the flight is placed: the same arming point, to a few centimetres.
    for k in ("origin_lat_deg", "origin_lon_deg"):
        assert tlog[k] == pytest.approx(csv[k], abs=1e-6), k


def test_a_tlog_of_joined_recordings_reads_each_on_its_own_clock(tmp_path):
    """Three recordings in one file, the clock stepping back 523 s and 488 s between them
    (a real tlog's shape): three flights, each its own 3 m hop, none interleaved with
    another, each sample at its own recording's wall time."""
    armed, end_s = (2.0, 14.0), 20.0
    t = np.arange(0.0, end_s, 0.02)
    up = np.clip(np.minimum(t - 4.0, 10.0 - t), 0.0, 3.0)
    hop = syn.Flight(
        t_s=t,
        xyz_m=np.stack([np.zeros_like(t), np.zeros_like(t), up], 1),
        armed=(t >= armed[0]) & (t < armed[1]),
    )
    starts = [1_700_000_000.0]
    for back in (523.0, 488.0):
        starts.append(starts[-1] + end_s - back)
    logs = [shaped_tlog.vehicle_flight(hop, t0=t0) for t0 in starts]
    path = shaped_tlog.write_joined(tmp_path / "joined.tlog", *logs)

    track = load_track(path)
    assert np.all(np.diff(track.t_s) > 0)  # one session clock, running forward
    flights = track_flights(track)
    assert len(flights) == 3
    for f, t0 in zip(flights, starts):
        part = track.select(f.samples)
        assert part.wall_time[0] == pytest.approx(t0 + armed[0], abs=0.3)
        assert part.wall_time[-1] == pytest.approx(t0 + armed[1], abs=0.3)
        assert np.nanmax(part.relative_alt_m) == pytest.approx(3.0, abs=0.2)
        step = np.hypot(np.diff(part.lat_deg), np.diff(part.lon_deg)) * 111e3
        assert step.max() < 0.5  # a hop on the spot: no jump to another recording's fix
