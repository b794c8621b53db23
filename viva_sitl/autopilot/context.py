"""The state every part of the autopilot shares, in one explicit object (PX4 shares it through uORB topics).

Commander, failsafe evaluation, land detector and the flight tasks read and write only what is here (plus their own
private state); nothing else is shared. Also the parameter-derived caches (airframe with SIM_*, controller gains,
battery configuration), rebuilt when the ParamStore revision changes.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from viva_sitl.autopilot.battery import Battery, BatteryConfig
from viva_sitl.autopilot.control import Airframe, Gains, PositionController, TrajectorySetpoint
from viva_sitl.autopilot.failsafe import FLOWN_ACTIONS, FailsafeAction, from_gf_act_param
from viva_sitl.autopilot.geofence import Geofence, RallyPoint
from viva_sitl.autopilot.params import SIM_EAV_PARAMS, ParamStore
from viva_sitl.autopilot.types import Event, FlightMode, Severity
from viva_sitl.dynamics import EavParams, EavState

# (north_m, east_m) -> True when the camera at that ground point still sees footage (geofence)
InsideFn = Callable[[float, float], bool]
Vec3 = NDArray[np.float64]


@dataclass(eq=False)
class FlightContext:
    """Vehicle status (armed, mode, home), the latest physics state, outgoing events and the shared controller."""

    params: ParamStore
    base_eav: EavParams  # the airframe as configured; eav_params() applies the SIM_* parameters on top
    inside: InsideFn | None = None
    now_s: float = 0.0
    state: EavState | None = None  # the latest physics state (None before the first update)
    armed: bool = False
    mode: FlightMode = FlightMode.AUTO_LOITER
    home: Vec3 = field(default_factory=lambda: np.zeros(3))
    home_set: bool = False
    events: list[Event] = field(default_factory=list)
    ctrl: PositionController = field(default_factory=PositionController)  # PX4's position + velocity loops
    yaw_sp: float = 0.0  # the yaw setpoint every task slews
    cruise_override: float | None = None  # DO_CHANGE_SPEED (commands and mission items)
    speed_override: float | None = None  # DO_REPOSITION ground speed for the current hold target
    battery: Battery = field(default_factory=Battery)
    geofence: Geofence = field(
        default_factory=Geofence
    )  # the uploaded fence (MISSION_TYPE_FENCE); empty = none
    rally: tuple[RallyPoint, ...] = ()  # the uploaded rally points (MISSION_TYPE_RALLY)
    # injected sensor failures (autopilot/failures.py), as PX4's failsafe flags: False when the global position is
    # invalid (GPS lost past the dead-reckoning time); the arming refusals the failed sensors cause
    position_valid: bool = True
    sensor_faults: tuple[str, ...] = ()
    calibrating: bool = False  # a sensor calibration runs (mavlink/calibration.py): arming is refused, as PX4
    _eav_rev: int = -1
    _eav_cached: EavParams | None = None
    _bat_rev: int = -1
    _bat_cfg: BatteryConfig = field(default_factory=BatteryConfig)
    _gains_rev: int = -1
    # tasks/common.limits' last (key, airframe, Limits): it runs at 250 Hz
    _limits_cache: tuple[object, EavParams, object] | None = field(default=None, repr=False, compare=False)
    _airframe_cache: tuple[EavParams, Airframe] | None = field(default=None, repr=False, compare=False)
    # tasks/common.position_setpoint / descent_setpoint: kind -> (the inputs' bits, TrajectorySetpoint)
    _sp_cache: dict[str, tuple[bytes, TrajectorySetpoint]] = field(
        default_factory=dict, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        self.home = np.array([0.0, 0.0, float(self.base_eav.ground_z_ned_m)])
        self._eav_cached = self.base_eav

    # --- the latest state -----------------------------------------------------------------
    @property
    def pos(self) -> Vec3:
        if self.state is None:
            return self.home.copy()
        return np.array(self.state.pos_ned_m, dtype=np.float64)

    @property
    def vel(self) -> Vec3:
        if self.state is None:
            return np.zeros(3)
        return np.array(self.state.vel_ned_m_s, dtype=np.float64)

    @property
    def yaw(self) -> float:
        return 0.0 if self.state is None else self.state.yaw_rad

    @property
    def on_ground(self) -> bool:
        return True if self.state is None else bool(self.state.landed)

    def event(self, severity: Severity, text: str, reached: int | None = None) -> None:
        self.events.append(Event(self.now_s, severity, text, mission_item_reached=reached))

    def is_inside(self, north_m: float, east_m: float) -> bool:
        """The geofence test; no fence = inside everywhere; a faulty callback counts as outside (never raises)."""
        if self.inside is None:
            return True
        try:
            return bool(self.inside(north_m, east_m))
        except Exception:
            return False

    def footage_action(self) -> FailsafeAction:
        """SIM_FTG_FENCE: what the footage edge does (GF_ACTION's codes; 0 off, 1 warn, 2 Hold ... 5 Land; NONE
        without a footage test)."""
        if self.inside is None:
            return FailsafeAction.NONE
        return from_gf_act_param(self.params.get_int("SIM_FTG_FENCE"))

    def footage_ok(self, north_m: float, east_m: float) -> bool:
        """False only where the footage edge is a hard fence (SIM_FTG_FENCE >= 2, Hold or stricter) and the
        camera at that point would not see footage: arming, repositioning and mission upload are refused there."""
        return self.footage_action() not in FLOWN_ACTIONS or self.is_inside(north_m, east_m)

    def fence_ok(self, north_m: float, east_m: float) -> bool:
        """Inside the uploaded geofence (no fence: everywhere)."""
        return self.geofence.empty or self.geofence.contains(north_m, east_m)

    def cruise(self) -> float:
        if self.speed_override is not None and self.mode == FlightMode.AUTO_LOITER:
            return self.speed_override
        if self.cruise_override is not None:
            return self.cruise_override
        return self.params.get("MPC_XY_CRUISE")

    def braking_point(self) -> Vec3:
        """Where the vehicle stops at MPC_ACC_HOR / MPC_ACC_DOWN_MAX (PX4 holds there, not where it was)."""
        pos, vel = self.pos, self.vel
        a_xy = self.params.get("MPC_ACC_HOR")
        a_z = self.params.get("MPC_ACC_DOWN_MAX")
        out = pos.copy()
        out[:2] += vel[:2] * np.hypot(vel[0], vel[1]) / (2.0 * a_xy)
        out[2] += vel[2] * abs(vel[2]) / (2.0 * a_z)
        return out

    # --- parameter-derived caches -----------------------------------------------------------
    def sync_sim_params_from(self, eav: EavParams) -> None:
        """SIM_* parameters not set explicitly (config file, PARAM_SET) take the configured airframe's values."""
        values = {
            "SIM_MASS": eav.mass_kg,
            "SIM_DRAG": eav.drag_kd_n_s_m,
            "SIM_WIND_N": eav.wind.mean_wind_ned_m_s[0],
            "SIM_WIND_E": eav.wind.mean_wind_ned_m_s[1],
            "SIM_WIND_D": eav.wind.mean_wind_ned_m_s[2],
            "SIM_GUST_STD": eav.wind.gust_std_m_s,
            "SIM_ATT_TAU": eav.attitude_tau_s,
            "SIM_YAW_TAU": eav.yaw_tau_s,
            "SIM_RP_RATE_MAX": eav.max_roll_pitch_rate_deg_s,
            "SIM_YAW_RATE_MAX": eav.max_yaw_rate_deg_s,
        }
        for name in SIM_EAV_PARAMS:
            if not self.params.is_modified(name):
                spec = self.params.spec(name)
                self.params.adopt(name, min(max(values[name], spec.min), spec.max))

    def eav_params(self) -> EavParams:
        """The airframe with SIM_* applied (cached on the parameter revision; the same object while unchanged).

        SIM_MASS scales max_thrust_n too (same thrust-to-weight ratio as configured); SIM_ATT_TAU, SIM_YAW_TAU,
        SIM_RP_RATE_MAX, SIM_YAW_RATE_MAX set the attitude response; dt, tilt limit and ground stay as configured.
        """
        cached = self._eav_cached
        assert cached is not None
        if self.params.revision != self._eav_rev:
            p, base = self.params, self.base_eav
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
                max_thrust_n=base.max_thrust_n
                if mass == base.mass_kg
                else base.max_thrust_n * mass / base.mass_kg,
                wind=wind,
                attitude_tau_s=p.get("SIM_ATT_TAU"),
                yaw_tau_s=p.get("SIM_YAW_TAU"),
                max_roll_pitch_rate_deg_s=p.get("SIM_RP_RATE_MAX"),
                max_yaw_rate_deg_s=p.get("SIM_YAW_RATE_MAX"),
            )
            if new != cached:
                self._eav_cached = cached = new
            self._eav_rev = p.revision
        return cached

    def battery_cfg(self) -> BatteryConfig:
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

    @property
    def battery_remaining(self) -> float:  # 0..1
        return self.battery.remaining(self.battery_cfg())

    def update_gains(self) -> None:
        if self.params.revision != self._gains_rev:
            p = self.params
            self.ctrl.gains = Gains(
                pos_xy_p=p.get("MPC_XY_P"),
                pos_z_p=p.get("MPC_Z_P"),
                vel_xy_p=p.get("MPC_XY_VEL_P_ACC"),
                vel_xy_i=p.get("MPC_XY_VEL_I_ACC"),
                vel_z_p=p.get("MPC_Z_VEL_P_ACC"),
                vel_z_i=p.get("MPC_Z_VEL_I_ACC"),
            )
            self._gains_rev = p.revision
