"""Ask the autopilot for the messages the station needs, at set rates.

Modern PX4 and ArduPilot take MAV_CMD_SET_MESSAGE_INTERVAL per message and answer with
COMMAND_ACK. Older firmware ignores or rejects it; then (no ACK in time, or a refusal)
we fall back to the legacy REQUEST_DATA_STREAM groups, which every ArduPilot and PX4
release understands.

Rates are per port on the autopilot, so another ground station on the same link (one we
forward to, or one on a shared network) can change ours: MAVProxy's REQUEST_DATA_STREAM
or a SET_MESSAGE_INTERVAL cut ATTITUDE from 50 to 2 Hz in a recording. `foreign_change`
recognises such a request and `reassert` sends ours again, as MAVProxy itself keeps its
stream rate setting.
"""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mavlink

ACK_TIMEOUT_S = 1.5

# Which legacy stream group carries each message (ArduPilot's grouping; PX4 honours it too).
_LEGACY_STREAM = {
    "GPS_RAW_INT": mavlink.MAV_DATA_STREAM_RAW_SENSORS,
    "SYS_STATUS": mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    "BATTERY_STATUS": mavlink.MAV_DATA_STREAM_EXTENDED_STATUS,
    "RC_CHANNELS": mavlink.MAV_DATA_STREAM_RC_CHANNELS,
    "SERVO_OUTPUT_RAW": mavlink.MAV_DATA_STREAM_RC_CHANNELS,
    "GLOBAL_POSITION_INT": mavlink.MAV_DATA_STREAM_POSITION,
    "LOCAL_POSITION_NED": mavlink.MAV_DATA_STREAM_POSITION,
    "ATTITUDE": mavlink.MAV_DATA_STREAM_EXTRA1,
    "VFR_HUD": mavlink.MAV_DATA_STREAM_EXTRA2,
    "SYSTEM_TIME": mavlink.MAV_DATA_STREAM_EXTRA3,
}


def message_id(name: str) -> int:
    mid: int | None = getattr(mavlink, f"MAVLINK_MSG_ID_{name}", None)
    if mid is None:
        raise ValueError(f"Unknown MAVLink message '{name}' in link.message_rates_hz.")
    return mid


class StreamRequester:
    """State machine: idle -> waiting for ACKs -> "message_interval" or "data_stream"."""

    def __init__(self, mav: mavlink.MAVLink, rates_hz: dict[str, float]) -> None:
        self._mav = mav
        self._rates = {name: rate for name, rate in rates_hz.items() if rate > 0}
        self._ids = {message_id(name) for name in self._rates}
        self.mode = "none"
        self._target: tuple[int, int] = (0, 0)
        self._deadline: float | None = None
        # Which legacy streams carry what we need (MAV_DATA_STREAM_ALL carries everything).
        self._streams_needed = {_LEGACY_STREAM[n] for n in self._rates if n in _LEGACY_STREAM}
        self._streams_needed.add(mavlink.MAV_DATA_STREAM_ALL)

    def start(self, now: float, sysid: int, compid: int) -> list[mavlink.MAVLink_message]:
        """The SET_MESSAGE_INTERVAL commands; call on (re)connection to the autopilot."""
        if not self._rates:
            return []
        self._target = (sysid, compid)
        self._deadline = now + ACK_TIMEOUT_S
        self.mode = "waiting"
        return [
            self._mav.command_long_encode(
                sysid,
                compid,
                mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                0,
                float(message_id(name)),
                1e6 / rate,
                0,
                0,
                0,
                0,
                0,
            )
            for name, rate in self._rates.items()
        ]

    def on_ack(self, msg: mavlink.MAVLink_message, now: float) -> list[mavlink.MAVLink_message]:
        if msg.command != mavlink.MAV_CMD_SET_MESSAGE_INTERVAL or self.mode != "waiting":
            return []
        if getattr(msg, "target_system", 0) not in (0, self._mav.srcSystem):
            return []  # the answer to another ground station's request
        if msg.result == mavlink.MAV_RESULT_ACCEPTED:
            self.mode = "message_interval"
            self._deadline = None
            return []
        if msg.result in (mavlink.MAV_RESULT_IN_PROGRESS, mavlink.MAV_RESULT_TEMPORARILY_REJECTED):
            return []
        return self._fallback()

    def foreign_change(self, msg: mavlink.MAVLink_message, autopilot: int | None) -> str | None:
        """What `msg` (from someone else, to the autopilot) does to our rates, in words;
        None if it leaves them alone."""
        if not self._rates or autopilot is None:
            return None
        mtype = msg.get_type()
        if mtype == "REQUEST_DATA_STREAM":
            if msg.target_system not in (0, autopilot):
                return None
            if msg.req_stream_id not in self._streams_needed:
                return None
            rate = msg.req_message_rate if msg.start_stop else 0
            return f"REQUEST_DATA_STREAM stream {msg.req_stream_id} at {rate} Hz"
        if mtype in ("COMMAND_LONG", "COMMAND_INT"):
            if msg.command != mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                return None
            if msg.target_system not in (0, autopilot):
                return None
            if int(msg.param1) not in self._ids:
                return None
            cls = mavlink.mavlink_map.get(int(msg.param1))
            interval = msg.param2
            what = (
                "off"
                if interval < 0
                else "default rate"
                if interval == 0
                else f"{1e6 / interval:.3g} Hz"
            )
            return f"SET_MESSAGE_INTERVAL {cls.msgname if cls else int(msg.param1)} {what}"
        return None

    def reassert(self) -> list[mavlink.MAVLink_message]:
        """Our requests again, in the way the autopilot already accepted (none while
        that is still being found out: the answer will settle it)."""
        if self.mode == "message_interval":
            sent = self.start(0.0, *self._target)
            self.mode = "message_interval"  # known to work: no new wait for ACKs
            self._deadline = None
            return sent
        if self.mode == "data_stream":
            return self._fallback()
        return []

    def poll(self, now: float) -> list[mavlink.MAVLink_message]:
        """The legacy requests once the ACK deadline passes unanswered."""
        if self.mode == "waiting" and self._deadline is not None and now >= self._deadline:
            return self._fallback()
        return []

    def _fallback(self) -> list[mavlink.MAVLink_message]:
        self.mode = "data_stream"
        self._deadline = None
        streams: dict[int, float] = {}
        for name, rate in self._rates.items():
            stream = _LEGACY_STREAM.get(name)
            if stream is not None:
                streams[stream] = max(streams.get(stream, 0.0), rate)
        sysid, compid = self._target
        return [
            self._mav.request_data_stream_encode(sysid, compid, stream, max(1, round(rate)), 1)
            for stream, rate in sorted(streams.items())
        ]
