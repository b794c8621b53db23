"""Mission (AUTO_MISSION): the uploaded plan and its executor (PX4's Navigator mission).

TAKEOFF items climb vertically at the current position; a mission started on the ground without a TAKEOFF item
first climbs to MIS_TAKEOFF_ALT (or the item's altitude). Non-navigation items complete at once: DO_JUMP is
followed (PX4's repeat counts, kept across a pause), camera and gimbal items become payload actions / a gimbal
angle (`payload.py`), anything else is logged and skipped. NAV_DELAY waits where the last item left the vehicle.
Relative altitudes (GLOBAL_RELATIVE_ALT frames) are resolved against home when the item starts, not at upload.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence

import numpy as np

from viva_sitl.autopilot.context import FlightContext, Vec3
from viva_sitl.autopilot.control import TrajectorySetpoint
from viva_sitl.autopilot.mission import (
    NAV_COMMANDS,
    MissionProgress,
    mission_yaw,
    resolve_item,
    resolve_jumps,
    validate_mission,
)
from viva_sitl.autopilot.payload import DistanceTrigger, item_effect
from viva_sitl.autopilot.tasks.common import (
    auto_limits,
    goto,
    idle,
    limits,
    position_setpoint,
    run_position,
    yaw_rate_auto,
)
from viva_sitl.autopilot.tasks.land import descend
from viva_sitl.autopilot.types import (
    ACCEPTED,
    CommandResult,
    FlightMode,
    MissionCommand,
    MissionItem,
    Outcome,
    PayloadAction,
    Severity,
)
from viva_sitl.dynamics import EavCommand, EavParams, EavState

EnterModeFn = Callable[[FlightMode, float], None]
ControlFn = Callable[[float, float, EavState, EavParams], EavCommand]
MAX_ITEMS_PER_STEP = 4  # items completed in one physics step before the executor waits for the next


class MissionTask:
    def __init__(
        self, ctx: FlightContext, enter_mode: EnterModeFn, control: ControlFn, rtl: ControlFn
    ) -> None:
        self.ctx = ctx
        self._enter_mode = enter_mode  # mode changes the mission asks for (RTL item, cleared mission)
        self._control = control  # the active mode's task, after such a change
        self._rtl = rtl  # the RTL task's update
        self.items: tuple[MissionItem, ...] = ()
        self.valid = False
        self.progress = MissionProgress()
        # payload: camera actions for the MAVLink camera component, the gimbal angle, PX4's distance trigger
        self.payload: list[PayloadAction] = []
        # (pitch, yaw) the last gimbal item asked for (MAVLink: pitch 0 level, -90 down; yaw from the nose, + right);
        # None until one does (the camera keeps its configured mount)
        self.gimbal_deg: tuple[float, float] | None = None
        self.trigger = DistanceTrigger()

    # --- the plan -----------------------------------------------------------------------------------
    def _validate(self, items: Sequence[MissionItem]) -> None:
        ctx = self.ctx
        home = (float(ctx.home[0]), float(ctx.home[1]), float(ctx.home[2]))
        validate_mission(items, home, ctx.footage_ok, ctx.params.get("MIS_DIST_1WP"), fence_ok=ctx.fence_ok)

    def revalidate(self) -> None:
        """A new geofence: as PX4, a stored mission with a waypoint outside it becomes invalid (not startable)."""
        if not self.items:
            return
        try:
            self._validate(self.items)
            self.valid = True
        except ValueError as e:
            self.valid = False
            self.ctx.event(Severity.WARNING, str(e))

    def set_items(self, items: Sequence[MissionItem]) -> Outcome:
        ctx = self.ctx
        items = tuple(items)
        try:
            self._validate(items)
        except ValueError as e:
            return Outcome(CommandResult.DENIED, str(e))
        self.items = items
        self.valid = len(items) > 0
        self.progress = MissionProgress(seq=0)
        if ctx.mode == FlightMode.AUTO_MISSION:
            if self.valid:
                self.start_item(ctx.now_s)
            else:
                self._enter_mode(FlightMode.AUTO_LOITER, ctx.now_s)
        return ACCEPTED

    def clear(self) -> Outcome:
        self.items = ()
        self.valid = False
        self.progress = MissionProgress(seq=0)
        if self.ctx.mode == FlightMode.AUTO_MISSION:
            self._enter_mode(FlightMode.AUTO_LOITER, self.ctx.now_s)
        return ACCEPTED

    def set_current(self, seq: int) -> Outcome:
        if not (0 <= seq < len(self.items)):
            return Outcome(CommandResult.DENIED, f"Mission: item {seq} does not exist")
        self.progress = MissionProgress(seq=seq)
        if self.ctx.mode == FlightMode.AUTO_MISSION:
            self.start_item(self.ctx.now_s)
        return ACCEPTED

    def start_at(self, now_s: float, first_seq: int) -> None:
        self.progress = MissionProgress(seq=first_seq)
        self.ctx.mode = FlightMode.AUTO_MISSION
        self.start_item(now_s)

    def restart_if_finished(self) -> None:
        if self.progress.finished:
            self.progress = MissionProgress(seq=0)

    def activate(self, now_s: float, prev: FlightMode) -> None:
        """Entering Mission mode: resume at the current item (from the start once finished)."""
        if prev != FlightMode.AUTO_MISSION or self.progress.finished:
            self.restart_if_finished()
            # DO_JUMP counts survive a pause (PX4 keeps them in the stored items)
            self.progress = MissionProgress(seq=self.progress.seq, jumps_done=self.progress.jumps_done)
            self.start_item(now_s)

    @property
    def climbing(self) -> bool:
        return self.progress.climbing

    @property
    def landing(self) -> bool:
        return self.progress.landing

    # --- executor -----------------------------------------------------------------------------------
    def start_item(self, now_s: float) -> None:
        """Prepare the executor for progress.seq (targets resolved against the current position)."""
        ctx = self.ctx
        mp = self.progress
        mp.arrived_s = None
        mp.landing = False
        mp.climbing = False
        mp.climb_xy = None
        mp.seq, mp.jumps_done, cycling = resolve_jumps(self.items, mp.seq, mp.jumps_done)
        if cycling:
            ctx.event(Severity.CRITICAL, cycling)
        if not (0 <= mp.seq < len(self.items)):
            mp.finished = True
            return
        it = resolve_item(self.items[mp.seq], float(ctx.home[2]))  # relative altitude: the home of now
        pos = ctx.pos
        if it.command == MissionCommand.NAV_TAKEOFF:
            down = it.down_m if math.isfinite(it.down_m) else ctx.home[2] - ctx.params.get("MIS_TAKEOFF_ALT")
            mp.target = np.array([pos[0], pos[1], min(down, pos[2])])
            mp.climbing = True
        elif it.command == MissionCommand.NAV_LAND:
            n = it.north_m if math.isfinite(it.north_m) else pos[0]
            e = it.east_m if math.isfinite(it.east_m) else pos[1]
            mp.target = np.array([n, e, pos[2]])
        elif it.command in (MissionCommand.NAV_WAYPOINT, MissionCommand.NAV_LOITER_TIME):
            mp.target = np.array([it.north_m, it.east_m, it.down_m], dtype=np.float64)
            if ctx.on_ground and ctx.armed:
                mp.climbing = True  # implicit take-off first
        elif it.command == MissionCommand.NAV_DELAY:  # wait param1 s where the last item left the vehicle
            mp.target = mp.target.copy() if mp.target is not None else pos.copy()
        else:
            mp.target = None

    def item_done(self, now_s: float) -> None:
        ctx = self.ctx
        mp = self.progress
        it = self.items[mp.seq]
        ctx.event(Severity.INFO, f"Mission item {mp.seq} reached", reached=mp.seq)
        if it.command == MissionCommand.NAV_LAND:
            mp.landing = False
            mp.finished = True
            ctx.event(Severity.INFO, "Mission finished, landed")
            return
        if it.command == MissionCommand.NAV_RETURN_TO_LAUNCH:
            mp.finished = True
            self._enter_mode(FlightMode.AUTO_RTL, now_s)
            return
        if not it.autocontinue:
            mp.finished = True
            ctx.event(Severity.INFO, "Mission paused (autocontinue off), holding")
            return
        last_target = mp.target
        if mp.seq + 1 >= len(self.items):
            mp.finished = True
            mp.target = last_target
            ctx.event(Severity.INFO, "Mission finished, loitering")
            return
        mp.seq += 1
        self.start_item(now_s)
        if mp.target is None:
            mp.target = last_target
        if mp.finished:  # a DO_JUMP chain ran past the last item
            ctx.event(Severity.INFO, "Mission finished, loitering")

    def do_item(self, it: MissionItem, pos: Vec3) -> None:
        """A camera / gimbal / other DO item, at once."""
        eff = item_effect(it)
        self.payload.extend(eff.actions)
        if eff.gimbal_deg is not None:
            self.gimbal_deg = eff.gimbal_deg
        if eff.trigger_dist_m is not None:
            self.trigger.set(eff.trigger_dist_m, float(pos[0]), float(pos[1]))
        if eff.note:
            self.ctx.event(Severity.INFO, eff.note)

    def pop_payload(self) -> list[PayloadAction]:
        out, self.payload = self.payload, []
        return out

    def on_touchdown(self, now_s: float) -> None:
        """The land detector saw the ground: a LAND item in progress is reached."""
        if self.ctx.mode == FlightMode.AUTO_MISSION and self.progress.landing:
            self.item_done(now_s)

    def _yaw(self, it: MissionItem, pos: Vec3, target: Vec3) -> float | None:
        return mission_yaw(it, pos, target, self.ctx.home, self.ctx.params.get_int("MIS_YAWMODE"))

    def update(self, now_s: float, dt: float, state: EavState, eav: EavParams, depth: int = 0) -> EavCommand:
        ctx = self.ctx
        p = ctx.params
        mp = self.progress
        items = self.items
        pos = np.asarray(state.pos_ned_m, dtype=np.float64)
        # Non-navigation items complete at once (bounded loop: at most one pass over the mission).
        for _ in range(len(items) + 1):
            if mp.finished or not (0 <= mp.seq < len(items)):
                break
            it = items[mp.seq]
            if it.command == MissionCommand.DO_CHANGE_SPEED:
                if it.param2 > 0 and math.isfinite(it.param2):
                    ctx.cruise_override = min(it.param2, p.get("MPC_XY_VEL_MAX"))
                elif it.param2 == -2.0:
                    ctx.cruise_override = None
                self.item_done(now_s)
                continue
            if it.command == MissionCommand.NAV_RETURN_TO_LAUNCH:
                self.item_done(now_s)
                return self._rtl(now_s, dt, state, eav)
            if it.command not in NAV_COMMANDS:  # camera / gimbal / other DO items: at once
                self.do_item(it, pos)
                self.item_done(now_s)
                continue
            break
        if ctx.mode != FlightMode.AUTO_MISSION:
            return self._control(now_s, dt, state, eav)
        if mp.finished:
            if mp.target is None:
                mp.target = pos.copy()
            if items and items[min(mp.seq, len(items) - 1)].command == MissionCommand.NAV_LAND:
                if ctx.on_ground:
                    return idle(ctx)
                return descend(ctx, dt, state, eav, (float(mp.target[0]), float(mp.target[1])))
            return goto(ctx, dt, state, eav, mp.target)
        if not ctx.armed or mp.target is None:
            return idle(ctx)
        it = items[mp.seq]
        if depth > MAX_ITEMS_PER_STEP:
            # Several items completed in this step already: fly toward the current one, go on next step.
            return goto(ctx, dt, state, eav, mp.target)
        target = mp.target
        lim = auto_limits(ctx)
        alt_rad = p.get("NAV_MC_ALT_RAD")
        # Take-off (item or implicit before the first waypoint): vertical climb at the lift-off position.
        if mp.climbing:
            if it.command == MissionCommand.NAV_TAKEOFF:
                climb_down = float(target[2])
            else:
                climb_down = float(min(target[2], ctx.home[2] - p.get("MIS_TAKEOFF_ALT")))
            if mp.climb_xy is None or state.landed:
                mp.climb_xy = (float(pos[0]), float(pos[1]))
            if state.landed or abs(pos[2] - climb_down) >= alt_rad:
                sp = TrajectorySetpoint(pos_ned_m=(mp.climb_xy[0], mp.climb_xy[1], climb_down))
                up_lim = limits(ctx, xy=ctx.cruise(), up=p.get("MPC_TKO_SPEED"), auto=True)
                return run_position(ctx, dt, state, sp, up_lim, eav, None, 0.0)
            mp.climbing = False
            if it.command == MissionCommand.NAV_TAKEOFF:
                mp.target = np.array([mp.climb_xy[0], mp.climb_xy[1], climb_down])
                self.item_done(now_s)
                return self.update(now_s, dt, state, eav, depth + 1)
        if it.command == MissionCommand.NAV_LAND:
            dist = math.hypot(target[0] - pos[0], target[1] - pos[1])
            if not mp.landing and dist < min(p.get("NAV_ACC_RAD"), 1.0):
                mp.landing = True
            if mp.landing:
                if state.landed:
                    return idle(ctx)
                return descend(ctx, dt, state, eav, (float(target[0]), float(target[1])))
            sp = position_setpoint(ctx, target)
            return run_position(ctx, dt, state, sp, lim, eav, self._yaw(it, pos, target), yaw_rate_auto(ctx))
        # WAYPOINT / LOITER_TIME
        acc_rad = (
            it.param2 if it.command == MissionCommand.NAV_WAYPOINT and it.param2 > 0 else p.get("NAV_ACC_RAD")
        )
        dist = math.hypot(target[0] - pos[0], target[1] - pos[1])
        if mp.arrived_s is None and dist <= acc_rad and abs(target[2] - pos[2]) <= alt_rad:
            mp.arrived_s = now_s
        if mp.arrived_s is not None:
            hold_s = max(0.0, it.param1) if math.isfinite(it.param1) else 0.0
            if now_s - mp.arrived_s >= hold_s:
                self.item_done(now_s)
                if ctx.mode != FlightMode.AUTO_MISSION:
                    return self._control(now_s, dt, state, eav)
                if not mp.finished:
                    return self.update(now_s, dt, state, eav, depth + 1)
        tgt = mp.target if mp.target is not None else target
        sp = position_setpoint(ctx, tgt)
        return run_position(ctx, dt, state, sp, lim, eav, self._yaw(it, pos, tgt), yaw_rate_auto(ctx))
