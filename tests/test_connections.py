"""Every connection counted (server/client_limits.py, server/listen.py): one descriptor
budget for the main server's connections and the 3D panels' viewers, with the recorder's
reserve kept."""

from __future__ import annotations

import json
import resource
import socket
import threading
import time

import httpx
import psutil
from websockets.sync.client import connect

from fpv_station.server.app import create_app
from fpv_station.server.client_limits import BASELINE_FDS, CONTROL_CLIENTS, HTTP_ROOM, ClientLimits
from tests.helpers import run_uvicorn, station_settings, wait_until
from tests.station_process import LOW_LIMIT, serve_station


def test_every_kind_of_client_fits_under_the_descriptor_limit_with_the_reserve_kept():
    limits = ClientLimits.fitted(200, 40, reserve=128, nofile=256, max_3d=300)
    held = limits.connections.limit + limits.viewers3d.limit
    assert held <= 256 - BASELINE_FDS - 128
    streaming = limits.websocket.limit + limits.video.limit + CONTROL_CLIENTS
    assert streaming + HTTP_ROOM <= limits.connections.limit
    assert min(limits.websocket.limit, limits.video.limit, limits.viewers3d.limit) >= 1
    # A roomy limit keeps the configured caps.
    roomy = ClientLimits.fitted(200, 40, reserve=128, nofile=65536, max_3d=20)
    assert (roomy.websocket.limit, roomy.video.limit, roomy.viewers3d.limit) == (200, 40, 20)


def test_a_cap_counts_places_taken_from_many_threads():
    """viser accepts its viewers on its own threads: the count must not lose one."""
    cap = ClientLimits.fitted(200, 40, reserve=128, nofile=65536, max_3d=50).viewers3d
    taken = []

    def crowd() -> None:
        for _ in range(1000):
            if cap.try_take():
                taken.append(1)
                cap.give_back()

    threads = [threading.Thread(target=crowd) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert cap.active == 0 and len(taken) + cap.refused == 8000
    assert all(cap.try_take() for _ in range(50)) and not cap.try_take()
    assert cap.active == 50 and cap.refused >= 1


class SlowHeaders:
    """Clients that send a request's headers a byte at a time and never finish; each one
    the station closes comes back at once."""

    def __init__(self, port: int, count: int) -> None:
        self.port = port
        self.socks: list[socket.socket | None] = [None] * count
        self.reconnects = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> SlowHeaders:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(10)
        for s in self.socks:
            if s is not None:
                s.close()

    def _run(self) -> None:
        line = b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 10_000
        sent = [0] * len(self.socks)
        while not self._stop.wait(0.5):
            for i, s in enumerate(self.socks):
                try:
                    if s is None:
                        s = self.socks[i] = socket.create_connection(
                            ("127.0.0.1", self.port), timeout=2
                        )
                        sent[i] = 0
                        self.reconnects += 1
                    s.sendall(line[sent[i] : sent[i] + 1])
                    sent[i] += 1
                except OSError:  # closed by the station (or not accepted yet): again
                    if s is not None:
                        s.close()
                    self.socks[i] = None


def test_idle_and_slow_header_sockets_leave_health_and_arming_under_256_descriptors(tmp_path):
    """Under `prlimit --nofile=256` 400 idle TCP connections would fill the descriptor
    table: health checks would fail and arming could not create a session (EMFILE). Idle
    connections are closed after their request timeout, or sooner for a newer
    connection, slow-header clients after the timeout, and the recorder's reserve
    stays: health answers and arming the twin starts a recording."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    resource.setrlimit(resource.RLIMIT_NOFILE, (max(soft, min(hard, 4096)), hard))
    args = ["--source", "sim", "--open", "--no-3d", "--sessions-dir", str(tmp_path)]
    env = {"FPV_RECORDING__MIN_FREE_MB": "0"}
    idle: list[socket.socket] = []
    try:
        with serve_station(args, env, launcher=LOW_LIMIT) as station:
            assert station.process.rlimit(psutil.RLIMIT_NOFILE) == (256, 256)
            with SlowHeaders(station.port, 30) as slow:
                for _ in range(400):
                    try:
                        idle.append(socket.create_connection(("127.0.0.1", station.port), 5))
                    except OSError:
                        pass
                assert len(idle) >= 300
                assert station.process.num_fds() < 256 - 64  # the recorder's room is kept
                with httpx.Client(timeout=10) as client:
                    for _ in range(10):
                        reply = client.get(f"{station.base}/api/health")
                        assert reply.status_code == 200, reply.text
                        time.sleep(0.2)
                    # Arm the twin through the control API: arming starts a recording.
                    ws_url = station.base.replace("http", "ws") + "/ws/control"
                    with connect(ws_url, open_timeout=10) as ws:
                        assert json.loads(ws.recv(timeout=10))["type"] == "hello"
                        ws.send(json.dumps({"type": "arm"}))
                        ack = json.loads(ws.recv(timeout=15))
                        assert (ack["cmd"], ack["ok"]) == ("arm", True), ack
                        assert wait_until(
                            lambda: client.get(f"{station.base}/api/recording").json()["recording"],
                            15,
                        ), client.get(f"{station.base}/api/recording").text
                    assert client.get(f"{station.base}/api/health").status_code == 200
                # Slow clients are closed (they came back), idle ones too: each after its
                # timeout, so on a fast machine the waits above may not have lasted one.
                assert wait_until(lambda: slow.reconnects > 30, 30), slow.reconnects
                closed = lambda: sum(1 for s in idle if _closed_by_peer(s))  # noqa: E731
                assert wait_until(lambda: closed() >= len(idle) - 40, 30), closed()
            log = station.log_path.read_text()
            assert "Too many open files" not in log and "Traceback" not in log, log[-3000:]
    finally:
        for s in idle:
            s.close()


def _closed_by_peer(s: socket.socket) -> bool:
    s.setblocking(False)
    try:
        return s.recv(1) == b""
    except BlockingIOError:
        return False
    except OSError:
        return True


def test_a_silent_connection_and_an_idle_keep_alive_one_are_closed(tmp_path):
    """A connection holds a descriptor: one that sends nothing, and one that keeps its
    connection open after a response, are closed by the station (after its request
    timeout; the wait here is a hang guard)."""
    settings = station_settings("none", tmp_path)
    with run_uvicorn(create_app(settings)) as base:
        port = int(base.rsplit(":", 1)[1])
        silent = socket.create_connection(("127.0.0.1", port), timeout=30)
        kept = socket.create_connection(("127.0.0.1", port), timeout=30)
        kept.sendall(b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        reply = kept.recv(65536)
        assert reply.startswith(b"HTTP/1.1 200") and b"connection: close" not in reply.lower()
        assert silent.recv(1) == b""  # closed by the station, not by the guard's timeout
        assert kept.recv(1) == b""
        silent.close()
        kept.close()
        # A client that keeps sending keeps nothing open either: a request must be whole
        # within the timeout, however many bytes trickle in.
        slow = socket.create_connection(("127.0.0.1", port), timeout=30)
        closed = False
        for ch in b"GET /api/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: " + b"a" * 100:
            try:
                slow.sendall(bytes([ch]))
            except OSError:
                closed = True
                break
            time.sleep(0.25)
        assert closed or slow.recv(1) == b""
        slow.close()
