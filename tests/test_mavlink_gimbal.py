"""Gimbal manager v2 over real UDP (pymavlink codec client, selftest vehicle): discovery messages, control, pointing
the rendered VAC (cam_rot_body of the frame), limits and bad input. MAVSDK's own gimbal plugin: test_e2e_gimbal."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from mav_client import MavClient, Rig, VehicleThread
from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.camera import Mount
from viva_sitl.config import SimConfig
from viva_sitl.dynamics.rotation import rot_body_to_ned
from viva_sitl.mavlink.gimbal import euler_from_quat

M = mavlink2
ACCEPTED, DENIED, UNSUPPORTED = M.MAV_RESULT_ACCEPTED, M.MAV_RESULT_DENIED, M.MAV_RESULT_UNSUPPORTED


def gimbal_config() -> SimConfig:
    base = SimConfig(seed=0)
    return dataclasses.replace(base, camera=dataclasses.replace(base.camera, mount=Mount.GIMBAL))


@pytest.fixture
def gimbal_vehicle(vehicle_factory: Callable[..., VehicleThread]) -> VehicleThread:
    return vehicle_factory(sim_config=gimbal_config())


@pytest.fixture(params=[pytest.param("udp", marks=pytest.mark.slow), "sim"])
def gimbal_rig(request: pytest.FixtureRequest, rig_factory: Callable[..., Rig]) -> Rig:
    """The gimbal vehicle over UDP in real time (slow: seconds of waiting for streams), or on the sim-clock harness."""
    return rig_factory(request.param, sim_config=gimbal_config())


def view_deg(vt: VehicleThread | Rig) -> tuple[float, float]:
    """(elevation, azimuth from north) of the rendered VAC's optical axis, in degrees, from the frame's metadata."""

    def render() -> tuple[tuple[tuple[float, ...], ...], tuple[float, float, float]]:
        assert vt.vehicle is not None
        frame = vt.vehicle.vehicle.render()
        return frame.meta.cam_rot_body, tuple(float(v) for v in vt.vehicle.state.att_rpy_rad)  # type: ignore[return-value]

    cam_rot_body, att = vt.call(render)
    axis = rot_body_to_ned(*att) @ np.asarray(cam_rot_body)[:, 2]
    return math.degrees(-math.asin(float(axis[2]))), math.degrees(math.atan2(float(axis[1]), float(axis[0])))


def said(client: Any, text: str, timeout_s: float = 2.0) -> str | None:
    """A STATUSTEXT containing `text` received so far or within timeout_s (it may precede the COMMAND_ACK)."""
    for _, m in client.received:
        if m.get_type() == "STATUSTEXT" and text in m.text:
            return str(m.text)
    m = client.wait_for(lambda m: m.get_type() == "STATUSTEXT" and text in m.text, timeout_s)
    return None if m is None else str(m.text)


def take_control(client: Any) -> None:
    ack = client.command(M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, 255, 190, -1, -1, 0, 0, 0)
    assert ack is not None and ack.result == ACCEPTED


def pitchyaw(client: Any, pitch: float, yaw: float, flags: int = 0) -> int:
    ack = client.command(M.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW, pitch, yaw, math.nan, math.nan, flags, 0, 0)
    assert ack is not None
    return int(ack.result)


def test_fixed_mount_has_no_gimbal(vehicle_factory: Callable[..., VehicleThread], client: MavClient) -> None:
    vehicle_factory()
    ack = client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION)
    assert ack is not None and ack.result == UNSUPPORTED
    assert pitchyaw(client, -45, 0) == UNSUPPORTED


def test_discovery_control_and_pointing(gimbal_rig: Rig) -> None:
    vt, client = gimbal_rig, gimbal_rig.client
    assert view_deg(vt)[0] == pytest.approx(-90.0, abs=1e-6)  # at rest: the nadir mount
    ack = client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION)
    assert ack is not None and ack.result == ACCEPTED
    info = client.wait_for("GIMBAL_MANAGER_INFORMATION")
    assert info is not None and info.get_srcComponent() == 1 and info.gimbal_device_id == 1
    assert math.degrees(info.pitch_min) == pytest.approx(-90) and math.degrees(
        info.pitch_max
    ) == pytest.approx(30)
    assert info.cap_flags & M.GIMBAL_MANAGER_CAP_FLAGS_CAN_POINT_LOCATION_GLOBAL
    client.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_GIMBAL_DEVICE_INFORMATION)
    dev = client.wait_for("GIMBAL_DEVICE_INFORMATION")
    assert dev is not None and dev.gimbal_device_id == 1
    # streams: device attitude and manager status, nobody in control yet
    status = client.wait_for("GIMBAL_MANAGER_STATUS", 3.0)
    assert status is not None and (status.primary_control_sysid, status.primary_control_compid) == (0, 0)
    # as PX4: commands from someone not in control are DENIED, with the reason
    client.drain()
    assert pitchyaw(client, -30, 45) == DENIED
    assert said(client, "Gimbal: 255/190 is not in control")
    take_control(client)
    status = client.wait_for(
        lambda m: m.get_type() == "GIMBAL_MANAGER_STATUS" and m.primary_control_sysid == 255
    )
    assert status is not None and status.primary_control_compid == 190
    assert pitchyaw(client, -30, 45) == ACCEPTED
    elevation, azimuth = view_deg(vt)
    yaw0 = math.degrees(vt.call(lambda: float(vt.vehicle.state.yaw_rad)))  # type: ignore[union-attr]
    assert elevation == pytest.approx(-30, abs=0.01)
    assert azimuth == pytest.approx(yaw0 + 45, abs=0.01)  # yaw from the nose
    att = client.wait_for(
        lambda m: (
            m.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS"
            and abs(math.degrees(euler_from_quat(tuple(m.q))[1]) + 30) < 0.01
        ),  # type: ignore[arg-type]
        3.0,
    )
    assert att is not None and att.flags & M.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME
    assert math.degrees(euler_from_quat(tuple(att.q))[2]) == pytest.approx(45, abs=0.01)  # type: ignore[arg-type]
    # yaw lock: the yaw is from north
    assert pitchyaw(client, -60, 90, M.GIMBAL_MANAGER_FLAGS_YAW_LOCK) == ACCEPTED
    assert view_deg(vt) == pytest.approx((-60, 90), abs=0.01)
    # neutral flag: back to the mount
    assert pitchyaw(client, 0, 0, M.GIMBAL_MANAGER_FLAGS_NEUTRAL) == ACCEPTED
    assert view_deg(vt)[0] == pytest.approx(-90, abs=1e-6)
    # releasing control (-3): then denied again
    ack = client.command(M.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, -3, -3, -1, -1, 0, 0, 0)
    assert ack is not None and ack.result == ACCEPTED
    assert pitchyaw(client, -30, 0) == DENIED


def test_out_of_range_and_bad_input(gimbal_rig: Rig) -> None:
    vt, client = gimbal_rig, gimbal_rig.client
    take_control(client)
    client.drain()
    # out of range: clamped to the advertised limits (PX4 saturates), accepted, and said
    assert pitchyaw(client, -120, 0) == ACCEPTED
    assert said(client, "Gimbal pitch -120 outside [-90, 30]: -90")
    assert view_deg(vt)[0] == pytest.approx(-90, abs=1e-6)
    assert pitchyaw(client, 75, 0) == ACCEPTED
    assert view_deg(vt)[0] == pytest.approx(30, abs=0.01)
    # NaN pitch: that axis unchanged (MAVLink "no change"); a yaw beyond 180 wraps
    assert pitchyaw(client, math.nan, 370) == ACCEPTED
    elevation, azimuth = view_deg(vt)
    yaw0 = math.degrees(vt.call(lambda: float(vt.vehicle.state.yaw_rad)))  # type: ignore[union-attr]
    assert elevation == pytest.approx(30, abs=0.01)
    assert (azimuth - yaw0 - 10 + 180) % 360 - 180 == pytest.approx(0, abs=0.01)
    # GIMBAL_MANAGER_SET_ATTITUDE from someone not in control: ignored, with a warning
    other = vt.peer(42, 190)
    try:
        q = [math.cos(math.radians(-10)), 0.0, math.sin(math.radians(-10)), 0.0]  # pitch -20
        other.send(M.MAVLink_gimbal_manager_set_attitude_message(1, 1, 0, 0, q, math.nan, math.nan, math.nan))
        assert said(client, "Gimbal setpoint ignored: 42/190 is not in control")
        assert view_deg(vt)[0] == pytest.approx(30, abs=0.01)
    finally:
        other.close()
    # from the controller: applied; NaN quaternion and NaN rates: ignored, the angles stay
    client.send(M.MAVLink_gimbal_manager_set_attitude_message(1, 1, 0, 0, q, math.nan, math.nan, math.nan))
    assert client.wait_for(lambda m: False, 0.3) is None
    assert view_deg(vt)[0] == pytest.approx(-20, abs=0.01)
    nan4 = [math.nan] * 4
    client.send(M.MAVLink_gimbal_manager_set_attitude_message(1, 1, 0, 0, nan4, math.nan, math.nan, math.nan))
    assert client.wait_for(lambda m: False, 0.3) is None
    assert view_deg(vt)[0] == pytest.approx(-20, abs=0.01)
    assert vt.endpoint is not None and vt.endpoint.gimbal is not None
    assert vt.endpoint.gimbal.setpoints_ignored == 2
    assert vt.stats()["handler_errors"] == 0


def test_roi_location_and_none(gimbal_vehicle: VehicleThread, client: MavClient) -> None:
    """DO_SET_ROI_LOCATION points at the place (no control needed, as PX4's vehicle_roi); ROI_NONE rests."""
    vt = gimbal_vehicle
    assert vt.vehicle is not None
    pos = vt.call(lambda: tuple(float(v) for v in vt.vehicle.state.pos_ned_m))  # type: ignore[union-attr]
    # 20 m east of the vehicle and 20 m below it: 45 deg down, bearing 90
    lat, lon, alt = vt.vehicle.geo.ned_to_global(pos[0], pos[1] + 20.0, pos[2] + 20.0)
    # COMMAND_INT as MAVSDK sends it (COMMAND_LONG's float32 latitude is only ~0.5 m precise)
    client.send(client.mav.command_int_encode(1, 1, M.MAV_FRAME_GLOBAL, M.MAV_CMD_DO_SET_ROI_LOCATION, 0, 0, 0, 0, 0,
                                              0, round(lat * 1e7), round(lon * 1e7), alt))  # fmt: skip
    ack = client.wait_for(
        lambda m: m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_DO_SET_ROI_LOCATION
    )
    assert ack is not None and ack.result == ACCEPTED
    assert view_deg(vt) == pytest.approx((-45, 90), abs=0.05)
    ack = client.command(M.MAV_CMD_DO_SET_ROI_LOCATION, 0, 0, 0, 0, math.nan, math.nan, 0)
    assert ack is not None and ack.result == DENIED  # no location
    ack = client.command(M.MAV_CMD_DO_SET_ROI_NONE)
    assert ack is not None and ack.result == ACCEPTED
    assert view_deg(vt)[0] == pytest.approx(-90, abs=1e-6)
