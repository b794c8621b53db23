"""Offboard and manual streams: SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT, SET_ATTITUDE_TARGET, MANUAL_CONTROL.

Pure decoders from wire messages to the autopilot's types, following PX4's reading of the type masks:
- position target: a component group (position, velocity, acceleration) is used when none of its three axes is
  ignored; MAVSDK's masks are 2552 (position + yaw), 2503 (velocity + yaw), 1479 (BODY_NED velocity + yaw rate).
  A group with only some axes ignored cannot be expressed in PositionTarget and is refused with a reason.
- attitude target: type_mask 7 (rates ignored) -> attitude + thrust; 128 (attitude ignored) -> body rates + thrust;
  a setpoint without thrust (bit 64) is refused, as PX4 ignores attitude setpoints without thrust.
- NaN/inf in a used position/velocity/acceleration/attitude/thrust field refuses the whole setpoint; a NaN yaw or
  yaw rate only drops that component (PX4: "not controlled").
A refused setpoint returns a Rejected(reason) and is never passed to the autopilot.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.types import AttitudeTarget, ManualInput, OffboardFrame, PositionTarget
from viva_sitl.dynamics import EavState
from viva_sitl.geo import GeoOrigin
from viva_sitl.mavlink.base import MavMessage

# POSITION_TARGET_TYPEMASK bits
_POS_BITS = (1, 2, 4)
_VEL_BITS = (8, 16, 32)
_ACC_BITS = (64, 128, 256)
_FORCE_SET = 512
_YAW_IGNORE = 1024
_YAW_RATE_IGNORE = 2048

# ATTITUDE_TARGET_TYPEMASK bits
_RATE_BITS = (1, 2, 4)
_THROTTLE_IGNORE = 64
_ATTITUDE_IGNORE = 128

_LOCAL_FRAMES = {
    mavlink2.MAV_FRAME_LOCAL_NED: OffboardFrame.LOCAL_NED,
    mavlink2.MAV_FRAME_LOCAL_OFFSET_NED: OffboardFrame.LOCAL_NED,  # position made absolute below
    mavlink2.MAV_FRAME_BODY_NED: OffboardFrame.BODY_NED,
    mavlink2.MAV_FRAME_BODY_OFFSET_NED: OffboardFrame.BODY_NED,
    mavlink2.MAV_FRAME_BODY_FRD: OffboardFrame.BODY_NED,
}
_GLOBAL_AMSL_FRAMES = {mavlink2.MAV_FRAME_GLOBAL, mavlink2.MAV_FRAME_GLOBAL_INT}
_GLOBAL_RELATIVE_FRAMES = {
    mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT,
    mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
}
_TERRAIN_FRAMES = {mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT, mavlink2.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT}

MANUAL_AXIS_INVALID = 0x7FFF  # INT16_MAX: axis not sent


@dataclass(frozen=True)
class Rejected:
    """A setpoint that was not passed on, and why."""

    reason: str


def _group(
    mask: int, bits: tuple[int, int, int], values: tuple[float, float, float], name: str
) -> tuple[float, float, float] | None | Rejected:
    ignored = [bool(mask & b) for b in bits]
    if all(ignored):
        return None
    if any(ignored):
        return Rejected(f"{name}: partial axis masks are not supported (type_mask {mask})")
    if not all(math.isfinite(v) for v in values):
        return Rejected(f"{name} is not finite")
    return (float(values[0]), float(values[1]), float(values[2]))


def _yaw_parts(mask: int, yaw: float, yaw_rate: float) -> tuple[float | None, float | None]:
    yaw_rad = float(yaw) if not mask & _YAW_IGNORE and math.isfinite(yaw) else None
    rate = float(yaw_rate) if not mask & _YAW_RATE_IGNORE and math.isfinite(yaw_rate) else None
    return yaw_rad, rate


def _decode_groups(
    msg: MavMessage, pos: tuple[float, float, float]
) -> tuple[tuple[float, float, float] | None, ...] | Rejected:
    mask = int(msg.type_mask)
    p = _group(mask, _POS_BITS, pos, "position")
    v = _group(mask, _VEL_BITS, (msg.vx, msg.vy, msg.vz), "velocity")
    a = _group(
        mask, _ACC_BITS, (msg.afx, msg.afy, msg.afz), "acceleration"
    )  # FORCE_SET: read as acceleration
    for g in (p, v, a):
        if isinstance(g, Rejected):
            return g
    return (p, v, a)  # type: ignore[return-value]


def decode_position_target_local(msg: MavMessage, state: EavState) -> PositionTarget | Rejected:
    """SET_POSITION_TARGET_LOCAL_NED -> PositionTarget (LOCAL_NED, BODY_NED; offset frames made absolute)."""
    frame = _LOCAL_FRAMES.get(int(msg.coordinate_frame))
    if frame is None:
        return Rejected(f"unsupported coordinate_frame {msg.coordinate_frame}")
    groups = _decode_groups(msg, (msg.x, msg.y, msg.z))
    if isinstance(groups, Rejected):
        return groups
    pos, vel, acc = groups
    if pos is not None and int(msg.coordinate_frame) == mavlink2.MAV_FRAME_LOCAL_OFFSET_NED:
        cur = state.pos_ned_m
        pos = (pos[0] + float(cur[0]), pos[1] + float(cur[1]), pos[2] + float(cur[2]))
    yaw, yaw_rate = _yaw_parts(int(msg.type_mask), msg.yaw, msg.yaw_rate)
    if pos is None and vel is None and acc is None and yaw is None and yaw_rate is None:
        return Rejected(f"type_mask {msg.type_mask} ignores everything")
    return PositionTarget(pos, vel, acc, yaw, yaw_rate, frame)


def decode_position_target_global(
    msg: MavMessage, geo: GeoOrigin, home_ned_m: tuple[float, float, float], ground_z_ned_m: float = 0.0
) -> PositionTarget | Rejected:
    """SET_POSITION_TARGET_GLOBAL_INT -> PositionTarget in local NED (frame GLOBAL), through the GeoOrigin."""
    frame = int(msg.coordinate_frame)
    mask = int(msg.type_mask)
    pos: tuple[float, float, float] | None = None
    if not all(mask & b for b in _POS_BITS):
        if any(mask & b for b in _POS_BITS):
            return Rejected(f"position: partial axis masks are not supported (type_mask {mask})")
        lat, lon, alt = msg.lat_int / 1e7, msg.lon_int / 1e7, float(msg.alt)
        if not math.isfinite(alt) or not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
            return Rejected("global position is not valid")
        if frame in _GLOBAL_AMSL_FRAMES:
            north, east, down = geo.global_to_ned(lat, lon, alt)
        elif frame in _GLOBAL_RELATIVE_FRAMES:
            north, east, _ = geo.global_to_ned(lat, lon, geo.alt_amsl_m)
            base = ground_z_ned_m if frame in _TERRAIN_FRAMES else home_ned_m[2]
            down = base - alt
        else:
            return Rejected(f"unsupported coordinate_frame {frame}")
        pos = (north, east, down)
    groups = _decode_groups(msg, (0.0, 0.0, 0.0))
    if isinstance(groups, Rejected):
        return groups
    _, vel, acc = groups
    yaw, yaw_rate = _yaw_parts(mask, msg.yaw, msg.yaw_rate)
    if pos is None and vel is None and acc is None and yaw is None and yaw_rate is None:
        return Rejected(f"type_mask {mask} ignores everything")
    return PositionTarget(pos, vel, acc, yaw, yaw_rate, OffboardFrame.GLOBAL)


def decode_attitude_target(msg: MavMessage) -> AttitudeTarget | Rejected:
    """SET_ATTITUDE_TARGET -> AttitudeTarget (quaternion w,x,y,z and/or body rates, thrust 0..1)."""
    mask = int(msg.type_mask)
    if mask & _THROTTLE_IGNORE:
        return Rejected("attitude setpoint without thrust")
    thrust = float(msg.thrust)
    if not math.isfinite(thrust):
        return Rejected("thrust is not finite")
    q: tuple[float, float, float, float] | None = None
    if not mask & _ATTITUDE_IGNORE:
        w, x, y, z = (float(v) for v in msg.q)
        norm = math.sqrt(w * w + x * x + y * y + z * z)
        if not math.isfinite(norm) or norm < 1e-6:
            return Rejected("attitude quaternion is not finite or zero")
        q = (w / norm, x / norm, y / norm, z / norm)
    rates: tuple[float, float, float] | None = None
    if not all(mask & b for b in _RATE_BITS):
        values = (float(msg.body_roll_rate), float(msg.body_pitch_rate), float(msg.body_yaw_rate))
        if any(mask & b for b in _RATE_BITS):  # PX4 takes the given axes; unknown axes hold rate 0
            values = tuple(0.0 if mask & b else v for b, v in zip(_RATE_BITS, values, strict=True))  # type: ignore[assignment]
        if not all(math.isfinite(v) for v in values):
            return Rejected("body rates are not finite")
        rates = values
    if q is None and rates is None:
        return Rejected(f"type_mask {mask} ignores attitude and rates")
    return AttitudeTarget(q, rates, min(1.0, max(0.0, thrust)))


def decode_manual_control(msg: MavMessage) -> ManualInput | Rejected:
    """MANUAL_CONTROL (x, y, r in -1000..1000, z throttle 0..1000 as QGC/MAVSDK send it) -> ManualInput."""
    raw = (int(msg.x), int(msg.y), int(msg.z), int(msg.r))
    if any(v == MANUAL_AXIS_INVALID for v in raw):
        # INT16_MAX marks an axis the sender does not provide; treat it as centred (throttle: hover stick 0.5)
        raw = tuple(c if v == MANUAL_AXIS_INVALID else v for v, c in zip(raw, (0, 0, 500, 0), strict=True))  # type: ignore[assignment]
    x, y, z, r = (max(-1.0, min(1.0, v / 1000.0)) for v in raw)
    return ManualInput(x=x, y=y, z=max(0.0, z), r=r)
