"""Episodes of a recording, as a learner sees them: one per flight, resampled to a fixed
rate, with the twin's Gymnasium observation and the pilot's sticks as the action.

- Episode: one flight (`analysis.flights`: an armed period with a take-off), from its
  arming to its disarming, frames every `1 / fps` s of the session clock. Each frame
  takes the telemetry row at or before its instant (the recorder's rows hold the latest
  state; unknown values are carried forward from the last known one).
- State: `twin.gym_env.STATE_NAMES`, as `TwinEnv` observes it: position relative to the
  task's target pad (scene frame, ENU m: x, y from the fused GLOBAL_POSITION_INT, else
  GPS; z the pilot's altitude since arming), velocity ENU, roll and pitch, sin/cos of the
  heading (counter-clockwise from east), body rates (FLU: ATTITUDE's FRD rates with
  pitch and yaw negated), battery fraction (unknown reads as full), armed, on the ground
  (height under `ON_GROUND_M`), horizontal distance and height above the target.
  A flight that does not start within `ANCHOR_RADIUS_M` of the scene's start pad was
  flown on another field: its arming point is taken as the task's start pad.
- Action: (roll, pitch, yaw, throttle) in [-1, 1] as `TwinEnv` takes them, from the RC
  channels (PWM 1000-2000 us; throttle -1 = stick down) through a per-radio `ChannelMap`.
  The twin reports its sticks (from MANUAL_CONTROL or the pilot) as RC_CHANNELS in the
  default map, so twin and field sessions read the same way.
- Camera frames: per frame instant, the newest recorded JPEG captured at or before it
  (the first one before any was captured).
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from fpv_station.analysis.flights import Flight, split_flights
from fpv_station.analysis.recording import Recording
from fpv_station.analysis.report import SCENE_RADIUS_M
from fpv_station.core.geodesy import geodetic_to_enu
from fpv_station.core.scene import Scene
from fpv_station.twin.gym_env import ACTION_NAMES, STATE_NAMES

Array = NDArray[np.float64]

# As analysis: a flight starting farther from the pads is flown elsewhere.
ANCHOR_RADIUS_M = SCENE_RADIUS_M
ON_GROUND_M = 0.2
PWM_UNUSED = (0, 65535)
RC_CHANNELS = 18

# The telemetry columns episodes and exporters read (telemetry.csv names; missing ones
# are NaN): what `open_recording(path, COLUMNS)` loads.
COLUMNS: tuple[str, ...] = (
    "heartbeat.armed",
    "gps.lat_deg",
    "gps.lon_deg",
    "gps.alt_m",
    "gps.fix_type",
    "global_position.lat_deg",
    "global_position.lon_deg",
    "global_position.alt_m",
    "global_position.relative_alt_m",
    "global_position.vx_mps",
    "global_position.vy_mps",
    "global_position.vz_mps",
    "altitude.relative_alt_m",
    "attitude.roll_rad",
    "attitude.pitch_rad",
    "attitude.yaw_rad",
    "attitude.rollspeed_rad_s",
    "attitude.pitchspeed_rad_s",
    "attitude.yawspeed_rad_s",
    "battery.remaining_pct",
    "vfr_hud.climb_mps",
    *(f"rc.pwm_us.{i}" for i in range(RC_CHANNELS)),
)


@dataclass(frozen=True)
class ChannelMap:
    """Which RC channel (1-based) carries each stick; negative = reversed."""

    roll: int = 1
    pitch: int = 2
    throttle: int = 3
    yaw: int = 4

    PRESETS = {"AETR": (1, 2, 3, 4), "TAER": (2, 3, 1, 4), "AERT": (1, 2, 4, 3)}

    @classmethod
    def parse(cls, text: str) -> ChannelMap:
        """`AETR` (the default, as the twin sends), `TAER`, `AERT`, or explicit
        `roll=1,pitch=-2,throttle=3,yaw=4` (a minus reverses the channel)."""
        t = text.strip()
        if t.upper() in cls.PRESETS:
            r, p, th, y = cls.PRESETS[t.upper()]
            return cls(r, p, th, y)
        m = dict(re.findall(r"(roll|pitch|throttle|yaw)\s*=\s*(-?\d+)", t))
        if set(m) != {"roll", "pitch", "throttle", "yaw"}:
            raise ValueError(
                f"channel map '{text}': give a preset ({', '.join(cls.PRESETS)}) or "
                "roll=N,pitch=N,throttle=N,yaw=N (channels 1-18, minus to reverse)"
            )
        out = cls(**{k: int(v) for k, v in m.items()})
        if any(not 1 <= abs(c) <= RC_CHANNELS for c in out.channels()):
            raise ValueError(f"channel map '{text}': channels are 1 to {RC_CHANNELS}")
        return out

    def channels(self) -> tuple[int, int, int, int]:
        """In the env's action order: roll, pitch, yaw, throttle."""
        return (self.roll, self.pitch, self.yaw, self.throttle)

    def sticks(self, pwm_us: Array) -> NDArray[np.float32]:
        """(n, 18) PWM -> (n, 4) actions in [-1, 1]; unknown sticks centred (throttle
        centred holds altitude in Position mode)."""
        out = np.zeros((pwm_us.shape[0], 4))
        for k, ch in enumerate(self.channels()):
            v = pwm_us[:, abs(ch) - 1]
            v = np.where(np.isin(v, PWM_UNUSED), np.nan, v)
            a = (v - 1500.0) / 500.0
            out[:, k] = np.nan_to_num(-a if ch < 0 else a, nan=0.0)
        return np.clip(out, -1.0, 1.0).astype(np.float32)


@dataclass(frozen=True)
class Episode:
    recording: str  # the recording's name
    number: int  # the flight's number in its recording (1-based)
    flight: Flight  # indices into the recording's rows
    t_s: Array  # each frame's instant, session clock
    state: NDArray[np.float32]  # (n, len(STATE_NAMES))
    action: NDArray[np.float32]  # (n, 4) roll, pitch, yaw, throttle
    frames: dict[str, NDArray[np.intp]]  # per camera, the recorded frame shown at each frame
    landed: bool  # the flight ended disarmed on the ground (not cut off by the log's end)

    def __len__(self) -> int:
        return int(self.t_s.size)

    @property
    def duration_s(self) -> float:
        return float(self.t_s[-1] - self.t_s[0]) if len(self) else 0.0


def target_m(scene: Scene, task_id: int) -> Array:
    """The task's target in the scene frame: its end pad on the ground."""
    end = scene.pad(scene.task(task_id).end_pad)
    return np.array([end.x_m, end.y_m, 0.0])


def episodes(
    rec: Recording,
    scene: Scene,
    task_id: int,
    fps: float,
    channel_map: ChannelMap | None = None,
    cameras: tuple[str, ...] = (),
) -> Iterator[Episode]:
    """The recording's flights as episodes (see the module's docstring)."""
    cmap = channel_map or ChannelMap()
    t = rec.t_s
    armed = np.nan_to_num(rec.column("heartbeat.armed"), nan=0.0) > 0.5
    for flight in split_flights(t, armed, pilot_height(rec)):
        yield _episode(rec, flight, scene, task_id, fps, cmap, cameras)


def _episode(
    rec: Recording,
    f: Flight,
    scene: Scene,
    task_id: int,
    fps: float,
    cmap: ChannelMap,
    cameras: tuple[str, ...],
) -> Episode:
    t = rec.t_s
    n = int(np.floor((t[f.disarm] - t[f.arm]) * fps + 1e-6)) + 1
    tk = t[f.arm] + np.arange(n) / fps
    rows = np.clip(np.searchsorted(t, tk, side="right") - 1, f.arm, f.disarm)

    def at(name: str) -> Array:
        return carry_forward(rec.column(name))[rows]

    xyz = scene_xyz(rec, scene, task_id, rows)
    z = xyz[:, 2]
    rel = xyz - target_m(scene, task_id)
    vel = np.column_stack(
        [at("global_position.vy_mps"), at("global_position.vx_mps"), -at("global_position.vz_mps")]
    )
    yaw_enu = np.pi / 2 - at("attitude.yaw_rad")
    rates = np.column_stack(
        [
            at("attitude.rollspeed_rad_s"),
            -at("attitude.pitchspeed_rad_s"),
            -at("attitude.yawspeed_rad_s"),
        ]
    )
    battery = np.nan_to_num(at("battery.remaining_pct") / 100.0, nan=1.0)
    armed = (np.nan_to_num(at("heartbeat.armed"), nan=0.0) > 0.5).astype(float)
    state = np.column_stack(
        [
            rel,
            vel,
            at("attitude.roll_rad"),
            at("attitude.pitch_rad"),
            np.sin(yaw_enu),
            np.cos(yaw_enu),
            rates,
            battery,
            armed,
            (z < ON_GROUND_M).astype(float),
            np.hypot(rel[:, 0], rel[:, 1]),
            rel[:, 2],
        ]
    )
    assert state.shape[1] == len(STATE_NAMES)
    pwm = np.column_stack([at(f"rc.pwm_us.{i}") for i in range(RC_CHANNELS)])
    frames = {}
    for cam in cameras:
        ct = rec.cameras[cam].t_s
        frames[cam] = np.clip(np.searchsorted(ct, tk, side="right") - 1, 0, ct.size - 1)
    ended_disarmed = f.disarm < t.size - 1
    return Episode(
        recording=rec.name,
        number=f.number,
        flight=f,
        t_s=tk,
        state=np.nan_to_num(state, nan=0.0).astype(np.float32),
        action=cmap.sticks(pwm),
        frames=frames,
        landed=bool(ended_disarmed and z[-1] < 0.5),
    )


def pilot_height(rec: Recording) -> Array:
    """The pilot's altitude (since arming), else the autopilot's relative altitude."""
    return _first_known(
        rec.column("altitude.relative_alt_m"), rec.column("global_position.relative_alt_m")
    )


def scene_xyz(rec: Recording, scene: Scene, task_id: int, rows: NDArray[np.intp]) -> Array:
    """(len(rows), 3) positions of the vehicle at `rows` in the scene frame (ENU m about
    the scene's home): x, y from the fused position (else GPS), z the pilot's height.
    A flight whose first row is farther than `ANCHOR_RADIUS_M` from the task's start pad
    was flown on another field and is moved so that it starts on that pad."""
    lat = carry_forward(
        _first_known(rec.column("global_position.lat_deg"), rec.column("gps.lat_deg"))
    )
    lon = carry_forward(
        _first_known(rec.column("global_position.lon_deg"), rec.column("gps.lon_deg"))
    )
    z = np.nan_to_num(carry_forward(pilot_height(rec))[rows], nan=0.0)
    known = np.flatnonzero(np.isfinite(lat[rows]) & np.isfinite(lon[rows]))
    if known.size == 0:
        return np.column_stack([np.zeros((rows.size, 2)), z])
    h = scene.home
    enu = geodetic_to_enu(lat[rows], lon[rows], h.alt_m, h.lat_deg, h.lon_deg, h.alt_m)
    xy = np.nan_to_num(enu[:, :2], nan=0.0)
    start = scene.pad(scene.task(task_id).start_pad).xy_m
    first = enu[known[0], :2]
    if np.hypot(*(first - start)) > ANCHOR_RADIUS_M:
        xy = xy - first + start
    return np.column_stack([xy, z])


def _first_known(*columns: Array) -> Array:
    """The first column that has any value (sources differ in what they send)."""
    for c in columns:
        if np.isfinite(c).any():
            return c
    return columns[-1]


def carry_forward(v: Array) -> Array:
    """NaN replaced by the last known value before it (NaN until the first one)."""
    ok = np.isfinite(v)
    if ok.all() or not ok.any():
        return v
    idx = np.maximum.accumulate(np.where(ok, np.arange(v.size), -1))
    out = v[np.clip(idx, 0, None)]
    out[idx < 0] = np.nan
    return out


__all__ = ["ACTION_NAMES", "STATE_NAMES", "ChannelMap", "Episode", "episodes", "target_m"]
