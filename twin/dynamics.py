"""Rigid-body flight model of the paper's F450, vectorized over a batch of N vehicles.

Frames: world ENU (x east, y north, z up); body FLU (x forward, y left, z up);
`R_world_body` (N, 3, 3) maps body vectors to world. Rotors in PX4's quad-X order:
1 front-right (CCW), 2 rear-left (CCW), 3 front-left (CW), 4 rear-right (CW).

Each step is a fixed dt (>= 250 Hz): first-order motor lag towards the commanded speed,
thrust k_T w^2, reaction torque, linear + quadratic drag against the air (optional mean
wind with Gauss-Markov gusts), semi-implicit Euler, ground contact, and crash detection
against the ground (impact speed), the obstacles and the boundary net. The battery (3S
5500 mAh) sags under load: the terminal voltage limits the motors' top speed and the
electric power is calibrated so that a hover lasts about 11 minutes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

GRAVITY_MPS2 = 9.80665
CRASH_NONE, CRASH_GROUND, CRASH_OBSTACLE, CRASH_NET = 0, 1, 2, 3
CRASH_REASONS = {CRASH_NONE: "", CRASH_GROUND: "ground impact", CRASH_OBSTACLE: "obstacle",
                 CRASH_NET: "boundary net"}


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
    return np.interp(soc, [0.0, 0.05, 0.1, 0.2, 0.5, 0.8, 1.0],
                     [3.0, 3.45, 3.6, 3.7, 3.8, 3.95, 4.2])


@dataclass(frozen=True)
class Wind:
    mean_enu_mps: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_std_mps: float = 0.0
    gust_tau_s: float = 2.0


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
    wind_mps: np.ndarray  # (N, 3) current air velocity (mean + gust)

    @property
    def n(self) -> int:
        return self.pos_m.shape[0]


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
        self._eye = np.eye(3)
        self._dt_over_J = self.dt_s / self._J
        self._dJ = self._J[[2, 0, 1]] - self._J[[1, 2, 0]]
        self._rot_keep = 1.0 - af.rot_drag_nm_per_rad_s * self._dt_over_J
        self._dt_over_m = self.dt_s / af.mass_kg
        self._drag_lin_dt = af.drag_linear_n_per_mps * self._dt_over_m
        self._drag_quad_dt = af.drag_quadratic_n_per_mps2 * self._dt_over_m
        self._g_dt = self._g * self.dt_s
        self._grounded = True
        self._i1, self._i2 = np.array([1, 2, 0]), np.array([2, 0, 1])
        # (3, 9) generator: w @ G = dt * skew(w) flattened row-major.
        G = np.zeros((3, 9))
        G[2, 1], G[1, 2], G[0, 5] = -1, 1, -1
        G[2, 3], G[1, 6], G[0, 7] = 1, -1, 1
        self._skew_gen = G * self.dt_s
        self._w_max_alive = np.zeros((0, 1))
        # phi = [1, w (3), w w^T (9, row-major), rotor thrust (4)] -> [thrust dt/m, d omega].
        B = np.zeros((17, 4))
        B[13:, 0] = self._dt_over_m
        B[13:, 1:] = self._A_T[:, 1:] * self._dt_over_J
        B[1:4, 1:] = np.diag(self._rot_keep - 1.0)
        for row, (a, b) in enumerate([(1, 2), (2, 0), (0, 1)]):  # gyro: w_a w_b (J_b - J_a)
            B[4 + 3 * a + b, 1 + row] = -self._dJ[row] * self._dt_over_J[row]
        self._B = B
        # phi -> (I + S + S^2 / 2).flat with S = [w dt]x, S^2 = dt^2 (w w^T - |w|^2 I).
        G = np.zeros((17, 9))
        G[0] = np.eye(3).ravel()
        G[1:4] = self._skew_gen
        G[4:13] = 0.5 * self.dt_s ** 2 * (np.eye(9) - np.outer(np.eye(3).ravel(), np.eye(3).ravel()))
        self._G = G
        self._bound: BodyState | None = None
        self._bound_R: np.ndarray | None = None

    def initial_state(self, n: int, xy_m: np.ndarray, yaw_rad: float = 0.0) -> BodyState:
        af = self.airframe
        pos = np.zeros((n, 3))
        pos[:, :2] = xy_m
        charge = np.full(n, af.capacity_ah * 3600.0)
        volt = np.full(n, af.cells * float(ocv_per_cell_v(1.0)))
        self._w_max_alive = (af.kv_rad_s_per_v * volt)[:, None]
        self._grounded = True
        return BodyState(
            pos_m=pos, vel_mps=np.zeros((n, 3)), R_world_body=yaw_matrix(np.full(n, yaw_rad)),
            omega_rad_s=np.zeros((n, 3)), rotor_rad_s=np.zeros((n, 4)), charge_c=charge,
            voltage_v=volt, current_a=np.zeros(n), rotor_thrust_n=np.zeros((n, 4)),
            on_ground=np.ones(n, bool), crash=np.zeros(n, int),
            wind_mps=np.tile(np.asarray(self.wind.mean_enu_mps, float), (n, 1)),
        )

    def max_rotor_speed_rad_s(self, s: BodyState) -> np.ndarray:
        return self.airframe.kv_rad_s_per_v * s.voltage_v

    def _bind(self, s: BodyState) -> None:
        """Preallocate the step's work buffers for state `s` (once per state object).

        One vehicle pays numpy's per-call overhead, not arithmetic, so the step is a few
        fused array expressions into these buffers. `s.omega_rad_s` and `s.rotor_thrust_n`
        become views into the feature row phi = [1, w, w w^T, rotor thrust], from which one
        matmul gives every rate increment and another the rotation increment.
        """
        n = s.n
        phi = np.zeros((n, 17))
        phi[:, 0] = 1.0
        phi[:, 1:4] = s.omega_rad_s
        phi[:, 13:17] = s.rotor_thrust_n
        s.omega_rad_s, s.rotor_thrust_n = phi[:, 1:4], phi[:, 13:17]
        w = s.omega_rad_s
        self._phi = phi
        self._ww = phi[:, 4:13].reshape(n, 3, 3)
        self._w_col, self._w_row = w[:, :, None], w[:, None, :]
        self._u = np.empty((n, 4))
        self._dw = np.empty((n, 4))  # [thrust dt / m, d omega (3)]
        self._M = np.empty((n, 9))
        self._M3 = self._M.reshape(n, 3, 3)
        self._R_new = np.empty((n, 3, 3))
        self._va = np.empty((n, 3))
        self._dv = np.empty((n, 3))
        self._k = np.empty((n, 1))
        self._bound = s
        self._bound_R = s.R_world_body

    def step(self, s: BodyState, throttle: np.ndarray) -> None:
        """Advance every vehicle by dt under per-rotor throttle (N, 4) in [0, 1]; in place.

        The fast part only (rotors, rigid body, ground); `collisions` (~50 Hz) and
        `slow_update` (~10 Hz: battery, gusts) run at lower rates from the caller.
        """
        if s is not self._bound or s.R_world_body is not self._bound_R:
            self._bind(s)
        mul, add, mm = np.multiply, np.add, np.matmul
        u, r, phi, dw = self._u, s.rotor_rad_s, self._phi, self._dw
        np.maximum(throttle, 0.0, out=u)
        np.minimum(u, 1.0, out=u)
        mul(u, self._w_max_alive, u)  # commanded rotor speed
        np.subtract(u, r, u)
        mul(u, self._motor_alpha, u)
        add(r, u, r)  # first-order lag
        f = s.rotor_thrust_n
        mul(r, r, f)
        mul(f, self.airframe.thrust_coeff_n_per_rad2, f)

        # Rotation: Euler's equations with a diagonal inertia (gyroscopic term
        # w x Jw = (wy wz (Jz - Jy), wz wx (Jx - Jz), wx wy (Jy - Jx))) and rotor-wash
        # damping, all linear in phi = [1, w, w w^T, f]: one matmul gives d omega and the
        # thrust's dv. Then R <- R exp([w dt]x) to second order, I + S + S^2 / 2 with
        # S^2 = dt^2 (w w^T - |w|^2 I), again linear in phi; re-orthonormalized every 32 steps.
        w = s.omega_rad_s
        mul(self._w_col, self._w_row, self._ww)
        mm(phi, self._B, dw)
        add(w, dw[:, 1:], w)
        mul(self._w_col, self._w_row, self._ww)
        mm(phi, self._G, self._M)
        R = s.R_world_body
        mm(R, self._M3, self._R_new)
        np.copyto(R, self._R_new)
        self._steps += 1
        if self._steps % 32 == 0:
            U, _, Vt = np.linalg.svd(R)
            mm(U, Vt, R)

        # Translation: thrust along body z, gravity, drag against the air (all times dt).
        va, dv, k = self._va, self._dv, self._k
        np.subtract(s.vel_mps, s.wind_mps, va)
        mm(va[:, None, :], va[:, :, None], k[:, :, None])
        np.sqrt(k, k)
        mul(k, self._drag_quad_dt, k)
        add(k, self._drag_lin_dt, k)
        mul(va, k, va)
        mul(R[:, :, 2], dw[:, :1], dv)
        np.subtract(dv, va, dv)
        add(dv, self._g_dt, dv)
        add(s.vel_mps, dv, s.vel_mps)
        mul(s.vel_mps, self.dt_s, dv)
        add(s.pos_m, dv, s.pos_m)
        if self._grounded or np.minimum.reduce(s.pos_m[:, 2]) <= 0.0:
            self._ground(s)

    def revive(self, s: BodyState) -> None:
        """Recompute the motors' power after vehicles were reset in place."""
        alive = (s.crash == 0) & (s.charge_c > 0)
        self._w_max_alive = (self.airframe.kv_rad_s_per_v * s.voltage_v * alive)[:, None]
        self._grounded = bool(s.on_ground.any() or (s.pos_m[:, 2] <= 0).any())

    def slow_update(self, s: BodyState, dt: float) -> None:
        """Battery and gusts, which change slowly (~10 Hz is plenty)."""
        self._battery(s, s.rotor_thrust_n, dt)
        if self.wind.gust_std_mps > 0:
            k = dt / self.wind.gust_tau_s
            gust = s.wind_mps - self.wind.mean_enu_mps
            gust += -gust * k + self.wind.gust_std_mps * np.sqrt(2 * k) * self._rng.standard_normal(
                gust.shape)
            s.wind_mps = gust + self.wind.mean_enu_mps
        alive = (s.crash == 0) & (s.charge_c > 0)
        self._w_max_alive = (self.airframe.kv_rad_s_per_v * s.voltage_v * alive)[:, None]

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
        r = self.airframe.frame_radius_m
        z = s.pos_m[:, 2]
        if len(self.obstacle_boxes_m):
            b = self.obstacle_boxes_m
            x, y = s.pos_m[:, :1], s.pos_m[:, 1:2]
            inside = ((x > b[:, 0] - r) & (x < b[:, 3] + r) & (y > b[:, 1] - r)
                      & (y < b[:, 4] + r) & (z[:, None] < b[:, 5] + 0.05)).any(axis=1)
            hit = (s.crash == 0) & inside
            s.crash[hit] = CRASH_OBSTACLE
            s.vel_mps[hit, :2] = 0.0  # stopped by the obstacle; it falls from there
            self._w_max_alive[hit] = 0.0
        if self.net_half_extent_m is not None:
            hx, hy = self.net_half_extent_m
            out = ((np.abs(s.pos_m[:, 0]) > hx - r) | (np.abs(s.pos_m[:, 1]) > hy - r)) & (
                z < self.net_height_m)
            hit = (s.crash == 0) & out
            s.crash[hit] = CRASH_NET
            s.vel_mps[hit, :2] = 0.0  # caught in the net
            self._w_max_alive[hit] = 0.0

    def _ground(self, s: BodyState) -> None:
        touching = s.pos_m[:, 2] <= 0.0
        if touching.any():
            hard = touching & (s.vel_mps[:, 2] < -self.airframe.crash_speed_mps) & (s.crash == 0)
            s.crash[hard] = CRASH_GROUND
            idx = np.nonzero(touching)[0]
            s.pos_m[idx, 2] = 0.0
            # Skids on grass: no sliding, no bouncing, the frame settles level.
            s.vel_mps[idx] = 0.0
            yaw = np.arctan2(s.R_world_body[idx, 1, 0], s.R_world_body[idx, 0, 0])
            s.R_world_body[idx] = yaw_matrix(yaw)
            s.omega_rad_s[idx] = 0.0
            if hard.any():
                self._w_max_alive[hard] = 0.0
        s.on_ground = touching
        self._grounded = bool(touching.any())
