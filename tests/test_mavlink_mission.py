"""Mission protocol over real UDP: upload / download / clear round trips (frames 3 and 6), MISSION_CURRENT, flying a
mission with MISSION_ITEM_REACHED, and the state machine's answers to absurd counts, out-of-order items and silence."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
from mav_client import MavClient, Rig, VehicleThread
from pymavlink.dialects.v20 import common as M

from viva_sitl.geo import GeoOrigin

NAN = math.nan
GEO = GeoOrigin()


@pytest.fixture
def vehicle(vehicle_factory: Callable[..., VehicleThread]) -> VehicleThread:
    return vehicle_factory()


def _latlon_e7(north: float, east: float) -> tuple[int, int]:
    lat, lon, _ = GEO.ned_to_global(north, east, 0.0)
    return round(lat * 1e7), round(lon * 1e7)


def _items() -> list[tuple[int, int, float, float, float, float, int, int, float]]:
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


def _upload(
    client: MavClient, items: list[tuple[int, int, float, float, float, float, int, int, float]]
) -> int:
    """Answer the vehicle's MISSION_REQUEST_INTs; return the MISSION_ACK type."""
    client.send(client.mav.mission_count_encode(1, 1, len(items), M.MAV_MISSION_TYPE_MISSION))
    while True:
        msg = client.wait_for(
            lambda m: m.get_type() in ("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"), 2.0
        )
        assert msg is not None, "vehicle stopped answering during upload"
        if msg.get_type() == "MISSION_ACK":
            return int(msg.type)
        assert msg.get_type() == "MISSION_REQUEST_INT"
        assert msg.target_system == 255 and msg.target_component == 190
        frame, cmd, p1, p2, p3, p4, x, y, z = items[msg.seq]
        client.send(
            client.mav.mission_item_int_encode(1, 1, msg.seq, frame, cmd, 0, 1, p1, p2, p3, p4, x, y, z, 0)
        )


def _download(client: MavClient) -> list[M.MAVLink_message]:
    client.send(client.mav.mission_request_list_encode(1, 1, M.MAV_MISSION_TYPE_MISSION))
    count = client.wait_for("MISSION_COUNT", 1.0)
    assert count is not None
    out = []
    for seq in range(count.count):
        client.send(client.mav.mission_request_int_encode(1, 1, seq, M.MAV_MISSION_TYPE_MISSION))
        item = client.wait_for(lambda m, s=seq: m.get_type() == "MISSION_ITEM_INT" and m.seq == s, 1.0)
        assert item is not None, f"no MISSION_ITEM_INT {seq}"
        out.append(item)
    client.send(client.mav.mission_ack_encode(1, 1, M.MAV_MISSION_ACCEPTED, M.MAV_MISSION_TYPE_MISSION))
    return out


def _same(a: float, b: float) -> bool:
    return (math.isnan(a) and math.isnan(b)) or a == pytest.approx(b)


@pytest.mark.slow  # ported to the sim-clock harness: test_mavlink_harness.py::test_mission_upload_download_clear_round_trip
def test_upload_download_clear_round_trip(client: MavClient, vehicle: VehicleThread) -> None:
    items = _items()
    assert _upload(client, items) == M.MAV_MISSION_ACCEPTED
    ap_items = vehicle.call(lambda: list(vehicle.vehicle.autopilot.mission_items))
    assert len(ap_items) == 5
    # frame 6 waypoint 12 m north, 5 m east, 5 m above home -> NED (12, 5, -5)
    assert (ap_items[1].north_m, ap_items[1].east_m, ap_items[1].down_m) == pytest.approx(
        (12.0, 5.0, -5.0), abs=0.01
    )
    assert ap_items[1].param2 == pytest.approx(1.0)  # acceptance radius
    assert math.isnan(ap_items[0].north_m)  # TAKEOFF without coordinates: where the vehicle is
    assert ap_items[0].down_m == pytest.approx(-4.0)
    cur = client.wait_for(lambda m: m.get_type() == "MISSION_CURRENT" and m.total == 5, 2.0)
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
    legacy = client.wait_for("MISSION_ITEM", 1.0)
    assert legacy is not None and legacy.x == pytest.approx(items[1][6] * 1e-7, abs=1e-6)

    client.send(client.mav.mission_clear_all_encode(1, 1, M.MAV_MISSION_TYPE_MISSION))
    ack = client.wait_for("MISSION_ACK", 1.0)
    assert ack is not None and ack.type == M.MAV_MISSION_ACCEPTED
    assert _download(client) == []
    assert vehicle.call(lambda: len(vehicle.vehicle.autopilot.mission_items)) == 0


def test_fence_and_rally_start_empty(client: MavClient, vehicle: VehicleThread) -> None:
    # (their upload, download and clear are tested in test_mavlink_fence.py)
    for mtype in (M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY):
        client.send(client.mav.mission_request_list_encode(1, 1, mtype))
        count = client.wait_for("MISSION_COUNT", 1.0)
        assert count is not None and count.count == 0 and count.mission_type == mtype


def test_absurd_count_unsupported_item_and_old_mission_kept(
    client: MavClient, vehicle: VehicleThread
) -> None:
    assert _upload(client, _items()[:2]) == M.MAV_MISSION_ACCEPTED
    client.send(client.mav.mission_count_encode(1, 1, 65535, M.MAV_MISSION_TYPE_MISSION))
    ack = client.wait_for("MISSION_ACK", 1.0)
    assert ack is not None and ack.type == M.MAV_MISSION_NO_SPACE
    bad = [_items()[0], (M.MAV_FRAME_MISSION, 31999, 0, 3, 0, 0, 0, 0, 0.0)]  # not a MAV_CMD at all
    assert _upload(client, bad) == M.MAV_MISSION_UNSUPPORTED
    bad_frame = [(M.MAV_FRAME_BODY_FRD, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, NAN, 10, 10, 5.0)]
    assert _upload(client, bad_frame) == M.MAV_MISSION_UNSUPPORTED_FRAME
    nan_alt = [
        (M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, NAN, *_latlon_e7(1, 1), NAN)
    ]
    assert _upload(client, nan_alt) == M.MAV_MISSION_INVALID_PARAM7
    assert vehicle.call(lambda: len(vehicle.vehicle.autopilot.mission_items)) == 2  # untouched


def test_out_of_order_and_duplicate_items(client: MavClient, vehicle: VehicleThread) -> None:
    items = _items()[:3]
    client.send(client.mav.mission_count_encode(1, 1, 3, 0))
    req = client.wait_for("MISSION_REQUEST_INT", 1.0)
    assert req is not None and req.seq == 0
    frame, cmd, p1, p2, p3, p4, x, y, z = items[2]
    client.send(
        client.mav.mission_item_int_encode(1, 1, 2, frame, cmd, 0, 1, p1, p2, p3, p4, x, y, z, 0)
    )  # ahead
    req = client.wait_for("MISSION_REQUEST_INT", 1.0)
    assert req is not None and req.seq == 0, "an item ahead of the expected one re-requests the expected one"
    for seq in range(3):
        frame, cmd, p1, p2, p3, p4, x, y, z = items[seq]
        msg = client.mav.mission_item_int_encode(1, 1, seq, frame, cmd, 0, 1, p1, p2, p3, p4, x, y, z, 0)
        client.send(msg)
        if seq == 1:
            client.send(msg)  # duplicate: ignored
        if seq < 2:
            req = client.wait_for("MISSION_REQUEST_INT", 1.0)
            assert req is not None and req.seq == seq + 1
    ack = client.wait_for("MISSION_ACK", 1.0)
    assert ack is not None and ack.type == M.MAV_MISSION_ACCEPTED


@pytest.mark.slow  # ported to the sim-clock harness: test_mavlink_harness.py::test_mission_upload_timeout_retries_then_cancels
def test_upload_timeout_retries_then_cancels(
    client: MavClient, vehicle_factory: Callable[..., VehicleThread]
) -> None:
    vt = vehicle_factory(mission_retry_s=0.15, mission_max_retries=2)
    try:
        client.send(client.mav.mission_count_encode(1, 1, 4, 0))
        client.poll(1.2)
        requests = [m for _, m in client.received if m.get_type() == "MISSION_REQUEST_INT"]
        assert [r.seq for r in requests] == [0, 0, 0]  # first request + 2 retries
        acks = [m for _, m in client.received if m.get_type() == "MISSION_ACK"]
        assert len(acks) == 1 and acks[0].type == M.MAV_MISSION_OPERATION_CANCELLED
        assert any(m.get_type() == "HEARTBEAT" for _, m in client.received)
        assert vt.call(lambda: vt.endpoint.mission.upload) is None  # type: ignore[union-attr]
    finally:
        vt.stop()


def test_float_mission_items_accepted(client: MavClient, vehicle: VehicleThread) -> None:
    lat, lon, _ = GEO.ned_to_global(6.0, 0.0, 0.0)
    client.send(client.mav.mission_count_encode(1, 1, 1, 0))
    req = client.wait_for("MISSION_REQUEST_INT", 1.0)
    assert req is not None
    client.send(client.mav.mission_item_encode(1, 1, 0, M.MAV_FRAME_GLOBAL, M.MAV_CMD_NAV_WAYPOINT, 0, 1,
                                               0, 0, 0, NAN, lat, lon, GEO.alt_amsl_m + 7.0, 0))  # fmt: skip
    ack = client.wait_for("MISSION_ACK", 1.0)
    assert ack is not None and ack.type == M.MAV_MISSION_ACCEPTED
    it = vehicle.call(lambda: vehicle.vehicle.autopilot.mission_items[0])
    # float32 degrees resolve ~0.4 m at this latitude: why MISSION_ITEM_INT exists
    assert (it.north_m, it.east_m) == pytest.approx((6.0, 0.0), abs=0.5)
    assert it.down_m == pytest.approx(-7.0, abs=0.05)


@pytest.fixture(params=[pytest.param("udp", marks=pytest.mark.slow), "sim"])
def rig4(request: pytest.FixtureRequest, rig_factory: Callable[..., Rig]) -> Rig:
    """Over UDP at speed 4 (slow: a flight in real time), or on the sim-clock harness (the fast tier)."""
    return rig_factory(request.param, speed=4.0)


def test_mission_flown_reports_items_reached(rig4: Rig) -> None:
    client = rig4.client
    items = _items()
    assert _upload(client, items) == M.MAV_MISSION_ACCEPTED
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
    ack = client.command(M.MAV_CMD_MISSION_START, 0, 0)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    reached = set()
    landed = None
    for _ in range(4000):
        msg = client.wait_for(lambda m: m.get_type() in ("MISSION_ITEM_REACHED", "EXTENDED_SYS_STATE"), 15.0)
        assert msg is not None, f"mission stalled; reached {sorted(reached)}"
        if msg.get_type() == "MISSION_ITEM_REACHED":
            reached.add(msg.seq)
        elif msg.landed_state == 1 and 4 in reached:
            landed = msg
            break
    assert landed is not None and {1, 3, 4} <= reached
    lp = client.wait_for("LOCAL_POSITION_NED", 1.0)
    assert lp is not None and (lp.x, lp.y) == pytest.approx((12.0, -3.0), abs=1.0)
    assert any(m.get_type() == "MISSION_CURRENT" and m.seq >= 3 for _, m in client.received)
