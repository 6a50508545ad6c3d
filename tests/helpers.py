"""Shared test helpers: free ports, a real uvicorn server in a thread, Chromium flags."""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path

from server.listen import listening_socket, uvicorn_server
from server.settings import Settings, load_settings

# Flags that let Debian's chromium run headless as root on this closed network.
CHROMIUM_PATH = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


def free_port(kind: int = socket.SOCK_STREAM) -> int:
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def run_uvicorn(app, port: int | None = None, timeout: float = 15.0) -> Iterator[str]:
    """Serve `app` with a real uvicorn in a thread, configured and on the kind of socket
    `fpv-station serve` uses; yields the base URL."""
    sock = listening_socket("127.0.0.1", port or 0)
    port = sock.getsockname()[1]
    server = uvicorn_server(app, log_level="warning")
    thread = threading.Thread(
        target=server.run, kwargs={"sockets": [sock]}, name="uvicorn-test", daemon=True
    )
    thread.start()
    deadline = time.monotonic() + timeout
    while not server.started:
        if not thread.is_alive() or time.monotonic() > deadline:
            raise RuntimeError("uvicorn did not start")
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout)
        sock.close()


def wait_until(predicate, timeout: float = 5.0, interval: float = 0.02) -> bool:
    """Poll `predicate` until it is true or `timeout` passes; returns its last value."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value or time.monotonic() > deadline:
            return value
        time.sleep(interval)


def station_settings(source: str, sessions_dir: Path | None = None, **overrides) -> Settings:
    """A test station on `source`: no 3D panel, no recording on arming, and sessions (when
    it records) in `sessions_dir` whatever the disk's free space."""
    base: dict = {
        "link.source": source,
        "viser.enabled": False,
        "recording.auto_record_on_arm": False,
    }
    if sessions_dir is not None:
        base |= {"recording.sessions_dir": str(sessions_dir), "recording.min_free_mb": 0}
    return load_settings(environ={}, overrides={**base, **overrides})
