"""What every MAVLink concern module shares: the vehicle protocol, message origins, the outbox, small helpers.

pymavlink is used only as a codec (`pymavlink.dialects.v20.common`); no module here touches a socket.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol, TypeAlias

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.autopilot.autopilot import Autopilot
from viva_sitl.dynamics import EavState
from viva_sitl.geo import GeoOrigin
from viva_sitl.mavlink.camera_link import CameraLink

MavMessage: TypeAlias = mavlink2.MAVLink_message
M = mavlink2

STATUSTEXT_CHUNK_CHARS = (
    50  # STATUSTEXT.text is char[50]; longer texts go out in chunks (MAVLink 2 id/chunk_seq)
)
INT32_MAX = 2**31 - 1
UINT16_MAX = 0xFFFF


class Component(enum.IntEnum):
    """The MAVLink components this vehicle exposes."""

    AUTOPILOT = mavlink2.MAV_COMP_ID_AUTOPILOT1  # 1
    CAMERA = mavlink2.MAV_COMP_ID_CAMERA  # 100


class LinkKind(enum.Enum):
    """The two UDP links of PX4 SITL: the API/offboard link (14540) and the ground-station link (14550)."""

    API = "api"
    GCS = "gcs"


class VehicleLink(Protocol):
    """What the endpoint needs from the vehicle (the lead's app satisfies it).

    All attributes are read on the asyncio loop that runs the endpoint; the autopilot is called from that loop too,
    so the vehicle must step the autopilot on the same loop (or guard it).
    """

    @property
    def autopilot(self) -> Autopilot: ...
    @property
    def state(self) -> EavState: ...  # latest physics state
    @property
    def time_s(self) -> float: ...  # simulation time, s
    @property
    def geo(self) -> GeoOrigin: ...  # the NED origin on the ground
    @property
    def boot_wall_time_s(self) -> float: ...  # time.time() when the vehicle started
    @property
    def camera(self) -> CameraLink | None: ...


@dataclass(frozen=True)
class Origin:
    """Where a received message came from: the link, the peer's UDP address and its MAVLink ids."""

    link: LinkKind
    addr: tuple[str, int]
    sysid: int
    compid: int


class Outbox(Protocol):
    """How a concern module sends: `reply` to the peer a message came from, `broadcast` to every peer of every link."""

    def reply(self, origin: Origin, msg: MavMessage, component: Component = Component.AUTOPILOT) -> None: ...
    def broadcast(self, msg: MavMessage, component: Component = Component.AUTOPILOT) -> None: ...


def time_boot_ms(vehicle: VehicleLink) -> int:
    """PX4 SITL reports time since boot in simulation time (lockstep); uint32 wraps."""
    t = vehicle.time_s
    return int(t * 1000.0) & 0xFFFFFFFF if math.isfinite(t) and t >= 0 else 0


def time_boot_us(vehicle: VehicleLink) -> int:
    t = vehicle.time_s
    return int(t * 1e6) if math.isfinite(t) and t >= 0 else 0


def finite(*values: float) -> bool:
    return all(math.isfinite(v) for v in values)


def fixed_bytes(text: str, size: int) -> bytes:
    """A MAVLink uint8[size] / char[size] field: ASCII, truncated, zero padded."""
    return text.encode("ascii", errors="replace")[:size].ljust(size, b"\0")


def statustext_messages(severity: int, text: str, chunk_id: int) -> list[MavMessage]:
    """STATUSTEXT message(s) for `text`: one when it fits in 50 chars, else MAVLink 2 chunks sharing `chunk_id`."""
    raw = text.encode("ascii", errors="replace") or b" "
    if len(raw) <= STATUSTEXT_CHUNK_CHARS:
        return [mavlink2.MAVLink_statustext_message(severity, raw)]
    chunks = [raw[i : i + STATUSTEXT_CHUNK_CHARS] for i in range(0, len(raw), STATUSTEXT_CHUNK_CHARS)][:255]
    return [
        mavlink2.MAVLink_statustext_message(severity, c, chunk_id & 0xFFFF or 1, i)
        for i, c in enumerate(chunks)
    ]


def clamp_int(value: float, lo: int, hi: int) -> int:
    """Round and clamp a float into an integer wire field; NaN/inf map to the range edge nearest to 0."""
    if not math.isfinite(value):
        return lo if value < 0 else (hi if value > 0 else max(lo, min(hi, 0)))
    return max(lo, min(hi, int(round(value))))


@dataclass(frozen=True)
class CommandRequest:
    """A COMMAND_LONG or COMMAND_INT, normalised. lat/lon in degrees (NaN = not given), alt in `frame`."""

    command: int
    p1: float
    p2: float
    p3: float
    p4: float
    lat_deg: float
    lon_deg: float
    alt_m: float
    frame: int  # COMMAND_LONG: MAV_FRAME_GLOBAL (param7 AMSL, as PX4 reads it)
    is_int: bool
    target_component: int

    @classmethod
    def from_long(cls, msg: MavMessage) -> CommandRequest:
        return cls(
            int(msg.command), float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4),
            float(msg.param5), float(msg.param6), float(msg.param7), M.MAV_FRAME_GLOBAL, False,
            int(msg.target_component),
        )  # fmt: skip

    @classmethod
    def from_int(cls, msg: MavMessage) -> CommandRequest:
        x, y = int(msg.x), int(msg.y)
        # INT32_MAX marks "not given"; (0, 0) is never a real target either (PX4 reads it as unset)
        unset = x == INT32_MAX or y == INT32_MAX or (x == 0 and y == 0)
        lat = math.nan if unset else x * 1e-7
        lon = math.nan if unset else y * 1e-7
        return cls(
            int(msg.command), float(msg.param1), float(msg.param2), float(msg.param3), float(msg.param4),
            lat, lon, float(msg.z), int(msg.frame), True, int(msg.target_component),
        )  # fmt: skip

    @property
    def params(self) -> tuple[float, float, float, float, float, float, float]:
        return (self.p1, self.p2, self.p3, self.p4, self.lat_deg, self.lon_deg, self.alt_m)


EventListener = Callable[[str, int], None]  # (text, severity) for the app's log


class StatusSink(Protocol):
    """Sends a STATUSTEXT: to the peer of `origin`, or to everyone when origin is None."""

    def __call__(self, origin: Origin | None, severity: int, text: str) -> None: ...
