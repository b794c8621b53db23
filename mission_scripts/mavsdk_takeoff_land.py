#!/usr/bin/env python3
"""Take off, hover, land — MAVSDK-Python 4.x native API (`pip install mavsdk`).

Works unchanged against PX4 SITL and viva-sitl:

    viva-sitl run &                          # or: make px4_sitl gz_x500
    python mavsdk_takeoff_land.py            # default udpin://0.0.0.0:14540
    python mavsdk_takeoff_land.py udpin://0.0.0.0:14541 --altitude 5   # second vehicle (--instance 1)

Every step waits on telemetry (health, altitude, landed state, armed), never on a fixed sleep.
Exit status: 0 on success, 1 on a failed check, a rejected command or a timeout (the message says which).
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

from _mission import MissionFailed, add_time_limits, first_autopilot, log, run_flight, script_parser, wait_for
from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
from mavsdk.asyncio.plugins.telemetry import LandedState, TelemetryAsync


async def fly(args: argparse.Namespace) -> dict[str, Any]:
    async with first_autopilot(args.url, args.step_timeout) as system:
        log(f"connected to system {await system.get_system_id()}")
        telemetry, action = TelemetryAsync(system), ActionAsync(system)

        await wait_for(
            telemetry.subscribe_health(),
            lambda h: h.is_global_position_ok and h.is_home_position_ok and h.is_armable,
            args.step_timeout,
            "health: global position, home position and armable",
        )
        log("health ok: global position, home, armable")

        try:
            await action.set_takeoff_altitude(args.altitude)
            await action.arm()
            log("armed")
            await action.takeoff()
        except ActionError as exc:
            raise MissionFailed(f"command refused: {exc}") from exc
        log(f"taking off to {args.altitude:.1f} m")

        reached = await wait_for(
            telemetry.subscribe_position(),
            lambda p: p.relative_altitude_m >= args.altitude - args.alt_tolerance,
            args.step_timeout,
            f"relative altitude >= {args.altitude - args.alt_tolerance:.1f} m",
        )
        log(f"reached {reached.relative_altitude_m:.2f} m")
        await wait_for(
            telemetry.subscribe_landed_state(),
            lambda s: s == LandedState.IN_AIR,
            args.step_timeout,
            "landed state IN_AIR",
        )
        # Let the takeoff settle (a telemetry condition: vertical speed small), then check the hover altitude.
        await wait_for(
            telemetry.subscribe_velocity_ned(),
            lambda v: abs(v.down_m_s) < 0.2,
            args.step_timeout,
            "vertical speed < 0.2 m/s after takeoff",
        )
        hover = await wait_for(
            telemetry.subscribe_position(), lambda p: True, args.step_timeout, "a position"
        )
        if abs(hover.relative_altitude_m - args.altitude) > args.alt_tolerance:
            raise MissionFailed(
                f"hovering at {hover.relative_altitude_m:.2f} m, expected {args.altitude:.2f} ± {args.alt_tolerance} m"
            )
        log(f"hovering at {hover.relative_altitude_m:.2f} m")

        try:
            await action.land()
        except ActionError as exc:
            raise MissionFailed(f"land refused: {exc}") from exc
        log("landing")
        await wait_for(
            telemetry.subscribe_landed_state(),
            lambda s: s == LandedState.ON_GROUND,
            args.step_timeout,
            "landed state ON_GROUND",
        )
        log("touched down")
        await wait_for(
            telemetry.subscribe_armed(), lambda a: not a, args.step_timeout, "auto-disarm after landing"
        )
        log("disarmed")
        ground = await wait_for(
            telemetry.subscribe_position(), lambda p: True, args.step_timeout, "a position"
        )
        return {
            "hover_alt_m": round(hover.relative_altitude_m, 3),
            "landed_alt_m": round(ground.relative_altitude_m, 3),
        }


def main() -> int:
    parser = script_parser(__doc__, "udpin://0.0.0.0:14540", "MAVSDK connection URL")
    parser.add_argument("--altitude", type=float, default=5.0, help="takeoff altitude above home, m")
    parser.add_argument("--alt-tolerance", type=float, default=0.5, help="accepted hover altitude error, m")
    add_time_limits(parser, 120.0)
    args = parser.parse_args()
    return run_flight(fly(args), args.timeout)


if __name__ == "__main__":
    sys.exit(main())
