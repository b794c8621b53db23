"""End to end, bad input: malformed frames, garbage, NaN/inf setpoints, unknown commands and absurd mission counts
must neither crash nor derail the vehicle: it keeps heartbeating with a finite state and still flies afterwards."""

from __future__ import annotations

import math
import random
import time
from collections.abc import Callable

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from sitl_process import MODE_OFFBOARD, MavlinkPeer, SetpointStreamer, SitlProcess, finite, is_armed

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # slow: flights of a viva-sitl process

POSITION_ONLY_MASK = 2552  # MAVSDK's set_position_ned: position + yaw
ATTITUDE_MASK = 7  # ignore body rates: quaternion + thrust
NAN, INF = math.nan, math.inf


def assert_alive_and_finite(peer: MavlinkPeer, within_s: float = 3.0) -> None:
    t0 = time.monotonic()
    peer.wait(
        "HEARTBEAT", lambda m: m.get_srcComponent() == 1, within_s, since_s=t0, what="heartbeat after abuse"
    )
    pos = peer.wait("LOCAL_POSITION_NED", timeout_s=within_s, since_s=t0)
    assert finite(pos.x, pos.y, pos.z, pos.vx, pos.vy, pos.vz), f"non-finite LOCAL_POSITION_NED {pos}"
    att = peer.wait("ATTITUDE", timeout_s=within_s, since_s=t0)
    assert finite(att.roll, att.pitch, att.yaw), f"non-finite ATTITUDE {att}"


def garbage_datagrams(peer: MavlinkPeer, rng: random.Random) -> list[bytes]:
    """Random bytes, truncated and corrupted frames, lying length fields, MAVLink 1 noise."""
    valid = [
        peer.mav.heartbeat_encode(6, 8, 0, 0, 0).pack(peer.mav),
        peer.mav.command_long_encode(1, 1, 400, 0, 0, 0, 0, 0, 0, 0, 0).pack(
            peer.mav
        ),  # disarm: harmless if whole
        peer.mav.mission_request_list_encode(1, 1, 0).pack(peer.mav),
    ]
    out: list[bytes] = [b"", b"\xfd", b"\xfe", b"\xfd\xff", bytes(280), b"\xff" * 600]
    out += [bytes(rng.randrange(256) for _ in range(rng.randrange(1, 300))) for _ in range(200)]
    for frame in valid:
        out += [
            frame[: len(frame) // 2],
            frame[:-1],
            frame + frame[:5],
        ]  # truncated, short CRC, trailing junk
        bad_crc = bytearray(frame)
        bad_crc[-1] ^= 0xFF
        out.append(bytes(bad_crc))
        lying = bytearray(frame)
        lying[1] = 255  # payload length says 255, datagram is short
        out.append(bytes(lying))
    out.append(b"\xfd\x09\x00\x00\x00\xff\xbe\xff\xff\xff" + bytes(11))  # unknown msgid 0xFFFFFF
    out.append(b"\xfe\x09\x00\xff\xbe\x00" + bytes(11))  # MAVLink 1 heartbeat with a wrong CRC
    return out


def test_garbage_nan_unknown_commands_and_absurd_mission(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    api = peer_factory(sitl.ports.api)
    api.wait_autopilot()
    rng = random.Random(1234)

    for data in garbage_datagrams(peer, rng):
        peer.send_raw(data)
        api.send_raw(data)
    assert_alive_and_finite(peer)
    assert_alive_and_finite(api)

    # NaN / inf / degenerate setpoints while on the ground and not in offboard.
    mav = peer.mav
    for x, y, z in ((NAN, 0, -5), (0, INF, -5), (-INF, NAN, NAN), (3.0e38, -3.0e38, 3.0e38)):
        peer.send(
            mav.set_position_target_local_ned_encode(
                0, 1, 1, 1, POSITION_ONLY_MASK, x, y, z, 0, 0, 0, 0, 0, 0, 0, 0
            )
        )
        peer.send(mav.set_position_target_local_ned_encode(0, 1, 1, 8, 0, x, y, z, x, y, z, x, y, z, x, y))
    for q, thrust in (
        ([NAN, 0, 0, 0], 0.5),
        ([1, 0, 0, 0], INF),
        ([0, 0, 0, 0], 0.5),
        ([INF, INF, 0, 0], NAN),
    ):
        peer.send(mav.set_attitude_target_encode(0, 1, 1, ATTITUDE_MASK, q, 0, 0, 0, thrust))
        peer.send(mav.set_attitude_target_encode(0, 1, 1, 128, q, NAN, INF, -INF, thrust))
    peer.send(
        mav.set_position_target_global_int_encode(
            0, 1, 1, 6, 0, 2**31 - 1, -(2**31), NAN, 0, 0, 0, 0, 0, 0, 0, 0
        )
    )
    peer.send(mav.manual_control_encode(1, 32767, -32768, 32767, -32768, 0))
    peer.send(mav.param_set_encode(1, 1, b"MPC_XY_CRUISE", NAN, mavlink2.MAV_PARAM_TYPE_REAL32))
    peer.send(mav.param_set_encode(1, 1, b"NO_SUCH_PARAM_X", 1.0, mavlink2.MAV_PARAM_TYPE_REAL32))
    peer.send(mav.mission_item_int_encode(1, 1, 900, 3, 16, 0, 1, NAN, NAN, NAN, NAN, 0, 0, NAN, 0))
    peer.send(mav.mission_request_int_encode(1, 1, 60000, 0))
    assert_alive_and_finite(peer)

    # Unknown commands are ACKed UNSUPPORTED; known ones with NaN everywhere must not crash anything.
    for command in (31999, 65000, 1):
        ack = peer.command_long(command, [NAN] * 7)
        assert ack.result == mavlink2.MAV_RESULT_UNSUPPORTED, f"command {command}: MAV_RESULT {ack.result}"
    for command in (
        mavlink2.MAV_CMD_DO_REPOSITION,
        mavlink2.MAV_CMD_DO_CHANGE_SPEED,
        mavlink2.MAV_CMD_DO_SET_MODE,
    ):
        peer.command_long(command, [NAN, INF, -INF, NAN, NAN, NAN, NAN])  # any result: it must answer
    assert_alive_and_finite(peer)
    assert not is_armed(peer.latest("HEARTBEAT", component=1)), "bad input armed the vehicle"

    # An absurd mission count is refused with a MISSION_ACK error, not a 65535-item request loop.
    t0 = time.monotonic()
    peer.send(mav.mission_count_encode(1, 1, 65535, 0))
    ack = peer.wait("MISSION_ACK", timeout_s=3.0, since_s=t0, what="MISSION_ACK for MISSION_COUNT 65535")
    assert ack.type != mavlink2.MAV_MISSION_ACCEPTED, "MISSION_COUNT 65535 accepted"

    # The parameter kept a finite value.
    t0 = time.monotonic()
    peer.send(mav.param_request_read_encode(1, 1, b"MPC_XY_CRUISE", -1))
    value = peer.wait("PARAM_VALUE", lambda m: m.param_id == "MPC_XY_CRUISE", 3.0, since_s=t0).param_value
    assert math.isfinite(value) and value > 0

    # Still a working vehicle: a normal command is accepted.
    ack = peer.command_long(
        mavlink2.MAV_CMD_REQUEST_MESSAGE, [float(mavlink2.MAVLINK_MSG_ID_AUTOPILOT_VERSION)]
    )
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
    peer.wait("AUTOPILOT_VERSION", timeout_s=3.0, since_s=t0)
    x, y, z = peer.local_position()
    assert abs(z) < 0.3 and math.hypot(x, y) < 0.3, "bad input moved the vehicle on the ground"
    assert peer.bad_data == 0, "viva-sitl itself sent frames our parser rejects"


def test_nan_setpoints_in_offboard_flight_are_ignored(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    mav = peer.mav
    peer.set_param("MIS_TAKEOFF_ALT", 3.0)
    peer.wait_armable()
    assert peer.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, [1.0]).result == 0
    assert peer.command_long(mavlink2.MAV_CMD_NAV_TAKEOFF, [NAN] * 7).result == 0
    peer.wait("LOCAL_POSITION_NED", lambda m: m.z < -2.7 and abs(m.vz) < 0.2, 60.0, what="hover at 3 m")

    hold = mav.set_position_target_local_ned_encode(
        0, 1, 1, 1, POSITION_ONLY_MASK, 0, 0, -3, 0, 0, 0, 0, 0, 0, 0, 0
    )
    streamer = SetpointStreamer(peer, hold)
    try:
        streamer.wait_sent(20)  # PX4 wants the stream flowing for about 1 s before OFFBOARD
        ack = peer.command_long(mavlink2.MAV_CMD_DO_SET_MODE, [129.0, 6.0, 0.0])
        assert ack.result == mavlink2.MAV_RESULT_ACCEPTED, (
            f"OFFBOARD with a setpoint stream: MAV_RESULT {ack.result}"
        )
        peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1 and m.custom_mode == MODE_OFFBOARD, 3.0)
        abuse_start = time.monotonic()
        for _ in range(40):  # 2 s of poison between the good setpoints
            peer.send(
                mav.set_position_target_local_ned_encode(
                    0, 1, 1, 1, POSITION_ONLY_MASK, NAN, 0, -50, 0, 0, 0, 0, 0, 0, NAN, 0
                )
            )
            peer.send(
                mav.set_position_target_local_ned_encode(
                    0, 1, 1, 1, 0, INF, -INF, INF, NAN, NAN, NAN, INF, INF, INF, INF, INF
                )
            )
            peer.send(
                mav.set_attitude_target_encode(0, 1, 1, ATTITUDE_MASK, [NAN, NAN, NAN, NAN], 0, 0, 0, INF)
            )
            time.sleep(0.05)  # the abuse's own pace (20 Hz, like the stream it poisons), not a wait
        # what the last poison did shows within a second of sim time (time_boot_ms)
        last_ms = peer.wait("LOCAL_POSITION_NED", timeout_s=3.0).time_boot_ms
        peer.wait(
            "LOCAL_POSITION_NED", lambda m: m.time_boot_ms >= last_ms + 1000, 5.0, what="1 s after the abuse"
        )
        poisoned = peer.messages("LOCAL_POSITION_NED", since_s=abuse_start)
        assert poisoned, "no telemetry during the abuse"
        for m in poisoned:
            assert finite(m.x, m.y, m.z, m.vx, m.vy, m.vz), f"non-finite state {m}"
            assert math.hypot(m.x, m.y) < 1.0 and abs(m.z + 3.0) < 1.0, f"drifted off the hold point: {m}"
        hb = peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 3.0)
        assert hb.custom_mode == MODE_OFFBOARD and is_armed(hb), (
            "NaN setpoints knocked the vehicle out of OFFBOARD"
        )
    finally:
        streamer.stop()
    assert peer.command_long(mavlink2.MAV_CMD_NAV_LAND, [NAN] * 7).result == 0
    peer.wait(
        "EXTENDED_SYS_STATE",
        lambda m: m.landed_state == 1,
        60.0,
        since_s=time.monotonic() + 1.0,
        what="touchdown",
    )
    assert_alive_and_finite(peer)
