"""Mission items: validation on upload, the executor's progress record, and PX4's mission yaw (MIS_YAWMODE)."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from viva_sitl.autopilot.setpoints import MAX_ABS_POS_M, finite
from viva_sitl.autopilot.types import MissionCommand, MissionItem

MAX_MISSION_ITEMS = 2000
NAV_COMMANDS = frozenset(
    {
        MissionCommand.NAV_WAYPOINT,
        MissionCommand.NAV_LOITER_TIME,
        MissionCommand.NAV_TAKEOFF,
        MissionCommand.NAV_LAND,
    }
)


def validate_mission(
    items: Sequence[MissionItem],
    home_ned_m: tuple[float, float, float],
    inside: Callable[[float, float], bool],
    dist_1wp_m: float,
) -> None:
    """Raise ValueError with PX4-like reasons for a mission PX4 would not accept.

    Waypoints and loiters need a finite position; TAKEOFF/LAND may leave it NaN (= where the vehicle is). Items
    outside the footage (geofence) and a first waypoint farther than MIS_DIST_1WP from home are refused.
    """
    if len(items) > MAX_MISSION_ITEMS:
        raise ValueError(f"Mission rejected: too many items ({len(items)} > {MAX_MISSION_ITEMS})")
    for i, it in enumerate(items):
        if it.seq != i:
            raise ValueError(f"Mission rejected: item {i} has seq {it.seq}")
        if it.command not in NAV_COMMANDS:
            continue
        needs_pos = it.command in (MissionCommand.NAV_WAYPOINT, MissionCommand.NAV_LOITER_TIME)
        if needs_pos and not finite(it.north_m, it.east_m, it.down_m):
            raise ValueError(f"Mission rejected: item {i} position not finite")
        if any(
            math.isinf(v) or (math.isfinite(v) and abs(v) > MAX_ABS_POS_M)
            for v in (it.north_m, it.east_m, it.down_m)
        ):
            raise ValueError(f"Mission rejected: item {i} position out of range")
        if it.command != MissionCommand.NAV_TAKEOFF:
            if not finite(it.param1, it.param2):
                raise ValueError(f"Mission rejected: item {i} parameters not finite")
            if finite(it.north_m, it.east_m) and not inside(it.north_m, it.east_m):
                raise ValueError(f"Mission rejected: item {i} outside footage (geofence)")
    first_nav = next(
        (it for it in items if it.command in NAV_COMMANDS and finite(it.north_m, it.east_m)), None
    )
    if dist_1wp_m > 0 and first_nav is not None and first_nav.command != MissionCommand.NAV_TAKEOFF:
        d = math.hypot(first_nav.north_m - home_ned_m[0], first_nav.east_m - home_ned_m[1])
        if d > dist_1wp_m:
            raise ValueError(
                f"Mission rejected: first waypoint too far ({d:.0f} m > MIS_DIST_1WP {dist_1wp_m:.0f} m)"
            )


@dataclass
class MissionProgress:
    """Where the executor is inside the current item."""

    seq: int = 0
    target: NDArray[np.float64] | None = None  # NED target of the current (or last) nav item
    arrived_s: float | None = None  # when the vehicle first reached the item (hold timers)
    landing: bool = False  # LAND item: descending
    climbing: bool = False  # implicit or item take-off: climbing
    climb_xy: tuple[float, float] | None = None  # where the climb holds horizontally
    finished: bool = False


def mission_yaw(
    item: MissionItem,
    pos_ned_m: NDArray[np.float64],
    target_ned_m: NDArray[np.float64],
    home_ned_m: NDArray[np.float64],
    yaw_mode: int,
) -> float | None:
    """Yaw target for a nav item: param4 when given, else per MIS_YAWMODE (0 keep, 1 toward the waypoint,
    2 toward home, 3 away from home). None = keep the current yaw setpoint."""
    if math.isfinite(item.param4):
        return math.radians(item.param4)
    if yaw_mode == 0:
        return None
    if yaw_mode == 2:
        return math.atan2(home_ned_m[1] - pos_ned_m[1], home_ned_m[0] - pos_ned_m[0])
    if yaw_mode == 3:
        return math.atan2(pos_ned_m[1] - home_ned_m[1], pos_ned_m[0] - home_ned_m[0])
    if math.hypot(target_ned_m[0] - pos_ned_m[0], target_ned_m[1] - pos_ned_m[1]) > 2.0:
        return math.atan2(target_ned_m[1] - pos_ned_m[1], target_ned_m[0] - pos_ned_m[0])
    return None
