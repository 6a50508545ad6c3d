"""The systemd service: the unit file, install-service, and the notify/watchdog protocol
spoken to a real AF_UNIX datagram socket standing in for systemd's NOTIFY_SOCKET."""

from __future__ import annotations

import asyncio
import contextlib
import io
import os
import shutil
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from pathlib import Path

import httpx
import pytest

from fpv_station.companion.link_settings import LinkSettings
from fpv_station.server.app import create_app
from fpv_station.server.install_service import (
    HIDDEN_FROM_SERVICE,
    SMALL_PI_LINK,
    SMALL_PI_SERVER,
    UNIT_NAME,
    ServicePlan,
    install,
    small_pi_toml,
)
from fpv_station.server.sd_notify import Notifier, notify_loop
from fpv_station.server.settings import load_settings
from fpv_station.server.tasks import TaskSupervisor
from tests.helpers import free_port, run_uvicorn, station_settings, wait_until
from tests.mav_vehicle import MavVehicle

REPO = Path(__file__).resolve().parents[1]
FPV_STATION = str(Path(sys.executable).parent / "fpv-station")


def notify_socket(path: Path) -> socket.socket:
    s = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    s.bind(str(path))
    s.settimeout(0.05)
    return s


def datagrams(s: socket.socket, seconds: float) -> list[str]:
    got, end = [], time.monotonic() + seconds
    while time.monotonic() < end:
        try:
            got.append(s.recv(4096).decode())
        except TimeoutError:
            pass
    return got


def test_repo_unit_file_is_the_rendered_default():
    assert (REPO / "deploy" / UNIT_NAME).read_text() == ServicePlan().unit_text()


def test_repo_config_is_the_rendered_default_and_loads(tmp_path):
    text = (REPO / "deploy" / "config.toml").read_text()
    assert text == ServicePlan().config_text()
    (tmp_path / "config.toml").write_text(text)
    settings = load_settings(tmp_path / "config.toml", environ={})
    assert settings.recording.sessions_dir == Path("/var/lib/fpv-station/sessions")
    assert settings.link.source == "/dev/serial0:921600"


def test_small_pi_lines_of_the_config_load_and_keep_every_stream(tmp_path):
    """The two commented lines a Pi 3 or Zero 2 W team uncomments are valid settings,
    ask for every message the station uses (a stream missing from the table would not
    be requested at all), each at most at the default rate, and are what
    `pi_budget.py --small-pi` measures."""
    text = ServicePlan().config_text()
    lines = [f"# {SMALL_PI_SERVER}", f"# {SMALL_PI_LINK}"]
    assert all(line in text.splitlines() for line in lines)
    for line in lines:
        text = text.replace(line, line.removeprefix("# "))
    (tmp_path / "config.toml").write_text(text)
    small = load_settings(tmp_path / "config.toml", environ={})
    (tmp_path / "bench.toml").write_text(small_pi_toml())
    bench = load_settings(tmp_path / "bench.toml", environ={})
    default = LinkSettings().message_rates_hz
    for settings in (small, bench):
        assert settings.server.telemetry_rate_hz == 25
        rates = settings.link.message_rates_hz
        assert set(rates) == set(default)
        assert all(0 < rates[m] <= default[m] for m in default)
        assert sum(rates.values()) + settings.link.heartbeat_hz < 80  # the "about 80"
    assert small.link.source == "/dev/serial0:921600"  # the rest of the file still applies


def test_unit_has_what_a_field_station_needs():
    unit = ServicePlan().unit_text()
    for line in (
        "Type=notify",
        "WatchdogSec=30",
        "Restart=always",
        "User=fpv-station",
        "SupplementaryGroups=dialout video",
        "ExecStart=/usr/local/bin/fpv-station serve --config /etc/fpv-station/config.toml",
        "StateDirectory=fpv-station",
        "DeviceAllow=char-ttyAMA rw",
        "DeviceAllow=char-video4linux rw",
        "ProtectSystem=strict",
    ):
        assert line in unit.splitlines(), line
    assert not any(
        ln.startswith("PrivateDevices") for ln in unit.splitlines()
    )  # it would hide /dev/serial0 and /dev/video*
    # ProtectClock's filter makes even a read-only adjtimex() fail with EPERM: the station
    # could never tell that the Pi's clock is not synchronised (companion/system_clock.py)
    assert not any(ln.startswith("ProtectClock") for ln in unit.splitlines())
    assert "CapabilityBoundingSet=" in unit.splitlines()  # setting the clock stays denied


def test_unit_passes_systemd_analyze_verify(tmp_path):
    tool = shutil.which("systemd-analyze")
    if tool is None:
        pytest.skip("systemd-analyze is not installed here")
    unit = tmp_path / UNIT_NAME
    unit.write_text(ServicePlan(exec_path=FPV_STATION).unit_text())
    done = subprocess.run(
        [tool, "verify", "--man=no", str(unit)], capture_output=True, text=True, timeout=60
    )
    # Lines about other units on this machine (it is not a booted systemd host) are not ours.
    ours = [ln for ln in done.stderr.splitlines() if UNIT_NAME in ln]
    assert done.returncode == 0 and not ours, done.stderr


def test_install_service_dry_run_prints_unit_and_commands():
    out = io.StringIO()
    plan = ServicePlan(user="pilot", exec_path="/opt/fpv-station/bin/fpv-station")
    assert install(plan, dry_run=True, out=out) == 0
    text = out.getvalue()
    assert "User=pilot" in text
    assert "ExecStart=/opt/fpv-station/bin/fpv-station serve" in text
    assert 'sessions_dir = "/var/lib/fpv-station/sessions"' in text
    assert "systemctl enable --now fpv-station.service" in text


def test_install_service_command_line_dry_run():
    """The command runs this checkout's station: where the checkout lives (a home
    directory, CI's /tmp) decides whether the unit could reach it."""
    done = subprocess.run(
        [FPV_STATION, "install-service", "--user", "pilot", "--dry-run"],
        capture_output=True,
        text=True,
        timeout=60,
    )
    here = Path(FPV_STATION).resolve()
    if any(here.is_relative_to(d) for d in HIDDEN_FROM_SERVICE):
        assert done.returncode == 1 and str(here) in done.stdout, done.stdout
    else:
        assert done.returncode == 0, done.stderr
        assert "User=pilot" in done.stdout and f"ExecStart={here} serve" in done.stdout


@pytest.mark.parametrize("exec_path", ["/home/pi/venv/bin/fpv-station", "/tmp/v/bin/fpv-station"])
def test_install_service_refuses_a_station_the_unit_cannot_reach(exec_path):
    """A station pip-installed in a home directory (or /tmp): ProtectHome= and PrivateTmp=
    hide it from the service, which would fail to start (status 203/EXEC). Said before
    anything is written, in the dry run too (only that is run here: the tests run as root)."""
    out = io.StringIO()
    assert install(ServicePlan(exec_path=exec_path), dry_run=True, out=out) == 1
    text = out.getvalue()
    assert exec_path in text and "/opt/fpv-station" in text
    assert "[Service]" not in text  # no unit printed as if it would work


def test_install_service_refuses_without_root():
    if os.geteuid() == 0:
        pytest.skip("running as root: a real install would change this machine")
    done = subprocess.run(
        [FPV_STATION, "install-service"], capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 1 and "root" in done.stdout


def test_notifier_from_environ():
    assert Notifier.from_environ({}) is None
    n = Notifier.from_environ({"NOTIFY_SOCKET": "@fpv", "WATCHDOG_USEC": "30000000"})
    assert n == Notifier("\0fpv", 30.0)
    other_pid = Notifier.from_environ(
        {"NOTIFY_SOCKET": "/run/x", "WATCHDOG_USEC": "1000", "WATCHDOG_PID": "1"}
    )
    assert other_pid is not None and other_pid.watchdog_s is None  # meant for another process


def test_watchdog_pings_only_while_tasks_are_healthy(tmp_path):
    """Pings while every task lives; a task dies once systemd has had five; then one
    STATUS saying which, and silence. Paced by what arrives, not by the clock: a starved
    CI box only makes it slower."""
    sock = notify_socket(tmp_path / "notify")
    sock.setblocking(False)
    got: list[str] = []

    async def receive_until(done: Callable[[], bool]) -> None:
        loop = asyncio.get_running_loop()
        while not done():
            got.append((await loop.sock_recv(sock, 4096)).decode())

    async def scenario() -> None:
        tasks = TaskSupervisor()
        five_pings = asyncio.Event()

        async def dies_after_five_pings() -> None:
            await five_pings.wait()
            raise RuntimeError("camera thread wedged")

        tasks.spawn("front-camera", dies_after_five_pings())
        loop_task = asyncio.create_task(notify_loop(Notifier(str(tmp_path / "notify"), 0.1), tasks))
        await asyncio.wait_for(receive_until(lambda: got.count("WATCHDOG=1") >= 5), 30)
        five_pings.set()
        await asyncio.wait_for(
            receive_until(lambda: any(g.startswith("STATUS=unhealthy") for g in got)), 30
        )
        with contextlib.suppress(TimeoutError):  # ten ping periods: a ping would come
            await asyncio.wait_for(receive_until(lambda: False), 0.5)
        loop_task.cancel()
        await tasks.aclose()

    asyncio.run(scenario())
    assert got[0] == "READY=1\nSTATUS=serving"
    pings = got.index(next(g for g in got if g.startswith("STATUS=unhealthy")))
    assert pings >= 6 and all(g == "WATCHDOG=1" for g in got[1:pings])
    assert "front-camera: RuntimeError: camera thread wedged" in got[pings]
    assert got[pings + 1 :] == []  # no more pings: systemd restarts the station


def test_a_full_notify_queue_does_not_block_the_event_loop(tmp_path):
    sock = notify_socket(tmp_path / "notify")  # never read: the kernel queue fills (~10)
    notifier = Notifier(str(tmp_path / "notify"), None)
    t0 = time.monotonic()
    sent = [notifier.send("WATCHDOG=1") for _ in range(200)]
    assert time.monotonic() - t0 < 30  # a hang guard: a blocking send waits for ever
    assert sent[0] and not sent[-1]  # later ones dropped (and logged), not waited for
    sock.close()


def test_serve_notifies_systemd_ready_then_watchdog_then_stopping(tmp_path):
    sock = notify_socket(tmp_path / "notify")
    got: list[str] = []
    done = threading.Event()

    def read_all_the_time() -> None:
        # As systemd does: the socket's queue holds 10 datagrams, and a ping sent while it
        # is full is dropped, so a reader that paused during shutdown could lose STOPPING.
        while not done.is_set():
            got.extend(datagrams(sock, 0.1))

    reader = threading.Thread(target=read_all_the_time, daemon=True)
    reader.start()
    port = free_port()
    env = dict(os.environ, NOTIFY_SOCKET=str(tmp_path / "notify"), WATCHDOG_USEC="400000")
    proc = subprocess.Popen(
        [FPV_STATION, "serve", "--source", "none", "--no-3d", "--open"]
        + ["--host", "127.0.0.1", "--port", str(port), "--sessions-dir", str(tmp_path / "s")],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        ready = "READY=1\nSTATUS=serving"
        assert wait_until(lambda: ready in got, timeout=60)
        health = httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=10).json()
        assert health["ok"] is True  # READY means it already serves
        # Pings every 0.2 s: wait for three, however slowly a loaded box sends them.
        assert wait_until(lambda: got[got.index(ready) :].count("WATCHDOG=1") >= 3, timeout=30)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) in (0, -signal.SIGTERM)  # uvicorn re-raises the signal
        assert wait_until(lambda: "STOPPING=1" in got, timeout=5)
    finally:
        done.set()
        reader.join()
        if proc.poll() is None:
            proc.kill()
            proc.wait()


def test_a_dead_link_thread_stops_the_watchdog_and_degrades_health(tmp_path):
    """The link thread catches what kills it (a bug, say) instead of vanishing; the
    station must then say so and let systemd restart it, not serve stale telemetry
    forever. The fault is injected into the running link's packet handler: no real input
    is known to kill the thread (the two that did are fixed)."""
    with MavVehicle("udp") as v:
        app = create_app(station_settings(v.station_source, tmp_path / "sessions"))
        with run_uvicorn(app) as base:
            station = app.state.station
            assert wait_until(lambda: station.state.get() is not None, 10)
            assert httpx.get(f"{base}/api/health").json()["ok"] is True

            def a_bug(*args: object) -> int:
                raise RuntimeError("a bug in the packet handler")

            station.link._on_bytes = a_bug
            assert wait_until(lambda: not station.link.running, 10)
            health = httpx.get(f"{base}/api/health").json()
            assert health["status"] == "degraded", health
            assert health["failed_tasks"] == {
                "mavlink link thread": "RuntimeError: a bug in the packet handler"
            }
            assert station.tasks.healthy is False  # what notify_loop pings by
