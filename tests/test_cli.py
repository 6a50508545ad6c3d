"""`fpv-station serve` as a real process: flags, TOML, environment, forwarding."""

import os
import socket
import subprocess
import sys
from pathlib import Path

import httpx

from tests.helpers import free_port, wait_until
from tests.mav_vehicle import MavVehicle

ROOT = Path(__file__).resolve().parents[1]


def serve(*args, env=None):
    return subprocess.Popen(
        [sys.executable, "-m", "fpv_station.server", "serve", *args],
        cwd=ROOT,
        # Any free port for the 3D panel (other runs may hold 8080), no sessions here.
        env={
            **os.environ,
            "FPV_VISER__PORT": "0",
            "FPV_RECORDING__AUTO_RECORD_ON_ARM": "false",
            **(env or {}),
        },
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )


def test_bad_source_is_refused_with_a_clear_message():
    for args, words in (
        (["--source", "serial0"], "Unknown MAVLink connection"),
        (["--source", "udpin:nohost"], "HOST:PORT"),
        (["--source", "none", "--forward", "tcp:1.2.3.4:5"], "--forward"),
        (["--source", "replay:x.tlog?speed=fast"], "speed"),
    ):
        p = serve(*args)
        out, _ = p.communicate(timeout=30)
        assert p.returncode == 2, out
        assert words in out


def test_serve_with_flags_config_env_and_forwarding(tmp_path):
    qgc = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    qgc.bind(("127.0.0.1", 0))
    qgc.settimeout(5)
    port = free_port()
    cfg = tmp_path / "station.toml"
    cfg.write_text(f'[server]\nhost = "127.0.0.1"\nport = {port}\n[link]\nlink_lost_s = 9.0\n')
    with MavVehicle("udp", sysid=9) as v:
        p = serve(
            "--config",
            str(cfg),
            "--source",
            v.station_source,
            "--sysid",
            "9",
            "--forward",
            f"udpout:127.0.0.1:{qgc.getsockname()[1]}",
            env={"FPV_LINK__LINK_LOST_S": "1.25"},
        )
        try:
            base = f"http://127.0.0.1:{port}"

            def status():
                try:
                    return httpx.get(f"{base}/api/status", timeout=10).json()
                except httpx.HTTPError:
                    return None

            assert wait_until(
                lambda: (s := status()) and s["state"] and s["state"]["heartbeat"]["sysid"] == 9,
                timeout=90,  # a station process starting on a loaded machine
            )
            data, _ = qgc.recvfrom(65535)  # the forward copy arrives
            assert data[0] in (0xFD, 0xFE)
            v.silent = True  # env (1.25 s) beat the file (9 s): lost within seconds
            assert wait_until(lambda: status()["link"]["link_lost"], timeout=15)
        finally:
            p.terminate()
            out, _ = p.communicate(timeout=15)
            qgc.close()
        assert "open http://127.0.0.1" in out
