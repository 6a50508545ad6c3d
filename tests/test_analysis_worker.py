"""Heavy anonymous reads against a real station: figure requests, cache-busting or not,
while a telemetry WebSocket client runs. Figures are made in one worker process, at most
MAX_PENDING jobs at a time (one more gets the 503 error shape at once), and answered
from a cache keyed on the files and the parsed parameters, so junk in the query finds
the cached figure. Correctness only: no assertion on a rate or a delay."""

from __future__ import annotations

import asyncio
import json
import threading

import httpx
import psutil
import pytest
from websockets.sync.client import connect

from fpv_station.server.analysis_worker import MAX_PENDING
from fpv_station.server.app import create_app
from tests import synthetic as syn
from tests.helpers import run_uvicorn, station_settings, wait_until
from tests.mav_vehicle import MavVehicle
from tests.station_process import serve_station

SID = "20261122T040000Z_udp"


class TelemetryReader:
    """A /ws/telemetry client in a thread, counting what it receives."""

    def __init__(self, ws_url: str) -> None:
        self.url, self.count = ws_url, 0
        self.error: Exception | None = None
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run)

    def _run(self) -> None:
        try:
            with connect(self.url) as ws:
                while not self.stop.is_set():
                    if json.loads(ws.recv(timeout=10)).get("state") is not None:
                        self.count += 1
        except Exception as exc:  # noqa: BLE001 - reported by the test
            self.error = exc

    def __enter__(self) -> TelemetryReader:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop.set()
        self.thread.join(15)


async def _get_all(base: str, urls: list[str]) -> list[httpx.Response]:
    async with httpx.AsyncClient(base_url=base, timeout=120) as client:
        return await asyncio.gather(*(client.get(u) for u in urls))


@pytest.mark.timeout(300)
def test_plot_load_is_bounded_cached_and_leaves_telemetry_flowing(tmp_path):
    syn.write_session(syn.a_to_b_flight(), tmp_path / SID, meta={"id": SID})
    with MavVehicle("udp") as vehicle:
        app = create_app(station_settings(vehicle.station_source, tmp_path))
        with run_uvicorn(app) as base:
            worker = app.state.station.analysis_worker
            ws_url = base.replace("http", "ws") + "/ws/telemetry"
            with TelemetryReader(ws_url) as telemetry:
                assert wait_until(lambda: telemetry.count > 0, 20), telemetry.error
                plot = f"/api/sessions/{SID}/analysis/birdseye.png?task=a-to-b"

                # 24 anonymous clients at once, each with its own cache-busting junk.
                busted = asyncio.run(_get_all(base, [f"{plot}&_={i}&x{i}=y" for i in range(24)]))
                assert [r.status_code for r in busted] == [200] * 24
                assert len({r.content for r in busted}) == 1  # one figure
                assert busted[0].content[:8] == b"\x89PNG\r\n\x1a\n"
                assert worker.stats.jobs == 1  # made once, for everyone
                assert worker.stats.joined + worker.stats.cache_hits == 23
                again = httpx.get(f"{base}{plot}&_=later", timeout=60)
                assert again.status_code == 200 and again.content == busted[0].content
                assert worker.stats.jobs == 1 and worker.stats.cache_hits >= 1
                seen = telemetry.count

                # 12 really different figures at once: at most MAX_PENDING are taken, the
                # others are refused at once with the error shape, never queued.
                distinct = [f"{plot}&margin_m={2 + i / 100}" for i in range(12)]
                answers = asyncio.run(_get_all(base, distinct))
                codes = [r.status_code for r in answers]
                assert set(codes) <= {200, 503}, codes
                busy = [r.json() for r in answers if r.status_code == 503]
                assert busy and all(b["error"] == "AnalysisBusy" for b in busy), codes
                assert all("try again" in b["error_msg"] for b in busy)
                assert worker.stats.peak_pending <= MAX_PENDING
                assert codes.count(200) >= 1
                assert worker.stats.processes == 1  # one worker process did all of it
                # A refused figure is made when asked again.
                retry = distinct[codes.index(503)]
                assert httpx.get(f"{base}{retry}", timeout=120).status_code == 200
                # The flight state kept coming to the client through all of it.
                assert wait_until(lambda: telemetry.count > seen, 20)
            assert telemetry.error is None, telemetry.error
            # The table goes through the same worker and cache; junk changes nothing.
            table = httpx.get(f"{base}/api/sessions/{SID}/analysis?task=a-to-b&_=1", timeout=60)
            jobs = worker.stats.jobs
            same = httpx.get(f"{base}/api/sessions/{SID}/analysis?task=a-to-b&_=2", timeout=60)
            assert table.status_code == 200 and same.json() == table.json()
            assert worker.stats.jobs == jobs

            # A worker killed mid-life (the OOM killer) costs one 503; the next request
            # gets a new worker.
            (proc,) = [
                p
                for p in psutil.Process().children()
                if any("spawn_main" in part for part in p.cmdline())
            ]
            proc.kill()
            proc.wait(10)
            fresh = [f"{plot}&margin_m={3 + i / 100}" for i in range(2)]
            first = httpx.get(f"{base}{fresh[0]}", timeout=120)
            assert first.status_code in (200, 503), first.text
            if first.status_code == 503:
                assert first.json()["error"] == "AnalysisBusy"
            assert httpx.get(f"{base}{fresh[1]}", timeout=120).status_code == 200
            assert worker.stats.processes == 2


@pytest.mark.timeout(300)
@pytest.mark.parametrize("stop", ["terminate", "kill"])
def test_the_worker_ends_with_its_station(tmp_path, stop):
    """Stopped (SIGTERM) or killed outright (SIGKILL: no chance to stop its pool), a
    station leaves no analysis worker behind."""
    syn.write_session(syn.a_to_b_flight(), tmp_path / SID, meta={"id": SID})
    env = {"FPV_RECORDING__SESSIONS_DIR": str(tmp_path), "FPV_VISER__ENABLED": "false"}
    with serve_station(["--source", "none"], env) as station:
        plot = f"/api/sessions/{SID}/analysis/birdseye.png?task=a-to-b"
        assert httpx.get(f"{station.base}{plot}", timeout=120).status_code == 200
        (worker,) = [
            p
            for p in station.process.children()
            if any("spawn_main" in part for part in p.cmdline())
        ]
        try:
            getattr(station.popen, stop)()
            station.popen.wait(60)
            gone = lambda: not worker.is_running() or worker.status() == "zombie"  # noqa: E731
            assert wait_until(gone, 30)
        finally:
            if worker.is_running():  # the test failed: leave no process behind
                worker.kill()
