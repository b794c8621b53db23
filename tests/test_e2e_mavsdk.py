"""End to end, MAVSDK-Python 4.x (native API): the mission scripts fly against a `viva-sitl run` subprocess.
(The offboard attitude and velocity scripts are in test_e2e_offboard.py.)

Each test starts viva-sitl on free ports, runs a script from mission_scripts/ on the API link and, independently, watches
the vehicle with a pymavlink peer on the GCS link, asserting positions, modes and landed states from that telemetry.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable

import pytest
from sitl_process import (
    LANDED_IN_AIR,
    LANDED_LANDING,
    LANDED_ON_GROUND,
    MODE_AUTO_LAND,
    MODE_AUTO_LOITER,
    MODE_AUTO_TAKEOFF,
    MODE_OFFBOARD,
    MavlinkPeer,
    SitlProcess,
    assert_landed_disarmed,
    landed_states_seen,
    modes_seen,
    run_script,
)

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # slow: flights of a viva-sitl process


def test_takeoff_land_script(sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]) -> None:
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    run = run_script(
        "mavsdk_takeoff_land.py", [sitl.ports.mavsdk_url, "--altitude", "4", "--timeout", "90"], 120
    )
    assert run.returncode == 0, run.describe()
    assert abs(float(run.result["hover_alt_m"]) - 4.0) < 0.5, run.result

    # Independent check from the GCS link: climbed to 4 m, through the PX4 modes, then down and disarmed.
    min_z = min(m.z for m in peer.messages("LOCAL_POSITION_NED"))
    assert -4.6 < min_z < -3.5, (
        f"peak LOCAL_POSITION_NED z {min_z:.2f}, takeoff altitude 4 m ({peer.lost} lost)"
    )
    modes = modes_seen(peer)
    assert MODE_AUTO_TAKEOFF in modes and MODE_AUTO_LAND in modes, modes
    assert modes.index(MODE_AUTO_TAKEOFF) < modes.index(MODE_AUTO_LAND), modes
    states = landed_states_seen(peer)
    assert LANDED_IN_AIR in states and LANDED_LANDING in states, states
    assert states[-1] == LANDED_ON_GROUND, states
    assert_landed_disarmed(peer, near=(0.0, 0.0))


def test_precision_land_script(sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]) -> None:
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    run = run_script(
        "mavsdk_precision_land.py",
        [sitl.ports.mavsdk_url, "--north", "6", "--east", "-4", "--altitude", "8", "--tolerance", "0.5"],
        180,
    )
    assert run.returncode == 0, run.describe()
    assert float(run.result["touchdown_error_m"]) < 0.5, run.result
    assert MODE_OFFBOARD in modes_seen(peer) and MODE_AUTO_LAND in modes_seen(peer)
    assert_landed_disarmed(peer, near=(6.0, -4.0), tol_m=0.5)


def test_offboard_refused_without_setpoints(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    """MAVSDK refuses locally without a setpoint; the vehicle refuses OFFBOARD without a setpoint stream."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.offboard import OffboardAsync, OffboardError, OffboardResult
    from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync

    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()

    async def scenario() -> None:
        async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as mavsdk:
            await mavsdk.add_any_connection(sitl.ports.mavsdk_url)
            system = await mavsdk.first_autopilot(timeout_s=15.0)
            assert system is not None, "no autopilot discovered"
            offboard, action, telemetry = OffboardAsync(system), ActionAsync(system), TelemetryAsync(system)
            with pytest.raises(OffboardError) as err:
                await offboard.start()
            assert err.value.result == OffboardResult.NO_SETPOINT_SET
            await action.set_takeoff_altitude(3.0)
            await action.arm()
            await action.takeoff()
            async with asyncio.timeout(60):
                async for position in telemetry.subscribe_position():
                    if position.relative_altitude_m > 2.7:
                        break
                async for mode in telemetry.subscribe_flight_mode():
                    if mode == FlightMode.HOLD:
                        break
            # The vehicle side: DO_SET_MODE OFFBOARD with no setpoint stream at all is refused, mode unchanged.
            ack = peer.command_long(176, [129.0, 6.0, 0.0])
            assert ack.result in (1, 2), (
                f"OFFBOARD without setpoints: MAV_RESULT {ack.result}, expected DENIED/TEMP_REJ"
            )
            hb = peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 3.0)
            assert hb.custom_mode == MODE_AUTO_LOITER, f"mode changed to {hb.custom_mode}"
            assert await offboard.is_active() is False
            await action.land()
            async with asyncio.timeout(60):
                async for armed in telemetry.subscribe_armed():
                    if not armed:
                        break

    asyncio.run(scenario())
    assert_landed_disarmed(peer)
