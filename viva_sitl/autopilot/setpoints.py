"""Pure checks and conversions of the streamed inputs: offboard setpoints and MANUAL_CONTROL sticks.

Each check raises ValueError with the reason a pilot sees; the autopilot turns it into a DENIED Outcome and leaves
its state untouched (PX4 ignores such setpoints).
"""

from __future__ import annotations

import math

from viva_sitl.autopilot.control import TrajectorySetpoint
from viva_sitl.autopilot.types import AttitudeTarget, ManualInput, OffboardFrame, PositionTarget
from viva_sitl.dynamics import euler_from_quat

NAN = math.nan
MAX_ABS_POS_M = 1.0e6
MAX_ABS_VEL_M_S = 100.0
MAX_ABS_ACC_M_S2 = 100.0
MAX_ABS_RATE_RAD_S = 50.0
MAX_ABS_YAW_RAD = 100.0


def finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def _bounded(v: tuple[float, ...] | None, bound: float) -> bool:
    return v is None or all(math.isfinite(c) and abs(c) <= bound for c in v)


def rot_yaw(yaw_rad: float, v_xy: tuple[float, float]) -> tuple[float, float]:
    """Rotate a horizontal vector from the heading frame to NED."""
    c, s = math.cos(yaw_rad), math.sin(yaw_rad)
    return c * v_xy[0] - s * v_xy[1], s * v_xy[0] + c * v_xy[1]


def position_target_to_local(
    target: PositionTarget, pos_ned_m: tuple[float, float, float], yaw_rad: float
) -> TrajectorySetpoint:
    """SET_POSITION_TARGET_* -> PX4 trajectory setpoint in LOCAL_NED (yaw / yaw rate are read by the caller).

    BODY_NED (PX4): velocity and acceleration are rotated by the current heading; a position is an offset from the
    vehicle, rotated the same way.
    """
    if not (
        _bounded(target.pos_ned_m, MAX_ABS_POS_M)
        and _bounded(target.vel_ned_m_s, MAX_ABS_VEL_M_S)
        and _bounded(target.acc_ned_m_s2, MAX_ABS_ACC_M_S2)
        and (target.yaw_rad is None or _bounded((target.yaw_rad,), MAX_ABS_YAW_RAD))
        and (target.yaw_rate_rad_s is None or _bounded((target.yaw_rate_rad_s,), MAX_ABS_RATE_RAD_S))
    ):
        raise ValueError("Offboard setpoint ignored: NaN/inf or out of range")
    pos, vel, acc = target.pos_ned_m, target.vel_ned_m_s, target.acc_ned_m_s2
    if pos is None and vel is None and acc is None:
        raise ValueError("Offboard setpoint ignored: no position, velocity or acceleration")
    if target.frame == OffboardFrame.BODY_NED:
        if pos is not None:
            dn, de = rot_yaw(yaw_rad, (pos[0], pos[1]))
            pos = (pos_ned_m[0] + dn, pos_ned_m[1] + de, pos_ned_m[2] + pos[2])
        if vel is not None:
            vel = (*rot_yaw(yaw_rad, (vel[0], vel[1])), vel[2])
        if acc is not None:
            acc = (*rot_yaw(yaw_rad, (acc[0], acc[1])), acc[2])
    nan3 = (NAN, NAN, NAN)
    return TrajectorySetpoint(
        pos_ned_m=pos if pos is not None else nan3,
        vel_ned_m_s=vel if vel is not None else nan3,
        acc_ned_m_s2=acc if acc is not None else nan3,
    )


def check_attitude_target(target: AttitudeTarget) -> tuple[float, float, float] | None:
    """Validate SET_ATTITUDE_TARGET; returns (roll, pitch, yaw) for the quaternion form, None for body rates."""
    if not math.isfinite(target.thrust_norm):
        raise ValueError("Attitude setpoint ignored: no thrust")
    if not (0.0 <= target.thrust_norm <= 1.0):
        raise ValueError(f"Attitude setpoint ignored: thrust {target.thrust_norm} outside 0..1")
    if target.q_wxyz is not None:
        if not _bounded(target.q_wxyz, 1e6):
            raise ValueError("Attitude setpoint ignored: quaternion NaN/inf")
        try:
            return euler_from_quat(*target.q_wxyz)
        except ValueError:
            raise ValueError("Attitude setpoint ignored: zero quaternion") from None
    if target.body_rates_rad_s is not None:
        if not _bounded(target.body_rates_rad_s, MAX_ABS_RATE_RAD_S):
            raise ValueError("Attitude setpoint ignored: body rates NaN/inf or out of range")
        return None
    raise ValueError("Attitude setpoint ignored: neither attitude nor body rates")


def check_manual_input(manual: ManualInput) -> None:
    if not finite(manual.x, manual.y, manual.z, manual.r):
        raise ValueError("Manual control ignored: NaN/inf")
    eps = 1e-6
    sticks_ok = all(-1 - eps <= v <= 1 + eps for v in (manual.x, manual.y, manual.r))
    if not (sticks_ok and -eps <= manual.z <= 1 + eps):
        raise ValueError("Manual control ignored: out of range")


def deadzone(v: float, dz: float) -> float:
    """Stick deadzone, rescaled so full travel stays 1."""
    if abs(v) <= dz:
        return 0.0
    return math.copysign((abs(v) - dz) / (1.0 - dz), v)


def throttle_to_thrust_norm(z: float, hover: float) -> float:
    """PX4's STABILIZED throttle curve: mid-stick = MPC_THR_HOVER, piecewise linear to 0 and 1."""
    z = min(max(z, 0.0), 1.0)
    return z / 0.5 * hover if z <= 0.5 else hover + (z - 0.5) / 0.5 * (1.0 - hover)
