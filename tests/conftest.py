"""Fixtures shared by several test modules."""

from __future__ import annotations

import os
import socket
import tempfile

import pytest
from pymavlink import mavutil

from fpv_station.twin.runner import Twin
from fpv_station.twin.sensors import SensorParams
from fpv_station.twin.sim import SimConfig
from tests.helpers import chromium, free_port

# `fpv-station serve` keeps its first-start control token under XDG_CONFIG_HOME: test
# stations (and their subprocesses) get a throwaway one, never the user's.
os.environ["XDG_CONFIG_HOME"] = tempfile.mkdtemp(prefix="fpv-test-config-")


@pytest.fixture
def browser():
    """Headless Debian chromium (tests.helpers.chromium), one per test."""
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
