"""One flight task per mode (PX4's FlightTasks + Navigator modes): each turns the latest state into an EAV command.

Every task has `activate(now_s)` (called when its mode is entered) and `update(now_s, dt, state, eav) -> EavCommand`
(called once per physics step while its mode is active, armed). They share only the FlightContext.
`FlightTasks` holds one of each, enters modes (PX4's mode transition side effects) and dispatches the control step.
"""

from __future__ import annotations

from viva_sitl.autopilot.context import FlightContext
from viva_sitl.autopilot.tasks.follow import FollowTargetTask
from viva_sitl.autopilot.tasks.hold import HoldTask
from viva_sitl.autopilot.tasks.land import LandTask
from viva_sitl.autopilot.tasks.manual import MANUAL_MODES, ManualTask
from viva_sitl.autopilot.tasks.mission import MissionTask
from viva_sitl.autopilot.tasks.offboard import OffboardKind, OffboardTask
from viva_sitl.autopilot.tasks.orbit import OrbitTask
from viva_sitl.autopilot.tasks.rtl import RtlPhase, RtlTask
from viva_sitl.autopilot.tasks.takeoff import TakeoffTask
from viva_sitl.autopilot.types import FlightMode
from viva_sitl.dynamics import EavCommand, EavParams, EavState


class FlightTasks:
    def __init__(self, ctx: FlightContext) -> None:
        self.ctx = ctx
        self.hold = HoldTask(ctx)
        self.takeoff = TakeoffTask(ctx, self.hold)
        self.land = LandTask(ctx)
        self.rtl = RtlTask(ctx)
        self.offboard = OffboardTask(ctx)
        self.manual = ManualTask(ctx)
        self.orbit = OrbitTask(ctx)
        self.follow = FollowTargetTask(ctx)
        self.mission = MissionTask(ctx, self.enter, self.control, self.rtl.update)

    def enter(self, mode: FlightMode, now_s: float) -> None:
        """Switch to `mode` (no checks: the commander decides) and activate its task."""
        ctx = self.ctx
        prev = ctx.mode
        ctx.mode = mode
        ctx.speed_override = None
        ctx.ctrl.restart_trajectory()
        if mode == FlightMode.AUTO_LOITER:
            self.hold.activate(now_s)
        elif mode == FlightMode.AUTO_LAND:
            self.land.activate(now_s)
        elif mode == FlightMode.AUTO_RTL:
            self.rtl.activate(now_s)
        elif mode == FlightMode.AUTO_TAKEOFF:
            self.takeoff.activate(now_s)
        elif mode == FlightMode.AUTO_MISSION:
            self.mission.activate(now_s, prev)
        elif mode == FlightMode.OFFBOARD:
            self.offboard.activate(now_s)
        elif mode == FlightMode.ORBIT:
            self.orbit.activate(now_s)
        elif mode == FlightMode.AUTO_FOLLOW_TARGET:
            self.follow.activate(now_s)
        elif mode in MANUAL_MODES:
            self.manual.activate(now_s)
        if prev != mode and prev == FlightMode.OFFBOARD:
            ctx.ctrl.reset_xy()

    def control(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        """The active mode's task: one control step (armed)."""
        mode = self.ctx.mode
        if mode == FlightMode.AUTO_TAKEOFF:
            return self.takeoff.update(now_s, dt, state, eav)
        if mode == FlightMode.AUTO_LAND:
            return self.land.update(now_s, dt, state, eav)
        if mode == FlightMode.AUTO_RTL:
            return self.rtl.update(now_s, dt, state, eav)
        if mode == FlightMode.AUTO_MISSION:
            return self.mission.update(now_s, dt, state, eav)
        if mode == FlightMode.OFFBOARD:
            return self.offboard.update(now_s, dt, state, eav)
        if mode == FlightMode.ORBIT:
            return self.orbit.update(now_s, dt, state, eav)
        if mode == FlightMode.AUTO_FOLLOW_TARGET:
            return self.follow.update(now_s, dt, state, eav)
        if mode in MANUAL_MODES:
            return self.manual.update(now_s, dt, state, eav)
        return self.hold.update(now_s, dt, state, eav)

    @property
    def takeoff_phase(self) -> bool:
        """Climbing out (PX4's landed state TAKEOFF)."""
        mode = self.ctx.mode
        return mode == FlightMode.AUTO_TAKEOFF or (mode == FlightMode.AUTO_MISSION and self.mission.climbing)

    @property
    def landing_phase(self) -> bool:
        """Descending to land (PX4's landed state LANDING)."""
        mode = self.ctx.mode
        return (
            mode == FlightMode.AUTO_LAND
            or (mode == FlightMode.AUTO_RTL and self.rtl.landing)
            or (mode == FlightMode.AUTO_MISSION and self.mission.landing)
        )


__all__ = [
    "MANUAL_MODES",
    "FlightTasks",
    "FollowTargetTask",
    "HoldTask",
    "LandTask",
    "ManualTask",
    "MissionTask",
    "OffboardKind",
    "OffboardTask",
    "OrbitTask",
    "RtlPhase",
    "RtlTask",
    "TakeoffTask",
]
