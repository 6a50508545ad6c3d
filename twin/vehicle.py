"""The twin as a MAVLink vehicle: PX4 identity and mode encoding, Pixhawk-like telemetry
rates, and the commands a ground station or a pilot's radio sends: arming, modes,
take-off, landing, DO_REPOSITION (COMMAND_LONG or COMMAND_INT), the mission protocol
(`twin.mission_protocol`) and AUTO.MISSION flights (`twin.mission`).

Take-off altitude: PX4's MAV_CMD_NAV_TAKEOFF takes param7 above mean sea level, and
QGroundControl sends home + height to PX4; ArduPilot's ground stations (MAVProxy's
"takeoff 10", Mission Planner, QGroundControl on ArduPilot) send the height above home.
In COMMAND_INT the frame says which. In COMMAND_LONG, a value below home's altitude
cannot be an altitude above sea level to climb to, so it is read as the height above
home; any other value as above sea level (ambiguous only on a field whose home is lower
than the requested height above it, i.e. near sea level).

It owns one UDP socket (`udpout:HOST:PORT` sends to a ground station as PX4 SITL does;
`udpin:HOST:PORT` listens and answers whoever spoke last) and pymavlink's MAVLink 2
encoder/parser. It is driven by `poll(sim)` from the twin's thread, never blocks, and
counts what it cannot parse instead of failing.

With a signing key it behaves as a Pixhawk set up with MAVProxy's `signing setup`: it
signs all it sends and obeys only packets signed with the key (`core.mavlink.signing`;
`signing.counts` says what it refused), so that signing can be tested end to end.
"""

from __future__ import annotations

import logging
import math
import socket
from dataclasses import dataclass

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.core.mavlink.px4_modes import (
    AUTO_MAIN_MODE,
    PX4_MODES,
    px4_main_sub,
    px4_mode_name,
)
from fpv_station.core.mavlink.signing import SignatureCheck, enable_signing
from fpv_station.twin.control import AUTO_LOITER, AUTO_MISSION
from fpv_station.twin.log_server import LOG_MESSAGES, LogServer
from fpv_station.twin.mission import (
    AMSL_FRAMES,
    RELATIVE_FRAMES,
    MissionRunner,
    target_enu,
    up_m,
)
from fpv_station.twin.mission_protocol import MissionProtocol
from fpv_station.twin.params import ParamServer, px4_params
from fpv_station.twin.sim import MODE_BY_NAME, Sim
from fpv_station.twin.telemetry import Telemetry

log = logging.getLogger(__name__)


# Telemetry rates (Hz), close to PX4's defaults on a companion (onboard) link.
DEFAULT_RATES_HZ = {
    "HEARTBEAT": 1.0,
    "SYS_STATUS": 2.0,
    "BATTERY_STATUS": 1.0,
    "GPS_RAW_INT": 5.0,
    "GLOBAL_POSITION_INT": 10.0,
    "LOCAL_POSITION_NED": 10.0,
    "ATTITUDE": 20.0,
    "VFR_HUD": 10.0,
    "RC_CHANNELS": 10.0,
    "SERVO_OUTPUT_RAW": 10.0,
    "EXTENDED_SYS_STATE": 1.0,
    "HOME_POSITION": 0.5,
    "MISSION_CURRENT": 1.0,
    "SYSTEM_TIME": 1.0,
}
STICK_TIMEOUT_S = 1.0  # no MANUAL_CONTROL/override for this long = sticks centred
_MISSION_MESSAGES = frozenset(
    {
        "MISSION_REQUEST_LIST",
        "MISSION_REQUEST_INT",
        "MISSION_REQUEST",
        "MISSION_COUNT",
        "MISSION_ITEM_INT",
        "MISSION_ITEM",
        "MISSION_ACK",
        "MISSION_CLEAR_ALL",
        "MISSION_SET_CURRENT",
    }
)
_INT32_UNSET = 2**31 - 1  # COMMAND_INT x/y "not given"


@dataclass(frozen=True)
class CommandArgs:
    """COMMAND_LONG and COMMAND_INT in one shape: params 5-7 are x, y, z (degrees for a
    COMMAND_INT's global frames); `frame` is None for COMMAND_LONG, which has none."""

    command: int
    params: tuple[float, float, float, float, float, float, float]
    frame: int | None

    @staticmethod
    def of(msg) -> CommandArgs:
        if msg.get_type() == "COMMAND_LONG":
            p = (msg.param1, msg.param2, msg.param3, msg.param4, msg.param5, msg.param6)
            return CommandArgs(msg.command, (*p, msg.param7), None)
        scale = 1e-7 if msg.frame in AMSL_FRAMES | RELATIVE_FRAMES else 1.0

        def xy(v: int) -> float:
            return math.nan if v == _INT32_UNSET else v * scale

        p4 = (msg.param1, msg.param2, msg.param3, msg.param4)
        return CommandArgs(msg.command, (*p4, xy(msg.x), xy(msg.y), msg.z), msg.frame)


@dataclass
class VehicleStats:
    sent: int = 0
    received: int = 0
    bad: int = 0
    send_errors: int = 0
    last_input_s: float = -1e9


class MavlinkVehicle:
    def __init__(
        self,
        connection: str,
        rates_hz: dict[str, float] | None = None,
        sysid: int = 1,
        compid: int = 1,
        signing_key: bytes | None = None,
    ) -> None:
        self.sysid, self.compid = sysid, compid
        self.sock, self._peer = self._open(connection)
        self._listening = self._peer is None  # udpin: answer whoever spoke last
        self.mav = mavlink.MAVLink(self, srcSystem=sysid, srcComponent=compid)  # encoder
        # A parser of its own: the encoder's key must never reach pymavlink's decoder.
        self._parser = mavlink.MAVLink(None)
        self._parser.robust_parsing = True
        self.signing: SignatureCheck | None = (
            enable_signing(self.mav, signing_key) if signing_key else None
        )
        self.defaults_hz = dict(DEFAULT_RATES_HZ)
        self.defaults_hz.update(rates_hz or {})
        self.interval_s = {k: (1.0 / v if v > 0 else None) for k, v in self.defaults_hz.items()}
        self._next_s: dict[str, float] = dict.fromkeys(self.interval_s, 0.0)
        self.stats = VehicleStats()
        self.telemetry = Telemetry(self.mav)
        self.params: ParamServer | None = None  # built from the sim's config on first use
        self.logs: LogServer | None = None  # the flight logs' server, when the twin logs
        self._pending_once: list[str] = []
        self._last_poll_s = 0.0
        self.mission = MissionRunner(
            reached=lambda seq: self.mav.mission_item_reached_send(seq),
            current_changed=lambda seq: self._pending_once.append("MISSION_CURRENT"),
            say=lambda text: self.mav.statustext_send(mavlink.MAV_SEVERITY_INFO, text.encode()),
        )
        self.mission_protocol = MissionProtocol(
            self.mav,
            get_items=lambda: self.mission.items,
            set_items=self.mission.load,
            set_current=self.mission.set_current,
        )

    @staticmethod
    def _open(connection: str) -> tuple[socket.socket, tuple[str, int] | None]:
        kind, _, rest = connection.partition(":")
        host, _, port = rest.rpartition(":")
        if kind not in ("udpout", "udpin") or not port.isdigit():
            raise ValueError(
                f"MAVLink connection '{connection}' is not udpout:HOST:PORT or udpin:HOST:PORT."
            )
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.setblocking(False)
        if kind == "udpin":
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host or "0.0.0.0", int(port)))
            return sock, None
        return sock, (host or "127.0.0.1", int(port))

    def close(self) -> None:
        self.sock.close()

    # pymavlink's encoder writes through this file-like method.
    def write(self, data: bytes) -> None:
        if self._peer is None:
            return
        try:
            self.sock.sendto(data, self._peer)
            self.stats.sent += 1
        except OSError as exc:  # no listener yet (ICMP refused), network down: keep flying
            self.stats.send_errors += 1
            log.debug("twin MAVLink send failed: %s", exc)

    # ---- the loop body ----
    def poll(self, sim: Sim, now_s: float) -> None:
        """Handle what arrived, then send whatever telemetry is due at sim time `now_s`."""
        for _ in range(200):  # bounded per tick; the rest waits in the socket buffer
            try:
                data, addr = self.sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                break
            except OSError:  # e.g. ICMP port unreachable surfacing on Linux
                continue
            # Signing on: only a sender that signed with the key is answered from now on
            # (a refused datagram must not turn the telemetry to its sender).
            if self._listening and self.signing is None:
                self._peer = addr
            parser = self._parser
            for msg in parser.parse_buffer(data) or []:
                if msg.get_type() == "BAD_DATA":
                    self.stats.bad += 1
                    continue
                if self.signing is not None:
                    verdict = self.signing.check(msg.get_msgbuf())
                    if verdict not in ("signed", "unsigned_allowed"):
                        continue  # counted in signing.counts
                    if verdict == "signed" and self._listening:
                        self._peer = addr
                self.stats.received += 1
                self._handle(sim, msg, now_s)
            if parser.buf_len():
                # A datagram holds whole packets: a truncated or bogus header must not
                # swallow the next datagram's packet.
                self.stats.bad += 1
                parser.buf, parser.buf_index = bytearray(), 0
                parser.expected_length = mavlink.HEADER_LEN_V1 + 2
        if now_s - self.stats.last_input_s > STICK_TIMEOUT_S and self.stats.last_input_s > -1e8:
            sim.set_sticks(0.0, 0.0, 0.0, 0.5)
            self.stats.last_input_s = -1e9
        self.mission_protocol.poll()
        if self.logs is not None:
            self.logs.poll()
        self.mission.update(sim, now_s, self._home_alt_m(sim))
        for event in sim.drain_events():
            self.mav.statustext_send(event.severity, event.text.encode()[:50])
        if now_s < self._last_poll_s:  # the sim clock went back: restart the schedule
            self._next_s = dict.fromkeys(self._next_s, now_s)
        self._last_poll_s = now_s
        for name in self._pending_once:
            self._send(sim, name, now_s)
        self._pending_once.clear()
        for name, interval in self.interval_s.items():
            if interval is not None and now_s >= self._next_s[name]:
                self._next_s[name] = max(self._next_s[name] + interval, now_s)
                self._send(sim, name, now_s)

    # ---- inputs ----
    def _handle(self, sim: Sim, msg, now_s: float) -> None:
        kind = msg.get_type()
        if kind == "MANUAL_CONTROL":
            if msg.target not in (0, self.sysid):
                return
            # PX4: x pitch (forward +), y roll (right +), z throttle 0..1000, r yaw.
            sim.set_sticks(msg.y / 1000.0, msg.x / 1000.0, msg.r / 1000.0, msg.z / 1000.0)
            self.stats.last_input_s = now_s
        elif kind == "RC_CHANNELS_OVERRIDE":
            if msg.target_system not in (0, self.sysid):
                return
            ch = [msg.chan1_raw, msg.chan2_raw, msg.chan3_raw, msg.chan4_raw]
            cur = sim.sticks[0]
            vals = [cur[0], cur[1], cur[3], cur[2]]  # AETR order: roll, pitch, throttle, yaw
            for k, pwm in enumerate(ch):
                if 800 <= pwm <= 2200:
                    vals[k] = (pwm - 1500) / 500.0 if k != 2 else (pwm - 1000) / 1000.0
            sim.set_sticks(vals[0], vals[1], vals[3], vals[2])
            self.stats.last_input_s = now_s
        elif kind in ("COMMAND_LONG", "COMMAND_INT"):
            if msg.target_system not in (0, self.sysid):
                return
            result, text = self._command(sim, CommandArgs.of(msg))
            if text:  # the reason first, then the ack, as PX4's commander does
                self.mav.statustext_send(mavlink.MAV_SEVERITY_WARNING, text.encode()[:50])
            self.mav.command_ack_send(
                msg.command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
            )
        elif kind in ("PARAM_REQUEST_LIST", "PARAM_REQUEST_READ", "PARAM_SET"):
            if getattr(msg, "target_system", 0) not in (0, self.sysid):
                return
            if self.params is None:
                self.params = ParamServer(self.mav, px4_params(sim.config, self.sysid))
            note = self.params.handle(msg)
            if note:
                self.mav.statustext_send(mavlink.MAV_SEVERITY_WARNING, note.encode()[:50])
        elif kind in _MISSION_MESSAGES:
            if msg.target_system not in (0, self.sysid):
                return
            self.mission_protocol.handle(msg)
        elif kind in LOG_MESSAGES:
            if self.logs is not None and msg.target_system in (0, self.sysid):
                self.logs.handle(msg)
        elif kind == "TIMESYNC":
            self._timesync(msg, now_s)
        elif kind == "SET_MODE":
            if msg.target_system not in (0, self.sysid):
                return
            ok, why = self._set_mode(sim, *px4_main_sub(msg.custom_mode))
            if not ok:
                self.mav.statustext_send(mavlink.MAV_SEVERITY_WARNING, why.encode()[:50])

    def _timesync(self, msg, now_s: float) -> None:
        """Answer a TIMESYNC request as PX4 does: `tc1` our boot clock (the sim's) in ns,
        `ts1` mirrored (to no one in particular: pymavlink's dialect has no target
        fields); answers to us (tc1 != 0) are not ours to use."""
        if msg.tc1 != 0:
            return
        self.mav.timesync_send(int(now_s * 1e9), msg.ts1)

    def _set_mode(self, sim: Sim, main: int, sub: int) -> tuple[bool, str]:
        # PX4's name for the pair, in the twin's words (MANUAL: a multicopter flies it
        # stabilized); AUTO without a sub mode holds position, as AUTO.LOITER.
        name = "LOITER" if (main, sub) == (AUTO_MAIN_MODE, 0) else px4_mode_name(main, sub)
        mode = MODE_BY_NAME.get(name or "")
        if mode is None:
            return False, f"unsupported mode {main}/{sub}"
        if mode == AUTO_MISSION and not self.mission.items:
            return False, "mission mode refused: no mission"
        if mode == MODE_BY_NAME["RTL"]:  # PX4: choosing Return mode starts the return
            return sim.return_to_launch()
        return sim.commander.request_mode(0, mode, sim.est_pos_m[0], sim.sensors.has_fix(sim.t_s))

    def _home_alt_m(self, sim: Sim) -> float:
        """PX4's home altitude (set on the ground at arming), the scene's before a fix."""
        return self.telemetry.home_alt_m or sim.scene.home.alt_m

    def _takeoff_height_m(self, sim: Sim, args: CommandArgs) -> float | None:
        """The take-off height above home that a ground station meant (module docstring)."""
        alt = args.params[6]
        if not math.isfinite(alt):
            return None
        home = self._home_alt_m(sim)
        if args.frame in RELATIVE_FRAMES:
            return alt
        if args.frame in AMSL_FRAMES or alt >= home:
            return alt - home
        return alt

    def _reposition(self, sim: Sim, args: CommandArgs) -> tuple[bool, str]:
        """MAV_CMD_DO_REPOSITION: hold (AUTO.LOITER) at the given place, as PX4 does; an
        unset (NaN) latitude/longitude or altitude keeps the current one."""
        com = sim.commander
        if not com.armed[0] or com.landed[0]:
            return False, "reposition refused: not flying"
        lat, lon, alt = args.params[4:7]
        frame = mavlink.MAV_FRAME_GLOBAL if args.frame is None else args.frame
        if frame not in AMSL_FRAMES | RELATIVE_FRAMES:
            return False, f"reposition refused: frame {frame}"
        pos = sim.est_pos_m[0]
        target = pos.copy()
        home = self._home_alt_m(sim)
        if math.isfinite(lat) and math.isfinite(lon):
            target[:2] = target_enu(sim, lat, lon, 0.0, frame, home)[:2]
        if math.isfinite(alt):
            target[2] = max(up_m(sim, alt, frame, home), 0.5)
        ok, why = com.request_mode(0, AUTO_LOITER, pos, sim.sensors.has_fix(sim.t_s))
        if ok:
            com.target_m[0] = target
        return ok, why

    def _command(self, sim: Sim, args: CommandArgs) -> tuple[int, str]:
        c, p = args.command, args.params
        ok_, fail = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED
        if c == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
            ok, why = sim.arm(p[0] > 0.5, force=int(p[1]) == 21196)
        elif c == mavlink.MAV_CMD_NAV_TAKEOFF:
            ok, why = sim.takeoff(self._takeoff_height_m(sim, args))
        elif c == mavlink.MAV_CMD_NAV_LAND:
            ok, why = sim.land()
        elif c == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            ok, why = sim.return_to_launch()  # AUTO.RTL, as PX4 (twin.commander)
        elif c == mavlink.MAV_CMD_DO_REPOSITION:
            ok, why = self._reposition(sim, args)
        elif c == mavlink.MAV_CMD_MISSION_START:
            first = int(p[0]) if math.isfinite(p[0]) and p[0] > 0 else self.mission.current
            if not self.mission.set_current(first):
                return fail, "mission start refused: no mission or no such item"
            ok, why = self._set_mode(sim, *PX4_MODES["MISSION"])
        elif c == mavlink.MAV_CMD_DO_SET_MISSION_CURRENT:
            ok, why = self.mission.set_current(int(p[0])), "no such mission item"
        elif c == mavlink.MAV_CMD_DO_SET_MODE:
            ok, why = self._set_mode(sim, int(p[1]), int(p[2]))
        elif c == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
            return self._set_interval(int(p[0]), p[1])
        elif c == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            self._pending_once.append("AUTOPILOT_VERSION")
            return ok_, ""
        elif c == mavlink.MAV_CMD_REQUEST_MESSAGE:
            name = _msg_name(int(p[0]))
            if name not in self.interval_s and name != "AUTOPILOT_VERSION":
                return fail, f"message {int(p[0])} not supported"
            self._pending_once.append(name)
            return ok_, ""
        else:
            return mavlink.MAV_RESULT_UNSUPPORTED, ""
        return (ok_ if ok else fail), ("" if ok else why)

    def _set_interval(self, msg_id: int, interval_us: float) -> tuple[int, str]:
        name = _msg_name(msg_id)
        if name not in self.interval_s:
            return mavlink.MAV_RESULT_DENIED, f"message {msg_id} not streamed"
        if interval_us < 0:
            self.interval_s[name] = None
        elif interval_us == 0:
            hz = self.defaults_hz.get(name, 0)
            self.interval_s[name] = 1.0 / hz if hz > 0 else None
        else:
            self.interval_s[name] = max(interval_us * 1e-6, 0.002)  # at most 500 Hz
        return mavlink.MAV_RESULT_ACCEPTED, ""

    # ---- outputs ----
    def _send(self, sim: Sim, name: str, now_s: float) -> None:
        if name == "MISSION_CURRENT":
            m = self.mission
            self.mav.mission_current_send(m.current, len(m.items))
            return
        self.telemetry.send(name, sim, int(now_s * 1000) & 0xFFFFFFFF)


def _msg_name(msg_id: int) -> str:
    cls = mavlink.mavlink_map.get(msg_id)
    return cls.msgname if cls is not None else f"#{msg_id}"
