"""The virtual PX4: modes, controllers and failsafes on top of the EAV. Pure logic: no sockets, no clock.

CONTRACT (used by viva_sitl/mavlink and viva_sitl/app.py): keep these signatures; add, don't change.
Every method takes `now_s` (simulation time, s) where time matters; the caller owns the clock.

Behaviour choices where PX4's is unclear or unsuitable (also in the README):
- Boot mode is AUTO_LOITER (Hold), as PX4 SITL without RC.
- Command refusals come back only as Outcome(reason); the MAVLink layer sends the reason as STATUSTEXT. Events are
  for things that happen by themselves (failsafes, take-off/landing detection, auto-disarm, mission progress).
- Arming is allowed in every mode that can run (RTL and LAND too, so a vehicle that landed there can be re-armed
  and take off again); refusals are DENIED, mode-switch refusals TEMPORARILY_REJECTED (PX4 Commander's mapping).
- Takeoff while disarmed: DENIED ("Takeoff denied: vehicle not armed"). Land while on the ground: ACCEPTED (mode
  becomes AUTO_LAND; an armed vehicle then auto-disarms after COM_DISARM_LAND).
- OFFBOARD is accepted when a valid setpoint arrived within the last 0.5 s (i.e. a > 2 Hz stream). PX4 itself only
  checks that the stream is not lost; requiring a full second would refuse MAVSDK's own start() sequence
  (one set_*(), then start(), while MAVSDK's 20 Hz stream begins).
- Offboard loss (COM_OF_LOSS_T): COM_OBL_RC_ACT; the RC-based choices 0..2 (Position/Altitude/Manual) fall back to
  Hold when no MANUAL_CONTROL is arriving, as PX4 v1.14's failsafe framework (default 0 -> Hold).
- Geofence (footage edge, GF_ACTION, default 2 Hold): Hold holds at the last position that was still inside the
  footage, so the camera sees footage again. Arming outside the footage, repositioning to or uploading a mission with
  a waypoint outside it are refused.
- DO_REPOSITION needs an armed vehicle in the air (landed: TEMPORARILY_REJECTED). Without the change-mode flag
  (MAV_DO_REPOSITION_FLAGS_CHANGE_MODE) it moves the Hold target only when already in Hold; otherwise the target is
  kept and flown the next time Hold is entered (PX4's reposition triplet).
- Uploaded geofence (geofence.py), rally points (RTL to the closest of home and rally points), Orbit (orbit.py),
  DO_JUMP / NAV_DELAY / camera items (mission.py, payload.py): the logic lives in those pure modules; the hunks
  marked "# [fence]" below are the thin calls into them.
- Mission TAKEOFF items climb vertically at the current position (the item's horizontal position is ignored); a
  mission started on the ground without a TAKEOFF item first climbs to MIS_TAKEOFF_ALT (or the item's altitude).
"""

from __future__ import annotations

import contextlib
import enum
import math
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from viva_sitl.autopilot.battery import Battery, BatteryConfig
from viva_sitl.autopilot.control import (
    Airframe,
    AttitudeThrust,
    Gains,
    Limits,
    PositionController,
    TrajectorySetpoint,
    body_rates_to_euler_rates,
    slew_yaw,
)
from viva_sitl.autopilot.geofence import (  # [fence]
    FenceLimits,
    Geofence,
    GeofenceAction,
    RallyPoint,
    breach_reason,
    rtl_destination,
)
from viva_sitl.autopilot.mission import (
    NAV_COMMANDS,
    MissionProgress,
    mission_yaw,
    resolve_item,
    resolve_jumps,
    validate_mission,
)
from viva_sitl.autopilot.orbit import Orbit, apply_command, orbit_step  # [fence]
from viva_sitl.autopilot.params import SIM_EAV_PARAMS, ParamStore
from viva_sitl.autopilot.payload import DistanceTrigger, item_effect  # [fence]
from viva_sitl.autopilot.setpoints import (
    MAX_ABS_POS_M,
    check_attitude_target,
    check_manual_input,
    deadzone,
    finite,
    position_target_to_local,
    rot_yaw,
    throttle_to_thrust_norm,
)
from viva_sitl.autopilot.types import (
    ACCEPTED,
    AttitudeTarget,
    CommandResult,
    Event,
    FlightMode,
    LandedState,
    ManualInput,
    MissionCommand,
    MissionItem,
    Outcome,
    PayloadAction,
    PositionTarget,
    Severity,
)
from viva_sitl.dynamics import EavCommand, EavParams, EavState, wrap_pi

# (north_m, east_m) -> True when the camera at that ground point still sees footage (geofence)
InsideFn = Callable[[float, float], bool]

Vec3 = NDArray[np.float64]
NAN = math.nan

OFFBOARD_FRESH_S = 0.5  # a setpoint within this -> the stream runs at > 2 Hz (mode switch / arming)
MANUAL_DEADZONE = 0.05  # stick deadzone (fraction of full travel)
THROTTLE_DEADZONE = 0.1  # around mid-stick for climb-rate modes
HOLD_LOCK_SPEED_M_S = 0.3
GEOFENCE_CHECK_S = 0.1  # the footage test runs at 10 Hz (it may be costly)
MAX_TAKEOFF_ALT_M = 1000.0

_MANUAL_MODES = frozenset({FlightMode.MANUAL, FlightMode.STABILIZED, FlightMode.ALTCTL, FlightMode.POSCTL})
_TILT_STICK_MODES = frozenset({FlightMode.MANUAL, FlightMode.STABILIZED, FlightMode.ALTCTL})


def _denied(reason: str) -> Outcome:
    return Outcome(CommandResult.DENIED, reason)


def _rejected(reason: str) -> Outcome:
    return Outcome(CommandResult.TEMPORARILY_REJECTED, reason)


class RtlPhase(enum.Enum):
    CLIMB = 1
    RETURN = 2
    DESCEND = 3
    LOITER = 4
    LAND = 5


class OffboardKind(enum.Enum):
    NONE = 0
    TRAJECTORY = 1  # position / velocity / acceleration
    ATTITUDE = 2  # quaternion + thrust
    RATES = 3  # body rates + thrust


class Autopilot:
    def __init__(self, params: ParamStore, eav: EavParams, inside: InsideFn | None = None) -> None:
        self.params = params
        self.eav = eav  # the airframe as configured; eav_params() applies the SIM_* parameters on top
        self.inside = inside
        self._base_eav = eav
        # Parameters not set explicitly (config file, PARAM_SET) take the configured airframe's values.
        self._sync_sim_params_from(eav)
        self._eav_rev = -1
        self._eav_cached = eav
        self._bat_rev = -1
        self._bat_cfg = BatteryConfig()
        self._gains_rev = -1

        self._armed = False
        self._mode = FlightMode.AUTO_LOITER
        self._landed_state = LandedState.ON_GROUND
        self._state: EavState | None = None
        self._now_s = 0.0
        self._home: Vec3 = np.array([0.0, 0.0, float(eav.ground_z_ned_m)])
        self._home_set = False
        self._events: list[Event] = []

        self._ctrl = PositionController()
        self._yaw_sp = 0.0
        self._hold: Vec3 | None = None  # AUTO_LOITER target (NED)
        self._hold_yaw: float | None = None
        self._takeoff_target: Vec3 | None = None
        self._land_xy: tuple[float, float] | None = None
        self._rtl_phase = RtlPhase.CLIMB
        self._rtl_alt_down = 0.0
        self._rtl_loiter_since = 0.0
        self._cruise_override: float | None = None
        self._speed_override: float | None = None  # DO_REPOSITION ground speed for the current hold target

        self._mission: tuple[MissionItem, ...] = ()
        self._mission_valid = False
        self._mp = MissionProgress()

        self._offb_kind = OffboardKind.NONE
        self._offb_last_s = -math.inf
        self._offb_traj = TrajectorySetpoint()
        self._offb_yaw: float | None = None
        self._offb_yaw_rate: float = 0.0
        self._offb_att = (0.0, 0.0, 0.0, 0.0)  # roll, pitch, yaw, thrust_norm
        self._offb_rates = (0.0, 0.0, 0.0)
        self._offb_rate_att: Vec3 | None = None  # integrated attitude target for body rates

        self._manual: ManualInput | None = None
        self._manual_last_s = -math.inf
        self._man_hold_xy: tuple[float, float] | None = None
        self._man_hold_z: float | None = None

        self._gcs_seen = False
        self._gcs_last_s = -math.inf
        self._dll_lost = False
        self._rc_lost_handled = False
        self._gf_outside = False
        self._gf_next_check_s = -math.inf
        self._last_inside_ned: Vec3 | None = None

        # [fence] uploaded geofence, rally points, orbit, pending reposition, payload
        self._fence = Geofence()
        self._rally: tuple[RallyPoint, ...] = ()
        self._fence_breached = False
        self._fence_next_check_s = -math.inf
        self._rtl_dest: Vec3 | None = None  # where RTL returns to (home or a rally point)
        self._orbit: Orbit | None = None
        self._orbit_approach = True
        self._pending_reposition: tuple[Vec3, float | None, float | None] | None = None
        self._payload: list[PayloadAction] = []
        self._trigger = DistanceTrigger()
        self._gimbal_deg = (0.0, 0.0)

        self._battery = Battery()
        self._bat_level = 0  # 0 ok, 1 low, 2 critical (events once per crossing)
        self._ground_since_s = 0.0
        self._has_flown = False
        self._was_on_ground = True

    # --- parameters -> airframe ---------------------------------------------------------
    def _sync_sim_params_from(self, eav: EavParams) -> None:
        values = {
            "SIM_MASS": eav.mass_kg,
            "SIM_DRAG": eav.drag_kd_n_s_m,
            "SIM_WIND_N": eav.wind.mean_wind_ned_m_s[0],
            "SIM_WIND_E": eav.wind.mean_wind_ned_m_s[1],
            "SIM_WIND_D": eav.wind.mean_wind_ned_m_s[2],
            "SIM_GUST_STD": eav.wind.gust_std_m_s,
        }
        for name in SIM_EAV_PARAMS:
            if not self.params.is_modified(name):
                spec = self.params.spec(name)
                self.params.adopt(name, min(max(values[name], spec.min), spec.max))

    def eav_params(self) -> EavParams:
        """The EAV parameters with SIM_* applied: the app calls this after physics steps and, when it differs from
        what the simulator uses, swaps it in (Simulator.set_params). Cached: cheap to call every step.

        SIM_MASS scales max_thrust_n too (same thrust-to-weight ratio as configured); dt, tilt limit, ground and
        attitude lag stay as configured.
        """
        if self.params.revision != self._eav_rev:
            p, base = self.params, self._base_eav
            mass = p.get("SIM_MASS")
            wind = replace(
                base.wind,
                mean_wind_ned_m_s=(p.get("SIM_WIND_N"), p.get("SIM_WIND_E"), p.get("SIM_WIND_D")),
                gust_std_m_s=p.get("SIM_GUST_STD"),
            )
            new = replace(
                base,
                mass_kg=mass,
                drag_kd_n_s_m=p.get("SIM_DRAG"),
                max_thrust_n=base.max_thrust_n * mass / base.mass_kg,
                wind=wind,
            )
            if new != self._eav_cached:
                self._eav_cached = new
            self._eav_rev = p.revision
        return self._eav_cached

    def _battery_cfg(self) -> BatteryConfig:
        if self.params.revision != self._bat_rev:
            p = self.params
            # An inconsistent pair (V_EMPTY >= V_CHARGED) keeps the last valid configuration.
            with contextlib.suppress(ValueError):
                self._bat_cfg = BatteryConfig(
                    capacity_mah=p.get("BAT1_CAPACITY"),
                    n_cells=p.get_int("BAT1_N_CELLS"),
                    v_charged=p.get("BAT1_V_CHARGED"),
                    v_empty=p.get("BAT1_V_EMPTY"),
                    r_internal_ohm=p.get("BAT1_R_INTERNAL"),
                    hover_current_a=p.get("SIM_BAT_HOV_A"),
                    min_remaining=p.get("SIM_BAT_MIN_PCT") / 100.0,
                )
            self._bat_rev = p.revision
        return self._bat_cfg

    def _update_gains(self) -> None:
        if self.params.revision != self._gains_rev:
            p = self.params
            self._ctrl.gains = Gains(
                pos_xy_p=p.get("MPC_XY_P"),
                pos_z_p=p.get("MPC_Z_P"),
                vel_xy_p=p.get("MPC_XY_VEL_P_ACC"),
                vel_xy_i=p.get("MPC_XY_VEL_I_ACC"),
                vel_z_p=p.get("MPC_Z_VEL_P_ACC"),
                vel_z_i=p.get("MPC_Z_VEL_I_ACC"),
            )
            self._gains_rev = p.revision

    # --- read by telemetry -------------------------------------------------------------
    @property
    def armed(self) -> bool:
        return self._armed

    @property
    def mode(self) -> FlightMode:
        return self._mode

    @property
    def landed_state(self) -> LandedState:
        return self._landed_state

    @property
    def home_ned_m(self) -> tuple[float, float, float]:
        return float(self._home[0]), float(self._home[1]), float(self._home[2])

    @property
    def mission_current_seq(self) -> int:
        return self._mp.seq

    @property
    def mission_items(self) -> Sequence[MissionItem]:
        return self._mission

    @property
    def mission_finished(self) -> bool:
        return self._mp.finished

    @property
    def battery_remaining(self) -> float:  # 0..1
        return self._battery.remaining(self._battery_cfg())

    @property
    def battery_voltage_v(self) -> float:
        return self._battery.voltage_v(self._battery_cfg())

    @property
    def battery_current_a(self) -> float:
        return self._battery.current_a

    def pop_events(self) -> list[Event]:  # STATUSTEXT / MISSION_ITEM_REACHED since the last call
        ev, self._events = self._events, []
        return ev

    def _event(self, severity: Severity, text: str, reached: int | None = None) -> None:
        self._events.append(Event(self._now_s, severity, text, mission_item_reached=reached))

    # --- helpers on the last known state --------------------------------------------------
    @property
    def _pos(self) -> Vec3:
        if self._state is None:
            return self._home.copy()
        return np.array(self._state.pos_ned_m, dtype=np.float64)

    @property
    def _vel(self) -> Vec3:
        if self._state is None:
            return np.zeros(3)
        return np.array(self._state.vel_ned_m_s, dtype=np.float64)

    @property
    def _yaw(self) -> float:
        return 0.0 if self._state is None else self._state.yaw_rad

    @property
    def _on_ground(self) -> bool:
        return True if self._state is None else bool(self._state.landed)

    def _offboard_fresh(self, now_s: float) -> bool:
        return self._offb_kind != OffboardKind.NONE and now_s - self._offb_last_s <= OFFBOARD_FRESH_S

    def _manual_fresh(self, now_s: float) -> bool:
        return self._manual is not None and now_s - self._manual_last_s <= self.params.get("COM_RC_LOSS_T")

    def _inside(self, north_m: float, east_m: float) -> bool:
        if self.inside is None:
            return True
        try:
            return bool(self.inside(north_m, east_m))
        except Exception:  # a faulty callback must never crash the control loop: treat as outside
            return False

    def _cruise(self) -> float:
        if self._speed_override is not None and self._mode == FlightMode.AUTO_LOITER:
            return self._speed_override
        if self._cruise_override is not None:
            return self._cruise_override
        return self.params.get("MPC_XY_CRUISE")

    # --- commands ----------------------------------------------------------------------
    def prearm_check(self, now_s: float) -> Outcome:
        """ACCEPTED when arming would be allowed now (SYS_STATUS pre-arm bit), else the refusal."""
        if self._state is None:
            return _rejected("Arming denied: system not ready")
        if not self._on_ground:
            return _denied("Arming denied: vehicle not landed")
        pos = self._pos
        if not self._inside(float(pos[0]), float(pos[1])):
            return _denied("Arming denied: outside footage (geofence)")
        if self.params.get_int("GF_ACTION") != 0 and not self._fence_ok(
            float(pos[0]), float(pos[1])
        ):  # [fence]
            return _denied("Arming denied: vehicle outside geofence")
        if self.battery_remaining <= self.params.get("BAT_CRIT_THR"):
            return _denied("Arming denied: battery too low")
        mode = self._mode
        if mode == FlightMode.AUTO_MISSION and not self._mission_valid:
            return _denied("Arming denied: no valid mission")
        if mode == FlightMode.OFFBOARD and not self._offboard_fresh(now_s):
            return _denied("Arming denied: offboard setpoints not streaming")
        if mode == FlightMode.AUTO_READY:
            return _denied("Arming denied: mode not armable")
        if mode in _MANUAL_MODES:
            if not self._manual_fresh(now_s) or self._manual is None:
                return _denied("Arming denied: manual control lost")
            limit = 0.2 if mode in (FlightMode.MANUAL, FlightMode.STABILIZED) else 0.6
            if self._manual.z > limit:
                return _denied(
                    "Arming denied: throttle above center" if limit > 0.5 else "Arming denied: throttle high"
                )
        return ACCEPTED

    def arm(self, now_s: float, force: bool = False) -> Outcome:
        self._now_s = now_s
        if self._armed:
            return ACCEPTED
        if not force:
            check = self.prearm_check(now_s)
            if not check.ok:
                return check
        self._armed = True
        self._has_flown = False
        self._ground_since_s = now_s
        self._home = self._pos.copy()
        self._home_set = True
        self._ctrl.reset()
        self._yaw_sp = self._yaw
        self._rc_lost_handled = False
        self._event(Severity.INFO, "Armed by external command")
        if self._mode == FlightMode.AUTO_MISSION:
            if self._mp.finished:
                self._mp = MissionProgress(seq=0)
            self._start_item(now_s)
        else:
            self._enter_mode(self._mode, now_s)
        return ACCEPTED

    def _do_disarm(self, text: str, severity: Severity = Severity.INFO) -> None:
        self._armed = False
        self._ctrl.reset()
        self._offb_rate_att = None
        self._event(severity, text)

    def disarm(self, now_s: float, force: bool = False) -> Outcome:
        self._now_s = now_s
        if not self._armed:
            return ACCEPTED
        if not force and not self._on_ground:
            return _denied("Disarming denied: not landed")
        self._do_disarm("Disarmed by external command")
        return ACCEPTED

    def kill(self, now_s: float) -> Outcome:
        self._now_s = now_s
        if self._armed:
            self._do_disarm("Kill switch engaged: motors stopped", Severity.CRITICAL)
        return ACCEPTED

    def takeoff(self, now_s: float, altitude_m: float | None = None) -> Outcome:  # None -> MIS_TAKEOFF_ALT
        self._now_s = now_s
        alt = (
            self.params.get("MIS_TAKEOFF_ALT") if altitude_m is None or math.isnan(altitude_m) else altitude_m
        )
        if not (math.isfinite(alt) and 0.0 < alt <= MAX_TAKEOFF_ALT_M):
            return _denied(f"Takeoff denied: altitude {alt} m out of range")
        if not self._armed:
            return _denied("Takeoff denied: vehicle not armed")
        self._start_takeoff(alt)
        return ACCEPTED

    def land(self, now_s: float) -> Outcome:
        self._now_s = now_s
        self._enter_mode(FlightMode.AUTO_LAND, now_s)
        return ACCEPTED

    def return_to_launch(self, now_s: float) -> Outcome:
        self._now_s = now_s
        self._enter_mode(FlightMode.AUTO_RTL, now_s)
        return ACCEPTED

    def set_mode(self, now_s: float, mode: FlightMode) -> Outcome:
        self._now_s = now_s
        if mode == self._mode:
            return ACCEPTED
        if mode == FlightMode.AUTO_READY:
            return _rejected("Switching to Ready is not possible")
        if mode == FlightMode.OFFBOARD and not self._offboard_fresh(now_s):
            return _rejected("Switching to Offboard denied: no setpoint stream (> 2 Hz)")
        if mode == FlightMode.AUTO_MISSION and not self._mission_valid:
            return _rejected("Switching to Mission denied: no valid mission")
        if mode in _MANUAL_MODES and not self._manual_fresh(now_s):
            return _rejected(f"Switching to {mode.name} denied: no manual control (RC)")
        if mode == FlightMode.ORBIT and (not self._armed or self._on_ground):  # [fence]
            return _rejected("Switching to Orbit denied: not flying")
        if mode == FlightMode.AUTO_TAKEOFF:
            if self._armed:
                self._start_takeoff(self.params.get("MIS_TAKEOFF_ALT"))
            else:
                self._mode = FlightMode.AUTO_TAKEOFF
                self._takeoff_target = None
            return ACCEPTED
        self._enter_mode(mode, now_s)
        return ACCEPTED

    def reposition(self, now_s: float, north_m: float, east_m: float, down_m: float, yaw_rad: float | None,
                   speed_m_s: float | None = None, change_mode: bool = True) -> Outcome:  # fmt: skip
        self._now_s = now_s
        if not self._armed:
            return _denied("Reposition denied: vehicle not armed")
        if self._on_ground:
            return _rejected("Reposition denied: landed, take off first")
        pos = self._pos
        target = np.array(
            [
                north_m if math.isfinite(north_m) else pos[0],
                east_m if math.isfinite(east_m) else pos[1],
                down_m if math.isfinite(down_m) else pos[2],
            ]
        )
        if np.any(np.abs(target) > MAX_ABS_POS_M):
            return _denied("Reposition denied: target out of range")
        if yaw_rad is not None and not math.isfinite(yaw_rad):
            yaw_rad = None
        if speed_m_s is not None and not (math.isfinite(speed_m_s) and speed_m_s > 0.0):
            speed_m_s = None
        if not self._inside(float(target[0]), float(target[1])):
            return _denied("Reposition denied: target outside footage")
        if not change_mode and self._mode != FlightMode.AUTO_LOITER:  # [fence] PX4: kept for the next Hold
            self._pending_reposition = (target, yaw_rad, speed_m_s)
            return ACCEPTED
        self._pending_reposition = None
        self._enter_mode(FlightMode.AUTO_LOITER, now_s)
        self._hold = target
        self._hold_yaw = yaw_rad
        if speed_m_s is not None:
            self._speed_override = min(speed_m_s, self.params.get("MPC_XY_VEL_MAX"))
        return ACCEPTED

    def change_speed(self, now_s: float, speed_m_s: float) -> Outcome:
        """DO_CHANGE_SPEED: > 0 sets the auto cruise speed (clamped to MPC_XY_VEL_MAX); -1 no change; -2 default."""
        self._now_s = now_s
        if not math.isfinite(speed_m_s):
            return _denied("Change speed denied: speed not finite")
        if speed_m_s == -2.0:
            self._cruise_override = None
            return ACCEPTED
        if speed_m_s < 0.0:
            return ACCEPTED
        if speed_m_s == 0.0:
            return _denied("Change speed denied: speed must be > 0")
        self._cruise_override = min(speed_m_s, self.params.get("MPC_XY_VEL_MAX"))
        if self._mode == FlightMode.AUTO_LOITER:
            self._speed_override = self._cruise_override
        return ACCEPTED

    def mission_start(self, now_s: float, first_seq: int = 0) -> Outcome:
        self._now_s = now_s
        if not self._mission_valid:
            return _denied("Mission start denied: no valid mission")
        if not (0 <= first_seq < len(self._mission)):
            return _denied(f"Mission start denied: item {first_seq} does not exist")
        self._mp = MissionProgress(seq=first_seq)
        self._mode = FlightMode.AUTO_MISSION
        self._start_item(now_s)
        return ACCEPTED

    def set_mission(self, items: Sequence[MissionItem]) -> Outcome:
        items = tuple(items)
        try:
            validate_mission(items, self.home_ned_m, self._inside, self.params.get("MIS_DIST_1WP"),
                             fence_ok=self._fence_ok)  # fmt: skip
        except ValueError as e:
            return _denied(str(e))
        self._mission = items
        self._mission_valid = len(items) > 0
        self._mp = MissionProgress(seq=0)
        if self._mode == FlightMode.AUTO_MISSION:
            if self._mission_valid:
                self._start_item(self._now_s)
            else:
                self._enter_mode(FlightMode.AUTO_LOITER, self._now_s)
        return ACCEPTED

    def clear_mission(self) -> Outcome:
        self._mission = ()
        self._mission_valid = False
        self._mp = MissionProgress(seq=0)
        if self._mode == FlightMode.AUTO_MISSION:
            self._enter_mode(FlightMode.AUTO_LOITER, self._now_s)
        return ACCEPTED

    def set_mission_current(self, seq: int) -> Outcome:
        if not (0 <= seq < len(self._mission)):
            return _denied(f"Mission: item {seq} does not exist")
        self._mp = MissionProgress(seq=seq)
        if self._mode == FlightMode.AUTO_MISSION:
            self._start_item(self._now_s)
        return ACCEPTED

    def set_home(self, now_s: float, home_ned_m: tuple[float, float, float]) -> Outcome:
        """DO_SET_HOME (optional in the contract)."""
        if not finite(*home_ned_m) or any(abs(v) > MAX_ABS_POS_M for v in home_ned_m):
            return _denied("Set home denied: position not finite")
        self._home = np.array(home_ned_m, dtype=np.float64)
        self._home_set = True
        return ACCEPTED

    # --- [fence] geofence, rally points, orbit, payload (logic in geofence.py / orbit.py / payload.py) ---------
    @property
    def geofence(self) -> Geofence:
        return self._fence

    @property
    def rally_points(self) -> tuple[RallyPoint, ...]:
        return self._rally

    def set_geofence(self, fence: Geofence) -> Outcome:
        """MISSION_TYPE_FENCE upload (already validated geometry). An empty Geofence clears it. As PX4, the stored
        mission is checked again: one with a waypoint outside the new fence becomes invalid (not startable)."""
        self._fence = fence
        self._fence_breached = False
        self._fence_next_check_s = -math.inf
        if self._mission:
            try:
                validate_mission(self._mission, self.home_ned_m, self._inside, self.params.get("MIS_DIST_1WP"),
                                 fence_ok=self._fence_ok)  # fmt: skip
                self._mission_valid = True
            except ValueError as e:
                self._mission_valid = False
                self._event(Severity.WARNING, str(e))
        return ACCEPTED

    def set_rally_points(self, points: Sequence[RallyPoint]) -> Outcome:
        self._rally = tuple(points)
        return ACCEPTED

    def orbit(self, now_s: float, radius_m: float, velocity_m_s: float, yaw_behaviour: float,
              center_ne_m: tuple[float, float] | None, center_down_m: float | None) -> Outcome:  # fmt: skip
        """MAV_CMD_DO_ORBIT: NaN radius/velocity/yaw behaviour keep the current orbit's (or PX4's defaults)."""
        self._now_s = now_s
        if not self._armed:
            return _denied("Orbit denied: vehicle not armed")
        if self._on_ground:
            return _rejected("Orbit denied: landed, take off first")
        if center_ne_m is not None and not finite(*center_ne_m):
            center_ne_m = None
        pos = self._pos
        prev = self._orbit if self._mode == FlightMode.ORBIT else None
        if prev is None and center_ne_m is None:
            center_ne_m = (float(pos[0]), float(pos[1]))
        try:
            orbit = apply_command(prev, pos, self._yaw, radius_m, velocity_m_s, yaw_behaviour, center_ne_m,
                                  center_down_m, self.params.get("MC_ORBIT_RAD_MAX"))  # fmt: skip
        except ValueError as e:
            return _denied(str(e))
        if self._mode != FlightMode.ORBIT:
            self._enter_mode(FlightMode.ORBIT, now_s)
        self._orbit = orbit
        self._orbit_approach = True
        return ACCEPTED

    @property
    def orbit_status(self) -> Orbit | None:
        """The orbit flown now (ORBIT_EXECUTION_STATUS), None outside Orbit mode."""
        return self._orbit if self._mode == FlightMode.ORBIT else None

    @property
    def gimbal_pitch_yaw_deg(self) -> tuple[float, float]:
        """Last gimbal pitch/yaw a mission item asked for (DO_MOUNT_CONTROL / DO_GIMBAL_MANAGER_PITCHYAW)."""
        return self._gimbal_deg

    def pop_payload_actions(self) -> list[PayloadAction]:
        """Camera actions asked for by mission items / the distance trigger since the last call."""
        out, self._payload = self._payload, []
        return out

    def _fence_ok(self, north_m: float, east_m: float) -> bool:
        return self._fence.empty or self._fence.contains(north_m, east_m)

    # --- streams (ignored with a reason when NaN/inf or out of range; never raise) -----
    def set_position_target(self, now_s: float, target: PositionTarget) -> Outcome:
        pos = self._pos
        try:
            self._offb_traj = position_target_to_local(
                target, (float(pos[0]), float(pos[1]), float(pos[2])), self._yaw
            )
        except ValueError as e:
            return _denied(str(e))
        self._offb_yaw = target.yaw_rad
        self._offb_yaw_rate = target.yaw_rate_rad_s if target.yaw_rate_rad_s is not None else 0.0
        if self._offb_kind != OffboardKind.TRAJECTORY and self._mode == FlightMode.OFFBOARD:
            self._yaw_sp = self._yaw
            self._ctrl.reset()
        self._offb_kind = OffboardKind.TRAJECTORY
        self._offb_last_s = now_s
        return ACCEPTED

    def set_attitude_target(self, now_s: float, target: AttitudeTarget) -> Outcome:
        try:
            rpy = check_attitude_target(target)
        except ValueError as e:
            return _denied(str(e))
        if rpy is not None:
            self._offb_att = (*rpy, target.thrust_norm)
            self._offb_kind = OffboardKind.ATTITUDE
        else:
            assert target.body_rates_rad_s is not None
            if self._offb_kind != OffboardKind.RATES:
                self._offb_rate_att = None  # restart integration from the current attitude
            self._offb_rates = target.body_rates_rad_s
            self._offb_att = (*self._offb_att[:3], target.thrust_norm)
            self._offb_kind = OffboardKind.RATES
        self._offb_last_s = now_s
        return ACCEPTED

    def set_manual_input(self, now_s: float, manual: ManualInput) -> Outcome:
        try:
            check_manual_input(manual)
        except ValueError as e:
            return _denied(str(e))
        self._manual = manual
        self._manual_last_s = now_s
        return ACCEPTED

    def gcs_heartbeat(self, now_s: float) -> None:  # for NAV_DLL_ACT link-loss
        self._gcs_seen = True
        self._gcs_last_s = now_s
        if self._dll_lost:
            self._dll_lost = False
            self._event(Severity.INFO, "Data link regained")

    # --- mode entry -------------------------------------------------------------------
    def _braking_point(self) -> Vec3:
        pos, vel = self._pos, self._vel
        a_xy = self.params.get("MPC_ACC_HOR")
        a_z = self.params.get("MPC_ACC_DOWN_MAX")
        out = pos.copy()
        out[:2] += vel[:2] * np.hypot(vel[0], vel[1]) / (2.0 * a_xy)
        out[2] += vel[2] * abs(vel[2]) / (2.0 * a_z)
        return out

    def _enter_mode(self, mode: FlightMode, now_s: float) -> None:
        prev = self._mode
        self._mode = mode
        self._speed_override = None
        self._ctrl.restart_trajectory()
        if mode == FlightMode.AUTO_LOITER:
            self._hold = self._braking_point() if not self._on_ground else self._pos.copy()
            self._hold_yaw = None
            if self._pending_reposition is not None and self._armed and not self._on_ground:  # [fence]
                self._hold, self._hold_yaw, speed = self._pending_reposition
                self._pending_reposition = None
                if speed is not None:
                    self._speed_override = min(speed, self.params.get("MPC_XY_VEL_MAX"))
        elif mode == FlightMode.ORBIT:  # [fence] PX4 defaults: around the current position, 1 m, 1 m/s
            self._orbit = apply_command(None, self._pos, self._yaw, math.nan, math.nan, math.nan, None, None,
                                        self.params.get("MC_ORBIT_RAD_MAX"))  # fmt: skip
            self._orbit_approach = True
        elif mode == FlightMode.AUTO_LAND:
            pos = self._braking_point()
            self._land_xy = (float(pos[0]), float(pos[1]))
        elif mode == FlightMode.AUTO_RTL:
            self._start_rtl()
        elif mode == FlightMode.AUTO_TAKEOFF:
            if self._armed:
                self._start_takeoff(self.params.get("MIS_TAKEOFF_ALT"))
        elif mode == FlightMode.AUTO_MISSION:
            if prev != FlightMode.AUTO_MISSION or self._mp.finished:
                if self._mp.finished:
                    self._mp = MissionProgress(seq=0)
                self._mp = MissionProgress(
                    seq=self._mp.seq, jumps_done=self._mp.jumps_done
                )  # [fence] keep counts
                self._start_item(now_s)
        elif mode == FlightMode.OFFBOARD:
            self._offb_rate_att = None
            self._yaw_sp = self._yaw
        elif mode in _MANUAL_MODES:
            self._man_hold_xy = None
            self._man_hold_z = None
            self._yaw_sp = self._yaw
        if prev != mode and prev == FlightMode.OFFBOARD:
            self._ctrl.reset_xy()

    def _start_takeoff(self, alt_m: float) -> None:
        pos = self._pos
        self._mode = FlightMode.AUTO_TAKEOFF
        self._takeoff_target = np.array([pos[0], pos[1], self._home[2] - alt_m])
        if not self._on_ground and self._takeoff_target[2] > pos[2]:
            self._takeoff_target[2] = pos[2]  # already higher: PX4 does not descend in take-off
        self._speed_override = None

    def _start_rtl(self) -> None:
        pos = self._pos
        dest, rally_i = rtl_destination(pos, self._home, self._rally)  # [fence] RTL_TYPE 0
        self._rtl_dest = np.array(dest, dtype=np.float64)
        if rally_i is not None:
            self._event(Severity.INFO, f"RTL: returning to rally point {rally_i}")
        self._rtl_alt_down = float(min(pos[2], self._home[2] - self.params.get("RTL_RETURN_ALT")))
        self._rtl_phase = RtlPhase.LAND if self._on_ground else RtlPhase.CLIMB
        self._hold = self._braking_point()
        self._land_xy = (float(self._rtl_dest[0]), float(self._rtl_dest[1]))

    def _failsafe(self, action: int, reason: str, *, kind: str) -> None:
        """Apply a PX4 failsafe action code: 1 Hold, 2 Return, 3 Land, 5 Terminate, 6 Lockdown (disarm)."""
        now = self._now_s
        if action == 1:
            self._enter_mode(FlightMode.AUTO_LOITER, now)
            what = "Hold"
        elif action == 2:
            self._enter_mode(FlightMode.AUTO_RTL, now)
            what = "Return"
        elif action == 3:
            self._enter_mode(FlightMode.AUTO_LAND, now)
            what = "Land"
        elif action in (5, 6):
            self._do_disarm(f"{kind}: {'termination' if action == 5 else 'lockdown'}", Severity.EMERGENCY)
            return
        else:
            return
        self._event(Severity.WARNING, f"Failsafe activated ({reason}): switching to {what}")

    # --- failsafes --------------------------------------------------------------------
    def _check_failsafes(self, now_s: float) -> None:
        p = self.params
        in_air = self._armed and not self._on_ground
        # Offboard loss.
        if self._mode == FlightMode.OFFBOARD and now_s - self._offb_last_s > p.get("COM_OF_LOSS_T"):
            act = p.get_int("COM_OBL_RC_ACT")
            manual_ok = self._manual_fresh(now_s)
            if act in (0, 1, 2) and manual_ok:
                target = {0: FlightMode.POSCTL, 1: FlightMode.ALTCTL, 2: FlightMode.STABILIZED}[act]
                self._enter_mode(target, now_s)
                self._event(
                    Severity.WARNING, f"Failsafe activated (offboard lost): switching to {target.name}"
                )
            else:
                code = {0: 1, 1: 1, 2: 1, 3: 2, 4: 3, 5: 1, 6: 5, 7: 6}.get(act, 1)
                if not self._armed:
                    self._enter_mode(FlightMode.AUTO_LOITER, now_s)
                else:
                    self._failsafe(code, "no offboard", kind="Offboard lost")
        # Manual control loss in manual modes.
        if self._mode in _MANUAL_MODES and self._armed and not self._manual_fresh(now_s):
            if not self._rc_lost_handled:
                self._rc_lost_handled = True
                act = p.get_int("NAV_RCL_ACT")
                self._failsafe(act if act in (1, 2, 3, 5, 6) else 1, "manual control lost", kind="RC lost")
        elif self._manual_fresh(now_s):
            self._rc_lost_handled = False
        # Ground-station link loss (only once a GCS has been seen).
        if self._gcs_seen and not self._dll_lost and now_s - self._gcs_last_s > p.get("COM_DL_LOSS_T"):
            self._dll_lost = True
            act = p.get_int("NAV_DLL_ACT")
            self._event(Severity.CRITICAL, "Connection to ground station lost")
            if in_air and act in (1, 2, 3, 5, 6):
                self._failsafe(act, "no GCS", kind="GCS lost")
        self._check_fence(now_s, in_air)  # [fence] uploaded geofence
        # Geofence: the footage edge, at 10 Hz.
        if self.inside is not None and now_s >= self._gf_next_check_s:
            self._gf_next_check_s = now_s + GEOFENCE_CHECK_S
            pos = self._pos
            inside = self._inside(float(pos[0]), float(pos[1]))
            if inside:
                self._last_inside_ned = pos.copy()
                self._gf_outside = False
            elif not self._gf_outside:
                self._gf_outside = True
                act = p.get_int("GF_ACTION")
                if in_air and act >= 1:
                    self._event(Severity.CRITICAL, "Geofence breached: outside footage")
                    if act == 2:
                        self._enter_mode(FlightMode.AUTO_LOITER, now_s)
                        if self._last_inside_ned is not None:
                            self._hold = self._last_inside_ned.copy()
                            self._hold[2] = pos[2]
                        self._event(Severity.WARNING, "Failsafe activated (geofence): switching to Hold")
                    elif act in (3, 5):
                        self._failsafe({3: 2, 5: 3}[act], "geofence", kind="Geofence")
                    elif act == 4:
                        self._failsafe(5, "geofence", kind="Geofence")

    def _check_fence(self, now_s: float, in_air: bool) -> None:
        """[fence] The uploaded geofence and GF_MAX_HOR/VER_DIST, at 10 Hz; GF_ACTION once per breach."""
        if now_s < self._fence_next_check_s:
            return
        self._fence_next_check_s = now_s + GEOFENCE_CHECK_S
        p = self.params
        limits = FenceLimits(p.get("GF_MAX_HOR_DIST"), p.get("GF_MAX_VER_DIST"))
        reason = breach_reason(self._fence, self._pos, self._home, limits)
        if reason is None:
            self._fence_breached = False
            return
        if self._fence_breached or not in_air:
            return
        self._fence_breached = True
        act = p.get_int("GF_ACTION")
        if act == GeofenceAction.NONE:
            return
        self._event(Severity.CRITICAL, f"Geofence breached: {reason}")
        if act == GeofenceAction.HOLD:
            self._failsafe(1, "geofence", kind="Geofence")
        elif act == GeofenceAction.RETURN:
            self._failsafe(2, "geofence", kind="Geofence")
        elif act == GeofenceAction.LAND:
            self._failsafe(3, "geofence", kind="Geofence")
        elif act == GeofenceAction.TERMINATE:
            self._failsafe(5, "geofence", kind="Geofence")

    # --- the control loop: called once per physics step -------------------------------
    def update(self, now_s: float, state: EavState) -> EavCommand:
        self._now_s = now_s
        first = self._state is None
        self._state = state
        if first:
            self._first_state(now_s, state)
        dt = state.dt_s
        eav = self.eav_params()
        self._update_gains()
        p = self.params

        self._update_landed(now_s, state)
        self._check_failsafes(now_s)
        self._auto_disarm(now_s)

        cmd: EavCommand
        if not self._armed:
            self._yaw_sp = state.yaw_rad
            self._ctrl.reset()
            cmd = EavCommand(0.0, 0.0, state.yaw_rad, 0.0)
        else:
            cmd = self._control(now_s, dt, state, eav)
            if not (math.isfinite(cmd.roll_rad) and math.isfinite(cmd.pitch_rad)
                    and math.isfinite(cmd.yaw_rad) and math.isfinite(cmd.thrust_n)):  # fmt: skip
                # Never hand the EAV a non-finite command: level, hover, reset the integrators.
                self._ctrl.reset()
                self._yaw_sp = state.yaw_rad if math.isfinite(state.yaw_rad) else 0.0
                cmd = EavCommand(0.0, 0.0, self._yaw_sp, eav.hover_thrust_n)
        if self._armed and self._trigger.update(
            float(state.pos_ned_m[0]), float(state.pos_ned_m[1])
        ):  # [fence]
            self._payload.append(PayloadAction("capture_once"))
        hover = eav.hover_thrust_n
        self._battery.update(dt, cmd.thrust_n / hover, self._armed, self._battery_cfg())
        self._check_battery(p)
        return cmd

    def _first_state(self, now_s: float, state: EavState) -> None:
        """Home from the first state; a vehicle that starts in the air (the paper's experiments start at altitude)
        starts armed in Hold there, with home on the ground below it."""
        self._yaw_sp = state.yaw_rad
        self._was_on_ground = bool(state.landed)
        if not self._home_set:
            self._home = np.array(state.pos_ned_m, dtype=np.float64)
            if not state.landed:
                self._home[2] = max(float(self._home[2]), self.eav.ground_z_ned_m)
        if not state.landed:
            self._armed = True
            self._has_flown = True
            self._mode = FlightMode.AUTO_LOITER
            self._hold = np.array(state.pos_ned_m, dtype=np.float64)
            self._hold_yaw = None
            self._event(Severity.INFO, "Air start: armed, holding position")

    def _check_battery(self, p: ParamStore) -> None:
        rem = self.battery_remaining
        level = 2 if rem <= p.get("BAT_CRIT_THR") else 1 if rem <= p.get("BAT_LOW_THR") else 0
        if level > self._bat_level:
            if level == 1:
                self._event(
                    Severity.WARNING, f"Low battery level! Return advised ({rem * 100:.0f}% remaining)"
                )
            else:
                self._event(
                    Severity.CRITICAL, f"Critical battery level! Land now ({rem * 100:.0f}% remaining)"
                )
        self._bat_level = level

    def _update_landed(self, now_s: float, state: EavState) -> None:
        on_ground = bool(state.landed)
        if on_ground and not self._was_on_ground:
            self._ground_since_s = now_s
            if self._armed:
                self._event(Severity.INFO, "Landing detected")
                if self._mode == FlightMode.AUTO_MISSION and self._mp.landing:
                    self._mission_item_done(now_s)
        elif not on_ground and self._was_on_ground and self._armed:
            self._has_flown = True
            self._event(Severity.INFO, "Takeoff detected")
        self._was_on_ground = on_ground
        if on_ground:
            self._landed_state = LandedState.ON_GROUND
        elif not self._armed:
            self._landed_state = LandedState.IN_AIR
        elif self._mode == FlightMode.AUTO_TAKEOFF or (
            self._mode == FlightMode.AUTO_MISSION and self._mp.climbing
        ):
            self._landed_state = LandedState.TAKEOFF
        elif (
            self._mode == FlightMode.AUTO_LAND
            or (self._mode == FlightMode.AUTO_RTL and self._rtl_phase == RtlPhase.LAND)
            or (self._mode == FlightMode.AUTO_MISSION and self._mp.landing)
        ):
            self._landed_state = LandedState.LANDING
        else:
            self._landed_state = LandedState.IN_AIR

    def _auto_disarm(self, now_s: float) -> None:
        if not (self._armed and self._on_ground):
            return
        limit = self.params.get("COM_DISARM_LAND") if self._has_flown else self.params.get("COM_DISARM_PRFLT")
        if limit < 0:
            return
        if now_s - self._ground_since_s >= limit:
            why = "landed" if self._has_flown else "no takeoff"
            self._do_disarm(f"Disarmed by auto disarm ({why})")

    # --- per-mode control -----------------------------------------------------------------
    def _limits(self, *, xy: float, up: float | None = None, down: float | None = None, auto: bool) -> Limits:
        p = self.params
        eav = self.eav_params()
        mg = eav.hover_thrust_n
        hover_norm = p.get("MPC_THR_HOVER")
        tilt = math.radians(p.get("MPC_TILTMAX_AIR"))
        return Limits(
            vel_xy_m_s=xy,
            vel_up_m_s=p.get("MPC_Z_VEL_MAX_UP") if up is None else up,
            vel_down_m_s=p.get("MPC_Z_VEL_MAX_DN") if down is None else down,
            tilt_max_rad=min(tilt, eav.max_tilt_rad),
            thrust_min_n=min(p.get("MPC_THR_MIN") / hover_norm, 0.9) * mg,
            thrust_max_n=eav.max_thrust_n,
            brake_acc_xy_m_s2=p.get("MPC_ACC_HOR") if auto else eav.gravity_m_s2 * math.tan(tilt) * 0.5,
            brake_acc_z_m_s2=p.get("MPC_ACC_DOWN_MAX") if auto else 5.0,
            slew_acc_xy_m_s2=p.get("MPC_ACC_HOR") if auto else math.inf,
            slew_acc_up_m_s2=p.get("MPC_ACC_UP_MAX") if auto else math.inf,
            slew_acc_down_m_s2=p.get("MPC_ACC_DOWN_MAX") if auto else math.inf,
        )

    def _airframe(self, eav: EavParams) -> Airframe:
        return Airframe(mass_kg=eav.mass_kg, drag_kd_n_s_m=eav.drag_kd_n_s_m, gravity_m_s2=eav.gravity_m_s2)

    def _thrust_from_norm(self, thrust_norm: float, eav: EavParams) -> float:
        """Offboard/STABILIZED normalised thrust -> N: MPC_THR_HOVER hovers (linear)."""
        return max(0.0, thrust_norm) / self.params.get("MPC_THR_HOVER") * eav.hover_thrust_n

    def _run_position(
        self, dt: float, state: EavState, sp: TrajectorySetpoint, limits: Limits, eav: EavParams,
        yaw_target: float | None, yaw_rate_max: float,
    ) -> EavCommand:  # fmt: skip
        if yaw_target is not None and math.isfinite(yaw_target):
            self._yaw_sp = slew_yaw(self._yaw_sp, yaw_target, yaw_rate_max, dt)
        on_ground = bool(state.landed)
        out: AttitudeThrust = self._ctrl.update(
            dt,
            np.asarray(state.pos_ned_m, dtype=np.float64),
            np.asarray(state.vel_ned_m_s, dtype=np.float64),
            sp,
            self._yaw_sp,
            limits,
            self._airframe(eav),
            integrate=not on_ground,
        )
        if on_ground:
            # On the ground: idle unless the controller asks for more than hover (take-off); no tilting.
            up = out.thrust_n * math.cos(out.roll_rad) * math.cos(out.pitch_rad)
            if up <= eav.hover_thrust_n * 1.02:
                self._ctrl.reset()
                return EavCommand(0.0, 0.0, self._yaw_sp, 0.0)
            return EavCommand(0.0, 0.0, self._yaw_sp, out.thrust_n)
        return EavCommand(out.roll_rad, out.pitch_rad, out.yaw_rad, out.thrust_n)

    def _yaw_rate_auto(self) -> float:
        return math.radians(self.params.get("MPC_YAWRAUTO_MAX"))

    def _control(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        mode = self._mode
        if mode == FlightMode.AUTO_TAKEOFF:
            return self._ctl_takeoff(now_s, dt, state, eav)
        if mode == FlightMode.AUTO_LAND:
            return self._ctl_land(dt, state, eav, self._land_xy)
        if mode == FlightMode.AUTO_RTL:
            return self._ctl_rtl(now_s, dt, state, eav)
        if mode == FlightMode.AUTO_MISSION:
            return self._ctl_mission(now_s, dt, state, eav)
        if mode == FlightMode.OFFBOARD:
            return self._ctl_offboard(now_s, dt, state, eav)
        if mode == FlightMode.ORBIT:  # [fence]
            return self._ctl_orbit(dt, state, eav)
        if mode in _MANUAL_MODES:
            return self._ctl_manual(now_s, dt, state, eav)
        return self._ctl_hold(dt, state, eav)

    def _ctl_hold(self, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        if self._hold is None:
            self._hold = np.array(state.pos_ned_m, dtype=np.float64)
        target = self._hold
        yaw_target = self._hold_yaw
        pos = state.pos_ned_m
        if yaw_target is None and math.hypot(target[0] - pos[0], target[1] - pos[1]) > 3.0:
            # Travelling to a reposition target: face it (PX4 heads toward DO_REPOSITION targets).
            yaw_target = math.atan2(target[1] - pos[1], target[0] - pos[0])
        sp = TrajectorySetpoint(pos_ned_m=(float(target[0]), float(target[1]), float(target[2])))
        return self._run_position(dt, state, sp, self._limits(xy=self._cruise(), auto=True), eav, yaw_target,
                                  self._yaw_rate_auto())  # fmt: skip

    def _ctl_orbit(self, dt: float, state: EavState, eav: EavParams) -> EavCommand:  # [fence]
        if self._orbit is None:
            self._orbit = apply_command(None, state.pos_ned_m, state.yaw_rad, math.nan, math.nan, math.nan, None,
                                        None, self.params.get("MC_ORBIT_RAD_MAX"))  # fmt: skip
        step = orbit_step(
            self._orbit, state.pos_ned_m, self._orbit_approach, self.params.get("NAV_MC_ALT_RAD")
        )
        self._orbit_approach = step.approaching
        xy = self.params.get("MPC_XY_CRUISE") if step.approaching else self.params.get("MPC_XY_VEL_MAX")
        limits = self._limits(xy=xy, auto=True)
        if (
            not step.approaching
        ):  # the circle's own acceleration feed-forward: no slew (it would count it twice)
            limits = replace(limits, slew_acc_xy_m_s2=math.inf)
        return self._run_position(dt, state, step.setpoint, limits, eav, step.yaw_rad, self._yaw_rate_auto())

    def _ctl_takeoff(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        if self._takeoff_target is None:
            self._start_takeoff(self.params.get("MIS_TAKEOFF_ALT"))
        assert self._takeoff_target is not None
        t = self._takeoff_target
        alt_err = abs(float(state.pos_ned_m[2]) - float(t[2]))
        if not state.landed and alt_err < min(self.params.get("NAV_MC_ALT_RAD"), 0.5):
            # Reached: PX4 switches to Hold at the take-off setpoint.
            self._mode = FlightMode.AUTO_LOITER
            self._hold = t.copy()
            self._hold_yaw = None
            self._speed_override = None
            self._takeoff_target = None
            self._event(Severity.INFO, "Takeoff altitude reached, holding")
            return self._ctl_hold(dt, state, eav)
        sp = TrajectorySetpoint(pos_ned_m=(float(t[0]), float(t[1]), float(t[2])))
        limits = self._limits(xy=self._cruise(), up=self.params.get("MPC_TKO_SPEED"), auto=True)
        return self._run_position(dt, state, sp, limits, eav, None, 0.0)

    def _land_speed(self, state: EavState, eav: EavParams) -> float:
        p = self.params
        alt = eav.ground_z_ned_m - float(state.pos_ned_m[2])
        v_land, v_fast = p.get("MPC_LAND_SPEED"), p.get("MPC_Z_VEL_MAX_DN")
        a1, a2 = p.get("MPC_LAND_ALT1"), p.get("MPC_LAND_ALT2")
        if alt <= a2:
            return v_land
        if alt >= a1 or a1 <= a2:
            return max(v_fast, v_land) if alt >= a1 else v_land
        return v_land + (max(v_fast, v_land) - v_land) * (alt - a2) / (a1 - a2)

    def _ctl_land(
        self, dt: float, state: EavState, eav: EavParams, xy: tuple[float, float] | None
    ) -> EavCommand:
        if xy is None:
            xy = (float(state.pos_ned_m[0]), float(state.pos_ned_m[1]))
            self._land_xy = xy
        v = self._land_speed(state, eav)
        sp = TrajectorySetpoint(pos_ned_m=(xy[0], xy[1], NAN), vel_ned_m_s=(NAN, NAN, v))
        limits = self._limits(xy=self._cruise(), down=max(v, 0.1), auto=True)
        return self._run_position(dt, state, sp, limits, eav, None, 0.0)

    def _ctl_rtl(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        p = self.params
        pos = np.asarray(state.pos_ned_m, dtype=np.float64)
        home = self._rtl_dest if self._rtl_dest is not None else self._home  # [fence] home or a rally point
        if self._hold is None:
            self._hold = pos.copy()
        if self._rtl_phase == RtlPhase.CLIMB:
            target = np.array([self._hold[0], self._hold[1], self._rtl_alt_down])
            if pos[2] - self._rtl_alt_down < 0.5:
                self._rtl_phase = RtlPhase.RETURN
        if self._rtl_phase == RtlPhase.RETURN:
            target = np.array([home[0], home[1], self._rtl_alt_down])
            if math.hypot(pos[0] - home[0], pos[1] - home[1]) < min(p.get("NAV_ACC_RAD"), 1.0):
                self._rtl_phase = RtlPhase.DESCEND
        if self._rtl_phase == RtlPhase.DESCEND:
            desc_down = float(max(self._rtl_alt_down, home[2] - p.get("RTL_DESCEND_ALT")))
            target = np.array([home[0], home[1], desc_down])
            if abs(pos[2] - desc_down) < 0.5:
                self._rtl_phase = RtlPhase.LOITER
                self._rtl_loiter_since = now_s
        if self._rtl_phase == RtlPhase.LOITER:
            delay = p.get("RTL_LAND_DELAY")
            target = np.array([home[0], home[1], max(self._rtl_alt_down, home[2] - p.get("RTL_DESCEND_ALT"))])
            if delay >= 0 and now_s - self._rtl_loiter_since >= delay:
                self._rtl_phase = RtlPhase.LAND
        if self._rtl_phase == RtlPhase.LAND:
            return self._ctl_land(dt, state, eav, (float(home[0]), float(home[1])))
        yaw_target = None
        if self._rtl_phase == RtlPhase.RETURN and math.hypot(home[0] - pos[0], home[1] - pos[1]) > 3.0:
            yaw_target = math.atan2(home[1] - pos[1], home[0] - pos[0])
        sp = TrajectorySetpoint(pos_ned_m=(float(target[0]), float(target[1]), float(target[2])))
        return self._run_position(dt, state, sp, self._limits(xy=self._cruise(), auto=True), eav, yaw_target,
                                  self._yaw_rate_auto())  # fmt: skip

    # --- mission ----------------------------------------------------------------------
    def _start_item(self, now_s: float) -> None:
        """Prepare the executor for self._mp.seq (targets resolved against the current position)."""
        mp = self._mp
        mp.arrived_s = None
        mp.landing = False
        mp.climbing = False
        mp.climb_xy = None
        mp.seq, mp.jumps_done, cycling = resolve_jumps(
            self._mission, mp.seq, mp.jumps_done
        )  # [fence] DO_JUMP
        if cycling:
            self._event(Severity.CRITICAL, cycling)
        if not (0 <= mp.seq < len(self._mission)):
            mp.finished = True
            return
        it = resolve_item(
            self._mission[mp.seq], float(self._home[2])
        )  # [fence] relative altitude: home of now
        pos = self._pos
        if it.command == MissionCommand.NAV_TAKEOFF:
            down = (
                it.down_m if math.isfinite(it.down_m) else self._home[2] - self.params.get("MIS_TAKEOFF_ALT")
            )
            mp.target = np.array([pos[0], pos[1], min(down, pos[2])])
            mp.climbing = True
        elif it.command == MissionCommand.NAV_LAND:
            n = it.north_m if math.isfinite(it.north_m) else pos[0]
            e = it.east_m if math.isfinite(it.east_m) else pos[1]
            mp.target = np.array([n, e, pos[2]])
        elif it.command in (MissionCommand.NAV_WAYPOINT, MissionCommand.NAV_LOITER_TIME):
            mp.target = np.array([it.north_m, it.east_m, it.down_m], dtype=np.float64)
            if self._on_ground and self._armed:
                mp.climbing = True  # implicit take-off first
        elif it.command == MissionCommand.NAV_DELAY:  # [fence] wait param1 s where the last item left us
            mp.target = mp.target.copy() if mp.target is not None else pos.copy()
        else:
            mp.target = None

    def _mission_item_done(self, now_s: float) -> None:
        mp = self._mp
        it = self._mission[mp.seq]
        self._event(Severity.INFO, f"Mission item {mp.seq} reached", reached=mp.seq)
        if it.command == MissionCommand.NAV_LAND:
            mp.landing = False
            mp.finished = True
            self._event(Severity.INFO, "Mission finished, landed")
            return
        if it.command == MissionCommand.NAV_RETURN_TO_LAUNCH:
            mp.finished = True
            self._enter_mode(FlightMode.AUTO_RTL, now_s)
            return
        if not it.autocontinue:
            mp.finished = True
            self._event(Severity.INFO, "Mission paused (autocontinue off), holding")
            return
        last_target = mp.target
        if mp.seq + 1 >= len(self._mission):
            mp.finished = True
            mp.target = last_target
            self._event(Severity.INFO, "Mission finished, loitering")
            return
        mp.seq += 1
        self._start_item(now_s)
        if mp.target is None:
            mp.target = last_target
        if mp.finished:  # [fence] a DO_JUMP chain ended the mission
            self._event(Severity.INFO, "Mission finished, loitering")

    def _ctl_mission(
        self, now_s: float, dt: float, state: EavState, eav: EavParams, depth: int = 0
    ) -> EavCommand:
        p = self.params
        mp = self._mp
        pos = np.asarray(state.pos_ned_m, dtype=np.float64)
        # Non-navigation items complete at once (bounded loop: at most one pass over the mission).
        for _ in range(len(self._mission) + 1):
            if mp.finished or not (0 <= mp.seq < len(self._mission)):
                break
            it = self._mission[mp.seq]
            if it.command == MissionCommand.DO_CHANGE_SPEED:
                if it.param2 > 0 and math.isfinite(it.param2):
                    self._cruise_override = min(it.param2, p.get("MPC_XY_VEL_MAX"))
                elif it.param2 == -2.0:
                    self._cruise_override = None
                self._mission_item_done(now_s)
                continue
            if it.command == MissionCommand.NAV_RETURN_TO_LAUNCH:
                self._mission_item_done(now_s)
                return self._ctl_rtl(now_s, dt, state, eav)
            if it.command not in NAV_COMMANDS:  # [fence] camera / gimbal / other DO items: at once
                self._do_item(it, pos)
                self._mission_item_done(now_s)
                continue
            break
        if self._mode != FlightMode.AUTO_MISSION:
            return self._control(now_s, dt, state, eav)
        if mp.finished:
            if mp.target is None:
                mp.target = pos.copy()
            if (
                self._mission
                and self._mission[min(mp.seq, len(self._mission) - 1)].command == MissionCommand.NAV_LAND
            ):
                if self._on_ground:
                    return EavCommand(0.0, 0.0, self._yaw_sp, 0.0)
                return self._ctl_land(dt, state, eav, (float(mp.target[0]), float(mp.target[1])))
            sp = TrajectorySetpoint(pos_ned_m=(float(mp.target[0]), float(mp.target[1]), float(mp.target[2])))
            return self._run_position(
                dt, state, sp, self._limits(xy=self._cruise(), auto=True), eav, None, 0.0
            )
        if not self._armed or mp.target is None:
            return EavCommand(0.0, 0.0, self._yaw_sp, 0.0)
        it = self._mission[mp.seq]
        if depth > 4:
            # Several items completed in this step already: fly toward the current one, go on next step.
            sp = TrajectorySetpoint(pos_ned_m=(float(mp.target[0]), float(mp.target[1]), float(mp.target[2])))
            return self._run_position(
                dt, state, sp, self._limits(xy=self._cruise(), auto=True), eav, None, 0.0
            )
        target = mp.target
        limits = self._limits(xy=self._cruise(), auto=True)
        alt_rad = p.get("NAV_MC_ALT_RAD")
        # Take-off (item or implicit before the first waypoint): vertical climb at the lift-off position.
        if mp.climbing:
            if it.command == MissionCommand.NAV_TAKEOFF:
                climb_down = float(target[2])
            else:
                climb_down = float(min(target[2], self._home[2] - p.get("MIS_TAKEOFF_ALT")))
            if mp.climb_xy is None or state.landed:
                mp.climb_xy = (float(pos[0]), float(pos[1]))
            if state.landed or abs(pos[2] - climb_down) >= alt_rad:
                sp = TrajectorySetpoint(pos_ned_m=(mp.climb_xy[0], mp.climb_xy[1], climb_down))
                up_lim = self._limits(xy=self._cruise(), up=p.get("MPC_TKO_SPEED"), auto=True)
                return self._run_position(dt, state, sp, up_lim, eav, None, 0.0)
            mp.climbing = False
            if it.command == MissionCommand.NAV_TAKEOFF:
                mp.target = np.array([mp.climb_xy[0], mp.climb_xy[1], climb_down])
                self._mission_item_done(now_s)
                return self._ctl_mission(now_s, dt, state, eav, depth + 1)
        if it.command == MissionCommand.NAV_LAND:
            dist = math.hypot(target[0] - pos[0], target[1] - pos[1])
            if not mp.landing and dist < min(p.get("NAV_ACC_RAD"), 1.0):
                mp.landing = True
            if mp.landing:
                if state.landed:
                    return EavCommand(0.0, 0.0, self._yaw_sp, 0.0)
                return self._ctl_land(dt, state, eav, (float(target[0]), float(target[1])))
            sp = TrajectorySetpoint(pos_ned_m=(float(target[0]), float(target[1]), float(target[2])))
            return self._run_position(dt, state, sp, limits, eav, self._mission_yaw(it, pos, target),
                                      self._yaw_rate_auto())  # fmt: skip
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
                self._mission_item_done(now_s)
                if self._mode != FlightMode.AUTO_MISSION:
                    return self._control(now_s, dt, state, eav)
                if not mp.finished:
                    return self._ctl_mission(now_s, dt, state, eav, depth + 1)
        tgt = mp.target if mp.target is not None else target
        sp = TrajectorySetpoint(pos_ned_m=(float(tgt[0]), float(tgt[1]), float(tgt[2])))
        return self._run_position(dt, state, sp, limits, eav, self._mission_yaw(it, pos, tgt),
                                  self._yaw_rate_auto())  # fmt: skip

    def _do_item(self, it: MissionItem, pos: Vec3) -> None:  # [fence]
        eff = item_effect(it)
        self._payload.extend(eff.actions)
        if eff.gimbal_deg is not None:
            self._gimbal_deg = eff.gimbal_deg
        if eff.trigger_dist_m is not None:
            self._trigger.set(eff.trigger_dist_m, float(pos[0]), float(pos[1]))
        if eff.note:
            self._event(Severity.INFO, eff.note)

    def _mission_yaw(self, it: MissionItem, pos: Vec3, target: Vec3) -> float | None:
        return mission_yaw(it, pos, target, self._home, self.params.get_int("MIS_YAWMODE"))

    # --- offboard ---------------------------------------------------------------------
    def _ctl_offboard(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        p = self.params
        if self._offb_kind == OffboardKind.ATTITUDE:
            r, pt, y, t = self._offb_att
            self._yaw_sp = y
            return EavCommand(r, pt, y, self._thrust_from_norm(t, eav))
        if self._offb_kind == OffboardKind.RATES:
            if self._offb_rate_att is None:
                self._offb_rate_att = np.array(state.att_rpy_rad, dtype=np.float64)
            a = self._offb_rate_att
            dr, dp, dy = body_rates_to_euler_rates(float(a[0]), float(a[1]), self._offb_rates)
            lim = eav.max_tilt_rad
            a[0] = min(max(a[0] + dr * dt, -lim), lim)
            a[1] = min(max(a[1] + dp * dt, -lim), lim)
            a[2] = wrap_pi(float(a[2] + dy * dt))
            self._yaw_sp = float(a[2])
            return EavCommand(
                float(a[0]), float(a[1]), float(a[2]), self._thrust_from_norm(self._offb_att[3], eav)
            )
        sp = self._offb_traj
        if self._offb_yaw is not None:
            yaw_target: float | None = self._offb_yaw
        else:
            yaw_target = None
            self._yaw_sp = wrap_pi(self._yaw_sp + self._offb_yaw_rate * dt)
        limits = self._limits(xy=p.get("MPC_XY_VEL_MAX"), auto=False)
        return self._run_position(dt, state, sp, limits, eav, yaw_target, math.radians(200.0))

    # --- manual (MANUAL_CONTROL as QGC's joystick) ---------------------------------------
    def _ctl_manual(self, now_s: float, dt: float, state: EavState, eav: EavParams) -> EavCommand:
        p = self.params
        m = self._manual if self._manual is not None else ManualInput(0.0, 0.0, 0.5, 0.0)
        x = deadzone(m.x, MANUAL_DEADZONE)
        y = deadzone(m.y, MANUAL_DEADZONE)
        r = deadzone(m.r, MANUAL_DEADZONE)
        self._yaw_sp = wrap_pi(self._yaw_sp + r * math.radians(p.get("MPC_MAN_Y_MAX")) * dt)
        pos = np.asarray(state.pos_ned_m, dtype=np.float64)
        vel = np.asarray(state.vel_ned_m_s, dtype=np.float64)
        mode = self._mode
        if mode in (FlightMode.MANUAL, FlightMode.STABILIZED):
            tilt = math.radians(p.get("MPC_MAN_TILT_MAX"))
            hover = p.get("MPC_THR_HOVER")
            thrust = self._thrust_from_norm(throttle_to_thrust_norm(m.z, hover), eav)
            if state.landed and thrust <= eav.hover_thrust_n:
                return EavCommand(0.0, 0.0, self._yaw_sp, thrust)
            return EavCommand(y * tilt, -x * tilt, self._yaw_sp, thrust)
        # Vertical: throttle = climb rate, centred = altitude hold.
        climb = deadzone((m.z - 0.5) * 2.0, THROTTLE_DEADZONE)
        if climb == 0.0:
            if self._man_hold_z is None and abs(vel[2]) < HOLD_LOCK_SPEED_M_S:
                self._man_hold_z = float(pos[2])
            z_pos, z_vel = (self._man_hold_z, NAN) if self._man_hold_z is not None else (NAN, 0.0)
        else:
            self._man_hold_z = None
            z_pos = NAN
            z_vel = -climb * p.get("MPC_Z_VEL_MAX_UP") if climb > 0 else -climb * p.get("MPC_Z_VEL_MAX_DN")
        if state.landed and climb <= 0.0:
            self._man_hold_xy = None
            self._man_hold_z = None
            self._ctrl.reset()
            return EavCommand(0.0, 0.0, self._yaw_sp, 0.0)
        if mode == FlightMode.ALTCTL:
            sp = TrajectorySetpoint(pos_ned_m=(NAN, NAN, z_pos), vel_ned_m_s=(NAN, NAN, z_vel),
                                    acc_ned_m_s2=(0.0, 0.0, NAN))  # fmt: skip
            cmd = self._run_position(dt, state, sp, self._limits(xy=p.get("MPC_VEL_MANUAL"), auto=False), eav,
                                     None, 0.0)  # fmt: skip
            tilt = math.radians(p.get("MPC_MAN_TILT_MAX"))
            roll, pitch = y * tilt, -x * tilt
            up = cmd.thrust_n * math.cos(cmd.roll_rad) * math.cos(cmd.pitch_rad)
            thrust = up / max(0.2, math.cos(roll) * math.cos(pitch))
            return EavCommand(roll, pitch, self._yaw_sp, thrust)
        # POSCTL: sticks = velocity in the heading frame, centred = position hold.
        vmax = p.get("MPC_VEL_MANUAL")
        if x == 0.0 and y == 0.0:
            if self._man_hold_xy is None and math.hypot(vel[0], vel[1]) < HOLD_LOCK_SPEED_M_S:
                self._man_hold_xy = (float(pos[0]), float(pos[1]))
            if self._man_hold_xy is not None:
                xy_pos, xy_vel = self._man_hold_xy, (NAN, NAN)
            else:
                xy_pos, xy_vel = (NAN, NAN), (0.0, 0.0)
        else:
            self._man_hold_xy = None
            xy_pos = (NAN, NAN)
            xy_vel = rot_yaw(self._yaw_sp, (x * vmax, y * vmax))
        sp = TrajectorySetpoint(
            pos_ned_m=(xy_pos[0], xy_pos[1], z_pos), vel_ned_m_s=(xy_vel[0], xy_vel[1], z_vel)
        )
        return self._run_position(dt, state, sp, self._limits(xy=vmax, auto=False), eav, None, 0.0)
