"""A test MAVLink vehicle: real packets from pymavlink's encoder over real sockets.

    with MavVehicle("udp") as v:              # sends to the station's udpin port
        link = MavlinkLink(LinkSettings(source=v.station_source))
        v.arm(); v.set_mode("POSCTL"); v.alt_m += 3; v.silent = True; v.inject(b"junk")

UDP: the vehicle sends from its own socket to `station_port` (station source
`udpin:127.0.0.1:PORT`), as a Pixhawk's network bridge does. TCP: the vehicle listens
(`tcp:127.0.0.1:PORT`), as SITL does, and accepts the station again after a drop.
It answers SET_MESSAGE_INTERVAL (or refuses, or ignores it: `interval_reply`), records
what the station sends, and changes its own rates on request. Parsing of what the station
sends uses pymavlink's own parser, not the station's code.

`answer_sender=True` (UDP): the vehicle listens on `port` and answers whoever spoke last,
as PX4 SITL or a network bridge does; the station then connects with `udpout:`.
As an autopilot (component 1) it answers TIMESYNC as PX4 and ArduPilot do (`tc1` its
boot clock in ns, `ts1` mirrored, addressed to the asker; signed, MAVLink 1 or
`timesync="untargeted"`: as older firmware, to no one; "none": never), on a boot clock that runs `clock_rate` vehicle seconds per second of
this host's monotonic clock (every `time_boot_ms`/`time_usec` it sends is on that clock).
`command_results`: the COMMAND_ACK result it answers other COMMAND_LONGs with, by
MAV_CMD (a command not in it, or mapped to None, is not answered), each after a
STATUSTEXT of `command_texts[command]` if there is one, as PX4 says why it refuses;
`commands_lost`: that many of the next such commands are lost on the way (unanswered);
`commands_held`: that many are answered late, just before the next command's answer
(as a slow link delivers them), and `repeat_result`, if set, answers a command sent
again (confirmation above 0) instead of `command_results`.
`signing_key`: MAVLink 2 signing as pymavlink (and so MAVProxy) does it: everything sent
is signed with the key; what arrives is checked by pymavlink and `signed(msg)` says
whether it carried a good signature.
"""

from __future__ import annotations

import collections
import contextlib
import math
import socket
import struct
import threading
import time
from collections.abc import Callable
from typing import Literal, Self

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink
from pymavlink.generator.mavcrc import x25crc

from fpv_station.companion.link import MavlinkLink
from fpv_station.companion.link_settings import LinkSettings
from tests.helpers import free_port

DEFAULT_RATES_HZ = {
    "HEARTBEAT": 1.0,
    "ATTITUDE": 20.0,
    "GLOBAL_POSITION_INT": 10.0,
    "GPS_RAW_INT": 5.0,
    "VFR_HUD": 5.0,
    "SYS_STATUS": 2.0,
    "RC_CHANNELS": 5.0,
    "SERVO_OUTPUT_RAW": 5.0,
    "BATTERY_STATUS": 1.0,
    "LOCAL_POSITION_NED": 5.0,
    "SYSTEM_TIME": 1.0,
}

# What PX4 streams on a link in `MAV_X_MODE = Onboard` before anyone asks for anything
# (src/modules/mavlink/mavlink_main.cpp, MAVLINK_MODE_ONBOARD), the streams a quadcopter
# without extra sensors sends in position mode: rates the station asks for replace
# theirs; the others (about 210 packets/s) it does not read. benchmarks/pi_budget.py
# --autopilot-streams px4-onboard measures what they cost the station.
PX4_ONBOARD_RATES_HZ = {
    **DEFAULT_RATES_HZ,
    "ALTITUDE": 10.0,
    "ATTITUDE": 100.0,
    "ATTITUDE_QUATERNION": 50.0,
    "ATTITUDE_TARGET": 10.0,
    "BATTERY_STATUS": 0.5,
    "ESTIMATOR_STATUS": 1.0,
    "EXTENDED_SYS_STATE": 5.0,
    "GLOBAL_POSITION_INT": 50.0,
    "HIGHRES_IMU": 50.0,
    "HOME_POSITION": 0.5,
    "LOCAL_POSITION_NED": 30.0,
    "NAV_CONTROLLER_OUTPUT": 10.0,
    "ODOMETRY": 30.0,
    "PING": 1.0,
    "POSITION_TARGET_GLOBAL_INT": 10.0,
    "POSITION_TARGET_LOCAL_NED": 10.0,
    "RC_CHANNELS": 20.0,
    "SERVO_OUTPUT_RAW": 10.0,
    "SYS_STATUS": 5.0,
    "TIMESYNC": 10.0,
    "UTM_GLOBAL_POSITION": 1.0,
    "VFR_HUD": 10.0,
    "WIND_COV": 10.0,
}


def px4_custom_mode(name: str) -> tuple[int, int]:
    base, main, sub = mavutil.px4_map[name]
    return base, (main << 16) | (sub << 24)


def copter_custom_mode(name: str) -> int:
    return {v: k for k, v in mavutil.mode_mapping_acm.items()}[name]


def timesync_v2(
    mav: mavlink.MAVLink, tc1: int, ts1: int, target_system: int, target_component: int
) -> Callable[[int], bytes]:
    """A MAVLink 2 TIMESYNC with its extension fields target_system/target_component, as
    PX4 1.14 and ArduPilot 4.3 send it (pymavlink's dialect here has no such fields)."""

    def packet(seq: int) -> bytes:
        body = struct.pack("<qqBB", tc1, ts1, target_system, target_component).rstrip(b"\0")
        msg_id = mavlink.MAVLINK_MSG_ID_TIMESYNC
        header = struct.pack(
            "<BBBBBBBHB",
            0xFD,
            len(body),
            0,
            0,
            seq,
            mav.srcSystem,
            mav.srcComponent,
            msg_id & 0xFFFF,
            msg_id >> 16,
        )
        crc = x25crc(header[1:] + body)
        crc.accumulate(bytes([mavlink.MAVLink_timesync_message.crc_extra]))
        return header + body + struct.pack("<H", crc.crc)

    return packet


class MavVehicle:
    def __init__(
        self,
        transport: Literal["udp", "tcp"] = "udp",
        *,
        sysid: int = 1,
        compid: int = 1,
        autopilot: Literal["px4", "ardupilot", "invalid"] = "px4",
        mavlink1: bool = False,
        rates_hz: dict[str, float] | None = None,
        station_port: int | None = None,
        port: int | None = None,
        interval_reply: Literal["accept", "unsupported", "ignore"] = "accept",
        answer_sender: bool = False,
        signing_key: bytes | None = None,
        signing_clock_s: float = 0.0,
        host: str = "127.0.0.1",
        timesync: Literal["targeted", "untargeted", "none"] = "targeted",
        clock_rate: float = 1.0,
    ) -> None:
        self.transport = transport
        self.timesync = timesync
        self.clock_rate = clock_rate
        self.sysid, self.compid = sysid, compid
        self.autopilot = autopilot
        self.mavlink1 = mavlink1
        self.rates_hz = dict(DEFAULT_RATES_HZ if rates_hz is None else rates_hz)
        self.interval_reply = interval_reply
        self.mav = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        if signing_key is not None:
            # As mavutil's setup_signing does, with one signing state for what is sent and
            # what is received (an accepted timestamp moves the next one sent forward);
            # `signing_clock_s` ahead (+) or behind (-) the wall clock.
            self._parser.signing = self.mav.signing
            self.mav.signing.secret_key = signing_key
            self.mav.signing.link_id = 0
            t = time.time() + signing_clock_s - 1420070400
            self.mav.signing.timestamp = int(t * 1e5)
            self.mav.signing.sign_outgoing = True
            # Let unsigned packets through to `received`; `signed(msg)` tells them apart.
            self._parser.signing.allow_unsigned_callback = lambda mav, msg_id: True
        self.answer_sender = answer_sender
        self.reply_to: tuple[str, int] | None = None  # answer_sender: the last sender
        # The flight state it reports; tests change these attributes directly.
        self.armed = False
        self.mode = "POSCTL" if autopilot == "px4" else "LOITER"
        self.lat_deg, self.lon_deg, self.alt_m = 43.0021, -78.7875, 180.0
        self.relative_alt_m = 0.0
        self.vx_mps, self.vy_mps, self.vz_mps = 0.0, 0.0, 0.0
        self.roll_rad, self.pitch_rad, self.yaw_rad = 0.0, 0.0, 0.0
        self.fix_type, self.satellites = 3, 12
        # Its GPS UTC minus this host's clock; None: no UTC yet (SYSTEM_TIME says 0).
        self.gps_utc_offset_s: float | None = 0.0
        self.voltage_v, self.current_a, self.remaining_pct = 12.3, 4.5, 87
        # Charge drawn (mAh), as an autopilot counts it: the send loop integrates current_a
        # over the vehicle's clock while armed (so a test sets it while disarmed without a
        # race); None: no current sensor (sends -1).
        self.consumed_mah: float | None = 0.0
        self.rc_pwm = [1500] * 8 + [0] * 10
        self.servo_pwm = [1100] * 4 + [0] * 12
        self.silent = False  # True: sends nothing (a vehicle gone out of range)
        self.command_results: dict[int, int | None] = {}
        self.command_texts: dict[int, str] = {}
        self.commands_lost = 0  # the next this many answerable COMMAND_LONGs are lost
        self.commands_held = 0  # the next this many are answered with the one after them
        self.repeat_result: int | None = None
        self._held: list[mavlink.MAVLink_message] = []
        self.received: collections.deque[mavlink.MAVLink_message] = collections.deque(maxlen=2000)
        self.sent: collections.Counter[str] = collections.Counter()
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.boot_mono = time.monotonic()
        self._threads: list[threading.Thread] = []
        self._conn: socket.socket | None = None
        if transport == "udp":
            self.station_port = station_port or free_port(socket.SOCK_DGRAM)
            self._sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self._sock.bind((host, port or 0))  # 127.0.0.2, ...: another host
            self._sock.settimeout(0.05)
            self.port = self._sock.getsockname()[1]
            self.station_source = (
                f"udpout:127.0.0.1:{self.port}"
                if answer_sender
                else f"udpin:127.0.0.1:{self.station_port}"
            )
        else:
            self._sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            self._sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            self._sock.bind(("127.0.0.1", port or 0))
            self._sock.listen(1)
            self._sock.settimeout(0.05)
            self.port = self._sock.getsockname()[1]
            self.station_source = f"tcp:127.0.0.1:{self.port}"

    # -- lifecycle ---------------------------------------------------------------------

    def start(self) -> Self:
        for target, name in ((self._send_loop, "send"), (self._recv_loop, "recv")):
            t = threading.Thread(target=target, name=f"mav-vehicle-{name}", daemon=True)
            t.start()
            self._threads.append(t)
        return self

    def stop(self) -> None:
        self._stop.set()
        for t in self._threads:
            t.join(2)
        self.drop_connection()
        self._sock.close()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- what tests do -------------------------------------------------------------------

    def arm(self) -> None:
        self.armed = True
        self.send_now("HEARTBEAT")

    def disarm(self) -> None:
        self.armed = False
        self.send_now("HEARTBEAT")

    def set_mode(self, name: str) -> None:
        self.mode = name
        self.send_now("HEARTBEAT")

    def inject(self, data: bytes) -> None:
        """Raw bytes onto the wire (garbage, corrupted packets)."""
        self._write(data)

    def skip_seq(self, n: int) -> None:
        """Pretend `n` packets were lost on the way: advance the sequence number."""
        with self._lock:
            self.mav.seq = (self.mav.seq + n) % 256

    def send_message(self, msg: mavlink.MAVLink_message) -> bytes:
        # Written under the lock too: an autopilot sends its packets in sequence order. Two
        # threads (the send loop and an ACK from the receive loop) writing outside it could
        # swap two packets on the wire, which the station rightly counts as 255 lost.
        with self._lock:
            buf = msg.pack(self.mav, force_mavlink1=self.mavlink1)
            self.mav.seq = (self.mav.seq + 1) % 256
            self._write(buf)
        self.sent[msg.get_type()] += 1
        return buf

    def send_raw(self, packet_of_seq: Callable[[int], bytes]) -> None:
        """A packet built by hand (`packet_of_seq(seq)`), in sequence with the rest."""
        with self._lock:
            self._write(packet_of_seq(self.mav.seq))
            self.mav.seq = (self.mav.seq + 1) % 256

    def send_now(self, name: str) -> bytes:
        return self.send_message(self.build(name))

    def drop_connection(self) -> None:
        """TCP: close the station's connection (it must reconnect)."""
        conn, self._conn = self._conn, None
        if conn is not None:
            try:
                conn.close()
            except OSError:
                pass

    @staticmethod
    def signed(msg: mavlink.MAVLink_message) -> bool:
        """The packet carried a signature pymavlink found good with our key."""
        return bool(msg.get_signed())

    def received_types(self) -> list[str]:
        return [m.get_type() for m in list(self.received)]

    # -- messages ----------------------------------------------------------------------

    def boot_s(self) -> float:
        """Its boot clock: `clock_rate` seconds per second since `boot_mono` (the
        host's monotonic time of its boot)."""
        return (time.monotonic() - self.boot_mono) * self.clock_rate

    def time_boot_ms(self) -> int:
        return int(self.boot_s() * 1000)

    def heartbeat(self) -> mavlink.MAVLink_message:
        armed = mavlink.MAV_MODE_FLAG_SAFETY_ARMED if self.armed else 0
        if self.autopilot == "px4":
            base, custom = px4_custom_mode(self.mode)
            ap = mavlink.MAV_AUTOPILOT_PX4
        elif self.autopilot == "ardupilot":
            base = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
            custom, ap = copter_custom_mode(self.mode), mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
        else:  # a radio, camera or other GCS: no autopilot
            return self.mav.heartbeat_encode(
                mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, mavlink.MAV_STATE_ACTIVE
            )
        status = mavlink.MAV_STATE_ACTIVE if self.armed else mavlink.MAV_STATE_STANDBY
        return self.mav.heartbeat_encode(
            mavlink.MAV_TYPE_QUADROTOR, ap, base | armed, custom, status
        )

    def autopilot_version(self) -> mavlink.MAVLink_message:
        """PX4 1.14.3 (git hash bytes, binary) or ArduCopter 4.5.7 (hash as text)."""
        if self.autopilot == "ardupilot":
            sw, custom = (4 << 24) | (5 << 16) | (7 << 8) | 255, list(b"2a3dc4b7")
        else:
            sw, custom = (1 << 24) | (14 << 16) | (3 << 8) | 255, [0x77, 0x17, 0, 0, 1, 2, 3, 4]
        return self.mav.autopilot_version_encode(
            0, sw, 0, 0, 0, custom, [0] * 8, [0] * 8, 0x26AC, 0x11, 0
        )

    def build(self, name: str) -> mavlink.MAVLink_message:
        m, t = self.mav, self.time_boot_ms()
        lat, lon = int(self.lat_deg * 1e7), int(self.lon_deg * 1e7)
        speed = math.hypot(self.vx_mps, self.vy_mps)
        if name == "HEARTBEAT":
            return self.heartbeat()
        if name == "ATTITUDE":
            return m.attitude_encode(
                t, self.roll_rad, self.pitch_rad, self.yaw_rad, 0.01, 0.02, 0.03
            )
        if name == "GLOBAL_POSITION_INT":
            return m.global_position_int_encode(
                t,
                lat,
                lon,
                int(self.alt_m * 1000),
                int(self.relative_alt_m * 1000),
                int(self.vx_mps * 100),
                int(self.vy_mps * 100),
                int(self.vz_mps * 100),
                int(math.degrees(self.yaw_rad) % 360 * 100),
            )
        if name == "GPS_RAW_INT":
            return m.gps_raw_int_encode(
                t * 1000,
                self.fix_type,
                lat,
                lon,
                int(self.alt_m * 1000),
                80,
                120,
                int(speed * 100),
                9000,
                self.satellites,
            )
        if name == "VFR_HUD":
            return m.vfr_hud_encode(
                speed, speed, int(math.degrees(self.yaw_rad)) % 360, 50, self.alt_m, -self.vz_mps
            )
        if name == "SYS_STATUS":
            return m.sys_status_encode(
                0,
                0,
                0,
                500,
                int(self.voltage_v * 1000),
                int(self.current_a * 100),
                self.remaining_pct,
                0,
                0,
                0,
                0,
                0,
                0,
            )
        if name == "BATTERY_STATUS":
            cells = [int(self.voltage_v * 1000 / 3)] * 3 + [65535] * 7
            return m.battery_status_encode(
                0,
                0,
                0,
                2500,
                cells,
                int(self.current_a * 100),
                -1 if self.consumed_mah is None else int(self.consumed_mah),
                -1,
                self.remaining_pct,
            )
        if name == "RC_CHANNELS":
            return m.rc_channels_encode(t, 8, *self.rc_pwm, 200)
        if name == "SERVO_OUTPUT_RAW":
            return m.servo_output_raw_encode(t * 1000, 0, *self.servo_pwm)
        if name == "LOCAL_POSITION_NED":
            return m.local_position_ned_encode(
                t, 1.0, 2.0, -self.relative_alt_m, self.vx_mps, self.vy_mps, self.vz_mps
            )
        if name == "SYSTEM_TIME":
            off = self.gps_utc_offset_s
            return m.system_time_encode(0 if off is None else int((time.time() + off) * 1e6), t)
        extra = self._build_px4_extra(name, t, lat, lon)
        if extra is None:
            raise ValueError(f"MavVehicle cannot build {name}")
        return extra

    def _build_px4_extra(
        self, name: str, t: int, lat: int, lon: int
    ) -> mavlink.MAVLink_message | None:
        """The streams of PX4_ONBOARD_RATES_HZ that the station does not ask for: plausible
        values, for their cost to the station (it does not read them)."""
        m, us = self.mav, t * 1000
        q = [1.0, 0.0, 0.0, 0.0]
        alt_mm, rel = int(self.alt_m * 1000), self.relative_alt_m
        v = (self.vx_mps, self.vy_mps, self.vz_mps)
        match name:
            case "ALTITUDE":
                return m.altitude_encode(us, self.alt_m, self.alt_m, rel, rel, -1, -1)
            case "ATTITUDE_QUATERNION":
                return m.attitude_quaternion_encode(t, *q, 0.01, 0.02, 0.03, q)
            case "ATTITUDE_TARGET":
                return m.attitude_target_encode(t, 0, q, 0.0, 0.0, 0.0, 0.5)
            case "ESTIMATOR_STATUS":
                return m.estimator_status_encode(us, 831, 0.1, 0.1, 0.1, 0.1, 0.0, 0.0, 0.5, 0.8)
            case "EXTENDED_SYS_STATE":
                return m.extended_sys_state_encode(0, 2 if self.armed else 1)
            case "HIGHRES_IMU":
                return m.highres_imu_encode(
                    us,
                    0.01,
                    -0.02,
                    -9.81,
                    0.001,
                    0.002,
                    0.003,
                    0.2,
                    0.0,
                    0.4,
                    1000.0,
                    0.0,
                    self.alt_m,
                    35.0,
                    0x1FFF,
                    0,
                )
            case "HOME_POSITION":
                return m.home_position_encode(lat, lon, alt_mm, 0.0, 0.0, 0.0, q, 0.0, 0.0, 0.0, us)
            case "NAV_CONTROLLER_OUTPUT":
                return m.nav_controller_output_encode(0.0, 0.0, 0, 0, 0, 0.0, 0.0, 0.0)
            case "ODOMETRY":
                return m.odometry_encode(
                    us,
                    1,
                    8,
                    1.0,
                    2.0,
                    -rel,
                    q,
                    *v,
                    0.0,
                    0.0,
                    0.0,
                    [float("nan")] * 21,
                    [float("nan")] * 21,
                    0,
                    2,
                    100,
                )
            case "PING":
                return m.ping_encode(us, t // 1000, 0, 0)
            case "POSITION_TARGET_GLOBAL_INT":
                return m.position_target_global_int_encode(
                    t, 6, 0, lat, lon, rel, *v, 0.0, 0.0, 0.0, self.yaw_rad, 0.0
                )
            case "POSITION_TARGET_LOCAL_NED":
                return m.position_target_local_ned_encode(
                    t, 1, 0, 1.0, 2.0, -rel, *v, 0.0, 0.0, 0.0, self.yaw_rad, 0.0
                )
            case "TIMESYNC":
                return m.timesync_encode(0, us * 1000)
            case "UTM_GLOBAL_POSITION":
                return m.utm_global_position_encode(
                    int(time.time() * 1e6),
                    [0] * 18,
                    lat,
                    lon,
                    alt_mm,
                    int(rel * 1000),
                    0,
                    0,
                    0,
                    500,
                    800,
                    100,
                    lat,
                    lon,
                    alt_mm,
                    100,
                    3,
                    0x3F,
                )
            case "WIND_COV":
                return m.wind_cov_encode(us, 0.5, 0.3, 0.0, 0.2, 0.2, self.alt_m, 1.0, 1.0)
            case _:
                return None

    # -- threads -------------------------------------------------------------------------

    def _write(self, data: bytes) -> None:
        try:
            if self.transport == "udp":
                if self.answer_sender:
                    if self.reply_to is not None:
                        self._sock.sendto(data, self.reply_to)
                else:
                    self._sock.sendto(data, ("127.0.0.1", self.station_port))
            elif self._conn is not None:
                self._conn.sendall(data)
        except OSError:
            self.drop_connection() if self.transport == "tcp" else None

    def _send_loop(self) -> None:
        due: dict[str, float] = {}
        last = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            if self.armed and self.consumed_mah is not None:  # mAh = A * s / 3.6
                self.consumed_mah += self.current_a * (now - last) / 3.6
            last = now
            for name, rate in list(self.rates_hz.items()):
                if rate <= 0:
                    continue
                t_due = due.setdefault(name, now)
                if now >= t_due:
                    due[name] = max(t_due + 1.0 / rate, now - 0.5)
                    if not self.silent:
                        self.send_now(name)
            nxt = min(
                (due.get(n, now) for n, r in self.rates_hz.items() if r > 0), default=now + 0.05
            )
            self._stop.wait(min(max(nxt - time.monotonic(), 0.0), 0.05))

    def _recv_loop(self) -> None:
        while not self._stop.is_set():
            try:
                if self.transport == "udp":
                    data, addr = self._sock.recvfrom(65535)
                    if self.answer_sender:
                        self.reply_to = addr
                elif self._conn is None:
                    conn, _ = self._sock.accept()
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    conn.settimeout(0.05)
                    self._conn = conn
                    continue
                else:
                    data = self._conn.recv(65535)
                    if not data:
                        self.drop_connection()
                        continue
            except (TimeoutError, BlockingIOError):
                continue
            except OSError:
                if self.transport == "tcp":
                    self.drop_connection()
                    continue
                return
            for msg in self._parser.parse_buffer(data) or []:
                if msg.get_type() != "BAD_DATA":
                    self.received.append(msg)
                    self._handle(msg)

    def _handle(self, msg: mavlink.MAVLink_message) -> None:
        if msg.get_type() == "TIMESYNC":
            autopilot = (
                self.compid == mavlink.MAV_COMP_ID_AUTOPILOT1 and self.autopilot != "invalid"
            )
            if msg.tc1 == 0 and self.timesync != "none" and autopilot:  # not a radio's
                tc1 = int(self.boot_s() * 1e9)
                if self.timesync == "untargeted" or self.mavlink1 or self.mav.signing.sign_outgoing:
                    self.send_message(self.mav.timesync_encode(tc1, msg.ts1))
                else:
                    to = (msg.get_srcSystem(), msg.get_srcComponent())
                    self.send_raw(timesync_v2(self.mav, tc1, msg.ts1, *to))
            return
        if (
            msg.get_type() == "COMMAND_LONG"
            and msg.command == mavlink.MAV_CMD_REQUEST_MESSAGE
            and int(msg.param1) == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION
        ):
            self.send_message(self.mav.command_ack_encode(msg.command, mavlink.MAV_RESULT_ACCEPTED))
            self.send_message(self.autopilot_version())
            return
        if msg.get_type() == "COMMAND_LONG" and msg.command != mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            self._answer_command(msg)
            return
        if msg.get_type() != "COMMAND_LONG":
            return
        if self.interval_reply == "ignore":
            return
        result = mavlink.MAV_RESULT_ACCEPTED
        if self.interval_reply == "unsupported":
            result = mavlink.MAV_RESULT_UNSUPPORTED
        else:
            name = mavlink.mavlink_map[int(msg.param1)].msgname
            if msg.param2 > 0:
                self.rates_hz[name] = 1e6 / msg.param2
        self.send_message(self.mav.command_ack_encode(msg.command, result))

    def _answer_command(self, msg: mavlink.MAVLink_message) -> None:
        result = self.command_results.get(msg.command)
        if result is None:
            return
        if self.commands_lost > 0:  # lost on the way: never heard, never answered
            self.commands_lost -= 1
            return
        if msg.confirmation > 0 and self.repeat_result is not None:
            result = self.repeat_result
        answer = []
        text = self.command_texts.get(msg.command)
        if text:
            answer.append(self.mav.statustext_encode(mavlink.MAV_SEVERITY_WARNING, text.encode()))
        answer.append(
            self.mav.command_ack_encode(
                msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )
        )
        if self.commands_held > 0:
            self.commands_held -= 1
            self._held.extend(answer)
            return
        for m in self._held + answer:
            self.send_message(m)
        self._held = []


@contextlib.contextmanager
def running_link(source, **kw):
    """The station's MavlinkLink to `source` (a MavVehicle's `station_source`, say),
    started; it notices a lost link after 1.5 s and retries every 0.2 s unless told."""
    kw.setdefault("link_lost_s", 1.5)
    kw.setdefault("reconnect_s", 0.2)
    link = MavlinkLink(LinkSettings(source=source, **kw))
    link.start()
    try:
        yield link
    finally:
        link.stop()
