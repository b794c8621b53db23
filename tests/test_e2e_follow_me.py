"""End to end: MAVSDK's follow_me plugin (MAVSDK-Python 4.x, as follow_me_example.py) against `viva-sitl run`:
set_config writes FLW_TGT_*, start() switches to AUTO.FOLLOW_TARGET, streamed target locations pull the vehicle to
FLW_TGT_DST behind the target at FLW_TGT_HT; a ground station's bad FOLLOW_TARGET (NaN altitude and velocity, then an
impossible position) neither crashes nor misleads it."""

from __future__ import annotations

import asyncio
import math
import time
from collections.abc import Callable
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from sitl_process import MavlinkPeer, SitlProcess, free_udp_ports

pytestmark = pytest.mark.slow

EARTH_R = 6371000.0
MODE_FOLLOW = (4 << 16) | (8 << 24)


def offset(lat: float, lon: float, north_m: float, east_m: float) -> tuple[float, float]:
    return (
        lat + math.degrees(north_m / EARTH_R),
        lon + math.degrees(east_m / (EARTH_R * math.cos(math.radians(lat)))),
    )


def ne_of(lat0: float, lon0: float, lat: float, lon: float) -> tuple[float, float]:
    return (
        math.radians(lat - lat0) * EARTH_R,
        math.radians(lon - lon0) * EARTH_R * math.cos(math.radians(lat0)),
    )


async def _home_when_ready(telemetry: Any) -> Any:
    """Wait (30 s) for a global position and home, as MAVSDK's examples do; returns home."""
    async with asyncio.timeout(30):
        async for health in telemetry.subscribe_health():
            if health.is_global_position_ok and health.is_home_position_ok:
                break
    return await anext(aiter(telemetry.subscribe_home()))


async def _take_off(action: Any, telemetry: Any) -> None:
    """Arm, take off, wait (60 s) until above 2 m."""
    await action.arm()
    await action.takeoff()
    async with asyncio.timeout(60):
        async for position in telemetry.subscribe_position():
            if position.relative_altitude_m > 2.0:
                break


async def _wait_mode(telemetry: Any, mode: Any) -> None:
    async with asyncio.timeout(10):
        async for m in telemetry.subscribe_flight_mode():
            if m == mode:
                break


def test_mavsdk_follow_me(sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]) -> None:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.follow_me import Config, FollowMeAsync, TargetLocation
    from mavsdk.asyncio.plugins.param import ParamAsync
    from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()

    async def scenario() -> dict[str, float]:
        async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as mavsdk:
            await mavsdk.add_any_connection(sitl.ports.mavsdk_url)
            system = await mavsdk.first_autopilot(timeout_s=15.0)
            assert system is not None, "no autopilot discovered"
            action, telemetry = ActionAsync(system), TelemetryAsync(system)
            follow, param = FollowMeAsync(system), ParamAsync(system)
            home = await _home_when_ready(telemetry)
            await follow.set_config(Config(10.0, 6.0, 0.1, Config.FollowAltitudeMode.CONSTANT, 8.0, 180.0))
            assert await param.get_param_float("FLW_TGT_HT") == pytest.approx(10.0)
            assert await param.get_param_float("FLW_TGT_DST") == pytest.approx(6.0)
            await _take_off(action, telemetry)
            following_since = time.monotonic()
            await follow.start()
            await _wait_mode(telemetry, FlightMode.FOLLOW_ME)
            assert await follow.is_active()

            async def fly_to(target_ne: tuple[float, float], want_ne: tuple[float, float]) -> float:
                """Stream the target (2 Hz wall) until the vehicle is within 1 m of want_ne; returns its height."""
                lat, lon = offset(home.latitude_deg, home.longitude_deg, *target_ne)
                loc = TargetLocation(lat, lon, home.absolute_altitude_m, 0.0, 0.0, 0.0)
                async with asyncio.timeout(60):
                    while True:
                        await follow.set_target_location(loc)
                        pos = await anext(aiter(telemetry.subscribe_position()))
                        ne = ne_of(home.latitude_deg, home.longitude_deg, pos.latitude_deg, pos.longitude_deg)
                        if math.dist(ne, want_ne) < 1.0 and abs(pos.relative_altitude_m - 10.0) < 0.5:
                            return float(pos.relative_altitude_m)
                        await asyncio.sleep(0.5)

            # a target 30 m north, standing: the vehicle faces north at the start, so "behind" is 6 m south of it
            height = await fly_to((30.0, 0.0), (24.0, 0.0))
            # bad input from a ground station while following: NaN altitude/velocity (a 2D target) is used,
            # an impossible position is ignored with one warning; the vehicle keeps following
            lat, lon = offset(home.latitude_deg, home.longitude_deg, 30.0, 0.0)
            nan3 = [math.nan] * 3
            peer.send(mavlink2.MAVLink_follow_target_message(0, 1, round(lat * 1e7), round(lon * 1e7), math.nan,
                                                            nan3, nan3, [1.0, 0, 0, 0], nan3, nan3, 0))  # fmt: skip
            peer.send(mavlink2.MAVLink_follow_target_message(0, 1, 950_000_000, 0, 0.0, nan3, nan3,
                                                            [1.0, 0, 0, 0], nan3, nan3, 0))  # fmt: skip
            # the warning is rate-limited to one per 5 sim s: one MAVSDK itself caused since following began (it
            # streams a not-yet-set target) may be the one this bad input is counted under, as PX4 would
            text = peer.wait("STATUSTEXT", lambda m: "Follow target ignored" in m.text, 5.0, since_s=following_since,
                             what="a warning")  # fmt: skip
            assert text.text == "Follow target ignored: lat/lon invalid"
            # the target moves 20 m east: the vehicle follows it there
            await fly_to((30.0, 20.0), (24.0, 20.0))
            await follow.stop()
            await _wait_mode(telemetry, FlightMode.HOLD)
            await action.land()
            async with asyncio.timeout(60):
                async for armed in telemetry.subscribe_armed():
                    if not armed:
                        break
            return {"height": height}

    result = asyncio.run(scenario())
    assert result["height"] == pytest.approx(10.0, abs=0.5)
    hb = peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 3.0, what="a heartbeat")
    assert hb.custom_mode != MODE_FOLLOW


def test_mavsdk_follow_me_with_the_camera_component_on(
    sitl_factory: Callable[..., SitlProcess], peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    """With video on, viva-sitl is two components (autopilot 1, camera 100). MAVSDK's Follow Me plugin takes the mode
    from whichever HEARTBEAT came last, so a camera heartbeat sent after the autopilot's made every
    set_target_location() answer NOT_ACTIVE (follow_me_example.py failed on the default `viva-sitl run`). The camera's
    heartbeat now goes first in each tick, the autopilot's right after it; what is left is the instant between the two
    datagrams in MAVSDK's receive thread: a call landing there is refused (seen once in a full suite on 2 loaded
    cores). So: at least 12 calls accepted, at most 2 refused (the old order refused nearly every call), and the
    vehicle moves toward the target."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.follow_me import (
        Config,
        FollowMeAsync,
        FollowMeError,
        FollowMeResult,
        TargetLocation,
    )
    from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

    (video_port,) = free_udp_ports(1)
    sitl = sitl_factory(video_port=video_port)
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 100, 10.0, what="the camera's heartbeat")

    async def scenario() -> tuple[int, int, float]:
        async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as mavsdk:
            await mavsdk.add_any_connection(sitl.ports.mavsdk_url)
            system = await mavsdk.first_autopilot(timeout_s=15.0)
            assert system is not None, "no autopilot discovered"
            action, telemetry, follow = ActionAsync(system), TelemetryAsync(system), FollowMeAsync(system)
            home = await _home_when_ready(telemetry)
            await follow.set_config(Config(8.0, 5.0, 0.1, Config.FollowAltitudeMode.CONSTANT, 8.0, 180.0))
            await _take_off(action, telemetry)
            await follow.start()
            await _wait_mode(telemetry, FlightMode.FOLLOW_ME)
            lat, lon = offset(home.latitude_deg, home.longitude_deg, 25.0, 0.0)
            target = TargetLocation(lat, lon, home.absolute_altitude_m, 0.0, 0.0, 0.0)
            accepted = refused = 0
            async with asyncio.timeout(60):
                while True:  # 12 calls spread over several heartbeats of both components, then until it moved
                    try:  # raises FollowMeError(NOT_ACTIVE) on nearly every call with the old heartbeat order
                        await follow.set_target_location(target)
                        accepted += 1
                    except FollowMeError as exc:
                        assert exc.result == FollowMeResult.NOT_ACTIVE, exc
                        refused += 1
                        assert refused <= 2, (
                            f"set_target_location refused {refused} times ({accepted} accepted)"
                        )
                    pos = await anext(aiter(telemetry.subscribe_position()))
                    ne = ne_of(home.latitude_deg, home.longitude_deg, pos.latitude_deg, pos.longitude_deg)
                    north = ne[0]
                    if accepted >= 12 and north > 5.0:
                        break
                    await asyncio.sleep(0.3)
            await follow.stop()
            await action.land()
            return accepted, refused, north

    accepted, refused, north = asyncio.run(scenario())
    assert accepted >= 12 and refused <= 2
    assert north > 5.0
