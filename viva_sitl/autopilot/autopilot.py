"""The virtual PX4: modes, controllers and failsafes on top of the EAV. Pure logic: no sockets, no clock.

Layout, along PX4's own seams (this class is the facade; each part is a module a newcomer can read alone):
  context.FlightContext       the shared state (armed, mode, home, latest state, events, controller, caches)
  commander.Commander         arming + pre-arm checks, mode transitions, commands, auto-disarm, failsafe actions
  failsafe.evaluate           pure failsafe evaluation: inputs + latched flags -> actions
  land_detector.LandDetector  ground contact, landed state, time on the ground
  tasks.*                     one flight task per mode: hold, takeoff, land, rtl, mission, offboard, orbit, manual
  geofence / orbit / payload / mission   pure logic: fence geometry + breach + RTL destination, orbit geometry,
                              camera and gimbal items + distance trigger, mission validation + DO_JUMP + altitudes

CONTRACT (used by viva_sitl/mavlink and viva_sitl/app.py): keep these signatures; add, don't change.
Every method takes `now_s` (simulation time, s) where time matters; the caller owns the clock.

Behaviour choices where PX4's is unclear or unsuitable (also in the README):
- Boot mode is AUTO_LOITER (Hold), as PX4 SITL without RC.
- Command refusals come back only as Outcome(reason); the MAVLink layer sends the reason as STATUSTEXT. Events are
  for things that happen by themselves (failsafes, take-off/landing detection, auto-disarm, mission progress).
- Arming is refused in Land and Return (PX4's mode_req_prevent_arming); selecting them while disarmed is accepted
  (PX4 allows every mode change while disarmed), and on disarming the mode returns to the last user-selected mode
  that allows arming (Hold at boot), so a vehicle that landed can be re-armed. Refusals are DENIED, mode-switch
  refusals TEMPORARILY_REJECTED (PX4 Commander's mapping).
- Takeoff while disarmed: DENIED ("Takeoff denied: vehicle not armed"). Land while on the ground: ACCEPTED (mode
  becomes AUTO_LAND; an armed vehicle then auto-disarms after COM_DISARM_LAND).
- OFFBOARD is accepted when a valid setpoint arrived within the last 0.5 s (i.e. a > 2 Hz stream). PX4 itself only
  checks that the stream is not lost; requiring a full second would refuse MAVSDK's own start() sequence
  (one set_*(), then start(), while MAVSDK's 20 Hz stream begins).
- Offboard loss (COM_OF_LOSS_T): COM_OBL_RC_ACT; the RC-based choices 0..2 (Position/Altitude/Manual) fall back to
  Hold when no MANUAL_CONTROL is arriving, as PX4 v1.14's failsafe framework (default 0 -> Hold).
- The footage edge is a fence the user chooses (SIM_FTG_FENCE, GF_ACTION's codes): 0 off, 1 warning (default: a
  STATUSTEXT once per exit; unchanged PX4 code flies beyond the footage), 2 Hold (holds at the last position that was
  still inside the footage, so the camera sees footage again), 3 Return, 4 Terminate, 5 Land. From 2 (Hold) up,
  arming outside the footage, repositioning to or uploading a mission with a waypoint outside it are refused too.
- The uploaded geofence (MISSION_TYPE_FENCE) and GF_MAX_HOR_DIST / GF_MAX_VER_DIST follow GF_ACTION (default Hold),
  as PX4: arming outside it is refused (GF_ACTION != 0), a mission outside it is refused, a new fence invalidates a
  stored mission outside it. RTL returns to the closest of home and the rally points (RTL_TYPE 0).
- DO_REPOSITION needs an armed vehicle in the air (landed: TEMPORARILY_REJECTED). Without the change-mode flag
  (MAV_DO_REPOSITION_FLAGS_CHANGE_MODE) it moves the Hold target only when already in Hold; otherwise the target is
  kept and flown the next time Hold is entered (PX4's reposition triplet).
- Orbit (DO_ORBIT or the mode) needs an armed vehicle in the air. Mission DO items never refuse a mission: DO_JUMP
  and camera/gimbal items run, others are logged and skipped; relative altitudes resolve when the item starts.
- Mission TAKEOFF items climb vertically at the current position (the item's horizontal position is ignored); a
  mission started on the ground without a TAKEOFF item first climbs to MIS_TAKEOFF_ALT (or the item's altitude).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from viva_sitl.autopilot.commander import MODE_NAMES, POSITION_MODES, Commander
from viva_sitl.autopilot.context import FlightContext, InsideFn
from viva_sitl.autopilot.failsafe import Cause, FailsafeAction, battery_level, battery_warning
from viva_sitl.autopilot.failures import (
    GPS_NOAID_TIMEOUT_S,
    SENSOR_NAMES,
    Failures,
    FailureType,
    FailureUnit,
    describe,
    motor_failure_command,
    parse,
)
from viva_sitl.autopilot.geofence import Geofence, RallyPoint
from viva_sitl.autopilot.gimbal import GimbalControl, GimbalMode, point_at
from viva_sitl.autopilot.land_detector import LandDetector, Transition
from viva_sitl.autopilot.orbit import Orbit
from viva_sitl.autopilot.params import ParamStore
from viva_sitl.autopilot.setpoints import MAX_ABS_POS_M
from viva_sitl.autopilot.tasks import FlightTasks, OffboardKind, RtlPhase
from viva_sitl.autopilot.tasks.follow import FollowTarget, TrackLookup
from viva_sitl.autopilot.types import (
    ACCEPTED,
    AttitudeTarget,
    CommandResult,
    Event,
    FlightMode,
    LandedState,
    ManualInput,
    MissionItem,
    Outcome,
    PayloadAction,
    PositionTarget,
    Severity,
)
from viva_sitl.dynamics import EavCommand, EavParams, EavState


class Autopilot:
    def __init__(
        self,
        params: ParamStore,
        eav: EavParams,
        inside: InsideFn | None = None,
        gimbal_neutral_deg: tuple[float, float] | None = None,
    ) -> None:
        self.params = params
        self.eav = eav  # the airframe as configured; eav_params() applies the SIM_* parameters on top
        self.inside = inside
        self.ctx = FlightContext(params, eav, inside)
        self.failures = Failures()  # injected failures (inject_failure): read where each one acts
        self.last_command: EavCommand | None = (
            None  # what update() returned last (the run log's attitude setpoint)
        )
        self.commands = 0  # flight commands received (arm ... mission_start): a pilot's actions, counted
        self.ctx.sync_sim_params_from(eav)
        self.tasks = FlightTasks(self.ctx)
        self.land_detector = LandDetector(params)
        self.commander = Commander(self.ctx, self.tasks, self.land_detector)
        self._bat_level = 0  # 0 ok, 1 low, 2 critical (events once per crossing)
        # a gimbal camera mount (the Vehicle passes its configured (pitch, yaw)): None = the camera is fixed
        self.gimbal: GimbalControl | None = (
            GimbalControl(gimbal_neutral_deg) if gimbal_neutral_deg is not None else None
        )
        self._gimbal_mission_seen: tuple[float, float] | None = None
        self._gps_lost_s: float | None = None  # when an injected GPS failure began (None: GPS fine)
        self._nav_fallback_from: FlightMode | None = None  # the mode a lost position made the vehicle leave

    def eav_params(self) -> EavParams:
        """The EAV parameters with SIM_* applied: the caller swaps it into the physics when it changes
        (viva_sitl.vehicle.Vehicle does, before every step). Cached: the same object while unchanged."""
        return self.ctx.eav_params()

    # --- read by telemetry -------------------------------------------------------------
    @property
    def armed(self) -> bool:
        return self.ctx.armed

    @property
    def mode(self) -> FlightMode:
        return self.ctx.mode

    @property
    def landed_state(self) -> LandedState:
        return self.land_detector.landed_state

    @property
    def home_ned_m(self) -> tuple[float, float, float]:
        h = self.ctx.home
        return float(h[0]), float(h[1]), float(h[2])

    @property
    def mission_current_seq(self) -> int:
        return self.tasks.mission.progress.seq

    @property
    def mission_items(self) -> Sequence[MissionItem]:
        return self.tasks.mission.items

    @property
    def mission_finished(self) -> bool:
        return self.tasks.mission.progress.finished

    @property
    def battery_remaining(self) -> float:  # 0..1
        return self.ctx.battery_remaining

    @property
    def battery_voltage_v(self) -> float:
        return self.ctx.battery.voltage_v(self.ctx.battery_cfg())

    @property
    def battery_current_a(self) -> float:
        return self.ctx.battery.current_a

    # --- injected failures, read by telemetry and the renderer (autopilot/failures.py) ---------
    @property
    def failed_health_bits(self) -> int:
        """SYS_STATUS sensor bits an injected failure makes unhealthy (gyro 1, accel 2, mag 4, baro 8, GPS 32,
        motor outputs 0x8000, RC 0x10000)."""
        return self.failures.health_mask()

    @property
    def gps_fix(self) -> bool:
        """The GPS receiver delivers a fix (False while an injected GPS OFF is on: GPS_RAW_INT fix 0; a stuck or
        wrong GPS still reports its fix, see sensor_fault)."""
        return not self.failures.is_active(FailureUnit.SENSOR_GPS, FailureType.OFF)

    def sensor_fault(self, unit: FailureUnit) -> FailureType | None:
        """The injected failure type of a unit now (OFF, STUCK, WRONG, ...), None while it works: what telemetry
        reads to freeze (STUCK), offset (GPS WRONG) or drop (OFF) that sensor's raw output."""
        return self.failures.active.get(unit)

    @property
    def global_position_valid(self) -> bool:
        """The global position estimate is valid (False once a lost GPS is past EKF2's dead-reckoning time):
        GLOBAL_POSITION_INT stops while False."""
        return self.ctx.position_valid

    @property
    def camera_fault(self) -> FailureType | None:
        """An injected camera failure (viva-sitl's FailureUnit.SENSOR_CAMERA): OFF no frames, STUCK frozen, WRONG
        black; None: live frames."""
        return self.failures.active.get(FailureUnit.SENSOR_CAMERA)

    def pop_events(self) -> list[Event]:  # STATUSTEXT / MISSION_ITEM_REACHED since the last call
        ev, self.ctx.events = self.ctx.events, []
        return ev

    # --- commands (Commander) ----------------------------------------------------------
    @property
    def calibrating(self) -> bool:
        """True while a sensor calibration runs: arming is refused (TEMPORARILY_REJECTED), as PX4 does."""
        return self.ctx.calibrating

    @calibrating.setter
    def calibrating(self, on: bool) -> None:
        self.ctx.calibrating = on

    def prearm_check(self, now_s: float) -> Outcome:
        """ACCEPTED when arming would be allowed now (SYS_STATUS pre-arm bit), else the refusal."""
        return self.commander.prearm_check(now_s)

    def arm(self, now_s: float, force: bool = False) -> Outcome:
        self.commands += 1
        return self.commander.arm(now_s, force)

    def disarm(self, now_s: float, force: bool = False) -> Outcome:
        self.commands += 1
        return self.commander.disarm(now_s, force)

    def kill(self, now_s: float) -> Outcome:
        self.commands += 1
        return self.commander.kill(now_s)

    def takeoff(self, now_s: float, altitude_m: float | None = None) -> Outcome:  # None -> MIS_TAKEOFF_ALT
        self.commands += 1
        return self.commander.takeoff(now_s, altitude_m)

    def land(self, now_s: float) -> Outcome:
        self.commands += 1
        return self.commander.land(now_s)

    def return_to_launch(self, now_s: float) -> Outcome:
        self.commands += 1
        return self.commander.return_to_launch(now_s)

    def set_mode(self, now_s: float, mode: FlightMode) -> Outcome:
        self.commands += 1
        return self.commander.set_mode(now_s, mode)

    def reposition(self, now_s: float, north_m: float, east_m: float, down_m: float, yaw_rad: float | None,
                   speed_m_s: float | None = None, change_mode: bool = True) -> Outcome:  # fmt: skip
        self.commands += 1
        return self.commander.reposition(now_s, north_m, east_m, down_m, yaw_rad, speed_m_s, change_mode)

    def orbit(self, now_s: float, radius_m: float, velocity_m_s: float, yaw_behaviour: float,
              center_ne_m: tuple[float, float] | None, center_down_m: float | None) -> Outcome:  # fmt: skip
        """MAV_CMD_DO_ORBIT: NaN radius/velocity/yaw behaviour keep the current orbit's (or PX4's defaults)."""
        self.commands += 1
        return self.commander.orbit(now_s, radius_m, velocity_m_s, yaw_behaviour, center_ne_m, center_down_m)

    def change_speed(self, now_s: float, speed_m_s: float) -> Outcome:
        """DO_CHANGE_SPEED: > 0 sets the auto cruise speed (clamped to MPC_XY_VEL_MAX); -1 no change; -2 default."""
        self.commands += 1
        return self.commander.change_speed(now_s, speed_m_s)

    def mission_start(self, now_s: float, first_seq: int = 0) -> Outcome:
        self.commands += 1
        return self.commander.mission_start(now_s, first_seq)

    def set_home(self, now_s: float, home_ned_m: tuple[float, float, float]) -> Outcome:
        """DO_SET_HOME (optional in the contract)."""
        return self.commander.set_home(now_s, home_ned_m)

    # --- the mission plan (the mission task) -------------------------------------------
    def set_mission(self, items: Sequence[MissionItem]) -> Outcome:
        return self.tasks.mission.set_items(items)

    def clear_mission(self) -> Outcome:
        return self.tasks.mission.clear()

    def set_mission_current(self, seq: int) -> Outcome:
        return self.tasks.mission.set_current(seq)

    # --- geofence and rally plans (Commander), orbit and payload state (their tasks) ----
    @property
    def geofence(self) -> Geofence:
        return self.ctx.geofence

    @property
    def rally_points(self) -> tuple[RallyPoint, ...]:
        return self.ctx.rally

    def set_geofence(self, fence: Geofence) -> Outcome:
        """MISSION_TYPE_FENCE upload (already validated geometry); an empty Geofence clears it."""
        return self.commander.set_geofence(fence)

    def set_rally_points(self, points: Sequence[RallyPoint]) -> Outcome:
        return self.commander.set_rally_points(points)

    @property
    def orbit_status(self) -> Orbit | None:
        """The orbit flown now (ORBIT_EXECUTION_STATUS), None outside Orbit mode."""
        return self.tasks.orbit.orbit if self.ctx.mode == FlightMode.ORBIT else None

    @property
    def orbit_approaching(self) -> bool:
        """In Orbit mode, still flying to the circle."""
        return self.tasks.orbit.approaching

    @property
    def gimbal_pitch_yaw_deg(self) -> tuple[float, float] | None:
        """The gimbal's (pitch, yaw) in degrees now (pitch 0 level, -90 down; yaw relative to the nose), None while
        it rests at its configured mount. Without a fitted gimbal: the last mission gimbal item's (DO_MOUNT_CONTROL /
        DO_GIMBAL_MANAGER_PITCHYAW), None before any. With one (`gimbal`, see autopilot/gimbal.py) the latest of
        the mission's items and the gimbal manager's commands wins. Vehicle.render applies it to a `gimbal` mount."""
        mission_deg = self.tasks.mission.gimbal_deg
        g = self.gimbal
        if g is None:
            return mission_deg
        if mission_deg is not self._gimbal_mission_seen:  # a new mission gimbal item since the last read
            self._gimbal_mission_seen = mission_deg
            if mission_deg is not None:
                g.set_angles(self.ctx.now_s, self.ctx.yaw, mission_deg[0], mission_deg[1])
        pos = self.ctx.pos
        here = (float(pos[0]), float(pos[1]), float(pos[2]))
        target = self.tasks.follow.following
        if self.ctx.mode == FlightMode.AUTO_FOLLOW_TARGET and target is not None:
            return point_at(target, here, self.ctx.yaw)  # PX4's follow task points the gimbal at the target
        if g.mode == GimbalMode.NEUTRAL:
            return None
        return g.current(self.ctx.now_s, here, self.ctx.yaw)

    def pop_payload_actions(self) -> list[PayloadAction]:
        """Camera actions asked for by mission items / the distance trigger since the last call."""
        return self.tasks.mission.pop_payload()

    # --- streams (ignored with a reason when NaN/inf or out of range; never raise) -----
    def set_position_target(self, now_s: float, target: PositionTarget) -> Outcome:
        return self.tasks.offboard.set_position_target(now_s, target)

    def set_attitude_target(self, now_s: float, target: AttitudeTarget) -> Outcome:
        return self.tasks.offboard.set_attitude_target(now_s, target)

    def set_manual_input(self, now_s: float, manual: ManualInput) -> Outcome:
        if self.failures.is_active(FailureUnit.SYSTEM_RC_SIGNAL):
            # an injected RC failure: the receiver hears nothing
            return Outcome(CommandResult.TEMPORARILY_REJECTED, "RC signal lost (injected failure)")
        return self.tasks.manual.set_input(now_s, manual)

    def set_follow_target(
        self,
        now_s: float,
        pos_ned_m: tuple[float, float, float],
        vel_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> Outcome:
        """A Follow Me target observation (FOLLOW_TARGET), used in AUTO_FOLLOW_TARGET. North/east must be finite
        and in range; a NaN down is a 2D target; NaN velocity components count as 0."""
        n, e, d = (float(v) for v in pos_ned_m)
        if not (math.isfinite(n) and math.isfinite(e)) or max(abs(n), abs(e)) > MAX_ABS_POS_M:
            return Outcome(CommandResult.DENIED, "Follow target: position not finite or out of range")
        if math.isfinite(d) and abs(d) > MAX_ABS_POS_M:
            d = math.nan
        vel = tuple(float(v) if math.isfinite(v) and abs(v) < 1000.0 else 0.0 for v in vel_ned_m_s)
        self.tasks.follow.set_target(FollowTarget(n, e, d, (vel[0], vel[1], vel[2]), now_s))
        return Outcome(CommandResult.ACCEPTED)

    @property
    def follow_track_lookup(self) -> TrackLookup | None:
        """(track index, sim time) -> (north, east, v_north, v_east) of a footage ground-truth track, or None: what
        FLW_TGT_TRACK >= 0 follows. The Vehicle sets it (the autopilot does no I/O)."""
        return self.tasks.follow.track_lookup

    @follow_track_lookup.setter
    def follow_track_lookup(self, lookup: TrackLookup | None) -> None:
        self.tasks.follow.track_lookup = lookup

    def gcs_heartbeat(self, now_s: float) -> None:  # for NAV_DLL_ACT link-loss
        if self.failures.is_active(FailureUnit.SYSTEM_MAVLINK_SIGNAL):
            return  # an injected link failure: the ground station is not heard
        self.commander.gcs_heartbeat(now_s)

    # --- failure injection and announcements (MAV_CMD_INJECT_FAILURE, the trials' events) ----------
    def inject_failure(
        self,
        now_s: float,
        unit: FailureUnit | int,
        ftype: FailureType | int,
        instance: int = 0,
        *,
        check_enabled: bool = True,
    ) -> Outcome:
        """PX4's MAV_CMD_INJECT_FAILURE (autopilot/failures.py says what each failure does). Refused (DENIED)
        unless SYS_FAILURE_EN = 1 when `check_enabled`; the simulator's own scenario failures pass False.
        Accepted: announced as PX4 does (WARNING "Injected: ..."), acting from the next control step on."""
        out = self.failures.inject(
            unit, ftype, instance, self.ctx.params, self.ctx.battery, check_enabled=check_enabled
        )
        if not out.ok:
            return out
        parsed = parse(unit, ftype, instance)
        assert not isinstance(parsed, Outcome)  # inject accepted it
        u, t, inst = parsed
        ctx = self.ctx
        ctx.event(Severity.WARNING, describe(u, t, inst))
        if u in SENSOR_NAMES and t in (FailureType.OFF, FailureType.STUCK):
            # PX4's sensor voter: no data is a timeout, a value that stops changing is stale
            why = "TIMEOUT" if t is FailureType.OFF else "STALE"
            ctx.event(Severity.EMERGENCY, f"{SENSOR_NAMES[u]} #0 fail: {why}!")
        if u is FailureUnit.SENSOR_GPS:
            # OFF, STUCK (no new sample) and WRONG (every sample rejected) all leave EKF2 without GPS aiding
            if t is not FailureType.OK and self._gps_lost_s is None:
                self._gps_lost_s = now_s if math.isfinite(now_s) else ctx.now_s
            elif t is FailureType.OK:
                self._gps_lost_s = None
        self._update_sensor_faults()
        return ACCEPTED

    def _update_sensor_faults(self) -> None:
        """The arming refusals the injected sensor failures cause (PX4's preflight checks)."""
        f = self.failures
        faults = [
            f"{SENSOR_NAMES[u]} sensor 0 {'stale' if f.is_active(u, FailureType.STUCK) else 'missing'}"
            for u in SENSOR_NAMES
            if f.is_active(u)
        ]
        if f.is_active(FailureUnit.SENSOR_GPS, FailureType.OFF):
            faults.append("GPS receiver missing")
        elif f.is_active(FailureUnit.SENSOR_GPS):
            faults.append("GPS data invalid")
        if f.is_active(FailureUnit.SYSTEM_MOTOR):
            faults.append("motor failure")
        self.ctx.sensor_faults = tuple(faults)

    def _check_injected_failures(self, now_s: float) -> None:
        """The consequences that follow from the injected failures in time: the position estimate lost after a GPS
        loss (PX4's mode fallback: Altitude with RC in Position, else Descend) and regained after OK; no attitude
        estimate in the air (accel or gyro off): flight termination."""
        ctx = self.ctx
        lost = self._gps_lost_s is not None and now_s - self._gps_lost_s >= GPS_NOAID_TIMEOUT_S
        if lost and ctx.position_valid:
            ctx.position_valid = False
            in_air = ctx.armed and not ctx.on_ground
            if in_air and ctx.mode == FlightMode.POSCTL and self.tasks.manual.fresh(now_s):
                self.tasks.enter(FlightMode.ALTCTL, now_s)
                ctx.event(Severity.WARNING, "Failsafe activated (no GPS): switching to Altitude")
            elif in_air and ctx.mode in POSITION_MODES:
                self._nav_fallback_from = ctx.mode
                self.tasks.enter(FlightMode.AUTO_LAND, now_s)
                ctx.event(Severity.WARNING, "Failsafe activated (no GPS): switching to Descend")
            else:
                ctx.event(Severity.CRITICAL, "Global position estimate invalid (GPS lost)")
        elif not lost and not ctx.position_valid:
            ctx.position_valid = True
            back = self._nav_fallback_from
            self._nav_fallback_from = None
            if back is not None and ctx.mode == FlightMode.AUTO_LAND and ctx.armed and not ctx.on_ground:
                self.tasks.enter(back, now_s)  # PX4 clears a mode fallback when its condition clears
                ctx.event(Severity.INFO, f"Global position regained: back to {MODE_NAMES[back]}")
            else:
                ctx.event(Severity.INFO, "Global position regained")
        if (
            ctx.armed
            and not ctx.on_ground
            and (
                self.failures.is_active(FailureUnit.SENSOR_ACCEL)
                or self.failures.is_active(FailureUnit.SENSOR_GYRO)
            )
        ):
            self.commander.failsafe(FailsafeAction.TERMINATE, Cause.ATTITUDE_INVALID)

    def announce(self, severity: Severity, text: str) -> None:
        """A message from outside the flight logic (the trial's "land now", an operator note) sent as the
        vehicle's STATUSTEXT, in order with the autopilot's own events (pop_events)."""
        self.ctx.event(severity, text)

    # --- the control loop: called once per physics step -------------------------------
    def start(self, now_s: float, state: EavState) -> None:
        """Take the initial state (home, air start, pre-arm checks) without a control step; the first `update`
        does this itself when `start` was not called."""
        if self.ctx.state is None:
            self.ctx.now_s = now_s
            self.ctx.state = state
            self._first_state(state)

    def update(self, now_s: float, state: EavState) -> EavCommand:
        ctx = self.ctx
        ctx.now_s = now_s
        first = ctx.state is None
        ctx.state = state
        if first:
            self._first_state(state)
        dt = state.dt_s
        eav = ctx.eav_params()
        ctx.update_gains()

        change = self.land_detector.update(now_s, state, ctx.armed)
        if change == Transition.TOUCHDOWN and ctx.armed:
            ctx.event(Severity.INFO, "Landing detected")
            self.tasks.mission.on_touchdown(now_s)
        elif change == Transition.LIFTOFF:
            ctx.event(Severity.INFO, "Takeoff detected")
        self.land_detector.classify(ctx.armed, self.tasks.takeoff_phase, self.tasks.landing_phase)
        if self.failures.active or not ctx.position_valid:
            self._check_injected_failures(now_s)
        self.commander.check_failsafes(now_s)
        self.commander.auto_disarm(now_s)

        cmd: EavCommand
        if not ctx.armed:
            ctx.yaw_sp = state.yaw_rad
            ctx.ctrl.reset()
            cmd = EavCommand(0.0, 0.0, state.yaw_rad, 0.0)
        else:
            cmd = self.tasks.control(now_s, dt, state, eav)
            if not (math.isfinite(cmd.roll_rad) and math.isfinite(cmd.pitch_rad)
                    and math.isfinite(cmd.yaw_rad) and math.isfinite(cmd.thrust_n)):  # fmt: skip
                # Never hand the EAV a non-finite command: level, hover, reset the integrators.
                ctx.ctrl.reset()
                ctx.yaw_sp = state.yaw_rad if math.isfinite(state.yaw_rad) else 0.0
                cmd = EavCommand(0.0, 0.0, ctx.yaw_sp, eav.hover_thrust_n)
            if self.failures.motors_off:  # dead motors (injected): what the airframe makes of the command
                cmd = motor_failure_command(cmd, self.failures.motors_off, state.yaw_rad, eav.max_thrust_n)
        mission = self.tasks.mission
        if ctx.armed and mission.trigger.update(float(state.pos_ned_m[0]), float(state.pos_ned_m[1])):
            mission.payload.append(PayloadAction("capture_once"))
        ctx.battery.update(dt, cmd.thrust_n / eav.hover_thrust_n, ctx.armed, ctx.battery_cfg())
        self._check_battery()
        self.last_command = cmd
        return cmd

    def _first_state(self, state: EavState) -> None:
        """Home from the first state; a vehicle that starts in the air (the paper's experiments start at altitude)
        starts armed in Hold there, with home on the ground below it."""
        ctx = self.ctx
        ctx.yaw_sp = state.yaw_rad
        self.land_detector.start(state)
        if not ctx.home_set:
            ctx.home = np.array(state.pos_ned_m, dtype=np.float64)
            if not state.landed:
                ctx.home[2] = max(float(ctx.home[2]), self.eav.ground_z_ned_m)
        if not state.landed:
            ctx.armed = True
            self.land_detector.has_flown = True
            ctx.mode = FlightMode.AUTO_LOITER
            self.tasks.hold.hold_at(np.array(state.pos_ned_m, dtype=np.float64))
            ctx.event(Severity.INFO, "Air start: armed, holding position")

    def _check_battery(self) -> None:
        rem = self.battery_remaining
        level = battery_level(rem, self.params)
        if level > self._bat_level:
            warning = battery_warning(level, rem)
            if warning is not None:
                self.ctx.event(warning.severity, warning.text)
        self._bat_level = level


__all__ = ["Autopilot", "InsideFn", "OffboardKind", "RtlPhase"]
