"""`fpv-station doctor` against the test MAVLink vehicle over UDP and a pty, a missing
serial device, a disk under the configured minimum, and a port already taken."""

from __future__ import annotations

import os
import pty
import re
import socket
import subprocess
import sys
import threading
import tty
from pathlib import Path

from fpv_station.server.doctor import (
    check_disk,
    check_heartbeat,
    check_pi_uart,
    check_ports,
    check_serial,
    firmware_version,
)
from fpv_station.server.listen import listening_socket
from fpv_station.server.settings import Settings
from tests.helpers import free_port, station_settings
from tests.mav_vehicle import MavVehicle

FPV_STATION = str(Path(sys.executable).parent / "fpv-station")


def doctor(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [FPV_STATION, "doctor", "--no-3d", "--port", str(free_port()), *args],
        capture_output=True,
        text=True,
        timeout=90,
    )


def test_doctor_hears_the_vehicle_over_udp(tmp_path):
    with MavVehicle("udp", sysid=7) as v:
        done = doctor("--source", v.station_source, "--sessions-dir", str(tmp_path))
    assert done.returncode == 0, done.stdout + done.stderr
    assert "px4 quadrotor, sysid 7 compid 1, MAVLink 2" in done.stdout
    assert (
        "autopilot firmware" in done.stdout
        and "1.14.3 official (git 7717000001020304)" in done.stdout
    )
    # The vehicle sends ATTITUDE at 20 Hz of its own; doctor shows what it gets after asking.
    # Half the asked rate tells the two apart on a starved box (the figure is not a speed).
    asked = Settings().link.message_rates_hz["ATTITUDE"]
    got = float(re.search(r"ATTITUDE (\d+)", done.stdout).group(1))
    assert asked / 2 > 20 and got > asked / 2, done.stdout
    assert "min of recording" in done.stdout
    assert "all checks passed" in done.stdout


def test_doctor_over_a_serial_pty():
    master, slave = pty.openpty()
    tty.setraw(master)
    vehicle = MavVehicle("udp", autopilot="ardupilot")  # its encoder and flight state only
    vehicle._sock.close()
    stop = threading.Event()

    def feed() -> None:
        while not stop.wait(0.05):
            for name in ("HEARTBEAT", "ATTITUDE"):
                os.write(master, vehicle.build(name).pack(vehicle.mav))
            try:
                os.read(master, 4096)  # what the station sends; keep the pty from filling
            except BlockingIOError:
                pass

    os.set_blocking(master, False)
    feeder = threading.Thread(target=feed, daemon=True)
    feeder.start()
    try:
        settings = station_settings(f"{os.ttyname(slave)}:921600")
        serial = check_serial(settings)
        assert serial[0].status == "ok", serial
        hb = check_heartbeat(settings, timeout_s=5, rates_s=1)
        assert hb[0].status == "ok", hb
        assert "ardupilot" in hb[0].detail and "sysid 1" in hb[0].detail
    finally:
        stop.set()
        feeder.join()
        os.close(master)
        os.close(slave)


def test_doctor_fails_a_serial_port_that_is_the_kernel_console(tmp_path):
    """The Pi's serial login shell is a getty run by root: a user's doctor cannot see it in
    /proc/*/fd. The kernel's command line says it (the firmware writes cmdline.txt's
    console=serial0 as the UART, console=ttyS0); here for a pty, console=pts/N."""
    master, slave = pty.openpty()
    try:
        device = os.ttyname(slave)
        settings = station_settings(f"{device}:921600")
        proc = tmp_path / "proc"  # a kernel command line of our own, in a real file
        proc.mkdir()
        console = f"console={device.removeprefix('/dev/')},115200"
        (proc / "cmdline").write_text(f"coherent_pool=1M {console} console=tty1 rootwait\n")
        (check,) = check_serial(settings, proc)
        assert check.status == "FAIL", check
        assert console in check.detail and "login shell No" in check.fix
        (proc / "cmdline").write_text("coherent_pool=1M console=tty1 rootwait\n")
        (check,) = check_serial(settings, proc)
        assert check.status == "ok", check
    finally:
        os.close(master)
        os.close(slave)


def test_pi_uart_is_judged_by_the_device_the_source_names(tmp_path):
    """On a Pi, what matters is whether the link's port is the PL011 UART (ttyAMA*) or the
    mini UART (ttyS*), however config.txt got it there; a USB cable to the Pixhawk (README
    step 1) is no UART at all. /dev/serial0 is a link the firmware points at one or the
    other: here links of our own, in real files."""
    model = tmp_path / "model"
    model.write_bytes(b"Raspberry Pi 4 Model B Rev 1.5\0")
    master, slave = pty.openpty()
    try:
        usb = os.ttyname(slave)  # a serial device that is no Pi UART, like /dev/ttyACM0
        (check,) = check_pi_uart(station_settings(f"{usb}:921600"), model)
        assert check.status == "skip" and "not the Pi's UART" in check.detail, check
    finally:
        os.close(master)
        os.close(slave)
    for target, status in (("ttyS0", "FAIL"), ("ttyAMA0", "ok")):
        uart = tmp_path / target
        uart.touch()
        serial0 = tmp_path / f"serial0-{target}"
        serial0.symlink_to(uart)
        (check,) = check_pi_uart(station_settings(f"{serial0}:921600"), model)
        assert check.status == status and target in check.detail, check
        if status == "FAIL":
            assert "mini UART" in check.detail and "dtoverlay=disable-bt" in check.fix
    (check,) = check_pi_uart(station_settings("udpin:0.0.0.0:14550"), model)
    assert check.status == "skip"


def test_doctor_reports_a_missing_serial_device_with_a_fix(tmp_path):
    done = doctor(
        "--source", "/dev/ttyDOESNOTEXIST:921600", "--heartbeat-s", "1",
        "--sessions-dir", str(tmp_path),
    )  # fmt: skip
    assert done.returncode == 1
    assert "FAIL  serial device" in done.stdout
    assert "/dev/ttyDOESNOTEXIST does not exist" in done.stdout
    assert "fix: Check the cable" in done.stdout
    assert "FAIL  MAVLink heartbeat" in done.stdout
    assert "failed: serial device, MAVLink heartbeat" in done.stdout


def test_doctor_refuses_a_malformed_source_with_a_clear_error(tmp_path):
    """The tool a field team runs on a bad setup says what is wrong with it, as `serve`
    does, instead of a traceback out of its first MAVLink check."""
    done = doctor("--source", "ttyAMA0:921600", "--sessions-dir", str(tmp_path))
    assert done.returncode == 2, done.stdout + done.stderr
    assert "Unknown MAVLink connection 'ttyAMA0:921600'" in done.stderr
    assert "Traceback" not in done.stderr


def test_doctor_fails_a_disk_under_the_configured_minimum(tmp_path):
    free_mb = os.statvfs(tmp_path).f_bavail * os.statvfs(tmp_path).f_frsize / 2**20
    full = station_settings("none", tmp_path, **{"recording.min_free_mb": free_mb + 1024})
    (check,) = check_disk(full, video_bytes_per_s=2e6)
    assert check.status == "FAIL" and "min_free_mb" in check.detail and check.fix
    roomy = station_settings("none", tmp_path, **{"recording.min_free_mb": 0})
    (check,) = check_disk(roomy, video_bytes_per_s=2e6, probe_mb=2)
    assert check.status in ("ok", "warn") and "MB/s" in check.detail
    assert list(tmp_path.iterdir()) == []  # the write probe is gone


def test_doctor_fails_a_port_in_use():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        settings = station_settings(
            "none", **{"server.port": port, "server.host": "127.0.0.1", "viser.enabled": False}
        )
        (check,) = check_ports(settings)
    assert check.status == "FAIL" and f"{port} (web)" in check.detail


def port_in_time_wait() -> int:
    """A port whose listener has closed after closing a connection first, as a station
    stopped with viewers connected leaves it: TIME_WAIT for a minute."""
    with listening_socket("127.0.0.1", 0) as listener:  # the station's own listener
        port = listener.getsockname()[1]
        with socket.create_connection(("127.0.0.1", port)) as client:
            conn, _ = listener.accept()
            conn.close()  # the server side closes first: its end waits
            client.recv(1)
    return port


def test_doctor_passes_a_port_the_station_can_bind():
    """Right after `systemctl stop fpv-station` (README step 5) the web port is in
    TIME_WAIT; the station binds it anyway (SO_REUSEADDR), so doctor must not call it in
    use. Nor is an IPv6 host ("::", dual stack) a port in use."""
    port = port_in_time_wait()
    for host in ("127.0.0.1", "::"):
        settings = station_settings(
            "none", **{"server.port": port, "server.host": host, "viser.enabled": False}
        )
        (check,) = check_ports(settings)
        assert check.status == "ok", (host, check)


def test_firmware_version_as_ardupilot_and_px4_pack_it():
    ardupilot = (4 << 24) | (5 << 16) | (7 << 8) | 255
    assert firmware_version(ardupilot, list(b"2a3dc4b7")) == "4.5.7 official (git 2a3dc4b7)"
    assert firmware_version((1 << 24) | (15 << 16) | 192, [0] * 8) == "1.15.0 rc"


def test_doctor_says_signing_refused_the_vehicle(tmp_path):
    """A vehicle that does not sign, heard by a station with a key: the heartbeat check
    fails and says why (signing), not "check the wiring"."""
    from fpv_station.core.mavlink.signing import write_key_file

    key = write_key_file(tmp_path / "mavlink.key", "field day 2026")
    with MavVehicle("udp") as vehicle:
        settings = station_settings(vehicle.station_source, **{"link.signing_key_file": key})
        hb = check_heartbeat(settings, timeout_s=1.5, rates_s=0)
    assert hb[0].status == "FAIL", hb
    assert "signing refused" in hb[0].detail and "unsigned" in hb[0].detail
    assert "signing setup" in hb[0].fix
