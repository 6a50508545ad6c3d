"""The uvicorn server as the station runs it (server/listen.py): its idle main loop."""

from __future__ import annotations

import asyncio
import threading

import httpx

from fpv_station.server.listen import listening_socket, uvicorn_server
from tests.helpers import CountingSelector, wait_until


async def _app(scope, receive, send):
    if scope["type"] == "lifespan":
        while True:
            message = await receive()
            if message["type"] == "lifespan.startup":
                await send({"type": "lifespan.startup.complete"})
            elif message["type"] == "lifespan.shutdown":
                await send({"type": "lifespan.shutdown.complete"})
                return
    await send({"type": "http.response.start", "status": 200, "headers": []})
    await send({"type": "http.response.body", "body": b"ok"})


def test_an_idle_server_wakes_once_a_second_and_stops_at_once_when_asked():
    """uvicorn's main loop looked ten times a second whether it should exit; here it
    wakes once a second (the Date header), and `should_exit`, set from another thread as
    a signal handler or a test does, ends it without waiting for that second."""
    sock = listening_socket("127.0.0.1", 0)
    port = sock.getsockname()[1]
    server = uvicorn_server(_app, log_level="warning")
    selector = CountingSelector()

    def serve() -> None:
        loop = asyncio.SelectorEventLoop(selector)
        try:
            loop.run_until_complete(server.serve(sockets=[sock]))
        finally:
            loop.close()

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        assert wait_until(lambda: server.started, 10.0)
        assert httpx.get(f"http://127.0.0.1:{port}/", timeout=10).text == "ok"
        turns = selector.turns
        threading.Event().wait(2.0)
        idle_turns = selector.turns - turns
    finally:
        server.should_exit = True
        thread.join(10.0)
    assert not thread.is_alive()
    assert idle_turns <= 10  # two ticks and the closing request's turns (42 before)
