"""Takeoff (AUTO_TAKEOFF): climb vertically at MPC_TKO_SPEED to the take-off altitude, then Hold there."""

from __future__ import annotations

import numpy as np

from viva_sitl.autopilot.context import FlightContext, Vec3
from viva_sitl.autopilot.tasks.common import limits, position_setpoint, run_position
from viva_sitl.autopilot.tasks.hold import HoldTask
from viva_sitl.autopilot.types import FlightMode, Severity
from viva_sitl.dynamics import EavCommand, EavParams, EavState


class TakeoffTask:
    def __init__(self, ctx: FlightContext, hold: HoldTask) -> None:
        self.ctx = ctx
        self.hold = hold  # where the vehicle goes when the altitude is reached
        self.target: Vec3 | None = None

    def activate(self, now_s: float) -> None:
        if self.ctx.armed:
            self.start(self.ctx.params.get("MIS_TAKEOFF_ALT"))

    def start(self, alt_m: float) -> None:
        """Take off to `alt_m` above home from here (already higher: stay at the current altitude)."""
        ctx = self.ctx
        pos = ctx.pos
        ctx.mode = FlightMode.AUTO_TAKEOFF
        self.target = np.array([pos[0], pos[1], ctx.home[2] - alt_m])
        if not ctx.on_ground and self.target[2] > pos[2]:
            self.target[2] = pos[2]  # already higher: PX4 does not descend in take-off
        ctx.speed_override = None

    def update(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        ctx = self.ctx
        if self.target is None:
            self.start(ctx.params.get("MIS_TAKEOFF_ALT"))
        assert self.target is not None
        t = self.target
        alt_err = abs(float(state.pos_ned_m[2]) - float(t[2]))
        if not state.landed and alt_err < min(ctx.params.get("NAV_MC_ALT_RAD"), 0.5):
            # Reached: PX4 switches to Hold at the take-off setpoint.
            ctx.mode = FlightMode.AUTO_LOITER
            self.hold.hold_at(t.copy())
            ctx.speed_override = None
            self.target = None
            ctx.event(Severity.INFO, "Takeoff altitude reached, holding")
            return self.hold.update(now_s, dt, state, eav)
        sp = position_setpoint(self.ctx, t)
        lim = limits(ctx, xy=ctx.cruise(), up=ctx.params.get("MPC_TKO_SPEED"), auto=True)
        return run_position(ctx, dt, state, sp, lim, eav, None, 0.0)
