"""Offboard: follow the latest SET_POSITION_TARGET_* (position / velocity / acceleration) or SET_ATTITUDE_TARGET
(attitude or body rates + thrust) stream."""

from __future__ import annotations

import enum
import math

import numpy as np

from viva_sitl.autopilot.context import FlightContext, Vec3
from viva_sitl.autopilot.control import TrajectorySetpoint, body_rates_to_euler_rates
from viva_sitl.autopilot.setpoints import check_attitude_target, position_target_to_local
from viva_sitl.autopilot.tasks.common import limits, run_position, thrust_from_norm
from viva_sitl.autopilot.types import (
    ACCEPTED,
    AttitudeTarget,
    CommandResult,
    FlightMode,
    Outcome,
    PositionTarget,
)
from viva_sitl.dynamics import EavCommand, EavParams, EavState, wrap_pi

OFFBOARD_FRESH_S = 0.5  # a setpoint within this -> the stream runs at > 2 Hz (mode switch / arming)


class OffboardKind(enum.Enum):
    NONE = 0
    TRAJECTORY = 1  # position / velocity / acceleration
    ATTITUDE = 2  # quaternion + thrust
    RATES = 3  # body rates + thrust


class OffboardTask:
    def __init__(self, ctx: FlightContext) -> None:
        self.ctx = ctx
        self.kind = OffboardKind.NONE
        self.last_s = -math.inf  # when the last valid setpoint arrived
        self.traj = TrajectorySetpoint()
        self.yaw_rad: float | None = None
        self.yaw_rate_rad_s = 0.0
        self.att = (0.0, 0.0, 0.0, 0.0)  # roll, pitch, yaw, thrust_norm
        self.rates = (0.0, 0.0, 0.0)
        self.rate_att: Vec3 | None = None  # integrated attitude target for body rates

    def fresh(self, now_s: float) -> bool:
        return self.kind != OffboardKind.NONE and now_s - self.last_s <= OFFBOARD_FRESH_S

    def activate(self, now_s: float) -> None:
        self.rate_att = None
        self.ctx.yaw_sp = self.ctx.yaw

    # --- the setpoint stream (ignored with a reason when NaN/inf or out of range; never raises) ---------------
    def set_position_target(self, now_s: float, target: PositionTarget) -> Outcome:
        ctx = self.ctx
        pos = ctx.pos
        try:
            self.traj = position_target_to_local(
                target, (float(pos[0]), float(pos[1]), float(pos[2])), ctx.yaw
            )
        except ValueError as e:
            return Outcome(CommandResult.DENIED, str(e))
        self.yaw_rad = target.yaw_rad
        self.yaw_rate_rad_s = target.yaw_rate_rad_s if target.yaw_rate_rad_s is not None else 0.0
        if self.kind != OffboardKind.TRAJECTORY and ctx.mode == FlightMode.OFFBOARD:
            ctx.yaw_sp = ctx.yaw
            ctx.ctrl.reset()
        self.kind = OffboardKind.TRAJECTORY
        self.last_s = now_s
        return ACCEPTED

    def set_attitude_target(self, now_s: float, target: AttitudeTarget) -> Outcome:
        try:
            rpy = check_attitude_target(target)
        except ValueError as e:
            return Outcome(CommandResult.DENIED, str(e))
        if rpy is not None:
            self.att = (*rpy, target.thrust_norm)
            self.kind = OffboardKind.ATTITUDE
        else:
            assert target.body_rates_rad_s is not None
            if self.kind != OffboardKind.RATES:
                self.rate_att = None  # restart integration from the current attitude
            self.rates = target.body_rates_rad_s
            self.att = (*self.att[:3], target.thrust_norm)
            self.kind = OffboardKind.RATES
        self.last_s = now_s
        return ACCEPTED

    def update(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        ctx = self.ctx
        if self.kind == OffboardKind.ATTITUDE:
            r, pt, y, t = self.att
            ctx.yaw_sp = y
            return EavCommand(r, pt, y, thrust_from_norm(ctx, t, eav))
        if self.kind == OffboardKind.RATES:
            if self.rate_att is None:
                self.rate_att = np.array(state.att_rpy_rad, dtype=np.float64)
            a = self.rate_att
            dr, dp, dy = body_rates_to_euler_rates(float(a[0]), float(a[1]), self.rates)
            tilt_lim = eav.max_tilt_rad
            a[0] = min(max(a[0] + dr * dt, -tilt_lim), tilt_lim)
            a[1] = min(max(a[1] + dp * dt, -tilt_lim), tilt_lim)
            a[2] = wrap_pi(float(a[2] + dy * dt))
            ctx.yaw_sp = float(a[2])
            return EavCommand(float(a[0]), float(a[1]), float(a[2]), thrust_from_norm(ctx, self.att[3], eav))
        if self.yaw_rad is not None:
            yaw_target: float | None = self.yaw_rad
        else:
            yaw_target = None
            ctx.yaw_sp = wrap_pi(ctx.yaw_sp + self.yaw_rate_rad_s * dt)
        lim = limits(ctx, xy=ctx.params.get("MPC_XY_VEL_MAX"), auto=False)
        return run_position(ctx, dt, state, self.traj, lim, eav, yaw_target, math.radians(200.0))
