"""MAVLink endpoint that makes viva-sitl look like PX4 SITL (pymavlink as codec only, asyncio UDP I/O).

    endpoint = MavlinkEndpoint(vehicle, MavlinkConfig(instance=0))   # vehicle satisfies VehicleLink
    await endpoint.start()        # binds 127.0.0.1:14580 (API, -> :14540) and :18570 (GCS, -> :14550), starts tasks
    ...                           # the vehicle steps Autopilot.update on the same asyncio loop
    await endpoint.stop()         # cancels and awaits its tasks, closes the sockets
    endpoint.stats                # dict: rx/tx counts, bad frames, setpoints handled/rejected, ...

Modules, one per concern: codec (datagram parser, encoders), endpoint (links, peers, dispatch, tasks), telemetry
(messages + per-link rates), commands (COMMAND_LONG/INT -> Autopilot), params, mission, offboard (setpoint decoding),
camera (compid 100; its CameraLink protocol and data types in camera_link), logs (the MAVLink log protocol over
the run's ULog files), calibration (MAV_CMD_PREFLIGHT_CALIBRATION with PX4's "[cal]" texts), selftest (a minimal vehicle for
`python -m viva_sitl.mavlink.selftest`; the test clients live in tests/mav_client.py).
The endpoint consumes Autopilot.pop_events() (STATUSTEXT, MISSION_ITEM_REACHED); add_event_listener() lets the app
log the same texts.
"""

from viva_sitl.mavlink.base import Component, LinkKind, VehicleLink
from viva_sitl.mavlink.camera_link import (
    CameraInfo,
    CameraLink,
    CaptureResult,
    StreamEncoding,
    VideoStreamSpec,
)
from viva_sitl.mavlink.endpoint import EndpointStats, MavlinkConfig, MavlinkEndpoint
from viva_sitl.mavlink.telemetry import StreamProfile

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
