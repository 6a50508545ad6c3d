"""A PX4-like multicopter controller, vectorized over N vehicles.

Cascade as in PX4: position -> velocity -> acceleration/thrust vector (outer loop, called
at the outer rate, ~50 Hz) and attitude -> body rate -> torque -> mixer (inner loop, every
physics step). Modes follow PX4's behaviour for the pilot:

- Position (POSCTL): sticks command horizontal velocity (up to `max_vel_xy_mps`) in the
  heading frame, climb rate and yaw rate; centred sticks brake, then hold position and
  altitude. The paper flew every task in this mode.
- Altitude (ALTCTL): horizontal sticks command tilt angles, throttle commands climb rate;
  centred throttle holds altitude.
- Stabilized (MANUAL/STABILIZED): sticks command tilt angles, throttle is collective thrust.
- AUTO takeoff / loiter / land / mission: position setpoints from the commander (the
  mission's from `twin.mission`); sticks ignored.

Sticks are (N, 4) of roll (right +), pitch (forward +), yaw (clockwise +) in [-1, 1] and
throttle in [0, 1], the normalized form of MANUAL_CONTROL / RC PWM.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from fpv_station.twin.dynamics import GRAVITY_MPS2, Airframe, _clip

STABILIZED, ALTCTL, POSCTL, AUTO_TAKEOFF, AUTO_LOITER, AUTO_LAND, AUTO_MISSION, AUTO_RTL = range(8)
MODE_NAMES = {
    STABILIZED: "STABILIZED",
    ALTCTL: "ALTCTL",
    POSCTL: "POSCTL",
    AUTO_TAKEOFF: "TAKEOFF",
    AUTO_LOITER: "LOITER",
    AUTO_LAND: "LAND",
    AUTO_MISSION: "MISSION",
    AUTO_RTL: "RTL",
}


@dataclass(frozen=True)
class ControlGains:
    max_vel_xy_mps: float = 5.0  # PX4 MPC_VEL_MANUAL (lowered for a field with a net)
    max_climb_mps: float = 3.0  # MPC_Z_VEL_MAX_UP
    max_descent_mps: float = 1.5  # MPC_Z_VEL_MAX_DN
    land_speed_mps: float = 0.7  # MPC_LAND_SPEED
    takeoff_speed_mps: float = 1.5  # MPC_TKO_SPEED
    max_yaw_rate_rad_s: float = np.radians(150)  # MPC_MAN_Y_MAX
    max_tilt_rad: float = np.radians(35)  # MPC_MAN_TILT_MAX
    stick_deadband: float = 0.1
    pos_p: float = 0.95  # MPC_XY_P
    z_pos_p: float = 1.0  # MPC_Z_P
    vel_p: float = 1.8  # MPC_XY_VEL_P_ACC
    vel_i: float = 0.4
    z_vel_p: float = 4.0
    z_vel_i: float = 2.0
    max_acc_xy_mps2: float = 5.0
    brake_speed_mps: float = 0.3  # below this the position is latched for holding
    att_p: tuple[float, float, float] = (6.5, 6.5, 2.8)  # MC_ROLL_P, MC_PITCH_P, MC_YAW_P
    rate_p: tuple[float, float, float] = (20.0, 20.0, 8.0)  # rad/s^2 per rad/s of error
    max_rate_rad_s: tuple[float, float, float] = tuple(np.radians([220.0, 220.0, 200.0]))


def yaw_of(R: np.ndarray) -> np.ndarray:
    return np.arctan2(R[:, 1, 0], R[:, 0, 0])


class Controller:
    """Setpoints and integrators of N vehicles; `outer()` at ~50 Hz, `inner()` every step."""

    def __init__(self, n: int, airframe: Airframe, gains: ControlGains | None = None) -> None:
        self.af, self.g = airframe, gains or ControlGains()
        self.n = n
        self.hold_pos_m = np.zeros((n, 3))
        self.hold_xy_valid = np.zeros(n, bool)
        self.hold_z_valid = np.zeros(n, bool)
        self.yaw_sp_rad = np.zeros(n)
        self.vel_sp_mps = np.zeros((n, 3))
        self.vel_int = np.zeros((n, 3))
        self.thrust_sp_n = np.zeros(n)
        self.R_sp = np.tile(np.eye(3), (n, 1, 1))
        self._A_inv = np.linalg.inv(airframe.mixer())
        self._J = np.asarray(airframe.inertia_kg_m2, float)
        self._att_p = np.asarray(self.g.att_p)
        self._rate_p = np.asarray(self.g.rate_p)
        self._max_rate = np.asarray(self.g.max_rate_rad_s)
        self._J_rate_p = self._J * self._rate_p
        self._A_inv_T = self._A_inv.T.copy()
        vee = np.zeros((9, 3))  # E.flat @ vee = vee(E - E^T)
        vee[7, 0], vee[5, 0], vee[2, 1], vee[6, 1], vee[3, 2], vee[1, 2] = 1, -1, 1, -1, 1, -1
        self._vee = vee
        # Inner-loop buffers: the attitude error and thrust projection are linear in R, so
        # outer() folds R_sp into K (N, 9, 4) and inner() needs one matmul for both.
        self._K = np.zeros((n, 9, 4))
        self._y = np.zeros((n, 1, 4))
        self._rate_sp, self._along = self._y[:, 0, :3], self._y[:, 0, 3:]
        self._max_rate = np.tile(self._max_rate, (n, 1))
        self._neg_max_rate = -self._max_rate
        self._wrench = np.zeros((n, 4))
        self._u = np.zeros((n, 4))
        self._thrust_col = np.zeros((n, 1))
        # Same-shape operands everywhere: broadcasting triples numpy's per-call cost.
        self._u_lo, self._u_hi = np.zeros((n, 4)), np.zeros((n, 4))
        self._inv_w_max = np.ones((n, 4))
        self._zero1, self._zero4, self._w0 = np.zeros((n, 1)), np.zeros((n, 4)), self._wrench[:, :1]
        # [thrust, rate error] -> rotor speed^2: the rate P gain, mixer and 1/k_T in one matrix.
        self._mix = (
            np.concatenate([[1.0], self._J_rate_p])[:, None]
            * self._A_inv_T
            / airframe.thrust_coeff_n_per_rad2
        )
        self._R_src: np.ndarray | None = None
        self._R_flat = np.zeros((n, 1, 9))
        V = np.zeros((3, 3, 4))  # [i, j, c], c = 3 (the thrust projection) set separately
        V[:, :, :3] = vee.reshape(3, 3, 3) * (-0.5 * self._att_p)
        self._V = V.reshape(3, 12)
        self._K3 = self._K.reshape(n, 3, 12)  # [k, (j, c)]: a view, written by one matmul
        # Outer-loop constants (pre-shaped so each expression is one call per array).
        self._stick_scale = np.array([1.0, 1.0, 1.0, 2.0])
        self._stick_offset = np.array([0.0, 0.0, 0.0, -1.0])
        self._db_gain = 1.0 / (1.0 - self.g.stick_deadband)
        self._cs = np.zeros((n, 2))
        self._flip = np.array([1.0, -1.0])
        self._int_lo, self._int_hi = np.array([-2.0, -2.0, -3.0]), np.array([2.0, 2.0, 3.0])
        self._vel_p = np.array([self.g.vel_p, self.g.vel_p, self.g.z_vel_p])
        self._vel_i = np.array([self.g.vel_i, self.g.vel_i, self.g.z_vel_i])
        self._gravity = np.array([0.0, 0.0, GRAVITY_MPS2])
        self._tan_max = float(np.tan(self.g.max_tilt_rad))
        self._set_setpoint(self.R_sp, self.thrust_sp_n)

    def _set_setpoint(self, R_sp: np.ndarray, thrust_n: np.ndarray) -> None:
        # E.flat = (R_sp^T R).flat, so -att_p vee(E - E^T) / 2 = R.flat @ K with
        # K[(k, j), c] = sum_i R_sp[k, i] V[i, (j, c)]: one batched matmul.
        np.matmul(R_sp, self._V, self._K3)
        self._K[:, 2::3, 3] = R_sp[:, :, 2]  # R.flat[(k, 2)] = body z: z_sp . z_body
        self._thrust_col[:, 0] = thrust_n

    def reset(self, mask: np.ndarray, pos_m: np.ndarray, R: np.ndarray) -> None:
        """On the ground: forget integrators, latch position and heading."""
        if not mask.any():  # called at the outer rate; usually nobody is on the ground
            return
        self.vel_int[mask] = 0.0
        self.hold_pos_m[mask] = pos_m[mask]
        self.hold_xy_valid[mask] = True
        self.hold_z_valid[mask] = True
        self.yaw_sp_rad[mask] = yaw_of(R)[mask]
        self.vel_sp_mps[mask] = 0.0

    def outer(
        self,
        dt: float,
        mode: np.ndarray,
        sticks: np.ndarray,
        pos_m: np.ndarray,
        vel_mps: np.ndarray,
        R: np.ndarray,
        target_m: np.ndarray,
    ) -> None:
        """Velocity and thrust-vector setpoints. `target_m` (N, 3) serves the AUTO modes.

        Written for numpy's per-call cost at N = 1 (~1-2 us a call): whole-row expressions,
        np.where instead of masked writes, no column_stack, the clip ufunc."""
        g = self.g
        where, clip = np.where, _clip
        db = sticks * self._stick_scale
        db += self._stick_offset  # throttle 0..1 -> climb -1..1
        db = np.sign(db) * clip((np.abs(db) - g.stick_deadband) * self._db_gain, 0.0, 1.0)
        roll, pitch, yaw, climb = db[:, 0], db[:, 1], db[:, 2], db[:, 3]
        auto = mode >= AUTO_TAKEOFF
        posctl = mode == POSCTL
        yaw_sp = where(auto, self.yaw_sp_rad, self.yaw_sp_rad + yaw * (g.max_yaw_rate_rad_s * dt))
        self.yaw_sp_rad = (yaw_sp + np.pi) % (2 * np.pi) - np.pi

        # Horizontal: stick velocity, or brake then hold the latched position.
        cs = self._cs
        np.cos(self.yaw_sp_rad, cs[:, 0])
        np.sin(self.yaw_sp_rad, cs[:, 1])
        c, s = cs[:, 0], cs[:, 1]
        # [pitch c + roll s, pitch s - roll c] = pitch (c, s) + roll (s, -c)
        stick_v = pitch[:, None] * cs + roll[:, None] * cs[:, ::-1] * self._flip
        stick_v *= g.max_vel_xy_mps
        stick_active = posctl & ((roll != 0) | (pitch != 0))
        self.hold_xy_valid &= ~stick_active
        vel_xy = vel_mps[:, :2]
        latch = (
            ~self.hold_xy_valid
            & ~stick_active
            & ((vel_xy * vel_xy).sum(axis=1) < g.brake_speed_mps**2)
        )
        hold = self.hold_pos_m
        np.copyto(hold[:, :2], pos_m[:, :2], where=latch[:, None])
        self.hold_xy_valid |= latch
        hold_xy = where(auto[:, None], target_m[:, :2], hold[:, :2])
        pos_v = clip(g.pos_p * (hold_xy - pos_m[:, :2]), -g.max_vel_xy_mps, g.max_vel_xy_mps)
        holding = self.hold_xy_valid | auto
        vel_sp = self.vel_sp_mps
        vel_sp[:, :2] = where(stick_active[:, None], stick_v, where(holding[:, None], pos_v, 0.0))

        # Vertical: climb-rate stick, or hold the latched altitude; AUTO has its own targets.
        climb_v = climb * where(climb > 0, g.max_climb_mps, g.max_descent_mps)
        climb_active = (posctl | (mode == ALTCTL)) & (climb != 0)
        self.hold_z_valid &= ~climb_active
        latch_z = ~self.hold_z_valid & ~climb_active & (np.abs(vel_mps[:, 2]) < g.brake_speed_mps)
        np.copyto(hold[:, 2], pos_m[:, 2], where=latch_z)
        self.hold_z_valid |= latch_z
        hold_z = where(auto, target_m[:, 2], hold[:, 2])
        pos_vz = clip(g.z_pos_p * (hold_z - pos_m[:, 2]), -g.max_descent_mps, g.max_climb_mps)
        if auto.any():
            pos_vz = where(mode == AUTO_TAKEOFF, np.minimum(pos_vz, g.takeoff_speed_mps), pos_vz)
            pos_vz = where(mode == AUTO_LAND, -g.land_speed_mps, pos_vz)
        vel_sp[:, 2] = where(climb_active, climb_v, where(self.hold_z_valid | auto, pos_vz, 0.0))

        # Velocity -> acceleration (PI) -> thrust vector with a tilt limit.
        err = vel_sp - vel_mps
        self.vel_int += err * dt
        clip(self.vel_int, self._int_lo, self._int_hi, self.vel_int)
        acc = err * self._vel_p
        acc += self.vel_int * self._vel_i
        acc += self._gravity
        acc_xy = np.sqrt(acc[:, 0] * acc[:, 0] + acc[:, 1] * acc[:, 1])
        acc[:, :2] *= np.minimum(1.0, g.max_acc_xy_mps2 / np.maximum(acc_xy, 1e-9))[:, None]
        acc[:, 2] = np.maximum(acc[:, 2], 0.1 * GRAVITY_MPS2)
        acc_xy = np.sqrt(acc[:, 0] * acc[:, 0] + acc[:, 1] * acc[:, 1])
        acc[:, :2] *= np.minimum(1.0, self._tan_max * acc[:, 2] / np.maximum(acc_xy, 1e-9))[:, None]

        # Manual tilt modes: sticks are angles (pitch forward = nose down).
        manual_tilt = (mode == STABILIZED) | (mode == ALTCTL)
        if manual_tilt.any():
            roll_a, pitch_a = roll * g.max_tilt_rad, pitch * g.max_tilt_rad
            # Body z tilted: forward tilt moves thrust towards the heading.
            tilt_dir = np.column_stack(
                [np.tan(pitch_a) * c + np.tan(roll_a) * s, np.tan(pitch_a) * s - np.tan(roll_a) * c]
            )
            acc[manual_tilt, :2] = tilt_dir[manual_tilt] * acc[manual_tilt, 2:3]
            self.vel_int[manual_tilt, :2] = 0.0
        acc_norm = np.sqrt((acc * acc).sum(axis=1))
        z_d = acc / acc_norm[:, None]
        thrust = self.af.mass_kg * acc_norm
        stab = mode == STABILIZED
        if stab.any():
            max_thrust = 4 * self.af.thrust_coeff_n_per_rad2 * (self.af.kv_rad_s_per_v * 12.0) ** 2
            thrust[stab] = sticks[stab, 3] * max_thrust / np.maximum(z_d[stab, 2], 0.5)
        self.thrust_sp_n = thrust
        # R_sp = [x_d, y_d, z_d] with y_d = z_d x (cos yaw, sin yaw, 0), x_d = y_d x z_d.
        zx, zy, zz = z_d[:, 0], z_d[:, 1], z_d[:, 2]
        R_sp = np.empty((self.n, 3, 3))
        y_d = R_sp[:, :, 1]
        y_d[:, 0], y_d[:, 1], y_d[:, 2] = -zz * s, zz * c, zx * s - zy * c
        y_d /= np.sqrt((y_d * y_d).sum(axis=1))[:, None]
        yx, yy, yz = y_d[:, 0], y_d[:, 1], y_d[:, 2]
        R_sp[:, 0, 0], R_sp[:, 1, 0], R_sp[:, 2, 0] = (
            yy * zz - yz * zy,
            yz * zx - yx * zz,
            yx * zy - yy * zx,
        )
        R_sp[:, :, 2] = z_d
        self.R_sp = R_sp
        self._set_setpoint(R_sp, thrust)

    def set_limits(self, max_rotor_rad_s: np.ndarray, armed: np.ndarray, idle: np.ndarray) -> None:
        """Throttle bounds per vehicle, which change only at the outer rate (battery voltage,
        arming, idling on the ground): disarmed = 0, idle = idle throttle, else [idle, 1]."""
        idle_u = self.af.idle_throttle
        self._u_lo[:] = (idle_u * armed)[:, None]
        self._u_hi[:] = (np.where(idle, idle_u, 1.0) * armed)[:, None]
        self._inv_w_max[:] = 1.0 / max_rotor_rad_s[:, None]  # broadcast once here, not per step

    def inner(self, R: np.ndarray, omega: np.ndarray) -> np.ndarray:
        """Rotor throttles (N, 4) in [0, 1]: attitude P -> rate P -> torque -> mixer, within
        the bounds of `set_limits`. Returns the same buffer every call (overwritten)."""
        if R is not self._R_src:
            self._R_src, self._R_flat = R, R.reshape(-1, 1, 9)
        y, rate, wrench, u = self._y, self._rate_sp, self._wrench, self._u
        # One matmul: -att_p * vee(E - E^T) / 2 with E = R_sp^T R, and z_sp . z_body.
        np.matmul(self._R_flat, self._K, y)
        _clip(rate, self._neg_max_rate, self._max_rate, rate)
        np.subtract(rate, omega, wrench[:, 1:])
        # Collective along the current body z, as PX4 projects the thrust vector.
        np.maximum(self._along, self._zero1, out=self._w0)
        np.multiply(self._w0, self._thrust_col, self._w0)
        np.matmul(wrench, self._mix, u)  # rotor speeds squared
        np.maximum(u, self._zero4, out=u)
        np.sqrt(u, u)
        np.multiply(u, self._inv_w_max, u)
        _clip(u, self._u_lo, self._u_hi, u)
        return u

    @property
    def rate_sp_rad_s(self) -> np.ndarray:
        """The body-rate setpoints (N, 3), FLU, of the last `inner` (the same buffer)."""
        return self._rate_sp

    @property
    def throttle(self) -> np.ndarray:
        """The last rotor throttles (N, 4) `inner` returned (the same buffer)."""
        return self._u
