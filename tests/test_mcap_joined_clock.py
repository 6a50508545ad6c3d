"""The MCAP export of a tlog of joined recordings (the clock steps back 523 s and 488 s
between them, tests/test_clock_steps_back.py's shape) cuts each flight's raw MAVLink on
the session clock of its rows: every flight's file holds its own recording's packets,
from its arming to its disarming, on the same log time as its rows, never another
recording's packets that the log's own clock puts at the same wall time."""

from __future__ import annotations

from collections import Counter

import numpy as np
from mcap.reader import make_reader

from fpv_station.learn.export import ExportOptions, export_recordings
from tests import shaped_tlog
from tests.known_flights import HOP_ARMED_S, hop_recording, recording_starts


def topics(path) -> dict[str, list[int]]:
    """Each topic's log times (ns)."""
    out: dict[str, list[int]] = {}
    with open(path, "rb") as f:
        for _schema, channel, message in make_reader(f).iter_messages():
            out.setdefault(channel.topic, []).append(message.log_time)
    return out


def test_each_flight_holds_its_own_recordings_packets(tmp_path):
    logs = [shaped_tlog.vehicle_flight(hop_recording(), t0=t0) for t0 in recording_starts()]
    path = shaped_tlog.write_joined(tmp_path / "joined.tlog", *logs)
    out = tmp_path / "mcap"
    export_recordings([path], "mcap", out, ExportOptions(task_id=1, cameras=()))
    files = sorted(out.glob("*.mcap"), key=lambda p: int(p.stem.rsplit("flight", 1)[1]))
    assert len(files) == len(logs)
    # Each recording sends the same packets over its armed span (about 12 s at ~73/s).
    armed = [
        sum(HOP_ARMED_S[0] - 1.0 <= t - log.t0 <= HOP_ARMED_S[1] + 1.0 for t, _ in log.records)
        for log in logs
    ]
    counts = Counter()
    for k, f in enumerate(files):
        got = topics(f)
        rows, packets = np.array(got["/telemetry"]), np.array(got["/mavlink"])
        counts[k] = packets.size
        assert rows.size > 100, k
        # On the rows' time axis, inside the flight's rows (a row every 1/30 s).
        assert packets.min() >= rows.min() - 40e6 and packets.max() <= rows.max() + 40e6, k
        assert packets.size <= armed[k], k  # none of another recording's
        assert packets.size > 0.8 * (armed[k] - 2 * 73), k  # its own, arming to disarming
    assert max(counts.values()) - min(counts.values()) < 80, counts
