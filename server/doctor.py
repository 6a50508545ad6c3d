"""`fpv-station doctor`: is this Pi wired and set up to fly? A table of checks, each with
the fix for a failure; the exit code is 1 when any check fails.

Each check reads the real thing with the station's own settings: the serial node, the
Pi's boot config, a MAVLink link (the station's MavlinkLink, so the same stream requests),
the cameras, the sessions folder, the kernel's clock state, the ports.
"""

from __future__ import annotations

import os
import platform
import shutil
import stat
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.link_health import LinkSecurity
from fpv_station.companion.system_clock import clock_synchronised
from fpv_station.core.mavlink.framing import MavFramer
from fpv_station.server.listen import listening_socket
from fpv_station.server.settings import Settings

if TYPE_CHECKING:
    from fpv_station.companion.link import MavlinkLink

Status = Literal["ok", "FAIL", "warn", "skip"]
# JPEG bytes per 640x480 frame when no camera delivers one to measure (typical USB MJPEG).
ASSUMED_JPEG_BYTES = 40_000
TELEMETRY_BYTES_PER_S = 20_000  # tlog + telemetry.csv at the default rates, generously


@dataclass(frozen=True)
class Check:
    name: str
    status: Status
    detail: str
    fix: str = ""


def check_serial(settings: Settings, proc: Path = Path("/proc")) -> list[Check]:
    from fpv_station.companion.transports import parse_connection

    spec = parse_connection(settings.link.source)
    if spec.kind != "serial":
        return [Check("serial device", "skip", f"source is {spec.kind} ({spec.text})")]
    path = Path(spec.path)
    if not path.exists():
        return [
            Check(
                "serial device",
                "FAIL",
                f"{path} does not exist",
                "Check the cable; on a Pi UART enable it (raspi-config > Interface Options > "
                "Serial Port: login shell No, hardware Yes) and reboot; USB: /dev/ttyACM0.",
            )
        ]
    if not stat.S_ISCHR(path.stat().st_mode):
        return [Check("serial device", "FAIL", f"{path} is not a character device", "")]
    if not os.access(path, os.R_OK | os.W_OK):
        return [
            Check(
                "serial device",
                "FAIL",
                f"{path} is not readable and writable by this user",
                f"sudo usermod -aG dialout {_user()} (then log in again)",
            )
        ]
    console = _kernel_console_on(path, proc)
    if console is not None:
        return [
            Check(
                "serial device",
                "FAIL",
                f"{path} is the kernel's console ({console} in {proc / 'cmdline'}): boot "
                "messages and a login shell share the autopilot's wires",
                "raspi-config > Interface Options > Serial Port: login shell No, hardware Yes "
                "(it removes console=serial0 from cmdline.txt), then reboot.",
            )
        ]
    holders = _holders(path, proc)
    if holders:
        return [
            Check(
                "serial device",
                "FAIL",
                f"{path} is open by {', '.join(holders)}",
                "A login shell on the UART: raspi-config > Serial Port: login shell No; "
                "or stop the program named.",
            )
        ]
    return [Check("serial device", "ok", f"{path} at {spec.baud} baud, free, read/write")]


def _kernel_console_on(device: Path, proc: Path) -> str | None:
    """The `console=` argument of the running kernel that names `device`, if any. The Pi's
    serial login shell is a getty on that console, run by root: only root can see it in
    /proc/*/fd, while /proc/cmdline is readable by anyone. The firmware writes
    cmdline.txt's `console=serial0` as the UART it stands for (`console=ttyS0`), so both
    names of the device are looked for."""
    try:
        args = (proc / "cmdline").read_text().split()
    except OSError:
        return None
    real = device.resolve()
    names = {device.name, real.name}
    if real.is_relative_to("/dev"):
        names.add(str(real.relative_to("/dev")))  # /dev/pts/3 is console=pts/3
    for arg in args:
        if arg.startswith("console=") and arg.removeprefix("console=").split(",")[0] in names:
            return arg
    return None


def _holders(device: Path, proc: Path) -> list[str]:
    """Other processes with `device` open (`pid name`), from /proc/*/fd."""
    target = device.resolve()
    found = []
    for pid_dir in proc.glob("[0-9]*"):
        if pid_dir.name == str(os.getpid()):
            continue
        try:
            fds = list((pid_dir / "fd").iterdir())
        except OSError:
            continue
        for fd in fds:
            try:
                if Path(os.readlink(fd)) == target:
                    name = (pid_dir / "comm").read_text().strip()
                    found.append(f"{pid_dir.name} {name}")
                    break
            except OSError:
                continue
    return found


def check_pi_uart(
    settings: Settings, model_file: Path = Path("/proc/device-tree/model")
) -> list[Check]:
    """On a Pi, is the link's port the full PL011 UART (ttyAMA*) and not the mini UART
    (ttyS*)? Asked of the device the source names (/dev/serial0 is a link the firmware
    points at one or the other), so that any way of getting there passes (disable-bt,
    miniuart-bt, a Pi without Bluetooth) and a USB cable to the Pixhawk is no UART."""
    from fpv_station.companion.transports import parse_connection

    try:
        model = model_file.read_bytes().rstrip(b"\0").decode()
    except OSError:
        return [Check("Pi UART", "skip", "not a Raspberry Pi")]
    if "Raspberry Pi" not in model:
        return [Check("Pi UART", "skip", f"not a Raspberry Pi ({model})")]
    spec = parse_connection(settings.link.source)
    if spec.kind != "serial" or not Path(spec.path).exists():  # no port: "serial device"
        return [Check("Pi UART", "skip", f"{model}: no serial port to judge ({spec.text})")]
    real = Path(spec.path).resolve()
    if real.name.startswith("ttyS"):
        return [
            Check(
                "Pi UART",
                "FAIL",
                f"{model}: {spec.path} is {real}, the mini UART",
                "Add dtoverlay=disable-bt to /boot/firmware/config.txt (the PL011 UART then "
                "serves GPIO14/15) and reboot: the mini UART drifts at 921600 baud.",
            )
        ]
    if not real.name.startswith("ttyAMA"):
        return [Check("Pi UART", "skip", f"{model}: {real} is not the Pi's UART (USB?)")]
    return [Check("Pi UART", "ok", f"{model}: {spec.path} is {real}, the PL011 UART")]


def check_heartbeat(settings: Settings, timeout_s: float, rates_s: float = 3.0) -> list[Check]:
    from fpv_station.companion.link import MavlinkLink

    if settings.link.source.strip() in ("none", "sim"):
        return [Check("MAVLink heartbeat", "skip", f"source is {settings.link.source}")]
    link = MavlinkLink(settings.link)
    version = AutopilotVersionProbe()
    link.add_packet_listener(version.on_packet)
    link.start()
    try:
        deadline = time.monotonic() + timeout_s
        hb = None
        while time.monotonic() < deadline:
            current = link.state.get()
            if current is not None and current.value.heartbeat.sysid is not None:
                hb = current.value.heartbeat
                break
            time.sleep(0.05)
        if hb is None:
            health = link.health()
            why = health.last_error or (
                f"{health.bytes_total} bytes, {health.packets} packets, none from an autopilot"
            )
            fix = (
                "Check TX/RX are crossed, the baud rate matches (PX4 SER_TEL2_BAUD, "
                "ArduPilot SERIALn_BAUD) and MAVLink is enabled on that port."
            )
            refused, refused_fix = _refused(health.security)
            return [
                Check(
                    "MAVLink heartbeat",
                    "FAIL",
                    f"nothing heard on {settings.link.source} in {timeout_s:g} s ({why}{refused})",
                    refused_fix or fix,
                )
            ]
        version.ask(link, hb.sysid, hb.compid)
        time.sleep(rates_s)  # the stream requests have been sent; let the rates settle
        health = link.health()
    finally:
        link.stop()
    rates = ", ".join(f"{k} {v:.0f}" for k, v in sorted(health.rates_hz.items()) if v > 0)
    return [
        Check(
            "MAVLink heartbeat",
            "ok",
            f"{hb.autopilot} {hb.vehicle_type}, sysid {hb.sysid} compid {hb.compid}, "
            f"MAVLink {hb.mavlink_version}, mode {hb.mode}, streams via {health.stream_request}",
        ),
        version.check(),
        Check("MAVLink rates (Hz)", "ok" if rates else "warn", rates or "no messages"),
    ]


def _refused(sec: LinkSecurity) -> tuple[str, str | None]:
    """What the link refused, in words, and what to do about it (None: nothing refused)."""
    parts, fixes = [], []
    if sec.foreign_datagrams:
        parts.append(
            f"{sec.foreign_datagrams} datagrams from other addresses, latest "
            f"{sec.last_foreign_sender}"
        )
        fixes.append(
            "The vehicle answers from another address than the one the link hears: use "
            "udpin: for it, or set link.udpin_lock = false if several hosts feed one port."
        )
    if sec.refused:
        parts.append(
            f"signing refused {sec.unsigned_refused} unsigned, {sec.bad_signature_refused} "
            f"wrongly signed, {sec.replay_refused} replayed packets"
        )
        fixes.append(
            "The vehicle does not sign with link.signing_key_file's passphrase: give it "
            "the same one (MAVProxy 'signing setup PASSPHRASE' over USB) or fix the file."
        )
    return ("; " + "; ".join(parts) if parts else ""), (" ".join(fixes) or None)


# FIRMWARE_VERSION_TYPE, the low byte of AUTOPILOT_VERSION.flight_sw_version.
_RELEASE_TYPES = {0: "dev", 64: "alpha", 128: "beta", 192: "rc", 255: "official"}


def firmware_version(flight_sw_version: int, custom: bytes | list[int] = b"") -> str:
    """ "1.14.0 official (git 7717abcd)": AUTOPILOT_VERSION's packed major.minor.patch.type
    and the first bytes of the firmware's git hash, as PX4 and ArduPilot fill them."""
    v = flight_sw_version
    kind = _RELEASE_TYPES.get(v & 0xFF, f"type {v & 0xFF}")
    text = f"{v >> 24 & 0xFF}.{v >> 16 & 0xFF}.{v >> 8 & 0xFF} {kind}"
    git = bytes(custom).rstrip(b"\0")
    if git:
        text += (
            f" (git {git.decode('ascii', 'replace')})"
            if git.isascii() and git.isalnum()
            else (f" (git {git.hex()})")
        )
    return text


class AutopilotVersionProbe:
    """Asks the autopilot for AUTOPILOT_VERSION (MAV_CMD_REQUEST_MESSAGE, and the older
    REQUEST_AUTOPILOT_CAPABILITIES that ArduPilot before 4.1 answers) and keeps its answer.
    `on_packet` runs in the link's thread; `check` reads what it kept."""

    def __init__(self) -> None:
        self._framer = MavFramer()
        self._sysid: int | None = None
        self.version: str | None = None

    def ask(self, link: MavlinkLink, sysid: int | None, compid: int | None) -> None:
        self._sysid = sysid
        mav = link.mav
        for cmd, p1 in (
            (mavlink.MAV_CMD_REQUEST_MESSAGE, mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION),
            (mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1),
        ):
            link.send(
                mav.command_long_encode(sysid or 1, compid or 1, cmd, 0, p1, 0, 0, 0, 0, 0, 0)
            )

    def on_packet(self, t_wall: float, packet: bytes) -> None:
        if self.version is not None or self._sysid is None:
            return
        for msg in self._framer.feed(packet):
            if msg.get_type() == "AUTOPILOT_VERSION" and msg.get_srcSystem() == self._sysid:
                self.version = firmware_version(msg.flight_sw_version, msg.flight_custom_version)

    def check(self) -> Check:
        if self.version is None:
            return Check(
                "autopilot firmware",
                "warn",
                "no AUTOPILOT_VERSION in answer to MAV_CMD_REQUEST_MESSAGE",
                "Old firmware may not answer; the version shows in QGroundControl's "
                "Summary or Mission Planner's Messages tab.",
            )
        return Check("autopilot firmware", "ok", self.version)


def check_cameras(settings: Settings, seconds: float = 2.0) -> tuple[list[Check], float]:
    """Each configured camera: does it deliver, at what fps; and the bytes per second."""
    from fpv_station.companion.cameras.rig import CAMERA_NAMES, build_camera

    checks, bytes_per_s = [], 0.0
    for name in CAMERA_NAMES:
        cfg = getattr(settings.cameras, name)
        if cfg.spec in (None, "none"):
            checks.append(Check(f"camera {name}", "skip", "not configured"))
            continue
        if cfg.spec.startswith("sim"):
            checks.append(Check(f"camera {name}", "skip", "sim camera (needs the twin)"))
            continue
        camera = build_camera(name, cfg, link_source=settings.link.source)
        camera.start()
        try:
            time.sleep(seconds)
            stats, latest = camera.stats(), camera.frames.get()
        finally:
            camera.stop()
        frame = latest.value if latest is not None else None
        if not stats.signal or frame is None or not frame.signal:
            checks.append(
                Check(
                    f"camera {name}",
                    "FAIL",
                    f"{cfg.spec}: no picture in {seconds:g} s ({stats.reason or 'no frame'})",
                    "fpv-station cameras lists the devices and their formats; check the "
                    "cable and that this user is in the video group.",
                )
            )
            continue
        fps = stats.delivered_fps
        bytes_per_s += fps * len(frame.jpeg)
        mjpeg = "MJPEG passed through" if stats.passthrough_frames else "re-encoded (no MJPEG)"
        checks.append(
            Check(
                f"camera {name}",
                "ok" if fps >= 0.8 * stats.configured_fps else "warn",
                f"{stats.description}: {stats.width}x{stats.height}, {fps:.1f} fps delivered "
                f"(asked {stats.configured_fps:g}), {mjpeg}, {len(frame.jpeg) // 1000} kB/frame",
                ""
                if fps >= 0.8 * stats.configured_fps
                else "Lower fps or resolution, or a "
                "camera that delivers MJPEG (fpv-station cameras).",
            )
        )
    return checks, bytes_per_s


def check_disk(settings: Settings, video_bytes_per_s: float, probe_mb: int = 16) -> list[Check]:
    folder = settings.recording.sessions_dir
    try:
        folder.mkdir(parents=True, exist_ok=True)
        usage = shutil.disk_usage(folder)
    except OSError as exc:
        return [
            Check(
                "sessions disk",
                "FAIL",
                f"{folder}: {exc}",
                "Run doctor as the user the station runs as (the service's: sudo -u "
                "fpv-station ...; its folder is closed to others), or make the folder "
                "writable by that user.",
            )
        ]
    min_free = settings.recording.min_free_mb * 1024 * 1024
    usable = usage.free - min_free
    rate = video_bytes_per_s + TELEMETRY_BYTES_PER_S
    minutes = max(usable, 0) / rate / 60
    free = f"{usage.free / 1e9:.1f} GB free of {usage.total / 1e9:.1f} GB"
    if usable <= 0:
        return [
            Check(
                "sessions disk",
                "FAIL",
                f"{folder}: {free}, under recording.min_free_mb = "
                f"{settings.recording.min_free_mb:g}",
                "Pull and delete old sessions (see README 'Where sessions go'), or use a "
                "bigger SD card.",
            )
        ]
    speed = _write_speed(folder, probe_mb)
    if isinstance(speed, str):
        return [Check("sessions disk", "FAIL", f"{folder}: write failed: {speed}", "")]
    ok = speed * 1e6 > 2 * rate
    return [
        Check(
            "sessions disk",
            "ok" if ok else "warn",
            f"{folder}: {free}, writes {speed:.0f} MB/s, ~{minutes:.0f} min of recording "
            f"at {rate / 1e6:.1f} MB/s",
            "" if ok else "A faster SD card (A1/A2, U3) or a USB SSD.",
        )
    ]


def _write_speed(folder: Path, mb: int) -> float | str:
    """MB/s of a synced write of `mb` MB into `folder`; the error text if it fails."""
    probe = folder / ".doctor-write-probe"
    block = os.urandom(1024 * 1024)
    try:
        t0 = time.perf_counter()
        with open(probe, "wb") as f:
            for _ in range(mb):
                f.write(block)
            f.flush()
            os.fsync(f.fileno())
        return mb / (time.perf_counter() - t0)
    except OSError as exc:
        return str(exc)
    finally:
        probe.unlink(missing_ok=True)


def check_clock() -> list[Check]:
    synced = clock_synchronised()
    now = time.strftime("%Y-%m-%d %H:%M:%S UTC", time.gmtime())
    if synced is None:
        return [Check("clock sync", "skip", f"the kernel does not say ({now})")]
    if not synced:
        return [
            Check(
                "clock sync",
                "warn",
                f"system clock not synchronised ({now})",
                "A Pi has no RTC: sessions take UTC from the vehicle's GPS (SYSTEM_TIME) "
                "once it has a fix, and from this clock before. Give the Pi network time "
                "once (NTP), or fit an RTC HAT.",
            )
        ]
    return [Check("clock sync", "ok", f"synchronised ({now})")]


def check_ports(settings: Settings) -> list[Check]:
    wanted = {"web": settings.server.port}
    if settings.viser.enabled:
        wanted["3D panel"] = settings.viser.port
        wanted["replay 3D"] = settings.viser.replay_port_resolved
    busy = []
    for what, port in wanted.items():
        if port == 0:
            continue
        # Bound as the station binds (its family for the host, SO_REUSEADDR): a port left
        # in TIME_WAIT by a station just stopped is free to it, a listening one is not.
        try:
            listening_socket(settings.server.host, port).close()
        except OSError:
            busy.append(f"{port} ({what})")
    if busy:
        return [
            Check(
                "ports",
                "FAIL",
                f"in use: {', '.join(busy)}",
                "Another station running? systemctl status fpv-station; or choose --port.",
            )
        ]
    return [Check("ports", "ok", "free: " + ", ".join(f"{p} ({w})" for w, p in wanted.items()))]


def check_versions() -> list[Check]:
    from importlib.metadata import PackageNotFoundError, version

    parts = [f"python {platform.python_version()}", platform.machine()]
    for dist in ("fpv-station", "pymavlink", "opencv-python-headless", "numpy", "viser"):
        try:
            parts.append(f"{dist} {version(dist)}")
        except PackageNotFoundError:
            parts.append(f"{dist} missing")
    return [Check("versions", "ok", ", ".join(parts))]


def run_checks(settings: Settings, heartbeat_s: float = 5.0) -> list[Check]:
    cameras, video_rate = check_cameras(settings)
    if not any(c.status == "ok" for c in cameras):  # none measured: assume typical ones
        video_rate = 2 * 30 * ASSUMED_JPEG_BYTES
    return [
        *check_serial(settings),
        *check_pi_uart(settings),
        *check_heartbeat(settings, heartbeat_s),
        *cameras,
        *check_disk(settings, video_rate),
        *check_clock(),
        *check_ports(settings),
        *check_versions(),
    ]


def format_table(checks: list[Check]) -> str:
    width = max(len(c.name) for c in checks)
    lines = []
    for c in checks:
        lines.append(f"{c.status:<4}  {c.name:<{width}}  {c.detail}")
        if c.fix and c.status in ("FAIL", "warn"):
            lines.append(f"{'':<4}  {'':<{width}}  fix: {c.fix}")
    return "\n".join(lines)


def _user() -> str:
    import pwd

    return pwd.getpwuid(os.geteuid()).pw_name
