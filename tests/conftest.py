"""Fixtures shared by several test modules, and the markers each test gets by what it runs.

The test kit is every module of tests/ not named `test_*` (helpers, a MAVLink test vehicle,
flights with known answers, stations, pages, processes); test modules import from the kit,
never from each other (tests/test_layers.py). Markers (pyproject.toml) let a part run
alone: `pytest -m fast`, `-m browser`, `-m "not twin"`. `fast` is given by hand; the
others by what a test reaches, its fixtures and the kit functions it calls included:

- browser: Chromium (the `browser` fixture, tests.helpers.chromium);
- twin: the digital twin (anything of fpv_station.twin, the `twin_and_gcs` fixture, a
  station on the source "sim");
- subprocess: a process of its own (the subprocess or multiprocessing module).
"""

from __future__ import annotations

import inspect
import os
import socket
import tempfile
import types

import pytest
from pymavlink import mavutil

from fpv_station.twin.runner import Twin
from fpv_station.twin.sensors import SensorParams
from fpv_station.twin.sim import SimConfig
from tests.helpers import chromium, free_port
from tests.synthetic import write_two_sessions

# `fpv-station serve` keeps its first-start control token under XDG_CONFIG_HOME: test
# stations (and their subprocesses) get a throwaway one, never the user's.
os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="fpv-test-config-")


@pytest.fixture(scope="module")
def browser():
    """Headless Debian chromium (tests.helpers.chromium), one per test module: each test
    opens its own pages (`browser.new_page()`, a fresh context each)."""
    with chromium() as b:
        yield b


@pytest.fixture()
def twin_and_gcs():
    """An in-process twin (no sensor noise) and a pymavlink ground station on real UDP."""
    port = free_port(socket.SOCK_DGRAM)
    gcs = mavutil.mavlink_connection(f"udpin:127.0.0.1:{port}", source_system=255)
    twin = Twin(
        config=SimConfig(sensors=SensorParams(enabled=False)), mavlink=f"udpout:127.0.0.1:{port}"
    )
    twin.step_for(2.5)  # GPS fix; the vehicle's first packets make the GCS learn its address
    assert gcs.wait_heartbeat(timeout=5) is not None
    yield twin, gcs
    twin.stop()
    gcs.close()


@pytest.fixture
def anyio_backend():
    """The event loop of `@pytest.mark.anyio` tests (anyio's plugin): asyncio, as uvicorn's."""
    return "asyncio"


@pytest.fixture
def two_sessions_dir(tmp_path):
    """A sessions folder holding tests.synthetic's SESSION_A (with frames) and SESSION_B."""
    return write_two_sessions(tmp_path / "sessions")


# ------------------------------------------------------------------ markers by what runs

TWIN_KIT = {"twin_and_gcs", "twin_station_settings"}


class _Reach:
    """What a test's code reaches: the objects its names resolve to, followed through
    the kit's functions and classes (modules `tests.*`), and the strings in the code of
    the test's own module (a station's source, say; the kit's are not its choice)."""

    def __init__(self, module: str) -> None:
        self.module = module
        self.objects: list[object] = []
        self.names: set[str] = set()
        self.strings: set[str] = set()
        self._seen: set[types.CodeType] = set()

    def follow(self, func: object) -> None:
        func = inspect.unwrap(func) if callable(func) else func
        code = getattr(func, "__code__", None)
        if code is None or code in self._seen:
            return
        self._seen.add(code)
        scope: dict[str, object] = getattr(func, "__globals__", {})  # a function's, with __code__
        strings = scope.get("__name__") == self.module
        stack = [code]
        while stack:
            c = stack.pop()
            for const in c.co_consts:
                if isinstance(const, types.CodeType):
                    stack.append(const)
                elif strings and isinstance(const, str):
                    self.strings.add(const)
            for name in c.co_names:
                self.names.add(name)
                if name not in scope:
                    continue
                obj = scope[name]
                self.objects.append(obj)
                if (getattr(obj, "__module__", None) or "").startswith("tests."):
                    if inspect.isclass(obj):
                        for member in vars(obj).values():
                            self.follow(member)
                    else:
                        self.follow(obj)


def _markers(item: pytest.Function) -> set[str]:
    reach = _Reach(item.module.__name__)
    reach.follow(item.function)
    for name, defs in item._fixtureinfo.name2fixturedefs.items():
        reach.names.add(name)
        for fixturedef in defs:
            reach.follow(fixturedef.func)
    modules = {
        (o.__name__ if inspect.ismodule(o) else getattr(o, "__module__", None)) or ""
        for o in reach.objects
    }
    marks = set()
    # Names count too: an import inside a test puts its module and names there.
    if any(o is chromium for o in reach.objects) or {"chromium", "browser"} & reach.names:
        marks.add("browser")
    if (
        any(m.startswith("fpv_station.twin") for m in modules | reach.names)
        or TWIN_KIT & reach.names
        or "sim" in reach.strings
    ):
        marks.add("twin")
    if {"subprocess", "multiprocessing"} & ({m.split(".")[0] for m in modules} | reach.names):
        marks.add("subprocess")
    return marks


def pytest_ignore_collect(collection_path, config):
    """Under `-m fast` alone, a test module that marks nothing fast is not even imported:
    the fast tier takes its tests' time, not the import of the whole suite."""
    name = collection_path.name
    if config.getoption("markexpr") == "fast" and name.startswith("test_") and name.endswith(".py"):
        return "mark.fast" not in collection_path.read_text(encoding="utf-8") or None
    return None


@pytest.hookimpl(tryfirst=True)  # before `-m` deselects by markers
def pytest_collection_modifyitems(config, items):
    for item in items:
        if isinstance(item, pytest.Function):
            for mark in _markers(item):
                item.add_marker(mark)
