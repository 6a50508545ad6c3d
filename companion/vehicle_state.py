"""The typed flight state of the autopilot, one group per MAVLink message family.

Every group carries `t_mono` (station's time.monotonic() when the group was last
updated, None before its first message) and, where the message has one, the vehicle's
own timestamp (`time_boot_ms` or `time_usec`). Units are in the names. These names are
the contract for the WebSocket JSON, the recorder's CSV columns (flattened as
`group.field`, tuples as `group.field.N`), and the analysis loaders: rename with care.

Every class is frozen: the link publishes a new `VehicleState` (sharing unchanged
groups) for every change, and readers in other threads hold snapshots that never move
under them. Build changed copies with `dataclasses.replace`, or on the link's hot path
with `quick_constructor` / `quick_replace` (the same objects, built faster).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields, make_dataclass
from operator import attrgetter
from typing import Any, TypeVar

T = TypeVar("T")


@dataclass(frozen=True, slots=True)
class Heartbeat:
    t_mono: float | None = None
    sysid: int | None = None
    compid: int | None = None
    autopilot: str = "unknown"  # "px4", "ardupilot", "generic", ...
    vehicle_type: str = "unknown"  # "quadrotor", ...
    armed: bool = False
    mode: str = "UNKNOWN"  # human mode name in the autopilot family's own words
    base_mode: int = 0
    custom_mode: int = 0
    system_status: str = "UNKNOWN"
    mavlink_version: int | None = None  # 1 or 2, from the wire format of its packets
    # The flight timer, as Betaflight's "last armed" timer: `armed_since_mono` is the time
    # (the source's clock, as t_mono) of the first HEARTBEAT that said armed, reset at each
    # arming; `armed_for_s` is how long it has been armed as of this HEARTBEAT (a reader
    # adds the group's age while armed) and holds the flight's length after disarming
    # (the disarming HEARTBEAT's time). Both are known a heartbeat late (1 Hz on PX4);
    # a station started mid-flight counts from when it first heard the vehicle armed.
    # Kept in the state, not in a page, so that every page (one opened mid-flight too)
    # and the recording show the same timer.
    armed_since_mono: float | None = None
    armed_for_s: float | None = None  # None: never armed since the station heard it


@dataclass(frozen=True, slots=True)
class GpsRaw:
    """GPS_RAW_INT: the receiver's own solution."""

    t_mono: float | None = None
    time_usec: int | None = None
    fix_type: int = 0  # 0-1 no fix, 2 = 2D, 3 = 3D, 4 DGPS, 5 RTK float, 6 RTK fixed
    satellites: int | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None  # MSL
    eph_m: float | None = None
    epv_m: float | None = None
    # The receiver's horizontal position uncertainty (MAVLink 2 `h_acc`); None: not sent
    # (MAVLink 1, or 0: an autopilot that does not know it).
    h_acc_m: float | None = None
    ground_speed_mps: float | None = None
    course_deg: float | None = None


@dataclass(frozen=True, slots=True)
class GlobalPosition:
    """GLOBAL_POSITION_INT: the autopilot's fused position."""

    t_mono: float | None = None
    time_boot_ms: int | None = None
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_m: float | None = None  # MSL
    relative_alt_m: float | None = None  # the autopilot's own, relative to its home
    vx_mps: float | None = None  # north
    vy_mps: float | None = None  # east
    vz_mps: float | None = None  # down
    heading_deg: float | None = None


@dataclass(frozen=True, slots=True)
class VfrHud:
    t_mono: float | None = None
    ground_speed_mps: float | None = None
    airspeed_mps: float | None = None
    climb_mps: float | None = None
    heading_deg: float | None = None
    throttle_pct: float | None = None
    alt_m: float | None = None


@dataclass(frozen=True, slots=True)
class Attitude:
    t_mono: float | None = None
    time_boot_ms: int | None = None
    roll_rad: float | None = None
    pitch_rad: float | None = None
    yaw_rad: float | None = None
    rollspeed_rad_s: float | None = None
    pitchspeed_rad_s: float | None = None
    yawspeed_rad_s: float | None = None


@dataclass(frozen=True, slots=True)
class RcChannels:
    """RC_CHANNELS: the pilot's stick inputs as PWM (us); 0 or 65535 = unused."""

    t_mono: float | None = None
    time_boot_ms: int | None = None
    chancount: int = 0
    pwm_us: tuple[int, ...] = (0,) * 18
    rssi: int | None = None


@dataclass(frozen=True, slots=True)
class ServoOutputs:
    """SERVO_OUTPUT_RAW: the autopilot's outputs (motors) as PWM (us)."""

    t_mono: float | None = None
    time_usec: int | None = None
    port: int = 0
    pwm_us: tuple[int, ...] = (0,) * 16


@dataclass(frozen=True, slots=True)
class Battery:
    """SYS_STATUS and BATTERY_STATUS merged.

    `consumed_mah` is the autopilot's own BATTERY_STATUS `current_consumed` (charge drawn
    since it booted or its battery was reset), None while it says -1 (unknown) or sends
    none. The station does not integrate current itself: PX4, ArduPilot and INAV send it
    whenever they have a current sensor (without one there is no current to integrate),
    and a station's integral would start when the station first heard the vehicle, a
    second figure that disagrees with the autopilot's own failsafe."""

    t_mono: float | None = None
    voltage_v: float | None = None
    current_a: float | None = None
    remaining_pct: float | None = None
    consumed_mah: float | None = None


@dataclass(frozen=True, slots=True)
class LocalPosition:
    """LOCAL_POSITION_NED, when the autopilot sends it."""

    t_mono: float | None = None
    time_boot_ms: int | None = None
    x_m: float | None = None  # north
    y_m: float | None = None  # east
    z_m: float | None = None  # down
    vx_mps: float | None = None
    vy_mps: float | None = None
    vz_mps: float | None = None


@dataclass(frozen=True, slots=True)
class PilotAltitude:
    """The altitude the pilot sees: altitude now minus the altitude at arming.

    Reset at each arming; before the first arming it is relative to the first GPS fix
    (`reference` says which). The altitude at arming is where the vehicle stood at the
    last disarmed heartbeat, or, within a metre of it, the autopilot's home just after
    arming (`alt - relative_alt`: ArduPilot, PX4 and INAV set it there, after what arming
    itself moves, such as ArduPilot's barometer re-zero). The paper's definition, not the autopilot's relative_alt,
    which drifts with the power-on position. When the autopilot's altitude frame moves
    under it (ArduPilot setting its EKF origin: a jump of tens or hundreds of metres), the
    reference is re-taken by the frame's step (the step of `alt` less that of the
    autopilot's `relative_alt`, which the frame does not move: what the vehicle climbed
    meanwhile stays in the pilot's altitude): `reference` gains "_retaken" and
    `retaken_because` says what showed it.
    """

    t_mono: float | None = None
    relative_alt_m: float | None = None
    reference_alt_m: float | None = None  # MSL altitude the value is relative to
    reference: str = "none"  # "none", "first_fix", "arming", "first_fix_retaken", "arming_retaken"
    # What measures it: "alt" (GLOBAL_POSITION_INT `alt`, or GPS_RAW_INT's without it,
    # minus `reference_alt_m`) or "relative_alt" (the autopilot's `relative_alt` minus its
    # value at arming): chosen at arming, "relative_alt" where the two disagreed on the
    # ground (old firmware's GPS altitude in `alt`, metres of wander).
    source: str = "alt"
    retaken_because: str | None = None  # "EKF origin set", "altitude jump", "GPS agrees again"
    home_lat_deg: float | None = None  # where the reference was taken
    home_lon_deg: float | None = None


@dataclass(frozen=True, slots=True)
class LinkStatus:
    """Whether the autopilot is heard: `link_lost` after `link.link_lost_s` of silence.

    Part of the state so that the pilot's page, the recorder and the WebSocket see a
    lost link as a state change (nothing else changes when the vehicle goes silent).
    """

    t_mono: float | None = None  # when link_lost last changed
    link_lost: bool = True
    last_heartbeat_mono: float | None = None


# Vehicle times before this are no UTC (an unset RTC counts from 1970 or from boot).
UTC_PLAUSIBLE_AFTER_S = 1_577_836_800.0  # 2020-01-01


@dataclass(frozen=True, slots=True)
class VehicleUtc:
    """UTC as the vehicle knows it, from its GPS: SYSTEM_TIME's `time_unix_usec` (PX4 and
    ArduPilot set it from the GPS), or a GPS_RAW_INT `time_usec` that is a Unix time
    (most autopilots put time since boot there). A Pi has no real-time clock, so this is
    the field's best UTC when the Pi has had no network time (see companion.recording
    .session_clock)."""

    t_mono: float | None = None  # station's clock when it arrived
    unix_s: float | None = None  # the vehicle's UTC at t_mono
    source: str = "none"  # "SYSTEM_TIME" or "GPS_RAW_INT"

    def at(self, t_mono: float) -> float | None:
        """The vehicle's UTC at station time `t_mono` (elapsed on the monotonic clock, which
        a time service stepping the wall clock does not move)."""
        if self.unix_s is None or self.t_mono is None:
            return None
        return self.unix_s + (t_mono - self.t_mono)


@dataclass(frozen=True, slots=True)
class VehicleMessage:
    """One thing the vehicle said: a STATUSTEXT, or a COMMAND_ACK (the command it answers
    and its result, with a text a person reads)."""

    t_mono: float
    kind: str  # "statustext" or "command_ack"
    severity: int  # MAV_SEVERITY: 0 emergency ... 7 debug; an ACK: 6 accepted, 4 refused
    text: str
    command: str | None = None  # a COMMAND_ACK's command, e.g. "COMPONENT_ARM_DISARM"
    result: str | None = None  # a COMMAND_ACK's result, e.g. "ACCEPTED", "DENIED"


MESSAGES_KEPT = 16


@dataclass(frozen=True, slots=True)
class VehicleMessages:
    """What the vehicle said lately, newest last. `count` grows by one per message, so a
    reader that saw count n knows how many are new (at most MESSAGES_KEPT are kept).
    Not a telemetry.csv column group: the recorder writes messages.csv from it."""

    t_mono: float | None = None
    count: int = 0
    recent: tuple[VehicleMessage, ...] = ()


# Groups that are logs, not sampled values: no telemetry.csv columns (see the recorder).
LOG_GROUPS = ("messages",)


@dataclass(frozen=True, slots=True)
class VehicleState:
    """Everything the station knows about the autopilot it follows."""

    heartbeat: Heartbeat = field(default_factory=Heartbeat)
    gps: GpsRaw = field(default_factory=GpsRaw)
    global_position: GlobalPosition = field(default_factory=GlobalPosition)
    vfr_hud: VfrHud = field(default_factory=VfrHud)
    attitude: Attitude = field(default_factory=Attitude)
    rc: RcChannels = field(default_factory=RcChannels)
    servo: ServoOutputs = field(default_factory=ServoOutputs)
    battery: Battery = field(default_factory=Battery)
    local_position: LocalPosition = field(default_factory=LocalPosition)
    altitude: PilotAltitude = field(default_factory=PilotAltitude)
    link: LinkStatus = field(default_factory=LinkStatus)
    utc: VehicleUtc = field(default_factory=VehicleUtc)
    messages: VehicleMessages = field(default_factory=VehicleMessages)

    def last_heard_mono(self) -> float | None:
        """When the autopilot's newest message arrived (station clock), None if never.
        Only the autopilot's own messages count: `link` and `altitude` are the station's."""
        times = [
            g.t_mono
            for g in (
                self.heartbeat,
                self.gps,
                self.global_position,
                self.vfr_hud,
                self.attitude,
                self.rc,
                self.servo,
                self.battery,
                self.local_position,
            )
            if g.t_mono is not None
        ]
        return max(times) if times else None


# -- quick construction (the link's per-packet path) ---------------------------------------
#
# A frozen dataclass's generated __init__ sets each field with object.__setattr__, a slow
# call per field, and the state merge builds two or three objects per MAVLink packet. An
# unfrozen twin with the same fields, defaults and slots (so the same memory layout) is
# filled with plain attribute stores and then made an instance of the frozen class by assigning
# `__class__`, which CPython allows between classes of the same slot layout. The result
# is the frozen class's own object: its type, equality, hash, repr, fields and
# frozenness (FrozenInstanceError on a store) are the class's.


_Twin = tuple[type, Callable[[Any], tuple[Any, ...]]]
_TWINS: dict[type, _Twin] = {}


def _twin(cls: type) -> _Twin:
    """The unfrozen twin of the frozen slots dataclass `cls`, and a getter of all its
    field values in order (made once per class)."""
    made = _TWINS.get(cls)
    if made is None:
        made = _TWINS.setdefault(cls, _make_twin(cls))  # two threads: one twin wins
    return made


def _make_twin(cls: type) -> _Twin:
    specs = [
        (f.name, f.type, field(default=f.default, default_factory=f.default_factory))
        for f in fields(cls)
    ]
    twin = make_dataclass(f"_{cls.__name__}Draft", specs, slots=True)
    names = [f.name for f in fields(cls)]
    return twin, attrgetter(*names) if len(names) > 1 else lambda obj: (getattr(obj, names[0]),)


def unfrozen_twin(cls: type) -> type:
    """A mutable dataclass with the fields and defaults of `cls`: a draft to fill and
    hand to `quick_constructor(cls)` field by field, or to freeze with `freeze_draft`."""
    return _twin(cls)[0]


def quick_constructor(cls: type[T]) -> Callable[..., T]:
    """`cls(...)` for a frozen slots dataclass of this module, three to five times
    faster (positional arguments most): see the note above."""
    twin = _twin(cls)[0]

    def construct(*args: Any, **kwargs: Any) -> T:
        obj: T = twin(*args, **kwargs)  # a T once its class is set
        obj.__class__ = cls
        return obj

    construct.__qualname__ = construct.__name__ = f"quick_{cls.__name__}"
    return construct


def freeze_draft(draft: Any, cls: type[T]) -> T:
    """A frozen `cls` with the field values of `draft` (an `unfrozen_twin(cls)`), which
    stays a draft to change further."""
    return _copy_as(draft, cls, {})


def quick_replace(obj: T, **changes: Any) -> T:
    """`dataclasses.replace(obj, **changes)` for a frozen slots dataclass of this module,
    built the quick way; an unknown name is an AttributeError. For each class and set of
    names changed (a message handler's: the same every time), one function is made that
    calls the twin's constructor with every field in order, the changed ones from
    `changes` and the others from `obj`: as fast as the quick constructor."""
    key = (type(obj), tuple(changes))
    replace = _REPLACERS.get(key)
    if replace is None:
        replace = _REPLACERS[key] = _replacer(*key)
    new: T = replace(obj, changes)
    return new


_REPLACERS: dict[tuple[type, tuple[str, ...]], Callable[[Any, dict[str, Any]], Any]] = {}


def _replacer(cls: type, names: tuple[str, ...]) -> Callable[[Any, dict[str, Any]], Any]:
    """The function `quick_replace` calls for `names` of `cls` (made once, as dataclasses
    makes its __init__)."""
    all_names = [f.name for f in fields(cls)]
    unknown = set(names) - set(all_names)
    if unknown:
        raise AttributeError(f"{cls.__name__} has no field {', '.join(sorted(unknown))}")
    args = ", ".join(f"c[{n!r}]" if n in names else f"o.{n}" for n in all_names)
    scope: dict[str, Any] = {"twin": _twin(cls)[0], "cls": cls}
    exec(
        f"def replace(o, c):\n    new = twin({args})\n    new.__class__ = cls\n    return new",
        scope,
    )
    replace: Callable[[Any, dict[str, Any]], Any] = scope["replace"]
    return replace


def _copy_as(source: Any, cls: type[T], changes: dict[str, Any]) -> T:
    """A new frozen `cls` with the field values of `source` (a `cls` or its twin) and
    `changes`."""
    twin, values = _twin(cls)
    new: T = twin(*values(source))  # a T once its class is set
    for name, value in changes.items():
        setattr(new, name, value)
    new.__class__ = cls
    return new
