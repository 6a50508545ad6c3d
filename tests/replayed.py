"""A shaped log replayed through the real `replay:` source into a real station that records
on arming: the tests read its sessions over HTTP once the replay has ended."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path

import httpx

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
