"""Pure pieces of viva_sitl.mavlink: datagram codec, PX4 param encoding, config, STATUSTEXT chunks, stream
scheduling, mission frame conversion, camera stream URIs."""

from __future__ import annotations

import math
import struct

import pytest
from pymavlink.dialects.v20 import common as M

from viva_sitl.autopilot import MissionCommand, ParamType
from viva_sitl.config import SimConfig
from viva_sitl.geo import GeoOrigin
from viva_sitl.mavlink import MavlinkConfig, StreamProfile, VideoStreamSpec
from viva_sitl.mavlink.base import statustext_messages
from viva_sitl.mavlink.codec import DatagramParser, Encoder
from viva_sitl.mavlink.mission import ItemError, WireItem, wire_to_item
from viva_sitl.mavlink.params import decode_param_value, encode_param_value
from viva_sitl.mavlink.telemetry import LinkStreams
from viva_sitl.selftest import SelftestVehicle

ENC = Encoder(255, 190)


def _ping(seq: int) -> bytes:
    return ENC.pack(M.MAVLink_ping_message(seq, seq, 0, 0))


# --- codec ----------------------------------------------------------------------------------------------------


def test_parser_reads_several_frames_and_v1() -> None:
    p = DatagramParser()
    v1 = bytes(M.MAVLink_ping_message(9, 9, 0, 0).pack(M.MAVLink(None, 3, 4), force_mavlink1=True))
    r = p.parse(_ping(1) + _ping(2) + v1)
    assert [m.seq for m in r.messages] == [1, 2, 9]
    assert (r.bad_frames, r.garbage_bytes, r.unknown) == (0, 0, 0)
    assert r.messages[2].get_srcSystem() == 3


def test_parser_resets_between_datagrams() -> None:
    p = DatagramParser()
    first = _ping(1)
    r = p.parse(first[:8])  # truncated: the parser must not wait for the rest
    assert r.messages == [] and r.bad_frames >= 1
    r = p.parse(_ping(2))
    assert [m.seq for m in r.messages] == [2]


def test_parser_resyncs_after_bad_frames_and_garbage() -> None:
    p = DatagramParser()
    bad = bytearray(_ping(1))
    bad[12] ^= 0x55  # payload byte: CRC fails
    long_header = bytes([0xFD, 200, 0, 0, 0, 1, 1, 4, 0, 0])  # promises 200 bytes that are not there
    r = p.parse(b"junk\x00\x01" + bytes(bad) + long_header + _ping(2) + b"tail")
    assert [m.seq for m in r.messages] == [2]
    assert r.bad_frames >= 2 and r.garbage_bytes >= 6


def test_parser_counts_unknown_ids_and_bounds_work() -> None:
    p = DatagramParser()
    unknown = struct.pack("<BBBBBBBHB", 0xFD, 2, 0, 0, 0, 1, 1, 0xBEEF, 0x0A) + b"\x01\x02\x00\x00"
    r = p.parse(unknown + _ping(3))
    assert r.unknown == 1 and [m.seq for m in r.messages] == [3]
    r = p.parse(b"\xfd" * 65000)  # worst case: a start marker everywhere; bounded, no exception
    assert r.messages == [] and r.bad_frames + r.garbage_bytes > 0


def test_encoder_sequence_numbers_wrap() -> None:
    enc = Encoder(1, 1)
    seqs = [enc.pack(M.MAVLink_ping_message(0, 0, 0, 0))[4] for _ in range(258)]
    assert seqs[:3] == [0, 1, 2] and seqs[256:] == [0, 1]


# --- params ---------------------------------------------------------------------------------------------------


@pytest.mark.parametrize("value", [0, 1, 2, 7, 1000, -1, -100000, 2**31 - 1 - 2**24])
def test_int32_params_travel_bytewise(value: int) -> None:
    wire = encode_param_value(value, ParamType.INT32)
    assert struct.pack("<f", wire) == struct.pack("<i", value)
    assert decode_param_value(wire, ParamType.INT32) == value


def test_real32_params_are_plain_floats() -> None:
    assert encode_param_value(2.5, ParamType.REAL32) == 2.5
    assert decode_param_value(0.7, ParamType.REAL32) == pytest.approx(0.7)


# --- config ---------------------------------------------------------------------------------------------------


def test_config_ports_follow_px4_sitl_instances() -> None:
    c = MavlinkConfig()
    assert (c.system_id, c.api_remote_port_resolved, c.api_local_port_resolved, c.gcs_local_port_resolved, c.gcs_remote_port) == (
        1, 14540, 14580, 18570, 14550)  # fmt: skip
    c = MavlinkConfig(instance=3)
    assert (c.system_id, c.api_remote_port_resolved, c.api_local_port_resolved, c.gcs_local_port_resolved) == (
        4, 14543, 14583, 18573)  # fmt: skip
    c = MavlinkConfig(instance=3, sysid=42, api_remote_port=15000, gcs_profile="onboard")  # type: ignore[arg-type]
    assert (
        c.system_id == 42 and c.api_remote_port_resolved == 15000 and c.gcs_profile == StreamProfile.ONBOARD
    )


@pytest.mark.parametrize(
    "kwargs",
    [
        {"sysid": 0},
        {"sysid": 300},
        {"api_local_port": 70000},
        {"heartbeat_hz": 0.0},
        {"heartbeat_hz": math.nan},
        {"rate_overrides": (("NOT_A_MESSAGE", 5.0),)},
        {"rate_overrides": (("ATTITUDE", -1.0),)},
        {"mission_max_items": 0},
        {"listen_host": ""},
    ],
)
def test_config_rejects_bad_values(kwargs: dict[str, object]) -> None:
    with pytest.raises(ValueError):
        MavlinkConfig(**kwargs)  # type: ignore[arg-type]


# --- statustext, streams, camera uri ----------------------------------------------------------------------------


def test_statustext_chunks_long_texts() -> None:
    (one,) = statustext_messages(4, "short", 7)
    assert one.text == "short" and one.id == 0
    text = "x" * 120
    parts = statustext_messages(4, text, 7)
    assert len(parts) == 3 and {p.id for p in parts} == {7} and [p.chunk_seq for p in parts] == [0, 1, 2]
    assert "".join(p.text for p in parts) == text


def test_link_streams_schedule_and_intervals() -> None:
    s = LinkStreams(StreamProfile.ONBOARD, {M.MAVLINK_MSG_ID_ATTITUDE: 10.0}, {30, 31, 32, 33, 245})
    sent = {30: 0, 31: 0}
    for i in range(1001):  # 1 s at 1 ms steps
        for msgid in s.due(i / 1000.0):
            if msgid in sent:
                sent[msgid] += 1
    assert sent[30] in (10, 11) and sent[31] in (50, 51)  # override 10 Hz; ATTITUDE_QUATERNION 50 Hz
    assert s.set_interval(31, -1, 2.0) and s.interval_us(31) == -1
    assert s.set_interval(31, 0, 2.0) and s.interval_us(31) == 20_000
    assert s.set_interval(245, 250_000, 2.0) and s.interval_us(245) == 250_000  # EXTENDED_SYS_STATE
    assert not s.set_interval(9999, 1000, 2.0) and s.interval_us(9999) == 0


def test_video_stream_uri_for_qgc() -> None:
    assert VideoStreamSpec("udp://127.0.0.1:5600").wire_uri == "5600"
    assert VideoStreamSpec("5602").wire_uri == "5602"
    rtsp = VideoStreamSpec("rtsp://10.0.0.1:8554/live")
    assert rtsp.wire_uri == "rtsp://10.0.0.1:8554/live" and rtsp.stream_type == M.VIDEO_STREAM_TYPE_RTSP


# --- mission frames -----------------------------------------------------------------------------------------------


def _wire(frame: int, command: int, x: int, y: int, z: float) -> WireItem:
    return WireItem(0, frame, command, 0, 1, 0.0, 2.0, 0.0, math.nan, x, y, z)


def test_mission_frames_convert_to_ned() -> None:
    v = SelftestVehicle(SimConfig(home=GeoOrigin(lat_deg=37.38, lon_deg=126.65, alt_amsl_m=10.0)))
    v.step_once()
    lat, lon, _ = v.geo.ned_to_global(40.0, -25.0, 0.0)
    x, y = round(lat * 1e7), round(lon * 1e7)
    wp = MissionCommand.NAV_WAYPOINT
    amsl = wire_to_item(_wire(M.MAV_FRAME_GLOBAL_INT, wp, x, y, 30.0), v)
    assert (amsl.north_m, amsl.east_m, amsl.down_m) == pytest.approx((40.0, -25.0, -20.0), abs=0.02)
    rel = wire_to_item(_wire(M.MAV_FRAME_GLOBAL_RELATIVE_ALT, wp, x, y, 30.0), v)
    assert rel.down_m == pytest.approx(-30.0)
    rel6 = wire_to_item(_wire(M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, wp, x, y, 12.5), v)
    assert rel6.down_m == pytest.approx(-12.5) and rel6.param2 == 2.0 and math.isnan(rel6.param4)
    local = wire_to_item(_wire(M.MAV_FRAME_LOCAL_NED, wp, 30_000, -20_000, -4.0), v)  # x, y in m * 1e4
    assert (local.north_m, local.east_m, local.down_m) == (3.0, -2.0, -4.0)
    enu = wire_to_item(_wire(M.MAV_FRAME_LOCAL_ENU, wp, 30_000, -20_000, 4.0), v)
    assert (enu.north_m, enu.east_m, enu.down_m) == (-2.0, 3.0, -4.0)
    takeoff = wire_to_item(_wire(M.MAV_FRAME_GLOBAL_RELATIVE_ALT, MissionCommand.NAV_TAKEOFF, 0, 0, 5.0), v)
    assert math.isnan(takeoff.north_m) and takeoff.down_m == pytest.approx(-5.0)
    speed = wire_to_item(_wire(M.MAV_FRAME_MISSION, MissionCommand.DO_CHANGE_SPEED, 0, 0, 0.0), v)
    assert speed.command == MissionCommand.DO_CHANGE_SPEED and math.isnan(speed.north_m)
    with pytest.raises(ItemError) as err:
        wire_to_item(_wire(M.MAV_FRAME_BODY_FRD, wp, 0, 0, 1.0), v)
    assert err.value.result == M.MAV_MISSION_UNSUPPORTED_FRAME
    assert rel6.alt_rel_home_m == 12.5 and math.isnan(amsl.alt_rel_home_m)  # resolved when the item starts
    jump = wire_to_item(_wire(M.MAV_FRAME_MISSION, 177, 0, 0, 0.0), v)
    assert jump.command == MissionCommand.DO_JUMP and jump.param2 == 2.0
    vtol = wire_to_item(_wire(M.MAV_FRAME_MISSION, M.MAV_CMD_DO_VTOL_TRANSITION, 0, 0, 0.0), v)
    assert (
        vtol.command == MissionCommand.OTHER and vtol.raw_command == M.MAV_CMD_DO_VTOL_TRANSITION
    )  # skipped
    with pytest.raises(ItemError) as err:
        wire_to_item(_wire(M.MAV_FRAME_GLOBAL, 31999, 0, 0, 1.0), v)  # not a MAV_CMD
    assert err.value.result == M.MAV_MISSION_UNSUPPORTED
    with pytest.raises(ItemError) as err:
        wire_to_item(
            _wire(M.MAV_FRAME_GLOBAL, M.MAV_CMD_NAV_LOITER_TURNS, 0, 0, 1.0), v
        )  # a NAV we cannot fly
    assert err.value.result == M.MAV_MISSION_UNSUPPORTED
    with pytest.raises(ItemError) as err:
        wire_to_item(_wire(M.MAV_FRAME_GLOBAL_INT, wp, 95 * 10**7, 0, 1.0), v)
    assert err.value.result == M.MAV_MISSION_INVALID_PARAM5_X


# --- endpoint start errors ----------------------------------------------------------------------------------------


def test_endpoint_start_errors_are_clear() -> None:
    import asyncio
    import socket

    from viva_sitl.mavlink import MavlinkEndpoint
    from viva_sitl.mavlink.config import PortInUseError

    vehicle = SelftestVehicle()
    bad_host = MavlinkConfig(
        api_remote_host="no-such-host.invalid", api_local_port=0, gcs_local_port=0, gcs_remote_port=0
    )
    with pytest.raises(ValueError, match="cannot resolve the api remote host"):
        asyncio.run(MavlinkEndpoint(vehicle, bad_host).start())
    taken = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    taken.bind(("127.0.0.1", 0))
    try:
        busy = MavlinkConfig(
            api_local_port=taken.getsockname()[1], gcs_local_port=0, api_remote_port=0, gcs_remote_port=0
        )
        port = taken.getsockname()[1]
        with pytest.raises(
            PortInUseError, match=rf"UDP port {port} \(api link\).*already in use.*--instance N"
        ):
            asyncio.run(MavlinkEndpoint(vehicle, busy).start())
    finally:
        taken.close()
