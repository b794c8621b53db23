"""Cascaded multicopter control as PX4's PositionControl: position P -> velocity PI -> acceleration -> tilt + thrust.

Pure maths plus one small stateful object (the velocity integrator). No clock: the caller passes dt.
Setpoints follow PX4's trajectory_setpoint convention: per axis, a NaN position means "not position controlled",
a NaN velocity means "not velocity controlled" (acceleration only); finite velocity/acceleration next to a finite
position are feed-forward.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from viva_sitl.dynamics import wrap_pi

Vec3 = NDArray[np.float64]
_NAN3 = (math.nan, math.nan, math.nan)


def _nan_to_zero(v: Vec3) -> Vec3:
    # np.nan_to_num costs ~15 µs on a 3-vector (it also handles inf); this is ~1 µs and inputs are never inf.
    return np.where(np.isnan(v), 0.0, v)


def nan3() -> Vec3:
    return np.array(_NAN3, dtype=np.float64)


@dataclass(frozen=True)
class TrajectorySetpoint:
    """PX4's trajectory_setpoint: NaN components are not controlled at that level (NED, m, m/s, m/s², rad)."""

    pos_ned_m: tuple[float, float, float] = _NAN3
    vel_ned_m_s: tuple[float, float, float] = _NAN3
    acc_ned_m_s2: tuple[float, float, float] = _NAN3
    yaw_rad: float = math.nan  # NaN: keep the current yaw setpoint
    yaw_rate_rad_s: float = math.nan  # used when yaw_rad is NaN


@dataclass(frozen=True)
class Gains:
    """PX4 names in brackets."""

    pos_xy_p: float = 0.95  # [MPC_XY_P] 1/s
    pos_z_p: float = 1.0  # [MPC_Z_P] 1/s
    vel_xy_p: float = 2.4  # [MPC_XY_VEL_P_ACC] 1/s
    vel_xy_i: float = 0.4  # [MPC_XY_VEL_I_ACC] 1/s²
    vel_z_p: float = 4.0  # [MPC_Z_VEL_P_ACC] 1/s
    vel_z_i: float = 2.0  # [MPC_Z_VEL_I_ACC] 1/s²


@dataclass(frozen=True)
class Limits:
    vel_xy_m_s: float = 5.0  # horizontal speed limit of the position loop output
    vel_up_m_s: float = 3.0
    vel_down_m_s: float = 1.5
    tilt_max_rad: float = math.radians(45.0)
    thrust_min_n: float = 0.0  # min collective thrust in the air (keeps the vehicle controllable)
    thrust_max_n: float = 1e9
    # Auto trajectories: speed toward a position target limited so the vehicle can brake at acc_xy (no overshoot).
    brake_acc_xy_m_s2: float = math.inf
    brake_acc_z_m_s2: float = math.inf
    # Auto trajectories: velocity setpoint slew rate (m/s²), its slope fed forward as acceleration. inf = off.
    slew_acc_xy_m_s2: float = math.inf
    slew_acc_up_m_s2: float = math.inf
    slew_acc_down_m_s2: float = math.inf


@dataclass(frozen=True)
class Airframe:
    """What the controller knows of the vehicle: the EAV's mass, drag and gravity."""

    mass_kg: float
    drag_kd_n_s_m: float
    gravity_m_s2: float = 9.81


@dataclass(frozen=True)
class AttitudeThrust:
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    thrust_n: float


def _braking_speed(dist_m: float, gain: float, brake_acc: float) -> float:
    """Speed toward a target at dist: P law near it, capped by sqrt(2 a d) so braking at `brake_acc` stops on it."""
    if not math.isfinite(brake_acc):
        return gain * dist_m
    return min(gain * dist_m, math.sqrt(2.0 * brake_acc * dist_m))


def attitude_from_thrust_vector(force_ned_n: Vec3, yaw_rad: float) -> tuple[float, float, float]:
    """(roll, pitch, |F|) such that the body -z axis (thrust) of a ZYX attitude with this yaw points along F."""
    thrust = float(np.linalg.norm(force_ned_n))
    if thrust < 1e-9:
        return 0.0, 0.0, 0.0
    b3 = -force_ned_n / thrust  # body z axis (down) in NED
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    # Rz(-yaw) b3 = (sin p cos r, -sin r, cos p cos r) for the ZYX convention.
    bx = cy * b3[0] + sy * b3[1]
    by = -sy * b3[0] + cy * b3[1]
    bz = float(b3[2])
    roll = -math.asin(max(-1.0, min(1.0, by)))
    pitch = math.atan2(bx, bz)
    return roll, pitch, thrust


@dataclass
class PositionController:
    """Position P -> velocity PI -> thrust vector, with PX4's limits and anti-windup. One per vehicle."""

    gains: Gains = field(default_factory=Gains)
    vel_int_m_s2: Vec3 = field(default_factory=lambda: np.zeros(3))  # integral term (already times I gain)
    last_vel_sp_ned_m_s: Vec3 = field(default_factory=lambda: np.full(3, np.nan))  # NaN: start from measured

    def reset(self) -> None:
        self.vel_int_m_s2 = np.zeros(3)
        self.last_vel_sp_ned_m_s = np.full(3, np.nan)

    def restart_trajectory(self) -> None:
        """Next velocity setpoint slews from the measured velocity (mode change), integrators kept."""
        self.last_vel_sp_ned_m_s = np.full(3, np.nan)

    def reset_xy(self) -> None:
        self.vel_int_m_s2[:2] = 0.0

    def velocity_setpoint(self, pos_ned_m: Vec3, sp: TrajectorySetpoint, limits: Limits) -> tuple[Vec3, Vec3]:
        """Position P with feed-forward -> (vel_sp, acc_ff). NaN vel_sp: that axis is acceleration-only."""
        g = self.gains
        pos_sp = np.asarray(sp.pos_ned_m, dtype=np.float64)
        vel_ff = np.asarray(sp.vel_ned_m_s, dtype=np.float64)
        acc_ff = np.asarray(sp.acc_ned_m_s2, dtype=np.float64)
        vel_sp = vel_ff.copy()
        # Horizontal: P on the 2D error, direction preserved, braking-limited.
        if math.isfinite(pos_sp[0]) and math.isfinite(pos_sp[1]):  # (np.all costs ~5 µs per call)
            err = pos_sp[:2] - pos_ned_m[:2]
            dist = float(np.hypot(err[0], err[1]))
            v_xy = np.zeros(2)
            if dist > 1e-9:
                v_xy = err / dist * _braking_speed(dist, g.pos_xy_p, limits.brake_acc_xy_m_s2)
            ff = _nan_to_zero(vel_ff[:2])
            vel_sp[:2] = v_xy + ff
        if math.isfinite(pos_sp[2]):
            err_z = float(pos_sp[2] - pos_ned_m[2])
            v_z = math.copysign(_braking_speed(abs(err_z), g.pos_z_p, limits.brake_acc_z_m_s2), err_z)
            vel_sp[2] = v_z + (vel_ff[2] if math.isfinite(vel_ff[2]) else 0.0)
        # Speed limits (PX4: horizontal norm, vertical up/down separately).
        if math.isfinite(vel_sp[0]) and math.isfinite(vel_sp[1]):
            n = float(np.hypot(vel_sp[0], vel_sp[1]))
            if n > limits.vel_xy_m_s:
                vel_sp[:2] *= limits.vel_xy_m_s / n
        if math.isfinite(vel_sp[2]):
            vel_sp[2] = min(max(vel_sp[2], -limits.vel_up_m_s), limits.vel_down_m_s)
        return vel_sp, acc_ff

    def _slew(
        self, dt_s: float, vel_sp: Vec3, acc_ff: Vec3, vel_ned_m_s: Vec3, limits: Limits
    ) -> tuple[Vec3, Vec3]:
        """Rate-limit the velocity setpoint (auto modes) and feed its slope forward: smooth, overshoot-free moves."""
        if dt_s <= 0.0:
            return vel_sp, acc_ff
        prev = np.where(np.isfinite(self.last_vel_sp_ned_m_s), self.last_vel_sp_ned_m_s, vel_ned_m_s)
        vel_sp, acc_ff = vel_sp.copy(), acc_ff.copy()
        if math.isfinite(limits.slew_acc_xy_m_s2) and math.isfinite(vel_sp[0]) and math.isfinite(vel_sp[1]):
            dv = vel_sp[:2] - prev[:2]
            n = float(np.hypot(dv[0], dv[1]))
            max_dv = limits.slew_acc_xy_m_s2 * dt_s
            if n > max_dv:
                dv *= max_dv / n
            vel_sp[:2] = prev[:2] + dv
            acc_ff[:2] = _nan_to_zero(acc_ff[:2]) + dv / dt_s
        if math.isfinite(limits.slew_acc_up_m_s2) and math.isfinite(vel_sp[2]):
            dz = float(vel_sp[2] - prev[2])
            dz = min(max(dz, -limits.slew_acc_up_m_s2 * dt_s), limits.slew_acc_down_m_s2 * dt_s)
            vel_sp[2] = prev[2] + dz
            acc_ff[2] = (acc_ff[2] if math.isfinite(acc_ff[2]) else 0.0) + dz / dt_s
        return vel_sp, acc_ff

    def update(
        self,
        dt_s: float,
        pos_ned_m: Vec3,
        vel_ned_m_s: Vec3,
        sp: TrajectorySetpoint,
        yaw_sp_rad: float,
        limits: Limits,
        airframe: Airframe,
        integrate: bool = True,
    ) -> AttitudeThrust:
        """One control step -> attitude and thrust for the EAV. `integrate=False` freezes the integrator (ground)."""
        g = self.gains
        vel_sp, acc_ff = self.velocity_setpoint(pos_ned_m, sp, limits)
        vel_sp, acc_ff = self._slew(dt_s, vel_sp, acc_ff, vel_ned_m_s, limits)
        self.last_vel_sp_ned_m_s = vel_sp.copy()
        vel_ctrl = np.isfinite(vel_sp)
        kp = np.array([g.vel_xy_p, g.vel_xy_p, g.vel_z_p])
        ki = np.array([g.vel_xy_i, g.vel_xy_i, g.vel_z_i])
        err = np.where(vel_ctrl, _nan_to_zero(vel_sp) - vel_ned_m_s, 0.0)
        acc_sp = kp * err + np.where(vel_ctrl, self.vel_int_m_s2, 0.0) + _nan_to_zero(acc_ff)
        m, gz = airframe.mass_kg, airframe.gravity_m_s2
        # Drag feed-forward: the airframe's k_d is known to the autopilot (it is a SIM_ parameter).
        drag_ff = airframe.drag_kd_n_s_m / m * vel_ned_m_s
        force = m * (acc_sp + drag_ff - np.array([0.0, 0.0, gz]))

        # Vertical first (PX4 prioritises altitude): keep thrust within [min, max] along -z.
        fz_unsat = float(force[2])
        fz = min(max(fz_unsat, -limits.thrust_max_n), -limits.thrust_min_n)
        sat_z = fz != fz_unsat
        # Horizontal: tilt limit and remaining thrust margin.
        f_xy = force[:2].copy()
        f_xy_max = abs(fz) * math.tan(limits.tilt_max_rad)
        f_xy_max = min(f_xy_max, math.sqrt(max(0.0, limits.thrust_max_n**2 - fz * fz)))
        n_xy = float(np.hypot(f_xy[0], f_xy[1]))
        sat_xy = n_xy > f_xy_max
        if sat_xy:
            f_xy *= f_xy_max / n_xy
        force = np.array([f_xy[0], f_xy[1], fz])

        if integrate and dt_s > 0.0:
            # Conditional integration (anti-windup): no integration on a saturated axis group.
            inc = ki * err * dt_s
            if not sat_xy:
                self.vel_int_m_s2[:2] += inc[:2]
            if not sat_z:
                self.vel_int_m_s2[2] += inc[2]
            lim = 0.5 * gz  # integral authority: half a g
            np.clip(self.vel_int_m_s2, -lim, lim, out=self.vel_int_m_s2)
        roll, pitch, thrust = attitude_from_thrust_vector(force, yaw_sp_rad)
        return AttitudeThrust(roll, pitch, yaw_sp_rad, thrust)


def slew_yaw(current_sp_rad: float, target_rad: float, max_rate_rad_s: float, dt_s: float) -> float:
    """Move a yaw setpoint toward a target the shortest way, at most max_rate*dt per step."""
    err = wrap_pi(target_rad - current_sp_rad)
    step = max_rate_rad_s * dt_s
    if max_rate_rad_s <= 0.0 or abs(err) <= step:
        return wrap_pi(target_rad)
    return wrap_pi(current_sp_rad + math.copysign(step, err))


def body_rates_to_euler_rates(
    roll_rad: float, pitch_rad: float, rates_frd_rad_s: tuple[float, float, float]
) -> tuple[float, float, float]:
    """ZYX Euler angle rates from body rates (p, q, r); pitch is kept away from ±90° by the tilt limits."""
    p, q, r = rates_frd_rad_s
    sr, cr = math.sin(roll_rad), math.cos(roll_rad)
    cp = max(1e-3, math.cos(pitch_rad))
    tp = math.sin(pitch_rad) / cp
    return p + (q * sr + r * cr) * tp, q * cr - r * sr, (q * sr + r * cr) / cp
