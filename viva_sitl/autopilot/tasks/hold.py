"""Hold (AUTO_LOITER, PX4's Hold mode): stay at a point; DO_REPOSITION moves that point."""

from __future__ import annotations

import math

import numpy as np

from viva_sitl.autopilot.context import FlightContext, Vec3
from viva_sitl.autopilot.tasks.common import goto, yaw_rate_auto
from viva_sitl.dynamics import EavCommand, EavParams, EavState


class HoldTask:
    def __init__(self, ctx: FlightContext) -> None:
        self.ctx = ctx
        self.target: Vec3 | None = None  # NED
        self.yaw_rad: float | None = None  # None: keep the heading (or face a far target)

    def activate(self, now_s: float) -> None:
        """Hold at the braking point (in the air) or where the vehicle stands."""
        ctx = self.ctx
        self.hold_at(ctx.braking_point() if not ctx.on_ground else ctx.pos.copy())

    def hold_at(self, target: Vec3, yaw_rad: float | None = None) -> None:
        self.target = target
        self.yaw_rad = yaw_rad

    def update(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        if self.target is None:
            self.target = np.array(state.pos_ned_m, dtype=np.float64)
        target = self.target
        yaw_target = self.yaw_rad
        pos = state.pos_ned_m
        if yaw_target is None and math.hypot(target[0] - pos[0], target[1] - pos[1]) > 3.0:
            # Travelling to a reposition target: face it (PX4 heads toward DO_REPOSITION targets).
            yaw_target = math.atan2(target[1] - pos[1], target[0] - pos[0])
        return goto(self.ctx, dt, state, eav, target, yaw_target, yaw_rate_auto(self.ctx))
