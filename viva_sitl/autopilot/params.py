"""PX4-named parameters: names, types, defaults, ranges and descriptions. CONTRACT for viva_sitl/mavlink/params.py.

Values follow PX4 v1.14 defaults unless noted. `set` never clamps: a value that is NaN/inf, out of range or (for an
INT32 parameter) not integral raises ValueError and leaves the stored value unchanged, so a client always reads back
what the vehicle really uses.

SIM_* parameters describe the EAV airframe (mass, drag, wind). The autopilot turns them into an EavParams with
`Autopilot.eav_params()`, which the app polls after each batch of physics steps (see that method).
"""

from __future__ import annotations

import enum
import math
from collections.abc import Iterable
from dataclasses import dataclass


class ParamType(enum.IntEnum):
    """MAV_PARAM_TYPE used by PX4: INT32 (6) and REAL32 (9)."""

    INT32 = 6
    REAL32 = 9


@dataclass(frozen=True)
class ParamSpec:
    name: str  # <= 16 chars, PX4 name
    type: ParamType
    default: float
    min: float
    max: float
    description: str

    def __post_init__(self) -> None:
        if not (0 < len(self.name) <= 16) or not self.name.isascii():
            raise ValueError(f"parameter name must be 1..16 ASCII chars: {self.name!r}")
        if not (self.min <= self.default <= self.max):
            raise ValueError(f"{self.name}: default {self.default} outside [{self.min}, {self.max}]")

    def check(self, value: float) -> float:
        """The value as stored (float; integral for INT32) or ValueError with the reason."""
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ValueError(f"{self.name}: not a number: {value!r}") from None
        if not math.isfinite(v):
            raise ValueError(f"{self.name}: value must be finite, got {v}")
        if self.type == ParamType.INT32 and v != int(v):
            raise ValueError(f"{self.name}: integer parameter, got {v}")
        if not (self.min <= v <= self.max):
            raise ValueError(f"{self.name}: {v:g} outside [{self.min:g}, {self.max:g}]")
        return v


_I, _F = ParamType.INT32, ParamType.REAL32

# The table (order = param_index). (name, type, default, min, max, description)
_TABLE: tuple[tuple[str, ParamType, float, float, float, str], ...] = (
    # --- mission / takeoff
    ("MIS_TAKEOFF_ALT", _F, 2.5, 0.0, 100.0, "Take-off altitude above home (m)"),
    ("MIS_DIST_1WP", _F, 900.0, 0.0, 10000.0, "Max distance home -> first waypoint (m), 0 = off"),
    (
        "MIS_YAWMODE",
        _I,
        1,
        0,
        4,
        "Mission yaw: 0 as set by item (param4), 1 towards waypoint, 2 home, 3 away",
    ),
    ("NAV_ACC_RAD", _F, 2.0, 0.05, 200.0, "Default waypoint acceptance radius (m)"),
    ("NAV_MC_ALT_RAD", _F, 0.8, 0.05, 200.0, "Waypoint altitude acceptance (m)"),
    # --- multicopter position control
    ("MPC_XY_CRUISE", _F, 5.0, 0.5, 20.0, "Horizontal cruise speed in auto modes (m/s)"),
    (
        "MPC_XY_VEL_MAX",
        _F,
        12.0,
        0.5,
        20.0,
        "Max horizontal speed (offboard, clamp of DO_CHANGE_SPEED) (m/s)",
    ),
    ("MPC_VEL_MANUAL", _F, 10.0, 0.5, 20.0, "Max horizontal stick speed in POSCTL (m/s)"),
    ("MPC_Z_VEL_MAX_UP", _F, 3.0, 0.5, 8.0, "Max ascent speed (m/s)"),
    ("MPC_Z_VEL_MAX_DN", _F, 1.5, 0.5, 4.0, "Max descent speed (m/s)"),
    ("MPC_TKO_SPEED", _F, 1.5, 1.0, 5.0, "Take-off climb speed (m/s)"),
    ("MPC_LAND_SPEED", _F, 0.7, 0.3, 2.0, "Landing descent speed below MPC_LAND_ALT2 (m/s)"),
    ("MPC_LAND_ALT1", _F, 10.0, 0.0, 122.0, "Above this altitude land descends at MPC_Z_VEL_MAX_DN (m)"),
    ("MPC_LAND_ALT2", _F, 5.0, 0.0, 122.0, "Below this altitude land descends at MPC_LAND_SPEED (m)"),
    ("MPC_THR_HOVER", _F, 0.5, 0.1, 0.8, "Normalised thrust that hovers (offboard attitude, STABILIZED)"),
    ("MPC_THR_MIN", _F, 0.12, 0.05, 1.0, "Min collective thrust in controlled flight (normalised)"),
    ("MPC_TILTMAX_AIR", _F, 45.0, 20.0, 89.0, "Max tilt in controlled flight (deg)"),
    ("MPC_MAN_TILT_MAX", _F, 35.0, 1.0, 85.0, "Max tilt from sticks in ALTCTL/STABILIZED (deg)"),
    ("MPC_MAN_Y_MAX", _F, 150.0, 0.0, 400.0, "Max yaw rate from sticks (deg/s)"),
    ("MPC_YAWRAUTO_MAX", _F, 45.0, 0.0, 360.0, "Max yaw rate in auto/offboard position modes (deg/s)"),
    ("MPC_ACC_HOR", _F, 3.0, 2.0, 15.0, "Horizontal acceleration of auto trajectories (m/s^2)"),
    ("MPC_ACC_UP_MAX", _F, 4.0, 1.0, 15.0, "Upward acceleration of auto trajectories (m/s^2)"),
    ("MPC_ACC_DOWN_MAX", _F, 3.0, 1.0, 15.0, "Downward acceleration of auto trajectories (m/s^2)"),
    ("MPC_XY_P", _F, 0.95, 0.0, 2.0, "Horizontal position gain (1/s)"),
    ("MPC_Z_P", _F, 1.0, 0.0, 2.0, "Vertical position gain (1/s)"),
    ("MPC_XY_VEL_P_ACC", _F, 2.4, 1.2, 5.0, "Horizontal velocity P gain (1/s)"),
    ("MPC_XY_VEL_I_ACC", _F, 0.4, 0.0, 60.0, "Horizontal velocity I gain (1/s^2)"),
    ("MPC_Z_VEL_P_ACC", _F, 4.0, 2.0, 15.0, "Vertical velocity P gain (1/s)"),
    ("MPC_Z_VEL_I_ACC", _F, 2.0, 0.2, 3.0, "Vertical velocity I gain (1/s^2)"),
    # --- return
    ("RTL_RETURN_ALT", _F, 60.0, 0.0, 150.0, "Return altitude above home (m)"),
    ("RTL_DESCEND_ALT", _F, 30.0, 2.0, 100.0, "Altitude above home to descend to before landing (m)"),
    ("RTL_LAND_DELAY", _F, 0.0, -1.0, 300.0, "Hover time at RTL_DESCEND_ALT before landing (s), -1 = stay"),
    # --- commander
    ("COM_OF_LOSS_T", _F, 1.0, 0.0, 60.0, "Offboard setpoint timeout before failsafe (s)"),
    (
        "COM_OBL_RC_ACT",
        _I,
        0,
        0,
        7,
        "Offboard loss action: 0 Position, 1 Altitude, 2 Manual, 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm "
        "(0-2 need RC: without it they fall back to Hold, as PX4 v1.14)",
    ),
    ("COM_DL_LOSS_T", _I, 10, 5, 300, "GCS heartbeat timeout before NAV_DLL_ACT (s)"),
    (
        "NAV_DLL_ACT",
        _I,
        0,
        0,
        6,
        "GCS link loss action: 0 off, 1 Hold, 2 Return, 3 Land, 5 Terminate, 6 Lockdown",
    ),
    ("COM_RC_LOSS_T", _F, 0.5, 0.0, 35.0, "MANUAL_CONTROL timeout (s)"),
    (
        "NAV_RCL_ACT",
        _I,
        2,
        0,
        6,
        "Manual control loss action in manual modes: 1 Hold, 2 Return, 3 Land, 5/6 Term.",
    ),
    ("COM_DISARM_LAND", _F, 2.0, -1.0, 20.0, "Auto-disarm this long after landing (s), < 0 = off"),
    (
        "COM_DISARM_PRFLT",
        _F,
        10.0,
        -1.0,
        20.0,
        "Auto-disarm if no take-off this long after arming (s), < 0 = off",
    ),
    (
        "COM_ARM_WO_GPS",
        _I,
        1,
        0,
        2,
        "Allow arming without global position (informational: the sim always has it)",
    ),
    # --- geofence (the footage edge)
    (
        "GF_ACTION",
        _I,
        2,
        0,
        5,
        "Geofence (and footage-edge) action: 0 none, 1 warning, 2 Hold, 3 Return, 4 Terminate, 5 Land",
    ),
    ("GF_MAX_HOR_DIST", _F, 0.0, 0.0, 10000.0, "Max horizontal distance from home (m), 0 = off"),
    ("GF_MAX_VER_DIST", _F, 0.0, 0.0, 10000.0, "Max height above home (m), 0 = off"),
    ("MC_ORBIT_RAD_MAX", _F, 1000.0, 1.0, 10000.0, "Maximum radius of an orbit (m)"),
    # --- battery
    ("BAT1_CAPACITY", _F, 5000.0, 100.0, 100000.0, "Battery capacity (mAh)"),
    ("BAT1_N_CELLS", _I, 4, 1, 14, "Cells in series"),
    ("BAT1_V_CHARGED", _F, 4.05, 3.0, 5.0, "Full cell voltage (V)"),
    ("BAT1_V_EMPTY", _F, 3.6, 2.5, 4.2, "Empty cell voltage (V)"),
    ("BAT1_R_INTERNAL", _F, 0.005, 0.0, 0.2, "Internal resistance per cell (Ohm), voltage sag with current"),
    ("BAT_LOW_THR", _F, 0.15, 0.12, 0.5, "Low battery warning level (remaining, 0..1)"),
    ("BAT_CRIT_THR", _F, 0.07, 0.05, 0.5, "Critical battery level (remaining, 0..1)"),
    (
        "SIM_BAT_HOV_A",
        _F,
        10.0,
        0.0,
        200.0,
        "Sim: battery current at hover thrust (A), proportional to thrust",
    ),
    ("SIM_BAT_MIN_PCT", _F, 50.0, 0.0, 100.0, "Sim: battery never drains below this (%), as PX4 SITL"),
    # --- the EAV airframe (see Autopilot.eav_params)
    ("SIM_MASS", _F, 0.468, 0.01, 100.0, "Sim: EAV mass m (kg)"),
    ("SIM_DRAG", _F, 0.15, 0.0, 100.0, "Sim: EAV linear drag k_d (N s/m)"),
    ("SIM_WIND_N", _F, 0.0, -50.0, 50.0, "Sim: mean wind north (m/s)"),
    ("SIM_WIND_E", _F, 0.0, -50.0, 50.0, "Sim: mean wind east (m/s)"),
    ("SIM_WIND_D", _F, 0.0, -20.0, 20.0, "Sim: mean wind down (m/s)"),
    ("SIM_GUST_STD", _F, 0.0, 0.0, 20.0, "Sim: gust std-dev per axis (m/s)"),
)

DEFAULT_SPECS: tuple[ParamSpec, ...] = tuple(ParamSpec(*row) for row in _TABLE)

# The SIM_* parameters that define the EAV (Autopilot.eav_params reads them).
SIM_EAV_PARAMS: tuple[str, ...] = (
    "SIM_MASS",
    "SIM_DRAG",
    "SIM_WIND_N",
    "SIM_WIND_E",
    "SIM_WIND_D",
    "SIM_GUST_STD",
)


class ParamStore:
    """Ordered PX4 parameter table. get/set by name; set validates type and range (rejects, never clamps)."""

    def __init__(self, specs: Iterable[ParamSpec] = DEFAULT_SPECS) -> None:
        self._specs: dict[str, ParamSpec] = {}
        for s in specs:
            if s.name in self._specs:
                raise ValueError(f"duplicate parameter {s.name}")
            self._specs[s.name] = s
        self._names = list(self._specs)
        self._values: dict[str, float] = {n: float(s.default) for n, s in self._specs.items()}
        self._modified: set[str] = set()
        self._revision = 0

    def names(self) -> list[str]:
        """Stable order -> param_index."""
        return list(self._names)

    def __contains__(self, name: object) -> bool:
        return name in self._specs

    def __len__(self) -> int:
        return len(self._names)

    def spec(self, name: str) -> ParamSpec:
        """KeyError for unknown names."""
        try:
            return self._specs[name]
        except KeyError:
            raise KeyError(f"unknown parameter {name!r}") from None

    def index(self, name: str) -> int:
        self.spec(name)
        return self._names.index(name)

    def get(self, name: str) -> float:
        self.spec(name)
        return self._values[name]

    def get_int(self, name: str) -> int:
        return int(self.get(name))

    def set(self, name: str, value: float) -> None:
        """KeyError unknown, ValueError out of range / NaN / non-integral INT32 (value unchanged)."""
        v = self.spec(name).check(value)
        self._modified.add(name)
        if v != self._values[name]:
            self._values[name] = v
            self._revision += 1

    def adopt(self, name: str, value: float) -> None:
        """Set a value that comes from configuration elsewhere (e.g. the EAV config) without marking it modified."""
        v = self.spec(name).check(value)
        if v != self._values[name]:
            self._values[name] = v
            self._revision += 1

    def reset(self, name: str) -> None:
        """Back to the default; no longer counts as modified."""
        spec = self.spec(name)
        self._modified.discard(name)
        if self._values[name] != spec.default:
            self._values[name] = float(spec.default)
            self._revision += 1

    def is_modified(self, name: str) -> bool:
        """True once `set` was called for this name (e.g. from a config file or PARAM_SET)."""
        self.spec(name)
        return name in self._modified

    @property
    def revision(self) -> int:
        """Increases whenever a value changes: cheap change detection for derived objects (EavParams)."""
        return self._revision
