"""Rigid-body flight model of the paper's F450, vectorized over a batch of N vehicles.

Frames: world ENU (x east, y north, z up); body FLU (x forward, y left, z up);
`R_world_body` (N, 3, 3) maps body vectors to world. Rotors in PX4's quad-X order:
1 front-right (CCW), 2 rear-left (CCW), 3 front-left (CW), 4 rear-right (CW).

Each step is a fixed dt (>= 250 Hz): first-order motor lag towards the commanded speed,
thrust k_T w^2, reaction torque, linear + quadratic drag against the air (`Wind`: a mean,
gusts and Dryden-like turbulence; calm by default), semi-implicit Euler, ground contact, and crash detection
against the ground (impact speed), the obstacles and the boundary net. The battery (3S
5500 mAh) sags under load: the terminal voltage limits the motors' top speed and the
electric power is calibrated so that a hover lasts about 11 minutes.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, field

import numpy as np

GRAVITY_MPS2 = 9.80665
CRASH_NONE, CRASH_GROUND, CRASH_OBSTACLE, CRASH_NET = 0, 1, 2, 3
CRASH_REASONS = {
    CRASH_NONE: "",
    CRASH_GROUND: "ground impact",
    CRASH_OBSTACLE: "obstacle",
    CRASH_NET: "boundary net",
}


@dataclass(frozen=True)
class Airframe:
    """F450, 920 Kv motors, 9.4 in props, 3S 5500 mAh: the paper's vehicle."""

    mass_kg: float = 1.52
    arm_m: float = 0.225  # centre to motor (450 mm diagonal)
    inertia_kg_m2: tuple[float, float, float] = (0.0150, 0.0150, 0.0280)
    motor_tau_s: float = 0.04
    kv_rpm_per_v: float = 920.0
    motor_load_factor: float = 0.85  # loaded speed / no-load speed
    thrust_coeff_n_per_rad2: float = 1.25e-5
    yaw_moment_per_thrust_m: float = 0.016
    drag_linear_n_per_mps: float = 0.25
    drag_quadratic_n_per_mps2: float = 0.03
    rot_drag_nm_per_rad_s: float = 0.004
    idle_throttle: float = 0.08
    cells: int = 3
    capacity_ah: float = 5.5
    internal_resistance_ohm: float = 0.018
    avionics_w: float = 8.0  # Pixhawk, Pi, cameras, video transmitters
    # Electric power per rotor = coeff * thrust^1.5: momentum theory with a lumped
    # efficiency, calibrated so that hovering at 1.52 kg drains 90 % of the pack
    # (down to the 10 % failsafe) in about 11 minutes (tests/test_twin_physics.py).
    power_coeff_w_per_n1_5: float = 10.0
    frame_radius_m: float = 0.30  # for collisions with obstacles and the net
    crash_speed_mps: float = 3.0  # vertical touchdown speed that breaks the airframe

    @property
    def weight_n(self) -> float:
        return self.mass_kg * GRAVITY_MPS2

    @property
    def kv_rad_s_per_v(self) -> float:
        return self.kv_rpm_per_v * 2 * np.pi / 60 * self.motor_load_factor

    def mixer(self) -> np.ndarray:
        """A (4, 4): [thrust_n, tau_x, tau_y, tau_z] = A @ rotor thrusts (FLU body)."""
        a = self.arm_m / np.sqrt(2)
        x = np.array([a, -a, a, -a])  # forward positions of rotors 1..4
        y = np.array([-a, a, a, -a])  # left positions
        spin = np.array([-1.0, -1.0, 1.0, 1.0])  # CCW rotors push the body clockwise
        return np.vstack([np.ones(4), y, -x, spin * self.yaw_moment_per_thrust_m])


def ocv_per_cell_v(soc: np.ndarray) -> np.ndarray:
    """LiPo open-circuit voltage against state of charge (typical discharge curve)."""
    return np.interp(
        soc, [0.0, 0.05, 0.1, 0.2, 0.5, 0.8, 1.0], [3.0, 3.45, 3.6, 3.7, 3.8, 3.95, 4.2]
    )


@dataclass(frozen=True)
class Wind:
    """The air the vehicles fly in: a mean wind, gusts and turbulence (all ENU, m/s).

    - Gusts: a first-order Gauss-Markov process on each axis (std `gust_std_mps`,
      correlation time `gust_tau_s`): the wind's changes over seconds.
    - Turbulence: Dryden-like, the low-altitude form of MIL-F-8785C with first-order
      shaping filters (the u filter is Dryden's; v and w keep its variance and length
      scale without the second-order zero). `turbulence_std_mps` is the horizontal sigma
      (sigma_u = sigma_v); sigma_w = sigma_u (0.177 + 0.000823 h)^0.4, length scales
      L_u = L_v = h / (0.177 + 0.000823 h)^1.2 and L_w = h (h the vehicle's height in
      feet, held within 10-1000 ft), swept past at the vehicle's airspeed (at least
      1 m/s: the mean wind carries the eddies past a hovering vehicle).
    Both start from their stationary distribution, so an episode starts in gusty air.
    """

    mean_enu_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_std_mps: float = 0.0
    gust_tau_s: float = 2.0
    turbulence_std_mps: float = 0.0

    def __post_init__(self) -> None:
        if len(self.mean_enu_mps) != 3 or not np.all(np.isfinite(self.mean_enu_mps)):
            raise ValueError(f"mean_enu_mps must be 3 finite numbers, not {self.mean_enu_mps}")
        if not (self.gust_std_mps >= 0 and self.turbulence_std_mps >= 0):
            raise ValueError("gust_std_mps and turbulence_std_mps must be >= 0")
        if not self.gust_tau_s > 0:
            raise ValueError(f"gust_tau_s must be > 0, not {self.gust_tau_s}")

    @property
    def calm(self) -> bool:
        return not (any(self.mean_enu_mps) or self.gust_std_mps or self.turbulence_std_mps)

    @classmethod
    def parse(cls, value: Wind | dict | None) -> Wind | None:
        """A `Wind`, or one from a mapping of its fields (env options, JSON); None stays."""
        if value is None or isinstance(value, Wind):
            return value
        if not isinstance(value, dict):
            raise ValueError(f"wind must be a mapping of Wind's fields, not {value!r}")
        unknown = set(value) - set(cls.__dataclass_fields__)
        if unknown:
            raise ValueError(f"unknown wind fields: {', '.join(sorted(unknown))}")
        kw = dict(value)
        if "mean_enu_mps" in kw:
            kw["mean_enu_mps"] = tuple(float(v) for v in kw["mean_enu_mps"])
        return cls(**kw)


_FT = 0.3048


def dryden_low_altitude(height_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sigma ratios, length scales in m), each (N, 3) for (u, v, w) at the heights:
    sigma relative to the horizontal sigma; see `Wind`."""
    h = np.clip(np.asarray(height_m, float) / _FT, 10.0, 1000.0)
    den = 0.177 + 0.000823 * h
    L_uv = h / den**1.2 * _FT
    ratio = np.column_stack([np.ones_like(h), np.ones_like(h), den**0.4])
    return ratio, np.column_stack([L_uv, L_uv, h * _FT])


@dataclass
class BodyState:
    """The true state of N vehicles (arrays, first axis = vehicle)."""

    pos_m: np.ndarray  # (N, 3) ENU
    vel_mps: np.ndarray  # (N, 3) ENU
    R_world_body: np.ndarray  # (N, 3, 3)
    omega_rad_s: np.ndarray  # (N, 3) body rates
    rotor_rad_s: np.ndarray  # (N, 4)
    charge_c: np.ndarray  # (N,) coulombs left
    voltage_v: np.ndarray  # (N,) terminal voltage
    current_a: np.ndarray  # (N,)
    rotor_thrust_n: np.ndarray  # (N, 4)
    on_ground: np.ndarray  # (N,) bool
    crash: np.ndarray  # (N,) int, CRASH_* code of the first crash
    wind_mps: np.ndarray  # (N, 3) current air velocity (mean + gust + turbulence)
    gust_mps: np.ndarray  # (N, 3) the gust part of it
    turbulence_mps: np.ndarray  # (N, 3) the turbulence part of it

    @property
    def n(self) -> int:
        return self.pos_m.shape[0]


# The clip ufunc: one call with an output, unlike the np.clip wrapper. Looked up by
# name: numpy's stubs leave it out.
try:
    _umath = importlib.import_module("numpy._core.umath")
except ImportError:  # numpy < 2
    _umath = importlib.import_module("numpy.core.umath")
_clip: np.ufunc = _umath.clip
_min = np.minimum.reduce


def _per_rotor(x: np.ndarray) -> np.ndarray:
    """(N,) -> (N, 4): same-shape operands keep numpy's per-call cost down."""
    return np.repeat(x[:, None], 4, axis=1)


def yaw_matrix(yaw_rad: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw_rad), np.sin(yaw_rad)
    R = np.zeros((len(yaw_rad), 3, 3))
    R[:, 0, 0], R[:, 0, 1], R[:, 1, 0], R[:, 1, 1], R[:, 2, 2] = c, -s, s, c, 1.0
    return R


@dataclass
class Dynamics:
    """Integrates `BodyState` under motor commands in [0, 1]; owns the scene's colliders."""

    airframe: Airframe = field(default_factory=Airframe)
    dt_s: float = 1 / 250
    wind: Wind = field(default_factory=Wind)
    obstacle_boxes_m: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))
    net_half_extent_m: tuple[float, float] | None = None  # (x, y) half sizes of the netted area
    net_height_m: float = 0.0
    seed: int | None = 0

    def __post_init__(self) -> None:
        if self.dt_s > 1 / 250 + 1e-12:
            raise ValueError(f"dt_s={self.dt_s} is coarser than 250 Hz; the model needs >= 250 Hz.")
        af = self.airframe
        self._A_T = af.mixer().T.copy()
        self._J = np.asarray(af.inertia_kg_m2, float)
        self._motor_alpha = 1.0 - np.exp(-self.dt_s / af.motor_tau_s)
        self._g = np.array([0.0, 0.0, -GRAVITY_MPS2])
        self._rng = np.random.default_rng(self.seed)
        self._steps = 0
        self._dt_over_J = self.dt_s / self._J
        self._dJ = self._J[[2, 0, 1]] - self._J[[1, 2, 0]]
        self._rot_keep = 1.0 - af.rot_drag_nm_per_rad_s * self._dt_over_J
        self._dt_over_m = self.dt_s / af.mass_kg
        self._drag_lin_dt = af.drag_linear_n_per_mps * self._dt_over_m
        self._drag_quad_dt = af.drag_quadratic_n_per_mps2 * self._dt_over_m
        self._g_dt = self._g * self.dt_s
        self._grounded = True
        # (3, 9) generator: w @ G = dt * skew(w) flattened row-major.
        G = np.zeros((3, 9))
        G[2, 1], G[1, 2], G[0, 5] = -1, 1, -1
        G[2, 3], G[1, 6], G[0, 7] = 1, -1, 1
        self._skew_gen = G * self.dt_s
        self._w_max_alive = np.zeros((0, 4))
        # phi = [1, w (3), w w^T (9, row-major), rotor thrust (4)].
        # P: phi[:4] -> (w_i, w_j) for every (i, j), so that w w^T is one product.
        P = np.zeros((4, 18))
        for i in range(3):
            for j in range(3):
                P[1 + i, 3 * i + j] = P[1 + j, 9 + 3 * i + j] = 1.0
        self._P = P
        # B: phi -> [thrust dt/m (x3), new w = w + d omega, P of the new w].
        d_w = np.zeros((17, 3))
        d_w[13:] = self._A_T[:, 1:] * self._dt_over_J
        d_w[1:4] = np.diag(self._rot_keep)  # w itself, damped by the rotor wash
        for row, (a, b) in enumerate([(1, 2), (2, 0), (0, 1)]):  # gyro: w_a w_b (J_b - J_a)
            d_w[4 + 3 * a + b, row] = -self._dJ[row] * self._dt_over_J[row]
        to_pairs = np.zeros((17, 18))
        for i in range(3):
            for j in range(3):
                to_pairs[:, 3 * i + j], to_pairs[:, 9 + 3 * i + j] = d_w[:, i], d_w[:, j]
        B = np.zeros((17, 24))
        B[13:, :3] = self._dt_over_m
        B[:, 3:6] = d_w
        B[:, 6:] = to_pairs
        self._B = B
        # G: phi -> (I + S + S^2 / 2).flat with S = [w dt]x, S^2 = dt^2 (w w^T - |w|^2 I).
        G = np.zeros((17, 9))
        eye = np.eye(3).ravel()
        G[0] = eye
        G[1:4] = self._skew_gen
        G[4:13] = 0.5 * self.dt_s**2 * (np.eye(9) - np.outer(eye, eye))
        self._G = G
        self._ones33 = np.ones((3, 3))
        self._bound: tuple | None = None
        self._boxes: tuple | None = None

    def initial_state(
        self, n: int, xy_m: np.ndarray, yaw_rad: float | np.ndarray = 0.0
    ) -> BodyState:
        """`n` vehicles on the ground at `xy_m` ((2,) or (n, 2)) heading `yaw_rad` (scalar
        or (n,)), disarmed, battery full, in the wind's air (gusts and turbulence drawn
        from their stationary distribution)."""
        af = self.airframe
        pos = np.zeros((n, 3))
        pos[:, :2] = xy_m
        charge = np.full(n, af.capacity_ah * 3600.0)
        volt = np.full(n, af.cells * float(ocv_per_cell_v(np.array(1.0))))
        self._w_max_alive = _per_rotor(af.kv_rad_s_per_v * volt)
        self._grounded = True
        state = BodyState(
            pos_m=pos,
            vel_mps=np.zeros((n, 3)),
            R_world_body=yaw_matrix(np.broadcast_to(np.asarray(yaw_rad, float), (n,))),
            omega_rad_s=np.zeros((n, 3)),
            rotor_rad_s=np.zeros((n, 4)),
            charge_c=charge,
            voltage_v=volt,
            current_a=np.zeros(n),
            rotor_thrust_n=np.zeros((n, 4)),
            on_ground=np.ones(n, bool),
            crash=np.zeros(n, int),
            wind_mps=np.zeros((n, 3)),
            gust_mps=np.zeros((n, 3)),
            turbulence_mps=np.zeros((n, 3)),
        )
        w = self.wind
        if w.gust_std_mps > 0:
            state.gust_mps[:] = w.gust_std_mps * self._rng.standard_normal((n, 3))
        if w.turbulence_std_mps > 0:
            ratio, _ = dryden_low_altitude(pos[:, 2])
            state.turbulence_mps[:] = (
                w.turbulence_std_mps * ratio * self._rng.standard_normal((n, 3))
            )
        self._air(state)
        return state

    def max_rotor_speed_rad_s(self, s: BodyState) -> np.ndarray:
        return self.airframe.kv_rad_s_per_v * s.voltage_v

    def _bind(self, s: BodyState) -> None:
        """Preallocate the step's work buffers for state `s` (once per state object).

        One vehicle pays numpy's per-call overhead, not arithmetic, and a call costs two to
        three times more when it broadcasts or takes a Python scalar, so the step is a few
        fused expressions on same-shape operands into these buffers. `s.omega_rad_s` and
        `s.rotor_thrust_n` become views into the feature row phi = [1, w, w w^T, thrust],
        from which one matmul gives every rate increment and another the rotation increment.
        """
        n = s.n
        phi = np.zeros((n, 17))
        phi[:, 0] = 1.0
        phi[:, 1:4] = s.omega_rad_s
        phi[:, 13:17] = s.rotor_thrust_n
        s.omega_rad_s, s.rotor_thrust_n = phi[:, 1:4], phi[:, 13:17]
        self._phi, self._phi_w, self._ww = phi[:, :4], phi, phi[:, 4:13]
        self._pairs = np.empty((n, 18))  # w_i and w_j for every (i, j): w w^T = product
        self._p1, self._p2 = self._pairs[:, :9], self._pairs[:, 9:]
        self._inc = np.empty((n, 24))  # [thrust dt/m (x3), new w, pairs of the new w]
        self._thrust3, self._w_new = self._inc[:, :3], self._inc[:, 3:6]
        self._q1, self._q2 = self._inc[:, 6:15], self._inc[:, 15:]
        self._u = np.empty((n, 4))
        self._M = np.empty((n, 9))
        self._M3 = self._M.reshape(n, 3, 3)
        self._R_new = np.empty((n, 3, 3))
        self._z_body = s.R_world_body[:, :, 2]
        self._va, self._dv, self._k = np.empty((n, 3)), np.empty((n, 3)), np.empty((n, 3))
        full = lambda shape, v: np.full(shape, v, float)  # noqa: E731
        self._c_zero4, self._c_one4 = full((n, 4), 0.0), full((n, 4), 1.0)
        self._c_alpha4 = full((n, 4), self._motor_alpha)
        self._c_kT4 = full((n, 4), self.airframe.thrust_coeff_n_per_rad2)
        self._c_quad3 = full((n, 3), self._drag_quad_dt)
        self._c_lin3 = full((n, 3), self._drag_lin_dt)
        self._c_g3, self._c_dt3 = np.tile(self._g_dt, (n, 1)), full((n, 3), self.dt_s)
        self._pz = s.pos_m[:, 2]
        self._bound = (s, s.R_world_body, s.pos_m, s.vel_mps, s.rotor_rad_s, s.wind_mps)

    def step(self, s: BodyState, throttle: np.ndarray) -> None:
        """Advance every vehicle by dt under per-rotor throttle (N, 4) in [0, 1]; in place.

        The fast part only (rotors, rigid body, ground); `collisions` (~50 Hz) and
        `slow_update` (~10 Hz: battery, gusts) run at lower rates from the caller.
        """
        b = self._bound
        if (
            b is None
            or s is not b[0]
            or s.R_world_body is not b[1]
            or s.pos_m is not b[2]
            or s.vel_mps is not b[3]
            or s.rotor_rad_s is not b[4]
            or s.wind_mps is not b[5]
        ):
            self._bind(s)
        mul, add, sub, mm = np.multiply, np.add, np.subtract, np.matmul
        u, r, f = self._u, s.rotor_rad_s, s.rotor_thrust_n
        _clip(throttle, self._c_zero4, self._c_one4, u)
        mul(u, self._w_max_alive, u)  # commanded rotor speed
        sub(u, r, u)
        mul(u, self._c_alpha4, u)
        add(r, u, r)  # first-order lag
        mul(r, self._c_kT4, f)
        mul(f, r, f)

        # Rotation: Euler's equations with a diagonal inertia (gyroscopic term
        # w x Jw = (wy wz (Jz - Jy), wz wx (Jx - Jz), wx wy (Jy - Jx))) and rotor-wash
        # damping are linear in phi = [1, w, w w^T, f]: one matmul gives the new w, the
        # thrust's dv and the factors of the new w w^T. Then R <- R exp([w dt]x) to second
        # order, I + S + S^2 / 2 with S^2 = dt^2 (w w^T - |w|^2 I), again linear in phi;
        # re-orthonormalized every 32 steps.
        mm(self._phi, self._P, self._pairs)
        mul(self._p1, self._p2, self._ww)
        mm(self._phi_w, self._B, self._inc)
        np.copyto(s.omega_rad_s, self._w_new)
        mul(self._q1, self._q2, self._ww)
        mm(self._phi_w, self._G, self._M)
        R = s.R_world_body
        mm(R, self._M3, self._R_new)
        np.copyto(R, self._R_new)
        self._steps += 1
        if self._steps % 32 == 0:
            U, _, Vt = np.linalg.svd(R)
            mm(U, Vt, R)

        # Translation: thrust along body z, gravity, drag against the air (all times dt).
        va, dv, k = self._va, self._dv, self._k
        sub(s.vel_mps, s.wind_mps, va)
        mul(va, va, dv)
        mm(dv, self._ones33, k)  # |v_air|^2 in every column
        np.sqrt(k, k)
        mul(k, self._c_quad3, k)
        add(k, self._c_lin3, k)
        mul(va, k, va)
        mul(self._z_body, self._thrust3, dv)
        sub(dv, va, dv)
        add(dv, self._c_g3, dv)
        add(s.vel_mps, dv, s.vel_mps)
        mul(s.vel_mps, self._c_dt3, dv)
        add(s.pos_m, dv, s.pos_m)
        if self._grounded or _min(self._pz) <= 0.0:
            self._ground(s)

    def revive(self, s: BodyState) -> None:
        """Recompute the motors' power after vehicles were reset in place."""
        alive = (s.crash == 0) & (s.charge_c > 0)
        self._w_max_alive = _per_rotor(self.airframe.kv_rad_s_per_v * s.voltage_v * alive)
        self._grounded = bool(s.on_ground.any() or (s.pos_m[:, 2] <= 0).any())

    def slow_update(self, s: BodyState, dt: float) -> None:
        """Battery and gusts, which change slowly (~10 Hz is plenty)."""
        self._battery(s, s.rotor_thrust_n, dt)
        w = self.wind
        if w.gust_std_mps > 0 or w.turbulence_std_mps > 0:
            self._gusts_and_turbulence(s, dt)
        alive = (s.crash == 0) & (s.charge_c > 0)
        self._w_max_alive = _per_rotor(self.airframe.kv_rad_s_per_v * s.voltage_v * alive)

    def _gusts_and_turbulence(self, s: BodyState, dt: float) -> None:
        """Advance both first-order processes by `dt`, exactly discretized
        (x <- a x + sigma sqrt(1 - a^2) n, a = exp(-dt / tau)), so the rate it runs at
        does not change their statistics."""
        w, rng = self.wind, self._rng
        if w.gust_std_mps > 0:
            a = np.exp(-dt / w.gust_tau_s)
            s.gust_mps *= a
            s.gust_mps += (
                w.gust_std_mps * np.sqrt(1 - a * a) * rng.standard_normal(s.gust_mps.shape)
            )
        if w.turbulence_std_mps > 0:
            ratio, length = dryden_low_altitude(s.pos_m[:, 2])
            air = np.linalg.norm(s.vel_mps - s.wind_mps, axis=1)
            a = np.exp(-dt * np.maximum(air, 1.0)[:, None] / length)
            s.turbulence_mps *= a
            s.turbulence_mps += (
                w.turbulence_std_mps
                * ratio
                * np.sqrt(1 - a * a)
                * rng.standard_normal(s.turbulence_mps.shape)
            )
        self._air(s)

    def _air(self, s: BodyState) -> None:
        """The air velocity: mean + gust + turbulence, in place (the step holds the array)."""
        np.add(s.gust_mps, s.turbulence_mps, out=s.wind_mps)
        s.wind_mps += self.wind.mean_enu_mps

    def _battery(self, s: BodyState, f: np.ndarray, dt: float) -> None:
        af = self.airframe
        power_w = af.power_coeff_w_per_n1_5 * (f * np.sqrt(f)).sum(axis=1) + af.avionics_w
        soc = np.clip(s.charge_c / (af.capacity_ah * 3600.0), 0.0, 1.0)
        ocv = af.cells * ocv_per_cell_v(soc)
        # I = P / V with V = OCV - I R: the smaller root of R I^2 - OCV I + P = 0.
        disc = np.maximum(ocv * ocv - 4 * af.internal_resistance_ohm * power_w, 0.0)
        s.current_a = (ocv - np.sqrt(disc)) / (2 * af.internal_resistance_ohm)
        s.voltage_v = ocv - s.current_a * af.internal_resistance_ohm
        s.charge_c = np.maximum(s.charge_c - s.current_a * dt, 0.0)

    def collisions(self, s: BodyState) -> None:
        """Obstacles and the net (~50 Hz: 10 cm of travel at 5 m/s between checks)."""
        if self._boxes is None:  # obstacle boxes grown by the frame radius, once
            r, b = self.airframe.frame_radius_m, self.obstacle_boxes_m
            self._boxes = (b[:, 0] - r, b[:, 3] + r, b[:, 1] - r, b[:, 4] + r, b[:, 5] + 0.05)
        p = s.pos_m
        if len(self.obstacle_boxes_m):
            x0, x1, y0, y1, z1 = self._boxes
            x, y, z = p[:, :1], p[:, 1:2], p[:, 2:3]
            inside = ((x > x0) & (x < x1) & (y > y0) & (y < y1) & (z < z1)).any(axis=1)
            self._hit(s, inside, CRASH_OBSTACLE)  # stopped by the obstacle; it falls from there
        if self.net_half_extent_m is not None:
            r = self.airframe.frame_radius_m
            hx, hy = self.net_half_extent_m
            out = ((np.abs(p[:, 0]) > hx - r) | (np.abs(p[:, 1]) > hy - r)) & (
                p[:, 2] < self.net_height_m
            )
            self._hit(s, out, CRASH_NET)  # caught in the net

    def _hit(self, s: BodyState, touching: np.ndarray, code: int) -> None:
        hit = (s.crash == 0) & touching
        if hit.any():
            s.crash[hit] = code
            s.vel_mps[hit, :2] = 0.0
            self._w_max_alive[hit] = 0.0

    def _ground(self, s: BodyState) -> None:
        touching = s.pos_m[:, 2] <= 0.0
        if not touching.any():
            s.on_ground = touching
            self._grounded = False
            return
        # A vehicle resting on the ground comes here every step: basic slices when all
        # vehicles touch, and the checks below skip what is already settled.
        idx = slice(None) if touching.all() else np.nonzero(touching)[0]
        vz = s.vel_mps[:, 2]
        if _min(vz) < -self.airframe.crash_speed_mps:
            hard = touching & (vz < -self.airframe.crash_speed_mps) & (s.crash == 0)
            s.crash[hard] = CRASH_GROUND
            self._w_max_alive[hard] = 0.0
        s.pos_m[idx, 2] = 0.0
        # Skids on grass: no sliding, no bouncing, the frame settles level.
        s.vel_mps[idx] = 0.0
        s.omega_rad_s[idx] = 0.0
        R = s.R_world_body
        if _min(R[idx, 2, 2]) < 1.0:  # tilted: level it, keeping the heading
            R[idx] = yaw_matrix(np.arctan2(R[idx, 1, 0], R[idx, 0, 0]))
        s.on_ground = touching
        self._grounded = True
