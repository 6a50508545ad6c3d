"""Who may change things: a hostile page in the pilot's browser and oversized bodies,
against a real uvicorn server (server/guard.py)."""

from __future__ import annotations

import json
import logging
import socket
import time

import httpx
import pytest
from websockets.exceptions import InvalidStatus
from websockets.sync.client import connect

from fpv_station.server.app import create_app
from fpv_station.server.errors import DenialLogFilter
from fpv_station.server.guard import RedactTokens
from fpv_station.server.settings import load_settings
from tests.helpers import run_uvicorn, station_settings
from tests.stations import no_link_station
from tests.twin_flights import NO_CAMERAS


@pytest.fixture(scope="module")
def base(tmp_path_factory):
    with no_link_station(tmp_path_factory.mktemp("sessions")) as (url, _):
        yield url


def test_websocket_upgrades_from_another_site_are_refused(base):
    ws = base.replace("http", "ws")
    for path in ("/ws/control", "/ws/telemetry"):
        with pytest.raises(InvalidStatus) as exc:
            connect(f"{ws}{path}", origin="http://evil.example", open_timeout=5)
        assert exc.value.response.status_code == 403
    with connect(f"{ws}/ws/telemetry", origin=base, open_timeout=5) as conn:
        conn.ping().wait(5)


def test_a_huge_body_is_refused_before_it_is_read(base):
    host, port = base.removeprefix("http://").split(":")
    with socket.create_connection((host, int(port)), timeout=5) as sock:
        # Declares 300 MB and sends none of it: the answer must come at once.
        sock.sendall(
            b"PUT /api/replay3d HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            b"Content-Length: 300000000\r\n\r\n"
        )
        reply = sock.recv(4096).decode()
    assert reply.startswith("HTTP/1.1 413") and "PayloadTooLarge" in reply

    # A chunked body with no declared length is cut off at the limit the same way.
    def chunks():
        for _ in range(200):
            yield b"x" * 1024

    r = httpx.put(
        f"{base}/api/replay3d", content=chunks(), headers={"Content-Type": "application/json"}
    )
    assert r.status_code == 413


def test_tokens_are_kept_out_of_the_access_log():
    import logging

    record = logging.LogRecord(
        "uvicorn.access", logging.INFO, "", 0, '%s - "%s %s HTTP/%s" %d',
        ("1.2.3.4:5", "GET", "/ws/control?token=s3cret&x=1", "1.1", 101), None,
    )  # fmt: skip
    assert RedactTokens().filter(record)
    assert "s3cret" not in record.getMessage() and "token=<redacted>&x=1" in record.getMessage()


def test_settings_refuse_a_silly_body_limit():
    with pytest.raises(Exception, match="max_body_bytes"):
        load_settings(None, {"server.max_body_bytes": 10}, environ={})


def test_websocket_parameters_are_bounded_with_a_reason(base):
    ws = base.replace("http", "ws")
    for bad in ("1e-300", "-3", "nan", "abc", "5000"):
        with pytest.raises(InvalidStatus) as exc:
            connect(f"{ws}/ws/telemetry?max_rate={bad}", open_timeout=5)
        response = exc.value.response
        assert response.status_code == 400, bad
        body = json.loads(response.body)
        assert body["error"] == "BadRequest" and "max_rate" in body["error_msg"]


def test_a_binary_frame_on_the_control_socket_closes_it_cleanly(tmp_path):
    from websockets.exceptions import ConnectionClosed

    settings = station_settings("sim", tmp_path, **NO_CAMERAS)
    with run_uvicorn(create_app(settings)) as url:
        with connect(url.replace("http", "ws") + "/ws/control", open_timeout=10) as ws:
            assert "hello" in ws.recv(timeout=5)
            ws.send(b"\x00\x01binary")
            reply = ws.recv(timeout=5)
            assert '"BadRequest"' in reply and "text" in reply
            with pytest.raises(ConnectionClosed) as closed:
                ws.recv(timeout=5)
            assert closed.value.rcvd.code == 1003 and "binary" in closed.value.rcvd.reason
        # The pilot's place is free again: the handler ended.
        with connect(url.replace("http", "ws") + "/ws/control", open_timeout=10) as ws:
            assert "hello" in ws.recv(timeout=5)


def test_a_socket_flood_cannot_take_the_recorders_descriptors(tmp_path):
    """Without a cap, a thousand sockets make the recorder fail with EMFILE under the Pi's limit.
    With 256 descriptors for the whole process, a flood of telemetry clients is capped
    (503 beyond the cap), and recording still starts, writes and stops cleanly."""
    import os
    import resource
    import subprocess
    import sys
    import time

    from tests.helpers import free_port, wait_until, ws_upgrade

    port = free_port()

    def low_limit():
        resource.setrlimit(resource.RLIMIT_NOFILE, (256, 256))

    proc = subprocess.Popen(
        [sys.executable, "-m", "fpv_station.server", "serve", "--source", "none", "--open", "--no-3d",
         "--host", "127.0.0.1", "--port", str(port), "--sessions-dir", str(tmp_path)],
        preexec_fn=low_limit,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        env={**os.environ, "FPV_RECORDING__MIN_FREE_MB": "0"},
    )  # fmt: skip
    base = f"http://127.0.0.1:{port}"
    sockets = []
    try:
        assert wait_until(lambda: _up(base), 60)
        statuses = []
        for _ in range(300):
            s, status = ws_upgrade(port, "/ws/telemetry", timeout=5)
            statuses.append(status.split(b" ")[1])
            sockets.append(s)
        assert statuses.count(b"101") >= 1 and statuses.count(b"503") >= 100, set(statuses)
        # The pilot is not locked out: the control socket has places of its own.
        s, status = ws_upgrade(port, "/ws/control", timeout=5)
        sockets.append(s)
        assert status.split(b" ")[1] == b"101", status
        # The recorder still has its descriptors while the flood holds its sockets.
        r = httpx.post(f"{base}/api/recording/start", timeout=10)
        assert r.status_code == 200, r.text
        time.sleep(1.5)
        stop = httpx.post(f"{base}/api/recording/stop", timeout=10).json()
        assert stop["last_stop"]["reason"] == "requested"
        health = httpx.get(f"{base}/api/health", timeout=10).json()
        assert health["status"] == "ok", health
        meta = httpx.get(f"{base}/api/sessions/{stop['last_stop']['id']}", timeout=10).json()
        assert (
            meta["meta"]["status"] == "complete" and meta["meta"]["quality"]["telemetry_rows"] > 10
        )
    finally:
        for s in sockets:
            s.close()
        proc.terminate()
        proc.wait(10)


def _up(base: str) -> bool:
    try:
        return httpx.get(f"{base}/api/health", timeout=2).status_code == 200
    except httpx.HTTPError:
        return False


def test_a_websocket_beyond_its_cap_is_refused_with_a_reason_and_no_false_error(tmp_path):
    """503 in the error shape; uvicorn's false "without completing handshake" ERROR after
    a denial (Kludex/uvicorn#3138) is not logged, one for each refusal at a crowded cap,
    while that message with no denial behind it still is."""
    records: list[logging.LogRecord] = []
    handler = logging.Handler(logging.ERROR)
    handler.emit = records.append
    uvicorn_errors = logging.getLogger("uvicorn.error")
    app = create_app(station_settings("none", tmp_path, **{"server.max_ws_clients": 1}))
    with run_uvicorn(app) as base:
        uvicorn_errors.addHandler(handler)
        try:
            url = base.replace("http", "ws") + "/ws/telemetry"
            with connect(url, open_timeout=5):
                for _ in range(3):
                    with pytest.raises(InvalidStatus) as exc:
                        connect(url, open_timeout=5)
                    assert exc.value.response.status_code == 503
                    assert json.loads(exc.value.response.body)["error"] == "Unavailable"
            time.sleep(0.3)  # uvicorn logs after the handler returned
            assert [r.getMessage() for r in records] == []
            uvicorn_errors.error(DenialLogFilter.MESSAGE)  # a handler that really forgot
            assert [r.getMessage() for r in records] == [DenialLogFilter.MESSAGE]
        finally:
            uvicorn_errors.removeHandler(handler)


@pytest.mark.parametrize("mode", ["open", "token"])
def test_a_rebound_name_cannot_open_a_websocket_in_any_mode(tmp_path, mode):
    """DNS rebinding (its HTTP answers: tests/test_rest_contracts.py): the upgrade of a
    page on a rebound name is refused before it is accepted, in `--open` mode as with a
    token; the station's own address is upgraded."""
    token = {"server.token": "s3cret-token"} if mode == "token" else {}
    settings = station_settings(
        "none",
        tmp_path,
        **{"server.control": mode, "server.allowed_hosts": ["station.field"], **token},
    )
    with run_uvicorn(create_app(settings)) as base:
        port = base.rsplit(":", 1)[1]
        for host, status in (("evil.example", b"403"), (f"127.0.0.1:{port}", b"101")):
            with socket.create_connection(("127.0.0.1", int(port)), timeout=5) as s:
                s.sendall(
                    f"GET /ws/telemetry HTTP/1.1\r\nHost: {host}\r\nUpgrade: websocket\r\n"
                    "Connection: Upgrade\r\nSec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==\r\n"
                    "Sec-WebSocket-Version: 13\r\n\r\n".encode()
                )
                assert s.recv(64).split(b" ")[1] == status, host
