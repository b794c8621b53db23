"""Orbit (PX4's Orbit mode, MAV_CMD_DO_ORBIT): circle a centre at a radius and tangential velocity.

The geometry (approach, circle setpoint, yaw behaviour) is the pure `viva_sitl.autopilot.orbit`; this task keeps the
orbit flown now and runs the position controller on its setpoints. Entering the mode without a command orbits the
current position with PX4's defaults (1 m radius, 1 m/s).
"""

from __future__ import annotations

import math
from dataclasses import replace

from viva_sitl.autopilot.context import FlightContext
from viva_sitl.autopilot.orbit import Orbit, apply_command, orbit_step
from viva_sitl.autopilot.tasks.common import limits, run_position, yaw_rate_auto
from viva_sitl.dynamics import EavCommand, EavParams, EavState


class OrbitTask:
    def __init__(self, ctx: FlightContext) -> None:
        self.ctx = ctx
        self.orbit: Orbit | None = None
        self.approaching = True  # flying to the circle (cruise speed) before circling on it

    def activate(self, now_s: float) -> None:
        self.set(self.default())

    def default(self) -> Orbit:
        ctx = self.ctx
        return apply_command(None, ctx.pos, ctx.yaw, math.nan, math.nan, math.nan, None, None,
                             ctx.params.get("MC_ORBIT_RAD_MAX"))  # fmt: skip

    def set(self, orbit: Orbit) -> None:
        self.orbit = orbit
        self.approaching = True

    def update(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        ctx = self.ctx
        p = ctx.params
        if self.orbit is None:
            self.orbit = self.default()
        step = orbit_step(self.orbit, state.pos_ned_m, self.approaching, p.get("NAV_MC_ALT_RAD"))
        self.approaching = step.approaching
        xy = p.get("MPC_XY_CRUISE") if step.approaching else p.get("MPC_XY_VEL_MAX")
        lim = limits(ctx, xy=xy, auto=True)
        if (
            not step.approaching
        ):  # the circle's own acceleration feed-forward: no slew (it would count it twice)
            lim = replace(lim, slew_acc_xy_m_s2=math.inf)
        return run_position(ctx, dt, state, step.setpoint, lim, eav, step.yaw_rad, yaw_rate_auto(ctx))
