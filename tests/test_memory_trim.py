"""The station hands freed heap pages back to the system: glibc's malloc_trim, called
from a real station's task, and what one call does to a fragmented heap."""

from __future__ import annotations

import subprocess
import sys

import pytest

from fpv_station.server.app import create_app
from fpv_station.server.memory_trim import glibc_malloc_trim
from tests.helpers import run_uvicorn, station_settings, wait_until

pytestmark = pytest.mark.skipif(glibc_malloc_trim() is None, reason="not glibc")

# Buffers as the station frees them: many malloc'd blocks (over pymalloc's 512 bytes),
# most freed and a few kept, so the freed pages sit between live ones and glibc keeps
# them in the process.
FRAGMENTED_HEAP = """
import ctypes, sys
from fpv_station.server.memory_trim import glibc_malloc_trim

def rss_mb():
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * 4096 / 1e6

blocks = [bytes(2000) for _ in range(60_000)]
kept = blocks[::40]
del blocks
before = rss_mb()
if sys.argv[1] == "trim":
    glibc_malloc_trim()(0)
print(before, rss_mb())
"""


def _rss_after(action: str) -> tuple[float, float]:
    done = subprocess.run(
        [sys.executable, "-c", FRAGMENTED_HEAP, action],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    before, after = map(float, done.stdout.split())
    return before, after


def test_a_trim_returns_the_freed_pages_that_glibc_keeps():
    before, after = _rss_after("none")
    assert after > 0.9 * before > 100  # freed, yet still resident
    before, after = _rss_after("trim")
    assert after < before - 60, (before, after)  # most of the ~117 MB freed went back


def test_the_station_trims_on_its_period_and_not_when_off():
    app = create_app(station_settings("none", **{"server.malloc_trim_s": 0.05}))
    with run_uvicorn(app):
        trimmer = app.state.station.memory_trimmer
        assert wait_until(lambda: trimmer.trims >= 2, 60)
    app = create_app(station_settings("none", **{"server.malloc_trim_s": 0}))
    with run_uvicorn(app):
        assert app.state.station.memory_trimmer is None
