"""The pure state tracker: real packets from pymavlink's encoder, decoded, merged."""

import dataclasses

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from fpv_station.companion.state_tracker import StateTracker
from fpv_station.companion.vehicle_state import MESSAGES_KEPT, VehicleState
from fpv_station.core.mavlink.framing import MavFramer
from fpv_station.twin.sensors import SensorParams
from fpv_station.twin.sim import Sim, SimConfig
from fpv_station.twin.telemetry import Telemetry
from tests.mav_vehicle import MavVehicle


class Feed:
    """Packs a vehicle's messages to bytes and feeds them through the framer."""

    def __init__(self, tracker: StateTracker, vehicle: MavVehicle):
        self.tracker, self.vehicle, self.framer, self.t = tracker, vehicle, MavFramer(), 100.0

    def __call__(self, *names: str) -> bool:
        changed = False
        for name in names:
            msg = self.vehicle.build(name)
            buf = msg.pack(self.vehicle.mav, force_mavlink1=self.vehicle.mavlink1)
            self.vehicle.mav.seq = (self.vehicle.mav.seq + 1) % 256
            self.t += 0.1
            for decoded in self.framer.feed(buf):
                changed |= self.tracker.update(decoded, self.t)
        return changed


def make(autopilot="px4", sysid=1, mavlink1=False, pinned=None):
    v = MavVehicle("udp", autopilot=autopilot, sysid=sysid, mavlink1=mavlink1)
    v._sock.close()  # built only for its encoder and state here
    tracker = StateTracker(pinned)
    return tracker, v, Feed(tracker, v)


@pytest.mark.parametrize(
    "autopilot,modes",
    [
        ("px4", ["MANUAL", "ALTCTL", "POSCTL", "MISSION", "LOITER", "RTL", "LAND", "OFFBOARD"]),
        ("ardupilot", ["STABILIZE", "ALT_HOLD", "LOITER", "AUTO", "RTL", "LAND", "GUIDED"]),
    ],
)
@pytest.mark.parametrize("mavlink1", [False, True])
def test_mode_names_both_families(autopilot, modes, mavlink1):
    tracker, v, feed = make(autopilot, mavlink1=mavlink1)
    for mode in modes:
        v.mode = mode
        assert feed("HEARTBEAT")
        hb = tracker.state.heartbeat
        assert hb.mode == mode
        assert hb.autopilot == autopilot
        assert hb.vehicle_type == "quadrotor"
        assert hb.mavlink_version == (1 if mavlink1 else 2)


def test_every_group_is_filled():
    tracker, v, feed = make()
    v.roll_rad, v.vx_mps, v.vz_mps = 0.25, 2.0, -0.5
    feed(
        "HEARTBEAT",
        "GPS_RAW_INT",
        "GLOBAL_POSITION_INT",
        "VFR_HUD",
        "ATTITUDE",
        "RC_CHANNELS",
        "SERVO_OUTPUT_RAW",
        "SYS_STATUS",
        "BATTERY_STATUS",
        "LOCAL_POSITION_NED",
        "SYSTEM_TIME",
    )
    s = tracker.state
    assert s.gps.fix_type == 3 and s.gps.satellites == 12 and s.gps.eph_m == pytest.approx(0.8)
    assert s.gps.lat_deg == pytest.approx(43.0021) and s.gps.alt_m == pytest.approx(180.0)
    assert s.global_position.vx_mps == pytest.approx(
        2.0
    ) and s.global_position.vz_mps == pytest.approx(-0.5)
    assert s.vfr_hud.climb_mps == pytest.approx(0.5)
    assert s.attitude.roll_rad == pytest.approx(0.25) and s.attitude.time_boot_ms is not None
    assert s.rc.pwm_us[:8] == (1500,) * 8 and len(s.rc.pwm_us) == 18 and s.rc.rssi == 200
    assert s.servo.pwm_us[:4] == (1100,) * 4 and len(s.servo.pwm_us) == 16
    assert s.battery.voltage_v == pytest.approx(12.3, abs=0.01)
    assert s.battery.remaining_pct == 87 and s.battery.current_a == pytest.approx(4.5)
    assert s.local_position.z_m == pytest.approx(0.0) and s.local_position.x_m == pytest.approx(1.0)
    for group in dataclasses.fields(s):
        if group.name not in ("link", "messages"):  # the station's own; a log (below)
            assert getattr(s, group.name).t_mono is not None, group.name


def test_vehicle_messages_statustext_and_our_acks_only():
    tracker = StateTracker(gcs_sysid=254)
    framer = MavFramer()
    ap = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)

    def feed(msg, t):
        for decoded in framer.feed(msg.pack(ap)):
            tracker.update(decoded, t)

    feed(ap.heartbeat_encode(2, 12, 0, 0, 3), 1.0)  # the autopilot: quadrotor, PX4
    feed(ap.statustext_encode(mavlink.MAV_SEVERITY_CRITICAL, b"Arming denied: no GPS"), 2.0)
    arm = mavlink.MAV_CMD_COMPONENT_ARM_DISARM
    feed(ap.command_ack_encode(arm, mavlink.MAV_RESULT_DENIED, 0, 0, 254, 190), 2.1)
    feed(ap.command_ack_encode(arm, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 255, 190), 2.2)  # QGC's
    rates = mavlink.MAV_CMD_SET_MESSAGE_INTERVAL  # our own housekeeping: not shown
    feed(ap.command_ack_encode(rates, mavlink.MAV_RESULT_ACCEPTED, 0, 0, 254, 190), 2.3)
    msgs = tracker.state.messages
    assert msgs.count == 2 and msgs.t_mono == 2.1
    text, ack = msgs.recent
    assert (text.kind, text.severity, text.text) == ("statustext", 2, "Arming denied: no GPS")
    assert (ack.kind, ack.command, ack.result) == ("command_ack", "COMPONENT_ARM_DISARM", "DENIED")
    assert ack.text == "COMPONENT_ARM_DISARM: DENIED" and ack.severity == 4
    for i in range(40):  # the state keeps the newest few; the count says how many came
        feed(ap.statustext_encode(6, f"line {i}".encode()), 3.0 + i)
    msgs = tracker.state.messages
    assert msgs.count == 42 and len(msgs.recent) == MESSAGES_KEPT
    assert msgs.recent[-1].text == "line 39"


def test_pilot_altitude_first_fix_then_arming_and_rearming():
    tracker, v, feed = make()
    v.fix_type = 1
    feed("HEARTBEAT", "GPS_RAW_INT")
    assert tracker.state.altitude.reference == "none"
    v.fix_type = 3
    v.alt_m = 200.0
    feed("GPS_RAW_INT")
    alt = tracker.state.altitude
    assert alt.reference == "first_fix" and alt.reference_alt_m == pytest.approx(200.0)
    # The autopilot's own relative_alt, relative to its power-on home at 196 m.
    v.alt_m, v.relative_alt_m = 201.5, 5.5
    feed("GLOBAL_POSITION_INT")  # switch from GPS to fused altitude: no jump
    assert tracker.state.altitude.relative_alt_m == pytest.approx(0.0)
    v.alt_m, v.relative_alt_m = 203.0, 7.0
    feed("GLOBAL_POSITION_INT")
    assert tracker.state.altitude.relative_alt_m == pytest.approx(1.5)
    v.arm()
    feed("HEARTBEAT")
    assert tracker.state.altitude.reference == "arming"
    assert tracker.state.altitude.source == "alt"  # the two agree on the ground
    assert tracker.state.altitude.relative_alt_m == 0.0
    v.alt_m = 207.0
    feed("GLOBAL_POSITION_INT")
    assert tracker.state.altitude.relative_alt_m == pytest.approx(4.0)
    assert tracker.state.global_position.relative_alt_m == pytest.approx(7.0)  # both exposed
    v.armed = False
    feed("HEARTBEAT")
    v.alt_m = 210.0
    feed("GLOBAL_POSITION_INT")
    assert tracker.state.altitude.relative_alt_m == pytest.approx(7.0)  # still from arming
    feed("HEARTBEAT")  # a beat later, still disarmed on the ground
    v.armed = True
    feed("HEARTBEAT", "GLOBAL_POSITION_INT")
    assert tracker.state.altitude.relative_alt_m == pytest.approx(0.0)  # reset at each arming
    assert tracker.state.altitude.reference_alt_m == pytest.approx(210.0)


def test_arming_seen_late_takes_the_ground_altitude_of_the_last_disarmed_beat():
    # HEARTBEAT comes at 1 Hz: a pilot who climbs at once is in the air when the station
    # first sees the vehicle armed. The zero is where it stood at the last disarmed beat.
    tracker, v, feed = make()
    v.alt_m = 180.0
    feed("HEARTBEAT", "GLOBAL_POSITION_INT", "HEARTBEAT")
    v.armed = True
    v.alt_m = 182.5  # armed and climbing between two heartbeats
    feed("GLOBAL_POSITION_INT", "HEARTBEAT")
    alt = tracker.state.altitude
    assert alt.reference == "arming" and alt.reference_alt_m == pytest.approx(180.0)
    assert alt.relative_alt_m == pytest.approx(2.5)


def test_armed_before_any_altitude_takes_reference_at_first_altitude():
    tracker, v, feed = make()
    v.armed = True
    feed("HEARTBEAT")
    assert tracker.state.altitude.reference == "pending_arming"
    v.alt_m = 150.0
    feed("GLOBAL_POSITION_INT")
    assert tracker.state.altitude.reference == "arming"
    assert tracker.state.altitude.reference_alt_m == pytest.approx(150.0)


def test_follows_only_the_autopilot_auto_detected_or_pinned():
    tracker, ap, feed_ap = make(sysid=42)
    _, gcs, _ = make(autopilot="invalid", sysid=255)
    _, other, _ = make(sysid=7)
    feed_gcs, feed_other = Feed(tracker, gcs), Feed(tracker, other)
    assert not feed_gcs("HEARTBEAT")  # a GCS heartbeat is never the autopilot
    assert not feed_ap("ATTITUDE")  # nothing before the autopilot's heartbeat
    assert feed_ap("HEARTBEAT") and tracker.sysid == 42
    other.roll_rad = 1.0
    assert not feed_other("HEARTBEAT", "ATTITUDE")  # a second vehicle is ignored
    assert feed_ap("ATTITUDE") and tracker.state.attitude.roll_rad == 0.0

    pinned, ap2, feed2 = make(sysid=42, pinned=7)
    assert not feed2("HEARTBEAT")
    assert Feed(pinned, other)("HEARTBEAT", "ATTITUDE")
    assert pinned.state.heartbeat.sysid == 7 and pinned.state.attitude.roll_rad == 1.0


def test_published_snapshots_never_change():
    tracker, v, feed = make()
    feed("HEARTBEAT", "ATTITUDE")
    snapshot = tracker.state
    before = dataclasses.asdict(snapshot)
    v.roll_rad = 0.7
    feed("ATTITUDE", "GLOBAL_POSITION_INT")
    assert dataclasses.asdict(snapshot) == before
    assert tracker.state is not snapshot and tracker.state.attitude.roll_rad == pytest.approx(0.7)
    assert tracker.state.heartbeat is snapshot.heartbeat  # unchanged groups are shared
    with pytest.raises(dataclasses.FrozenInstanceError):
        snapshot.attitude.roll_rad = 1.0
    # The state is built from the tracker's draft when looked at: still a frozen
    # VehicleState of its own, the same object until the next change, a new one after it.
    with pytest.raises(dataclasses.FrozenInstanceError):
        snapshot.attitude = tracker.state.attitude
    now = tracker.state
    assert type(now) is VehicleState and tracker.state is now
    for d in MavFramer().feed(v.mav.param_value_encode(b"X", 1.0, 9, 1, 0).pack(v.mav)):
        assert not tracker.update(d, 200.0)  # nothing it merges
    assert tracker.state is now
    v.roll_rad = 0.2
    assert feed("ATTITUDE") and tracker.state is not now
    assert tracker.state.global_position is now.global_position
    assert tracker.state.attitude.roll_rad == pytest.approx(0.2)
    assert now.attitude.roll_rad == pytest.approx(0.7)


def test_unknown_sentinels_become_none():
    tracker, v, feed = make()
    feed("HEARTBEAT")
    m = v.mav.gps_raw_int_encode(0, 3, 0, 0, 0, 65535, 65535, 65535, 65535, 255)
    for d in MavFramer().feed(m.pack(v.mav)):
        tracker.update(d, 1.0)
    g = tracker.state.gps
    assert g.eph_m is None and g.ground_speed_mps is None and g.course_deg is None
    assert g.satellites is None
    assert isinstance(mavlink.MAVLink_gps_raw_int_message, type)


def test_consumed_mah_from_battery_status_and_unknown():
    tracker, v, feed = make()
    feed("HEARTBEAT", "BATTERY_STATUS")
    assert tracker.state.battery.consumed_mah == 0  # the vehicle's count since its start
    v.consumed_mah = 1234.9  # sent as an integer mAh, as the field is
    feed("BATTERY_STATUS", "SYS_STATUS")  # SYS_STATUS carries none: it keeps the figure
    assert tracker.state.battery.consumed_mah == 1234
    v.consumed_mah = None  # -1: the autopilot does not know (no current sensor)
    feed("BATTERY_STATUS")
    assert tracker.state.battery.consumed_mah is None
    assert tracker.state.battery.current_a == pytest.approx(4.5)


def test_armed_since_and_flight_timer_across_arm_disarm_rearm():
    tracker, v, feed = make()
    feed("HEARTBEAT")
    hb = tracker.state.heartbeat
    assert hb.armed_since_mono is None and hb.armed_for_s is None  # never armed
    v.armed = True
    feed("HEARTBEAT")
    armed_at = feed.t
    hb = tracker.state.heartbeat
    assert hb.armed_since_mono == armed_at and hb.armed_for_s == 0
    feed("ATTITUDE", "ATTITUDE", "HEARTBEAT")  # 0.3 s on the source's clock
    hb = tracker.state.heartbeat
    assert hb.armed_since_mono == armed_at and hb.armed_for_s == pytest.approx(0.3)
    v.armed = False
    feed("HEARTBEAT")  # disarmed: the timer stops at this beat and holds
    feed("ATTITUDE", "HEARTBEAT")
    hb = tracker.state.heartbeat
    assert not hb.armed and hb.armed_for_s == pytest.approx(0.4)
    assert hb.armed_since_mono == armed_at
    v.armed = True
    feed("HEARTBEAT")  # re-armed: a new flight, from zero
    hb = tracker.state.heartbeat
    assert hb.armed_since_mono == feed.t and hb.armed_for_s == 0


def test_the_twins_mah_used_reaches_the_state():
    """The twin sends BATTERY_STATUS current_consumed as PX4 does (the charge drawn from
    its pack): its bytes, through the framer, give the state the same figure."""

    class Wire:
        data = b""

        def write(self, buf: bytes) -> None:
            self.data += buf

    sim = Sim(config=SimConfig(sensors=SensorParams(enabled=False)))
    sim.run_for(2.5)
    assert sim.arm() == (True, "")
    sim.set_sticks(0, 0, 0, 0.8)  # climbing: the motors draw tens of amps
    sim.run_for(3.0)
    wire = Wire()
    telemetry = Telemetry(mavlink.MAVLink(wire, srcSystem=1, srcComponent=1))
    telemetry.send("HEARTBEAT", sim, 5500)
    telemetry.send("BATTERY_STATUS", sim, 5500)
    tracker = StateTracker()
    for decoded in MavFramer().feed(wire.data):
        tracker.update(decoded, 10.0)
    af = sim.config.airframe
    drawn_mah = (af.capacity_ah * 3600 - sim.state.charge_c[0]) / 3.6
    assert drawn_mah > 1  # it has flown on its battery
    assert tracker.state.battery.consumed_mah == int(drawn_mah)


# The fields each message carries: the only ones it may change. A field not named here
# (one added to a group later, or another message's) must keep its value.
_GPS = ("fix_type", "satellites", "lat_deg", "lon_deg", "alt_m", "eph_m", "epv_m", "h_acc_m")
_POSITION = ("lat_deg", "lon_deg", "alt_m", "relative_alt_m", "vx_mps", "vy_mps", "vz_mps")
_PILOT = ("relative_alt_m", "reference_alt_m", "reference", "retaken_because")
CARRIED = {
    "HEARTBEAT": {
        "heartbeat": (
            "sysid", "compid", "autopilot", "vehicle_type", "armed", "mode", "base_mode",
            "custom_mode", "system_status", "mavlink_version", "armed_since_mono",
            "armed_for_s",
        ),
    },
    "GPS_RAW_INT": {
        "gps": ("time_usec", *_GPS, "ground_speed_mps", "course_deg"),
        "utc": ("unix_s", "source"),
    },
    "GLOBAL_POSITION_INT": {
        "global_position": ("time_boot_ms", *_POSITION, "heading_deg"),
        "altitude": _PILOT,  # the pilot's altitude follows the fused one
    },
    "VFR_HUD": {
        "vfr_hud": (
            "ground_speed_mps", "airspeed_mps", "climb_mps", "heading_deg", "throttle_pct",
            "alt_m",
        ),
    },
    "ATTITUDE": {
        "attitude": (
            "time_boot_ms", "roll_rad", "pitch_rad", "yaw_rad", "rollspeed_rad_s",
            "pitchspeed_rad_s", "yawspeed_rad_s",
        ),
    },
    "RC_CHANNELS": {"rc": ("time_boot_ms", "chancount", "pwm_us", "rssi")},
    "SERVO_OUTPUT_RAW": {"servo": ("time_usec", "port", "pwm_us")},
    "SYS_STATUS": {"battery": ("voltage_v", "current_a", "remaining_pct")},
    "BATTERY_STATUS": {"battery": ("voltage_v", "current_a", "remaining_pct", "consumed_mah")},
    "LOCAL_POSITION_NED": {
        "local_position": ("time_boot_ms", "x_m", "y_m", "z_m", "vx_mps", "vy_mps", "vz_mps"),
    },
    "SYSTEM_TIME": {"utc": ("unix_s", "source")},
    "STATUSTEXT": {"messages": ("count", "recent")},
    "COMMAND_ACK": {"messages": ("count", "recent")},
}  # fmt: skip


def _sentinel(value, name: str):
    """A value of the field's kind that no message of the test sets."""
    if name == "t_mono":
        return 50.0  # before every message fed (the tracker's arithmetic needs a time)
    if isinstance(value, bool):
        return not value
    if isinstance(value, tuple):
        return (7,) * len(value) if all(isinstance(v, int) for v in value) else ()
    if isinstance(value, int):
        return 7
    if isinstance(value, str):
        return "sentinel"
    return 7.25  # float or None


@pytest.mark.parametrize("message", CARRIED)
def test_each_message_changes_only_the_fields_it_carries(message):
    """Every field of every group set to a sentinel, then one message: the fields it
    carries (and its group's time) change, every other field keeps its sentinel."""
    tracker, v, feed = make(autopilot="ardupilot")
    v.gps_utc_offset_s = 0.0
    feed("HEARTBEAT", "GPS_RAW_INT", "GLOBAL_POSITION_INT")  # the autopilot followed
    draft = tracker._draft
    for group in dataclasses.fields(VehicleState):
        old = getattr(draft, group.name)
        values = {f.name: _sentinel(getattr(old, f.name), f.name) for f in dataclasses.fields(old)}
        setattr(draft, group.name, dataclasses.replace(old, **values))
    if message == "GLOBAL_POSITION_INT":
        draft.global_position = dataclasses.replace(draft.global_position, alt_m=v.alt_m)
    before = {g.name: getattr(draft, g.name) for g in dataclasses.fields(VehicleState)}
    ap = v.mav
    if message == "STATUSTEXT":
        msg = ap.statustext_encode(6, b"EKF3 IMU0 is using GPS")
    elif message == "COMMAND_ACK":
        msg = ap.command_ack_encode(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 0, 0, 0, 0)
    else:
        msg = v.build(message)
    feed.t += 0.1
    for decoded in feed.framer.feed(msg.pack(ap)):
        assert tracker.update(decoded, feed.t)
    after = tracker.state
    carried = CARRIED[message]
    for group, old in before.items():
        new, own = getattr(after, group), carried.get(group, ())
        for f in dataclasses.fields(old):
            was, now = getattr(old, f.name), getattr(new, f.name)
            if f.name not in own and not (own and f.name == "t_mono"):
                assert now == was, f"{message} changed {group}.{f.name}: {was!r} -> {now!r}"
    first = next(iter(carried))  # the message's own group: updated, at the message's time
    assert getattr(after, first).t_mono == feed.t
    assert any(
        getattr(getattr(after, first), n) != getattr(before[first], n) for n in carried[first]
    )
