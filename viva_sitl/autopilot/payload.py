"""Camera and gimbal mission items (pure): what an item asks the camera/gimbal to do, and PX4's distance trigger.

The autopilot turns items into PayloadActions (routed by the MAVLink layer to the camera component, which renders
and saves the VAC frame) and gimbal angles (`Autopilot.gimbal_pitch_yaw_deg`; `Vehicle.render` points a `gimbal`
camera mount there).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from viva_sitl.autopilot.types import MissionCommand, MissionItem, PayloadAction


@dataclass(frozen=True)
class ItemEffect:
    """What one DO item does: payload actions, a gimbal (pitch, yaw) in degrees, a trigger distance, a log line."""

    actions: tuple[PayloadAction, ...] = ()
    gimbal_deg: tuple[float, float] | None = None
    trigger_dist_m: float | None = None
    note: str | None = None


def item_effect(item: MissionItem) -> ItemEffect:
    c = item.command
    if c == MissionCommand.IMAGE_START_CAPTURE:
        # param2 interval (s), param3 total images (0 = until stopped); one image when the interval is 0
        interval = item.param2 if math.isfinite(item.param2) and item.param2 > 0 else 0.0
        total = int(item.param3) if math.isfinite(item.param3) and item.param3 >= 0 else 1
        if interval <= 0 or total == 1:
            return ItemEffect(actions=(PayloadAction("capture_once"),))
        return ItemEffect(actions=(PayloadAction("capture_start", interval_s=interval, total=total),))
    if c == MissionCommand.IMAGE_STOP_CAPTURE:
        return ItemEffect(actions=(PayloadAction("capture_stop"),))
    if c == MissionCommand.DO_SET_CAM_TRIGG_DIST:
        dist = item.param1 if math.isfinite(item.param1) and item.param1 > 0 else 0.0
        once = (PayloadAction("capture_once"),) if item.param3 >= 0.5 else ()
        return ItemEffect(actions=once, trigger_dist_m=dist)
    if c == MissionCommand.DO_MOUNT_CONTROL:  # param1 pitch, param3 yaw (deg)
        return ItemEffect(gimbal_deg=(_deg(item.param1), _deg(item.param3)))
    if c == MissionCommand.DO_GIMBAL_MANAGER_PITCHYAW:  # param1 pitch, param2 yaw (deg)
        return ItemEffect(gimbal_deg=(_deg(item.param1), _deg(item.param2)))
    if c in (MissionCommand.DO_SET_ROI, MissionCommand.DO_SET_ROI_LOCATION, MissionCommand.DO_SET_ROI_NONE):
        return ItemEffect(note=f"Mission item {item.seq}: ROI accepted, not flown (no gimbal control)")
    if c == MissionCommand.OTHER:
        return ItemEffect(note=f"Mission item {item.seq}: command {item.raw_command} not supported, skipped")
    return ItemEffect()


def _deg(v: float) -> float:
    return v if math.isfinite(v) else 0.0


@dataclass
class DistanceTrigger:
    """DO_SET_CAM_TRIGG_DIST: one capture each time the vehicle has moved `distance_m` horizontally (0 = off)."""

    distance_m: float = 0.0
    _last_ne: tuple[float, float] | None = None

    def set(self, distance_m: float, north_m: float, east_m: float) -> None:
        self.distance_m = distance_m
        self._last_ne = (north_m, east_m) if distance_m > 0 else None

    def update(self, north_m: float, east_m: float) -> bool:
        if self.distance_m <= 0 or self._last_ne is None:
            return False
        if math.hypot(north_m - self._last_ne[0], east_m - self._last_ne[1]) >= self.distance_m:
            self._last_ne = (north_m, east_m)
            return True
        return False
