"""What the mission scripts share: failure reporting, the log line, telemetry waits and the MAVSDK 4.x flight steps.

Not a script: the scripts next to it import it (`python mission_scripts/X.py` puts this folder on sys.path).
Copying a script elsewhere? Copy this file with it. It imports nothing from MAVSDK at import time, so the pymavlink
and classic gRPC scripts use it too; the MAVSDK 4.x parts import `mavsdk.asyncio` when they run.
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import math
import sys
import time
from collections.abc import AsyncGenerator, AsyncIterator, Awaitable, Callable, Coroutine
from typing import TYPE_CHECKING, Any, Self, TypeVar

if TYPE_CHECKING:
    from mavsdk.asyncio import System
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync
    from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

T = TypeVar("T")
SETPOINT_PERIOD_S = 0.05  # 20 Hz, as MAVSDK's own re-send rate; PX4 needs > 2 Hz


class MissionFailed(Exception):
    """A check failed, a command was refused or a wait timed out: the message is what the user sees."""


def log(text: str) -> None:
    print(f"[{time.strftime('%H:%M:%S')}] {text}", flush=True)


# ----------------------------------------------------------------------------------------- the end of every script


def failed(message: str) -> int:
    """The `FAILED: ...` line on stderr; exit status 1."""
    print(f"FAILED: {message}", file=sys.stderr, flush=True)
    return 1


def print_result(result: dict[str, Any]) -> None:
    """The `RESULT key=value ...` line the tests and the trials harness read."""
    print("RESULT " + " ".join(f"{k}={v}" for k, v in result.items()), flush=True)


def succeeded(result: dict[str, Any]) -> int:
    print_result(result)
    log("success")
    return 0


def run_flight(flight: Coroutine[Any, Any, dict[str, Any]], timeout_s: float) -> int:
    """Fly `flight` under the whole-flight --timeout: RESULT line and 0, or FAILED line and 1."""
    try:
        result = asyncio.run(asyncio.wait_for(flight, timeout_s))
    except MissionFailed as exc:
        return failed(str(exc))
    except TimeoutError:
        return failed(f"the flight took longer than --timeout {timeout_s:.0f} s")
    return succeeded(result)


def script_parser(doc: str | None, url_default: str, url_help: str) -> argparse.ArgumentParser:
    """The parser every script starts with: its docstring as --help, the connection URL as optional positional."""
    parser = argparse.ArgumentParser(description=doc, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("url", nargs="?", default=url_default, help=url_help)
    return parser


def add_time_limits(parser: argparse.ArgumentParser, timeout_s: float) -> None:
    parser.add_argument("--timeout", type=float, default=timeout_s, help="whole-flight limit, wall seconds")
    parser.add_argument("--step-timeout", type=float, default=60.0, help="limit for each wait, wall seconds")


# ------------------------------------------------------------------------------------------------ telemetry waits


async def wait_for(
    stream: AsyncIterator[T], predicate: Callable[[T], bool], timeout_s: float, what: str
) -> T:
    """First value of a telemetry stream satisfying `predicate`; MissionFailed after timeout_s (wall seconds)."""

    async def first() -> T:
        # closing a generator unsubscribes (MAVSDK 4.x) or cancels its gRPC stream (classic API)
        async with contextlib.AsyncExitStack() as stack:
            if isinstance(stream, AsyncGenerator):
                await stack.enter_async_context(contextlib.aclosing(stream))
            async for value in stream:
                if predicate(value):
                    return value
        raise MissionFailed(f"telemetry stream ended while waiting for {what}")

    try:
        return await asyncio.wait_for(first(), timeout_s)
    except TimeoutError:
        raise MissionFailed(f"timed out after {timeout_s:.0f} s waiting for {what}") from None


class Tracker:
    """The latest MAVSDK 4.x telemetry, kept fresh by background subscriptions (streams are async generators).

    `values` holds the last position+velocity ("pv"), attitude ("euler"), flight mode ("mode"), landed state
    ("landed") and armed flag ("armed"). With `link_timeout_s`, every wait also fails once telemetry has been quiet
    that long (a lost vehicle). Subclasses add streams with `streams()` and `received()`.
    """

    NAMES = ("pv", "euler", "mode", "landed", "armed")

    def __init__(self, telemetry: TelemetryAsync, link_timeout_s: float | None = None) -> None:
        self._telemetry = telemetry
        self.values: dict[str, Any] = {}
        self.last_update = time.monotonic()
        self.link_timeout_s = link_timeout_s
        self._changed = asyncio.Event()
        self._tasks: list[asyncio.Task[None]] = []

    def streams(self) -> list[tuple[str, AsyncGenerator[Any, None]]]:
        t = self._telemetry
        return [
            ("pv", t.subscribe_position_velocity_ned()),
            ("euler", t.subscribe_attitude_euler()),
            ("mode", t.subscribe_flight_mode()),
            ("landed", t.subscribe_landed_state()),
            ("armed", t.subscribe_armed()),
        ]

    def received(self, name: str, value: Any) -> None:
        self.values[name] = value
        self.last_update = time.monotonic()

    async def _follow(self, name: str, stream: AsyncGenerator[Any, None]) -> None:
        async with contextlib.aclosing(stream):  # closing the generator unsubscribes
            async for value in stream:
                self.received(name, value)
                self._changed.set()

    async def start(self, timeout_s: float) -> None:
        for name, stream in self.streams():
            self._tasks.append(asyncio.create_task(self._follow(name, stream)))
        await self.wait_until(
            lambda: all(n in self.values for n in self.NAMES), timeout_s, "first telemetry of every stream"
        )

    async def stop(self) -> None:
        for task in self._tasks:
            task.cancel()
        await asyncio.gather(*self._tasks, return_exceptions=True)

    @contextlib.asynccontextmanager
    async def running(self, timeout_s: float) -> AsyncIterator[Self]:
        """`start()` on entry (MissionFailed after timeout_s without every stream), `stop()` on exit."""
        try:
            await self.start(timeout_s)
            yield self
        finally:
            await self.stop()

    def check_link(self) -> None:
        quiet = time.monotonic() - self.last_update
        if self.link_timeout_s is not None and quiet > self.link_timeout_s:
            raise MissionFailed(f"lost the vehicle: no telemetry for {quiet:.0f} s (disconnected?)")

    async def wait_until(self, predicate: Callable[[], bool], timeout_s: float, what: str) -> None:
        deadline = asyncio.get_running_loop().time() + timeout_s
        while not predicate():
            remaining = deadline - asyncio.get_running_loop().time()
            if remaining <= 0:
                raise MissionFailed(f"timed out after {timeout_s:.0f} s waiting for {what}")
            if self.values:
                self.check_link()
            self._changed.clear()
            with contextlib.suppress(TimeoutError):
                await asyncio.wait_for(self._changed.wait(), min(remaining, 1.0))

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


# ------------------------------------------------------------------------------------- MAVSDK 4.x flight steps


@contextlib.asynccontextmanager
async def first_autopilot(
    url: str, timeout_s: float, companion: bool = False, also: str = ""
) -> AsyncIterator[System]:
    """Connect a MAVSDK 4.x instance (a ground station, or a companion computer) and yield the first autopilot."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk

    kind = ComponentType.COMPANION_COMPUTER if companion else ComponentType.GROUND_STATION
    async with Mavsdk(Configuration.create_with_component_type(kind)) as mavsdk:
        log(f"connecting to {url}{also}")
        await mavsdk.add_any_connection(url)
        system = await mavsdk.first_autopilot(timeout_s=timeout_s)
        if system is None:
            raise MissionFailed(f"no autopilot heartbeat on {url} within {timeout_s:.0f} s")
        yield system


async def stream_until(
    tr: Tracker, send: Callable[[], Awaitable[None]], done: Callable[[], bool], timeout_s: float, what: str
) -> None:
    """Call `send()` (one setpoint) at 20 Hz until `done()`; MissionFailed on timeout or if OFFBOARD is lost."""
    from mavsdk.asyncio.plugins.telemetry import FlightMode

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
    await wait_for(
        telemetry.subscribe_health(),
        lambda h: bool(h.is_global_position_ok and h.is_home_position_ok and h.is_armable),
        timeout_s,
        "health (position, home, armable)",
    )


async def arm_and_take_off(
    tr: Tracker, telemetry: TelemetryAsync, action: ActionAsync, altitude_m: float, step_s: float
) -> None:
    """Health, arm, AUTO.TAKEOFF; returns once within 0.5 m of altitude_m."""
    from mavsdk.asyncio.plugins.action import ActionError

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


async def takeoff(
    tr: Tracker,
    telemetry: TelemetryAsync,
    action: ActionAsync,
    altitude_m: float,
    step_s: float,
    still_m_s: float = 0.2,
    still_what: str = "in air and still after takeoff",
) -> None:
    """Health, arm, AUTO.TAKEOFF to altitude_m; returns once in air and slower than still_m_s."""
    from mavsdk.asyncio.plugins.telemetry import LandedState

    await arm_and_take_off(tr, telemetry, action, altitude_m, step_s)
    await tr.wait_until(
        lambda: tr.values["landed"] == LandedState.IN_AIR and math.hypot(*tr.vel) < still_m_s,
        step_s,
        still_what,
    )
    log(f"hovering at {tr.alt_m:.2f} m, heading {tr.yaw_deg:.1f} deg")


async def stop_and_land(tr: Tracker, action: ActionAsync, offboard: OffboardAsync, step_s: float) -> None:
    """Leave offboard (Hold), land, wait for touchdown and auto-disarm."""
    from mavsdk.asyncio.plugins.action import ActionError
    from mavsdk.asyncio.plugins.offboard import OffboardError
    from mavsdk.asyncio.plugins.telemetry import FlightMode, LandedState

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
