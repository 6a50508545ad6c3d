"""Merge decoded MAVLink messages into the autopilot's `VehicleState`. Pure: no sockets.

A link carries several systems (the autopilot, a telemetry radio, other ground
stations, cameras). The tracker follows one autopilot: the sysid pinned in the
settings, or the first system whose HEARTBEAT names a real autopilot. Messages from
anyone else are ignored. Every update builds new frozen groups, and `state` is a new
frozen `VehicleState` after a change (sharing the unchanged groups), so a published state
never changes under a reader.
"""

from __future__ import annotations

from collections import deque
from operator import attrgetter
from typing import NamedTuple

from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.vehicle_state import (
    MESSAGES_KEPT,
    UTC_PLAUSIBLE_AFTER_S,
    GlobalPosition,
    GpsRaw,
    VehicleMessage,
    VehicleState,
    freeze_draft,
    quick_replace,
    unfrozen_twin,
)
from fpv_station.core.mavlink.ardupilot_modes import ardupilot_mode_name
from fpv_station.core.mavlink.framing import packet_version
from fpv_station.core.mavlink.px4_modes import px4_main_sub, px4_mode_name

_AUTOPILOT_NAMES = {
    mavlink.MAV_AUTOPILOT_PX4: "px4",
    mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA: "ardupilot",
    mavlink.MAV_AUTOPILOT_GENERIC: "generic",
}
_GPS_3D_FIX = 3
# The station's own housekeeping (stream rates), not something a person asked for.
_QUIET_ACKS = {mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mavlink.MAV_CMD_REQUEST_MESSAGE}
_GROUND_FIX_MAX_AGE_S = 2.5  # older than this (a gap in heartbeats): not "a moment ago"
_UINT16_UNKNOWN = 65535
# ArduPilot's altitude frame moves when its EKF origin is set ("EKF3 IMU0 Origin set to
# GPS", "EKF2 IMU0 origin set"): GLOBAL_POSITION_INT jumps from near 0 to the true AMSL
# altitude (93 m, 589 m on real logs). A step this fast is no flight: the frame changed.
_JUMP_MIN_M = 20.0
_JUMP_MIN_MPS = 100.0
# Just after the autopilot said its origin was set, a smaller sudden step is the frame too.
_ORIGIN_WINDOW_S = 10.0
_ORIGIN_STEP_MIN_M = 2.0
_ORIGIN_STEP_MIN_MPS = 20.0
# Fused and GPS altitude (both AMSL) further apart than this: not the same frame (GPS
# vertical error is metres, barometric drift over a flight some 10 m).
_DISAGREE_M = 40.0
_FRESH_GPS_S = 2.0
# Old firmware (2013 ArduCopter) puts its GPS altitude in GLOBAL_POSITION_INT `alt` and
# its barometer's height in `relative_alt`. The two come from one estimator on every
# autopilot since (their difference, the home altitude, holds still on the ground); on
# the ground before arming, a difference that wanders by more than this is two sensors,
# and the flight's altitude is `relative_alt`'s.
_GROUND_WANDER_M = 1.0
_GROUND_WINDOW_S = 30.0
_HOME_STEP_M = 0.5  # relative_alt stepping this much while alt holds: the home moved
# ArduPilot, PX4 and INAV set their home where the vehicle arms, so `alt - relative_alt`
# just after arming is the altitude at arming in the autopilot's own frame, with what the
# arming itself moved (ArduPilot re-zeroes its barometer and height there). Taken as the
# zero when within this of the ground altitude a heartbeat earlier (a home elsewhere, set
# at power-on or by hand, is not the arming point).
_HOME_AT_ARMING_M = 1.0
# A `relative_alt` that has not moved from its value at arming while `alt` has moved
# this much is not filled in (a minimal autopilot's 0): back to `alt`.
_RELATIVE_FROZEN_M = 5.0
_SLIDE_MPS = 2.0  # offset changing faster than this after agreeing: the frame still moves


# A new reference (`_take_reference`) before there is an altitude to take: the values
# of the one before it no longer hold.
_NO_REFERENCE = {
    "relative_alt_m": None,
    "reference_alt_m": None,
    "retaken_because": None,
    "home_lat_deg": None,
    "home_lon_deg": None,
}

# SYSTEM_TIME is the autopilot's UTC; a Unix GPS_RAW_INT time only stands in without it.
_SYSTEM_TIME_PREFERRED_S = 10.0


def _plausible_utc(usec: int) -> bool:
    return UTC_PLAUSIBLE_AFTER_S <= usec * 1e-6 < 4_102_444_800.0  # before 2100


# A message updates its group with `quick_replace` (companion.vehicle_state: the
# `dataclasses.replace` of the fields it carries, built the quick way), never by building
# the group anew: a field another message sets (BATTERY_STATUS's `consumed_mah` in the
# group SYS_STATUS updates too) keeps its value. The tracker keeps its groups in a mutable
# draft of the state that `state` freezes when read after a change: one VehicleState per
# reader's look (the link's: one per wake-up), not one per group changed.
_StateDraft = unfrozen_twin(VehicleState)
# The channels as one tuple, read in C. SERVO_OUTPUT_RAW's servo9-16 are MAVLink 2
# extensions: the dialect's message has them (0) also when a MAVLink 1 packet lacks them.
_RC_PWM = attrgetter(*(f"chan{i}_raw" for i in range(1, 19)))
_SERVO_PWM = attrgetter(*(f"servo{i}_raw" for i in range(1, 17)))


def _enum_name(enum: str, value: int, prefix: str) -> str:
    entry = mavlink.enums.get(enum, {}).get(value)
    if entry is None:
        return f"{prefix}{value}" if prefix else str(value)
    name: str = entry.name
    return name.removeprefix(prefix).lower()


def mode_name(autopilot: int, vehicle_type: int, base_mode: int, custom_mode: int) -> str:
    """The flight mode in the autopilot family's own words (PX4 'POSCTL', ArduCopter
    'LOITER'): PX4's from core.mavlink.px4_modes, the others' from ArduPilot's tables per
    vehicle type (core.mavlink.ardupilot_modes), as pymavlink's mode_string_v10 names them."""
    if autopilot == mavlink.MAV_AUTOPILOT_PX4:
        return px4_mode_name(*px4_main_sub(custom_mode)) or "UNKNOWN"
    return ardupilot_mode_name(vehicle_type, base_mode, custom_mode)


def _home_moved(last: tuple[float, float, float], gp: GlobalPosition) -> bool:
    """Between the ground sample `last` (t, alt - relative_alt, relative_alt) and `gp`,
    the autopilot moved its home (set it at a GPS fix, or by hand): `relative_alt`
    stepped while `alt` held."""
    _, offset, rel = last
    if gp.alt_m is None or gp.relative_alt_m is None:
        return False
    d_rel = gp.relative_alt_m - rel
    d_alt = gp.alt_m - (offset + rel)
    return abs(d_rel) > _HOME_STEP_M and abs(d_alt) < abs(d_rel) / 2


class _GroundFix(NamedTuple):
    t_mono: float
    alt_m: float
    lat_deg: float | None
    lon_deg: float | None
    relative_alt_m: float | None


def _climb_m(old: GlobalPosition, new: GlobalPosition, dt_s: float) -> float:
    """How much the vehicle climbed between two positions by their `relative_alt`; 0
    when it is missing or moved faster than a vehicle climbs (the autopilot moved its
    home with the frame: then the whole step is the frame's)."""
    if old.relative_alt_m is None or new.relative_alt_m is None:
        return 0.0
    climb = new.relative_alt_m - old.relative_alt_m
    return climb if abs(climb) <= _ORIGIN_STEP_MIN_MPS * max(dt_s, 1e-3) else 0.0


def _scaled(value: int, scale: float, unknown: int | None = None) -> float | None:
    if unknown is not None and value == unknown:
        return None
    return value * scale


class StateTracker:
    """Holds the current `VehicleState`; `update` says whether a message changed it."""

    def __init__(self, sysid: int | None = None, gcs_sysid: int | None = None) -> None:
        self.pinned_sysid = sysid
        self.gcs_sysid = gcs_sysid  # acks to other ground stations are theirs, not ours
        self.sysid: int | None = sysid
        self.compid: int | None = None
        self._draft = _StateDraft()  # the groups as they are now: handlers store into it
        self._state = VehicleState()  # the draft frozen, as `state` last returned it
        self._changed = False  # the draft changed since
        self._gp_seen = False  # GLOBAL_POSITION_INT ever received (preferred altitude)
        # Where the vehicle stood at its last disarmed HEARTBEAT. Arming is only seen in
        # the next HEARTBEAT (1 Hz on PX4), by which time a quick pilot is already
        # climbing; the ground position one beat earlier is the truth.
        self._ground_fix: _GroundFix | None = None
        # (t_mono, alt - relative_alt, relative_alt) on the ground lately (disarmed)
        self._ground_offsets: deque[tuple[float, float, float]] = deque(maxlen=512)
        self._relative_reference_m: float | None = None  # relative_alt at the reference
        self._relative_moved = False  # relative_alt moved from it since
        self._home_check = False  # armed: the next position may give the home at arming
        self._origin_note_t: float | None = None  # when the autopilot said "origin set"
        # fused - GPS altitude when they began to disagree (a frame not anchored to GPS)
        self._frame_offset_m: float | None = None
        self._sliding: bool | None = None  # after agreeing again, still sliding into place

    @property
    def state(self) -> VehicleState:
        """The current state, frozen: a new object after each change, the same one until
        the next (built here, once for all the updates since the last look)."""
        if self._changed:
            self._changed = False
            self._state = freeze_draft(self._draft, VehicleState)
        return self._state

    def is_autopilot_heartbeat(self, msg: mavlink.MAVLink_message) -> bool:
        if msg.get_type() != "HEARTBEAT" or msg.autopilot == mavlink.MAV_AUTOPILOT_INVALID:
            return False
        if msg.type == mavlink.MAV_TYPE_GCS:
            return False
        if self.sysid is not None and msg.get_srcSystem() != self.sysid:
            return False
        return self.compid is None or msg.get_srcComponent() == self.compid

    def follows(self, msg: mavlink.MAVLink_message) -> bool:
        """`msg` comes from the autopilot followed (any sender before one is)."""
        sysid: int = msg.get_srcSystem()
        if self.compid is None:
            return self.sysid is None or sysid == self.sysid
        compid: int = msg.get_srcComponent()
        return sysid == self.sysid and compid == self.compid

    def update(self, msg: mavlink.MAVLink_message, t_mono: float) -> bool:
        mtype = msg.get_type()
        if mtype == "HEARTBEAT":
            if not self.is_autopilot_heartbeat(msg):
                return False
            self.sysid = msg.get_srcSystem()
            self.compid = msg.get_srcComponent()
            self._heartbeat(msg, t_mono)
            self._changed = True
            return True
        if self.compid is None or msg.get_srcSystem() != self.sysid:
            return False  # not (yet) the autopilot we follow
        if msg.get_srcComponent() != self.compid:
            return False
        handler = _HANDLERS.get(mtype)
        if handler is None:
            return False
        handler(self, msg, t_mono)
        self._changed = True
        return True

    def set_link_lost(self, lost: bool, t_mono: float, last_heartbeat_mono: float | None) -> bool:
        link = self._draft.link
        if link.link_lost == lost and link.last_heartbeat_mono == last_heartbeat_mono:
            return False
        self._draft.link = quick_replace(
            link,
            t_mono=t_mono if link.link_lost != lost else link.t_mono,
            link_lost=lost,
            last_heartbeat_mono=last_heartbeat_mono,
        )
        self._changed = True
        return True

    # -- one method per message family ---------------------------------------------

    def _heartbeat(self, m: mavlink.MAVLink_message, t: float) -> None:
        armed = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
        old = self._draft.heartbeat
        was_armed = old.armed
        # The flight timer (vehicle_state.Heartbeat): from this beat at arming, stopped at
        # the disarming beat and held until the next arming.
        since = t if armed and not was_armed else old.armed_since_mono
        armed_for = t - since if since is not None and (armed or was_armed) else old.armed_for_s
        hb = quick_replace(
            old,
            t_mono=t,
            sysid=m.get_srcSystem(),
            compid=m.get_srcComponent(),
            autopilot=_AUTOPILOT_NAMES.get(m.autopilot)
            or _enum_name("MAV_AUTOPILOT", m.autopilot, "MAV_AUTOPILOT_"),
            vehicle_type=_enum_name("MAV_TYPE", m.type, "MAV_TYPE_"),
            armed=armed,
            mode=mode_name(m.autopilot, m.type, m.base_mode, m.custom_mode),
            base_mode=m.base_mode,
            custom_mode=m.custom_mode,
            system_status=_enum_name("MAV_STATE", m.system_status, "MAV_STATE_").upper(),
            mavlink_version=packet_version(m),
            armed_since_mono=since,
            armed_for_s=armed_for,
        )
        self._draft.heartbeat = hb
        if armed and not was_armed:
            ground = self._ground_fix
            fresh = ground is not None and t - ground.t_mono <= _GROUND_FIX_MAX_AGE_S
            self._take_reference("arming", t, ground if fresh else None)
        if not armed:
            alt = self._current_alt_m()
            rel = self._draft.global_position.relative_alt_m if self._gp_seen else None
            self._ground_fix = (
                None if alt is None else _GroundFix(t, alt, *self._current_latlon(), rel)
            )

    def _gps_raw(self, m: mavlink.MAVLink_message, t: float) -> None:
        g = quick_replace(
            self._draft.gps,
            t_mono=t,
            time_usec=m.time_usec,
            fix_type=m.fix_type,
            satellites=None if m.satellites_visible == 255 else m.satellites_visible,
            lat_deg=m.lat * 1e-7,
            lon_deg=m.lon * 1e-7,
            alt_m=m.alt * 1e-3,
            eph_m=_scaled(m.eph, 0.01, _UINT16_UNKNOWN),
            epv_m=_scaled(m.epv, 0.01, _UINT16_UNKNOWN),
            h_acc_m=_scaled(getattr(m, "h_acc", 0) or 0, 1e-3, 0),
            ground_speed_mps=_scaled(m.vel, 0.01, _UINT16_UNKNOWN),
            course_deg=_scaled(m.cog, 0.01, _UINT16_UNKNOWN),
        )
        self._draft.gps = g
        utc = self._draft.utc
        if (
            m.fix_type >= 2
            and _plausible_utc(m.time_usec)
            and (utc.source != "SYSTEM_TIME" or t - (utc.t_mono or t) > _SYSTEM_TIME_PREFERRED_S)
        ):
            self._draft.utc = quick_replace(
                utc, t_mono=t, unix_s=m.time_usec * 1e-6, source="GPS_RAW_INT"
            )
        if not self._gp_seen:
            self._altitude_changed(t)

    def _system_time(self, m: mavlink.MAVLink_message, t: float) -> None:
        # 0 (or a time in 1970) until the autopilot's clock is set, from its GPS.
        if _plausible_utc(m.time_unix_usec):
            self._draft.utc = quick_replace(
                self._draft.utc, t_mono=t, unix_s=m.time_unix_usec * 1e-6, source="SYSTEM_TIME"
            )

    def _global_position(self, m: mavlink.MAVLink_message, t: float) -> None:
        old_alt = self._current_alt_m()
        old_gp = self._draft.global_position
        gp = quick_replace(
            old_gp,
            t_mono=t,
            time_boot_ms=m.time_boot_ms,
            lat_deg=m.lat * 1e-7,
            lon_deg=m.lon * 1e-7,
            alt_m=m.alt * 1e-3,
            relative_alt_m=m.relative_alt * 1e-3,
            vx_mps=m.vx * 0.01,
            vy_mps=m.vy * 0.01,
            vz_mps=m.vz * 0.01,
            heading_deg=_scaled(m.hdg, 0.01, _UINT16_UNKNOWN),
        )
        self._draft.global_position = gp
        if not self._gp_seen:
            self._gp_seen = True
            alt = self._draft.altitude
            if alt.reference_alt_m is not None and old_alt is not None:
                # Switching from GPS to fused altitude: keep the pilot's value continuous.
                self._draft.altitude = quick_replace(
                    alt, reference_alt_m=alt.reference_alt_m + gp.alt_m - old_alt
                )
        else:
            self._check_altitude_frame(old_gp, gp, t)
        if self._home_check and self._draft.heartbeat.armed:
            self._home_check = False
            self._take_home_at_arming(gp)
        if not self._draft.heartbeat.armed and gp.alt_m is not None:
            offsets = self._ground_offsets
            if offsets and _home_moved(offsets[-1], gp):
                offsets.clear()  # one step of the home is no wander
            offsets.append((t, gp.alt_m - gp.relative_alt_m, gp.relative_alt_m))
            while offsets and t - offsets[0][0] > _GROUND_WINDOW_S:
                offsets.popleft()
        self._altitude_changed(t)

    def _statustext(self, m: mavlink.MAVLink_message, t: float) -> None:
        text = m.text if isinstance(m.text, str) else bytes(m.text).decode("utf-8", "replace")
        text = text.rstrip("\x00")
        if "origin set" in text.lower():  # EKF2/EKF3 "IMU0 Origin set to GPS" and kin
            self._origin_note_t = t
        self._add_message(VehicleMessage(t, "statustext", int(m.severity), text))

    def _command_ack(self, m: mavlink.MAVLink_message, t: float) -> None:
        if m.command in _QUIET_ACKS:
            return
        target = getattr(m, "target_system", 0)  # MAVLink 1 acks carry no target
        if target and self.gcs_sysid is not None and target != self.gcs_sysid:
            return
        command = _enum_name("MAV_CMD", m.command, "MAV_CMD_").upper()
        result = _enum_name("MAV_RESULT", m.result, "MAV_RESULT_").upper()
        ok = m.result in (mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_IN_PROGRESS)
        severity = mavlink.MAV_SEVERITY_INFO if ok else mavlink.MAV_SEVERITY_WARNING
        message = VehicleMessage(
            t, "command_ack", severity, f"{command}: {result}", command, result
        )
        self._add_message(message)

    def _add_message(self, message: VehicleMessage) -> None:
        old = self._draft.messages
        recent = (*old.recent[-(MESSAGES_KEPT - 1) :], message)
        self._draft.messages = quick_replace(
            old, t_mono=message.t_mono, count=old.count + 1, recent=recent
        )

    def _vfr_hud(self, m: mavlink.MAVLink_message, t: float) -> None:
        hud = quick_replace(
            self._draft.vfr_hud,
            t_mono=t,
            ground_speed_mps=m.groundspeed,
            airspeed_mps=m.airspeed,
            climb_mps=m.climb,
            heading_deg=float(m.heading),
            throttle_pct=float(m.throttle),
            alt_m=m.alt,
        )
        self._draft.vfr_hud = hud

    def _attitude(self, m: mavlink.MAVLink_message, t: float) -> None:
        att = quick_replace(
            self._draft.attitude,
            t_mono=t,
            time_boot_ms=m.time_boot_ms,
            roll_rad=m.roll,
            pitch_rad=m.pitch,
            yaw_rad=m.yaw,
            rollspeed_rad_s=m.rollspeed,
            pitchspeed_rad_s=m.pitchspeed,
            yawspeed_rad_s=m.yawspeed,
        )
        self._draft.attitude = att

    def _rc_channels(self, m: mavlink.MAVLink_message, t: float) -> None:
        pwm = _RC_PWM(m)
        rc = quick_replace(
            self._draft.rc,
            t_mono=t,
            time_boot_ms=m.time_boot_ms,
            chancount=m.chancount,
            pwm_us=pwm,
            rssi=None if m.rssi == 255 else m.rssi,
        )
        self._draft.rc = rc

    def _servo_output(self, m: mavlink.MAVLink_message, t: float) -> None:
        pwm = _SERVO_PWM(m)
        servo = quick_replace(
            self._draft.servo, t_mono=t, time_usec=m.time_usec, port=m.port, pwm_us=pwm
        )
        self._draft.servo = servo

    def _sys_status(self, m: mavlink.MAVLink_message, t: float) -> None:
        b = self._draft.battery
        # A vehicle with no battery monitor sends 0 mV (and 0 A), not the "unknown" value:
        # no flying pack reads 0 V, so 0 means unknown, and its current with it.
        no_monitor = m.voltage_battery == 0
        self._draft.battery = quick_replace(
            b,
            t_mono=t,
            voltage_v=None if no_monitor else _scaled(m.voltage_battery, 1e-3, _UINT16_UNKNOWN),
            current_a=None
            if m.current_battery == -1 or (no_monitor and m.current_battery == 0)
            else m.current_battery * 0.01,
            remaining_pct=float(m.battery_remaining)
            if m.battery_remaining != -1
            else b.remaining_pct,
        )

    def _battery_status(self, m: mavlink.MAVLink_message, t: float) -> None:
        if m.id != 0:  # the first battery is the flight pack; SYS_STATUS mirrors it
            return
        cells_mv = [v for v in m.voltages if v != _UINT16_UNKNOWN]
        if not any(cells_mv):  # 0 mV: no monitor (as in SYS_STATUS), not an empty pack
            cells_mv = []
        b = self._draft.battery
        self._draft.battery = quick_replace(
            b,
            t_mono=t,
            voltage_v=sum(cells_mv) * 1e-3 if cells_mv else b.voltage_v,
            current_a=m.current_battery * 0.01 if m.current_battery != -1 else b.current_a,
            remaining_pct=float(m.battery_remaining)
            if m.battery_remaining != -1
            else b.remaining_pct,
            consumed_mah=None if m.current_consumed == -1 else float(m.current_consumed),
        )

    def _local_position(self, m: mavlink.MAVLink_message, t: float) -> None:
        lp = quick_replace(
            self._draft.local_position,
            t_mono=t,
            time_boot_ms=m.time_boot_ms,
            x_m=m.x,
            y_m=m.y,
            z_m=m.z,
            vx_mps=m.vx,
            vy_mps=m.vy,
            vz_mps=m.vz,
        )
        self._draft.local_position = lp

    # -- the pilot's altitude (paper: relative to the altitude at arming) ---------------

    def _current_alt_m(self) -> float | None:
        alt_m: float | None
        if self._gp_seen:
            alt_m = self._draft.global_position.alt_m
        else:
            gps = self._draft.gps
            alt_m = gps.alt_m if gps.fix_type >= _GPS_3D_FIX else None
        return alt_m

    def _current_latlon(self) -> tuple[float | None, float | None]:
        if self._gp_seen:
            gp = self._draft.global_position
            return gp.lat_deg, gp.lon_deg
        return self._draft.gps.lat_deg, self._draft.gps.lon_deg

    def _has_fix(self) -> bool:
        gps: GpsRaw = self._draft.gps
        if gps.t_mono is not None:
            return gps.fix_type >= _GPS_3D_FIX
        gp: GlobalPosition = self._draft.global_position  # no GPS_RAW_INT: a fused fix counts
        return gp.lat_deg not in (None, 0.0) or gp.lon_deg not in (None, 0.0)

    def _take_reference(self, reference: str, t: float, at: _GroundFix | None = None) -> None:
        """Make the altitude now (or `at`, where the vehicle stood a moment ago) the zero
        of the pilot's altitude, measured by `alt` or, at arming where the two disagree on
        the ground, by `relative_alt` (`_altitude_source`)."""
        alt: float | None
        if at is not None:
            alt, lat, lon, rel = at.alt_m, at.lat_deg, at.lon_deg, at.relative_alt_m
        else:
            alt = self._current_alt_m()
            lat, lon = self._current_latlon()
            rel = self._draft.global_position.relative_alt_m if self._gp_seen else None
        source = "alt"
        if reference == "arming" and rel is not None:
            source = self._altitude_source(at.t_mono if at is not None else t)
        self._relative_reference_m = rel if source == "relative_alt" else None
        self._relative_moved = False
        self._home_check = reference == "arming"
        if alt is None:
            # Armed before any altitude: take the reference at the first altitude.
            self._draft.altitude = quick_replace(
                self._draft.altitude, t_mono=t, reference=f"pending_{reference}", **_NO_REFERENCE
            )
            return
        self._draft.altitude = quick_replace(
            self._draft.altitude,
            t_mono=t,
            relative_alt_m=0.0,  # set from the altitude now by _altitude_changed
            reference_alt_m=alt,
            reference=reference,
            source=source,
            retaken_because=None,
            home_lat_deg=lat,
            home_lon_deg=lon,
        )
        self._altitude_changed(t)

    def _take_home_at_arming(self, gp: GlobalPosition) -> None:
        """The zero becomes the autopilot's home (`alt - relative_alt`, in the frame now)
        where that is the arming point: see _HOME_AT_ARMING_M."""
        pilot = self._draft.altitude
        if (
            pilot.source != "alt"
            or pilot.reference_alt_m is None
            or gp.alt_m is None
            or gp.relative_alt_m is None
        ):
            return
        home = gp.alt_m - gp.relative_alt_m
        if abs(home - pilot.reference_alt_m) <= _HOME_AT_ARMING_M:
            self._draft.altitude = quick_replace(pilot, reference_alt_m=home)

    def _altitude_source(self, until: float) -> str:
        """What measures the flight: "relative_alt" when `alt` and `relative_alt`
        disagreed on the ground lately (their difference wandered: old firmware's GPS
        altitude in `alt`) up to `until` (the last disarmed beat; after it a quick pilot
        may be climbing already), else "alt"."""
        offsets = [o for t, o, _ in self._ground_offsets if t <= until]
        if len(offsets) < 2:
            return "alt"
        return "relative_alt" if max(offsets) - min(offsets) > _GROUND_WANDER_M else "alt"

    def _check_altitude_frame(self, old: GlobalPosition, new: GlobalPosition, t: float) -> None:
        """Re-take the pilot's reference when the fused altitude changed frame (ArduPilot's
        EKF origin): a step no vehicle can fly, a sudden step just after "origin set", or
        fused and GPS altitude coming to agree after disagreeing. The reference moves by
        the frame's step, so the pilot's altitude stays continuous (a hop stays a hop).
        The step between two positions is the frame's plus what the vehicle climbed
        meanwhile (most of a metre between positions a second apart): `relative_alt`,
        which the origin does not move, says how much that was."""
        if old.alt_m is None or new.alt_m is None:
            return
        step = new.alt_m - old.alt_m
        if old.time_boot_ms is not None and new.time_boot_ms is not None:
            dt = (new.time_boot_ms - old.time_boot_ms) * 1e-3  # the vehicle's own clock
        else:
            dt = t - (old.t_mono if old.t_mono is not None else t)
        rate = abs(step) / max(dt, 1e-3)
        climb = _climb_m(old, new, dt)
        primed = self._origin_note_t is not None and t - self._origin_note_t <= _ORIGIN_WINDOW_S
        shift: float | None = None
        why = ""
        if abs(step) > _JUMP_MIN_M and rate > _JUMP_MIN_MPS:
            shift, why = step - climb, "EKF origin set" if primed else "altitude jump"
        elif primed and abs(step) > _ORIGIN_STEP_MIN_M and rate > _ORIGIN_STEP_MIN_MPS:
            shift, why = step - climb, "EKF origin set"
        gps = self._draft.gps
        fresh = (
            gps.t_mono is not None
            and gps.alt_m is not None
            and gps.fix_type >= _GPS_3D_FIX
            and abs(t - gps.t_mono) <= _FRESH_GPS_S
        )
        if fresh:
            offset = new.alt_m - gps.alt_m
            disagree = abs(offset) > _DISAGREE_M
            held = self._frame_offset_m
            if shift is None and held is not None and not disagree:
                moved = offset - held
                if self._sliding is None or abs(moved) > _SLIDE_MPS * max(dt, 1e-3):
                    # The frame moved by the change of their offset: since they began to
                    # disagree, then sample by sample while it still slides into place.
                    shift, why = moved, "GPS agrees again"
                    self._frame_offset_m, self._sliding = offset, True
                else:  # settled
                    self._frame_offset_m = self._sliding = None
            elif not disagree:
                self._frame_offset_m = self._sliding = None
            elif shift is not None or held is None:
                self._frame_offset_m = offset  # the frame as it is now (after a step, the new one)
                self._sliding = None
        if shift is not None:
            self._rebase(shift, why, t)

    def _rebase(self, shift_m: float, why: str, t: float) -> None:
        if self._ground_fix is not None:
            self._ground_fix = self._ground_fix._replace(alt_m=self._ground_fix.alt_m + shift_m)
        self._ground_offsets.clear()  # a frame's step is no wander
        alt = self._draft.altitude
        if alt.reference_alt_m is None:
            return
        self._origin_note_t = None  # this note has been acted on
        self._draft.altitude = quick_replace(
            alt,
            t_mono=t,
            reference_alt_m=alt.reference_alt_m + shift_m,
            reference=alt.reference.removesuffix("_retaken") + "_retaken",
            retaken_because=why,
        )

    def _altitude_changed(self, t: float) -> None:
        pilot = self._draft.altitude
        if pilot.reference.startswith("pending_"):
            if self._current_alt_m() is not None:
                self._take_reference(pilot.reference.removeprefix("pending_"), t)
            return
        if pilot.reference == "none":
            if self._has_fix() and self._current_alt_m() is not None:
                self._take_reference("first_fix", t)
            return
        alt = self._current_alt_m()
        if self._relative_reference_m is not None and pilot.source == "relative_alt":
            rel = self._draft.global_position.relative_alt_m
            self._relative_moved |= rel != self._relative_reference_m
            frozen = (
                not self._relative_moved
                and alt is not None
                and pilot.reference_alt_m is not None
                and abs(alt - pilot.reference_alt_m) > _RELATIVE_FROZEN_M
            )
            if not frozen and rel is not None:
                self._draft.altitude = quick_replace(
                    pilot, t_mono=t, relative_alt_m=rel - self._relative_reference_m
                )
                return
            self._relative_reference_m = None
            pilot = self._draft.altitude = quick_replace(pilot, source="alt")
        if alt is None or pilot.reference_alt_m is None:
            return
        self._draft.altitude = quick_replace(
            pilot, t_mono=t, relative_alt_m=alt - pilot.reference_alt_m
        )


_HANDLERS = {
    "COMMAND_ACK": StateTracker._command_ack,
    "GPS_RAW_INT": StateTracker._gps_raw,
    "GLOBAL_POSITION_INT": StateTracker._global_position,
    "VFR_HUD": StateTracker._vfr_hud,
    "ATTITUDE": StateTracker._attitude,
    "RC_CHANNELS": StateTracker._rc_channels,
    "SERVO_OUTPUT_RAW": StateTracker._servo_output,
    "SYS_STATUS": StateTracker._sys_status,
    "BATTERY_STATUS": StateTracker._battery_status,
    "LOCAL_POSITION_NED": StateTracker._local_position,
    "STATUSTEXT": StateTracker._statustext,
    "SYSTEM_TIME": StateTracker._system_time,
}
