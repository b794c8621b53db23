"""Shared autopilot types: flight modes (PX4 custom_mode encoding), landed states, command results, setpoints.

This module is the contract between the autopilot (pure logic, no I/O) and the MAVLink layer.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class MainMode(enum.IntEnum):
    """PX4 main modes (px4_custom_mode.h)."""

    MANUAL = 1
    ALTCTL = 2
    POSCTL = 3
    AUTO = 4
    ACRO = 5
    OFFBOARD = 6
    STABILIZED = 7


class AutoSubMode(enum.IntEnum):
    READY = 1
    TAKEOFF = 2
    LOITER = 3
    MISSION = 4
    RTL = 5
    LAND = 6
    FOLLOW_TARGET = 8


class PosctlSubMode(enum.IntEnum):
    POSCTL = 0
    ORBIT = 1


class FlightMode(enum.Enum):
    """The modes viva-sitl flies, with PX4's (main, sub) pair."""

    MANUAL = (MainMode.MANUAL, 0)
    ALTCTL = (MainMode.ALTCTL, 0)
    POSCTL = (MainMode.POSCTL, 0)
    OFFBOARD = (MainMode.OFFBOARD, 0)
    STABILIZED = (MainMode.STABILIZED, 0)
    AUTO_READY = (MainMode.AUTO, AutoSubMode.READY)
    AUTO_TAKEOFF = (MainMode.AUTO, AutoSubMode.TAKEOFF)
    AUTO_LOITER = (MainMode.AUTO, AutoSubMode.LOITER)
    AUTO_MISSION = (MainMode.AUTO, AutoSubMode.MISSION)
    AUTO_RTL = (MainMode.AUTO, AutoSubMode.RTL)
    AUTO_LAND = (MainMode.AUTO, AutoSubMode.LAND)
    AUTO_FOLLOW_TARGET = (MainMode.AUTO, AutoSubMode.FOLLOW_TARGET)  # PX4's Follow Me
    ORBIT = (MainMode.POSCTL, PosctlSubMode.ORBIT)  # PX4 NAVIGATION_STATE_ORBIT

    @property
    def custom_mode(self) -> int:
        """HEARTBEAT.custom_mode: main_mode << 16 | sub_mode << 24 (e.g. OFFBOARD 393216, AUTO_LOITER 50593792)."""
        main, sub = self.value
        return (int(main) << 16) | (int(sub) << 24)

    @classmethod
    def from_px4(cls, main_mode: int, sub_mode: int = 0) -> FlightMode:
        """Decode DO_SET_MODE p2/p3 (or custom_mode fields). Raises ValueError for unknown pairs.

        PX4 maps AUTO with sub 0 to AUTO_LOITER; POSCTL with sub 1 is Orbit; other main modes ignore the sub mode.
        """
        if main_mode == MainMode.AUTO and sub_mode == 0:
            return cls.AUTO_LOITER
        if main_mode == MainMode.POSCTL:
            return cls.ORBIT if sub_mode == PosctlSubMode.ORBIT else cls.POSCTL
        for mode in cls:
            m, s = mode.value
            if m == main_mode and (m == MainMode.AUTO and s == sub_mode or m != MainMode.AUTO):
                return mode
        raise ValueError(f"unknown PX4 mode main={main_mode} sub={sub_mode}")

    @classmethod
    def from_custom_mode(cls, custom_mode: int) -> FlightMode:
        return cls.from_px4((custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF)


class LandedState(enum.IntEnum):
    """MAV_LANDED_STATE."""

    UNDEFINED = 0
    ON_GROUND = 1
    IN_AIR = 2
    TAKEOFF = 3
    LANDING = 4


class CommandResult(enum.IntEnum):
    """MAV_RESULT values, returned by every autopilot command."""

    ACCEPTED = 0
    TEMPORARILY_REJECTED = 1
    DENIED = 2
    UNSUPPORTED = 3
    FAILED = 4
    IN_PROGRESS = 5


@dataclass(frozen=True)
class Outcome:
    """A command's result and, when refused, the reason a pilot sees (sent as STATUSTEXT)."""

    result: CommandResult
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.result == CommandResult.ACCEPTED


ACCEPTED = Outcome(CommandResult.ACCEPTED)


class Severity(enum.IntEnum):
    """MAV_SEVERITY."""

    EMERGENCY = 0
    ALERT = 1
    CRITICAL = 2
    ERROR = 3
    WARNING = 4
    NOTICE = 5
    INFO = 6
    DEBUG = 7


@dataclass(frozen=True)
class Event:
    """Something a pilot should see (STATUSTEXT), or a mission milestone."""

    time_s: float
    severity: Severity
    text: str
    mission_item_reached: int | None = None  # set: also send MISSION_ITEM_REACHED(seq)


class OffboardFrame(enum.IntEnum):
    LOCAL_NED = 1
    BODY_NED = 8  # MAV_FRAME_BODY_NED: velocities/positions rotated by the vehicle's yaw
    GLOBAL = 6  # from SET_POSITION_TARGET_GLOBAL_INT, already converted to local NED by the caller


@dataclass(frozen=True)
class PositionTarget:
    """SET_POSITION_TARGET_LOCAL_NED after decoding the type_mask: None = ignored component. NED metres, rad."""

    pos_ned_m: tuple[float, float, float] | None = None
    vel_ned_m_s: tuple[float, float, float] | None = None
    acc_ned_m_s2: tuple[float, float, float] | None = None
    yaw_rad: float | None = None
    yaw_rate_rad_s: float | None = None
    frame: OffboardFrame = OffboardFrame.LOCAL_NED


@dataclass(frozen=True)
class AttitudeTarget:
    """SET_ATTITUDE_TARGET: attitude quaternion (w, x, y, z) or body rates (rad/s), thrust 0..1."""

    q_wxyz: tuple[float, float, float, float] | None
    body_rates_rad_s: tuple[float, float, float] | None
    thrust_norm: float  # 0..1, MPC_THR_HOVER hovers


@dataclass(frozen=True)
class ManualInput:
    """MANUAL_CONTROL normalised to -1..1 (x pitch/forward, y roll/right, r yaw) and 0..1 (z throttle)."""

    x: float
    y: float
    z: float
    r: float


class MissionCommand(enum.IntEnum):
    """MAV_CMD values accepted as mission items (OTHER: a MAV_CMD we accept, log and skip; see raw_command)."""

    OTHER = -1
    NAV_WAYPOINT = 16
    NAV_LOITER_TIME = 19
    NAV_RETURN_TO_LAUNCH = 20
    NAV_LAND = 21
    NAV_TAKEOFF = 22
    NAV_DELAY = 93
    DO_JUMP = 177
    DO_CHANGE_SPEED = 178
    DO_SET_ROI_LOCATION = 195
    DO_SET_ROI_NONE = 197
    DO_SET_ROI = 201
    DO_MOUNT_CONTROL = 205
    DO_SET_CAM_TRIGG_DIST = 206
    DO_GIMBAL_MANAGER_PITCHYAW = 1000
    IMAGE_START_CAPTURE = 2000
    IMAGE_STOP_CAPTURE = 2001


@dataclass(frozen=True)
class MissionItem:
    """One mission item, already converted to local NED by the MAVLink layer (down_m is NED z of the target)."""

    seq: int
    command: MissionCommand
    north_m: float
    east_m: float
    down_m: float
    param1: float = 0.0  # hold time (s) / LOITER_TIME time / DO_CHANGE_SPEED speed type
    param2: float = 0.0  # acceptance radius (m) / DO_CHANGE_SPEED speed (m/s)
    param3: float = 0.0
    param4: float = float("nan")  # yaw (deg), NaN = keep
    autocontinue: bool = True
    # GLOBAL_RELATIVE_ALT items: metres above home, resolved against home when the item starts (NaN: use down_m)
    alt_rel_home_m: float = float("nan")
    raw_command: int = 0  # the MAV_CMD number as uploaded (OTHER items keep theirs here)


@dataclass(frozen=True)
class PayloadAction:
    """A camera action a mission item (or the distance trigger) asks for; the MAVLink layer routes it to the
    camera component. kind: "capture_start" (interval_s, total), "capture_stop", "capture_once"."""

    kind: str
    interval_s: float = 0.0
    total: int = 1
