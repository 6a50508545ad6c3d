"""Test stations: the app in-process behind httpx's ASGITransport (the fast tier: no
server, no socket), or served by a real uvicorn (tests.helpers.run_uvicorn) with no link
or following the test MAVLink vehicle.

    async with in_process(station_settings("none", tmp_path)) as client:
        assert (await client.get("/api/status")).json()["source"] == "none"

`in_process` runs the app's own lifespan (server/app.py: the station is opened in it),
so a route sees the station it has under `fpv-station serve`.
"""

from __future__ import annotations

import contextlib
from collections.abc import AsyncIterator, Iterator
from pathlib import Path

import httpx
from fastapi import FastAPI

from fpv_station.server.app import create_app
from fpv_station.server.settings import Settings
from tests.helpers import run_uvicorn, station_settings
from tests.mav_vehicle import MavVehicle

# The host a client reaches the in-process station at: an address, which the request
# guard takes as the station's own (server/guard.py refuses other names).
IN_PROCESS_BASE = "http://127.0.0.1:8000"


class StationClient(httpx.AsyncClient):
    """An httpx client on one app in-process; `app.state.station` is its running station."""

    def __init__(self, app: FastAPI) -> None:
        super().__init__(transport=httpx.ASGITransport(app=app), base_url=IN_PROCESS_BASE)
        self.app = app


@contextlib.asynccontextmanager
async def in_process(settings: Settings) -> AsyncIterator[StationClient]:
    """A client on the app built from `settings`, its lifespan entered for the block."""
    app = create_app(settings)
    async with app.router.lifespan_context(app), StationClient(app) as client:
        yield client


@contextlib.contextmanager
def no_link_station(sessions_dir: Path | None = None, **overrides) -> Iterator[tuple[str, FastAPI]]:
    """A station with no vehicle link (tests.helpers.station_settings("none", ...))
    served by a real uvicorn: (its base URL, the app)."""
    app = create_app(station_settings("none", sessions_dir, **overrides))
    with run_uvicorn(app) as base:
        yield base, app


@contextlib.contextmanager
def vehicle_station(sessions_dir: Path, **overrides) -> Iterator[tuple[MavVehicle, str]]:
    """The test MAVLink vehicle on UDP and a real station following it: (the vehicle,
    the station's base URL)."""
    with MavVehicle("udp") as vehicle:
        settings = station_settings(vehicle.station_source, sessions_dir, **overrides)
        with run_uvicorn(create_app(settings)) as base:
            yield vehicle, base
