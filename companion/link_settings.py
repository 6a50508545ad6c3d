"""The vehicle link's settings section (`[link]`), composed by `server.settings`."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

from pydantic import Field

from fpv_station.core.mavlink.signing import load_key_file
from fpv_station.core.settings_section import Section, checked_by


class LinkSettings(Section):
    """The MAVLink link to the vehicle: where it is, who we are on it, what we ask for."""

    source: str = Field(
        "sim",
        description="Where the vehicle is: a serial port (/dev/serial0:921600, "
        "/dev/ttyACM0), udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT, "
        "replay:FILE.tlog[?speed=N], sim (the embedded digital twin) or none.",
    )
    sysid: int | None = Field(
        None, ge=1, le=255, description="Follow this autopilot; None: the first one heard."
    )
    forward: list[str] = Field(
        default_factory=list,
        description="Other ground stations that get a copy of every packet and may talk "
        "back to the vehicle (udpout:HOST:PORT or udpin:HOST:PORT; HOST may be a name).",
    )
    forward_resolve_s: float = Field(
        10.0,
        gt=0,
        description="How often a forward target given by name is looked up again (a laptop "
        "that joins the field Wi-Fi after the station started, or gets another DHCP address).",
    )
    link_lost_s: float = Field(2.0, gt=0, description="No heartbeat for this long (s): LINK LOST.")
    heartbeat_hz: float = Field(1.0, gt=0, description="Our GCS heartbeats a second.")
    timesync_hz: float = Field(
        1.0,
        ge=0,
        description="TIMESYNC requests a second, to measure the vehicle's boot clock "
        "against the station's (companion.timesync); 0: none, vehicle times are then "
        "placed by their shortest delay",
    )
    reconnect_s: float = Field(
        1.0, gt=0, description="Seconds between attempts to reopen a lost port or socket."
    )
    gcs_sysid: int = Field(
        254,
        ge=1,
        le=255,
        description="Our own system id on the link. Not QGroundControl's, Mission Planner's "
        "or MAVProxy's 255: with forward both talk to one vehicle, and a shared identity "
        "sends one's command acknowledgements and sequence numbers to the other.",
    )
    gcs_compid: int = Field(
        190, ge=1, le=255, description="Our component id (MAV_COMP_ID_MISSIONPLANNER: a GCS)."
    )
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
        },
        description="What the station asks the autopilot for, by message name "
        "(SET_MESSAGE_INTERVAL, or REQUEST_DATA_STREAM on older firmware); 0 leaves a "
        "message at the autopilot's own rate. SYSTEM_TIME gives the vehicle's GPS UTC: a "
        "Pi has no real-time clock.",
    )
    request_streams: bool = Field(
        True, description="Ask for message_rates_hz; false: listen only (another GCS asks)."
    )
    udpin_lock: bool = Field(
        True,
        description="udpin: hear only the host that spoke first (its port may change: a "
        "restarted bridge); datagrams from other hosts are dropped and counted in the link "
        "health. False: hear anyone and answer whoever spoke last (several hosts feed one "
        "port).",
    )
    signing_key_file: Annotated[Path | None, checked_by(load_key_file)] = Field(
        None,
        description="MAVLink 2 signing (core/mavlink/signing.py): a file holding the "
        "passphrase given to MAVProxy's `signing setup` or Mission Planner, readable by its "
        "owner only (chmod 600). Set: everything we send is signed, and unsigned or badly "
        "signed packets are refused and counted (a radio's RADIO_STATUS excepted). None: no "
        "signing. Replays of a tlog are never checked; `--source sim` signs the twin with "
        "the same key.",
    )

    def signing_key(self) -> bytes | None:
        """The 32-byte key, read now (None without signing)."""
        return None if self.signing_key_file is None else load_key_file(self.signing_key_file)
