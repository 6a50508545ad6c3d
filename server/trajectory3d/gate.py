"""The 3D panels' one door: each viewer's WebSocket comes through the station's own server
and is relayed to a viser server that listens on loopback only.

viser serves its panel from its own websockets server (its own thread and port) with none
of the station's rules: any Origin and Host, any number of viewers, 50 MiB frames, GUI
changes and its share-tunnel request from anyone, and a traceback for a frame it cannot
parse. So each panel's viser server binds 127.0.0.1 (`open_viser`), where the field
network cannot reach it, and browsers reach it only through the station's routes
(server/routes/viser_panel.py): there the guard (Origin, Host), the frame limit and the
viewer cap of every other WebSocket apply before `relay` runs. The relay then passes a
viewer's messages on only when they parse against the exact shape viser's client sends
and the viewer may send them (`ViewerRules`):

- its own camera (`ViewerCameraMessage`): what it looks at concerns nobody else;
- a GUI change (`GuiUpdateMessage`) to an input the panel declares (`ViewerInput`), with
  a value of the declared type: a "personal" input (one that acts on its own viewer only)
  from anyone, any other only from a viewer that presented the control token, since it
  changes what every viewer sees (the trail, the colour-coding, the field).

Everything else is dropped without a word: malformed frames, text frames, the share
request (which would open a public tunnel to the station), uploads, clicks; and so is a
viewer's message beyond `MESSAGES_PER_S` (viser's client sends its camera at most every
20 ms, the newest last), so that a flood costs viser nothing. What viser sends goes to
the browser as it is (no per-viewer re-encoding).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import secrets
import time
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Any

import msgspec
from starlette.websockets import WebSocket, WebSocketDisconnect

if TYPE_CHECKING:  # imported when a panel starts: viser costs memory and start-up time
    import viser

log = logging.getLogger(__name__)

LOOPBACK = "127.0.0.1"  # where the panels' viser servers listen: the relay's side only
UPSTREAM_OPEN_S = 5.0  # a viser server that does not answer on loopback within this is down
# A viewer's messages passed on a second, and the burst: viser's client sends its camera at
# most 50 times a second, a GUI change now and then.
MESSAGES_PER_S = 60.0
MESSAGES_BURST = 60.0


@dataclass(frozen=True, slots=True)
class ViewerInput:
    """A GUI input of a panel that viewers may change, and the values it takes."""

    kind: type[bool] | type[str]
    personal: bool = False  # acts on its own viewer only (its camera): anyone may use it
    choices: tuple[str, ...] | None = None  # a dropdown's options


def gui_uuid(handle: viser.GuiInputHandle[Any] | viser.GuiButtonHandle) -> str:
    """The uuid viser's client names a GUI input by in its GuiUpdateMessage (viser keeps
    it on the handle's state, `_impl`, and has no public name for it)."""
    return handle._impl.uuid


# -- what a viewer may send, in the exact shape viser's client sends it ------------------

_Number = Annotated[float, msgspec.Meta(ge=-1e9, le=1e9)]  # finite: NaN fails both bounds
_Vec3 = tuple[_Number, _Number, _Number]
_Pixels = Annotated[int, msgspec.Meta(ge=0, le=100_000)]


class _Camera(
    msgspec.Struct, tag_field="type", tag="ViewerCameraMessage", forbid_unknown_fields=True
):
    wxyz: tuple[_Number, _Number, _Number, _Number]
    position: _Vec3
    fov: _Number
    near: _Number
    far: _Number
    image_height: _Pixels
    image_width: _Pixels
    look_at: _Vec3
    up_direction: _Vec3


class _Value(msgspec.Struct, forbid_unknown_fields=True):
    value: bool | Annotated[str, msgspec.Meta(max_length=64)]


class _GuiUpdate(
    msgspec.Struct, tag_field="type", tag="GuiUpdateMessage", forbid_unknown_fields=True
):
    uuid: Annotated[str, msgspec.Meta(max_length=64)]
    updates: _Value


_decode = msgspec.msgpack.Decoder(_Camera | _GuiUpdate).decode


@dataclass(frozen=True, slots=True)
class ViewerRules:
    """What one viewer may pass to the panel: `inputs` are the panel's GUI inputs by
    uuid, `authorized` whether the viewer presented the control token."""

    inputs: Mapping[str, ViewerInput]
    authorized: bool

    def allows(self, frame: bytes) -> bool:
        try:
            message = _decode(frame)
        except (msgspec.DecodeError, msgspec.ValidationError):
            return False  # not viser's msgpack, or a message a viewer has no business sending
        if isinstance(message, _Camera):
            return True
        wanted = self.inputs.get(message.uuid)
        value = message.updates.value
        if wanted is None or type(value) is not wanted.kind:
            return False
        if wanted.choices is not None and value not in wanted.choices:
            return False
        return wanted.personal or self.authorized


@dataclass(slots=True)
class MessageBudget:
    """A token bucket: `rate_per_s` messages a second, up to `burst` at once."""

    rate_per_s: float = MESSAGES_PER_S
    burst: float = MESSAGES_BURST
    _tokens: float = MESSAGES_BURST
    _at: float = 0.0

    def take(self, now: float) -> bool:
        self._tokens = min(self.burst, self._tokens + (now - self._at) * self.rate_per_s)
        self._at = now
        if self._tokens < 1.0:
            return False
        self._tokens -= 1.0
        return True


# -- the viser servers ------------------------------------------------------------------


def open_viser(port: int, label: str, host: str = LOOPBACK) -> viser.ViserServer:
    """A viser server for a panel, listening on `host` (loopback: reached through the
    relay only), that can never open viser's public share tunnel nor offer it."""
    import viser

    server = viser.ViserServer(host=host, port=port, label=label, verbose=False)
    # viser answers a client's ShareUrlRequest by calling this method of the server, on a
    # worker thread: the instance's own attribute wins over the class's.
    server.request_share_url = _no_share_url  # type: ignore[method-assign]  # on purpose
    return server


def _no_share_url(verbose: bool = True) -> None:
    """The station is never shared through a public tunnel: there is none to ask for."""
    return None


@dataclass(frozen=True, slots=True)
class PilotPath:
    """The path on a panel's viser server by which the relay opens the connection of a
    viewer that presented the control token, so that the panel can give that client
    alone the controls (viser's per-client GUI). Random per panel: only the relay
    knows it, and any other connection (`/`) is a watcher's."""

    path: str = field(default_factory=lambda: "/pilot/" + secrets.token_urlsafe(18))

    def upstream(self, authorized: bool) -> str:
        return self.path if authorized else "/"

    def marks(self, server: viser.ViserServer, client: viser.ClientHandle) -> bool:
        """Whether viser's `client` came in by this path. viser keeps each client's
        websockets connection, and the request it opened with, in its server's
        `_live_connections` (no public name)."""
        conn = server._websock_server._live_connections.get(client.client_id)
        request = getattr(conn, "request", None)
        return request is not None and request.path == self.path


# -- the relay --------------------------------------------------------------------------


async def relay(ws: WebSocket, port: int, rules: ViewerRules, path: str = "/") -> None:
    """Serve one viewer: open its connection to the viser server on `port` (loopback) at
    `path` (a `PilotPath` for a viewer with the token), accept the viewer with the
    subprotocol viser chose, and pass frames both ways until either side leaves. Raises
    OSError (before accepting) when viser cannot be reached."""
    from websockets.asyncio.client import connect
    from websockets.exceptions import ConnectionClosed
    from websockets.typing import Subprotocol

    offered = [Subprotocol(p) for p in ws.scope.get("subprotocols", []) if p.startswith("viser-")]
    try:
        upstream = await connect(
            f"ws://{LOOPBACK}:{port}{path}",
            subprotocols=offered[:4] or None,
            compression=None,  # as viser serves it: compressing costs the Pi per viewer
            max_size=None,  # frames from the station's own viser: its scene, not a stranger's
            open_timeout=UPSTREAM_OPEN_S,
            proxy=None,
        )
    except (OSError, TimeoutError, ConnectionClosed) as exc:
        raise OSError(f"the 3D panel's viser server did not answer: {exc}") from exc
    dropped = 0
    budget = MessageBudget(_at=time.monotonic())

    async def to_viser() -> None:
        nonlocal dropped
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                return
            frame = message.get("bytes")
            if frame is not None and budget.take(time.monotonic()) and rules.allows(frame):
                await upstream.send(frame)
            else:
                dropped += 1

    async def to_viewer() -> None:
        async for frame in upstream:
            if isinstance(frame, bytes):
                await ws.send_bytes(frame)

    try:
        await ws.accept(subprotocol=upstream.subprotocol)
        pumps = [asyncio.ensure_future(to_viser()), asyncio.ensure_future(to_viewer())]
        try:
            await asyncio.wait(pumps, return_when=asyncio.FIRST_COMPLETED)
        finally:
            for pump in pumps:
                pump.cancel()
            for pump in pumps:  # a viewer gone mid-send ends its pump with an error: done
                with contextlib.suppress(asyncio.CancelledError, Exception):
                    await pump
    finally:
        closed_by_viser = upstream.close_code, upstream.close_reason
        await upstream.close()
        code, reason = _close_from(*closed_by_viser)
        with contextlib.suppress(RuntimeError, OSError, WebSocketDisconnect):
            await ws.close(code, reason)  # raises if the viewer already left
        if dropped:
            log.debug("3D viewer: %d messages dropped (not a viewer's to send)", dropped)


def _close_from(code: int | None, reason: str | None) -> tuple[int, str]:
    """The close viser gave (a version mismatch is 1002 with the reason), else 1001."""
    if code is not None and 1000 <= code < 5000 and code not in (1005, 1006, 1015):
        return code, (reason or "")[:120]
    return 1001, ""
