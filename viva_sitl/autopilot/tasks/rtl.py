"""Return (AUTO_RTL): climb to RTL_RETURN_ALT, fly home, descend to RTL_DESCEND_ALT, loiter RTL_LAND_DELAY, land."""

from __future__ import annotations

import enum
import math

import numpy as np

from viva_sitl.autopilot.context import FlightContext, Vec3
from viva_sitl.autopilot.tasks.common import goto, yaw_rate_auto
from viva_sitl.autopilot.tasks.land import descend
from viva_sitl.dynamics import EavCommand, EavParams, EavState


class RtlPhase(enum.Enum):
    CLIMB = 1
    RETURN = 2
    DESCEND = 3
    LOITER = 4
    LAND = 5


class RtlTask:
    def __init__(self, ctx: FlightContext) -> None:
        self.ctx = ctx
        self.phase = RtlPhase.CLIMB
        self.alt_down = 0.0  # return altitude (NED down)
        self.loiter_since_s = 0.0
        self.climb_at: Vec3 | None = None  # where the climb happens (the braking point)

    @property
    def landing(self) -> bool:
        return self.phase == RtlPhase.LAND

    def activate(self, now_s: float) -> None:
        ctx = self.ctx
        pos = ctx.pos
        self.alt_down = float(min(pos[2], ctx.home[2] - ctx.params.get("RTL_RETURN_ALT")))
        self.phase = RtlPhase.LAND if ctx.on_ground else RtlPhase.CLIMB
        self.climb_at = ctx.braking_point()

    def update(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        ctx = self.ctx
        p = ctx.params
        pos = np.asarray(state.pos_ned_m, dtype=np.float64)
        home = ctx.home
        if self.climb_at is None:
            self.climb_at = pos.copy()
        if self.phase == RtlPhase.CLIMB:
            target = np.array([self.climb_at[0], self.climb_at[1], self.alt_down])
            if pos[2] - self.alt_down < 0.5:
                self.phase = RtlPhase.RETURN
        if self.phase == RtlPhase.RETURN:
            target = np.array([home[0], home[1], self.alt_down])
            if math.hypot(pos[0] - home[0], pos[1] - home[1]) < min(p.get("NAV_ACC_RAD"), 1.0):
                self.phase = RtlPhase.DESCEND
        if self.phase == RtlPhase.DESCEND:
            desc_down = float(max(self.alt_down, home[2] - p.get("RTL_DESCEND_ALT")))
            target = np.array([home[0], home[1], desc_down])
            if abs(pos[2] - desc_down) < 0.5:
                self.phase = RtlPhase.LOITER
                self.loiter_since_s = now_s
        if self.phase == RtlPhase.LOITER:
            delay = p.get("RTL_LAND_DELAY")
            target = np.array([home[0], home[1], max(self.alt_down, home[2] - p.get("RTL_DESCEND_ALT"))])
            if delay >= 0 and now_s - self.loiter_since_s >= delay:
                self.phase = RtlPhase.LAND
        if self.phase == RtlPhase.LAND:
            return descend(ctx, dt, state, eav, (float(home[0]), float(home[1])))
        yaw_target = None
        if self.phase == RtlPhase.RETURN and math.hypot(home[0] - pos[0], home[1] - pos[1]) > 3.0:
            yaw_target = math.atan2(home[1] - pos[1], home[0] - pos[0])
        return goto(ctx, dt, state, eav, target, yaw_target, yaw_rate_auto(ctx))
