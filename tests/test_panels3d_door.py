"""The 3D panels behind the station's door, attacked as a stranger on the field Wi-Fi
would: real WebSockets through a real uvicorn to the panels' real viser servers, with real
Origin headers, real malformed msgpack and a real share request."""

from __future__ import annotations

import contextlib
import os
import resource
import socket
import threading
import time
from collections.abc import Iterator

import httpx
import msgspec
import psutil
import pytest
import viser
import zstandard
from viser._messages import ShareUrlRequest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import ClientConnection, connect
from websockets.typing import Subprotocol

from fpv_station.server.app import create_app
from fpv_station.server.trajectory3d.gate import MESSAGES_BURST, MESSAGES_PER_S, gui_uuid
from tests.helpers import free_port, panel_station_settings, run_uvicorn, wait_until, ws_upgrade
from tests.helpers import viser_camera as camera
from tests.station_process import LOW_LIMIT, serve_station
from tests.synthetic import state_at

TOKEN = "door-test-token"
SUBPROTOCOL = Subprotocol(f"viser-v{viser.__version__}")


def gui_update(uuid: str, value: object) -> bytes:
    return msgspec.msgpack.encode(
        {"type": "GuiUpdateMessage", "uuid": uuid, "updates": {"value": value}}
    )


def messages_in(frame: bytes) -> list[dict]:
    """The messages of one frame viser sends: sizes, zstd msgpack, then binary buffers."""
    inner, compressed = (int.from_bytes(frame[i : i + 8], "little") for i in (0, 8))
    body = zstandard.ZstdDecompressor().decompress(
        frame[16 : 16 + compressed], max_output_size=inner
    )
    return list(msgspec.msgpack.decode(body)["messages"])


class Viewer:
    """One browser's viser client, at the protocol: it reports its camera and keeps every
    message the panel sends it."""

    def __init__(self, ws: ClientConnection) -> None:
        self.ws = ws
        self.received: list[dict] = []
        self.closed = threading.Event()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()
        ws.send(camera())

    def _read(self) -> None:
        with contextlib.suppress(Exception):
            for frame in self.ws:
                if isinstance(frame, bytes):
                    self.received.extend(messages_in(frame))
        self.closed.set()

    def types(self) -> set[str | None]:
        return {m.get("type") for m in list(self.received)}

    def close(self) -> None:
        self.ws.close()
        self._thread.join(5)


def ws_url(base: str, path: str, token: str | None = None) -> str:
    return base.replace("http://", "ws://") + path + (f"?token={token}" if token else "")


@contextlib.contextmanager
def viewer(base: str, path: str = "/3d/live", *, origin: str | None = None, token=None):
    headers = {"Origin": origin} if origin else None
    ws = connect(
        ws_url(base, path, token),
        subprotocols=[SUBPROTOCOL],
        additional_headers=headers,
        max_size=None,
        open_timeout=30,
        proxy=None,
    )
    v = Viewer(ws)
    try:
        yield v
    finally:
        v.close()


@pytest.fixture
def station(tmp_path) -> Iterator[tuple[str, object]]:
    app = create_app(panel_station_settings(tmp_path, TOKEN, **{"server.max_3d_viewers": 3}))
    with run_uvicorn(app) as base:
        assert httpx.get(f"{base}/api/viser").json()["enabled"]  # starts the panels
        yield base, app.state.station


def listening_addresses(port: int) -> set[str]:
    """The local addresses a TCP port listens on, from the kernel's own tables."""
    found = set()
    for table, width in (("/proc/net/tcp", 8), ("/proc/net/tcp6", 32)):
        with contextlib.suppress(FileNotFoundError), open(table) as f:
            for line in f.readlines()[1:]:
                local, _, st = line.split()[1], None, line.split()[3]
                addr, hexport = local.split(":")
                if int(hexport, 16) == port and st == "0A" and len(addr) == width:
                    found.add(addr)
    return found


def test_the_panels_viser_servers_listen_on_loopback_only(station):
    base, st = station
    for port in (st.trajectory3d.port, st.replay3d.port):
        assert listening_addresses(port) == {"0100007F"}  # 127.0.0.1, nothing else
    info = httpx.get(f"{base}/api/viser").json()
    assert (info["path"], info["replay_path"]) == ("/3d/live/", "/3d/replay/")
    page = httpx.get(f"{base}/3d/live/")
    assert page.status_code == 200 and "<html" in page.text[:200].lower()


def test_a_viewer_from_another_origin_or_host_is_refused_and_the_stations_own_watches(station):
    base, st = station
    port = int(base.rsplit(":", 1)[1])
    for path in ("/3d/live", "/3d/replay"):
        # DNS rebinding: a page on evil.example whose name now points at the station.
        sock, status = raw_viewer(port, path, host=f"evil.example:{port}")
        sock.close()
        assert b" 101 " not in status and status.startswith(b"HTTP/1.1 4"), status
        assert httpx.get(f"{base}/3d/live/", headers={"Host": "evil.example"}).status_code == 421
        for origin in ("http://evil.example", "http://127.0.0.1:1", "null"):
            with pytest.raises(InvalidStatus) as refused:
                with viewer(base, path, origin=origin):
                    pass
            assert refused.value.response.status_code == 403
        with viewer(base, path, origin=base) as v:
            assert wait_until(lambda: "ThemeConfigurationMessage" in v.types(), 30)
    assert wait_until(lambda: st.client_limits.viewers3d.active == 0, 10)


def test_the_viewer_cap_refuses_the_excess_with_503(station):
    base, st = station
    with contextlib.ExitStack() as stack:
        viewers = [
            stack.enter_context(viewer(base, p)) for p in ("/3d/live", "/3d/replay", "/3d/live")
        ]
        assert st.client_limits.viewers3d.active == 3
        with pytest.raises(InvalidStatus) as refused:
            with viewer(base):
                pass
        reply = refused.value.response
        assert reply.status_code == 503 and b"at most 3 3D viewer clients" in reply.body
        assert all(not v.closed.is_set() for v in viewers)
    assert wait_until(lambda: st.client_limits.viewers3d.active == 0, 10)
    with viewer(base) as v:  # a place is free again
        assert wait_until(lambda: "ThemeConfigurationMessage" in v.types(), 30)


def camera_x(service, x: float) -> bool:
    return any(c.camera.position[0] == x for c in service.server.get_clients().values())


CONTROLS = ("Follow vehicle", "Colour by", "Show field", "Clear trail")


def controls_of(v: Viewer) -> dict[str, str]:
    """The live panel's controls a viewer was given: their uuids by label."""
    return {
        m["props"]["label"]: m["uuid"]
        for m in list(v.received)
        if str(m.get("type")).startswith("Gui")
        and isinstance(m.get("props"), dict)
        and m["props"].get("label") in CONTROLS
    }


def replayed(v: Viewer) -> bool:
    """Whether the viewer has the whole scene and GUI that were there when it came."""
    return "ReplayDoneMessage" in v.types()


def test_anonymous_viewers_watch_without_controls_and_only_the_token_changes_all(station):
    base, st = station
    live = st.trajectory3d
    for i in range(30):
        st.state.publish(state_at(i * 0.1))
    controls = live.controls
    with viewer(base, token=TOKEN) as pilot, viewer(base, token=TOKEN) as copilot:
        assert wait_until(lambda: len(controls_of(pilot)) == len(controls_of(copilot)) == 4, 30)
        ids = controls_of(pilot)
        assert wait_until(lambda: live.trail.n_points > 0, 30)
        for x, token in ((-11.0, None), (-12.0, "wrong")):
            with viewer(base, token=token) as watcher:
                # A watcher gets the scene and the status line, and no control to click.
                assert wait_until(lambda w=watcher: replayed(w), 30)
                assert "GuiMarkdownMessage" in watcher.types()
                assert controls_of(watcher) == {}
                assert len(controls.pilots) == 2
                # One that sends a pilot's inputs anyway changes nothing.
                for frame in (
                    gui_update(ids["Clear trail"], True),
                    gui_update(ids["Colour by"], "speed"),
                    gui_update(ids["Follow vehicle"], True),
                    gui_update(ids["Show field"], False),
                ):
                    watcher.ws.send(frame)
                # A viewer's messages reach viser in order: once its last camera is
                # there, the GUI changes before it were passed on, or dropped.
                watcher.ws.send(camera(x))
                assert wait_until(lambda x=x: camera_x(live, x), 30)
                time.sleep(0.2)  # the update loop applies GUI requests each tick
                assert live.trail.n_points > 0
                settings = (controls.color_by, controls.follow, controls.show_field)
                assert settings == ("height", False, True)
            # Its place under the cap (three here) is free once its relay has closed.
            assert wait_until(lambda: st.client_limits.viewers3d.active == 2, 10)

        with viewer(base) as anonymous:
            assert wait_until(lambda: replayed(anonymous), 30)
            pilot.ws.send(gui_update(ids["Colour by"], "speed"))
            pilot.ws.send(gui_update(ids["Clear trail"], True))
            assert wait_until(lambda: controls.color_by == "speed", 30)
            assert wait_until(lambda: live.trail.n_points == 0, 30)
            # What one pilot changed, the other's controls show; the watcher has none.
            theirs = controls_of(copilot)["Colour by"]
            assert wait_until(
                lambda: any(
                    m.get("type") == "GuiUpdateMessage"
                    and m.get("uuid") == theirs
                    and m.get("updates") == {"value": "speed"}
                    for m in list(copilot.received)
                ),
                30,
            )
            assert controls_of(anonymous) == {}
    assert wait_until(lambda: not controls.pilots and not live.viewer_inputs(), 10)


def test_no_request_makes_a_panel_open_a_share_tunnel_nor_shows_share(station, monkeypatch):
    base, st = station
    tunnels: list[tuple] = []

    class NoInternet:  # the Pi has no internet here; record who would have dialled out
        def __init__(self, *args, **kwargs) -> None:
            tunnels.append(args)
            raise OSError("no route to share.viser.studio")

    monkeypatch.setattr(viser._viser, "ViserTunnel", NoInternet)
    share = msgspec.msgpack.encode(ShareUrlRequest().as_serializable_dict())
    for path, panel in (("/3d/live", st.trajectory3d), ("/3d/replay", st.replay3d)):
        with viewer(base, path, token=TOKEN) as pilot:
            pilot.ws.send(share)
            pilot.ws.send(camera(-13.0))
            assert wait_until(lambda p=panel: camera_x(p, -13.0), 30)
            # The camera reply can overtake the reader thread's copy of the first messages.
            assert wait_until(lambda v=pilot: "ThemeConfigurationMessage" in v.types(), 30)
            themes = [m for m in pilot.received if m.get("type") == "ThemeConfigurationMessage"]
            assert all(m["show_share_button"] is False for m in themes)
        # A process on the station itself reaches viser's loopback port directly.
        with connect(f"ws://127.0.0.1:{panel.port}", subprotocols=[SUBPROTOCOL], proxy=None) as ws:
            ws.send(camera(-14.0))
            ws.send(share)
            ws.send(camera(-15.0))
            assert wait_until(lambda p=panel: camera_x(p, -15.0), 30)
    time.sleep(0.5)  # viser hands the share request to a worker thread
    assert tunnels == []
    assert st.trajectory3d.server._share_tunnel is None


def test_malformed_messages_are_dropped_without_a_traceback(station, capfd, caplog):
    base, st = station
    live = st.trajectory3d
    junk = [
        os.urandom(64),
        b"\xc1",  # a msgpack byte that is never valid
        msgspec.msgpack.encode([1, 2, 3]),
        msgspec.msgpack.encode({"type": "NoSuchMessage"}),
        msgspec.msgpack.encode({"type": "ViewerCameraMessage", "wxyz": "abcd"}),
        msgspec.msgpack.encode({"type": "ViewerCameraMessage", "position": [float("nan")] * 3}),
        msgspec.msgpack.encode(
            {"type": "GuiUpdateMessage", "uuid": "nope", "updates": {"value": 1}}
        ),
        msgspec.msgpack.encode({"type": "FileTransferStartUpload", "transfer_uuid": "x"}),
        b"\x91" * 4000 + b"\x90",  # lists nested four thousand deep
    ]
    with viewer(base, token=TOKEN) as pilot:
        assert wait_until(lambda: len(live.controls.pilots) == 1, 30)
        clear = gui_uuid(next(iter(live.controls.pilots.values())).clear)
        junk.append(
            msgspec.msgpack.encode(
                {"type": "GuiUpdateMessage", "uuid": clear, "updates": {"bogus": 1}}
            )
        )
        for frame in junk:
            pilot.ws.send(frame)
        pilot.ws.send("a text frame")
        pilot.ws.send(camera(-16.0))
        assert wait_until(lambda: camera_x(live, -16.0), 30)
        assert not pilot.closed.is_set()
        time.sleep(0.3)
    out, err = capfd.readouterr()
    assert "Traceback" not in out + err
    assert not [r for r in caplog.records if r.exc_info or r.levelname in ("ERROR", "CRITICAL")]


def raw_viewer(
    port: int, path: str = "/3d/live", timeout: float = 30.0, host: str | None = None
) -> tuple[socket.socket, bytes]:
    """A viewer's upgrade on a bare socket: (the socket, the status line it was answered)."""
    return ws_upgrade(port, path, host=host, subprotocol=SUBPROTOCOL, timeout=timeout)


def big_frame(sock: socket.socket, size: int, send: int | None = None) -> None:
    """Start one masked binary frame of `size` bytes and send `send` bytes of it (all by
    default), as far as the server takes them."""
    sock.sendall(b"\x82\xff" + size.to_bytes(8, "big") + os.urandom(4))
    chunk = bytes(1 << 20)
    left = size if send is None else send
    with contextlib.suppress(OSError):
        while left > 0:
            sock.sendall(chunk[: min(left, len(chunk))])
            left -= len(chunk)


def close_code(sock: socket.socket) -> int | None:
    """Read the server's frames (viser's scene first) up to its close: its code."""
    buf = b""

    def need(n: int) -> bytes:
        nonlocal buf
        while len(buf) < n:
            more = sock.recv(1 << 16)
            if not more:
                raise ConnectionError("closed without a close frame")
            buf += more
        out, buf = buf[:n], buf[n:]
        return out

    while True:
        b0, b1 = need(2)
        length = b1 & 0x7F
        if length == 126:
            length = int.from_bytes(need(2), "big")
        elif length == 127:
            length = int.from_bytes(need(8), "big")
        payload = need(length)
        if b0 & 0x0F == 0x8:
            return int.from_bytes(payload[:2], "big") if len(payload) >= 2 else None


def test_a_frame_over_the_limit_closes_the_viewer_with_1009_as_it_starts(station):
    base, st = station
    port = int(base.rsplit(":", 1)[1])
    sock, status = raw_viewer(port)
    with sock:
        assert b" 101 " in status
        big_frame(sock, 16 << 20, send=1024)  # 16 MiB announced, 1 KiB sent
        assert close_code(sock) == 1009
    assert wait_until(lambda: st.client_limits.viewers3d.active == 0, 10)


def rss_mb(process: psutil.Process) -> float:
    return process.memory_info().rss / 2**20


@pytest.mark.timeout(300)
def test_big_frames_from_30_viewers_leave_the_stations_memory_flat(tmp_path):
    """30 viewers x 2 frames of 16 MiB at the 3D panels (the viser servers took 50 MiB
    frames: 238 to 637 MB): each is refused as it starts, so RSS stays within +20 MB."""
    args = ["--source", "none", "--open", "--viser-port", "0", "--sessions-dir", str(tmp_path)]
    env = {"FPV_SERVER__MAX_3D_VIEWERS": "30"}
    with serve_station(args, env) as station:
        proc = station.process

        def attack(frames: int, size: int) -> list[bytes]:
            statuses: list[bytes] = []

            def one(path: str) -> None:
                for _ in range(frames):
                    sock, status = raw_viewer(station.port, path)
                    with sock:
                        statuses.append(status)
                        if size:
                            big_frame(sock, size)
                        else:
                            sock.sendall(b"\x88\x82" + os.urandom(4) + b"\x03\xe8")  # close

            threads = [
                threading.Thread(target=one, args=(("/3d/live", "/3d/replay")[i % 2],))
                for i in range(30)
            ]
            for t in threads:
                t.start()
            for t in threads:
                t.join(120)
            return statuses

        attack(2, 0)  # 30 viewers come and go: the panels start and warm up
        time.sleep(1.0)
        before = rss_mb(proc)
        statuses = attack(2, 16 << 20)
        assert sum(b" 101 " in s for s in statuses) >= 30, statuses  # the relay took them
        assert wait_until(lambda: httpx.get(f"{station.base}/api/health").json()["ok"], 30)
        time.sleep(1.0)
        after = rss_mb(proc)
        assert after - before < 20, (before, after)
        log = station.log_path.read_text()
        assert "Traceback" not in log, log[-3000:]


@pytest.mark.timeout(300)
def test_300_3d_viewers_under_256_descriptors_leave_health_answering(tmp_path):
    """Under `prlimit --nofile=256`, a few hundred viser viewers would fill the descriptor
    table. The 3D viewers' cap is fitted under the budget (three descriptors each): the excess is
    refused with 503, the recorder's room is kept and `/api/health` answers throughout."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, min(hard, 4096)), hard))
    args = ["--source", "none", "--open", "--viser-port", "0", "--sessions-dir", str(tmp_path)]
    held: list[socket.socket] = []
    statuses: list[bytes] = []
    lock = threading.Lock()
    try:
        with serve_station(args, launcher=LOW_LIMIT) as station:
            assert station.process.rlimit(psutil.RLIMIT_NOFILE) == (256, 256)

            def crowd(path: str, count: int) -> None:
                for _ in range(count):
                    try:
                        sock, status = raw_viewer(station.port, path, timeout=20)
                    except OSError as exc:
                        status, sock = f"error {exc}".encode(), None
                    with lock:
                        statuses.append(status)
                        if sock is not None:
                            held.append(sock)  # accepted or not: kept open, idle

            threads = [
                threading.Thread(target=crowd, args=(("/3d/live", "/3d/replay")[i % 2], 30))
                for i in range(10)
            ]
            for t in threads:
                t.start()
            with httpx.Client(timeout=10) as client:
                while any(t.is_alive() for t in threads):
                    assert client.get(f"{station.base}/api/health").status_code == 200
                    time.sleep(0.2)
                for t in threads:
                    t.join()
                assert len(statuses) == 300
                accepted = sum(b" 101 " in s for s in statuses)
                refused = sum(b" 503 " in s for s in statuses)
                assert 1 <= accepted <= 3, accepted
                assert refused >= 250, statuses[:20]
                assert station.process.num_fds() < 256 - 64  # the recorder's room is kept
                for _ in range(5):
                    assert client.get(f"{station.base}/api/health").status_code == 200
            log = station.log_path.read_text()
            assert "Too many open files" not in log and "Traceback" not in log, log[-3000:]
    finally:
        for s in held:
            s.close()


def test_a_flood_of_camera_messages_reaches_viser_at_a_bounded_rate(station):
    base, st = station
    live = st.trajectory3d
    updates: list[float] = []  # when viser took each camera (its callbacks come later)
    with viewer(base) as v:
        assert wait_until(lambda: live.server.get_clients(), 30)
        (client,) = live.server.get_clients().values()
        client.camera.on_update(lambda cam: updates.append(time.monotonic()))
        t0 = time.monotonic()
        for i in range(3000):
            v.ws.send(camera(float(i)))
        v.ws.send(camera(-17.0))  # after the flood: passed once the bucket has refilled
        time.sleep(1.0)
        v.ws.send(camera(-18.0))
        assert wait_until(lambda: camera_x(live, -18.0), 30)
        assert not v.closed.is_set()
    # At most the bucket's burst, plus its rate over the time the relay could have been
    # passing them on (it passes each before viser's callback for it runs).
    bound = MESSAGES_BURST + MESSAGES_PER_S * (updates[-1] - t0) + 1
    assert len(updates) <= bound, (len(updates), bound)


TRY_SOCKET = """(url) => new Promise((resolve) => {
  document.addEventListener("securitypolicyviolation", (e) => {
    if (e.blockedURI.startsWith(url.slice(0, 20))) resolve(`blocked by ${e.violatedDirective}`);
  });
  const ws = new WebSocket(url);
  ws.onopen = () => { ws.close(); resolve("opened"); };
  ws.onerror = () => setTimeout(() => resolve("failed"), 1000);  // a violation comes first
})"""


def test_the_panel_page_connects_to_this_station_only(station, browser):
    """viser's client shares the pilot page's origin (and its token): a crafted link
    whose ?websocket= names another server (which could send viser's RunJavascriptMessage)
    is refused, and the page's CSP lets its scripts connect to this station only."""
    base, st = station
    evil = f"ws://127.0.0.1:{free_port()}/3d/live"
    for url in (evil, "ws://evil.example/3d/live", f"{base.replace('http', 'ws')}/api/x"):
        reply = httpx.get(f"{base}/3d/live/", params={"websocket": url})
        assert reply.status_code == 400 and reply.json()["error"] == "BadRequest", url
    own = f"{base.replace('http', 'ws')}/3d/live"
    assert httpx.get(f"{base}/3d/live/", params={"websocket": own}).status_code == 200
    page = browser.new_page()
    page.goto(f"{base}/3d/live/", wait_until="domcontentloaded")
    assert page.evaluate(TRY_SOCKET, evil) == "blocked by connect-src"  # the page's CSP
    assert page.evaluate(TRY_SOCKET, own) == "opened"
