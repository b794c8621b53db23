"""Mission items: validation on upload, the executor's progress record, DO_JUMP resolution, relative altitudes
resolved when an item starts, and PX4's mission yaw (MIS_YAWMODE). Pure functions."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from viva_sitl.autopilot.setpoints import MAX_ABS_POS_M, finite
from viva_sitl.autopilot.types import MissionCommand, MissionItem

MAX_MISSION_ITEMS = 2000
MAX_JUMP_REPEAT = 0xFFFF  # PX4 stores the repeat count as uint16
NAV_COMMANDS = frozenset(
    {
        MissionCommand.NAV_WAYPOINT,
        MissionCommand.NAV_LOITER_TIME,
        MissionCommand.NAV_TAKEOFF,
        MissionCommand.NAV_LAND,
        MissionCommand.NAV_DELAY,
    }
)
# Items that end the mission or move the vehicle on their own (a DO_JUMP loop over one of them is not empty).
_FLYING_COMMANDS = NAV_COMMANDS | {MissionCommand.NAV_RETURN_TO_LAUNCH}


def _validate_jumps(items: Sequence[MissionItem]) -> None:
    for i, it in enumerate(items):
        if it.command != MissionCommand.DO_JUMP:
            continue
        t, r = it.param1, it.param2
        if not (math.isfinite(t) and t == int(t) and 0 <= t < len(items)):
            raise ValueError(f"Mission rejected: DO_JUMP {i} target {t:g} does not exist")
        if not math.isfinite(r) or r < 0:
            raise ValueError(f"Mission rejected: DO_JUMP {i} repeat count {r:g} must be >= 0")
        target = int(t)
        if target <= i and not any(items[k].command in _FLYING_COMMANDS for k in range(target, i)):
            raise ValueError(f"Mission rejected: DO_JUMP {i} loops without a waypoint")


def validate_mission(
    items: Sequence[MissionItem],
    home_ned_m: tuple[float, float, float],
    inside: Callable[[float, float], bool],
    dist_1wp_m: float,
    fence_ok: Callable[[float, float], bool] | None = None,
) -> None:
    """Raise ValueError with PX4-like reasons for a mission PX4 would not accept.

    Waypoints and loiters need a finite position; TAKEOFF/LAND may leave it NaN (= where the vehicle is). Items
    outside the footage (geofence), outside the uploaded geofence (`fence_ok`, PX4's mission feasibility check), a
    first waypoint farther than MIS_DIST_1WP from home and DO_JUMPs to nowhere or around no waypoint are refused.
    Other DO items are never a reason to refuse (they are executed, or logged and skipped).
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
        if fence_ok is not None and finite(it.north_m, it.east_m) and not fence_ok(it.north_m, it.east_m):
            raise ValueError(f"Geofence violation for waypoint {i + 1}")
    _validate_jumps(items)
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
    jumps_done: dict[int, int] = field(
        default_factory=dict
    )  # DO_JUMP seq -> jumps made (reset with the mission)


def resolve_jumps(
    items: Sequence[MissionItem], seq: int, jumps_done: dict[int, int]
) -> tuple[int, dict[int, int], str | None]:
    """From `seq`, follow DO_JUMP items (PX4: jump while the count is below the repeat count, else go on).

    Returns the first non-jump seq (len(items) = the end), the updated counters (a new dict) and a warning when the
    jumps cycle without reaching another item (bounded work: at most 2 * len(items) + 1 hops, never a hang).
    """
    done = dict(jumps_done)
    for _ in range(2 * len(items) + 1):
        if not (0 <= seq < len(items)) or items[seq].command != MissionCommand.DO_JUMP:
            return seq, done, None
        it = items[seq]
        repeat = min(int(it.param2), MAX_JUMP_REPEAT) if math.isfinite(it.param2) and it.param2 > 0 else 0
        count = done.get(seq, 0)
        target = int(it.param1) if math.isfinite(it.param1) else -1
        if count < repeat and 0 <= target < len(items):
            done[seq] = count + 1
            seq = target
        else:
            seq += 1
    return len(items), done, "DO JUMP is cycling, giving up"


def resolve_item(item: MissionItem, home_down_m: float) -> MissionItem:
    """An item's altitude above home (GLOBAL_RELATIVE_ALT frames) resolved against the home of now."""
    if math.isfinite(item.alt_rel_home_m) and math.isfinite(home_down_m):
        return replace(item, down_m=home_down_m - item.alt_rel_home_m)
    return item


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
