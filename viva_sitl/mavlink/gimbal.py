"""MAVLink gimbal protocol v2: the gimbal manager (and its device) of a `gimbal` camera mount, as PX4 exposes them.

Only with `[camera] mount = "gimbal"` (the autopilot then has a `gimbal`); a fixed camera has no gimbal, so nothing
here answers and MAVSDK's gimbal plugin finds none (as PX4 without a gimbal).

As PX4 with a gimbal it drives itself (MNT_MODE_OUT = AUX): the autopilot component (compid 1) is the gimbal manager
and the device is "gimbal device 1" (PX4's convention for a non-MAVLink device), so every message comes from compid 1:

- REQUEST_MESSAGE answers GIMBAL_MANAGER_INFORMATION (280: capabilities, pitch [-90, 30] deg, yaw [-180, 180] deg),
  GIMBAL_MANAGER_STATUS (281), GIMBAL_DEVICE_INFORMATION (283: PX4 has none for an AUX gimbal and MAVSDK then waits
  for its retries; answering it makes discovery prompt) and GIMBAL_DEVICE_ATTITUDE_STATUS (285).
- Streams on the simulation clock: GIMBAL_DEVICE_ATTITUDE_STATUS at 10 Hz (q: roll 0, pitch above the horizon, yaw
  from the nose; YAW_IN_VEHICLE_FRAME; delta_yaw = the vehicle heading) and GIMBAL_MANAGER_STATUS at 1 Hz and on
  every change of control.
- MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE (1001): p1/p2 primary control sysid/compid (-1 unchanged, -2 the autopilot,
  -3 release if held by the sender), p3/p4 the same for secondary; always ACCEPTED (PX4).
- MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW (1000): p1 pitch, p2 yaw (deg; NaN: unchanged), p3/p4 rates (deg/s), p5 (x in
  a COMMAND_INT) GIMBAL_MANAGER_FLAGS (YAW_LOCK / YAW_IN_EARTH_FRAME: yaw from north; NEUTRAL / RETRACT: rest). Only
  from the primary controller, else DENIED (PX4: take control with CONFIGURE first).
- GIMBAL_MANAGER_SET_ATTITUDE (282, quaternion + rates, rad) and GIMBAL_MANAGER_SET_PITCHYAW (287): the same, from
  the primary controller only; from anyone else they are ignored (PX4), with at most one STATUSTEXT every 5 s.
- MAV_CMD_DO_SET_ROI_LOCATION (195): point at a location (lat/lon, altitude in the command's frame; COMMAND_LONG:
  AMSL) as the vehicle moves; MAV_CMD_DO_SET_ROI_NONE (197): back to rest. No control needed (PX4's vehicle_roi).

Angle limits: a pitch outside [-90, 30] is clamped (PX4 saturates its output the same way) and the command is
ACCEPTED, with an INFO STATUSTEXT saying so; a yaw is wrapped. Non-finite quaternions/rates are ignored.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.gimbal import (
    PITCH_MAX_DEG,
    PITCH_MIN_DEG,
    YAW_MAX_DEG,
    YAW_MIN_DEG,
    GimbalControl,
    GimbalMode,
)
from viva_sitl.autopilot.types import CommandResult, Outcome, Severity
from viva_sitl.mavlink.base import (
    CommandRequest,
    MavMessage,
    Origin,
    Outbox,
    StatusSink,
    VehicleLink,
    fixed_bytes,
    time_boot_ms,
)

log = logging.getLogger(__name__)
M = mavlink2

GIMBAL_DEVICE_ID = 1  # PX4: a gimbal the autopilot drives itself is gimbal device 1
ATTITUDE_HZ = 10.0
STATUS_HZ = 1.0
IGNORED_WARN_INTERVAL_S = 5.0
_YAW_EARTH = M.GIMBAL_MANAGER_FLAGS_YAW_LOCK | M.GIMBAL_MANAGER_FLAGS_YAW_IN_EARTH_FRAME
_REST = M.GIMBAL_MANAGER_FLAGS_NEUTRAL | M.GIMBAL_MANAGER_FLAGS_RETRACT
CAP_FLAGS = (
    M.GIMBAL_MANAGER_CAP_FLAGS_HAS_NEUTRAL
    | M.GIMBAL_MANAGER_CAP_FLAGS_HAS_ROLL_LOCK
    | M.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_AXIS
    | M.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_LOCK
    | M.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_AXIS
    | M.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_FOLLOW
    | M.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_LOCK
    | M.GIMBAL_MANAGER_CAP_FLAGS_CAN_POINT_LOCATION_GLOBAL
)

# (alt, frame) -> NED down, None when NaN or the frame is unknown (CommandHandler._down_from_alt)
DownFromAlt = Callable[[float, int], "float | None"]
CommandFn = Callable[[Origin, CommandRequest], tuple[Outcome, list[MavMessage]]]


def quat_from_euler(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of a ZYX Euler rotation (rad), the MAVLink / PX4 convention."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


def euler_from_quat(q: tuple[float, float, float, float]) -> tuple[float, float, float]:
    """(roll, pitch, yaw) rad of a (w, x, y, z) quaternion (normalised here)."""
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    roll = math.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = math.asin(max(-1.0, min(1.0, 2 * (w * y - z * x))))
    yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    return roll, pitch, yaw


class GimbalManager:
    """The gimbal manager's protocol state: who is in control, when the streams are due."""

    def __init__(
        self, vehicle: VehicleLink, out: Outbox, statustext: StatusSink, down_from_alt: DownFromAlt
    ) -> None:
        self.vehicle = vehicle
        self.out = out
        self.statustext = statustext
        self.down_from_alt = down_from_alt
        self.primary: tuple[int, int] = (0, 0)  # (sysid, compid) in control; (0, 0): nobody (PX4 at boot)
        self.secondary: tuple[int, int] = (0, 0)
        self.next_attitude_s = 0.0
        self.next_status_s = 0.0
        self.setpoints_ignored = 0
        self._last_ignored_warn_s = -math.inf

    # --- registration -------------------------------------------------------------------------
    def command_handlers(self) -> dict[int, CommandFn]:
        return {
            M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW: self._pitchyaw,
            M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE: self._configure,
            M.MAV_CMD_DO_SET_ROI_LOCATION: self._roi_location,
            M.MAV_CMD_DO_SET_ROI_NONE: self._roi_none,
        }

    @property
    def control(self) -> GimbalControl | None:
        """The autopilot's gimbal, looked up per call (a Vehicle reset replaces the autopilot)."""
        return self.vehicle.autopilot.gimbal

    def _now(self) -> float:
        t = float(self.vehicle.time_s)
        return t if math.isfinite(t) else 0.0

    def _yaw(self) -> float:
        y = float(self.vehicle.state.yaw_rad)
        return y if math.isfinite(y) else 0.0

    def angles_deg(self) -> tuple[float, float]:
        """(pitch above the horizon, yaw from the nose) the camera points at now."""
        g = self.control
        if g is None:
            return (-90.0, 0.0)
        # what the VAC renders (mission items and Follow Me included)
        now = self.vehicle.autopilot.gimbal_pitch_yaw_deg
        return now if now is not None else g.current(self._now(), None, self._yaw())

    # --- messages -----------------------------------------------------------------------------
    def manager_information(self) -> MavMessage:
        r = math.radians
        return M.MAVLink_gimbal_manager_information_message(
            time_boot_ms(self.vehicle), CAP_FLAGS, GIMBAL_DEVICE_ID, 0.0, 0.0, r(PITCH_MIN_DEG), r(PITCH_MAX_DEG),
            r(YAW_MIN_DEG), r(YAW_MAX_DEG),
        )  # fmt: skip

    def device_information(self) -> MavMessage:
        r = math.radians
        caps = (
            M.GIMBAL_DEVICE_CAP_FLAGS_HAS_NEUTRAL | M.GIMBAL_DEVICE_CAP_FLAGS_HAS_ROLL_LOCK
            | M.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_AXIS | M.GIMBAL_DEVICE_CAP_FLAGS_HAS_PITCH_LOCK
            | M.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_AXIS | M.GIMBAL_DEVICE_CAP_FLAGS_HAS_YAW_FOLLOW
        )  # fmt: skip
        return M.MAVLink_gimbal_device_information_message(
            time_boot_ms(self.vehicle), fixed_bytes("viva-sitl", 32), fixed_bytes("VAC gimbal", 32),
            fixed_bytes("", 32), 0, 0, 0, caps, 0, 0.0, 0.0, r(PITCH_MIN_DEG), r(PITCH_MAX_DEG), r(YAW_MIN_DEG),
            r(YAW_MAX_DEG), GIMBAL_DEVICE_ID,
        )  # fmt: skip

    def _flags(self) -> int:
        g = self.control
        flags = M.GIMBAL_MANAGER_FLAGS_ROLL_LOCK | M.GIMBAL_MANAGER_FLAGS_PITCH_LOCK
        if g is not None and g.mode == GimbalMode.NEUTRAL:
            flags |= M.GIMBAL_MANAGER_FLAGS_NEUTRAL
        if g is not None and g.mode == GimbalMode.ANGLE and g.yaw_lock:
            flags |= M.GIMBAL_MANAGER_FLAGS_YAW_LOCK
        return flags

    def manager_status(self) -> MavMessage:
        return M.MAVLink_gimbal_manager_status_message(
            time_boot_ms(self.vehicle), self._flags(), GIMBAL_DEVICE_ID, *self.primary, *self.secondary
        )

    def device_attitude_status(self) -> MavMessage:
        pitch, yaw = self.angles_deg()
        q = quat_from_euler(0.0, math.radians(pitch), math.radians(yaw))
        flags = (
            M.GIMBAL_DEVICE_FLAGS_ROLL_LOCK | M.GIMBAL_DEVICE_FLAGS_PITCH_LOCK
            | M.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
        )  # fmt: skip
        return M.MAVLink_gimbal_device_attitude_status_message(
            0, 0, time_boot_ms(self.vehicle), flags, list(q), math.nan, math.nan, math.nan, 0, self._yaw(),
            math.nan, GIMBAL_DEVICE_ID,
        )  # fmt: skip

    def request_message(self, msgid: int) -> list[MavMessage] | None:
        if self.control is None:
            return None
        if msgid == M.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION:
            return [self.manager_information()]
        if msgid == M.MAVLINK_MSG_ID_GIMBAL_MANAGER_STATUS:
            return [self.manager_status()]
        if msgid == M.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION:
            return [self.device_information()]
        if msgid == M.MAVLINK_MSG_ID_GIMBAL_DEVICE_ATTITUDE_STATUS:
            return [self.device_attitude_status()]
        return None

    def poll(self, now_s: float) -> None:
        """The streams (the endpoint's housekeeping calls this on the simulation clock)."""
        if self.control is None:
            return
        if now_s < self.next_attitude_s - 1.0 / ATTITUDE_HZ or now_s < self.next_status_s - 1.0 / STATUS_HZ:
            self.next_attitude_s = self.next_status_s = now_s  # the simulation was reset
        if now_s >= self.next_attitude_s:
            self.next_attitude_s = now_s + 1.0 / ATTITUDE_HZ
            self.out.broadcast(self.device_attitude_status())
        if now_s >= self.next_status_s:
            self.next_status_s = now_s + 1.0 / STATUS_HZ
            self.out.broadcast(self.manager_status())

    # --- commands -----------------------------------------------------------------------------
    def _in_control(self, origin: Origin) -> bool:
        return (origin.sysid, origin.compid) == self.primary

    def _not_in_control(self, origin: Origin) -> Outcome:
        return Outcome(
            CommandResult.DENIED,
            f"Gimbal: {origin.sysid}/{origin.compid} is not in control (primary {self.primary[0]}/"
            f"{self.primary[1]}): send DO_GIMBAL_MANAGER_CONFIGURE first",
        )

    def _configure(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        if self.control is None:
            return Outcome(CommandResult.UNSUPPORTED), []
        own = (int(self.vehicle.autopilot.params.get("MAV_SYS_ID")), 1)

        def pick(value: float, current: int, sender: int, own_id: int) -> int:
            v = round(value) if math.isfinite(value) else -1
            if 0 <= v <= 255:
                return v
            if v == -2:
                return own_id
            if v == -3:  # release, if the sender holds it
                return 0 if current == sender else current
            return current  # -1 (unchanged) and anything else (PX4 warns and keeps it)

        prim = (
            pick(req.p1, self.primary[0], origin.sysid, own[0]),
            pick(req.p2, self.primary[1], origin.compid, own[1]),
        )
        sec = (
            pick(req.p3, self.secondary[0], origin.sysid, own[0]),
            pick(req.p4, self.secondary[1], origin.compid, own[1]),
        )
        changed = (prim, sec) != (self.primary, self.secondary)
        self.primary, self.secondary = prim, sec
        if changed:
            log.info("gimbal primary control %d/%d, secondary %d/%d", *prim, *sec)
            self.next_status_s = self._now()  # GIMBAL_MANAGER_STATUS goes out at once
            self.out.broadcast(self.manager_status())
        return Outcome(CommandResult.ACCEPTED), []

    def _set(self, origin: Origin, pitch_deg: float, yaw_deg: float, pitch_rate: float, yaw_rate: float,
             flags: int) -> Outcome:  # fmt: skip
        g = self.control
        if g is None:
            return Outcome(CommandResult.UNSUPPORTED)
        now, yaw_now = self._now(), self._yaw()
        if flags & _REST:
            g.set_neutral()
            return Outcome(CommandResult.ACCEPTED)
        if math.isfinite(pitch_deg) and not (PITCH_MIN_DEG <= pitch_deg <= PITCH_MAX_DEG):
            clamped = min(max(pitch_deg, PITCH_MIN_DEG), PITCH_MAX_DEG)
            self.statustext(origin, Severity.INFO,
                            f"Gimbal pitch {pitch_deg:g} outside [{PITCH_MIN_DEG:g}, {PITCH_MAX_DEG:g}]: {clamped:g}")  # fmt: skip
        g.set_angles(now, yaw_now, pitch_deg, yaw_deg, bool(flags & _YAW_EARTH), pitch_rate, yaw_rate)
        return Outcome(CommandResult.ACCEPTED)

    def _pitchyaw(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        if self.control is None:
            return Outcome(CommandResult.UNSUPPORTED), []
        if not self._in_control(origin):
            return self._not_in_control(origin), []
        if req.is_int:  # COMMAND_INT carries the flags in x (CommandRequest made it lat = x * 1e-7)
            flags = round(req.lat_deg * 1e7) if math.isfinite(req.lat_deg) else 0
        else:
            flags = int(req.lat_deg) if math.isfinite(req.lat_deg) and req.lat_deg >= 0 else 0
        return self._set(origin, req.p1, req.p2, req.p3, req.p4, flags), []

    def _roi_location(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        g = self.control
        if g is None:
            return Outcome(CommandResult.UNSUPPORTED), []
        lat, lon = req.lat_deg, req.lon_deg
        if not (
            math.isfinite(lat) and math.isfinite(lon) and -90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0
        ):
            return Outcome(CommandResult.DENIED, "ROI: latitude/longitude missing or out of range"), []
        geo = self.vehicle.geo
        north, east, _ = geo.global_to_ned(lat, lon, geo.alt_amsl_m)
        down = self.down_from_alt(req.alt_m, req.frame)
        if down is None:  # no altitude: the ground
            down = float(self.vehicle.autopilot.eav.ground_z_ned_m)
        g.set_roi((north, east, down))
        return Outcome(CommandResult.ACCEPTED), []

    def _roi_none(self, origin: Origin, req: CommandRequest) -> tuple[Outcome, list[MavMessage]]:
        g = self.control
        if g is None:
            return Outcome(CommandResult.UNSUPPORTED), []
        g.set_neutral()
        return Outcome(CommandResult.ACCEPTED), []

    # --- messages in --------------------------------------------------------------------------
    def _ignored(self, origin: Origin, why: str) -> None:
        self.setpoints_ignored += 1
        now = self._now()
        if now - self._last_ignored_warn_s >= IGNORED_WARN_INTERVAL_S:
            self._last_ignored_warn_s = now
            self.statustext(origin, Severity.WARNING, f"Gimbal setpoint ignored: {why}")

    def handle_set_attitude(self, origin: Origin, msg: MavMessage) -> None:
        """GIMBAL_MANAGER_SET_ATTITUDE (282): q (w, x, y, z; NaN: rates only) and angular velocity (rad/s)."""
        if self.control is None:
            return
        if not self._in_control(origin):
            self._ignored(origin, f"{origin.sysid}/{origin.compid} is not in control")
            return
        flags = int(msg.flags)
        q = tuple(float(v) for v in msg.q)
        rates = (float(msg.angular_velocity_y), float(msg.angular_velocity_z))
        pitch = yaw = math.nan
        if all(math.isfinite(v) for v in q) and any(v != 0.0 for v in q):
            _, p, y = euler_from_quat((q[0], q[1], q[2], q[3]))
            pitch, yaw = math.degrees(p), math.degrees(y)
        elif not (flags & _REST) and not any(math.isfinite(r) for r in rates):
            self._ignored(origin, "no finite attitude or rate")
            return
        self._set(origin, pitch, yaw, math.degrees(rates[0]), math.degrees(rates[1]), flags)

    def handle_set_pitchyaw(self, origin: Origin, msg: MavMessage) -> None:
        """GIMBAL_MANAGER_SET_PITCHYAW (287): pitch, yaw (rad; NaN: unchanged), rates (rad/s), flags."""
        if self.control is None:
            return
        if not self._in_control(origin):
            self._ignored(origin, f"{origin.sysid}/{origin.compid} is not in control")
            return
        vals = (float(msg.pitch), float(msg.yaw), float(msg.pitch_rate), float(msg.yaw_rate))
        if not any(math.isfinite(v) for v in vals) and not (int(msg.flags) & _REST):
            self._ignored(origin, "no finite angle or rate")
            return
        d = [math.degrees(v) for v in vals]
        self._set(origin, d[0], d[1], d[2], d[3], int(msg.flags))


__all__ = ["GIMBAL_DEVICE_ID", "GimbalManager", "euler_from_quat", "quat_from_euler"]
