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
import asyncio
import contextlib
import math
import sys
import time
from collections.abc import AsyncGenerator, Awaitable, Callable
from typing import Any

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError, PositionNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync

SETPOINT_PERIOD_S = 0.05  # 20 Hz, as MAVSDK's own re-send rate; PX4 needs > 2 Hz


class MissionFailed(Exception):
    """A check failed or a command was refused: the message is what the user sees."""


def log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


class Tracker:
    """The latest telemetry, kept fresh by background subscriptions (MAVSDK streams are async generators)."""

    def __init__(self, telemetry: TelemetryAsync) -> None:
        self._telemetry = telemetry
        self.values: dict[str, Any] = {}
        self._changed = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []

    async def _follow(self, name: str, stream: AsyncGenerator[Any, None]) -> None:
        async with contextlib.aclosing(stream):  # closing the generator unsubscribes
            async for value in stream:
                self.values[name] = value
                self._changed.set()

    async def start(self, timeout_s: float) -> None:
        t = self._telemetry
        for name, stream in (
            ("pv", t.subscribe_position_velocity_ned()),
            ("euler", t.subscribe_attitude_euler()),
            ("mode", t.subscribe_flight_mode()),
            ("landed", t.subscribe_landed_state()),
            ("armed", t.subscribe_armed()),
        ):
            self._tasks.append(asyncio.create_task(self._follow(name, stream)))
        await self.wait_until(lambda: len(self.values) == 5, timeout_s, "first telemetry of every stream")

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    async def wait_until(self, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = asyncio.get_running_loop().time() + timeout_s
        while not predicate():
            remaining = deadline - asyncio.get_running_loop().time()
            if remaining <= 0:
                raise MissionFailed(f"timed out after {timeout_s:.0f} s waiting for {what}")
            self._changed.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), remaining)

    # Convenience views of the cached values (NED metres, degrees).
    @property
    def ned(self) -> tuple[float, float, float]:
        p = self.values["pv"].position
        return p.north_m, p.east_m, p.down_m

    @property
    def vel(self) -> tuple[float, float, float]:
        v = self.values["pv"].velocity
        return v.north_m_s, v.east_m_s, v.down_m_s

    @property
    def alt_m(self) -> float:
        return -self.ned[2]

    @property
    def yaw_deg(self) -> float:
        return float(self.values["euler"].yaw_deg)

    @property
    def mode(self) -> FlightMode:
        return self.values["mode"]  # type: ignore[no-any-return]


async def stream_until(
    tr: Tracker, send: Callable[[], Awaitable[None]], done: Callable[[], bool], timeout_s: float, what: str
) -> None:
    """Call `send()` (one setpoint) at 20 Hz until `done()`; MissionFailed on timeout or if OFFBOARD is lost."""
    deadline = asyncio.get_running_loop().time() + timeout_s
    while not done():
        if asyncio.get_running_loop().time() > deadline:
            raise MissionFailed(f"timed out after {timeout_s:.0f} s waiting for {what}")
        if tr.mode != FlightMode.OFFBOARD:
            raise MissionFailed(f"left OFFBOARD (now {tr.mode.name}) while waiting for {what}")
        await send()
        await asyncio.sleep(SETPOINT_PERIOD_S)


async def wait_healthy(telemetry: TelemetryAsync, timeout_s: float) -> None:
    """Wait for global position, home and armable, as every MAVSDK example does before arming."""

    async def healthy() -> None:
        async with contextlib.aclosing(telemetry.subscribe_health()) as stream:
            async for h in stream:
                if h.is_global_position_ok and h.is_home_position_ok and h.is_armable:
                    return

    try:
        await asyncio.wait_for(healthy(), timeout_s)
    except TimeoutError:
        raise MissionFailed(
            f"timed out after {timeout_s:.0f} s waiting for health (position, home, armable)"
        ) from None


async def takeoff(
    tr: Tracker, telemetry: TelemetryAsync, action: ActionAsync, altitude_m: float, step_s: float
) -> None:
    """Health, arm, AUTO.TAKEOFF to altitude_m; returns once in air and still."""
    await wait_healthy(telemetry, step_s)
    log("health ok")
    try:
        await action.set_takeoff_altitude(altitude_m)
        await action.arm()
        await action.takeoff()
    except ActionError as exc:
        raise MissionFailed(f"command refused: {exc}") from exc
    log(f"armed, taking off to {altitude_m:.1f} m")
    await tr.wait_until(lambda: tr.alt_m >= altitude_m - 0.5, step_s, f"altitude {altitude_m - 0.5:.1f} m")
    await tr.wait_until(
        lambda: tr.values["landed"] == LandedState.IN_AIR and math.hypot(*tr.vel) < 0.2,
        step_s,
        "in air and still after takeoff",
    )
    log(f"hovering at {tr.alt_m:.2f} m, heading {tr.yaw_deg:.1f} deg")


async def stop_and_land(tr: Tracker, action: ActionAsync, offboard: OffboardAsync, step_s: float) -> None:
    """Leave offboard (Hold), land, wait for touchdown and auto-disarm."""
    try:
        await offboard.stop()
    except OffboardError as exc:
        raise MissionFailed(f"offboard stop refused: {exc}") from exc
    await tr.wait_until(lambda: tr.mode == FlightMode.HOLD, step_s, "flight mode HOLD after offboard stop")
    try:
        await action.land()
    except ActionError as exc:
        raise MissionFailed(f"land refused: {exc}") from exc
    log("landing")
    await tr.wait_until(lambda: tr.values["landed"] == LandedState.ON_GROUND, step_s, "touchdown")
    await tr.wait_until(lambda: not tr.values["armed"], step_s, "auto-disarm after landing")
    log("landed and disarmed")


async def fly(args: argparse.Namespace) -> dict[str, Any]:
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as mavsdk:
        log(f"connecting to {args.url}")
        await mavsdk.add_any_connection(args.url)
        system = await mavsdk.first_autopilot(timeout_s=args.step_timeout)
        if system is None:
            raise MissionFailed(f"no autopilot heartbeat on {args.url} within {args.step_timeout:.0f} s")
        telemetry, action, offboard = TelemetryAsync(system), ActionAsync(system), OffboardAsync(system)
        tracker = Tracker(telemetry)
        await tracker.start(args.step_timeout)
        try:
            await takeoff(tracker, telemetry, action, args.altitude, args.step_timeout)
            await approach(args, tracker, offboard)
            await stop_and_land(tracker, action, offboard, args.step_timeout)
            n, e, _ = tracker.ned
        finally:
            await tracker.stop()
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
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("url", nargs="?", default="udpin://0.0.0.0:14540", help="MAVSDK connection URL")
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
    parser.add_argument("--timeout", type=float, default=180.0, help="whole-flight limit, wall seconds")
    parser.add_argument("--step-timeout", type=float, default=60.0, help="limit for each wait, wall seconds")
    args = parser.parse_args()
    if not all(math.isfinite(v) for v in (args.north, args.east, args.altitude, args.approach_alt)):
        parser.error("--north, --east, --altitude and --approach-alt must be finite numbers")
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
