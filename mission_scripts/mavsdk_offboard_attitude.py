#!/usr/bin/env python3
"""Offboard attitude control — hover, tilt, climb — with MAVSDK-Python 4.x (`pip install mavsdk`).

Flies the vehicle directly with attitude + thrust setpoints (SET_ATTITUDE_TARGET), the way a learned or hand-written
low-level controller would, and checks that the telemetry reacts as physics says it should:

1. take off (AUTO.TAKEOFF) to --altitude and settle;
2. OFFBOARD, level at the hover thrust (read from PX4's MPC_THR_HOVER, 0.5 by default): the altitude must hold;
3. pitch nose-down by --tilt-deg (thrust raised by 1/cos(tilt) to keep the lift): the vehicle must move forward
   along its heading by --tilt-distance, then it pitches back to brake;
4. level with --climb-thrust: the vehicle must climb by --climb;
5. leave offboard (Hold), land, wait for touchdown and auto-disarm.

    viva-sitl run &
    python mavsdk_offboard_attitude.py                  # default udpin://0.0.0.0:14540

Waits are telemetry conditions; the only sleeps pace the setpoint stream. Exit status 0 on success, 1 on failure.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import sys
import time
from collections.abc import AsyncGenerator, Callable
from typing import Any

from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
from mavsdk.asyncio.plugins.offboard import Attitude, OffboardAsync, OffboardError
from mavsdk.asyncio.plugins.param import ParamAsync, ParamError
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
    offboard: OffboardAsync,
    tr: Tracker,
    setpoint: Attitude,
    done: Callable[[], bool],
    timeout_s: float,
    what: str,
) -> None:
    """Send `setpoint` at 20 Hz until `done()` holds; MissionFailed on timeout or if the vehicle leaves OFFBOARD."""
    deadline = asyncio.get_running_loop().time() + timeout_s
    while not done():
        if asyncio.get_running_loop().time() > deadline:
            raise MissionFailed(f"timed out after {timeout_s:.0f} s waiting for {what}")
        if tr.mode != FlightMode.OFFBOARD:
            raise MissionFailed(f"left OFFBOARD (now {tr.mode.name}) while waiting for {what}")
        await offboard.set_attitude(setpoint)
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
        if (
            args.hover_thrust is None
        ):  # the autopilot's own hover thrust, as PX4's position controller uses it
            try:
                args.hover_thrust = float(await ParamAsync(system).get_param_float("MPC_THR_HOVER"))
            except ParamError as exc:
                raise MissionFailed(f"cannot read MPC_THR_HOVER ({exc}); pass --hover-thrust") from exc
        log(f"hover thrust {args.hover_thrust:.3f} (MPC_THR_HOVER)")
        try:
            return await _fly(args, tracker, telemetry, action, offboard)
        finally:
            await tracker.stop()


async def _fly(
    args: argparse.Namespace,
    tr: Tracker,
    telemetry: TelemetryAsync,
    action: ActionAsync,
    offboard: OffboardAsync,
) -> dict[str, Any]:
    step = args.step_timeout
    await wait_healthy(telemetry, step)
    log("health ok")
    try:
        await action.set_takeoff_altitude(args.altitude)
        await action.arm()
        await action.takeoff()
    except ActionError as exc:
        raise MissionFailed(f"command refused: {exc}") from exc
    log(f"armed, taking off to {args.altitude:.1f} m")
    await tr.wait_until(
        lambda: tr.alt_m >= args.altitude - 0.5, step, f"altitude {args.altitude - 0.5:.1f} m"
    )
    await tr.wait_until(
        lambda: tr.values["landed"] == LandedState.IN_AIR and math.hypot(*tr.vel) < 0.1,
        step,
        "in air and still (< 0.1 m/s) after takeoff: open-loop thrust would keep any residual climb",
    )
    yaw_deg = tr.yaw_deg
    alt0 = tr.alt_m
    log(f"hovering at {alt0:.2f} m, heading {yaw_deg:.1f} deg")

    # Offboard needs a setpoint before start(); MAVSDK then keeps re-sending the latest one at 20 Hz.
    level = Attitude(0.0, 0.0, yaw_deg, args.hover_thrust)
    await offboard.set_attitude(level)
    try:
        await offboard.start()
    except OffboardError as exc:
        raise MissionFailed(f"offboard refused: {exc}") from exc
    await tr.wait_until(lambda: tr.mode == FlightMode.OFFBOARD, step, "flight mode OFFBOARD")
    log("offboard (attitude) active")

    # 1. Hover at the hover thrust: altitude must hold.
    hover_end = asyncio.get_running_loop().time() + args.hover_s
    max_dev = 0.0

    def hover_done() -> bool:
        nonlocal max_dev
        max_dev = max(max_dev, abs(tr.alt_m - alt0))
        return asyncio.get_running_loop().time() >= hover_end

    await stream_until(offboard, tr, level, hover_done, args.hover_s + step, "the hover phase")
    if max_dev > args.alt_tolerance:
        raise MissionFailed(f"altitude not held at thrust {args.hover_thrust}: drifted {max_dev:.2f} m")
    log(f"hover held: max altitude deviation {max_dev:.2f} m")

    # 2. Tilt nose-down: move forward along the heading.
    fwd = (math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg)))
    n0, e0, _ = tr.ned
    alt_tilt0 = tr.alt_m

    def forward_m() -> float:
        n, e, _ = tr.ned
        return (n - n0) * fwd[0] + (e - e0) * fwd[1]

    def lateral_m() -> float:
        n, e, _ = tr.ned
        return -(n - n0) * fwd[1] + (e - e0) * fwd[0]

    tilt_thrust = min(1.0, args.hover_thrust / math.cos(math.radians(args.tilt_deg)))
    await stream_until(
        offboard,
        tr,
        Attitude(0.0, -args.tilt_deg, yaw_deg, tilt_thrust),
        lambda: forward_m() >= args.tilt_distance,
        step,
        f"{args.tilt_distance:.1f} m of forward travel while pitched {-args.tilt_deg:.1f} deg",
    )
    moved, drift = forward_m(), lateral_m()
    log(f"tilted: moved {moved:.2f} m forward, {drift:.2f} m sideways")

    def forward_speed() -> float:
        vn, ve, _ = tr.vel
        return vn * fwd[0] + ve * fwd[1]

    await stream_until(
        offboard,
        tr,
        Attitude(0.0, args.tilt_deg, yaw_deg, tilt_thrust),
        lambda: forward_speed() <= 0.2,
        step,
        "braking to < 0.2 m/s",
    )
    tilt_alt_change = tr.alt_m - alt_tilt0
    if abs(drift) > 0.5 * moved + 1.0:
        raise MissionFailed(f"tilt moved the vehicle sideways: {drift:.2f} m for {moved:.2f} m forward")
    if abs(tilt_alt_change) > 2 * args.alt_tolerance:
        raise MissionFailed(f"altitude changed {tilt_alt_change:.2f} m during the tilt (compensated thrust)")
    log(f"braked: travelled {forward_m():.2f} m forward in total")

    # 3. Climb with more thrust, level.
    alt_climb0 = tr.alt_m
    max_climb_rate = 0.0

    def climbed() -> bool:
        nonlocal max_climb_rate
        max_climb_rate = max(max_climb_rate, -tr.vel[2])
        return tr.alt_m >= alt_climb0 + args.climb

    await stream_until(
        offboard,
        tr,
        Attitude(0.0, 0.0, yaw_deg, args.climb_thrust),
        climbed,
        step,
        f"a {args.climb:.1f} m climb at thrust {args.climb_thrust}",
    )
    log(f"climbed {tr.alt_m - alt_climb0:.2f} m (peak climb rate {max_climb_rate:.2f} m/s)")

    try:
        await offboard.stop()
    except OffboardError as exc:
        raise MissionFailed(f"offboard stop refused: {exc}") from exc
    await tr.wait_until(lambda: tr.mode == FlightMode.HOLD, step, "flight mode HOLD after offboard stop")
    try:
        await action.land()
    except ActionError as exc:
        raise MissionFailed(f"land refused: {exc}") from exc
    log("landing")
    await tr.wait_until(lambda: tr.values["landed"] == LandedState.ON_GROUND, step, "touchdown")
    await tr.wait_until(lambda: not tr.values["armed"], step, "auto-disarm after landing")
    log("landed and disarmed")
    return {
        "hover_thrust": round(args.hover_thrust, 4),
        "hover_max_dev_m": round(max_dev, 3),
        "tilt_forward_m": round(moved, 3),
        "tilt_lateral_m": round(drift, 3),
        "climb_rate_max_m_s": round(max_climb_rate, 3),
    }


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("url", nargs="?", default="udpin://0.0.0.0:14540", help="MAVSDK connection URL")
    parser.add_argument("--altitude", type=float, default=10.0, help="takeoff altitude, m")
    parser.add_argument(
        "--hover-thrust", type=float, default=0.5, help="thrust that hovers (PX4 MPC_THR_HOVER)"
    )
    parser.add_argument("--hover-s", type=float, default=2.0, help="how long to hover level, wall seconds")
    parser.add_argument(
        "--alt-tolerance", type=float, default=1.5, help="accepted altitude drift while hovering, m"
    )
    parser.add_argument("--tilt-deg", type=float, default=8.0, help="nose-down pitch, deg")
    parser.add_argument(
        "--tilt-distance", type=float, default=5.0, help="forward travel to reach while tilted, m"
    )
    parser.add_argument("--climb-thrust", type=float, default=0.6, help="thrust for the climb, 0..1")
    parser.add_argument("--climb", type=float, default=3.0, help="height to gain, m")
    parser.add_argument("--timeout", type=float, default=180.0, help="whole-flight limit, wall seconds")
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
