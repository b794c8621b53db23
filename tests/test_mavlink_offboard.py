"""Offboard: type_mask decoding as PX4 reads MAVSDK's masks, GLOBAL_INT conversion, and offboard flights over UDP
(position, velocity, attitude + thrust) with the real autopilot."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import pytest
from mav_client import Rig
from pymavlink.dialects.v20 import common as M

from viva_sitl.autopilot import FlightMode, OffboardFrame
from viva_sitl.dynamics import EavState, quat_from_euler
from viva_sitl.geo import GeoOrigin
from viva_sitl.mavlink.offboard import (
    Rejected,
    decode_attitude_target,
    decode_manual_control,
    decode_position_target_global,
    decode_position_target_local,
)

NAN = math.nan
MAV = M.MAVLink(None, 255, 190)
STATE = EavState.at_rest((1.0, 2.0, -3.0))


def _local(
    mask: int,
    frame: int = 1,
    pos=(1.0, 2.0, -3.0),
    vel=(0.5, -0.5, 0.1),
    acc=(0.0, 0.0, 0.0),
    yaw=0.3,
    yaw_rate=0.1,
):  # type: ignore[no-untyped-def]
    return MAV.set_position_target_local_ned_encode(0, 1, 1, frame, mask, *pos, *vel, *acc, yaw, yaw_rate)


def test_mavsdk_position_velocity_and_body_masks() -> None:
    t = decode_position_target_local(_local(2552), STATE)  # set_position_ned
    assert not isinstance(t, Rejected)
    assert t.pos_ned_m == (1.0, 2.0, -3.0) and t.vel_ned_m_s is None and t.acc_ned_m_s2 is None
    assert t.yaw_rad == pytest.approx(0.3) and t.yaw_rate_rad_s is None and t.frame == OffboardFrame.LOCAL_NED
    t = decode_position_target_local(_local(2503), STATE)  # set_velocity_ned
    assert not isinstance(t, Rejected)
    assert (
        t.pos_ned_m is None
        and t.vel_ned_m_s == pytest.approx((0.5, -0.5, 0.1))
        and t.yaw_rad == pytest.approx(0.3)
    )
    t = decode_position_target_local(_local(1479, frame=M.MAV_FRAME_BODY_NED), STATE)  # set_velocity_body
    assert not isinstance(t, Rejected)
    assert t.frame == OffboardFrame.BODY_NED and t.vel_ned_m_s is not None and t.yaw_rad is None
    assert t.yaw_rate_rad_s == pytest.approx(0.1)
    # LOCAL_OFFSET_NED positions are relative to the vehicle
    t = decode_position_target_local(
        _local(2552, frame=M.MAV_FRAME_LOCAL_OFFSET_NED, pos=(1.0, 0.0, 0.0)), STATE
    )
    assert not isinstance(t, Rejected) and t.pos_ned_m == pytest.approx((2.0, 2.0, -3.0))


def test_bad_position_targets_are_rejected_not_passed() -> None:
    assert isinstance(decode_position_target_local(_local(2552, pos=(NAN, 0.0, 0.0)), STATE), Rejected)
    assert isinstance(decode_position_target_local(_local(2503, vel=(math.inf, 0.0, 0.0)), STATE), Rejected)
    assert isinstance(
        decode_position_target_local(_local(2552 | 4), STATE), Rejected
    )  # partial: z ignored only
    assert isinstance(decode_position_target_local(_local(0xFFFF), STATE), Rejected)  # ignores everything
    assert isinstance(decode_position_target_local(_local(2552, frame=M.MAV_FRAME_GLOBAL), STATE), Rejected)
    # NaN yaw with yaw in use: yaw dropped, the setpoint kept (PX4: "not controlled")
    t = decode_position_target_local(_local(2552, yaw=NAN), STATE)
    assert not isinstance(t, Rejected) and t.yaw_rad is None


def test_global_int_target_converted_through_geo_origin() -> None:
    geo = GeoOrigin()
    lat, lon, _ = geo.ned_to_global(30.0, -20.0, 0.0)
    home = (0.0, 0.0, -1.0)  # home 1 m above the NED origin
    msg = MAV.set_position_target_global_int_encode(0, 1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 2552,
                                                     round(lat * 1e7), round(lon * 1e7), 10.0, 0, 0, 0, 0, 0, 0, 0, 0)  # fmt: skip
    t = decode_position_target_global(msg, geo, home)
    assert not isinstance(t, Rejected) and t.frame == OffboardFrame.GLOBAL
    assert t.pos_ned_m == pytest.approx((30.0, -20.0, -11.0), abs=0.02)
    msg = MAV.set_position_target_global_int_encode(0, 1, 1, M.MAV_FRAME_GLOBAL_INT, 2552,
                                                     round(lat * 1e7), round(lon * 1e7), geo.alt_amsl_m + 5, 0, 0, 0, 0, 0, 0, 0, 0)  # fmt: skip
    t = decode_position_target_global(msg, geo, home)
    assert (
        not isinstance(t, Rejected)
        and t.pos_ned_m is not None
        and t.pos_ned_m[2] == pytest.approx(-5.0, abs=1e-3)
    )
    bad = MAV.set_position_target_global_int_encode(
        0, 1, 1, 6, 2552, 2**31 - 1, 0, 5.0, 0, 0, 0, 0, 0, 0, 0, 0
    )
    assert isinstance(decode_position_target_global(bad, geo, home), Rejected)


def test_attitude_target_masks() -> None:
    q = quat_from_euler(0.1, -0.05, 1.0)
    t = decode_attitude_target(MAV.set_attitude_target_encode(0, 1, 1, 7, list(q), 0, 0, 0, 0.6))
    assert not isinstance(t, Rejected)
    assert t.q_wxyz == pytest.approx(q) and t.body_rates_rad_s is None and t.thrust_norm == pytest.approx(0.6)
    t = decode_attitude_target(MAV.set_attitude_target_encode(0, 1, 1, 128, [1, 0, 0, 0], 0.1, 0.2, 0.3, 0.5))
    assert (
        not isinstance(t, Rejected)
        and t.q_wxyz is None
        and t.body_rates_rad_s == pytest.approx((0.1, 0.2, 0.3))
    )
    assert isinstance(
        decode_attitude_target(MAV.set_attitude_target_encode(0, 1, 1, 7 | 64, list(q), 0, 0, 0, 0.5)),
        Rejected,
    )
    assert isinstance(
        decode_attitude_target(MAV.set_attitude_target_encode(0, 1, 1, 7, list(q), 0, 0, 0, NAN)), Rejected
    )
    assert isinstance(
        decode_attitude_target(MAV.set_attitude_target_encode(0, 1, 1, 7, [0, 0, 0, 0], 0, 0, 0, 0.5)),
        Rejected,
    )
    t = decode_attitude_target(MAV.set_attitude_target_encode(0, 1, 1, 7, [2, 0, 0, 0], 0, 0, 0, 1.7))
    assert not isinstance(t, Rejected) and t.q_wxyz == pytest.approx((1, 0, 0, 0)) and t.thrust_norm == 1.0


def test_manual_control_normalised() -> None:
    m = decode_manual_control(MAV.manual_control_encode(1, 1000, -500, 500, 0, 0))
    assert not isinstance(m, Rejected) and (m.x, m.y, m.z, m.r) == (1.0, -0.5, 0.5, 0.0)
    m = decode_manual_control(MAV.manual_control_encode(1, -32768, 32767, -1000, 32767, 0))
    assert not isinstance(m, Rejected) and m.x == -1.0 and m.y == 0.0 and m.z == 0.0 and m.r == 0.0


# --- over UDP ----------------------------------------------------------------------------------------------------


@pytest.fixture(params=[pytest.param("udp", marks=pytest.mark.slow), "sim"])
def rig(request: pytest.FixtureRequest, rig_factory: Callable[..., Rig]) -> Rig:
    """Over UDP at speed 3 (slow: ~5 s of wall-clock streaming a flight), or on the sim-clock harness with the
    client's timeouts and stream periods scaled by 3: the same setpoint stream in sim time (the fast tier)."""
    # Telemetry runs per sim second (3x the wall rate here) and this client shares the process (GIL) with the
    # vehicle: only the streams these tests read, so the client keeps up and its setpoint stream stays regular.
    rates = (
        ("ATTITUDE", 30.0),
        ("ATTITUDE_QUATERNION", 0.0),
        ("GLOBAL_POSITION_INT", 5.0),
        ("ALTITUDE", 0.0),
    )
    return rig_factory(request.param, speed=3.0, rate_overrides=rates)


def _stream(client: Any, msg: M.MAVLink_message, seconds: float, hz: float = 20.0) -> None:
    for _ in range(int(seconds * hz)):
        client.send(msg)
        client.poll(1.0 / hz)


def _stream_until(client: Any, msg: M.MAVLink_message, pred: Callable[[M.MAVLink_message], bool],
                  timeout_s: float = 2.0, hz: float = 20.0) -> M.MAVLink_message | None:  # fmt: skip
    """Keep the setpoint stream going (PX4 leaves offboard after COM_OF_LOSS_T without it) while waiting."""
    client.drain()
    for _ in range(int(timeout_s * hz)):
        client.send(msg)
        for m in client.poll(1.0 / hz):
            if pred(m):
                return m
    return None


def test_offboard_refused_without_stream_then_position_and_velocity(rig: Rig) -> None:
    client = rig.client
    mav = client.mav
    ack = client.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0)
    assert ack is not None and ack.result == M.MAV_RESULT_TEMPORARILY_REJECTED
    pos = mav.set_position_target_local_ned_encode(
        0, 1, 1, 1, 2552, 2.0, -1.0, -3.0, 0, 0, 0, 0, 0, 0, 0.0, 0
    )
    _stream(client, pos, 1.0)
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
    client.send(pos)  # the stream goes on while we wait for acks (MAVSDK streams in the background)
    ack = client.command(M.MAV_CMD_DO_SET_MODE, 129, 6, 0)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    _stream(client, pos, 2.5)
    hb = _stream_until(client, pos, lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1)
    assert hb is not None and hb.custom_mode == FlightMode.OFFBOARD.custom_mode == 393216
    lp = _stream_until(client, pos, lambda m: m.get_type() == "LOCAL_POSITION_NED")
    assert lp is not None and (lp.x, lp.y, lp.z) == pytest.approx((2.0, -1.0, -3.0), abs=0.4)
    # velocity (MAVSDK set_velocity_ned): 1 m/s east
    vel = mav.set_position_target_local_ned_encode(0, 1, 1, 1, 2503, 0, 0, 0, 0.0, 1.0, 0.0, 0, 0, 0, 0.0, 0)
    _stream(client, vel, 1.5)
    lp = _stream_until(client, vel, lambda m: m.get_type() == "LOCAL_POSITION_NED")
    assert lp is not None and lp.vy == pytest.approx(1.0, abs=0.25) and lp.y > 0.0
    # stop streaming: PX4's offboard-loss failsafe (COM_OF_LOSS_T) leaves OFFBOARD
    hb = client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1
                         and m.custom_mode != FlightMode.OFFBOARD.custom_mode, 3.0)  # fmt: skip
    assert hb is not None
    st = rig.stats()
    assert st["setpoints_handled"] >= 80 and st["setpoints_rejected"] == 0


def test_offboard_attitude_thrust_hover_and_climb(rig: Rig) -> None:
    client = rig.client
    mav = client.mav
    hover = rig.call(lambda: rig.vehicle.params.get("MPC_THR_HOVER"))
    climb = mav.set_attitude_target_encode(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, min(1.0, hover + 0.15))
    _stream(client, climb, 1.0)
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
    client.send(climb)  # the stream goes on while we wait for acks (MAVSDK streams in the background)
    assert client.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
    _stream(client, climb, 1.0)
    climbing = _stream_until(client, climb, lambda m: m.get_type() == "LOCAL_POSITION_NED")
    assert climbing is not None and climbing.z < -0.5 and climbing.vz < -0.2, (
        "thrust above MPC_THR_HOVER must climb"
    )
    level = mav.set_attitude_target_encode(0, 1, 1, 7, [1, 0, 0, 0], 0, 0, 0, hover)
    _stream(client, level, 1.5)
    lp = _stream_until(client, level, lambda m: m.get_type() == "LOCAL_POSITION_NED")
    # at MPC_THR_HOVER thrust balances weight: only drag acts, the climb rate decays (k_d/m ~ 0.32/s)
    assert lp is not None and abs(lp.vz) < 0.6 * abs(climbing.vz)
    att = _stream_until(client, level, lambda m: m.get_type() == "ATTITUDE")
    assert att is not None and abs(att.roll) < 0.05 and abs(att.pitch) < 0.05
