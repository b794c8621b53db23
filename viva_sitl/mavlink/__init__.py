"""MAVLink endpoint that makes viva-sitl look like PX4 SITL (pymavlink as codec only, asyncio UDP I/O).

    endpoint = MavlinkEndpoint(vehicle, MavlinkConfig(instance=0))   # vehicle satisfies VehicleLink
    await endpoint.start()        # binds 127.0.0.1:14580 (API, -> :14540) and :18570 (GCS, -> :14550), starts tasks
    ...                           # the vehicle steps Autopilot.update on the same asyncio loop
    await endpoint.stop()         # cancels and awaits its tasks, closes the sockets
    endpoint.stats                # dict: rx/tx counts, bad frames, setpoints handled/rejected, ...

Modules, one per concern: config (the `[mavlink]` table, the endpoint's counters and start-up errors; no pymavlink),
codec (datagram parser, encoders, message ids), endpoint (the composition of links: transport, peers; dispatch:
message -> handler; schedule: sim-clock streams; testing: the in-memory, sim-clock harness), telemetry (messages +
per-link rates), commands (COMMAND_LONG/INT -> Autopilot), params, mission, offboard (setpoint decoding), camera
(compid 100; its CameraLink protocol and data types in camera_link), logs (the MAVLink log protocol over the run's
ULog files), calibration (MAV_CMD_PREFLIGHT_CALIBRATION with PX4's "[cal]" texts). A minimal paced vehicle for the
endpoint is viva_sitl.selftest (`python -m viva_sitl.selftest`); the test clients live in tests/mav_client.py.
The endpoint consumes Autopilot.pop_events() (STATUSTEXT, MISSION_ITEM_REACHED); add_event_listener() lets the app
log the same texts.

This face imports only the config at once; the other names load their module (and pymavlink) on first use, so that
`viva_sitl.config` can build a MavlinkConfig without the codec.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from viva_sitl.mavlink.config import EndpointStats, MavlinkConfig, StreamProfile

if TYPE_CHECKING:
    from viva_sitl.mavlink.base import Component, LinkKind, VehicleLink
    from viva_sitl.mavlink.camera_link import (
        CameraInfo,
        CameraLink,
        CaptureResult,
        StreamEncoding,
        VideoStreamSpec,
    )
    from viva_sitl.mavlink.endpoint import MavlinkEndpoint

_BASE = {"Component", "LinkKind", "VehicleLink"}
_CAMERA_LINK = {"CameraInfo", "CameraLink", "CaptureResult", "StreamEncoding", "VideoStreamSpec"}


def __getattr__(name: str) -> Any:
    if name in _BASE:
        from viva_sitl.mavlink import base

        return getattr(base, name)
    if name in _CAMERA_LINK:
        from viva_sitl.mavlink import camera_link

        return getattr(camera_link, name)
    if name == "MavlinkEndpoint":
        from viva_sitl.mavlink import endpoint

        return endpoint.MavlinkEndpoint
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "CameraInfo",
    "CameraLink",
    "CaptureResult",
    "Component",
    "EndpointStats",
    "LinkKind",
    "MavlinkConfig",
    "MavlinkEndpoint",
    "StreamEncoding",
    "StreamProfile",
    "VehicleLink",
    "VideoStreamSpec",
]
