#!/usr/bin/env python3
"""Take off, hover, land — the classic gRPC MAVSDK-Python API that most existing mission code uses.

That API (`System()`, `await drone.connect(...)`, `drone.telemetry.position()` as a stream) lives in
`pip install mavsdk-grpc` (import `mavsdk_grpc`) and in `mavsdk<4` (import `mavsdk`); both start a bundled
`mavsdk_server` and talk to it over gRPC (--grpc-port, 50051 by default: give each concurrent script its own).

    viva-sitl run &
    python grpc_takeoff_land.py                              # default udpin://0.0.0.0:14540
    python grpc_takeoff_land.py udpin://0.0.0.0:14541 --grpc-port 50052   # second vehicle

Waits are telemetry conditions, never fixed sleeps. Exit status 0 on success, 1 on failure.
The script ends with os._exit(): the gRPC API's mavsdk_server log thread can keep a finished process alive.
"""

from __future__ import annotations

import argparse
import asyncio
import os
import sys
from typing import Any

from _mission import MissionFailed, add_time_limits, log, run_flight, script_parser, wait_for

try:  # mavsdk-grpc (current home of the classic API)
    from mavsdk_grpc import System
    from mavsdk_grpc.action import ActionError
except ImportError:  # mavsdk<4 (the same API under the old name)
    from mavsdk import System  # type: ignore[no-redef]
    from mavsdk.action import ActionError  # type: ignore[no-redef]


async def fly(args: argparse.Namespace) -> dict[str, Any]:
    try:
        drone = System(port=args.grpc_port)
    except TypeError as exc:  # `mavsdk` 4.x is the native binding: System() raises there
        raise MissionFailed(f"the classic API is not installed (pip install mavsdk-grpc): {exc}") from exc
    log(f"starting mavsdk_server on gRPC port {args.grpc_port}, connecting to {args.url}")
    try:
        return await _fly(args, drone)
    finally:
        # The classic API has no public close(); its atexit hook kills mavsdk_server, but os._exit skips atexit.
        stop_server = getattr(drone, "_stop_mavsdk_server", None)
        if stop_server is not None:
            stop_server()


async def _fly(args: argparse.Namespace, drone: Any) -> dict[str, Any]:
    step = args.step_timeout
    try:  # mavsdk_server serves gRPC only once it has heard a vehicle, so connect() waits for one
        await asyncio.wait_for(drone.connect(system_address=args.url), step)
    except TimeoutError:
        raise MissionFailed(f"timed out after {step:.0f} s waiting for a vehicle on {args.url}") from None
    await wait_for(drone.core.connection_state(), lambda s: s.is_connected, step, f"a vehicle on {args.url}")
    log("connected")
    await wait_for(
        drone.telemetry.health(),
        lambda h: h.is_global_position_ok and h.is_home_position_ok and h.is_armable,
        step,
        "health: global position, home position and armable",
    )
    log("health ok")
    try:
        await drone.action.set_takeoff_altitude(args.altitude)
        await drone.action.arm()
        log("armed")
        await drone.action.takeoff()
    except ActionError as exc:
        raise MissionFailed(f"command refused: {exc}") from exc
    log(f"taking off to {args.altitude:.1f} m")
    reached = await wait_for(
        drone.telemetry.position(),
        lambda p: p.relative_altitude_m >= args.altitude - args.alt_tolerance,
        step,
        f"relative altitude >= {args.altitude - args.alt_tolerance:.1f} m",
    )
    log(f"reached {reached.relative_altitude_m:.2f} m")
    await wait_for(drone.telemetry.in_air(), lambda a: a, step, "in air")
    await wait_for(
        drone.telemetry.velocity_ned(), lambda v: abs(v.down_m_s) < 0.2, step, "vertical speed < 0.2 m/s"
    )
    hover = await wait_for(drone.telemetry.position(), lambda p: True, step, "a position")
    if abs(hover.relative_altitude_m - args.altitude) > args.alt_tolerance:
        raise MissionFailed(
            f"hovering at {hover.relative_altitude_m:.2f} m, expected {args.altitude:.2f} ± {args.alt_tolerance} m"
        )
    log(f"hovering at {hover.relative_altitude_m:.2f} m")
    try:
        await drone.action.land()
    except ActionError as exc:
        raise MissionFailed(f"land refused: {exc}") from exc
    log("landing")
    await wait_for(drone.telemetry.in_air(), lambda a: not a, step, "touchdown (in_air false)")
    log("touched down")
    await wait_for(drone.telemetry.armed(), lambda a: not a, step, "auto-disarm after landing")
    log("disarmed")
    return {"hover_alt_m": round(hover.relative_altitude_m, 3)}


def main() -> int:
    parser = script_parser(__doc__, "udpin://0.0.0.0:14540", "MAVSDK connection URL")
    parser.add_argument("--altitude", type=float, default=5.0, help="takeoff altitude above home, m")
    parser.add_argument("--alt-tolerance", type=float, default=0.5, help="accepted hover altitude error, m")
    parser.add_argument(
        "--grpc-port", type=int, default=50051, help="local TCP port for mavsdk_server's gRPC"
    )
    add_time_limits(parser, 120.0)
    args = parser.parse_args()
    return run_flight(fly(args), args.timeout)


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # not sys.exit: mavsdk_server's log-reader thread can hang interpreter shutdown
