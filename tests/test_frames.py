"""Bounded frames and messages: each WebSocket route takes frames that fit its messages
(server/listen.py), and a deeply nested JSON message gets the error shape
(server/guard.py), through real sockets to a real station."""

from __future__ import annotations

import json
import socket
import struct
import threading

import psutil
from websockets.sync.client import connect

from tests.helpers import ws_upgrade
from tests.station_process import serve_station

FRAME = 16 * 1024 * 1024
CLIENTS = 30


def _handshake(port: int, path: str) -> socket.socket:
    s, status = ws_upgrade(port, path)
    assert status.split(b" ")[1] == b"101", status
    return s


def _big_frame_close_code(port: int, path: str) -> int | None:
    """Send one 16 MiB masked text frame; the close code the station answers with."""
    s = _handshake(port, path)
    try:
        s.sendall(b"\x81\xff" + struct.pack(">Q", FRAME) + b"\x00\x00\x00\x00")
        chunk = b"x" * (1 << 20)
        try:
            for _ in range(FRAME // len(chunk)):
                s.sendall(chunk)
        except OSError:
            pass  # the station closed the socket: it read no more
        data = b""
        try:
            while len(data) < 4 or data[0] != 0x88:
                more = s.recv(4096)
                if not more:
                    break
                data += more
                if data and data[0] != 0x88:  # a telemetry message before the close
                    n = data[1] & 0x7F
                    skip = 2 + n if n < 126 else 4 + struct.unpack(">H", data[2:4])[0]
                    if len(data) < skip:
                        continue
                    data = data[skip:]
        except OSError:
            return None
        return struct.unpack(">H", data[2:4])[0] if len(data) >= 4 else None
    finally:
        s.close()


def test_big_frames_are_refused_with_1009_and_memory_stays_flat(tmp_path):
    """uvicorn's default 16 MiB frames let 30 anonymous clients drive the station from
    207 MB to 1.49 GB. Each route takes frames that fit its messages: a larger frame
    is closed with 1009 as it starts, before its payload is read."""
    args = ["--source", "none", "--open", "--no-3d", "--sessions-dir", str(tmp_path)]
    with serve_station(args) as station:
        proc = station.process
        # Warm up: one small exchange on each route, so the memory compared is the
        # running station's.
        for path in ("/ws/telemetry", "/ws/control"):
            _handshake(station.port, path).close()
        rss0 = proc.memory_info().rss
        codes: list[int | None] = []
        lock = threading.Lock()

        def client(n: int) -> None:
            path = "/ws/telemetry" if n % 2 else "/ws/control"
            for _ in range(2):
                code = _big_frame_close_code(station.port, path)
                with lock:
                    codes.append(code)

        threads = [threading.Thread(target=client, args=(n,)) for n in range(CLIENTS)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(120)
        grown = proc.memory_info().rss - rss0
        assert grown < 20e6, f"RSS grew by {grown / 1e6:.1f} MB"
        assert len(codes) == 2 * CLIENTS
        # Telemetry's are all 1009; the control socket of a station without the twin
        # may close with 4409 first, and a client whose socket was reset sees none.
        assert codes.count(1009) >= CLIENTS, codes
        assert isinstance(proc, psutil.Process) and proc.is_running()
        assert "Traceback" not in station.log_path.read_text()


def test_deeply_nested_json_gets_the_error_shape_and_the_socket_stays(tmp_path):
    args = ["--source", "sim", "--open", "--no-3d", "--sessions-dir", str(tmp_path)]
    with serve_station(args, {"FPV_RECORDING__MIN_FREE_MB": "0"}) as station:
        url = station.base.replace("http", "ws") + "/ws/control"
        with connect(url, open_timeout=10) as ws:
            assert json.loads(ws.recv(timeout=10))["type"] == "hello"
            ws.send("[" * 2000 + "]" * 2000)  # within the frame limit
            reply = json.loads(ws.recv(timeout=10))
            assert reply["error"] == "BadRequest" and "nested" in reply["error_msg"], reply
            ws.send(json.dumps({"type": "reset"}))
            assert json.loads(ws.recv(timeout=10)) == {"type": "ack", "cmd": "reset", "ok": True}
        assert "Traceback" not in station.log_path.read_text()
