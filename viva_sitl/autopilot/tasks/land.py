"""Land (AUTO_LAND): descend at MPC_LAND_SPEED below MPC_LAND_ALT2 (faster above, blended up to MPC_LAND_ALT1),
holding the horizontal position; also the final phase of RTL and of a mission LAND item."""

from __future__ import annotations

import math

from viva_sitl.autopilot.context import FlightContext
from viva_sitl.autopilot.control import TrajectorySetpoint
from viva_sitl.autopilot.tasks.common import descent_setpoint, limits, run_position
from viva_sitl.dynamics import EavCommand, EavParams, EavState


def land_speed_m_s(ctx: FlightContext, state: EavState, eav: EavParams) -> float:
    p = ctx.params
    alt = eav.ground_z_ned_m - float(state.pos_ned_m[2])
    v_land, v_fast = p.get("MPC_LAND_SPEED"), p.get("MPC_Z_VEL_MAX_DN")
    a1, a2 = p.get("MPC_LAND_ALT1"), p.get("MPC_LAND_ALT2")
    if alt <= a2:
        return v_land
    if alt >= a1 or a1 <= a2:
        return max(v_fast, v_land) if alt >= a1 else v_land
    return v_land + (max(v_fast, v_land) - v_land) * (alt - a2) / (a1 - a2)


def descend(
    ctx: FlightContext, dt: float, state: EavState, eav: EavParams, xy: tuple[float, float]
) -> EavCommand:
    """One step of a landing descent at the ground point `xy` (NED north, east)."""
    v = land_speed_m_s(ctx, state, eav)
    sp = descent_setpoint(ctx, xy[0], xy[1], v)
    lim = limits(ctx, xy=ctx.cruise(), down=max(v, 0.1), auto=True)
    return run_position(ctx, dt, state, sp, lim, eav, None, 0.0)


def descend_blind(ctx: FlightContext, dt: float, state: EavState, eav: EavParams) -> EavCommand:
    """PX4's Descend (no horizontal position estimate, e.g. the GPS lost): no horizontal control, level (zero
    horizontal acceleration), down at MPC_LAND_SPEED on the height estimate, drifting with the wind."""
    v = ctx.params.get("MPC_LAND_SPEED")
    sp = TrajectorySetpoint(vel_ned_m_s=(math.nan, math.nan, v), acc_ned_m_s2=(0.0, 0.0, math.nan))
    lim = limits(ctx, xy=ctx.cruise(), down=max(v, 0.1), auto=True)
    return run_position(ctx, dt, state, sp, lim, eav, None, 0.0)


class LandTask:
    def __init__(self, ctx: FlightContext) -> None:
        self.ctx = ctx
        self.xy: tuple[float, float] | None = None

    def activate(self, now_s: float) -> None:
        pos = self.ctx.braking_point()
        self.xy = (float(pos[0]), float(pos[1]))

    def update(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        if not self.ctx.position_valid:
            return descend_blind(self.ctx, dt, state, eav)
        if self.xy is None:
            self.xy = (float(state.pos_ned_m[0]), float(state.pos_ned_m[1]))
        return descend(self.ctx, dt, state, eav, self.xy)
