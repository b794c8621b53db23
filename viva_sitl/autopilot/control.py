"""Cascaded multicopter control as PX4's PositionControl: position P -> velocity PI -> acceleration -> tilt + thrust.

Pure maths plus one small stateful object (the velocity integrator). No clock: the caller passes dt.
Setpoints follow PX4's trajectory_setpoint convention: per axis, a NaN position means "not position controlled",
a NaN velocity means "not velocity controlled" (acceleration only); finite velocity/acceleration next to a finite
position are feed-forward.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import cast

import numpy as np
from numpy.typing import NDArray

from viva_sitl.dynamics import floats3, wrap_pi

Vec3 = NDArray[np.float64]
_NAN3 = (math.nan, math.nan, math.nan)


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


def _norm3(buf: Vec3, x: float, y: float, z: float) -> float:
    """np.linalg.norm of (x, y, z), bit for bit: sqrt(v.dot(v)) (BLAS ddot, whose rounding math on floats does not
    reproduce) on `buf`, a float64 3-vector reused so that no array is created per call."""
    buf[0] = x
    buf[1] = y
    buf[2] = z
    return math.sqrt(buf.dot(buf))


def _libm_hypot() -> Callable[[float, float], float] | None:
    """The C library's hypot through ctypes (~0.4 us a call; np.hypot on two floats ~0.7 us). np.hypot calls the
    same libm function; math.hypot is Python's own algorithm and differs in the last bit now and then."""
    try:  # the symbols already loaded into the process (CPython links libm), no library search; PyDLL keeps
        # the GIL (a CDLL call releases and re-takes it: 4 GIL hand-overs per step to any other thread)
        fn = ctypes.PyDLL(None).hypot
    except (OSError, AttributeError, TypeError):
        return None
    fn.restype = ctypes.c_double
    fn.argtypes = (ctypes.c_double, ctypes.c_double)
    ok = all(fn(x, y) == float(np.hypot(x, y)) for x, y in ((3.0, 4.0), (0.1, 0.7), (1e-3, 2.5), (-0.3, 1e5)))
    return cast("Callable[[float, float], float]", fn) if ok else None


def _np_hypot(x: float, y: float) -> float:
    return float(np.hypot(x, y))


_hypot: Callable[[float, float], float] = _libm_hypot() or _np_hypot


def _attitude_from_force(norm_buf: Vec3, fx: float, fy: float, fz: float, yaw_rad: float
                         ) -> tuple[float, float, float]:  # fmt: skip
    thrust = _norm3(norm_buf, fx, fy, fz)
    if thrust < 1e-9:
        return 0.0, 0.0, 0.0
    b0, b1, b2 = -fx / thrust, -fy / thrust, -fz / thrust  # body z axis (down) in NED
    cy, sy = math.cos(yaw_rad), math.sin(yaw_rad)
    # Rz(-yaw) b3 = (sin p cos r, -sin r, cos p cos r) for the ZYX convention.
    bx = cy * b0 + sy * b1
    by = -sy * b0 + cy * b1
    roll = -math.asin(max(-1.0, min(1.0, by)))
    pitch = math.atan2(bx, b2)
    return roll, pitch, thrust


def attitude_from_thrust_vector(force_ned_n: Vec3, yaw_rad: float) -> tuple[float, float, float]:
    """(roll, pitch, |F|) such that the body -z axis (thrust) of a ZYX attitude with this yaw points along F."""
    f = np.asarray(force_ned_n, dtype=np.float64).reshape(3)
    return _attitude_from_force(np.empty(3), float(f[0]), float(f[1]), float(f[2]), yaw_rad)


def _nz(x: float) -> float:
    """NaN -> 0.0 (inf kept), as np.where(np.isnan(x), 0.0, x)."""
    return x if x == x else 0.0


_isfinite = math.isfinite

Xyz = tuple[float, float, float]


class PositionController:
    """Position P -> velocity PI -> thrust vector, with PX4's limits and anti-windup. One per vehicle.

    The 250 Hz step works on Python floats, one axis after the other, in the order of operations the numpy
    3-vector code had (the same IEEE doubles, so the same bits); the state is exposed as numpy arrays."""

    def __init__(self, gains: Gains | None = None) -> None:
        self.gains = gains if gains is not None else Gains()
        self._int: Xyz = (0.0, 0.0, 0.0)  # integral term (already times I gain)
        self._last: Xyz = _NAN3  # last velocity setpoint; NaN: start from measured
        self._norm_buf = np.empty(3)

    @property
    def vel_int_m_s2(self) -> Vec3:
        """The velocity integrator (already times the I gain), a copy."""
        return np.array(self._int, dtype=np.float64)

    @vel_int_m_s2.setter
    def vel_int_m_s2(self, value: Vec3) -> None:
        self._int = floats3(value)

    @property
    def last_vel_sp_ned_m_s(self) -> Vec3:
        """The last velocity setpoint (NaN: none yet, the next one slews from the measured velocity), a copy."""
        return np.array(self._last, dtype=np.float64)

    @last_vel_sp_ned_m_s.setter
    def last_vel_sp_ned_m_s(self, value: Vec3) -> None:
        self._last = floats3(value)

    def reset(self) -> None:
        self._int = (0.0, 0.0, 0.0)
        self._last = _NAN3

    def restart_trajectory(self) -> None:
        """Next velocity setpoint slews from the measured velocity (mode change), integrators kept."""
        self._last = _NAN3

    def reset_xy(self) -> None:
        self._int = (0.0, 0.0, self._int[2])

    def velocity_setpoint(self, pos_ned_m: Vec3, sp: TrajectorySetpoint, limits: Limits) -> tuple[Vec3, Vec3]:
        """Position P with feed-forward -> (vel_sp, acc_ff). NaN vel_sp: that axis is acceleration-only."""
        p = np.asarray(pos_ned_m, dtype=np.float64).reshape(3)
        vel_sp, acc_ff = self._velocity_setpoint(float(p[0]), float(p[1]), float(p[2]), sp, limits)
        return np.array(vel_sp, dtype=np.float64), np.array(acc_ff, dtype=np.float64)

    def _velocity_setpoint(self, px: float, py: float, pz: float, sp: TrajectorySetpoint, limits: Limits
                           ) -> tuple[Xyz, Xyz]:  # fmt: skip
        g = self.gains
        spx, spy, spz = sp.pos_ned_m
        spx, spy, spz = float(spx), float(spy), float(spz)
        fx, fy, fz = sp.vel_ned_m_s
        vx, vy, vz = fx, fy, fz = float(fx), float(fy), float(fz)
        ax, ay, az = sp.acc_ned_m_s2
        acc: Xyz = (float(ax), float(ay), float(az))
        # Horizontal: P on the 2D error, direction preserved, braking-limited.
        if _isfinite(spx) and _isfinite(spy):
            ex, ey = spx - px, spy - py
            dist = _hypot(ex, ey)
            vxy0 = vxy1 = 0.0
            if dist > 1e-9:
                speed = _braking_speed(dist, g.pos_xy_p, limits.brake_acc_xy_m_s2)
                vxy0, vxy1 = ex / dist * speed, ey / dist * speed
            vx, vy = vxy0 + _nz(fx), vxy1 + _nz(fy)
        if _isfinite(spz):
            err_z = spz - pz
            v_z = math.copysign(_braking_speed(abs(err_z), g.pos_z_p, limits.brake_acc_z_m_s2), err_z)
            vz = v_z + (fz if _isfinite(fz) else 0.0)
        # Speed limits (PX4: horizontal norm, vertical up/down separately).
        if _isfinite(vx) and _isfinite(vy):
            n = _hypot(vx, vy)
            if n > limits.vel_xy_m_s:
                k = limits.vel_xy_m_s / n
                vx, vy = vx * k, vy * k
        if _isfinite(vz):
            vz = float(min(max(vz, -limits.vel_up_m_s), limits.vel_down_m_s))
        return (vx, vy, vz), acc

    def _slew(self, dt_s: float, vel_sp: Xyz, acc_ff: Xyz, vel: Xyz, limits: Limits) -> tuple[Xyz, Xyz]:
        """Rate-limit the velocity setpoint (auto modes) and feed its slope forward: smooth, overshoot-free moves."""
        if dt_s <= 0.0:
            return vel_sp, acc_ff
        lx, ly, lz = self._last
        px = lx if _isfinite(lx) else vel[0]
        py = ly if _isfinite(ly) else vel[1]
        pz = lz if _isfinite(lz) else vel[2]
        vx, vy, vz = vel_sp
        ax, ay, az = acc_ff
        if _isfinite(limits.slew_acc_xy_m_s2) and _isfinite(vx) and _isfinite(vy):
            dvx, dvy = vx - px, vy - py
            n = _hypot(dvx, dvy)
            max_dv = limits.slew_acc_xy_m_s2 * dt_s
            if n > max_dv:
                k = max_dv / n
                dvx, dvy = dvx * k, dvy * k
            vx, vy = px + dvx, py + dvy
            ax, ay = _nz(ax) + dvx / dt_s, _nz(ay) + dvy / dt_s
        if _isfinite(limits.slew_acc_up_m_s2) and _isfinite(vz):
            dz = vz - pz
            dz = min(max(dz, -limits.slew_acc_up_m_s2 * dt_s), limits.slew_acc_down_m_s2 * dt_s)
            vz = pz + dz
            az = (az if _isfinite(az) else 0.0) + dz / dt_s
        return (vx, vy, vz), (ax, ay, az)

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
        p = np.asarray(pos_ned_m, dtype=np.float64).reshape(3).tolist()
        v = np.asarray(vel_ned_m_s, dtype=np.float64).reshape(3).tolist()
        return self.update_xyz(dt_s, p[0], p[1], p[2], (v[0], v[1], v[2]), sp, yaw_sp_rad, limits, airframe,
                               integrate)  # fmt: skip

    def update_xyz(self, dt_s: float, px: float, py: float, pz: float, vel: Xyz, sp: TrajectorySetpoint,
                   yaw_sp_rad: float, limits: Limits, airframe: Airframe, integrate: bool = True,
                   ) -> AttitudeThrust:  # fmt: skip
        """`update` on floats: position (px, py, pz) and velocity `vel`, NED."""
        g = self.gains
        vel_sp, acc_ff = self._velocity_setpoint(px, py, pz, sp, limits)
        (vx, vy, vz), (ax, ay, az) = self._slew(dt_s, vel_sp, acc_ff, vel, limits)
        self._last = (vx, vy, vz)
        mvx, mvy, mvz = vel
        cx, cy, cz = _isfinite(vx), _isfinite(vy), _isfinite(vz)
        ex = vx - mvx if cx else 0.0
        ey = vy - mvy if cy else 0.0
        ez = vz - mvz if cz else 0.0
        ix, iy, iz = self._int
        kxy, kz = g.vel_xy_p, g.vel_z_p
        acc_x = kxy * ex + (ix if cx else 0.0) + _nz(ax)
        acc_y = kxy * ey + (iy if cy else 0.0) + _nz(ay)
        acc_z = kz * ez + (iz if cz else 0.0) + _nz(az)
        m, gz = airframe.mass_kg, airframe.gravity_m_s2
        # Drag feed-forward: the airframe's k_d is known to the autopilot (it is a SIM_ parameter).
        kd_m = airframe.drag_kd_n_s_m / m
        f_x = m * (acc_x + kd_m * mvx)
        f_y = m * (acc_y + kd_m * mvy)
        fz_unsat = m * (acc_z + kd_m * mvz - gz)

        # Vertical first (PX4 prioritises altitude): keep thrust within [min, max] along -z.
        fz = min(max(fz_unsat, -limits.thrust_max_n), -limits.thrust_min_n)
        sat_z = fz != fz_unsat
        # Horizontal: tilt limit and remaining thrust margin.
        f_xy_max = abs(fz) * math.tan(limits.tilt_max_rad)
        f_xy_max = min(f_xy_max, math.sqrt(max(0.0, limits.thrust_max_n**2 - fz * fz)))
        n_xy = _hypot(f_x, f_y)
        sat_xy = n_xy > f_xy_max
        if sat_xy:
            k = f_xy_max / n_xy
            f_x, f_y = f_x * k, f_y * k

        if integrate and dt_s > 0.0:
            # Conditional integration (anti-windup): no integration on a saturated axis group.
            kixy, kiz = g.vel_xy_i, g.vel_z_i
            if not sat_xy:
                ix += kixy * ex * dt_s
                iy += kixy * ey * dt_s
            if not sat_z:
                iz += kiz * ez * dt_s
            lim = 0.5 * gz  # integral authority: half a g
            self._int = (min(max(ix, -lim), lim), min(max(iy, -lim), lim), min(max(iz, -lim), lim))
        roll, pitch, thrust = _attitude_from_force(self._norm_buf, f_x, f_y, fz, yaw_sp_rad)
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
