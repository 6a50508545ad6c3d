"""Shared test helpers: free ports, a real uvicorn server in a thread, Debian's Chromium."""

from __future__ import annotations

import base64
import contextlib
import json
import os
import selectors
import socket
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from fpv_station.server.listen import listening_socket, uvicorn_server
from fpv_station.server.settings import Settings, load_settings

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


@contextlib.contextmanager
def chromium():
    """Debian's chromium, headless, through Playwright (no browser download): yields the
    Browser. Tests take it as the `browser` fixture (conftest.py)."""
    from playwright.sync_api import expect, sync_playwright

    # Hang guards, not speed figures: a starved 2-core CI box has taken more than the 5 s
    # default for a page's first telemetry. Explicit waits in the tests are 15 or 30 s.
    expect.set_options(timeout=15_000)
    with sync_playwright() as p:
        browser = p.chromium.launch(executable_path=CHROMIUM_PATH, args=CHROMIUM_ARGS)
        try:
            yield browser
        finally:
            browser.close()


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


def viser_camera(x: float = -25.0) -> bytes:
    """A 3D panel viewer's camera report, as viser's client sends it (`x` east)."""
    import msgspec
    from viser._messages import ViewerCameraMessage

    message = ViewerCameraMessage(
        wxyz=(1.0, 0.0, 0.0, 0.0),
        position=(x, -30.0, 20.0),
        fov=1.0,
        near=0.01,
        far=1000.0,
        image_height=480,
        image_width=640,
        look_at=(0.0, 0.0, 0.0),
        up_direction=(0.0, 0.0, 1.0),
    )
    return msgspec.msgpack.encode(message.as_serializable_dict())


def watch_viser_pushes(monkeypatch, module) -> list[tuple[str, str]]:
    """The messages viser is handed from a thread other than its own loop's, once
    `module.open_viser` has built a server (its constructor queues its own defaults):
    (thread name, message type) each. viser wakes its senders with an Event of its own
    loop, set by the thread that changes the scene (server/trajectory3d/viser_loop.py)."""
    import asyncio

    from viser.infra._async_message_buffer import AsyncMessageBuffer

    foreign: list[tuple[str, str]] = []
    push = AsyncMessageBuffer.push
    opened = module.open_viser
    built = threading.Event()

    def open_viser(*args, **kwargs):
        server = opened(*args, **kwargs)
        built.set()
        return server

    def checked_push(self, message):
        if built.is_set():
            try:
                running = asyncio.get_running_loop()
            except RuntimeError:
                running = None
            if running is not self.event_loop:
                foreign.append((threading.current_thread().name, type(message).__name__))
        return push(self, message)

    monkeypatch.setattr(AsyncMessageBuffer, "push", checked_push)
    monkeypatch.setattr(module, "open_viser", open_viser)
    return foreign


@contextlib.contextmanager
def viser_viewer(port: int) -> Iterator[Any]:
    """A viewer of the panel at viser's protocol: a WebSocket with viser's subprotocol that
    reports its camera (viser counts a client from its first camera message) and reads
    (and drops) what the server sends, as the browser's client does. Yields the socket,
    to send what a viewer sends (a GUI click, say)."""
    import viser
    from websockets.sync.client import connect
    from websockets.typing import Subprotocol

    ws = connect(
        f"ws://127.0.0.1:{port}", subprotocols=[Subprotocol(f"viser-v{viser.__version__}")]
    )
    ws.send(viser_camera())

    def drain() -> None:
        with contextlib.suppress(Exception):
            for _ in ws:
                pass

    thread = threading.Thread(target=drain, name="viser-viewer", daemon=True)
    thread.start()
    try:
        yield ws
    finally:
        ws.close()
        thread.join(5)


class CountingSelector(selectors.DefaultSelector):
    """An event loop's own selector, counting the loop's turns (each select call): run a
    loop on it (`asyncio.SelectorEventLoop(selector)`) to count how often it wakes."""

    turns = 0

    def select(self, timeout=None):
        self.turns += 1
        return super().select(timeout)


def wait_until(predicate, timeout: float = 5.0, interval: float = 0.02, sleep=time.sleep) -> bool:
    """Poll `predicate` until it is true or `timeout` passes; returns its last value.
    `sleep(seconds)` waits between polls: a page's `wait_for_timeout` when the predicate
    needs Playwright's event handlers (a route's, a console listener's) to run meanwhile."""
    deadline = time.monotonic() + timeout
    while True:
        value = predicate()
        if value or time.monotonic() > deadline:
            return value
        sleep(interval)


def station_settings(
    source: str, sessions_dir: Path | None = None, /, **overrides: Any
) -> Settings:
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


def panel_station_settings(sessions_dir: Path, token: str, **overrides) -> Settings:
    """A test station with no link and both 3D panels on (viser on free loopback ports,
    drawing at 60 Hz), whose control token is `token`."""
    panels = {"viser.enabled": True, "viser.port": 0, "viser.update_hz": 60, "server.token": token}
    return station_settings("none", sessions_dir, **{**panels, **overrides})


def ws_upgrade(
    port: int,
    path: str,
    *,
    host: str | None = None,
    subprotocol: str | None = None,
    rcvbuf: int | None = None,
    timeout: float | None = 20.0,
) -> tuple[socket.socket, bytes]:
    """A WebSocket upgrade on a bare socket to 127.0.0.1:`port`: (the socket, the status
    line it was answered with). The answer's head is read byte by byte, so the frames
    after it stay in the socket; `rcvbuf` shrinks its receive buffer (a slow reader)."""
    sock = socket.socket()
    sock.settimeout(timeout)
    if rcvbuf is not None:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
    sock.connect(("127.0.0.1", port))
    key = base64.b64encode(os.urandom(16)).decode()
    offer = f"Sec-WebSocket-Protocol: {subprotocol}\r\n" if subprotocol else ""
    sock.sendall(
        f"GET {path} HTTP/1.1\r\nHost: {host or f'127.0.0.1:{port}'}\r\n"
        f"Upgrade: websocket\r\nConnection: Upgrade\r\nSec-WebSocket-Key: {key}\r\n"
        f"Sec-WebSocket-Version: 13\r\n{offer}\r\n".encode()
    )
    head = b""
    while b"\r\n\r\n" not in head:
        chunk = sock.recv(1)
        if not chunk:
            break
        head += chunk
    return sock, head.split(b"\r\n")[0]


class RawWsClient:
    """A WebSocket client on a bare socket: it can stop reading (a stalled browser)."""

    def __init__(self, base: str, path: str, rcvbuf: int = 4096):
        host, port = base.removeprefix("http://").split(":")
        self.sock, status = ws_upgrade(int(port), path, host=host, rcvbuf=rcvbuf, timeout=None)
        assert b" 101 " in status, status
        self.buf = b""

    def _need(self, n):
        while len(self.buf) < n:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("closed")
            self.buf += chunk

    def recv_json(self):
        self._need(2)
        length, head = self.buf[1] & 0x7F, 2
        if length == 126:
            self._need(4)
            length, head = int.from_bytes(self.buf[2:4], "big"), 4
        elif length == 127:
            self._need(10)
            length, head = int.from_bytes(self.buf[2:10], "big"), 10
        self._need(head + length)
        payload, self.buf = self.buf[head : head + length], self.buf[head + length :]
        return json.loads(payload)

    def send_text(self, text: str) -> None:
        """A masked text frame, as a browser sends it (RFC 6455 5.3)."""
        payload, mask = text.encode(), os.urandom(4)
        assert len(payload) < 126
        masked = bytes(b ^ mask[i % 4] for i, b in enumerate(payload))
        self.sock.sendall(bytes([0x81, 0x80 | len(payload)]) + mask + masked)

    def close(self):
        self.sock.close()


# A camera's picture as drawn, [width, page width], of the view whose id is given: the
# view's canvas holds it contained at its frames' aspect ratio (the canvas's own size,
# 4:3 until a frame gives it).
PICTURE_WIDTH = """(view) => {
  const img = document.querySelector(`#${view} .video-stream`);
  const r = img.getBoundingClientRect();
  return [Math.min(r.width, r.height * img.width / img.height), innerWidth];
}"""


def sticks_on(page, base: str) -> None:
    """Open the pilot page of a station on the twin and turn the browser's sticks on (hang
    guards: a twin station starting on a loaded box starves the page for seconds)."""
    page.goto(base + "/", timeout=60_000)
    page.wait_for_selector("#control-widget:not([hidden])", timeout=60_000)
    page.click("#ctl-toggle")
    page.wait_for_function("window.fpvDebug.control.enabled === true", timeout=60_000)


def arm_and_climb(page, station, height_m: float = 1.5, timeout: float = 60.0) -> None:
    """With the sticks on (sticks_on): Arm, then climb on ArrowUp until the twin is
    `height_m` up, and let go of the key. Arm is pressed again every 10 s until the twin
    is armed, as a pilot does after a toast of no answer (a twin starved by a loaded box)."""
    armed = lambda: (latest := station.state.get()) and latest.value.heartbeat.armed  # noqa: E731
    deadline = time.monotonic() + timeout
    while True:
        page.click("#ctl-arm")
        if wait_until(armed, timeout=min(10.0, max(deadline - time.monotonic(), 0.0))):
            break
        assert time.monotonic() < deadline, "the twin did not arm"
    page.keyboard.down("ArrowUp")
    assert wait_until(lambda: station.twin.pose().pos_enu_m[2] > height_m, timeout=timeout)
    page.keyboard.up("ArrowUp")


def eval_rows(text: str) -> dict[str, list[str]]:
    """`learn eval`'s Markdown table in `text`: per row's policy name, its other cells."""
    rows = {}
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) > 3 and cells[0] not in ("policy", "---"):
            rows[cells[0]] = cells[1:]
    return rows
