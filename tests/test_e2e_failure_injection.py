"""MAV_CMD_INJECT_FAILURE end to end against a `viva-sitl run` process (failure_injection.py's flow, issue 24 §1):
MAVSDK's failure plugin is refused while SYS_FAILURE_EN = 0; with it set, a ground station's SYSTEM_BATTERY OFF
empties the battery in SYS_STATUS and OK restores it, units the simulator does not implement answer UNSUPPORTED,
and non-finite parameters are DENIED; MAVSDK's own flow: GPS off in flight -> no global position, PX4's Descend
failsafe and its messages, OK -> back to Hold. The same Autopilot.inject_failure path the trials' failures take."""

from __future__ import annotations

import asyncio
import time
from collections.abc import Callable
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from sitl_process import MavlinkPeer, SitlProcess, free_udp_ports

pytestmark = pytest.mark.e2e

INJECT = mavlink2.MAV_CMD_INJECT_FAILURE
BATTERY, GPS, FLOW = 100, 4, 5  # FAILURE_UNIT_SYSTEM_BATTERY, _SENSOR_GPS, _SENSOR_OPTICAL_FLOW
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
    assert (
        peer.command_long(INJECT, (FLOW, OFF, 0)).result == mavlink2.MAV_RESULT_UNSUPPORTED
    )  # no such sensor
    assert peer.command_long(INJECT, (float("nan"), OFF, 0)).result == mavlink2.MAV_RESULT_DENIED

    t0 = time.monotonic()
    assert peer.command_long(INJECT, (BATTERY, OFF, 0)).result == mavlink2.MAV_RESULT_ACCEPTED
    peer.wait("SYS_STATUS", lambda m: m.battery_remaining == 0, 10.0, since_s=t0, what="battery 0 %")
    t1 = time.monotonic()
    assert peer.command_long(INJECT, (BATTERY, OK, 0)).result == mavlink2.MAV_RESULT_ACCEPTED
    peer.wait("SYS_STATUS", lambda m: m.battery_remaining > 90, 10.0, since_s=t1, what="battery back")


@pytest.mark.slow  # ~8-10 s: a take-off, 5 s of dead reckoning, the failsafe and back
def test_mavsdk_gps_off_in_flight_descends_and_ok_restores(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    """failure_injection.py's flow, checked: SYS_FAILURE_EN = 1 through MAVSDK's param plugin while its failure
    plugin already exists (it answered DISABLED before: a second PARAM_VALUE, as PX4's, updates it), take off, inject GPS OFF through MAVSDK's failure
    plugin -> GPS_RAW_INT fix 0, the GPS health bit cleared (MAVSDK: global position not OK), PX4's announcement,
    then after EKF2's dead-reckoning time GLOBAL_POSITION_INT stops and the Descend failsafe (AUTO.LAND) flies;
    Hold is refused meanwhile; FAILURE_TYPE_OK -> global position back and the vehicle back in Hold."""
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
    from mavsdk.asyncio.plugins.action import ActionAsync
    from mavsdk.asyncio.plugins.failure import FailureAsync
    from mavsdk.asyncio.plugins.param import ParamAsync
    from mavsdk.asyncio.plugins.telemetry import FlightMode, TelemetryAsync
    from mavsdk.plugins.failure import FailureError, FailureResult, FailureType, FailureUnit

    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()

    async def until(stream: object, pred: Callable[[object], bool], timeout_s: float) -> object:
        async with asyncio.timeout(timeout_s):
            async for item in stream:
                if pred(item):
                    return item
        raise AssertionError("unreachable")

    async def scenario() -> None:
        async with Mavsdk(Configuration.create_with_component_type(ComponentType.GROUND_STATION)) as mavsdk:
            await mavsdk.add_any_connection(sitl.ports.mavsdk_url)
            system = await mavsdk.first_autopilot(timeout_s=15.0)
            assert system is not None, "no autopilot discovered"
            action, telemetry, failure = ActionAsync(system), TelemetryAsync(system), FailureAsync(system)
            await until(telemetry.subscribe_health(), lambda h: h.is_global_position_ok, 30.0)
            # the example's order: the failure plugin exists (it read SYS_FAILURE_EN = 0) before the param plugin
            # sets it; the plugin learns the change from PX4's second, unsolicited PARAM_VALUE
            with pytest.raises(FailureError) as disabled:
                await failure.inject(FailureUnit.SYSTEM_BATTERY, FailureType.OFF, 0)
            assert disabled.value.result == FailureResult.DISABLED
            await ParamAsync(system).set_param_int("SYS_FAILURE_EN", 1)
            await action.set_takeoff_altitude(10.0)
            await action.arm()
            await action.takeoff()
            await until(telemetry.subscribe_position(), lambda p: p.relative_altitude_m > 9.0, 60.0)
            await until(telemetry.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD, 30.0)

            t0 = time.monotonic()
            await failure.inject(
                FailureUnit.SENSOR_GPS, FailureType.OFF, 0
            )  # raises FailureError unless SUCCESS
            await until(telemetry.subscribe_health(), lambda h: not h.is_global_position_ok, 10.0)
            peer.wait(
                "GPS_RAW_INT", lambda m: m.fix_type == 0 and m.satellites_visible == 0, 10.0, since_s=t0
            )
            peer.wait("STATUSTEXT", lambda m: m.text == "Injected: gps off, all instances", 10.0, since_s=t0)
            await until(telemetry.subscribe_flight_mode(), lambda m: m == FlightMode.LAND, 30.0)  # Descend
            fs = peer.wait(
                "STATUSTEXT", lambda m: m.text.startswith("Failsafe activated (no GPS)"), 5.0, since_s=t0
            )
            assert "Descend" in fs.text, fs.text
            t_lost = time.monotonic()
            ack = peer.command_long(176, [129.0, 4.0, 3.0])  # DO_SET_MODE Hold: needs a global position
            assert ack.result == mavlink2.MAV_RESULT_TEMPORARILY_REJECTED, ack.result
            assert peer.messages("GLOBAL_POSITION_INT", since_s=t0 - 2.0), "no GLOBAL_POSITION_INT before"
            peer.wait("HEARTBEAT", lambda m: True, 5.0, since_s=time.monotonic() + 1.5)  # >= 1.5 s more
            n_global = len(peer.messages("GLOBAL_POSITION_INT", since_s=t_lost + 0.3))
            assert n_global == 0, f"{n_global} GLOBAL_POSITION_INT while the global position is invalid"

            await failure.inject(FailureUnit.SENSOR_GPS, FailureType.OK, 0)
            await until(telemetry.subscribe_health(), lambda h: h.is_global_position_ok, 10.0)
            await until(telemetry.subscribe_flight_mode(), lambda m: m == FlightMode.HOLD, 15.0)
            t1 = time.monotonic()
            peer.wait("GLOBAL_POSITION_INT", lambda m: True, 5.0, since_s=t1)
            peer.wait("GPS_RAW_INT", lambda m: m.fix_type == 3, 5.0, since_s=t1)

    asyncio.run(scenario())


CAMERA = 200  # viva-sitl's FAILURE_UNIT extension: the VAC (MAVLink has no camera unit)
WRONG = 4  # FAILURE_TYPE_WRONG: black frames (STUCK, frozen, is checked in test_failure_injection.py)


@pytest.mark.slow  # a viva-sitl process streaming video
def test_camera_failure_blacks_out_and_drops_frame_socket_frames(
    sitl_factory: Callable[..., SitlProcess], peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    """A camera failure over MAVLink reaches the frame socket (and the RTP outputs, fed by the same render step):
    WRONG -> black frames with the pose still in their metadata, OFF -> no frames at all, OK -> live frames."""
    from viva_sitl.video.frame_socket import FrameClient

    (video_port,) = free_udp_ports(1)
    sitl = sitl_factory(video_port=video_port)
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    assert peer.set_param_int("SYS_FAILURE_EN", 1) == 1
    with FrameClient(f"tcp://127.0.0.1:{sitl.frame_socket_port}", latest_only=True) as client:

        def next_frame(after_s: float) -> tuple[Any, dict[str, Any]]:
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:
                item = client.receive(timeout_s=1.0)
                if item is not None and time.monotonic() > after_s:
                    return item
            raise AssertionError("no frame on the frame socket")

        live, _ = next_frame(0.0)
        assert live.any(), "the live VAC frame is all black"
        assert peer.command_long(INJECT, (CAMERA, WRONG, 0)).result == mavlink2.MAV_RESULT_ACCEPTED
        black, meta = next_frame(time.monotonic() + 0.3)
        assert not black.any() and "pos_ned_m" in meta
        assert peer.command_long(INJECT, (CAMERA, OFF, 0)).result == mavlink2.MAV_RESULT_ACCEPTED
        t_off = time.monotonic()
        while time.monotonic() < t_off + 0.5:  # frames already on their way
            client.receive(timeout_s=0.1)
        assert client.receive(timeout_s=1.5) is None, "frames still delivered while the camera is off"
        assert peer.command_long(INJECT, (CAMERA, OK, 0)).result == mavlink2.MAV_RESULT_ACCEPTED
        back, _ = next_frame(time.monotonic())
        assert back.any()


def test_sensor_stuck_and_wrong_over_mavlink_and_unsupported_types(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    """The failure types PX4 SITL honours beyond OFF, over real MAVLink: GPS STUCK repeats the last GPS_RAW_INT (its
    time_usec too), GPS WRONG offsets it by +1 deg; baro STUCK is stale (STATUSTEXT, SYS_STATUS baro health bit
    cleared); GARBAGE / SLOW / DELAYED / INTERMITTENT answer UNSUPPORTED, as PX4's simulation modules do."""
    stuck, garbage, wrong = 2, 3, 4  # FAILURE_TYPE_STUCK, _GARBAGE, _WRONG
    baro, baro_bit = 3, mavlink2.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    peer.send(peer.mav.param_set_encode(1, 1, b"SYS_FAILURE_EN", 1, mavlink2.MAV_PARAM_TYPE_INT32))
    peer.wait(
        "PARAM_VALUE", lambda m: m.param_id == "SYS_FAILURE_EN" and m.param_value == 1, 5.0, since_s=0.0
    )
    for ftype in (garbage, 5, 6, 7):
        assert peer.command_long(INJECT, (GPS, ftype, 0)).result == mavlink2.MAV_RESULT_UNSUPPORTED, ftype
    assert peer.command_long(INJECT, (baro, wrong, 0)).result == mavlink2.MAV_RESULT_UNSUPPORTED

    live = peer.wait("GPS_RAW_INT", lambda m: m.fix_type == 3, 10.0, since_s=time.monotonic())
    t0 = time.monotonic()
    assert peer.command_long(INJECT, (GPS, stuck, 0)).result == mavlink2.MAV_RESULT_ACCEPTED
    peer.wait("STATUSTEXT", lambda m: m.text == "Injected: gps stuck, all instances", 5.0, since_s=t0)
    first = peer.wait("GPS_RAW_INT", lambda m: True, 5.0, since_s=time.monotonic())
    later = peer.wait("GPS_RAW_INT", lambda m: True, 5.0, since_s=time.monotonic() + 0.5)
    assert first.time_usec >= live.time_usec and later.time_usec == first.time_usec  # the same fix, repeated
    assert (later.lat, later.lon, later.fix_type) == (first.lat, first.lon, 3)
    assert peer.command_long(INJECT, (GPS, wrong, 0)).result == mavlink2.MAV_RESULT_ACCEPTED
    off = peer.wait("GPS_RAW_INT", lambda m: m.lat - live.lat > 0.99e7, 5.0, since_s=time.monotonic())
    assert off.lon - live.lon > 0.99e7 and 99_000 < off.alt - live.alt < 101_000
    t1 = time.monotonic()
    assert peer.command_long(INJECT, (GPS, OK, 0)).result == mavlink2.MAV_RESULT_ACCEPTED
    peer.wait(
        "GPS_RAW_INT", lambda m: abs(m.lat - live.lat) < 1000, 5.0, since_s=t1, what="the true fix back"
    )

    t2 = time.monotonic()
    assert peer.command_long(INJECT, (baro, stuck, 1)).result == mavlink2.MAV_RESULT_ACCEPTED
    peer.wait("STATUSTEXT", lambda m: m.text == "Baro #0 fail: STALE!", 5.0, since_s=t2)
    peer.wait("SYS_STATUS", lambda m: not m.onboard_control_sensors_health & baro_bit, 5.0, since_s=t2)
    t3 = time.monotonic()
    assert peer.command_long(INJECT, (baro, OK, 1)).result == mavlink2.MAV_RESULT_ACCEPTED
    peer.wait("SYS_STATUS", lambda m: m.onboard_control_sensors_health & baro_bit, 5.0, since_s=t3)
