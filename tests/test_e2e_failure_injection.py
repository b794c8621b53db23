"""MAV_CMD_INJECT_FAILURE end to end against a `viva-sitl run` process (failure_injection.py's flow, issue 24 §1):
MAVSDK's failure plugin is refused while SYS_FAILURE_EN = 0; with it set, a ground station's SYSTEM_BATTERY OFF
empties the battery in SYS_STATUS and OK restores it, units the simulator does not implement answer UNSUPPORTED,
and non-finite parameters are DENIED. The same Autopilot.inject_failure path the trials' scenario failures take."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from sitl_process import MavlinkPeer, SitlProcess

pytestmark = pytest.mark.e2e

INJECT = mavlink2.MAV_CMD_INJECT_FAILURE
BATTERY, GPS = 100, 4  # FAILURE_UNIT_SYSTEM_BATTERY, FAILURE_UNIT_SENSOR_GPS
OK, OFF = 0, 1  # FAILURE_TYPE_OK, FAILURE_TYPE_OFF


def test_failure_injection_is_gated_acknowledged_and_reversible(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.failure import FailureAsync
    from mavsdk.plugins.failure import FailureError, FailureResult, FailureType, FailureUnit

    async def mavsdk_inject_while_disabled() -> object:
        async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as mavsdk:
            await mavsdk.add_any_connection(sitl.ports.mavsdk_url)
            system = await mavsdk.first_autopilot(timeout_s=15.0)
            assert system is not None, "no autopilot discovered"
            try:
                await FailureAsync(system).inject(FailureUnit.SYSTEM_BATTERY, FailureType.OFF, 0)
            except FailureError as exc:
                return exc.result
            return FailureResult.SUCCESS

    assert asyncio.run(mavsdk_inject_while_disabled()) in (FailureResult.DENIED, FailureResult.DISABLED)

    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    denied = peer.command_long(INJECT, (BATTERY, OFF, 0))
    assert denied.result == mavlink2.MAV_RESULT_DENIED  # PX4's gate: SYS_FAILURE_EN = 0
    peer.send(peer.mav.param_set_encode(1, 1, b"SYS_FAILURE_EN", 1, mavlink2.MAV_PARAM_TYPE_INT32))
    peer.wait(
        "PARAM_VALUE", lambda m: m.param_id == "SYS_FAILURE_EN" and m.param_value == 1, 5.0, since_s=0.0
    )
    assert peer.command_long(INJECT, (GPS, OFF, 0)).result == mavlink2.MAV_RESULT_UNSUPPORTED
    assert peer.command_long(INJECT, (float("nan"), OFF, 0)).result == mavlink2.MAV_RESULT_DENIED

    t0 = time.monotonic()
    assert peer.command_long(INJECT, (BATTERY, OFF, 0)).result == mavlink2.MAV_RESULT_ACCEPTED
    peer.wait("SYS_STATUS", lambda m: m.battery_remaining == 0, 10.0, since_s=t0, what="battery 0 %")
    t1 = time.monotonic()
    assert peer.command_long(INJECT, (BATTERY, OK, 0)).result == mavlink2.MAV_RESULT_ACCEPTED
    peer.wait("SYS_STATUS", lambda m: m.battery_remaining > 90, 10.0, since_s=t1, what="battery back")
