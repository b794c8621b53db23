"""What every flight task uses: the controller limits from the MPC_* parameters and one position-control step."""

from __future__ import annotations

import math
import struct
from collections.abc import Sequence

import numpy as np

from viva_sitl.autopilot.context import FlightContext
from viva_sitl.autopilot.control import Airframe, AttitudeThrust, Limits, TrajectorySetpoint, slew_yaw
from viva_sitl.autopilot.params import ParamStore
from viva_sitl.dynamics import EavCommand, EavParams, EavState

NAN = math.nan


def limits(ctx: FlightContext, *, xy: float, up: float | None = None, down: float | None = None,
           auto: bool) -> Limits:  # fmt: skip
    """Velocity, tilt, thrust and (auto modes) acceleration limits: MPC_* parameters within the airframe's own."""
    p = ctx.params
    eav = ctx.eav_params()
    # the same Limits while the parameters (revision), the airframe object and the arguments are unchanged: this
    # runs at 250 Hz and reads ~9 parameters
    key = (p, p.revision, xy, up, down, auto)
    cached = ctx._limits_cache
    if cached is not None and cached[1] is eav and cached[0] == key:
        lim = cached[2]
        assert isinstance(lim, Limits)
        return lim
    lim = _limits(p, eav, xy, up, down, auto)
    ctx._limits_cache = (key, eav, lim)
    return lim


def _limits(
    p: ParamStore, eav: EavParams, xy: float, up: float | None, down: float | None, auto: bool
) -> Limits:
    mg = eav.hover_thrust_n
    hover_norm = p.get("MPC_THR_HOVER")
    tilt = math.radians(p.get("MPC_TILTMAX_AIR"))
    return Limits(
        vel_xy_m_s=xy,
        vel_up_m_s=p.get("MPC_Z_VEL_MAX_UP") if up is None else up,
        vel_down_m_s=p.get("MPC_Z_VEL_MAX_DN") if down is None else down,
        tilt_max_rad=min(tilt, eav.max_tilt_rad),
        thrust_min_n=min(p.get("MPC_THR_MIN") / hover_norm, 0.9) * mg,
        thrust_max_n=eav.max_thrust_n,
        brake_acc_xy_m_s2=p.get("MPC_ACC_HOR") if auto else eav.gravity_m_s2 * math.tan(tilt) * 0.5,
        brake_acc_z_m_s2=p.get("MPC_ACC_DOWN_MAX") if auto else 5.0,
        slew_acc_xy_m_s2=p.get("MPC_ACC_HOR") if auto else math.inf,
        slew_acc_up_m_s2=p.get("MPC_ACC_UP_MAX") if auto else math.inf,
        slew_acc_down_m_s2=p.get("MPC_ACC_DOWN_MAX") if auto else math.inf,
    )


def auto_limits(ctx: FlightContext) -> Limits:
    """Auto modes (hold, RTL, mission): cruise speed, PX4's auto acceleration limits."""
    return limits(ctx, xy=ctx.cruise(), auto=True)


def yaw_rate_auto(ctx: FlightContext) -> float:
    return math.radians(ctx.params.get("MPC_YAWRAUTO_MAX"))


def thrust_from_norm(ctx: FlightContext, thrust_norm: float, eav: EavParams) -> float:
    """Offboard/STABILIZED normalised thrust -> N: MPC_THR_HOVER hovers (linear)."""
    return max(0.0, thrust_norm) / ctx.params.get("MPC_THR_HOVER") * eav.hover_thrust_n


def idle(ctx: FlightContext) -> EavCommand:
    """Motors at zero, level, holding the yaw setpoint."""
    return EavCommand(0.0, 0.0, ctx.yaw_sp, 0.0)


def _airframe(ctx: FlightContext, eav: EavParams) -> Airframe:
    """What the controller knows of `eav` (the same object while the airframe is unchanged: this runs at 250 Hz)."""
    cached = ctx._airframe_cache
    if cached is not None and cached[0] is eav:
        return cached[1]
    air = Airframe(mass_kg=eav.mass_kg, drag_kd_n_s_m=eav.drag_kd_n_s_m, gravity_m_s2=eav.gravity_m_s2)
    ctx._airframe_cache = (eav, air)
    return air


def run_position(
    ctx: FlightContext, dt: float, state: EavState, sp: TrajectorySetpoint, lim: Limits, eav: EavParams,
    yaw_target: float | None, yaw_rate_max: float,
) -> EavCommand:  # fmt: skip
    """One step of the position/velocity controller toward `sp`, slewing the yaw setpoint to `yaw_target`."""
    if yaw_target is not None and math.isfinite(yaw_target):
        ctx.yaw_sp = slew_yaw(ctx.yaw_sp, yaw_target, yaw_rate_max, dt)
    on_ground = bool(state.landed)
    # floats, not 3-vectors: the same IEEE operations, in the same order, as state.vel_ned_m_s
    p = state.pos_ned_m.tolist()
    q = state.prev_pos_ned_m.tolist()
    sdt = state.dt_s
    vel = ((p[0] - q[0]) / sdt, (p[1] - q[1]) / sdt, (p[2] - q[2]) / sdt)
    out: AttitudeThrust = ctx.ctrl.update_xyz(
        dt, p[0], p[1], p[2], vel, sp, ctx.yaw_sp, lim, _airframe(ctx, eav), integrate=not on_ground
    )
    if on_ground:
        # On the ground: idle unless the controller asks for more than hover (take-off); no tilting.
        up = out.thrust_n * math.cos(out.roll_rad) * math.cos(out.pitch_rad)
        if up <= eav.hover_thrust_n * 1.02:
            ctx.ctrl.reset()
            return idle(ctx)
        return EavCommand(0.0, 0.0, ctx.yaw_sp, out.thrust_n)
    return EavCommand(out.roll_rad, out.pitch_rad, out.yaw_rad, out.thrust_n)


_PACK3 = struct.Struct(
    "=3d"
).pack  # three doubles' bits: a cache key that tells -0.0 from 0.0 (and NaN never hits)


def position_setpoint(ctx: FlightContext, target: Sequence[float] | np.ndarray) -> TrajectorySetpoint:
    """TrajectorySetpoint(pos_ned_m=target as floats); the same object while the target's bits are unchanged (a
    hold target or a waypoint stays put for thousands of 250 Hz steps)."""
    x, y, z = target.tolist() if isinstance(target, np.ndarray) else target
    key = _PACK3(x, y, z)
    cached = ctx._sp_cache.get("pos")
    if cached is not None and cached[0] == key:
        return cached[1]
    sp = TrajectorySetpoint(pos_ned_m=(float(x), float(y), float(z)))
    ctx._sp_cache["pos"] = (key, sp)
    return sp


def descent_setpoint(
    ctx: FlightContext, north_m: float, east_m: float, vel_down_m_s: float
) -> TrajectorySetpoint:
    """TrajectorySetpoint(pos_ned_m=(north, east, NaN), vel_ned_m_s=(NaN, NaN, v)), cached as position_setpoint."""
    key = _PACK3(north_m, east_m, vel_down_m_s)
    cached = ctx._sp_cache.get("descent")
    if cached is not None and cached[0] == key:
        return cached[1]
    sp = TrajectorySetpoint(pos_ned_m=(north_m, east_m, NAN), vel_ned_m_s=(NAN, NAN, vel_down_m_s))
    ctx._sp_cache["descent"] = (key, sp)
    return sp


def goto(ctx: FlightContext, dt: float, state: EavState, eav: EavParams, target: np.ndarray,
         yaw_target: float | None = None, yaw_rate_max: float = 0.0) -> EavCommand:  # fmt: skip
    """Fly to a NED position with the auto limits."""
    sp = position_setpoint(ctx, target)
    return run_position(ctx, dt, state, sp, auto_limits(ctx), eav, yaw_target, yaw_rate_max)
