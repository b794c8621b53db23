#!/usr/bin/env python3
"""Position-target landing at a chosen spot with MAVSDK-Python 4.x (`pip install mavsdk`).

1. take off (AUTO.TAKEOFF) to --altitude;
2. OFFBOARD with position setpoints (SET_POSITION_TARGET_LOCAL_NED): fly to (--north, --east) at that altitude,
   then descend over the spot to --approach-alt;
3. leave offboard (Hold) and land (AUTO.LAND); wait for touchdown and auto-disarm;
4. report the touchdown error, the horizontal distance between where it landed and the chosen spot, and fail
   when it exceeds --tolerance.

North/east are metres in the local NED frame, whose origin is where the vehicle started (home).

    viva-sitl run &
    python mavsdk_precision_land.py --north 8 --east -5 --tolerance 0.5

Waits are telemetry conditions; the only sleeps pace the setpoint stream. Exit status 0 on success, 1 on failure.
"""

from __future__ import annotations

import argparse
import math
import sys
from typing import Any

from _mission import (
    MissionFailed,
    Tracker,
    add_time_limits,
    first_autopilot,
    log,
    run_flight,
    script_parser,
    stop_and_land,
    stream_until,
    takeoff,
)
from mavsdk.asyncio.plugins.action import ActionAsync
from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError, PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync


async def fly(args: argparse.Namespace) -> dict[str, Any]:
    async with first_autopilot(args.url, args.step_timeout) as system:
        telemetry, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        async with Tracker(telemetry).running(args.step_timeout) as tracker:
            await takeoff(tracker, telemetry, action, args.altitude, args.step_timeout)
            await approach(args, tracker, offboard)
            await stop_and_land(tracker, action, offboard, args.step_timeout)
            n, e, _ = tracker.ned
    error_m = math.hypot(n - args.north, e - args.east)
    log(
        f"touched down at ({n:.2f}, {e:.2f}) m; target ({args.north:.2f}, {args.east:.2f}) m; error {error_m:.2f} m"
    )
    if error_m > args.tolerance:
        raise MissionFailed(f"touchdown error {error_m:.2f} m exceeds the tolerance {args.tolerance} m")
    return {
        "touchdown_north_m": round(n, 3),
        "touchdown_east_m": round(e, 3),
        "touchdown_error_m": round(error_m, 3),
    }


async def approach(args: argparse.Namespace, tr: Tracker, offboard: OffboardAsync) -> None:
    step = args.step_timeout
    yaw = tr.yaw_deg
    await offboard.set_position_ned(
        PositionNedYaw(*tr.ned, yaw)
    )  # hold here first: a setpoint before start()
    try:
        await offboard.start()
    except OffboardError as exc:
        raise MissionFailed(f"offboard refused: {exc}") from exc
    await tr.wait_until(lambda: tr.mode == FlightMode.OFFBOARD, step, "flight mode OFFBOARD")
    log("offboard (position) active")

    for label, down_m in (("cruise", -args.altitude), ("approach", -args.approach_alt)):
        target = PositionNedYaw(args.north, args.east, down_m, yaw)

        async def send(target: PositionNedYaw = target) -> None:
            await offboard.set_position_ned(target)

        def arrived(target: PositionNedYaw = target) -> bool:
            n, e, d = tr.ned
            return (
                math.hypot(n - target.north_m, e - target.east_m) < args.arrive_radius
                and abs(d - target.down_m) < 0.3
                and math.hypot(*tr.vel) < 0.3
            )

        await stream_until(
            tr,
            send,
            arrived,
            step,
            f"{label} point ({target.north_m:.1f}, {target.east_m:.1f}, {target.down_m:.1f})",
        )
        n, e, d = tr.ned
        log(f"{label}: at ({n:.2f}, {e:.2f}, {d:.2f}) m")


def main() -> int:
    parser = script_parser(__doc__, "udpin://0.0.0.0:14540", "MAVSDK connection URL")
    parser.add_argument("--north", type=float, default=8.0, help="landing spot, metres north of home")
    parser.add_argument("--east", type=float, default=-5.0, help="landing spot, metres east of home")
    parser.add_argument("--altitude", type=float, default=10.0, help="takeoff and cruise altitude, m")
    parser.add_argument(
        "--approach-alt", type=float, default=3.0, help="altitude over the spot before LAND, m"
    )
    parser.add_argument(
        "--arrive-radius", type=float, default=0.2, help="horizontal radius counted as over the spot"
    )
    parser.add_argument("--tolerance", type=float, default=1.0, help="accepted touchdown error, m")
    add_time_limits(parser, 180.0)
    args = parser.parse_args()
    if not all(math.isfinite(v) for v in (args.north, args.east, args.altitude, args.approach_alt)):
        parser.error("--north, --east, --altitude and --approach-alt must be finite numbers")
    return run_flight(fly(args), args.timeout)


if __name__ == "__main__":
    sys.exit(main())
