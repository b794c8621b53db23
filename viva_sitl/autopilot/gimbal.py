"""The gimbal's pointing (PX4's gimbal module, the part between its inputs and the device): pure, no I/O.

A `gimbal` camera mount (`[camera] mount = "gimbal"`) stabilises roll and pitch; its yaw follows the body. What the
gimbal manager (viva_sitl.mavlink.gimbal), mission gimbal items and Follow Me ask for becomes one setpoint here, and
`angles()` turns it into the (pitch, yaw-from-the-nose) the VAC is rendered with, at the current pose:

- NEUTRAL: the configured mount (nadir by default); PX4's neutral is level, but this camera's rest is its mount.
- ANGLE: pitch above the horizon (MAVLink: 0 level, -90 down) and yaw from the nose (+ right), or from north with
  yaw lock (GIMBAL_MANAGER_FLAGS_YAW_LOCK; converted with the vehicle's heading at every read); optional rates
  (deg/s) move the angles on from when they were set, as PX4 integrates angular-velocity inputs.
- ROI: a NED point; pitch = atan2(height difference, ground distance) and yaw = the bearing, at every read (PX4's
  OutputBase position update).
- Follow Me (AUTO.FOLLOW_TARGET with a target): the autopilot points the gimbal at the target on the ground instead,
  as PX4's follow task does (Autopilot.gimbal_pitch_yaw_deg); the setpoint above applies again after the mode.

Limits: pitch is clamped to [PITCH_MIN_DEG, PITCH_MAX_DEG] (PX4 saturates its output the same way; the manager
advertises these limits in GIMBAL_MANAGER_INFORMATION); yaw is wrapped to [-180, 180).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

PITCH_MIN_DEG = -90.0  # straight down
PITCH_MAX_DEG = 30.0  # above the horizon: a typical camera gimbal's stop
YAW_MIN_DEG = -180.0
YAW_MAX_DEG = 180.0


class GimbalMode(enum.Enum):
    NEUTRAL = "neutral"
    ANGLE = "angle"
    ROI = "roi"


def wrap_deg(a: float) -> float:
    """Wrap to [-180, 180)."""
    return (a + 180.0) % 360.0 - 180.0


def clamp_pitch(p: float) -> float:
    return min(max(p, PITCH_MIN_DEG), PITCH_MAX_DEG)


def point_at(
    target_ned_m: tuple[float, float, float], pos_ned_m: tuple[float, float, float], vehicle_yaw_rad: float
) -> tuple[float, float]:
    """(pitch, yaw from the nose) in degrees that look from pos at target (pitch clamped, yaw wrapped)."""
    dn = target_ned_m[0] - pos_ned_m[0]
    de = target_ned_m[1] - pos_ned_m[1]
    ground = math.hypot(dn, de)
    # NED down: a target below the vehicle (larger down) gives a negative pitch (looking down)
    pitch = math.degrees(math.atan2(pos_ned_m[2] - target_ned_m[2], ground))
    bearing = math.degrees(math.atan2(de, dn)) if ground > 1e-6 else math.degrees(vehicle_yaw_rad)
    return clamp_pitch(pitch), wrap_deg(bearing - math.degrees(vehicle_yaw_rad))


@dataclass
class GimbalControl:
    """The gimbal's setpoint. `neutral_deg`: the configured mount's (pitch, yaw) in the same MAVLink convention."""

    neutral_deg: tuple[float, float] = (-90.0, 0.0)
    mode: GimbalMode = GimbalMode.NEUTRAL
    pitch_deg: float = -90.0
    yaw_deg: float = 0.0
    yaw_lock: bool = False  # yaw_deg from north instead of from the nose
    pitch_rate_deg_s: float = 0.0
    yaw_rate_deg_s: float = 0.0
    set_at_s: float = 0.0
    roi_ned_m: tuple[float, float, float] | None = None
    revision: int = 0  # bumped on every new setpoint

    def set_neutral(self) -> None:
        self.mode = GimbalMode.NEUTRAL
        self.roi_ned_m = None
        self.revision += 1

    def set_angles(self, now_s: float, vehicle_yaw_rad: float, pitch_deg: float, yaw_deg: float,
                   yaw_lock: bool = False, pitch_rate_deg_s: float = math.nan,
                   yaw_rate_deg_s: float = math.nan) -> None:  # fmt: skip
        """A new angle setpoint. NaN angles keep the current one of that axis (MAVLink: "no change"); NaN rates are
        zero. The pitch is clamped, the yaw wrapped."""
        cur_pitch, cur_yaw_body = self.current(now_s, None, vehicle_yaw_rad)
        if not math.isfinite(pitch_deg):
            pitch_deg = cur_pitch
        if not math.isfinite(yaw_deg):
            yaw_deg = wrap_deg(cur_yaw_body + math.degrees(vehicle_yaw_rad)) if yaw_lock else cur_yaw_body
        self.mode = GimbalMode.ANGLE
        self.roi_ned_m = None
        self.pitch_deg = clamp_pitch(pitch_deg)
        self.yaw_deg = wrap_deg(yaw_deg)
        self.yaw_lock = yaw_lock
        self.pitch_rate_deg_s = pitch_rate_deg_s if math.isfinite(pitch_rate_deg_s) else 0.0
        self.yaw_rate_deg_s = yaw_rate_deg_s if math.isfinite(yaw_rate_deg_s) else 0.0
        self.set_at_s = now_s
        self.revision += 1

    def set_roi(self, roi_ned_m: tuple[float, float, float]) -> None:
        self.mode = GimbalMode.ROI
        self.roi_ned_m = roi_ned_m
        self.revision += 1

    def current(
        self, now_s: float, pos_ned_m: tuple[float, float, float] | None, vehicle_yaw_rad: float
    ) -> tuple[float, float]:
        """(pitch above the horizon, yaw from the nose) in degrees, now."""
        if self.mode == GimbalMode.ROI and self.roi_ned_m is not None and pos_ned_m is not None:
            return point_at(self.roi_ned_m, pos_ned_m, vehicle_yaw_rad)
        if self.mode == GimbalMode.ANGLE:
            dt = max(0.0, now_s - self.set_at_s) if math.isfinite(now_s) else 0.0
            pitch = clamp_pitch(self.pitch_deg + self.pitch_rate_deg_s * dt)
            yaw = self.yaw_deg + self.yaw_rate_deg_s * dt
            if self.yaw_lock:
                yaw -= math.degrees(vehicle_yaw_rad)
            return pitch, wrap_deg(yaw)
        return clamp_pitch(self.neutral_deg[0]), wrap_deg(self.neutral_deg[1])


__all__ = [
    "PITCH_MAX_DEG",
    "PITCH_MIN_DEG",
    "YAW_MAX_DEG",
    "YAW_MIN_DEG",
    "GimbalControl",
    "GimbalMode",
    "clamp_pitch",
    "point_at",
    "wrap_deg",
]
