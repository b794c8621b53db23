"""Commander (PX4's commander module, reduced): arming and its pre-arm checks, mode transitions and their
requirements, commands (takeoff, land, RTL, reposition, orbit, speed, mission start, home, geofence and rally
plans), auto-disarm, and carrying out the actions the failsafe evaluation asks for.

Refusal mapping as PX4 Commander: arming refusals DENIED, mode-switch refusals TEMPORARILY_REJECTED.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from viva_sitl.autopilot.context import FlightContext
from viva_sitl.autopilot.failsafe import (
    Action,
    ApplyFailsafe,
    Cause,
    FailsafeAction,
    FailsafeFlags,
    FailsafeInputs,
    HoldAt,
    Notify,
    SwitchMode,
    evaluate,
    from_gf_act_param,
)
from viva_sitl.autopilot.failsafe import (
    quiet as failsafe_quiet,
)
from viva_sitl.autopilot.geofence import Geofence, RallyPoint
from viva_sitl.autopilot.land_detector import LandDetector
from viva_sitl.autopilot.orbit import apply_command
from viva_sitl.autopilot.setpoints import MAX_ABS_POS_M, finite
from viva_sitl.autopilot.tasks import MANUAL_MODES, FlightTasks
from viva_sitl.autopilot.types import ACCEPTED, CommandResult, FlightMode, Outcome, Severity

MAX_TAKEOFF_ALT_M = 1000.0
# the failsafe actions that switch mode (the mode, the word in the STATUSTEXT), and those that disarm
_FAILSAFE_MODES = {FailsafeAction.HOLD: (FlightMode.AUTO_LOITER, "Hold"),
                   FailsafeAction.RTL: (FlightMode.AUTO_RTL, "Return"),
                   FailsafeAction.LAND: (FlightMode.AUTO_LAND, "Land")}  # fmt: skip
_DISARM_TEXT = {FailsafeAction.TERMINATE: "termination", FailsafeAction.DISARM: "lockdown"}
# PX4's mode_req_prevent_arming (of the modes this vehicle has): arming is refused while one of them is selected.
# Selecting them while disarmed is allowed (PX4 allows every mode change while disarmed); on disarming, the mode
# returns to the last one the user selected that allows arming (PX4's UserModeIntention::onDisarm).
PREVENTS_ARMING = frozenset({FlightMode.AUTO_LAND, FlightMode.AUTO_RTL})
GEOFENCE_CHECK_S = 0.1  # the footage and geofence tests run at 10 Hz (the footage test may be costly)
# the modes that need a global (or local horizontal) position estimate: refused while it is invalid (a lost GPS)
POSITION_MODES = frozenset({FlightMode.AUTO_LOITER, FlightMode.AUTO_MISSION, FlightMode.AUTO_RTL,
                            FlightMode.AUTO_TAKEOFF, FlightMode.POSCTL, FlightMode.ORBIT})  # fmt: skip
MODE_NAMES = {FlightMode.AUTO_LOITER: "Hold", FlightMode.AUTO_MISSION: "Mission", FlightMode.AUTO_RTL: "Return",
              FlightMode.AUTO_TAKEOFF: "Takeoff", FlightMode.POSCTL: "Position", FlightMode.ORBIT: "Orbit"}  # fmt: skip


def no_position(what: str) -> Outcome:
    """PX4 refuses a mode that needs a position estimate while it is invalid (TEMPORARILY_REJECTED)."""
    return rejected(f"{what} denied: no global position (GPS lost)")


def denied(reason: str) -> Outcome:
    return Outcome(CommandResult.DENIED, reason)


def rejected(reason: str) -> Outcome:
    return Outcome(CommandResult.TEMPORARILY_REJECTED, reason)


class Commander:
    def __init__(self, ctx: FlightContext, tasks: FlightTasks, land: LandDetector) -> None:
        self.ctx = ctx
        self.tasks = tasks
        self.land_detector = land
        self.failsafe_flags = FailsafeFlags()
        self.gcs_seen = False
        self.gcs_last_s = -math.inf
        self._gf_next_check_s = -math.inf
        self._fence_next_check_s = -math.inf
        self.mode_after_disarm = FlightMode.AUTO_LOITER  # the last user-selected mode that allows arming

    def _user_selected(self, mode: FlightMode) -> None:
        if mode not in PREVENTS_ARMING and mode != FlightMode.AUTO_TAKEOFF:
            self.mode_after_disarm = mode

    # --- arming --------------------------------------------------------------------------------
    def prearm_check(self, now_s: float) -> Outcome:
        """ACCEPTED when arming would be allowed now (SYS_STATUS pre-arm bit), else the refusal."""
        ctx, tasks = self.ctx, self.tasks
        if ctx.state is None:
            return rejected("Arming denied: system not ready")
        if not ctx.on_ground:
            return denied("Arming denied: vehicle not landed")
        pos = ctx.pos
        if not ctx.footage_ok(float(pos[0]), float(pos[1])):
            return denied("Arming denied: outside footage (geofence)")
        if from_gf_act_param(ctx.params.get_int("GF_ACTION")) is not FailsafeAction.NONE and not ctx.fence_ok(
            float(pos[0]), float(pos[1])
        ):
            return denied("Arming denied: vehicle outside geofence")
        if ctx.battery_remaining <= ctx.params.get("BAT_CRIT_THR"):
            return denied("Arming denied: battery too low")
        if ctx.sensor_faults:
            return denied(f"Arming denied: {ctx.sensor_faults[0]}")
        if ctx.calibrating:
            return rejected("Arming denied: calibration in progress")
        mode = ctx.mode
        if mode in POSITION_MODES and not ctx.position_valid:
            return denied(f"Arming denied: {MODE_NAMES[mode]} mode requires a global position")
        if mode == FlightMode.AUTO_MISSION and not tasks.mission.valid:
            return denied("Arming denied: no valid mission")
        if mode == FlightMode.OFFBOARD and not tasks.offboard.fresh(now_s):
            return denied("Arming denied: offboard setpoints not streaming")
        if mode == FlightMode.AUTO_READY:
            return denied("Arming denied: mode not armable")
        if mode in PREVENTS_ARMING:
            return denied(
                f"Arming denied: {'Land' if mode == FlightMode.AUTO_LAND else 'Return'} mode not armable"
            )
        if mode in MANUAL_MODES:
            manual = tasks.manual.input
            if not tasks.manual.fresh(now_s) or manual is None:
                return denied("Arming denied: manual control lost")
            limit = 0.2 if mode in (FlightMode.MANUAL, FlightMode.STABILIZED) else 0.6
            if manual.z > limit:
                return denied(
                    "Arming denied: throttle above center" if limit > 0.5 else "Arming denied: throttle high"
                )
        return ACCEPTED

    def arm(self, now_s: float, force: bool = False) -> Outcome:
        ctx = self.ctx
        ctx.now_s = now_s
        if ctx.armed:
            return ACCEPTED
        if not force:
            check = self.prearm_check(now_s)
            if not check.ok:
                return check
        ctx.armed = True
        self.land_detector.on_armed(now_s)
        ctx.home = ctx.pos.copy()
        ctx.home_set = True
        ctx.ctrl.reset()
        ctx.yaw_sp = ctx.yaw
        self.failsafe_flags = FailsafeFlags(
            dll_lost=self.failsafe_flags.dll_lost,
            gf_outside=self.failsafe_flags.gf_outside,
            last_inside_ned_m=self.failsafe_flags.last_inside_ned_m,
            fence_breached=self.failsafe_flags.fence_breached,
        )  # a new flight: manual-control loss may trigger again
        ctx.event(Severity.INFO, "Armed by external command")
        if ctx.mode == FlightMode.AUTO_MISSION:
            self.tasks.mission.restart_if_finished()
            self.tasks.mission.start_item(now_s)
        else:
            self.tasks.enter(ctx.mode, now_s)
        return ACCEPTED

    def do_disarm(self, text: str, severity: Severity = Severity.INFO) -> None:
        self.ctx.armed = False
        self.ctx.ctrl.reset()
        self.tasks.offboard.rate_att = None
        self.ctx.event(severity, text)
        if self.ctx.mode in PREVENTS_ARMING:
            self.ctx.mode = self.mode_after_disarm  # activated when armed again

    def disarm(self, now_s: float, force: bool = False) -> Outcome:
        self.ctx.now_s = now_s
        if not self.ctx.armed:
            return ACCEPTED
        if not force and not self.ctx.on_ground:
            return denied("Disarming denied: not landed")
        self.do_disarm("Disarmed by external command")
        return ACCEPTED

    def kill(self, now_s: float) -> Outcome:
        self.ctx.now_s = now_s
        if self.ctx.armed:
            self.do_disarm("Kill switch engaged: motors stopped", Severity.CRITICAL)
        return ACCEPTED

    def auto_disarm(self, now_s: float) -> None:
        """COM_DISARM_LAND after the land detector declared the landing, COM_DISARM_PRFLT when armed but never took
        off (< 0: never)."""
        ctx, ld = self.ctx, self.land_detector
        if not (ctx.armed and ld.landed):
            return
        limit = ctx.params.get("COM_DISARM_LAND") if ld.has_flown else ctx.params.get("COM_DISARM_PRFLT")
        if limit < 0:
            return
        if now_s - ld.ground_since_s >= limit:
            why = "landed" if ld.has_flown else "no takeoff"
            self.do_disarm(f"Disarmed by auto disarm ({why})")

    # --- commands ------------------------------------------------------------------------------
    def takeoff(self, now_s: float, altitude_m: float | None = None) -> Outcome:
        ctx = self.ctx
        ctx.now_s = now_s
        alt = (
            ctx.params.get("MIS_TAKEOFF_ALT") if altitude_m is None or math.isnan(altitude_m) else altitude_m
        )
        if not (math.isfinite(alt) and 0.0 < alt <= MAX_TAKEOFF_ALT_M):
            return denied(f"Takeoff denied: altitude {alt} m out of range")
        if not ctx.armed:
            return denied("Takeoff denied: vehicle not armed")
        if not ctx.position_valid:
            return no_position("Takeoff")
        self.tasks.takeoff.start(alt)
        return ACCEPTED

    def land(self, now_s: float) -> Outcome:
        self.ctx.now_s = now_s
        self.tasks.enter(FlightMode.AUTO_LAND, now_s)
        return ACCEPTED

    def return_to_launch(self, now_s: float) -> Outcome:
        self.ctx.now_s = now_s
        if not self.ctx.position_valid:
            return no_position("Return")
        self.tasks.enter(FlightMode.AUTO_RTL, now_s)
        return ACCEPTED

    def set_mode(self, now_s: float, mode: FlightMode) -> Outcome:
        ctx, tasks = self.ctx, self.tasks
        ctx.now_s = now_s
        if mode == ctx.mode:
            return ACCEPTED
        if mode == FlightMode.AUTO_READY:
            return rejected("Switching to Ready is not possible")
        if mode == FlightMode.OFFBOARD and not tasks.offboard.fresh(now_s):
            return rejected("Switching to Offboard denied: no setpoint stream (> 2 Hz)")
        if mode == FlightMode.AUTO_MISSION and not tasks.mission.valid:
            return rejected("Switching to Mission denied: no valid mission")
        if mode in MANUAL_MODES and not tasks.manual.fresh(now_s):
            return rejected(f"Switching to {mode.name} denied: no manual control (RC)")
        if mode == FlightMode.ORBIT and (not ctx.armed or ctx.on_ground):
            return rejected("Switching to Orbit denied: not flying")
        if mode in POSITION_MODES and not ctx.position_valid:
            return no_position(f"Switching to {MODE_NAMES[mode]}")
        self._user_selected(mode)
        if mode == FlightMode.AUTO_TAKEOFF:
            if ctx.armed:
                tasks.takeoff.start(ctx.params.get("MIS_TAKEOFF_ALT"))
            else:
                ctx.mode = FlightMode.AUTO_TAKEOFF
                tasks.takeoff.target = None
            return ACCEPTED
        tasks.enter(mode, now_s)
        return ACCEPTED

    def reposition(self, now_s: float, north_m: float, east_m: float, down_m: float, yaw_rad: float | None,
                   speed_m_s: float | None = None, change_mode: bool = True) -> Outcome:  # fmt: skip
        """DO_REPOSITION. Without the change-mode flag, outside Hold, the target is kept for the next Hold (PX4)."""
        ctx = self.ctx
        ctx.now_s = now_s
        if not ctx.armed:
            return denied("Reposition denied: vehicle not armed")
        if ctx.on_ground:
            return rejected("Reposition denied: landed, take off first")
        if not ctx.position_valid:
            return no_position("Reposition")
        pos = ctx.pos
        target = np.array(
            [
                north_m if math.isfinite(north_m) else pos[0],
                east_m if math.isfinite(east_m) else pos[1],
                down_m if math.isfinite(down_m) else pos[2],
            ]
        )
        if np.any(np.abs(target) > MAX_ABS_POS_M):
            return denied("Reposition denied: target out of range")
        if yaw_rad is not None and not math.isfinite(yaw_rad):
            yaw_rad = None
        if speed_m_s is not None and not (math.isfinite(speed_m_s) and speed_m_s > 0.0):
            speed_m_s = None
        if not ctx.footage_ok(float(target[0]), float(target[1])):
            return denied("Reposition denied: target outside footage")
        hold = self.tasks.hold
        if not change_mode and ctx.mode != FlightMode.AUTO_LOITER:
            hold.pending = (target, yaw_rad, speed_m_s)
            return ACCEPTED
        hold.pending = None
        self._user_selected(FlightMode.AUTO_LOITER)
        self.tasks.enter(FlightMode.AUTO_LOITER, now_s)
        self.tasks.hold.hold_at(target, yaw_rad)
        if speed_m_s is not None:
            ctx.speed_override = min(speed_m_s, ctx.params.get("MPC_XY_VEL_MAX"))
        return ACCEPTED

    def orbit(self, now_s: float, radius_m: float, velocity_m_s: float, yaw_behaviour: float,
              center_ne_m: tuple[float, float] | None, center_down_m: float | None) -> Outcome:  # fmt: skip
        """MAV_CMD_DO_ORBIT: NaN radius/velocity/yaw behaviour keep the current orbit's (or PX4's defaults)."""
        ctx, task = self.ctx, self.tasks.orbit
        ctx.now_s = now_s
        if not ctx.armed:
            return denied("Orbit denied: vehicle not armed")
        if ctx.on_ground:
            return rejected("Orbit denied: landed, take off first")
        if not ctx.position_valid:
            return no_position("Orbit")
        if center_ne_m is not None and not finite(*center_ne_m):
            center_ne_m = None
        pos = ctx.pos
        prev = task.orbit if ctx.mode == FlightMode.ORBIT else None
        if prev is None and center_ne_m is None:
            center_ne_m = (float(pos[0]), float(pos[1]))
        try:
            orbit = apply_command(prev, pos, ctx.yaw, radius_m, velocity_m_s, yaw_behaviour, center_ne_m,
                                  center_down_m, ctx.params.get("MC_ORBIT_RAD_MAX"))  # fmt: skip
        except ValueError as e:
            return denied(str(e))
        if ctx.mode != FlightMode.ORBIT:
            self._user_selected(FlightMode.ORBIT)
            self.tasks.enter(FlightMode.ORBIT, now_s)
        task.set(orbit)
        return ACCEPTED

    def set_geofence(self, fence: Geofence) -> Outcome:
        """MISSION_TYPE_FENCE upload (geometry already validated); an empty Geofence clears it. The stored mission is
        checked again (PX4: one with a waypoint outside the new fence is no longer startable)."""
        self.ctx.geofence = fence
        self.failsafe_flags = replace(self.failsafe_flags, fence_breached=False)
        self._fence_next_check_s = -math.inf
        self.tasks.mission.revalidate()
        return ACCEPTED

    def set_rally_points(self, points: Sequence[RallyPoint]) -> Outcome:
        self.ctx.rally = tuple(points)
        return ACCEPTED

    def change_speed(self, now_s: float, speed_m_s: float) -> Outcome:
        """DO_CHANGE_SPEED: > 0 sets the auto cruise speed (clamped to MPC_XY_VEL_MAX); -1 no change; -2 default."""
        ctx = self.ctx
        ctx.now_s = now_s
        if not math.isfinite(speed_m_s):
            return denied("Change speed denied: speed not finite")
        if speed_m_s == -2.0:
            ctx.cruise_override = None
            return ACCEPTED
        if speed_m_s < 0.0:
            return ACCEPTED
        if speed_m_s == 0.0:
            return denied("Change speed denied: speed must be > 0")
        ctx.cruise_override = min(speed_m_s, ctx.params.get("MPC_XY_VEL_MAX"))
        if ctx.mode == FlightMode.AUTO_LOITER:
            ctx.speed_override = ctx.cruise_override
        return ACCEPTED

    def mission_start(self, now_s: float, first_seq: int = 0) -> Outcome:
        self.ctx.now_s = now_s
        mission = self.tasks.mission
        if not mission.valid:
            return denied("Mission start denied: no valid mission")
        if not self.ctx.position_valid:
            return no_position("Mission start")
        if not (0 <= first_seq < len(mission.items)):
            return denied(f"Mission start denied: item {first_seq} does not exist")
        self._user_selected(FlightMode.AUTO_MISSION)
        mission.start_at(now_s, first_seq)
        return ACCEPTED

    def set_home(self, now_s: float, home_ned_m: tuple[float, float, float]) -> Outcome:
        if not finite(*home_ned_m) or any(abs(v) > MAX_ABS_POS_M for v in home_ned_m):
            return denied("Set home denied: position not finite")
        self.ctx.home = np.array(home_ned_m, dtype=np.float64)
        self.ctx.home_set = True
        return ACCEPTED

    def gcs_heartbeat(self, now_s: float) -> None:
        self.gcs_seen = True
        self.gcs_last_s = now_s
        if self.failsafe_flags.dll_lost:
            self.failsafe_flags = FailsafeFlags(
                dll_lost=False,
                rc_lost_handled=self.failsafe_flags.rc_lost_handled,
                gf_outside=self.failsafe_flags.gf_outside,
                last_inside_ned_m=self.failsafe_flags.last_inside_ned_m,
                fence_breached=self.failsafe_flags.fence_breached,
            )
            self.ctx.event(Severity.INFO, "Data link regained")

    # --- failsafes --------------------------------------------------------------------------------
    def check_failsafes(self, now_s: float) -> None:
        ctx, tasks = self.ctx, self.tasks
        inside: bool | None = None
        if ctx.footage_action() is not FailsafeAction.NONE and now_s >= self._gf_next_check_s:
            self._gf_next_check_s = now_s + GEOFENCE_CHECK_S
            pos = ctx.pos
            inside = ctx.is_inside(float(pos[0]), float(pos[1]))
        fence: Geofence | None = None
        if now_s >= self._fence_next_check_s:
            self._fence_next_check_s = now_s + GEOFENCE_CHECK_S
            fence = ctx.geofence
        if (
            inside is None
            and fence is None
            and failsafe_quiet(
                now_s,
                ctx.mode,
                tasks.offboard.last_s,
                self.gcs_seen,
                self.gcs_last_s,
                self.failsafe_flags,
                ctx.params,
            )  # fmt: skip
        ):
            return  # nothing evaluate() could act on this step
        pos = ctx.pos
        home = ctx.home
        inp = FailsafeInputs(
            now_s=now_s,
            mode=ctx.mode,
            armed=ctx.armed,
            in_air=ctx.armed and not ctx.on_ground,
            offboard_last_s=tasks.offboard.last_s,
            manual_fresh=tasks.manual.fresh(now_s),
            gcs_seen=self.gcs_seen,
            gcs_last_s=self.gcs_last_s,
            inside=inside,
            pos_ned_m=(float(pos[0]), float(pos[1]), float(pos[2])),
            geofence=fence,
            home_ned_m=(float(home[0]), float(home[1]), float(home[2])),
        )
        self.failsafe_flags, actions = evaluate(inp, self.failsafe_flags, ctx.params)
        for action in actions:
            self.apply(action, now_s)

    def apply(self, action: Action, now_s: float) -> None:
        ctx = self.ctx
        if isinstance(action, Notify):
            ctx.event(action.severity, action.text)
        elif isinstance(action, SwitchMode):
            self.tasks.enter(action.mode, now_s)
            if action.text:
                ctx.event(Severity.WARNING, action.text)
        elif isinstance(action, HoldAt):
            self.tasks.enter(FlightMode.AUTO_LOITER, now_s)
            if action.pos_ned_m is not None:
                self.tasks.hold.hold_at(np.array(action.pos_ned_m, dtype=np.float64))
        elif isinstance(action, ApplyFailsafe):
            self.failsafe(action.action, action.cause)

    def failsafe(self, action: FailsafeAction, cause: Cause) -> None:
        """Take a failsafe action: Hold, RTL and Land switch mode; Terminate and Disarm (PX4's "Lockdown") disarm;
        the others (none, a warning, a manual fallback) do nothing here."""
        if action in _DISARM_TEXT:
            self.do_disarm(f"{cause.kind}: {_DISARM_TEXT[action]}", Severity.EMERGENCY)
            return
        if action not in _FAILSAFE_MODES:
            return
        mode, what = _FAILSAFE_MODES[action]
        self.tasks.enter(mode, self.ctx.now_s)
        self.ctx.event(Severity.WARNING, f"Failsafe activated ({cause.reason}): switching to {what}")
