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
import asyncio
import contextlib
import sys
import time
from collections.abc import AsyncGenerator, Callable
from typing import Any, TypeVar

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
from mavsdk.asyncio.plugins.telemetry import LandedState, TelemetryAsync

T = TypeVar("T")


class MissionFailed(Exception):
    """A check failed or a command was refused: the message is what the user sees."""


def log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


async def wait_for(
    stream: AsyncGenerator[T, None], predicate: Callable[[T], bool], timeout_s: float, what: str
) -> T:
    """First value of a telemetry stream satisfying `predicate`; MissionFailed after timeout_s (wall seconds)."""

    async def first() -> T:
        async with contextlib.aclosing(stream):  # closing the generator unsubscribes
            async for value in stream:
                if predicate(value):
                    return value
        raise MissionFailed(f"telemetry stream ended while waiting for {what}")

    try:
        return await asyncio.wait_for(first(), timeout_s)
    except TimeoutError:
        raise MissionFailed(f"timed out after {timeout_s:.0f} s waiting for {what}") from None


async def fly(args: argparse.Namespace) -> dict[str, Any]:
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as mavsdk:
        log(f"connecting to {args.url}")
        await mavsdk.add_any_connection(args.url)
        system = await mavsdk.first_autopilot(timeout_s=args.step_timeout)
        if system is None:
            raise MissionFailed(f"no autopilot heartbeat on {args.url} within {args.step_timeout:.0f} s")
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
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("url", nargs="?", default="udpin://0.0.0.0:14540", help="MAVSDK connection URL")
    parser.add_argument("--altitude", type=float, default=5.0, help="takeoff altitude above home, m")
    parser.add_argument("--alt-tolerance", type=float, default=0.5, help="accepted hover altitude error, m")
    parser.add_argument("--timeout", type=float, default=120.0, help="whole-flight limit, wall seconds")
    parser.add_argument("--step-timeout", type=float, default=60.0, help="limit for each wait, wall seconds")
    args = parser.parse_args()
    try:
        result = asyncio.run(asyncio.wait_for(fly(args), args.timeout))
    except MissionFailed as exc:
        print(f"FAILED: {exc}", file=sys.stderr, flush=True)
        return 1
    except TimeoutError:
        print(
            f"FAILED: the flight took longer than --timeout {args.timeout:.0f} s", file=sys.stderr, flush=True
        )
        return 1
    print("RESULT " + " ".join(f"{k}={v}" for k, v in result.items()), flush=True)
    log("success")
    return 0


if __name__ == "__main__":
    sys.exit(main())
