"""The vehicle link's settings section (`[link]`), composed by `server.settings`."""

from __future__ import annotations

from pydantic import Field

from core.settings_section import Section


class LinkSettings(Section):
    # serial (/dev/serial0:921600, /dev/ttyACM0), udpin:/udpout:/tcp: strings,
    # replay:FILE.tlog[?speed=N], or "sim" for the embedded digital twin.
    source: str = "sim"
    sysid: int | None = Field(None, ge=1, le=255)  # pin the autopilot; None = auto-detect
    forward: list[str] = Field(default_factory=list)  # raw MAVLink copies (udpout:HOST:PORT)
    link_lost_s: float = Field(2.0, gt=0)
    heartbeat_hz: float = Field(1.0, gt=0)
    reconnect_s: float = Field(1.0, gt=0)
    # Our own identity on the link. Not QGroundControl's or Mission Planner's 255/190 (nor
    # MAVProxy's 255): with --forward both talk to one vehicle, and a shared identity
    # sends one's command acknowledgements and sequence numbers to the other.
    gcs_sysid: int = Field(254, ge=1, le=255)
    gcs_compid: int = Field(190, ge=1, le=255)  # MAV_COMP_ID_MISSIONPLANNER: a GCS
    # What the station asks the autopilot for (SET_MESSAGE_INTERVAL, or REQUEST_DATA_STREAM
    # on older firmware); 0 leaves a message at the autopilot's own rate.
    message_rates_hz: dict[str, float] = Field(
        default_factory=lambda: {
            "ATTITUDE": 50.0,
            "GLOBAL_POSITION_INT": 25.0,
            "LOCAL_POSITION_NED": 25.0,
            "VFR_HUD": 10.0,
            "GPS_RAW_INT": 5.0,
            "RC_CHANNELS": 10.0,
            "SERVO_OUTPUT_RAW": 10.0,
            "SYS_STATUS": 2.0,
            "BATTERY_STATUS": 1.0,
            "SYSTEM_TIME": 1.0,  # the vehicle's GPS UTC: a Pi has no real-time clock
        }
    )
    request_streams: bool = True  # False: listen only (another GCS already asks)
