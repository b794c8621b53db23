"""Protocol tests on the in-memory, sim-clock harness (viva_sitl.mavlink.testing): the real MavlinkEndpoint (links,
dispatch, schedule, concern modules) and the real Autopilot + EAV dynamics, with no socket, thread or sleep.

Ports of socket tests in test_mavlink_protocol.py, test_mavlink_mission.py, test_mavlink_logs.py and
test_mavlink_io.py (which stay, marked slow; the other socket tests there check the UDP transport in the fast tier):
the same exchanges, with timeouts in simulated seconds, so rates and retries are exact counts. Other protocol tests
run one body over both (conftest's `rig_factory`)."""

from __future__ import annotations

import hashlib
import math
import struct
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as M

from viva_sitl.autopilot import FlightMode, ParamStore
from viva_sitl.geo import GeoOrigin
from viva_sitl.mavlink import MavlinkConfig
from viva_sitl.mavlink.base import LinkKind
from viva_sitl.mavlink.testing import SimClient, SimHarness
from viva_sitl.selftest import SelftestVehicle

NAN = math.nan
GEO = GeoOrigin()


def _harness(**config: object) -> SimHarness:
    sv = SelftestVehicle()
    return SimHarness(sv, lambda: sv.vehicle.step(1), MavlinkConfig(**config))  # type: ignore[arg-type]


@pytest.fixture
def harness() -> Iterator[SimHarness]:
    h = _harness()
    yield h
    h.vehicle.vehicle.close()  # type: ignore[attr-defined]


@pytest.fixture
def client(harness: SimHarness) -> SimClient:
    return harness.client()


def _autopilot_hb(m: M.MAVLink_message) -> bool:
    return m.get_type() == "HEARTBEAT" and m.get_srcComponent() == 1


def _int_as_float(v: int) -> float:
    return float(struct.unpack("<f", struct.pack("<i", v))[0])


def _float_as_int(f: float) -> int:
    return int(struct.unpack("<i", struct.pack("<f", f))[0])


def _count(client: SimClient, msg_type: str, sim_s: float) -> int:
    return sum(1 for m in client.poll(sim_s) if m.get_type() == msg_type)


# --- the harness itself -------------------------------------------------------------------------------------------


def test_time_moves_only_when_stepped(harness: SimHarness, client: SimClient) -> None:
    assert harness.time_s == 0.0
    hb = client.wait_for(_autopilot_hb, 1.0)
    assert hb is not None and hb.type == M.MAV_TYPE_QUADROTOR
    t = harness.time_s
    assert t < 0.05  # the first heartbeat goes out on the first step
    client.send(client.mav.ping_encode(1, 2, 0, 0))  # answered at once, at the same simulation time
    assert client.wait_for("PING", 0.0) is not None and harness.time_s == t
    harness.advance(0.5)
    assert harness.time_s == pytest.approx(t + 0.5, abs=0.005)
    assert harness.undelivered == 0  # nothing went to an address without a client


def test_gcs_peer_gets_telemetry_once_it_talks(harness: SimHarness, client: SimClient) -> None:
    gcs = harness.client(LinkKind.GCS, sysid=254)
    assert _count(gcs, "ATTITUDE", 0.5) == 0  # no GCS remote configured: nobody listens on that link yet
    gcs.send(gcs.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0))
    assert _count(gcs, "HEARTBEAT", 2.0) == 2  # 1 Hz on sim time
    assert [p[0] for p in harness.endpoint.peers_heard()] == ["gcs"]


def test_charged_timing_holds_then_releases_on_sim_time(harness: SimHarness, client: SimClient) -> None:
    ep = harness.endpoint
    ep.hold_incoming(True)
    client.send(client.mav.ping_encode(5, 1, 0, 0))
    assert client.wait_for("PING", 0.1) is None  # held, not handled
    due = harness.time_s + 0.2
    assert ep.stamp_held(due) == 1
    ep.release_due(harness.time_s)
    assert client.wait_for("PING", 0.0) is None  # not due yet
    harness.advance(0.2)
    ep.release_due(harness.time_s)
    ping = client.wait_for("PING", 0.0)
    assert ping is not None and ping.seq == 1
    ep.hold_incoming(False)


# --- ports of test_mavlink_protocol.py ------------------------------------------------------------------------


def test_every_command_is_acked(harness: SimHarness, client: SimClient) -> None:
    ap = harness.vehicle.autopilot

    def ack(cmd: int, *p: float, **kw: int) -> int:
        a = client.command(cmd, *p, timeout_s=0.5, **kw)
        assert a is not None, f"no COMMAND_ACK for command {cmd} within 0.5 sim s"
        return int(a.result)

    assert ack(M.MAV_CMD_NAV_TAKEOFF, *[NAN] * 7) == M.MAV_RESULT_DENIED  # not armed
    assert any(m.get_type() == "STATUSTEXT" and "not armed" in m.text for _, m in client.received)
    assert ack(M.MAV_CMD_MISSION_START, 0, 0) == M.MAV_RESULT_DENIED  # no mission
    assert ack(M.MAV_CMD_DO_SET_MODE, 1, 6, 0) == M.MAV_RESULT_TEMPORARILY_REJECTED  # offboard w/o setpoints
    assert ack(M.MAV_CMD_DO_REPOSITION, -1, 1, 0, NAN, NAN, NAN, NAN) == M.MAV_RESULT_DENIED  # not armed
    assert ack(M.MAV_CMD_DO_CHANGE_SPEED, 1, 3.0, -1) == M.MAV_RESULT_ACCEPTED
    assert ack(M.MAV_CMD_DO_CHANGE_SPEED, 1, -2.0, -1) == M.MAV_RESULT_ACCEPTED  # back to default
    assert ack(M.MAV_CMD_DO_CHANGE_SPEED, 1, 0.0, -1) == M.MAV_RESULT_DENIED
    assert ack(M.MAV_CMD_DO_SET_MODE, 129, 4, 3) == M.MAV_RESULT_ACCEPTED  # Hold, base_mode 129 is not "arm"
    assert not ap.armed
    assert ack(M.MAV_CMD_DO_SET_MODE, 1, 99, 0) == M.MAV_RESULT_DENIED  # unknown mode
    assert ack(31999, 1, 2, 3) == M.MAV_RESULT_UNSUPPORTED
    assert ack(M.MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, 1) == M.MAV_RESULT_UNSUPPORTED
    assert ack(M.MAV_CMD_COMPONENT_ARM_DISARM, 1, NAN) == M.MAV_RESULT_ACCEPTED  # MAVSDK: param2 NaN
    assert harness.vehicle.autopilot.armed
    assert ack(M.MAV_CMD_NAV_RETURN_TO_LAUNCH) == M.MAV_RESULT_ACCEPTED
    assert ack(M.MAV_CMD_NAV_LAND, *[NAN] * 7) == M.MAV_RESULT_ACCEPTED
    assert ack(M.MAV_CMD_COMPONENT_ARM_DISARM, 0, 21196) == M.MAV_RESULT_ACCEPTED  # kill
    assert not harness.vehicle.autopilot.armed
    # COMMAND_INT gets its ACK too
    client.send(
        client.mav.command_int_encode(
            1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 31998, 0, 0, 0, 0, 0, 0, 0, 0, 0
        )
    )
    a = client.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == 31998, 0.5)
    assert a is not None and a.result == M.MAV_RESULT_UNSUPPORTED
    # SET_MODE message: answered like DO_SET_MODE, and the heartbeat shows the mode at once (housekeeping)
    client.send(client.mav.set_mode_encode(1, 1, FlightMode.AUTO_RTL.custom_mode))
    a = client.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_DO_SET_MODE, 0.5)
    assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
    hb = client.wait_for(lambda m: _autopilot_hb(m) and m.custom_mode == FlightMode.AUTO_RTL.custom_mode, 0.1)
    assert hb is not None, "the mode change waited for the next 1 Hz heartbeat"
    # a command for another system or component is not ours: silence
    ignored = harness.endpoint.stats["ignored_messages"]
    assert client.command(M.MAV_CMD_NAV_LAND, target_system=7, timeout_s=0.4) is None
    assert client.command(M.MAV_CMD_NAV_LAND, target_component=55, timeout_s=0.4) is None
    assert harness.endpoint.stats["ignored_messages"] == ignored + 2
    assert harness.endpoint.stats["handler_errors"] == 0


def test_param_set_float_and_int32_bytewise(harness: SimHarness, client: SimClient) -> None:
    params = harness.vehicle.autopilot.params
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 5.5, M.MAV_PARAM_TYPE_REAL32))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT", 0.0)
    assert pv is not None and pv.param_value == pytest.approx(5.5)  # answered before any step
    assert params.get("MIS_TAKEOFF_ALT") == pytest.approx(5.5)

    # INT32: the integer's bytes travel in the float field (PX4 bytewise encoding)
    client.send(client.mav.param_set_encode(1, 1, b"NAV_DLL_ACT", _int_as_float(2), M.MAV_PARAM_TYPE_INT32))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "NAV_DLL_ACT", 0.0)
    assert pv is not None and pv.param_type == M.MAV_PARAM_TYPE_INT32
    assert _float_as_int(pv.param_value) == 2
    assert params.get("NAV_DLL_ACT") == 2

    # read back by name and by index
    client.send(client.mav.param_request_read_encode(1, 1, b"NAV_DLL_ACT", -1))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "NAV_DLL_ACT", 0.0)
    assert pv is not None and _float_as_int(pv.param_value) == 2
    idx = ParamStore().names().index("MIS_TAKEOFF_ALT")
    client.send(client.mav.param_request_read_encode(1, 1, b"", idx))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_index == idx, 0.0)
    assert pv is not None and pv.param_id == "MIS_TAKEOFF_ALT" and pv.param_value == pytest.approx(5.5)

    # the changed values are re-announced once by the parameter task (PX4's send_untransmitted)
    client.drain()
    n = len(client.received)
    harness.pump_params()
    again = sorted(m.param_id for _, m in client.received[n:] if m.get_type() == "PARAM_VALUE")
    assert again == ["MIS_TAKEOFF_ALT", "NAV_DLL_ACT"]


def test_param_rejections_as_px4(harness: SimHarness, client: SimClient) -> None:
    params = harness.vehicle.autopilot.params

    def values() -> list[M.MAVLink_message]:
        return [m for _, m in client.received if m.get_type() == "PARAM_VALUE"]

    # unknown name: no PARAM_VALUE, a STATUSTEXT (PX4: "[pm] unknown param")
    client.send(client.mav.param_set_encode(1, 1, b"NO_SUCH_PARAM", 1.0, M.MAV_PARAM_TYPE_REAL32))
    text = client.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "unknown param" in m.text, 0.0)
    assert text is not None and "NO_SUCH_PARAM" in text.text
    assert values() == []
    client.send(client.mav.param_request_read_encode(1, 1, b"NO_SUCH_PARAM", -1))
    assert client.wait_for("PARAM_VALUE", 0.5) is None

    # type mismatch: REAL32 write to an INT32 parameter changes nothing
    client.send(client.mav.param_set_encode(1, 1, b"NAV_DLL_ACT", 3.0, M.MAV_PARAM_TYPE_REAL32))
    assert client.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "mismatch" in m.text, 0.0) is not None
    assert params.get("NAV_DLL_ACT") == 0

    # out of range: stored and echoed as PX4 does (PX4 does not enforce min/max; the GCS warns)
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 1e6, M.MAV_PARAM_TYPE_REAL32))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT", 0.0)
    assert pv is not None and pv.param_value == pytest.approx(1e6)
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", 2.5, M.MAV_PARAM_TYPE_REAL32))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT", 0.0)
    assert pv is not None and pv.param_value == pytest.approx(2.5)

    # index beyond the list: no PARAM_VALUE, a STATUSTEXT
    n = len(values())
    client.send(client.mav.param_request_read_encode(1, 1, b"", len(ParamStore())))
    assert client.wait_for(lambda m: m.get_type() == "STATUSTEXT" and "unknown param" in m.text, 0.0)
    assert len(values()) == n

    # NaN value: refused, the stored value is echoed
    client.send(client.mav.param_set_encode(1, 1, b"MIS_TAKEOFF_ALT", NAN, M.MAV_PARAM_TYPE_REAL32))
    pv = client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "MIS_TAKEOFF_ALT", 0.0)
    assert pv is not None and pv.param_value == pytest.approx(2.5)
    assert harness.endpoint.stats["handler_errors"] == 0


def test_default_rates_and_set_message_interval(harness: SimHarness, client: SimClient) -> None:
    # on the sim clock the rates are exact counts, not wall-clock estimates (the socket test allows +-30 %)
    harness.advance(0.3)
    assert _count(client, "ATTITUDE", 1.0) == 100
    ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 100_000)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    # the new interval starts at once (one right after the ACK), then one each 0.1 s: 21 in [t, t + 2 s]
    assert _count(client, "ATTITUDE_QUATERNION", 2.0) == 21
    ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, -1)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    assert _count(client, "ATTITUDE_QUATERNION", 1.0) == 0
    ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE_QUATERNION, 0)  # default
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    assert _count(client, "ATTITUDE_QUATERNION", 1.0) == 50
    # a message it cannot produce
    ack = client.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_HIL_SENSOR, 100_000)
    assert ack is not None and ack.result == M.MAV_RESULT_UNSUPPORTED
    # GET via REQUEST_MESSAGE(MESSAGE_INTERVAL, p2 = message id)
    ack = client.command(
        M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE
    )
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    mi = next((m for _, m in client.received if m.get_type() == "MESSAGE_INTERVAL"), None)
    assert mi is not None and mi.message_id == M.MAVLINK_MSG_ID_ATTITUDE and mi.interval_us == 10_000
    # the interval is per link: the GCS link keeps its own table
    gcs = harness.client(LinkKind.GCS, sysid=254)
    gcs.send(gcs.mav.heartbeat_encode(M.MAV_TYPE_GCS, M.MAV_AUTOPILOT_INVALID, 0, 0, 0))
    ack = gcs.command(M.MAV_CMD_SET_MESSAGE_INTERVAL, M.MAVLINK_MSG_ID_ATTITUDE, 500_000)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    gcs.received.clear()
    client.received.clear()
    harness.advance(1.0)
    assert sum(m.get_type() == "ATTITUDE" for _, m in gcs.received) == 2
    assert sum(m.get_type() == "ATTITUDE" for _, m in client.received) == 100


def test_ping_and_timesync_answered(harness: SimHarness, client: SimClient) -> None:
    client.send(client.mav.ping_encode(123456789, 42, 0, 0))
    ping = client.wait_for("PING", 0.0)
    assert ping is not None
    assert (ping.time_usec, ping.seq, ping.target_system, ping.target_component) == (123456789, 42, 255, 190)
    harness.advance(0.25)
    client.send(client.mav.timesync_encode(0, 987654321))
    ts = client.wait_for(lambda m: m.get_type() == "TIMESYNC" and m.ts1 == 987654321, 0.0)
    assert ts is not None and ts.tc1 == int(harness.time_s * 1e9)  # our clock: sim time since boot
    # a PING addressed to us is a reply to a ping we never sent: no answer
    client.send(client.mav.ping_encode(1, 43, 1, 1))
    assert client.wait_for("PING", 0.5) is None


# --- ports of test_mavlink_mission.py ---------------------------------------------------------------------------


def _latlon_e7(north: float, east: float) -> tuple[int, int]:
    lat, lon, _ = GEO.ned_to_global(north, east, 0.0)
    return round(lat * 1e7), round(lon * 1e7)


Item = tuple[int, int, float, float, float, float, int, int, float]


def _items() -> list[Item]:
    """(frame, command, p1, p2, p3, p4, x, y, z) of a small mission with frames 3 and 6."""
    wx, wy = _latlon_e7(12.0, 5.0)
    lx, ly = _latlon_e7(12.0, -3.0)
    return [
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, 4.0),
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, 0, 1.0, 0, NAN, wx, wy, 5.0),
        (M.MAV_FRAME_MISSION, M.MAV_CMD_DO_CHANGE_SPEED, 1, 3.0, -1, 0, 0, 0, 0.0),
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT, M.MAV_CMD_NAV_LOITER_TIME, 1.0, 0, 0, NAN, lx, ly, 5.0),
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, lx, ly, 0.0),
    ]


def _upload(client: SimClient, items: list[Item]) -> int:
    """Answer the vehicle's MISSION_REQUEST_INTs; return the MISSION_ACK type."""
    client.send(client.mav.mission_count_encode(1, 1, len(items), M.MAV_MISSION_TYPE_MISSION))
    while True:
        msg = client.wait_for(
            lambda m: m.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"), 0.0
        )
        assert msg is not None, "the vehicle did not answer at once"
        if msg.get_type() == "MISSION_ACK":
            return int(msg.type)
        assert msg.get_type() == "MISSION_REQUEST_INT"
        assert msg.target_system == 255 and msg.target_component == 190
        frame, cmd, p1, p2, p3, p4, x, y, z = items[msg.seq]
        client.send(
            client.mav.mission_item_int_encode(1, 1, msg.seq, frame, cmd, 0, 1, p1, p2, p3, p4, x, y, z, 0)
        )


def _download(client: SimClient) -> list[M.MAVLink_message]:
    client.send(client.mav.mission_request_list_encode(1, 1, M.MAV_MISSION_TYPE_MISSION))
    count = client.wait_for("MISSION_COUNT", 0.0)
    assert count is not None
    out = []
    for seq in range(count.count):
        client.send(client.mav.mission_request_int_encode(1, 1, seq, M.MAV_MISSION_TYPE_MISSION))
        item = client.wait_for(lambda m, s=seq: m.get_type() == "MISSION_ITEM_INT" and m.seq == s, 0.0)
        assert item is not None, f"no MISSION_ITEM_INT {seq}"
        out.append(item)
    client.send(client.mav.mission_ack_encode(1, 1, M.MAV_MISSION_ACCEPTED, M.MAV_MISSION_TYPE_MISSION))
    return out


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b)


def test_mission_upload_download_clear_round_trip(harness: SimHarness, client: SimClient) -> None:
    ap = harness.vehicle.autopilot
    items = _items()
    assert _upload(client, items) == M.MAV_MISSION_ACCEPTED
    assert len(ap.mission_items) == 5
    # frame 6 waypoint 12 m north, 5 m east, 5 m above home -> NED (12, 5, -5)
    wp = ap.mission_items[1]
    assert (wp.north_m, wp.east_m, wp.down_m) == pytest.approx((12.0, 5.0, -5.0), abs=0.01)
    assert wp.param2 == pytest.approx(1.0)  # acceptance radius
    assert math.isnan(ap.mission_items[0].north_m)  # TAKEOFF without coordinates: where the vehicle is
    assert ap.mission_items[0].down_m == pytest.approx(-4.0)
    # MISSION_CURRENT on change: within one housekeeping period (20 Hz), not the 1 Hz stream
    cur = client.wait_for(lambda m: m.get_type() == "MISSION_CURRENT" and m.total == 5, 0.06)
    assert cur is not None and cur.seq == 0

    got = _download(client)
    assert len(got) == len(items)
    for item, (frame, cmd, p1, p2, _p3, p4, x, y, z) in zip(got, items, strict=True):
        assert (item.frame, item.command, item.x, item.y) == (frame, cmd, x, y)
        assert (
            _same(item.z, z) and _same(item.param1, p1) and _same(item.param2, p2) and _same(item.param4, p4)
        )
        assert item.target_system == 255

    # float MISSION_REQUEST (legacy) is answered with MISSION_ITEM in degrees
    client.send(client.mav.mission_request_encode(1, 1, 1, M.MAV_MISSION_TYPE_MISSION))
    legacy = client.wait_for("MISSION_ITEM", 0.0)
    assert legacy is not None and legacy.x == pytest.approx(items[1][6] * 1e-7, abs=1e-6)

    client.send(client.mav.mission_clear_all_encode(1, 1, M.MAV_MISSION_TYPE_MISSION))
    ack = client.wait_for("MISSION_ACK", 0.0)
    assert ack is not None and ack.type == M.MAV_MISSION_ACCEPTED
    assert _download(client) == []
    assert len(ap.mission_items) == 0
    assert harness.endpoint.stats["mission_uploads_completed"] == 1


def test_mission_upload_timeout_retries_then_cancels() -> None:
    h = _harness(mission_retry_s=0.15, mission_max_retries=2)
    try:
        client = h.client()
        client.send(client.mav.mission_count_encode(1, 1, 4, 0))
        client.poll(1.2)
        requests = [(t, m) for t, m in client.received if m.get_type() == "MISSION_REQUEST_INT"]
        assert [m.seq for _, m in requests] == [0, 0, 0]  # first request + 2 retries
        # the retries are 0.15 SIMULATED seconds apart (to one housekeeping period)
        gaps = [b[0] - a[0] for a, b in zip(requests, requests[1:], strict=False)]
        assert gaps == [pytest.approx(0.15, abs=0.051)] * 2
        acks = [m for _, m in client.received if m.get_type() == "MISSION_ACK"]
        assert len(acks) == 1 and acks[0].type == M.MAV_MISSION_OPERATION_CANCELLED
        assert any(m.get_type() == "HEARTBEAT" for _, m in client.received)
        assert h.endpoint.mission.upload is None
        assert h.endpoint.stats["mission_uploads_failed"] == 1
    finally:
        h.vehicle.vehicle.close()  # type: ignore[attr-defined]


# --- ports of test_mavlink_logs.py ----------------------------------------------------------------------------


def _ask(
    client: SimClient, request: M.MAVLink_message, kind: str, sim_s: float = 0.5
) -> list[M.MAVLink_message]:
    """Send `request`; the messages of `kind` answered within `sim_s` simulated seconds (at once, or streamed; the
    UDP test waits for 0.5 wall s of quiet)."""
    n = len(client.received)
    client.send(request)
    client.poll(sim_s)
    return [m for _, m in client.received[n:] if m.get_type() == kind]


def _log_download(client: SimClient, log_id: int, size: int) -> bytes:
    data = bytearray()
    for msg in _ask(client, client.mav.log_request_data_encode(1, 1, log_id, 0, size), "LOG_DATA"):
        assert msg.id == log_id and msg.ofs == len(data), (msg.ofs, len(data))
        data += bytes(msg.data[: msg.count])
    return bytes(data)


def test_list_and_download_logs_and_the_bad_requests_px4_ignores(
    harness: SimHarness, client: SimClient, tmp_path: Path
) -> None:
    old = tmp_path / "old.ulg"
    old.write_bytes(bytes(range(256)) * 3 + b"tail")  # 772 bytes: 8 full LOG_DATA and a short one
    cur = tmp_path / "log.ulg"
    cur.write_bytes(b"ULog" * 50)
    files = [(old, False), (cur, True)]
    harness.endpoint.logs.set_source(lambda: list(files))

    # before any list: PX4 does not answer
    assert _ask(client, client.mav.log_request_data_encode(1, 1, 0, 0, 100), "LOG_DATA") == []

    entries = _ask(client, client.mav.log_request_list_encode(1, 1, 0, 0xFFFF), "LOG_ENTRY")
    assert [(e.id, e.num_logs, e.last_log_num, e.size) for e in entries] == [(0, 2, 1, 772), (1, 2, 1, 200)]
    assert abs(entries[0].time_utc - old.stat().st_mtime) <= 1

    assert _log_download(client, 0, 772) == old.read_bytes()
    assert _log_download(client, 1, 0xFFFFFFFF) == cur.read_bytes()

    # a part of a log, from an offset
    parts = _ask(client, client.mav.log_request_data_encode(1, 1, 0, 180, 100), "LOG_DATA")
    assert [(m.ofs, m.count) for m in parts] == [(180, 90), (270, 10)]
    assert bytes(parts[0].data[:90]) + bytes(parts[1].data[:10]) == old.read_bytes()[180:280]

    # past the end: one LOG_DATA with count 0 at the offset (PX4)
    assert [
        (m.id, m.ofs, m.count)
        for m in _ask(client, client.mav.log_request_data_encode(1, 1, 0, 5000, 90), "LOG_DATA")
    ] == [(0, 5000, 0)]

    # unknown id: no answer (PX4)
    assert _ask(client, client.mav.log_request_data_encode(1, 1, 7, 0, 90), "LOG_DATA") == []

    # the log being written grows: a new list shows its new size
    cur.write_bytes(b"ULog" * 60)
    assert [
        e.size for e in _ask(client, client.mav.log_request_list_encode(1, 1, 0, 0xFFFF), "LOG_ENTRY")
    ] == [772, 240]

    # a range of the list
    assert [
        (e.id, e.num_logs, e.last_log_num)
        for e in _ask(client, client.mav.log_request_list_encode(1, 1, 1, 1), "LOG_ENTRY")
    ] == [(1, 2, 1)]

    # LOG_REQUEST_END forgets the list: data requests go unanswered until the next list
    client.send(client.mav.log_request_end_encode(1, 1))
    assert _ask(client, client.mav.log_request_data_encode(1, 1, 0, 0, 90), "LOG_DATA") == []
    assert harness.endpoint.stats["handler_errors"] == 0


# --- ports of test_mavlink_io.py ------------------------------------------------------------------------------

KEY_HEX = "00112233445566778899aabbccddeeff00112233445566778899aabbccddeeff"


def _sign(client: SimClient, key: bytes) -> None:
    """Make the client a signing MAVLink 2 peer (pymavlink's own signing)."""
    client.mav.signing.secret_key = key
    client.mav.signing.sign_outgoing = True
    client.mav.signing.link_id = 1
    client.mav.signing.timestamp = int((time.time() - 1420070400) * 100_000)


def test_signing_accepts_signed_client_rejects_unsigned() -> None:
    key = bytes.fromhex(KEY_HEX)
    h = _harness(signing_key=KEY_HEX)
    try:
        signed = h.client()  # the API link's remote
        unsigned = h.client(addr=("127.0.0.1", 40001))
        _sign(signed, key)
        # a signed client is served...
        signed.send(signed.mav.param_request_read_encode(1, 1, b"COM_DL_LOSS_T", -1))
        assert signed.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "COM_DL_LOSS_T", 2.0)
        ack = signed.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION)
        assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
        # ...and what the vehicle sends is signed with the key (the checker's parser verifies it)
        checker = M.MAVLink(None)
        checker.signing.secret_key = key
        hb = signed.wait_for("HEARTBEAT", 3.0)
        assert hb is not None
        frame = bytes(hb.get_msgbuf())
        assert frame[2] & M.MAVLINK_IFLAG_SIGNED
        assert checker.parse_char(frame).get_type() == "HEARTBEAT"  # raises on a bad signature
        before = h.endpoint.stats["unsigned_rejected"]
        # an unsigned client is not: no answer, counted
        assert (
            unsigned.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, timeout_s=1.5)
            is None
        )
        unsigned.send(unsigned.mav.param_request_read_encode(1, 1, b"COM_DL_LOSS_T", -1))
        # a client signing with another key neither
        wrong = h.client(addr=("127.0.0.1", 40002))
        _sign(wrong, hashlib.sha256(b"not the key").digest())
        assert (
            wrong.command(M.MAV_CMD_REQUEST_MESSAGE, M.MAVLINK_MSG_ID_AUTOPILOT_VERSION, timeout_s=1.5)
            is None
        )
        # RADIO_STATUS is one of the messages PX4 accepts unsigned
        unsigned.send(unsigned.mav.radio_status_encode(200, 190, 100, 90, 80, 0, 0))
        signed.poll(0.3)
        stats = h.endpoint.stats
        assert stats["unsigned_rejected"] - before == 3
        assert stats["commands"] == 1  # only the signed client's command reached a handler
        assert stats["signing"] == {"key_set": True, "sign_cfg": 1}
        assert not any(m.get_type() == "COMMAND_ACK" for _, m in unsigned.received)
    finally:
        h.vehicle.vehicle.close()  # type: ignore[attr-defined]
