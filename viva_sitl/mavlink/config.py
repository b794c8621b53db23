"""The `[mavlink]` table (`MavlinkConfig`), the endpoint's counters (`EndpointStats`) and its start-up errors.

A leaf that imports no pymavlink: viva_sitl.config builds a MavlinkConfig for every process, and only the endpoint
needs the codec. The checks that need pymavlink's dialect (message names in `rate_overrides`) or the signing code
(`signing_key`) import it when there is something to check.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from viva_sitl.mavlink.signing import SigningState


class StreamProfile(enum.Enum):
    """PX4 mavlink mode whose default rates a link uses."""

    ONBOARD = "onboard"
    NORMAL = "normal"


@dataclass(frozen=True)
class MavlinkConfig:
    """The `[mavlink]` table. Ports left at None follow PX4 SITL's conventions for `instance`; 0 = any free port
    (local) or no default remote (remote: only peers that talk are answered)."""

    instance: int = 0  # PX4 SITL -i N: offsets the API ports and the sysid
    sysid: int | None = None  # None: 1 + instance
    listen_host: str = "127.0.0.1"
    api_remote_host: str = "127.0.0.1"
    api_remote_port: int | None = None  # None: 14540 + instance (MAVSDK's udpin://0.0.0.0:14540)
    gcs_remote_host: str = "127.0.0.1"
    gcs_remote_port: int = 14550  # QGroundControl's auto-connect port, the same for every instance (as PX4)
    api_local_port: int | None = None  # None: 14580 + instance
    gcs_local_port: int | None = None  # None: 18570 + instance
    heartbeat_hz: float = 1.0
    api_profile: StreamProfile = StreamProfile.ONBOARD  # PX4 mavlink mode of the API link ("-m onboard")
    # The issue asks for PX4's onboard rates; PX4 SITL's own GCS link runs the lighter "normal" mode (ATTITUDE 15 Hz,
    # LOCAL_POSITION_NED 1 Hz, ...): choose StreamProfile.NORMAL here to save CPU when only QGC listens there.
    gcs_profile: StreamProfile = StreamProfile.ONBOARD
    rate_overrides: tuple[tuple[str, float], ...] = ()  # (("ATTITUDE", 50.0), ...) Hz for both links; 0 = off
    peer_timeout_s: float = (
        10.0  # sim s: a peer silent this long stops receiving telemetry (default remote: never)
    )
    mission_max_items: int = 1000
    mission_retry_s: float = 0.5  # sim s between mission-protocol retries
    mission_max_retries: int = 5
    tlog: bool = True  # the app records a .tlog (in the run directory unless tlog_path says where)
    tlog_path: str | None = None  # the endpoint records every packet sent/accepted here; None = no log
    signing_key: str | None = None  # MAVLink 2 signing key: 64 hex digits, or a passphrase (its SHA-256)
    sign_cfg: int | None = None  # PX4's MAV_SIGN_CFG: 0 off, 1/2 required (UDP); None: 1 with a key, else 0

    def __post_init__(self) -> None:
        if isinstance(self.api_profile, str):  # accept "onboard"/"normal" from code, like TOML
            object.__setattr__(self, "api_profile", StreamProfile(self.api_profile.lower()))
        if isinstance(self.gcs_profile, str):
            object.__setattr__(self, "gcs_profile", StreamProfile(self.gcs_profile.lower()))
        if not 0 <= self.instance <= 200:
            raise ValueError(f"mavlink.instance must be in 0..200, got {self.instance}")
        if not 1 <= self.system_id <= 255:
            raise ValueError(f"mavlink.sysid must be in 1..255, got {self.system_id}")
        for name in ("api_remote_port", "gcs_remote_port", "api_local_port", "gcs_local_port"):
            port = getattr(self, name)
            if port is not None and not 0 <= port <= 65535:
                raise ValueError(f"mavlink.{name} must be in 0..65535, got {port}")
        for name in ("listen_host", "api_remote_host", "gcs_remote_host"):
            if not getattr(self, name):
                raise ValueError(f"mavlink.{name} must not be empty")
        if not (math.isfinite(self.heartbeat_hz) and 0.2 <= self.heartbeat_hz <= 50.0):
            raise ValueError(
                f"mavlink.heartbeat_hz must be in 0.2..50 (MAVSDK times out after 3 s), got {self.heartbeat_hz}"
            )
        for item in self.rate_overrides:
            if len(item) != 2:
                raise ValueError(f"mavlink.rate_overrides entries are (name, hz), got {item!r}")
            name, hz = item
            from viva_sitl.mavlink.codec import message_id  # pymavlink's dialect: only when there are names

            message_id(str(name))  # ValueError for unknown names
            if not (math.isfinite(float(hz)) and float(hz) >= 0.0):
                raise ValueError(f"mavlink.rate_overrides: rate of {name} must be >= 0 Hz, got {hz!r}")
        if not self.peer_timeout_s > 0:
            raise ValueError(f"mavlink.peer_timeout_s must be > 0, got {self.peer_timeout_s}")
        if not 1 <= self.mission_max_items <= 65535:
            raise ValueError(f"mavlink.mission_max_items must be in 1..65535, got {self.mission_max_items}")
        if not (self.mission_retry_s > 0 and self.mission_max_retries >= 0):
            raise ValueError("mavlink.mission_retry_s must be > 0 and mission_max_retries >= 0")
        if self.signing_key is not None:
            from viva_sitl.mavlink.signing import parse_key

            parse_key(self.signing_key)  # ValueError for an empty key
        if self.sign_cfg is not None and self.sign_cfg not in (0, 1, 2):
            raise ValueError(f"mavlink.sign_cfg (PX4 MAV_SIGN_CFG) must be 0, 1 or 2, got {self.sign_cfg}")

    @property
    def system_id(self) -> int:
        return self.sysid if self.sysid is not None else 1 + self.instance

    @property
    def api_remote_port_resolved(self) -> int:
        return self.api_remote_port if self.api_remote_port is not None else 14540 + self.instance

    @property
    def api_local_port_resolved(self) -> int:
        return self.api_local_port if self.api_local_port is not None else 14580 + self.instance

    @property
    def gcs_local_port_resolved(self) -> int:
        return self.gcs_local_port if self.gcs_local_port is not None else 18570 + self.instance

    def signing_state(self) -> SigningState:
        from viva_sitl.mavlink.signing import SIGN_CFG_NON_USB, SIGN_CFG_OFF, SigningState, parse_key

        key = parse_key(self.signing_key) if self.signing_key is not None else None
        cfg = self.sign_cfg if self.sign_cfg is not None else (SIGN_CFG_NON_USB if key else SIGN_CFG_OFF)
        return SigningState(key, cfg)

    def overrides_hz(self) -> dict[int, float]:
        from viva_sitl.mavlink.codec import message_id

        return {message_id(str(name)): float(hz) for name, hz in self.rate_overrides}


@dataclass
class EndpointStats:
    rx_datagrams: int = 0
    rx_messages: int = 0
    rx_bytes: int = 0
    tx_messages: int = 0
    tx_bytes: int = 0
    bad_frames: int = 0  # bad CRC/length or truncated frames
    garbage_bytes: int = 0
    unknown_messages: int = 0  # message ids not in the dialect
    ignored_messages: int = 0  # known messages we do not handle, or addressed to another system/component
    handler_errors: int = 0  # exceptions caught in a handler (a bug: logged with traceback)
    commands: int = 0
    setpoints_handled: int = 0  # decoded and passed to the autopilot
    setpoints_refused: int = 0  # passed, the autopilot refused (its reason)
    setpoints_rejected: int = 0  # not decodable (NaN/inf, masks, frames): never reached the autopilot
    manual_inputs: int = 0
    send_errors: int = 0
    telemetry_late: int = 0  # telemetry messages due but skipped: one physics step crossed several periods
    unsigned_rejected: int = 0  # signing on: frames without a valid signature, dropped (PX4: not handled)


class EndpointStartError(OSError):
    """The endpoint cannot start (a port it cannot bind, a .tlog it cannot create): `strerror` says why in one line."""


class PortInUseError(EndpointStartError):
    """A MAVLink UDP port is taken (another viva-sitl or PX4 SITL instance): the message names it."""
