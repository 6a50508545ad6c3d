"""The MAVLink mission protocol, vehicle side, as PX4 answers it.

    download: GCS MISSION_REQUEST_LIST -> MISSION_COUNT; MISSION_REQUEST(_INT) n ->
              MISSION_ITEM(_INT) n, for each n; the GCS ends with MISSION_ACK
    upload:   GCS MISSION_COUNT -> MISSION_REQUEST_INT 0; MISSION_ITEM(_INT) n ->
              MISSION_REQUEST_INT n+1 ... -> MISSION_ACK (accepted or why not)
    also:     MISSION_CLEAR_ALL -> MISSION_ACK; MISSION_SET_CURRENT -> MISSION_CURRENT

Only the mission proper (MAV_MISSION_TYPE_MISSION) is kept. QGroundControl asks for the
geofence and rally points too: those read as empty, and an empty upload of them is
accepted, but a non-empty one is refused (MAV_MISSION_UNSUPPORTED) rather than stored and
silently not enforced. An upload replaces the mission only once every item has arrived
and is flyable. Lost packets: the vehicle asks again for the item it waits for, and
gives up (MAV_MISSION_OPERATION_CANCELLED) after a few tries. Timeouts run on the wall
clock: they are about the network, not the simulated flight.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.twin.mission import MissionItem

RETRY_S = 1.0  # PX4 re-requests after about a second
RETRIES = 5
MISSION = mavlink.MAV_MISSION_TYPE_MISSION


class MissionProtocol:
    """One upload at a time, from one ground station; downloads are stateless."""

    def __init__(
        self,
        mav: mavlink.MAVLink,
        get_items: Callable[[], list[MissionItem]],
        set_items: Callable[[list[MissionItem]], None],
        set_current: Callable[[int], bool],
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.mav = mav
        self._get_items = get_items
        self._set_items = set_items
        self._set_current = set_current
        self._clock = clock
        self._upload: _Upload | None = None

    def handle(self, msg: mavlink.MAVLink_message) -> None:
        """Any MISSION_* message addressed to this vehicle."""
        kind = msg.get_type()
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        mtype = getattr(msg, "mission_type", MISSION)
        if kind == "MISSION_REQUEST_LIST":
            count = len(self._get_items()) if mtype == MISSION else 0
            self.mav.mission_count_send(*src, count, mtype)
        elif kind in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            self._send_item(src, msg.seq, mtype, as_int=kind == "MISSION_REQUEST_INT")
        elif kind == "MISSION_COUNT":
            self._start_upload(src, msg.count, mtype)
        elif kind in ("MISSION_ITEM_INT", "MISSION_ITEM"):
            self._on_item(src, msg, mtype)
        elif kind == "MISSION_CLEAR_ALL":
            if mtype in (MISSION, mavlink.MAV_MISSION_TYPE_ALL):
                self._set_items([])
            self._ack(src, mavlink.MAV_MISSION_ACCEPTED, mtype)
        elif kind == "MISSION_SET_CURRENT":
            if not self._set_current(msg.seq):
                self._ack(src, mavlink.MAV_MISSION_INVALID_SEQUENCE, MISSION)
        # MISSION_ACK from the GCS ends its download: nothing to keep.

    def poll(self) -> None:
        """Ask again for the item an upload waits for, or give it up."""
        up = self._upload
        if up is None or self._clock() < up.retry_at:
            return
        if up.tries >= RETRIES:
            self._upload = None
            self._ack(up.src, mavlink.MAV_MISSION_OPERATION_CANCELLED, up.mission_type)
            return
        self._request(up)

    # ---- download ----
    def _send_item(self, src: tuple[int, int], seq: int, mtype: int, as_int: bool) -> None:
        items = self._get_items() if mtype == MISSION else []
        if not 0 <= seq < len(items):
            self._ack(src, mavlink.MAV_MISSION_INVALID_SEQUENCE, mtype)
            return
        it = items[seq]
        lat: float | int
        lon: float | int
        if as_int:
            lat, lon = int(round(it.lat_deg * 1e7)), int(round(it.lon_deg * 1e7))
            send = self.mav.mission_item_int_send
        else:
            lat, lon = it.lat_deg, it.lon_deg
            send = self.mav.mission_item_send
        send(
            *src, seq, it.frame, it.command, 0, int(it.autocontinue),
            it.param1, it.param2, it.param3, it.param4, lat, lon, it.alt_m, mtype,
        )  # fmt: skip

    # ---- upload ----
    def _start_upload(self, src: tuple[int, int], count: int, mtype: int) -> None:
        if mtype not in (MISSION, mavlink.MAV_MISSION_TYPE_FENCE, mavlink.MAV_MISSION_TYPE_RALLY):
            self._ack(src, mavlink.MAV_MISSION_UNSUPPORTED, mtype)
            return
        if count == 0:
            if mtype == MISSION:
                self._set_items([])
            self._upload = None
            self._ack(src, mavlink.MAV_MISSION_ACCEPTED, mtype)
            return
        if mtype != MISSION:
            self._ack(src, mavlink.MAV_MISSION_UNSUPPORTED, mtype)  # no fence, no rally
            return
        self._upload = _Upload(src, count, mtype)
        self._request(self._upload)

    def _on_item(self, src: tuple[int, int], msg: mavlink.MAVLink_message, mtype: int) -> None:
        up = self._upload
        if up is None or src != up.src or mtype != up.mission_type:
            return  # not part of an upload we run: PX4 ignores it too
        if msg.seq != len(up.items):
            if msg.seq > len(up.items):
                self._request(up)  # one went missing: ask for it again
            return  # an old repeat
        item = MissionItem.from_message(msg)
        problem = item.problem()
        if problem is not None:
            self._upload = None
            self._ack(src, problem, mtype)
            return
        up.items.append(item)
        up.tries = 0
        if len(up.items) < up.count:
            self._request(up)
            return
        self._upload = None
        self._set_items(up.items)
        self._ack(src, mavlink.MAV_MISSION_ACCEPTED, mtype)

    def _request(self, up: _Upload) -> None:
        up.tries += 1
        up.retry_at = self._clock() + RETRY_S
        self.mav.mission_request_int_send(*up.src, len(up.items), up.mission_type)

    def _ack(self, src: tuple[int, int], result: int, mtype: int) -> None:
        self.mav.mission_ack_send(*src, result, mtype)


class _Upload:
    def __init__(self, src: tuple[int, int], count: int, mission_type: int) -> None:
        self.src = src
        self.count = count
        self.mission_type = mission_type
        self.items: list[MissionItem] = []
        self.tries = 0
        self.retry_at = 0.0
