"""Bad input over real UDP: malformed frames, bad CRCs, unknown ids, NaN/inf fields, absurd counts, commands full of
NaN. The vehicle must keep heartbeating with finite telemetry, answer what is valid, and count what it dropped."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable

import numpy as np
import pytest
from mav_client import MavClient, Rig, VehicleThread
from pymavlink.dialects.v20 import common as M

NAN, INF = math.nan, math.inf


@pytest.fixture
def vehicle(vehicle_factory: Callable[..., VehicleThread]) -> VehicleThread:
    return vehicle_factory(speed=2.0)


def _pack(client: MavClient, msg: M.MAVLink_message) -> bytes:
    buf = bytes(msg.pack(client.mav))
    client.mav.seq = (client.mav.seq + 1) % 256
    return buf


def _unknown_frame(msgid: int = 0xABCDE) -> bytes:
    payload = b"\x01\x02\x03\x04"
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, 7, 255, 190, msgid & 0xFFFF, msgid >> 16)
    return header + payload + b"\x00\x00"


def _ping(client: MavClient, seq: int) -> bytes:
    return _pack(client, client.mav.ping_encode(1000 + seq, seq, 0, 0))


def _answered(client: MavClient, seq: int, timeout_s: float = 1.0) -> bool:
    return client.wait_for(lambda m: m.get_type() == "PING" and m.seq == seq, timeout_s) is not None


def test_parser_resyncs_within_and_across_datagrams(client: MavClient, vehicle: VehicleThread) -> None:
    # a truncated frame in front of a valid one, in the same datagram
    cut = _ping(client, 200)[:-6]
    client.send_raw(cut + _ping(client, 1))
    assert _answered(client, 1), "valid frame after a truncated one was lost"
    # a frame whose header promises 255 bytes: must not swallow the next datagram
    client.send_raw(bytes([0xFD, 0xFF, 0, 0, 0, 255, 190, 4, 0, 0]) + b"\x00" * 20)
    client.send_raw(_ping(client, 2))
    assert _answered(client, 2), "a truncated datagram swallowed the next one"
    # garbage around a frame, bad CRC before a frame
    rng = np.random.default_rng(7)
    bad_crc = bytearray(_ping(client, 201))
    bad_crc[-1] ^= 0xFF
    client.send_raw(
        rng.bytes(100).replace(b"\xfd", b"\x00").replace(b"\xfe", b"\x00") + _ping(client, 3) + rng.bytes(50)
    )
    assert _answered(client, 3)
    client.send_raw(bytes(bad_crc) + _ping(client, 4))
    assert _answered(client, 4)
    assert client.wait_for(lambda m: m.get_type() == "PING" and m.seq == 201, 0.3) is None  # bad CRC: dropped
    # MAVLink 1 frames are understood too
    client.send_raw(bytes(client.mav.ping_encode(1, 5, 0, 0).pack(client.mav, force_mavlink1=True)))
    assert _answered(client, 5)
    st = vehicle.stats()
    assert st["bad_frames"] >= 3 and st["garbage_bytes"] >= 100
    assert st["handler_errors"] == 0


@pytest.fixture(params=[pytest.param("udp", marks=pytest.mark.slow), "sim"])
def rig(request: pytest.FixtureRequest, rig_factory: Callable[..., Rig]) -> Rig:
    """Over UDP at speed 2 (slow: seconds of streaming and waiting), or on the sim-clock harness (the fast tier)."""
    return rig_factory(request.param, speed=2.0)


def test_garbage_nan_and_absurd_input_keep_vehicle_alive(rig: Rig) -> None:
    client = rig.client
    mav = client.mav
    rng = np.random.default_rng(1)
    # raw garbage, a datagram full of start markers, an unknown message id, an empty datagram
    for _ in range(20):
        client.send_raw(rng.bytes(int(rng.integers(1, 600))))
    client.send_raw(b"\xfd" * 60000)
    client.send_raw(_unknown_frame())
    client.send_raw(b"")
    # NaN / inf setpoints of every kind
    for mask, frame in ((2552, 1), (2503, 1), (1479, 8), (0, 1), (7, 1), (2552, 77)):
        client.send(
            mav.set_position_target_local_ned_encode(
                0, 1, 1, frame, mask, NAN, INF, -INF, NAN, NAN, NAN, INF, 0, 0, NAN, INF
            )
        )
    client.send(
        mav.set_position_target_global_int_encode(
            0, 1, 1, 6, 2552, 2**31 - 1, -(2**31), NAN, 0, 0, 0, 0, 0, 0, 0, 0
        )
    )
    for mask in (7, 128, 0, 64, 255):
        client.send(mav.set_attitude_target_encode(0, 1, 1, mask, [NAN, INF, 0, 0], NAN, INF, -INF, NAN))
    client.send(mav.set_attitude_target_encode(0, 1, 1, 7, [0, 0, 0, 0], 0, 0, 0, 0.5))  # zero quaternion
    client.send(mav.manual_control_encode(1, -32768, 32767, -32768, 32767, 0))
    # every command with NaN/inf parameters, long and int
    commands = (
        400,
        22,
        21,
        20,
        176,
        192,
        178,
        300,
        224,
        185,
        179,
        512,
        520,
        511,
        510,
        410,
        2000,
        2001,
        31000,
    )
    for cmd in commands:
        client.send(mav.command_long_encode(1, 0, cmd, 0, NAN, INF, -INF, NAN, NAN, NAN, NAN))
        client.send(
            mav.command_int_encode(1, 1, 250, cmd, 0, 0, NAN, INF, NAN, NAN, 2**31 - 1, -(2**31), NAN)
        )
    # absurd mission traffic and parameters
    client.send(mav.mission_count_encode(1, 1, 65535, 0))
    client.send(mav.mission_item_int_encode(1, 1, 40000, 77, 9999, 5, 9, NAN, NAN, NAN, NAN, 0, 0, NAN, 0))
    client.send(mav.mission_request_int_encode(1, 1, 9999, 0))
    client.send(mav.mission_request_list_encode(1, 1, 77))
    client.send(mav.mission_set_current_encode(1, 1, 65535))
    client.send(mav.param_set_encode(1, 1, b"\xff\xfe\x00", NAN, 200))
    client.send(mav.param_request_read_encode(1, 1, b"", 32000))

    acks = {}
    for _ in range(400):
        m = client.wait_for("COMMAND_ACK", 1.0)
        if m is None:
            break
        acks[m.command] = m.result
    assert set(commands) <= set(acks), f"commands without ACK: {sorted(set(commands) - set(acks))}"
    assert acks[31000] == M.MAV_RESULT_UNSUPPORTED

    client.received.clear()
    client.poll(2.5)
    types = [m.get_type() for _, m in client.received]
    assert (
        sum(1 for _, m in client.received if m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1) >= 2
    )
    for _, m in client.received:
        if m.get_type() in ("ATTITUDE", "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "VFR_HUD", "ALTITUDE"):
            for name in m.get_fieldnames():
                v = getattr(m, name)
                if isinstance(v, float):
                    assert math.isfinite(v), f"{m.get_type()}.{name} = {v}"
    assert "ATTITUDE" in types and "GLOBAL_POSITION_INT" in types
    client.send(mav.ping_encode(1, 99, 0, 0))
    assert _answered(client, 99)
    st = rig.stats()
    assert st["handler_errors"] == 0, st
    assert st["unknown_messages"] >= 1 and st["bad_frames"] >= 1
    assert st["setpoints_rejected"] >= 10
    state = rig.call(lambda: rig.vehicle.state)
    assert np.all(np.isfinite(state.pos_ned_m)) and np.all(np.isfinite(state.att_rpy_rad))


def test_nan_setpoints_in_offboard_flight_keep_state_finite(rig: Rig) -> None:
    client = rig.client
    mav = client.mav

    def sp(x: float, y: float, z: float) -> M.MAVLink_message:
        return mav.set_position_target_local_ned_encode(0, 1, 1, 1, 2552, x, y, z, 0, 0, 0, 0, 0, 0, 0, 0)

    for _ in range(30):  # > 2 Hz for ~1 s before OFFBOARD (PX4's rule)
        client.send(sp(0, 0, -2))
        client.poll(0.03)
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
    ack = client.command(M.MAV_CMD_DO_SET_MODE, 1, 6, 0)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    for i in range(120):
        client.send(sp(NAN, INF, -INF) if i % 2 else sp(1.0, 0.0, -2.0))
        client.poll(0.02)
    client.drain()
    lp = client.wait_for("LOCAL_POSITION_NED", 1.0)
    assert lp is not None and all(math.isfinite(v) for v in (lp.x, lp.y, lp.z, lp.vx, lp.vy, lp.vz))
    assert lp.z < -0.5, "the valid setpoints (z = -2) were not followed"
    st = rig.stats()
    assert st["setpoints_rejected"] >= 50 and st["setpoints_handled"] >= 80 and st["handler_errors"] == 0
