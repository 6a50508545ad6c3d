"""Synthetic flights with known answers, written exactly as the station records them:
a session folder (`telemetry.csv` in the recorder's columns, rows at the telemetry rate,
GPS updating slower) or a bare `.tlog` encoded by pymavlink. Tests and
`benchmarks/analysis.py` use them; they also show what the analysis expects.

A `Flight` is a dense trajectory in the paper's aligned frame (x towards the landing
pad, y left, z up, origin at the start pad), placed on the Earth by `home` and `heading_deg`
(the compass direction of +x), so the loaders see real latitudes and longitudes.
"""

from __future__ import annotations

import csv
import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from fpv_station.companion.recording import layout
from fpv_station.companion.vehicle_state import Attitude, GlobalPosition, GpsRaw, VehicleState
from fpv_station.core.geodesy import enu_to_geodetic, rotate_about_up

Array = NDArray[np.float64]
FIELD_HOME = (43.0021, -78.7875, 180.0)  # the paper's field, as core/scenes/field.toml


@dataclass(frozen=True)
class Flight:
    t_s: Array  # dense time (s)
    xyz_m: Array  # (n, 3) aligned frame
    armed: NDArray[np.bool_]
    home: tuple[float, float, float] = FIELD_HOME
    heading_deg: float = 90.0  # compass bearing of +x; 90 = due east

    def enu_m(self) -> Array:
        # +x at compass bearing b is the ENU direction rotated by (90 - b) degrees.
        return rotate_about_up(self.xyz_m, np.radians(90.0 - self.heading_deg))

    def llh(self) -> Array:
        return enu_to_geodetic(self.enu_m(), *self.home)

    def point_llh(self, x_m: float, y_m: float) -> tuple[float, float]:
        enu = rotate_about_up(np.array([x_m, y_m, 0.0]), np.radians(90.0 - self.heading_deg))
        lat, lon, _ = enu_to_geodetic(enu, *self.home)
        return float(lat), float(lon)


def _phases(dt: float, *segments: tuple[float, Callable[[Array], Array]]) -> tuple[Array, Array]:
    """Concatenate segments (duration_s, f(tau) -> (n,3)) sampled every dt."""
    ts, ps, t0 = [], [], 0.0
    for duration, f in segments:
        tau = np.arange(0.0, duration, dt)
        ts.append(t0 + tau)
        ps.append(f(tau))
        t0 += duration
    return np.concatenate(ts), np.concatenate(ps)


def _at(x: float, y: float, z: float):
    return lambda tau: np.tile([x, y, z], (tau.size, 1)).astype(float)


def _vertical(x: float, y: float, z0: float, rate_mps: float):
    """Straight up (rate > 0) or down from height z0 over the point (x, y)."""
    return lambda tau: np.column_stack(
        [np.full(tau.size, x), np.full(tau.size, y), z0 + rate_mps * tau]
    )


def _with_ground(
    dt: float,
    climb_to: tuple[float, float, float],
    flight,
    land_at: tuple[float, float],
    climb_mps: float = 1.0,
    descent_mps: float = 0.5,
    pre_s: float = 2.0,
    post_s: float = 2.0,
) -> Flight:
    """Ground (disarmed 1 s, armed `pre_s`), vertical climb, `flight`, descent, ground."""
    x0, y0, zc = climb_to
    fly_s, fly = flight
    end = fly(np.array([fly_s]))[0]
    t, p = _phases(
        dt,
        (1.0, _at(x0, y0, 0.0)),
        (pre_s, _at(x0, y0, 0.0)),
        (zc / climb_mps, _vertical(x0, y0, 0.0, climb_mps)),
        (fly_s, fly),
        (end[2] / descent_mps, _vertical(land_at[0], land_at[1], end[2], -descent_mps)),
        (post_s, _at(land_at[0], land_at[1], 0.0)),
    )
    armed = (t >= 1.0) & (t < t[-1] - post_s / 2)
    return Flight(t_s=t, xyz_m=p, armed=armed)


def hover_flight(
    radius_m: float = 0.3,
    height_m: float = 4.0,
    bob_m: float = 0.1,
    hover_s: float = 24.0,
    dt: float = 0.02,
    heading_deg: float = 90.0,
) -> Flight:
    """Climb to `height_m` while drifting out to a circle of `radius_m`, then circle it
    (distance to origin = radius exactly) with height bobbing +-bob_m at 0.5 Hz
    (height std over whole periods = bob/sqrt(2))."""
    climb = height_m  # at 1 m/s

    def climb_f(tau: Array) -> Array:
        r = radius_m * tau / climb
        return np.column_stack([r, np.zeros_like(tau), tau])

    def hover_f(tau: Array) -> Array:
        w = 2 * np.pi / 8.0
        return np.column_stack(
            [
                radius_m * np.cos(w * tau),
                radius_m * np.sin(w * tau),
                height_m + bob_m * np.sin(2 * np.pi * 0.5 * tau),
            ]
        )

    t, p = _phases(
        dt,
        (1.0, _at(0, 0, 0)),
        (2.0, _at(0, 0, 0)),
        (climb, climb_f),
        (hover_s, hover_f),
        (height_m / 0.5, _vertical(radius_m, 0.0, height_m, -0.5)),
        (2.0, _at(radius_m, 0, 0)),
    )
    return Flight(t_s=t, xyz_m=p, armed=(t >= 1.0) & (t < t[-1] - 1.0), heading_deg=heading_deg)


def a_to_b_flight(
    length_m: float = 40.0,
    height_m: float = 3.0,
    lateral_amp_m: float = 0.5,
    lateral_wavelength_m: float = 6.0,
    height_amp_m: float = 0.2,
    speed_mps: float = 1.2,
    dt: float = 0.02,
    heading_deg: float = 90.0,
) -> Flight:
    """Straight from x=0 to x=length at `speed_mps`, weaving y = A sin(2 pi x / wavelength)
    (std A/sqrt(2) over whole wavelengths) and z = h + a sin(2 pi x / 12)."""
    fly_s = length_m / speed_mps

    def fly(tau: Array) -> Array:
        x = speed_mps * tau
        return np.column_stack(
            [
                x,
                lateral_amp_m * np.sin(2 * np.pi * x / lateral_wavelength_m),
                height_m + height_amp_m * np.sin(2 * np.pi * x / 12.0),
            ]
        )

    f = _with_ground(dt, (0.0, 0.0, height_m), (fly_s, fly), (length_m, 0.0))
    return dataclasses.replace(f, heading_deg=heading_deg)


def figure8_flight(
    centre_x_m: float = 20.0,
    half_length_m: float = 10.0,
    half_width_m: float = 4.0,
    height_m: float = 3.0,
    lap_s: float = 60.0,
    dt: float = 0.02,
    heading_deg: float = 90.0,
) -> Flight:
    """Out along +x to the 8's centre, one lap of the lemniscate-like curve
    x = c + L sin(th), y = W sin(2 th), back to the start pad."""
    leg_s = centre_x_m / 1.2

    def out(tau: Array) -> Array:
        return np.column_stack([1.2 * tau, np.zeros_like(tau), np.full(tau.size, height_m)])

    def eight(tau: Array) -> Array:
        th = 2 * np.pi * tau / lap_s
        return np.column_stack(
            [
                centre_x_m + half_length_m * np.sin(th),
                half_width_m * np.sin(2 * th),
                np.full(tau.size, height_m),
            ]
        )

    def back(tau: Array) -> Array:
        x = centre_x_m - 1.2 * tau
        return np.column_stack([x, np.zeros_like(tau), np.full(tau.size, height_m)])

    total = 2 * leg_s + lap_s

    def fly(tau: Array) -> Array:
        return np.where(
            (tau < leg_s)[:, None],
            out(tau),
            np.where((tau < leg_s + lap_s)[:, None], eight(tau - leg_s), back(tau - leg_s - lap_s)),
        )

    f = _with_ground(dt, (0.0, 0.0, height_m), (total, fly), (0.0, 0.0))
    return dataclasses.replace(f, heading_deg=heading_deg)


# ---------------------------------------------------------------- writers


def write_session(
    flight: Flight,
    folder: Path,
    gps_hz: float = 10.0,
    wall_t0: float = 1.7e9,
    fix_type: int = 3,
    meta: dict | None = None,
) -> Path:
    """A session folder whose `telemetry.csv` has one row per dense sample (the telemetry
    rate) and GPS values held between GPS updates, as the recorder writes them."""
    import json

    folder.mkdir(parents=True, exist_ok=True)
    t = flight.t_s
    llh = flight.llh()
    # GPS sample-and-hold: each row shows the last GPS solution at or before it.
    gps_i = np.searchsorted(t, np.floor(t * gps_hz) / gps_hz - 1e-9, side="left")
    gps_i = np.clip(gps_i, 0, t.size - 1)
    vel = np.gradient(flight.xyz_m, t, axis=0)
    n = t.size
    # The recorder's own header and cell format, so tests read what the recorder writes.
    cols = {name: np.full(n, "", dtype=object) for name in layout.telemetry_columns()}

    def put(name: str, values, fmt: str = "%.3f") -> None:
        cols[name] = np.char.mod(fmt, np.asarray(values))

    put("t_s", t)
    put("wall_time", wall_t0 + t, "%.6f")
    put("gps.t_mono", 1000.0 + t[gps_i], "%.6f")
    put("gps.time_usec", np.round(t[gps_i] * 1e6).astype(np.int64), "%d")
    put("gps.fix_type", np.full(n, fix_type), "%d")
    put("gps.satellites", np.full(n, 12), "%d")
    put("gps.lat_deg", llh[gps_i, 0], "%.9f")
    put("gps.lon_deg", llh[gps_i, 1], "%.9f")
    put("gps.alt_m", llh[gps_i, 2], "%.4f")
    put("gps.ground_speed_mps", np.hypot(vel[gps_i, 0], vel[gps_i, 1]))
    put("global_position.t_mono", 1000.0 + t)
    put("global_position.lat_deg", llh[:, 0], "%.9f")
    put("global_position.lon_deg", llh[:, 1], "%.9f")
    put("global_position.alt_m", llh[:, 2], "%.4f")
    put("global_position.relative_alt_m", flight.xyz_m[:, 2])
    put("altitude.relative_alt_m", flight.xyz_m[:, 2])
    put("vfr_hud.ground_speed_mps", np.hypot(vel[:, 0], vel[:, 1]))
    put("vfr_hud.climb_mps", vel[:, 2])
    cols["heartbeat.armed"] = np.where(flight.armed, "1", "0")
    cols["heartbeat.mode"] = np.full(n, "POSCTL", dtype=object)
    seq = np.floor(t * 30.0).astype(np.int64)  # cameras at 30 fps
    for cam in layout.CAMERAS:
        put(f"{cam}.seq", seq, "%d")
        cols[f"{cam}.file"] = np.array([layout.frame_relpath(cam, int(k)) for k in seq], object)
        put(f"{cam}.t_wall", wall_t0 + seq / 30.0, "%.6f")
        put(f"{cam}.skew_s", t - seq / 30.0, "%.6f")
    table = np.column_stack([np.asarray(v, dtype=object) for v in cols.values()])
    lines = [",".join(cols)] + [",".join(row) for row in table.tolist()]
    (folder / layout.TELEMETRY_CSV).write_text("\n".join(lines) + "\n")
    if meta is not None:
        (folder / layout.SESSION_JSON).write_text(json.dumps(meta))
    return folder


def write_tlog(flight: Flight, path: Path, gps_hz: float = 10.0, wall_t0: float = 1.7e9) -> Path:
    """A real .tlog: HEARTBEAT at 1 Hz, GPS_RAW_INT at `gps_hz`, GLOBAL_POSITION_INT, each
    packed by pymavlink and prefixed by its 8-byte big-endian microsecond timestamp."""
    from pymavlink.dialects.v20 import common as mav

    link = mav.MAVLink(None, srcSystem=1, srcComponent=1)
    t = flight.t_s
    llh = flight.llh()
    vel = np.gradient(flight.xyz_m, t, axis=0)
    gps_t = np.arange(0.0, t[-1], 1.0 / gps_hz)
    gi = np.clip(np.searchsorted(t, gps_t), 0, t.size - 1)
    events: list[tuple[float, bytes]] = []
    for k in range(int(t[-1]) + 1):
        i = min(int(np.searchsorted(t, float(k))), t.size - 1)
        armed = mav.MAV_MODE_FLAG_SAFETY_ARMED if flight.armed[i] else 0
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | armed
        msg = link.heartbeat_encode(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_PX4, base, 0, 4)
        events.append((float(k), msg.pack(link)))
    for tk, i in zip(gps_t, gi):
        lat, lon = int(round(llh[i, 0] * 1e7)), int(round(llh[i, 1] * 1e7))
        alt = int(round(llh[i, 2] * 1000))
        speed = int(round(100 * np.hypot(vel[i, 0], vel[i, 1])))
        msg = link.gps_raw_int_encode(int(tk * 1e6), 3, lat, lon, alt, 80, 120, speed, 0, 12)
        events.append((float(tk) + 1e-4, msg.pack(link)))
        msg = link.global_position_int_encode(
            int(tk * 1000), lat, lon, alt, int(round(flight.xyz_m[i, 2] * 1000)), 0, 0, 0, 0
        )
        events.append((float(tk) + 2e-4, msg.pack(link)))
    events.sort(key=lambda e: e[0])
    with open(path, "wb") as f:
        for tk, packet in events:
            f.write(int((wall_t0 + tk) * 1e6).to_bytes(8, "big") + packet)
    return path


def write_frames(folder, camera: str, n: int, fps: float = 5.0) -> None:
    """A camera folder as the recorder writes it (session format 2): the JPEGs back to
    back in frames.mjpeg, and frames.csv with each one's name, offset and size."""
    (folder / camera).mkdir(parents=True, exist_ok=True)
    offset = 0
    with (
        open(folder / layout.frames_csv_relpath(camera), "w", newline="") as f,
        open(folder / layout.frames_pack_relpath(camera), "wb") as pack,
    ):
        w = csv.writer(f)
        w.writerow(layout.FRAME_COLUMNS)
        for seq in range(n):
            img = np.full((48, 64, 3), (seq * 7) % 255, np.uint8)
            ok, jpeg = cv2.imencode(".jpg", img)
            pack.write(jpeg.tobytes())
            rel = layout.frame_relpath(camera, seq)
            row = (seq, rel, round(seq / fps, 6), 1.7e9 + seq / fps, 64, 48, len(jpeg), offset)
            w.writerow(row)
            offset += len(jpeg)


def drop_fix(folder, t0_s: float, t1_s: float) -> None:
    """Turn the GPS fix off between t0 and t1 (a real dropout: rows stay, fix goes)."""
    path = folder / "telemetry.csv"
    lines = path.read_text().splitlines()
    header = lines[0].split(",")
    i_t, i_fix = header.index("t_s"), header.index("gps.fix_type")
    out = [lines[0]]
    for line in lines[1:]:
        cells = line.split(",")
        if t0_s <= float(cells[i_t]) < t1_s:
            cells[i_fix] = "0"
        out.append(",".join(cells))
    path.write_text("\n".join(out) + "\n")


# Two recorded sessions: an a-to-b flight with both cameras' frames and a 3 s GPS
# dropout, and a figure 8 (no frames), for the replay and session pages.
SESSION_A = "20261122T040000Z_sim"
SESSION_B = "20261122T041000Z_serial"


def write_two_sessions(root: Path) -> Path:
    """SESSION_A and SESSION_B under `root` (returned)."""
    a = write_session(a_to_b_flight(heading_deg=30.0), root / SESSION_A)
    drop_fix(a, 20.0, 23.0)
    write_frames(a, "front", 250)
    write_frames(a, "bottom", 250)
    write_session(figure8_flight(heading_deg=120.0), root / SESSION_B)
    return root


def state_at(t_s: float) -> VehicleState:
    """The vehicle's state `t_s` into a figure 8 at 3-6 m, 12 m across, about FIELD_HOME,
    as the link publishes it."""
    e, n, u = 12 * math.sin(t_s / 4), 6 * math.sin(t_s / 2), 3 + 3 * (1 - math.cos(t_s / 8)) / 2
    lat, lon, alt = (float(v) for v in enu_to_geodetic([e, n, u], *FIELD_HOME))
    return VehicleState(
        gps=GpsRaw(t_mono=t_s, fix_type=3, lat_deg=lat, lon_deg=lon, alt_m=alt),
        global_position=GlobalPosition(
            t_mono=t_s, lat_deg=lat, lon_deg=lon, alt_m=alt, vx_mps=1.0, vy_mps=1.0
        ),
        attitude=Attitude(t_mono=t_s, roll_rad=0.1, pitch_rad=0.0, yaw_rad=t_s / 4),
    )


# Three recorded sessions for the analysis API: an a-to-b flight from a physical vehicle,
# a wider one flown on the twin, and the physical one again without a GPS fix.
ANALYSIS_PHYSICAL = "20261122T040000Z_udp"
ANALYSIS_TWIN = "20261122T040500Z_sim"
ANALYSIS_NOFIX = "20261122T041000Z_udp"
ANALYSIS_HEADING = 35.0


def write_analysis_sessions(root: Path) -> Flight:
    """The three under `root`; returns the physical flight (its points place references)."""
    real = a_to_b_flight(lateral_amp_m=0.5, heading_deg=ANALYSIS_HEADING)
    twin = a_to_b_flight(lateral_amp_m=1.0, height_m=3.5, heading_deg=ANALYSIS_HEADING)
    physical = {"id": ANALYSIS_PHYSICAL, "source": "udpin:0.0.0.0:14550"}
    write_session(real, root / ANALYSIS_PHYSICAL, meta=physical)
    write_session(twin, root / ANALYSIS_TWIN, meta={"id": ANALYSIS_TWIN, "source": "sim"})
    write_session(real, root / ANALYSIS_NOFIX, fix_type=0)
    return real
