"""`fpv-station install-service`: the systemd unit that runs the station on the Pi.

The unit text lives here (so a pip-installed station can write it) and
deploy/fpv-station.service is its rendering with the defaults (a test keeps the two the
same). Paths a field team looks for:

    /etc/fpv-station/config.toml         settings (written once, never overwritten)
    /var/lib/fpv-station/sessions        recorded sessions
    /var/lib/fpv-station/token           the control token (`sudo cat` it)
"""

from __future__ import annotations

import grp
import os
import pwd
import shutil
import subprocess
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

UNIT_NAME = "fpv-station.service"
UNIT_DIR = Path("/etc/systemd/system")
CONFIG_FILE = Path("/etc/fpv-station/config.toml")
STATE_DIR = Path("/var/lib/fpv-station")  # systemd's StateDirectory=fpv-station
DEFAULT_USER = "fpv-station"
DEFAULT_EXEC = "/usr/local/bin/fpv-station"
# dialout: the Pixhawk's UART or USB serial; video: the V4L2 cameras.
DEVICE_GROUPS = ("dialout", "video")
WATCHDOG_S = 30
# What the unit hides from the service (ProtectHome=, PrivateTmp=): a station installed
# there cannot be started by it; its user could not read a login user's home anyway.
HIDDEN_FROM_SERVICE = ("/home", "/root", "/run/user", "/tmp", "/var/tmp")

UNIT_TEMPLATE = """\
# fpv-station on the Raspberry Pi: written by `fpv-station install-service`.
[Unit]
Description=fpv-station ground station (telemetry, cameras, recording)
Wants=network-online.target
After=network-online.target time-sync.target
# Restart=always forever: a field station has nobody to reset a start limit.
StartLimitIntervalSec=0

[Service]
Type=notify
NotifyAccess=main
ExecStart={exec_path} serve --config {config}
User={user}
Group={user}
SupplementaryGroups={groups}
StateDirectory=fpv-station
StateDirectoryMode=0750
ConfigurationDirectory=fpv-station
WorkingDirectory={state_dir}
Environment=HOME={state_dir}
# READY when serving; WATCHDOG only while every supervised task lives (server/sd_notify.py).
WatchdogSec={watchdog_s}
TimeoutStartSec=90
TimeoutStopSec=20
Restart=always
RestartSec=2

# Hardening that still reaches the serial ports and the V4L2 cameras (no PrivateDevices).
DevicePolicy=closed
DeviceAllow=char-ttyAMA rw
DeviceAllow=char-ttyS rw
DeviceAllow=char-ttyACM rw
DeviceAllow=char-ttyUSB rw
DeviceAllow=char-video4linux rw
NoNewPrivileges=yes
CapabilityBoundingSet=
AmbientCapabilities=
ProtectSystem=strict
ProtectHome=yes
PrivateTmp=yes
ProtectKernelTunables=yes
ProtectKernelModules=yes
ProtectKernelLogs=yes
ProtectControlGroups=yes
ProtectHostname=yes
# No ProtectClock: its seccomp filter refuses adjtimex() even to read whether the clock
# is synchronised (systemd issue 26413), which sessions need on an RTC-less Pi
# (companion/system_clock.py). The empty CapabilityBoundingSet already denies setting it.
RestrictAddressFamilies=AF_UNIX AF_INET AF_INET6 AF_NETLINK
RestrictNamespaces=yes
RestrictRealtime=yes
RestrictSUIDSGID=yes
LockPersonality=yes
SystemCallArchitectures=native
UMask=0027

[Install]
WantedBy=multi-user.target
"""

# A small Pi (Pi 3, Pi Zero 2 W): the pages at 25 messages a second and about half the
# MAVLink messages (75 a second instead of 140), which `benchmarks/pi_budget.py
# --rates small-pi` measures (docs/PERFORMANCE.md). The horizon then redraws at
# 25 Hz, about the cameras' rate; the trajectory and the tlog get positions at 10 Hz.
# The config file has them commented out, one line in [server] and one in [link].
SMALL_PI_SERVER = "telemetry_rate_hz = 25"
SMALL_PI_LINK = (
    "message_rates_hz = { ATTITUDE = 25, GLOBAL_POSITION_INT = 10, LOCAL_POSITION_NED = 10, "
    "VFR_HUD = 5, GPS_RAW_INT = 5, RC_CHANNELS = 10, SERVO_OUTPUT_RAW = 5, SYS_STATUS = 2, "
    "BATTERY_STATUS = 1, SYSTEM_TIME = 1 }"
)


def small_pi_toml() -> str:
    """The small-Pi settings as a TOML file of their own (for the benchmark)."""
    return f"[server]\n{SMALL_PI_SERVER}\n\n[link]\n{SMALL_PI_LINK}\n"


CONFIG_TEMPLATE = (
    """\
# fpv-station settings; `fpv-station config --dump --config FILE` prints every setting,
# what it does and the value it takes (flags override these).
[server]
token_file = "{state_dir}/token"
# On a Pi 3 or a Pi Zero 2 W uncomment this line and the last one of [link]:
# """
    + SMALL_PI_SERVER
    + """

[link]
# The Pixhawk on the Pi's UART (TELEM2 at 921600); a USB cable is /dev/ttyACM0.
source = "/dev/serial0:921600"
# """
    + SMALL_PI_LINK.replace("{", "{{").replace("}", "}}")
    + """

[recording]
sessions_dir = "{state_dir}/sessions"

[cameras.front]
spec = "v4l2:/dev/video0?width=640&height=480&fps=30&fourcc=MJPG"

[cameras.bottom]
spec = "v4l2:/dev/video2?width=640&height=480&fps=30&fourcc=MJPG"
"""
)


@dataclass(frozen=True)
class ServicePlan:
    user: str = DEFAULT_USER
    exec_path: str = DEFAULT_EXEC
    config: Path = CONFIG_FILE
    unit_dir: Path = UNIT_DIR

    def unit_text(self) -> str:
        return UNIT_TEMPLATE.format(
            exec_path=self.exec_path,
            config=self.config,
            user=self.user,
            groups=" ".join(DEVICE_GROUPS),
            state_dir=STATE_DIR,
            watchdog_s=WATCHDOG_S,
        )

    def config_text(self) -> str:
        return CONFIG_TEMPLATE.format(state_dir=STATE_DIR)

    def commands(self, user_exists: bool) -> list[list[str]]:
        """What install runs after writing the files, in order."""
        cmds = []
        if not user_exists:
            cmds.append(
                ["useradd", "--system", "--user-group", "--home-dir", str(STATE_DIR)]
                + ["--no-create-home", "--shell", "/usr/sbin/nologin", self.user]
            )
        present = [g for g in DEVICE_GROUPS if _group_exists(g)]
        if present:
            cmds.append(["usermod", "--append", "--groups", ",".join(present), self.user])
        cmds.append(["systemctl", "daemon-reload"])
        cmds.append(["systemctl", "enable", "--now", UNIT_NAME])
        return cmds


def _group_exists(name: str) -> bool:
    return _known(grp.getgrnam, name)


def _user_exists(name: str) -> bool:
    return _known(pwd.getpwnam, name)


def _known(lookup: Callable[[str], object], name: str) -> bool:
    try:
        lookup(name)
        return True
    except KeyError:
        return False


def installed_exec_path() -> str:
    """This fpv-station's own executable (a venv's or pip's), else the default path."""
    if Path(sys.argv[0]).name == "fpv-station":  # run as the script itself
        return str(Path(sys.argv[0]).resolve())
    found = shutil.which("fpv-station")
    return str(Path(found).resolve()) if found else DEFAULT_EXEC


def install(plan: ServicePlan, dry_run: bool, out=sys.stdout) -> int:
    if any(Path(plan.exec_path).is_relative_to(d) for d in HIDDEN_FROM_SERVICE):
        print(
            f"fpv-station install-service: {plan.exec_path} is where the service cannot "
            "reach it (ProtectHome=yes, PrivateTmp=yes): it would fail to start. Install "
            "the station in /opt (sudo python3 -m venv /opt/fpv-station; sudo "
            "/opt/fpv-station/bin/pip install ./fpv-station) and run that one's "
            "install-service.",
            file=out,
        )
        return 1
    unit_path = plan.unit_dir / UNIT_NAME
    cmds = plan.commands(_user_exists(plan.user))
    if dry_run:
        print(f"# {unit_path}", file=out)
        print(plan.unit_text(), file=out)
        print(f"# {plan.config} (only if absent)", file=out)
        print(plan.config_text(), file=out)
        print("# then:", file=out)
        for cmd in cmds:
            print(" ".join(cmd), file=out)
        return 0
    if os.geteuid() != 0:
        print("fpv-station install-service: run it as root (sudo), or use --dry-run.", file=out)
        return 1
    plan.config.parent.mkdir(parents=True, exist_ok=True)
    if not plan.config.exists():  # a field team's edits are never overwritten
        plan.config.write_text(plan.config_text())
    unit_path.write_text(plan.unit_text())
    for cmd in cmds:
        print("+ " + " ".join(cmd), file=out)
        done = subprocess.run(cmd, check=False)
        if done.returncode != 0:
            print(f"fpv-station install-service: '{cmd[0]}' failed.", file=out)
            return 1
    print(f"fpv-station: installed and started; logs: journalctl -u {UNIT_NAME} -f", file=out)
    return 0
