"""Test processes: a Python module or `fpv-station serve` spawned from the checkout, the
marker lines it prints, its health, its stop; and the complete rows of a CSV its writer
may have been cut off in."""

from __future__ import annotations

import csv
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx

ROOT = Path(__file__).resolve().parent.parent


def complete_rows(path: Path) -> list[dict[str, str]]:
    """The rows of a CSV file up to its last whole line (a killed writer cuts the next)."""
    data = path.read_bytes()
    data = data[: data.rfind(b"\n") + 1]  # a cut last line is not a row
    return list(csv.DictReader(data.decode().splitlines()))


def spawn(args: list[str], env: dict | None = None) -> subprocess.Popen:
    """`python ARGS` from the checkout, `env` added to ours, its output read as text."""
    return subprocess.Popen(
        [sys.executable, *args],
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
        env={**os.environ, **(env or {})},
    )


def serve_args(source: str, port: int) -> list[str]:
    """`fpv-station serve` on loopback; --open: these tests are not about the token."""
    return ["-m", "fpv_station.server", "serve", "--source", source, "--host", "127.0.0.1"] + [
        *("--port", str(port), "--no-3d", "--open")
    ]


def station_up(base: str) -> bool:
    try:
        return httpx.get(f"{base}/api/health", timeout=1).status_code == 200
    except httpx.HTTPError:
        return False


def terminate(proc: subprocess.Popen, timeout: float = 30.0) -> None:
    """SIGTERM, then SIGKILL if it has not ended within `timeout` (a hang guard)."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def read_line(proc: subprocess.Popen, prefix: str, timeout: float = 20.0) -> str:
    """The rest of the first line `proc` prints that starts with `prefix`."""
    deadline = time.monotonic() + timeout
    assert proc.stdout is not None
    while time.monotonic() < deadline:
        line = proc.stdout.readline()
        if line.startswith(prefix):
            return line[len(prefix) :].strip()
        if not line and proc.poll() is not None:
            break
    raise AssertionError(f"no '{prefix}' line from the recording process")
