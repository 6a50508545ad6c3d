"""Sensors of the twin: GPS (M8N-like), barometer and the autopilot's state estimate.

Errors are Gauss-Markov drifts (slow, as a real receiver wanders) plus white noise, from a
seeded generator. The estimate the controller flies on follows the GPS drift horizontally
and the baro drift vertically, as PX4's EKF does, so a held position wanders the way
the paper's physical hover did (by less without noise). Positions are georeferenced at the
scene's home (WGS-84, through the same geodesy as the analysis).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fpv_station.core.geodesy import enu_to_geodetic
from fpv_station.core.scene import Home


@dataclass(frozen=True)
class SensorParams:
    gps_rate_hz: float = 5.0
    gps_fix_delay_s: float = 2.0
    gps_drift_std_m: float = 0.2  # horizontal, per axis
    gps_drift_tau_s: float = 100.0
    gps_noise_std_m: float = 0.05
    gps_vert_drift_std_m: float = 0.4
    gps_vel_noise_std_mps: float = 0.05
    gps_eph_m: float = 0.9
    gps_satellites: int = 14
    baro_drift_std_m: float = 0.1
    baro_drift_tau_s: float = 30.0
    baro_noise_std_m: float = 0.03
    attitude_noise_std_rad: float = 0.002
    enabled: bool = True  # False = perfect sensors (tests, ground truth studies)


@dataclass
class GpsFix:
    """One receiver solution of one vehicle (GPS_RAW_INT)."""

    t_s: float
    fix_type: int
    satellites: int
    lat_deg: float
    lon_deg: float
    alt_m: float
    eph_m: float
    epv_m: float
    vel_enu_mps: np.ndarray

    @property
    def ground_speed_mps(self) -> float:
        return float(np.hypot(self.vel_enu_mps[0], self.vel_enu_mps[1]))

    @property
    def course_deg(self) -> float:
        return float(np.degrees(np.arctan2(self.vel_enu_mps[0], self.vel_enu_mps[1])) % 360)


class Sensors:
    def __init__(self, n: int, home: Home, params: SensorParams, rng: np.random.Generator):
        self.p, self.home, self.rng, self.n = params, home, rng, n
        scale = 1.0 if params.enabled else 0.0
        self._scale = scale
        self.gps_drift_m = (
            rng.standard_normal((n, 3))
            * scale
            * np.array(
                [params.gps_drift_std_m, params.gps_drift_std_m, params.gps_vert_drift_std_m]
            )
        )
        self.baro_drift_m = rng.standard_normal(n) * scale * params.baro_drift_std_m
        self.satellites = np.full(n, params.gps_satellites)
        self._next_gps_s = 0.0
        self.last_fix: list[GpsFix | None] = [None] * n

    def redraw(self, idx: np.ndarray) -> None:
        """New drift states for reset vehicles (a receiver that was switched off and on)."""
        p, k = self.p, len(idx)
        std = np.array([p.gps_drift_std_m, p.gps_drift_std_m, p.gps_vert_drift_std_m])
        self.gps_drift_m[idx] = self.rng.standard_normal((k, 3)) * std * self._scale
        self.baro_drift_m[idx] = self.rng.standard_normal(k) * p.baro_drift_std_m * self._scale

    def has_fix(self, t_s: float) -> bool:
        return t_s >= self.p.gps_fix_delay_s

    def update(self, dt: float) -> None:
        """Advance the drift processes by dt (called at the outer-loop rate)."""
        if not self._scale:
            return
        p = self.p
        k = dt / p.gps_drift_tau_s
        std = np.array([p.gps_drift_std_m, p.gps_drift_std_m, p.gps_vert_drift_std_m])
        self.gps_drift_m += -self.gps_drift_m * k + std * np.sqrt(2 * k) * self.rng.standard_normal(
            (self.n, 3)
        )
        kb = dt / p.baro_drift_tau_s
        self.baro_drift_m += -self.baro_drift_m * kb + p.baro_drift_std_m * np.sqrt(
            2 * kb
        ) * self.rng.standard_normal(self.n)

    def estimate(self, pos_m: np.ndarray, vel_mps: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The autopilot's position and velocity estimate (ENU): GPS drift in x/y, baro in z."""
        est = pos_m.copy()
        est[:, :2] += self.gps_drift_m[:, :2]
        est[:, 2] += self.baro_drift_m
        return est, vel_mps

    def baro_alt_m(self, pos_m: np.ndarray) -> np.ndarray:
        noise = self.rng.standard_normal(self.n) * self.p.baro_noise_std_m * self._scale
        return self.home.alt_m + pos_m[:, 2] + self.baro_drift_m + noise

    def attitude_noise(self) -> np.ndarray:
        return self.rng.standard_normal((self.n, 3)) * self.p.attitude_noise_std_rad * self._scale

    def poll_gps(self, t_s: float, pos_m: np.ndarray, vel_mps: np.ndarray) -> list[GpsFix] | None:
        """New GPS solutions for every vehicle when one is due at sim time `t_s`, else None."""
        if t_s + 1e-9 < self._next_gps_s:
            return None
        self._next_gps_s = max(self._next_gps_s + 1.0 / self.p.gps_rate_hz, t_s)
        p, s = self.p, self._scale
        fix = self.has_fix(t_s)
        noisy = (
            pos_m
            + self.gps_drift_m
            + self.rng.standard_normal((self.n, 3)) * (p.gps_noise_std_m * s)
        )
        vel = vel_mps + self.rng.standard_normal((self.n, 3)) * p.gps_vel_noise_std_mps * s
        if s and self.rng.random() < 0.02:  # satellites come and go slowly
            self.satellites = np.clip(self.satellites + self.rng.integers(-1, 2, self.n), 8, 20)
        geo = enu_to_geodetic(noisy, self.home.lat_deg, self.home.lon_deg, self.home.alt_m)
        eph = p.gps_eph_m * 14.0 / self.satellites
        fixes = [
            GpsFix(
                t_s=t_s,
                fix_type=3 if fix else 1,
                satellites=int(self.satellites[i]) if fix else 3,
                lat_deg=float(geo[i, 0]),
                lon_deg=float(geo[i, 1]),
                alt_m=float(geo[i, 2]),
                eph_m=float(eph[i]) if fix else 99.99,
                epv_m=float(eph[i] * 1.5) if fix else 99.99,
                vel_enu_mps=vel[i].copy(),
            )
            for i in range(self.n)
        ]
        self.last_fix = list(fixes)
        return fixes
