"""The virtual PX4: parameters, modes, controllers, mission executor and failsafes (pure logic, no I/O)."""

from viva_sitl.autopilot.autopilot import Autopilot, InsideFn
from viva_sitl.autopilot.params import ParamSpec, ParamStore, ParamType
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
    OffboardFrame,
    Outcome,
    PositionTarget,
    Severity,
)

__all__ = [
    "ACCEPTED",
    "AttitudeTarget",
    "Autopilot",
    "CommandResult",
    "Event",
    "FlightMode",
    "InsideFn",
    "LandedState",
    "ManualInput",
    "MissionCommand",
    "MissionItem",
    "OffboardFrame",
    "Outcome",
    "ParamSpec",
    "ParamStore",
    "ParamType",
    "PositionTarget",
    "Severity",
]
