#!/usr/bin/env python3
"""Offboard velocity pattern — a square in the NED frame, then a leg in the body frame — with MAVSDK-Python 4.x.

1. take off (AUTO.TAKEOFF) to --altitude;
2. OFFBOARD with velocity setpoints (SET_POSITION_TARGET_LOCAL_NED, frame LOCAL_NED): fly a square of --side metres
   north, east, south, west at up to --speed m/s; each leg ends when the telemetry says the corner is reached, and
   the corner, the cross-track error and the altitude are checked;
3. turn to face 90 deg right of the start heading, then fly --side metres "forward" with a body-frame velocity
   (frame BODY_NED): the vehicle must move along its new heading;
4. leave offboard (Hold), land, wait for touchdown and auto-disarm.

    viva-sitl run &
    python mavsdk_offboard_velocity.py --side 10 --speed 2

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
from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError, VelocityBodyYawspeed, VelocityNedYaw
from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState, TelemetryAsync

SETPOINT_PERIOD_S = 0.05  # 20 Hz, as MAVSDK's own re-send rate; PX4 needs > 2 Hz
SLOWDOWN_GAIN_1_S = (
    1.0  # commanded speed = gain * remaining distance near a corner, so legs end without overshoot
)
ARRIVED_M = 0.3


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


def wrap_deg(angle_deg: float) -> float:
    return (angle_deg + 180.0) % 360.0 - 180.0


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
            result = await pattern(args, tracker, offboard)
            await stop_and_land(tracker, action, offboard, args.step_timeout)
            return result
        finally:
            await tracker.stop()


async def pattern(args: argparse.Namespace, tr: Tracker, offboard: OffboardAsync) -> dict[str, Any]:
    step = args.step_timeout
    yaw0 = tr.yaw_deg
    alt0 = tr.alt_m
    await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, yaw0))
    try:
        await offboard.start()
    except OffboardError as exc:
        raise MissionFailed(f"offboard refused: {exc}") from exc
    await tr.wait_until(lambda: tr.mode == FlightMode.OFFBOARD, step, "flight mode OFFBOARD")
    log("offboard (velocity) active")

    # --- the square, NED frame -------------------------------------------------------------------------------
    n0, e0, _ = tr.ned
    corner = (n0, e0)
    max_cross_m = max_alt_dev_m = max_corner_err_m = 0.0
    for name, (dn, de) in (("north", (1, 0)), ("east", (0, 1)), ("south", (-1, 0)), ("west", (0, -1))):
        start = corner
        corner = (start[0] + dn * args.side, start[1] + de * args.side)
        target = corner

        def remaining(target: tuple[float, float] = target) -> tuple[float, float]:
            n, e, _ = tr.ned
            return target[0] - n, target[1] - e

        async def send(dn: int = dn, de: int = de, start: tuple[float, float] = start) -> None:
            nonlocal max_cross_m, max_alt_dev_m
            rn, re = remaining()
            dist = math.hypot(rn, re)
            speed = min(args.speed, SLOWDOWN_GAIN_1_S * dist)
            n, e, _ = tr.ned
            max_cross_m = max(max_cross_m, abs(-(n - start[0]) * de + (e - start[1]) * dn))
            max_alt_dev_m = max(max_alt_dev_m, abs(tr.alt_m - alt0))
            vn, ve = (speed * rn / dist, speed * re / dist) if dist > 1e-6 else (0.0, 0.0)
            await offboard.set_velocity_ned(VelocityNedYaw(vn, ve, 0.0, yaw0))

        await stream_until(
            tr,
            send,
            lambda: math.hypot(*remaining()) < ARRIVED_M and math.hypot(*tr.vel[:2]) < 0.3,
            step,
            f"the {name} corner ({target[0]:.1f}, {target[1]:.1f}) m",
        )
        n, e, _ = tr.ned
        err = math.hypot(n - target[0], e - target[1])
        max_corner_err_m = max(max_corner_err_m, err)
        log(f"leg {name}: at ({n:.2f}, {e:.2f}) m, corner error {err:.2f} m")
    n, e, _ = tr.ned
    closure_m = math.hypot(n - n0, e - e0)
    if max_cross_m > args.tolerance:
        raise MissionFailed(f"cross-track error {max_cross_m:.2f} m exceeds {args.tolerance} m")
    if max_alt_dev_m > args.tolerance:
        raise MissionFailed(f"altitude deviated {max_alt_dev_m:.2f} m while flying the square")
    if closure_m > args.tolerance:
        raise MissionFailed(f"the square did not close: {closure_m:.2f} m from the start")
    log(f"square done: closure {closure_m:.2f} m, max cross-track {max_cross_m:.2f} m")

    # --- turn right 90 deg, then fly forward in the body frame ------------------------------------------------
    yaw1 = wrap_deg(yaw0 + 90.0)

    async def turn() -> None:
        await offboard.set_velocity_ned(VelocityNedYaw(0.0, 0.0, 0.0, yaw1))

    await stream_until(
        tr, turn, lambda: abs(wrap_deg(tr.yaw_deg - yaw1)) < 3.0, step, f"heading {yaw1:.0f} deg"
    )
    log(f"turned to {tr.yaw_deg:.1f} deg")
    bn, be, _ = tr.ned
    heading = (math.cos(math.radians(yaw1)), math.sin(math.radians(yaw1)))

    def forward_m() -> float:
        n, e, _ = tr.ned
        return (n - bn) * heading[0] + (e - be) * heading[1]

    async def forward() -> None:
        speed = min(args.speed, SLOWDOWN_GAIN_1_S * (args.side - forward_m()))
        await offboard.set_velocity_body(VelocityBodyYawspeed(max(speed, 0.0), 0.0, 0.0, 0.0))

    await stream_until(
        tr,
        forward,
        lambda: forward_m() > args.side - ARRIVED_M and math.hypot(*tr.vel[:2]) < 0.3,
        step,
        f"{args.side:.1f} m forward in the body frame",
    )
    n, e, _ = tr.ned
    body_m = math.hypot(n - bn, e - be)
    body_dir_deg = math.degrees(math.atan2(e - be, n - bn))
    body_dir_err_deg = abs(wrap_deg(body_dir_deg - yaw1))
    log(f"body-frame leg: {body_m:.2f} m towards {body_dir_deg:.1f} deg (heading {yaw1:.1f} deg)")
    if body_dir_err_deg > 10.0 or abs(body_m - args.side) > args.tolerance:
        raise MissionFailed(
            f"body-frame leg went {body_m:.2f} m towards {body_dir_deg:.1f} deg; expected {args.side:.1f} m "
            f"towards {yaw1:.1f} deg"
        )
    return {
        "square_closure_m": round(closure_m, 3),
        "max_corner_err_m": round(max_corner_err_m, 3),
        "max_cross_track_m": round(max_cross_m, 3),
        "max_alt_dev_m": round(max_alt_dev_m, 3),
        "body_leg_m": round(body_m, 3),
        "body_dir_err_deg": round(body_dir_err_deg, 2),
        "final_north_m": round(n, 3),
        "final_east_m": round(e, 3),
    }


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("url", nargs="?", default="udpin://0.0.0.0:14540", help="MAVSDK connection URL")
    parser.add_argument("--altitude", type=float, default=10.0, help="takeoff altitude, m")
    parser.add_argument("--side", type=float, default=10.0, help="side of the square and body-frame leg, m")
    parser.add_argument("--speed", type=float, default=2.0, help="cruise speed, m/s")
    parser.add_argument(
        "--tolerance", type=float, default=1.5, help="accepted path / corner / altitude error, m"
    )
    parser.add_argument("--timeout", type=float, default=240.0, help="whole-flight limit, wall seconds")
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
