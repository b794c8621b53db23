"""Failure injection, as PX4's MAV_CMD_INJECT_FAILURE: a (unit, type) pair switched on until FAILURE_TYPE_OK.

The enums carry MAVLink's FAILURE_UNIT / FAILURE_TYPE values, so the MAVLink command handler, the trials' scenario
failures and tests all name a failure the same way and reach it through one call, `Autopilot.inject_failure`.

What each supported failure does (PX4 SITL's consequence; everything else is UNSUPPORTED, as PX4 answers for the
failures its simulator does not implement):
- SYSTEM_MAVLINK_SIGNAL, OFF: the ground station's heartbeats are no longer heard (the radio link is gone; an onboard
  API link keeps working), so PX4's data-link-loss failsafe (COM_DL_LOSS_T, NAV_DLL_ACT) follows as on a vehicle.
  OK: heard again ("Data link regained" at the next heartbeat).
- SYSTEM_BATTERY, OFF: the battery reads empty (PX4's battery simulator forces the empty voltage: remaining 0 %, the
  emergency level and its failsafe). OK: the battery reads its real charge again.
- SYSTEM_BATTERY, WRONG (viva-sitl's own; PX4's battery simulator has no such type): the pack is drained to just
  below BAT_CRIT_THR now (SIM_BAT_MIN_PCT set to 0 so that it may go that low): PX4's "Critical battery level! Land
  now" warning and BAT_CRIT action follow at the next control step. A drain is not undone by OK.
"""

from __future__ import annotations

import enum

from viva_sitl.autopilot.battery import Battery
from viva_sitl.autopilot.params import ParamStore
from viva_sitl.autopilot.types import ACCEPTED, CommandResult, Outcome


class FailureUnit(enum.IntEnum):
    """MAVLink FAILURE_UNIT."""

    SENSOR_GYRO = 0
    SENSOR_ACCEL = 1
    SENSOR_MAG = 2
    SENSOR_BARO = 3
    SENSOR_GPS = 4
    SENSOR_OPTICAL_FLOW = 5
    SENSOR_VIO = 6
    SENSOR_DISTANCE_SENSOR = 7
    SENSOR_AIRSPEED = 8
    SYSTEM_BATTERY = 100
    SYSTEM_MOTOR = 101
    SYSTEM_SERVO = 102
    SYSTEM_AVOIDANCE = 103
    SYSTEM_RC_SIGNAL = 104
    SYSTEM_MAVLINK_SIGNAL = 105


class FailureType(enum.IntEnum):
    """MAVLink FAILURE_TYPE."""

    OK = 0
    OFF = 1
    STUCK = 2
    GARBAGE = 3
    WRONG = 4
    SLOW = 5
    DELAYED = 6
    INTERMITTENT = 7


SUPPORTED: frozenset[tuple[FailureUnit, FailureType]] = frozenset(
    {
        (FailureUnit.SYSTEM_MAVLINK_SIGNAL, FailureType.OFF),
        (FailureUnit.SYSTEM_MAVLINK_SIGNAL, FailureType.OK),
        (FailureUnit.SYSTEM_BATTERY, FailureType.OFF),
        (FailureUnit.SYSTEM_BATTERY, FailureType.OK),
        (FailureUnit.SYSTEM_BATTERY, FailureType.WRONG),
    }
)


class Failures:
    """The failures switched on now: unit -> type. Pure state; the autopilot reads it where a failure acts."""

    def __init__(self) -> None:
        self.active: dict[FailureUnit, FailureType] = {}

    def is_active(self, unit: FailureUnit, ftype: FailureType | None = None) -> bool:
        t = self.active.get(unit)
        return t is not None and (ftype is None or t == ftype)

    def inject(
        self,
        unit: FailureUnit | int,
        ftype: FailureType | int,
        instance: int,
        params: ParamStore,
        battery: Battery,
        *,
        check_enabled: bool = True,
    ) -> Outcome:
        """Switch a failure on (or off with OK). `check_enabled`: refuse unless SYS_FAILURE_EN = 1 (PX4's gate on
        MAV_CMD_INJECT_FAILURE); the simulator's own scenario failures pass False."""
        try:
            u, t = FailureUnit(int(unit)), FailureType(int(ftype))
        except ValueError:
            return Outcome(
                CommandResult.UNSUPPORTED, f"Failure injection: unknown unit {unit} / type {ftype}"
            )
        if check_enabled and params.get("SYS_FAILURE_EN") < 0.5:
            return Outcome(CommandResult.DENIED, "Failure injection disabled (SYS_FAILURE_EN = 0)")
        if (u, t) not in SUPPORTED or instance not in (0, -1):
            return Outcome(CommandResult.UNSUPPORTED, f"Failure injection: {u.name} {t.name} not supported")
        if t is FailureType.OK:
            self.active.pop(u, None)
            if u is FailureUnit.SYSTEM_BATTERY:
                battery.forced_empty = False
            return ACCEPTED
        if u is FailureUnit.SYSTEM_BATTERY and t is FailureType.WRONG:
            drain_to_critical(params, battery)
            return ACCEPTED  # a one-time drain, not a lasting state
        self.active[u] = t
        if u is FailureUnit.SYSTEM_BATTERY:
            battery.forced_empty = True
        return ACCEPTED


def drain_to_critical(params: ParamStore, battery: Battery) -> None:
    """Drain the pack to just below BAT_CRIT_THR now (SIM_BAT_MIN_PCT 0 so that it may go that low)."""
    target = max(0.0, params.get("BAT_CRIT_THR") - 0.01)
    params.set("SIM_BAT_MIN_PCT", 0.0)
    battery.used_mah = max(battery.used_mah, params.get("BAT1_CAPACITY") * (1.0 - target))


__all__ = ["SUPPORTED", "FailureType", "FailureUnit", "Failures", "drain_to_critical"]
