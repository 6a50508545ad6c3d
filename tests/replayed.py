"""A shaped log replayed through the real `replay:` source into a real station (read over
HTTP once the replay has ended), or packet by packet through the station's framer and
state tracker; and pymavlink's own `mavloss` on the same log, to compare with."""

from __future__ import annotations

import contextlib
import re
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np

from fpv_station.companion.state_tracker import StateTracker
from fpv_station.core.mavlink.framing import MavFramer
from fpv_station.core.mavlink.tlog_records import TlogReader
from fpv_station.server.app import create_app
from tests.helpers import run_uvicorn, station_settings, wait_until


@contextlib.contextmanager
def replayed_station(
    tlog: Path, sessions_dir: Path, speed: str = "max", timeout: float = 120.0
) -> Iterator[str]:
    """The station's base URL, once the whole log has played and the last session has
    been closed."""
    settings = station_settings(
        f"replay:{tlog}?speed={speed}", sessions_dir, **{"recording.auto_record_on_arm": True}
    )
    with run_uvicorn(create_app(settings)) as base:
        get = lambda url: httpx.get(f"{base}{url}", timeout=30).json()  # noqa: E731
        assert wait_until(lambda: get("/api/status")["link"]["replay_done"], timeout=timeout)
        assert wait_until(lambda: not get("/api/recording")["recording"], timeout=10)
        yield base


def replayed_sessions(tlog: Path, speed: str, sessions_dir: Path) -> list[dict]:
    """Replay at `speed` with recording on arming: each session's summary, its a-to-b
    analysis ("result") and the link's rates at the end ("rates_hz"), in start order."""
    with replayed_station(tlog, sessions_dir, speed) as base:
        get = lambda url: httpx.get(f"{base}{url}", timeout=30).json()  # noqa: E731
        rates = get("/api/status")["link"]["rates_hz"]
        out = []
        for s in sorted(get("/api/sessions"), key=lambda s: s["start_wall"]):
            table = get(f"/api/sessions/{s['id']}/analysis?task=a-to-b")
            out.append({**s, "result": table["results"][0], "rates_hz": rates})
        return out


def replay_status(path: Path, speed: str = "max", **overrides) -> dict:
    """Replay `path` through a real station and return /api/status once it is done."""
    settings = station_settings(f"replay:{path}?speed={speed}", **overrides)
    with run_uvicorn(create_app(settings)) as base:

        def status() -> dict:
            return httpx.get(f"{base}/api/status", timeout=5).json()

        assert wait_until(lambda: status()["link"]["replay_done"], timeout=60)
        return status()


def mavloss(path: Path) -> dict[tuple[int, int] | str, float]:
    """pymavlink's `mavloss` on the same file: loss % per (sysid, compid) and "total"."""
    script = Path(sys.executable).parent / "mavloss.py"
    out = subprocess.run(
        [sys.executable, str(script), str(path)], capture_output=True, text=True, check=True
    ).stdout
    figures: dict[tuple[int, int] | str, float] = {}
    for line in out.splitlines():
        row = re.fullmatch(r"\s*(\d+)\s+(\d+)\s+(\d+)\s+(\d+)\s+([\d.]+)%", line)
        if row:
            figures[(int(row[1]), int(row[2]))] = float(row[5])
        total = re.search(r"Total.*?(\d+) packets, (\d+) lost ([\d.]+)%", line)
        if total:
            figures["total"] = float(total[3])
    assert "total" in figures, out
    return figures


def by_stream(link: dict) -> dict[tuple[int, int], dict]:
    """/api/status's link streams by (sysid, compid)."""
    return {(s["sysid"], s["compid"]): s for s in link["streams"]}


def pilot_altitudes(path) -> tuple[np.ndarray, list[str]]:
    """Every value of the pilot's altitude after each packet, and the references seen."""
    tracker, framer = StateTracker(), MavFramer()
    alts, refs = [], []
    for t, packet in TlogReader(path):
        for msg in framer.feed(packet):
            if tracker.update(msg, t):
                a = tracker.state.altitude
                if tracker.state.heartbeat.armed and a.relative_alt_m is not None:
                    alts.append(a.relative_alt_m)
                refs.append(a.reference)
    return np.array(alts), refs
