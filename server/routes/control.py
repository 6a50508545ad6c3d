"""`WS /ws/control`: the pilot's sticks and commands from the browser to the vehicle.

With the digital twin (`--source sim`) the browser sends its sticks (gamepad or keyboard) at
~50 Hz; the station sends MANUAL_CONTROL to the twin through its ordinary MAVLink link at a
steady 50 Hz from the newest sticks. Dead-man: no message for 0.5 s = sticks centred
(Position mode then holds position and altitude). One pilot at a time has the sticks: the
first connection. Every other authorised page (a second pilot tab, the goggles, the
sessions page) connects too, without the sticks, and its Disarm, Land and RTL (EMERGENCY)
are always carried out: an emergency is never refused for want of the sticks. Anything
else from such a page is refused with the error shape (the page shows it).

With a real vehicle (a live link: serial, UDP or TCP) every authorised page may send
Disarm, Land and RTL, and nothing else: the station never sends stick inputs, arming,
take-off or mode changes from a browser to a real vehicle (the pilot's radio flies it).
No link, or a replay, refuses the connection. `control_level` says which applies
(`GET /api/status` `control`).

Client -> station, JSON:
    {"type": "sticks", "roll": r, "pitch": p, "yaw": y, "throttle": t}  r/p/y in [-1, 1],
                                                          throttle in [0, 1], 0.5 = centred
    {"type": "arm"} | {"type": "disarm"} | {"type": "mode", "mode": "POSCTL"}
    {"type": "takeoff", "alt_m": 4} | {"type": "land"} | {"type": "rtl"} | {"type": "reset"}
    {"type": "disarm", "force": true}   disarm in flight (param2 21196, the force value
                                        PX4 and ArduPilot take): the motors stop; the page
                                        asks first
Station -> client: {"type": "hello", "sticks": bool, "control": level} (whether this
connection has the sticks), {"type": "ack", "cmd": ..., "ok": ...} and the error shape
{"error": Name, "error_msg": text} for anything refused.

Every command goes to the followed autopilot (its sysid and compid as heard on the link)
and is answered with what the vehicle said, not with what the station sent: the ack waits
(without holding up the sticks) for the vehicle's COMMAND_ACK, at most ACK_TIMEOUT_S, and
carries its result and the vehicle's own words (STATUSTEXT since the command, e.g. PX4's
"Arming denied: ..."). A command not answered within ACK_TIMEOUT_S / COMMAND_SENDS is
sent again with its `confirmation` counted up, as the MAVLink command protocol asks (a
radio may lose it), at most COMMAND_SENDS times in all; each command here is one the
vehicle may receive twice (arm when armed, land when landing). The ack:
    {"type": "ack", "cmd": "disarm", "ok": false, "result": "DENIED",
     "text": "Disarming denied: not landed"}
`result` is "NO_ANSWER" when the vehicle did not answer in time.
"""

from __future__ import annotations

import asyncio
import contextlib
import copy
import functools
import json
import math
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Literal

from fastapi import APIRouter, WebSocket, WebSocketDisconnect
from pydantic import BaseModel, Field, ValidationError
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.core.mavlink.px4_modes import PX4_MODES
from fpv_station.server.auth import require_control_token
from fpv_station.server.errors import (
    ApiError,
    BadRequest,
    Conflict,
    Unavailable,
    deny_websocket,
)
from fpv_station.server.guard import loads_message
from fpv_station.server.pilot import DEADMAN_S, Pilot

if TYPE_CHECKING:
    from fpv_station.companion.link import MavlinkLink
    from fpv_station.server.station import Station

router = APIRouter(tags=["control"])

RATE_HZ = 50.0
# The largest frame the pilot's page sends is a stick message of ~100 bytes (a larger
# frame is refused with 1009 before it is read, server/listen.py).
MAX_FRAME_BYTES = 4096
# The modes a pilot may choose, as PX4 names them. MANUAL is sent as STABILIZED: on a
# multicopter PX4 flies the two alike, and the twin knows only STABILIZED.
PILOT_MODES = {
    "STABILIZED": "STABILIZED",
    "MANUAL": "STABILIZED",
    "ALTCTL": "ALTCTL",
    "POSCTL": "POSCTL",
}


class Sticks(BaseModel):
    type: Literal["sticks"]
    roll: float = Field(0.0, ge=-1, le=1)
    pitch: float = Field(0.0, ge=-1, le=1)
    yaw: float = Field(0.0, ge=-1, le=1)
    throttle: float = Field(0.5, ge=0, le=1)


class Command(BaseModel):
    type: Literal["arm", "disarm", "mode", "takeoff", "land", "rtl", "reset"]
    mode: str | None = None
    alt_m: float | None = Field(None, gt=0, le=100)
    force: bool = False  # disarm only: in flight too (the vehicle's force magic)


# Carried out from any authorised page, whoever has the sticks, and for a real vehicle.
EMERGENCY = frozenset({"disarm", "land", "rtl"})
# What the pages may do: "twin" (sticks and every command), "emergency" (a real vehicle:
# Disarm, Land and RTL only), "none" (no link, or a replay: nothing to command).
ControlLevel = Literal["twin", "emergency", "none"]


def control_level(station: Station) -> ControlLevel:
    link = station.link
    if link is None or link.spec.kind == "replay":
        return "none"
    return "twin" if station.twin is not None else "emergency"


# MAV_CMD_COMPONENT_ARM_DISARM param2 that makes PX4 and ArduPilot disarm in flight.
FORCE_MAGIC = 21196.0


def _error(name: str, message: str) -> str:
    return json.dumps({"error": name, "error_msg": message})


async def _send_sticks(link: MavlinkLink, pilot: Pilot, target: int) -> None:
    """MANUAL_CONTROL at a steady rate from the newest sticks (never queues up)."""
    period = 1.0 / RATE_HZ
    next_t = time.monotonic()
    while True:
        roll, pitch, yaw, thr = pilot.current(time.monotonic())
        link.send(
            link.mav.manual_control_encode(
                target, int(pitch * 1000), int(roll * 1000), int(thr * 1000), int(yaw * 1000), 0
            )
        )
        next_t += period
        await asyncio.sleep(max(0.0, next_t - time.monotonic()))


def _command(
    station: Station, link: MavlinkLink, cmd: Command
) -> mavlink.MAVLink_command_long_message | None:
    """Send `cmd` to the followed autopilot as a COMMAND_LONG through the link, as for
    any vehicle; returns the message sent (None for the twin's reset, done at once).
    Only EMERGENCY commands come here for a real vehicle (the route refuses the rest)."""
    twin, mav = station.twin, link.mav
    if cmd.type == "reset":
        if twin is None:
            raise Conflict("reset is the digital twin's.")
        twin.reset()
        return None
    target = link.autopilot()
    if target is None:
        raise Unavailable("No autopilot heard on the link yet: nothing to command.")
    if cmd.type in ("arm", "disarm"):
        arm = 1.0 if cmd.type == "arm" else 0.0
        force = FORCE_MAGIC if cmd.type == "disarm" and cmd.force else 0.0
        msg = mav.command_long_encode(
            *target, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, arm, force, 0, 0, 0, 0, 0
        )
    elif cmd.type == "mode":
        name = PILOT_MODES.get((cmd.mode or "").upper())
        if name is None:
            raise BadRequest(
                f"Mode '{cmd.mode}' is not one the pilot can choose: {', '.join(PILOT_MODES)}."
            )
        main, sub = PX4_MODES[name]
        custom = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        msg = mav.command_long_encode(
            *target, mavlink.MAV_CMD_DO_SET_MODE, 0, custom, main, sub, 0, 0, 0, 0
        )
    elif cmd.type == "takeoff":
        assert twin is not None  # the route sends a real vehicle no take-off
        alt = twin.scene.home.alt_m + (cmd.alt_m or 2.5)
        nan = math.nan
        msg = mav.command_long_encode(
            *target, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, nan, nan, nan, alt
        )
    elif cmd.type == "rtl":
        msg = mav.command_long_encode(
            *target, mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0, 0, 0, 0, 0, 0, 0, 0
        )
    else:  # land where it is (NaN latitude and longitude: the current position)
        nan = math.nan
        msg = mav.command_long_encode(
            *target, mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, 0, nan, nan, nan, 0
        )
    link.send(msg)
    return msg


def _send_again(link: MavlinkLink, msg: mavlink.MAVLink_command_long_message, sends: int) -> None:
    """`msg` sent once more: its `sends`-th time, `confirmation` = sends - 1."""
    again = copy.copy(msg)
    again.confirmation = sends - 1
    link.send(again)


ANOTHER_PAGE = "another page has the sticks; from here only Disarm, Land and RTL are carried out."
REAL_VEHICLE = (
    "the station sends a real vehicle only Disarm, Land and RTL from a page; fly it with its radio."
)
ACK_TIMEOUT_S = 3.0
COMMAND_SENDS = 3
REASON_GRACE_S = 0.3


async def vehicle_answer(
    station: Station,
    command: int,
    since_mono: float,
    send_again: Callable[[int], None],
) -> dict[str, Any]:
    """The vehicle's COMMAND_ACK of `command` sent at `since_mono` (station clock), with
    its STATUSTEXT since then: {"ok", "result", "text"}. Until it answers, `send_again(n)`
    sends the command an n-th time every ACK_TIMEOUT_S / COMMAND_SENDS. Of several acks
    (one per send), an accepting one wins: the vehicle carried the command out."""
    name = mavlink.enums["MAV_CMD"][command].name.removeprefix("MAV_CMD_")
    deadline = since_mono + ACK_TIMEOUT_S
    every = ACK_TIMEOUT_S / COMMAND_SENDS
    version, answer, sends = 0, None, 1
    while True:
        now = time.monotonic()
        left = deadline - now
        if answer is None and sends < COMMAND_SENDS:
            until_again = since_mono + sends * every - now
            if until_again <= 0:
                sends += 1
                send_again(sends)
                # Each send is given its time to be answered, late as a busy loop may be.
                deadline = max(deadline, now + every)
                continue
            left = min(left, until_again)
        if left <= 0:
            break
        current = await station.state.wait_newer(version, timeout=left)
        if current is not None:
            version = current.version
            said = [m for m in current.value.messages.recent if m.t_mono >= since_mono]
            acks = [m for m in said if m.kind == "command_ack" and m.command == name]
            words = [m.text for m in said if m.kind == "statustext"]
            if acks:
                accepting = [a for a in acks if a.result in ("ACCEPTED", "IN_PROGRESS")]
                ack = (accepting or acks)[-1]
                ok = bool(accepting)
                answer = {"ok": ok, "result": ack.result, "text": "; ".join(words) or ack.text}
                # A refusal's reason may follow it (ArduPilot sends it after the ack).
                if ok or words:
                    return answer
                deadline = min(deadline, ack.t_mono + REASON_GRACE_S)
    if answer is not None:
        return answer
    return {
        "ok": False,
        "result": "NO_ANSWER",
        "text": f"The vehicle did not answer {name}, sent {sends} times in "
        f"{time.monotonic() - since_mono:.0f} s.",
    }


@router.websocket("/ws/control")
async def ws_control(ws: WebSocket) -> None:
    station: Station = ws.app.state.station
    try:
        with station.client_limits.control.slot():
            await _serve_control(ws, station)
    except Unavailable as exc:
        await deny_websocket(ws, 503, "Unavailable", exc.message)


async def _serve_control(ws: WebSocket, station: Station) -> None:
    await ws.accept()
    try:
        require_control_token(ws)
    except ApiError as exc:
        await ws.send_text(_error(type(exc).__name__, exc.message))
        await ws.close(code=4401)
        return
    link, level = station.link, control_level(station)
    if link is None or level == "none":
        await ws.send_text(
            _error(
                "Conflict",
                "No vehicle to command: the station has no live link (none, or a replay).",
            )
        )
        await ws.close(code=4409)
        return
    # The twin's first connection has the sticks; the others, and every page of a real
    # vehicle, only the emergency commands.
    refusal = ANOTHER_PAGE if level == "twin" else REAL_VEHICLE
    pilot: Pilot | None = None
    sender: asyncio.Task[None] | None = None
    if level == "twin" and station.pilot is None:
        pilot = station.pilot = Pilot()
        sender = station.tasks.spawn("control-sticks", _send_sticks(link, pilot, 1))
    sticks_refused = False  # said once: a page sends sticks 50 times a second
    send_lock = asyncio.Lock()  # acks are sent from their own tasks
    answers: set[asyncio.Task[None]] = set()

    async def send(text: str) -> None:
        async with send_lock:
            await ws.send_text(text)

    async def answer(
        cmd: Command, msg: mavlink.MAVLink_command_long_message, sent_at: float
    ) -> None:
        # Its own task: sticks keep flowing while the vehicle thinks it over.
        again = functools.partial(_send_again, link, msg)
        reply = await vehicle_answer(station, msg.command, sent_at, again)
        with contextlib.suppress(WebSocketDisconnect, RuntimeError, ConnectionError):
            await send(json.dumps({"type": "ack", "cmd": cmd.type, **reply}))

    try:
        hello = {
            "rate_hz": RATE_HZ,
            "deadman_s": DEADMAN_S,
            "sticks": pilot is not None,
            "control": level,
        }
        await send(json.dumps({"type": "hello", **hello}))
        while True:
            message = await ws.receive()
            if message["type"] == "websocket.disconnect":
                break
            text = message.get("text")
            if text is None:  # a binary frame: this protocol is JSON text only
                await send(_error("BadRequest", "Control messages are JSON text frames."))
                await ws.close(code=1003, reason="binary frames are not accepted")
                break
            try:
                data = loads_message(text)
                if not isinstance(data, dict):
                    raise ValueError("a message is a JSON object")
                if data.get("type") == "sticks":
                    s = Sticks.model_validate(data)
                    if pilot is not None:
                        pilot.sticks, pilot.at = (
                            (s.roll, s.pitch, s.yaw, s.throttle),
                            time.monotonic(),
                        )
                    elif not sticks_refused:
                        sticks_refused = True
                        await send(_error("Conflict", refusal))
                    continue
                cmd = Command.model_validate(data)
                if pilot is None and cmd.type not in EMERGENCY:
                    await send(_error("Conflict", f"{cmd.type}: {refusal}"))
                    continue
                sent_at = time.monotonic()
                msg = _command(station, link, cmd)
                if msg is None:  # done by the station itself (reset)
                    await send(json.dumps({"type": "ack", "cmd": cmd.type, "ok": True}))
                    continue
                task = asyncio.create_task(answer(cmd, msg, sent_at))
                answers.add(task)
                task.add_done_callback(answers.discard)
            except (ValueError, ValidationError) as exc:
                await send(_error("BadRequest", f"Bad control message: {exc}"[:500]))
            except ApiError as exc:
                await send(_error(type(exc).__name__, exc.message))
    except (WebSocketDisconnect, RuntimeError, ConnectionError):
        pass
    finally:
        for task in answers:
            task.cancel()
        if sender is not None:
            sender.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await sender
            # The pilot left: centre the sticks now rather than wait for the twin's timeout.
            with contextlib.suppress(Exception):
                link.send(link.mav.manual_control_encode(1, 0, 0, 500, 0, 0))
            station.pilot = None
