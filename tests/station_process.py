"""`fpv-station serve` in a subprocess for a test or a benchmark: spawned, waited for,
stopped.

    with serve_station(["--source", "none"], env={...}) as station:
        httpx.get(f"{station.base}/api/cameras"); station.process.cpu_times()

The station runs on its own (so its CPU and memory are its own), on a free loopback port,
with a fresh config folder (so no token file of the user's is read or written). It is
ready at the first `/api/health` that answers 200 with `ok`; `ready_s` is the time from
the spawn to that answer: the start-up time a field team waits for.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import httpx
import psutil

from tests.helpers import free_port

ROOT = Path(__file__).resolve().parents[1]


# `fpv-station serve` with RLIMIT_NOFILE at 256 (soft and hard), as `prlimit --nofile=256`
# starts it: the station cannot raise it, and fits its budget under it.
LOW_LIMIT = (
    "-c",
    "import resource, sys; resource.setrlimit(resource.RLIMIT_NOFILE, (256, 256)); "
    "sys.argv[0] = 'fpv-station'; from fpv_station.server.cli import main; sys.exit(main())",
)


class StationFailed(RuntimeError):
    """The station exited or did not get healthy in time; the message has its log's tail."""


@dataclass
class StationProcess:
    popen: subprocess.Popen
    port: int
    ready_s: float  # spawn -> first healthy /api/health
    ready_cpu_s: float  # its CPU seconds by then: load on the machine does not stretch it
    log_path: Path

    @property
    def base(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def process(self) -> psutil.Process:
        return psutil.Process(self.popen.pid)


@contextlib.contextmanager
def serve_station(
    args: Sequence[str] = (),
    env: Mapping[str, str] | None = None,
    *,
    launcher: Sequence[str] = ("-m", "fpv_station.server"),
    log_path: Path | None = None,
    timeout_s: float = 60.0,
    root: Path = ROOT,
    python: str | Path = sys.executable,
) -> Iterator[StationProcess]:
    """Run `python LAUNCHER serve --host 127.0.0.1 --port P ARGS` until the block ends.

    `env` is added to this process's environment; `launcher` replaces `-m fpv_station.server` (a
    script that sets something up, then runs the CLI). The server's output goes to
    `log_path` (a temporary file by default: uvicorn logs every connection). `root` is the
    checkout whose station runs (another commit's, to compare side by side); `python` the
    interpreter (another environment's, to run what is installed there)."""
    port = free_port()
    tmp = Path(tempfile.mkdtemp(prefix="fpv-station-process-"))
    keep_tmp = log_path is not None  # the caller keeps the log: leave it where it is
    log_path = log_path or tmp / "server.log"
    cmd = [str(python), *launcher, "serve", "--host", "127.0.0.1", "--port", str(port), *args]
    full_env = {
        **os.environ,
        "PYTHONPATH": str(root),
        "XDG_CONFIG_HOME": str(tmp / "config"),
        **(env or {}),
    }
    with log_path.open("w") as log:
        t0 = time.monotonic()
        popen = subprocess.Popen(cmd, cwd=root, env=full_env, stdout=log, stderr=subprocess.STDOUT)
        try:
            ready_s = _wait_healthy(popen, f"http://127.0.0.1:{port}", t0, timeout_s, log_path)
            times = psutil.Process(popen.pid).cpu_times()
            yield StationProcess(popen, port, ready_s, times.user + times.system, log_path)
        finally:
            popen.terminate()
            try:
                popen.wait(30)
            except subprocess.TimeoutExpired:
                popen.kill()
                popen.wait()
            if not keep_tmp:
                shutil.rmtree(tmp, ignore_errors=True)


def _wait_healthy(
    popen: subprocess.Popen, base: str, t0: float, timeout_s: float, log_path: Path
) -> float:
    last = "no answer"
    with httpx.Client(timeout=2.0) as client:
        while time.monotonic() - t0 < timeout_s:
            if popen.poll() is not None:
                raise StationFailed(f"station exited ({popen.returncode}): {_tail(log_path)}")
            try:
                reply = client.get(f"{base}/api/health")
                if reply.status_code == 200 and reply.json().get("ok"):
                    return time.monotonic() - t0
                last = f"{reply.status_code} {reply.text[:200]}"
            except httpx.HTTPError as exc:
                last = type(exc).__name__
            time.sleep(0.01)
    raise StationFailed(f"not healthy after {timeout_s:g} s ({last}): {_tail(log_path)}")


def _tail(path: Path, lines: int = 20) -> str:
    try:
        return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])
    except OSError:
        return "(no log)"
