"""Geofence and rally plans, DO_ORBIT and DO_JUMP over real UDP with a pymavlink client: upload / download / clear
per mission type, PX4's MAV_MISSION_* refusals for bad fences, a mission outside the fence refused, the fence
breach reaction, RTL to the nearest rally point, Orbit mode in HEARTBEAT with ORBIT_EXECUTION_STATUS.

The tests that take a `rig` run twice: on the in-memory, sim-clock harness (viva_sitl.mavlink.testing; the fast
tier) and over UDP against a vehicle thread at speed 4 (marked slow: the same exchanges, the socket transport is
checked by the other tests here in the fast tier)."""

from __future__ import annotations

import math
import struct
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from mav_client import MavClient, Rig, VehicleThread
from pymavlink.dialects.v20 import common as M

from viva_sitl.autopilot import FlightMode
from viva_sitl.geo import GeoOrigin
from viva_sitl.mavlink import MavlinkConfig
from viva_sitl.selftest import SnapshotCamera

NAN = math.nan
GEO = GeoOrigin()
FENCE, RALLY, MISSION = M.MAV_MISSION_TYPE_FENCE, M.MAV_MISSION_TYPE_RALLY, M.MAV_MISSION_TYPE_MISSION
Item = tuple[int, int, float, float, float, float, int, int, float]  # frame, command, p1..p4, x, y, z


SPEED = 4.0  # the UDP vehicle's sim/wall factor; the harness client's sim timeouts are scaled by it to match


@pytest.fixture
def vehicle(vehicle_factory: Callable[..., VehicleThread]) -> VehicleThread:
    return vehicle_factory(speed=SPEED)


@pytest.fixture(params=[pytest.param("udp", marks=pytest.mark.slow), "sim"])
def rig(request: pytest.FixtureRequest, rig_factory: Callable[..., Rig]) -> Rig:
    return rig_factory(request.param, speed=SPEED)


def _ll(north: float, east: float) -> tuple[int, int]:
    lat, lon, _ = GEO.ned_to_global(north, east, 0.0)
    return round(lat * 1e7), round(lon * 1e7)


def _upload(client: Any, items: list[Item], mtype: int) -> int:
    """Answer the vehicle's MISSION_REQUEST_INTs for `mtype`; return the MISSION_ACK type."""
    client.send(client.mav.mission_count_encode(1, 1, len(items), mtype))
    while True:
        msg = client.wait_for(lambda m: m.get_type() in ("MISSION_REQUEST_INT", "MISSION_ACK"), 2.0)
        assert msg is not None, "vehicle stopped answering during upload"
        assert msg.mission_type == mtype
        if msg.get_type() == "MISSION_ACK":
            return int(msg.type)
        frame, cmd, p1, p2, p3, p4, x, y, z = items[msg.seq]
        client.send(client.mav.mission_item_int_encode(1, 1, msg.seq, frame, cmd, 0, 1, p1, p2, p3, p4, x, y, z,
                                                       mtype))  # fmt: skip


def _download(client: Any, mtype: int) -> list[tuple[int, int, float, int, int]]:
    client.send(client.mav.mission_request_list_encode(1, 1, mtype))
    count = client.wait_for("MISSION_COUNT", 2.0)
    assert count is not None and count.mission_type == mtype
    out = []
    for seq in range(count.count):
        client.send(client.mav.mission_request_int_encode(1, 1, seq, mtype))
        it = client.wait_for("MISSION_ITEM_INT", 2.0)
        assert it is not None and it.seq == seq and it.mission_type == mtype
        out.append((it.command, it.frame, it.param1, it.x, it.y))
    client.send(client.mav.mission_ack_encode(1, 1, M.MAV_MISSION_ACCEPTED, mtype))
    return out


def _polygon(
    corners: list[tuple[float, float]], cmd: int = M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
) -> list[Item]:
    n = len(corners)
    return [(M.MAV_FRAME_GLOBAL_INT, cmd, n, 0, 0, 0, *_ll(a, b), 0.0) for a, b in corners]


SQUARE = [(-30.0, -30.0), (30.0, -30.0), (30.0, 30.0), (-30.0, 30.0)]


def _text(client: Any, start: str, timeout_s: float = 2.0) -> str | None:
    """A STATUSTEXT starting with `start`, already received (it may precede the ACK a helper waited for) or coming."""
    for _, m in client.received:
        if m.get_type() == "STATUSTEXT" and m.text.startswith(start):
            return str(m.text)
    m = client.wait_for(lambda m: m.get_type() == "STATUSTEXT" and m.text.startswith(start), timeout_s)
    return None if m is None else str(m.text)


def test_fence_and_rally_round_trip_per_type_and_clear(rig: Rig) -> None:
    client = rig.client
    fence = _polygon(SQUARE) + [
        (M.MAV_FRAME_GLOBAL_INT, M.MAV_CMD_NAV_FENCE_CIRCLE_EXCLUSION, 5.0, 0, 0, 0, *_ll(10, 10), 0.0),
        (M.MAV_FRAME_GLOBAL_INT, M.MAV_CMD_NAV_FENCE_RETURN_POINT, 0, 0, 0, 0, *_ll(1, 1), 0.0),
    ]
    rally = [(M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_RALLY_POINT, 0, 0, 0, 0, *_ll(20, 0), 10.0)]
    assert _upload(client, fence, FENCE) == M.MAV_MISSION_ACCEPTED
    assert _upload(client, rally, RALLY) == M.MAV_MISSION_ACCEPTED
    wp = [(M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, NAN, *_ll(5, -5), 5.0)]
    assert _upload(client, wp, MISSION) == M.MAV_MISSION_ACCEPTED
    got = _download(client, FENCE)
    assert [(c, p1, x, y) for c, _, p1, x, y in got] == [(f[1], f[2], f[6], f[7]) for f in fence]
    assert [(c, x, y) for c, _, _, x, y in _download(client, RALLY)] == [(r[1], r[6], r[7]) for r in rally]
    assert len(_download(client, MISSION)) == 1  # types stored separately
    ap = rig.autopilot
    fz = rig.call(lambda: ap.geofence)
    assert (
        len(fz.polygons) == 1 and len(fz.circles) == 1 and not fz.contains(10.0, 12.0) and fz.contains(-10, 0)
    )
    assert rig.call(lambda: ap.rally_points[0].north_m) == pytest.approx(20.0, abs=0.05)
    # clear one type, then all
    client.send(client.mav.mission_clear_all_encode(1, 1, RALLY))
    ack = client.wait_for("MISSION_ACK", 1.0)
    assert ack is not None and ack.type == M.MAV_MISSION_ACCEPTED and ack.mission_type == RALLY
    assert _download(client, RALLY) == [] and len(_download(client, FENCE)) == len(fence)
    client.send(client.mav.mission_clear_all_encode(1, 1, M.MAV_MISSION_TYPE_ALL))
    ack = client.wait_for("MISSION_ACK", 1.0)
    assert ack is not None and ack.type == M.MAV_MISSION_ACCEPTED
    assert _download(client, FENCE) == [] and _download(client, MISSION) == []
    assert rig.call(lambda: ap.geofence.empty)


def test_bad_fences_are_refused_with_px4_codes(rig: Rig) -> None:
    client = rig.client
    good = _polygon(SQUARE)
    assert _upload(client, good, FENCE) == M.MAV_MISSION_ACCEPTED
    bowtie = _polygon([(0.0, 0.0), (20.0, 20.0), (20.0, 0.0), (0.0, 20.0)])
    assert _upload(client, bowtie, FENCE) == M.MAV_MISSION_ERROR
    assert _text(client, "Geofence rejected: polygon 0 self-intersects")
    two = _polygon([(0.0, 0.0), (20.0, 20.0)])
    assert _upload(client, two, FENCE) == M.MAV_MISSION_INVALID_PARAM1
    wrong_count = [(f[0], f[1], 5, *f[3:]) for f in good]  # says 5 vertices, has 4
    assert _upload(client, wrong_count, FENCE) == M.MAV_MISSION_INVALID_PARAM1
    bad_lat = [(*good[0][:6], 95 * 10**7, good[0][7], 0.0), *good[1:]]
    assert _upload(client, bad_lat, FENCE) == M.MAV_MISSION_INVALID_PARAM5_X
    negative_circle = [
        (M.MAV_FRAME_GLOBAL_INT, M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, -5.0, 0, 0, 0, *_ll(0, 0), 0.0)
    ]
    assert _upload(client, negative_circle, FENCE) == M.MAV_MISSION_INVALID_PARAM1
    nan_circle = [
        (M.MAV_FRAME_GLOBAL_INT, M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, NAN, 0, 0, 0, *_ll(0, 0), 0.0)
    ]
    assert _upload(client, nan_circle, FENCE) == M.MAV_MISSION_INVALID_PARAM1
    waypoint_in_fence = [(M.MAV_FRAME_GLOBAL_INT, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, *_ll(0, 0), 0.0)]
    assert _upload(client, waypoint_in_fence, FENCE) == M.MAV_MISSION_UNSUPPORTED
    ap = rig.autopilot
    assert rig.call(lambda: len(ap.geofence.polygons)) == 1  # every refusal kept the good fence
    # a mission with a waypoint outside the fence: PX4's feasibility check text
    out = [(M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, NAN, *_ll(50, 0), 5.0)]
    assert _upload(client, out, MISSION) == M.MAV_MISSION_DENIED
    assert _text(client, "Geofence violation for waypoint 1")
    # a rally point outside the fence: accepted with a warning (PX4 does not check them)
    rally = [(M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_RALLY_POINT, 0, 0, 0, 0, *_ll(80, 0), 10.0)]
    assert _upload(client, rally, RALLY) == M.MAV_MISSION_ACCEPTED
    assert _text(client, "Rally point 0 is outside the geofence")


def test_zero_radius_circle_at_lat_lon_zero_is_stored_and_contains_nothing(
    client: MavClient, vehicle: VehicleThread
) -> None:
    """MAVSDK's geofence plugin (its geofence.py example) sends a polygon plus an inclusion circle of radius 0 at
    lat/lon 0/0 as "no circle": PX4 accepts and stores it, and it contains no point (the polygon alone decides)."""
    placeholder = (M.MAV_FRAME_GLOBAL_INT, M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION, 0.0, 0, 0, 0, 0, 0, 0.0)
    assert _upload(client, [*_polygon(SQUARE), placeholder], FENCE) == M.MAV_MISSION_ACCEPTED
    ap = vehicle.vehicle.autopilot  # type: ignore[union-attr]
    fence = vehicle.call(lambda: ap.geofence)
    assert len(fence.polygons) == 1 and len(fence.circles) == 1
    assert fence.contains(0.0, 0.0) and not fence.contains(40.0, 0.0)
    down = _download(client, FENCE)
    assert [d[0] for d in down][-1] == M.MAV_CMD_NAV_FENCE_CIRCLE_INCLUSION and down[-1][2:] == (0.0, 0, 0)
    # the stored fence does not refuse a mission inside the polygon, and arming at home is allowed
    inside = [(M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, NAN, *_ll(10, 10), 5.0)]
    assert _upload(client, inside, MISSION) == M.MAV_MISSION_ACCEPTED
    ack = client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    # alone, the zero circle is an inclusion area nothing is inside (PX4): a mission point is then outside the fence
    assert _upload(client, [placeholder], FENCE) == M.MAV_MISSION_ACCEPTED
    assert _upload(client, inside, MISSION) == M.MAV_MISSION_DENIED


def _fly_to(client: Any, alt_m: float = 6.0) -> None:
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
    ack = client.command(M.MAV_CMD_NAV_TAKEOFF, NAN, NAN, NAN, NAN, NAN, NAN, 488.0 + alt_m)
    assert ack is not None and ack.result == M.MAV_RESULT_ACCEPTED
    top = client.wait_for(lambda m: m.get_type() == "GLOBAL_POSITION_INT" and m.relative_alt > (alt_m - 0.3) * 1e3,
                          15.0)  # fmt: skip
    assert top is not None


def _reposition(client: Any, north: float, east: float, alt_rel: float) -> None:
    x, y = _ll(north, east)
    client.send(client.mav.command_int_encode(1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_DO_REPOSITION,
                                              0, 0, -1, 1, 0, NAN, x, y, alt_rel))  # fmt: skip
    a = client.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_DO_REPOSITION, 1.0)
    assert a is not None and a.result == M.MAV_RESULT_ACCEPTED


def test_breach_returns_to_the_nearest_rally_point(rig: Rig) -> None:
    client = rig.client
    gf_return = struct.unpack("<f", struct.pack("<i", 3))[0]  # PX4 INT32 parameters travel bytewise
    client.send(client.mav.param_set_encode(1, 1, b"GF_ACTION", gf_return, M.MAV_PARAM_TYPE_INT32))
    assert client.wait_for(lambda m: m.get_type() == "PARAM_VALUE" and m.param_id == "GF_ACTION", 1.0)
    for name, v in ((b"RTL_RETURN_ALT", 8.0), (b"RTL_DESCEND_ALT", 4.0)):
        client.send(client.mav.param_set_encode(1, 1, name, v, M.MAV_PARAM_TYPE_REAL32))
    assert _upload(client, _polygon(SQUARE), FENCE) == M.MAV_MISSION_ACCEPTED
    rally = [(M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_NAV_RALLY_POINT, 0, 0, 0, 0, *_ll(25, 0), 0.0)]
    assert _upload(client, rally, RALLY) == M.MAV_MISSION_ACCEPTED
    _fly_to(client)
    _reposition(client, 45.0, 0.0, 6.0)
    assert _text(client, "Geofence breached", 20.0), "no breach reported"
    rtl = FlightMode.AUTO_RTL.custom_mode
    assert client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.custom_mode == rtl, 3.0)
    landed = client.wait_for(lambda m: m.get_type() == "EXTENDED_SYS_STATE" and m.landed_state == 1, 60.0)
    assert landed is not None
    lp = client.wait_for("LOCAL_POSITION_NED", 2.0)
    assert lp is not None and math.hypot(lp.x - 25.0, lp.y) < 1.0, (lp.x, lp.y)  # the rally point, not home


def test_do_orbit_mode_and_execution_status(rig: Rig) -> None:
    client = rig.client
    _fly_to(client)
    x, y = _ll(10.0, 0.0)
    # z is AMSL whatever the frame, as PX4's Orbit task reads it (and MAVSDK sends it)
    client.send(client.mav.command_int_encode(1, 1, M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, M.MAV_CMD_DO_ORBIT, 0, 0,
                                              -8.0, 2.0, 0, NAN, x, y, 488.0 + 7.0))  # fmt: skip
    a = client.wait_for(lambda m: m.get_type() == "COMMAND_ACK" and m.command == M.MAV_CMD_DO_ORBIT, 1.0)
    assert a is not None and a.result == M.MAV_RESULT_ACCEPTED
    orbit = FlightMode.ORBIT.custom_mode
    assert orbit == (3 << 16) | (1 << 24)  # POSCTL main mode, ORBIT sub mode (PX4)
    assert client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.custom_mode == orbit, 2.0)
    st = client.wait_for("ORBIT_EXECUTION_STATUS", 2.0)
    assert st is not None and st.radius == pytest.approx(-8.0) and (st.x, st.y) == (x, y)
    assert st.z == pytest.approx(488.0 + 7.0, abs=0.01)
    on_circle = client.wait_for(
        lambda m: m.get_type() == "LOCAL_POSITION_NED" and abs(math.hypot(m.x - 10.0, m.y) - 8.0) < 0.5
        and abs(m.z + 7.0) < 0.5, 20.0)  # fmt: skip
    assert on_circle is not None
    too_big = client.command(M.MAV_CMD_DO_ORBIT, 5000.0, NAN, NAN, NAN, NAN, NAN, NAN)
    assert too_big is not None and too_big.result == M.MAV_RESULT_DENIED
    assert _text(client, "Orbit radius limit exceeded")
    # Hold leaves Orbit and the status stream stops
    client.command(M.MAV_CMD_DO_SET_MODE, M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4, 3)
    hold = FlightMode.AUTO_LOITER.custom_mode
    assert client.wait_for(lambda m: m.get_type() == "HEARTBEAT" and m.custom_mode == hold, 2.0)
    client.drain()
    assert client.wait_for("ORBIT_EXECUTION_STATUS", 1.5) is None


def test_mission_with_do_jump_is_flown_with_its_visit_count(rig: Rig) -> None:
    client = rig.client
    rel = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    items: list[Item] = [
        (rel, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, 4.0),
        (rel, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, NAN, *_ll(6, 0), 4.0),
        (rel, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, NAN, *_ll(6, 6), 4.0),
        (M.MAV_FRAME_MISSION, M.MAV_CMD_DO_JUMP, 1, 1, 0, 0, 0, 0, 0.0),  # once more through 1 and 2
        (M.MAV_FRAME_MISSION, M.MAV_CMD_DO_VTOL_TRANSITION, 4, 0, 0, 0, 0, 0, 0.0),  # accepted, skipped
        (rel, M.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, 0, 0, 0.0),
    ]
    assert _upload(client, items, MISSION) == M.MAV_MISSION_ACCEPTED
    loop = [(M.MAV_FRAME_MISSION, M.MAV_CMD_DO_JUMP, 1, 5, 0, 0, 0, 0, 0.0)] * 2
    assert _upload(client, [items[0], *loop], MISSION) == M.MAV_MISSION_DENIED  # jumps around no waypoint
    assert _text(client, "Mission rejected: DO_JUMP 1 loops")
    assert _upload(client, items, MISSION) == M.MAV_MISSION_ACCEPTED
    assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
    assert client.command(M.MAV_CMD_MISSION_START, 0, 0).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
    reached: list[int] = []
    while 5 not in reached:
        m = client.wait_for("MISSION_ITEM_REACHED", 40.0)
        assert m is not None, f"mission stalled after {reached}"
        reached.append(int(m.seq))
    assert reached == [0, 1, 2, 1, 2, 4, 5]


def test_mission_camera_items_capture_the_vac_view(client: MavClient, tmp_path: Path) -> None:
    camera = SnapshotCamera(tmp_path / "captures")
    cfg = MavlinkConfig(api_remote_port=client.port, gcs_remote_port=0, api_local_port=0, gcs_local_port=0)
    rel = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
    items: list[Item] = [
        (rel, M.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, NAN, 0, 0, 4.0),
        (M.MAV_FRAME_MISSION, M.MAV_CMD_IMAGE_START_CAPTURE, 0, 0, 1, 0, 0, 0, 0.0),  # one image
        (M.MAV_FRAME_MISSION, M.MAV_CMD_DO_SET_CAM_TRIGG_DIST, 5.0, 0, 0, 0, 0, 0, 0.0),  # every 5 m
        (rel, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, NAN, *_ll(23, 0), 4.0),
        (M.MAV_FRAME_MISSION, M.MAV_CMD_DO_SET_CAM_TRIGG_DIST, 0.0, 0, 0, 0, 0, 0, 0.0),  # off
        (M.MAV_FRAME_MISSION, M.MAV_CMD_DO_MOUNT_CONTROL, -45.0, 0, 10.0, 0, 0, 0, 0.0),  # gimbal: recorded
        (rel, M.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, NAN, *_ll(23, 12), 4.0),
        (rel, M.MAV_CMD_NAV_LAND, 0, 0, 0, NAN, 0, 0, 0.0),
    ]
    with VehicleThread(cfg, speed=4.0, camera=camera) as vt:
        client.target = vt.api
        assert _upload(client, items, MISSION) == M.MAV_MISSION_ACCEPTED
        assert client.command(M.MAV_CMD_COMPONENT_ARM_DISARM, 1).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
        assert client.command(M.MAV_CMD_MISSION_START, 0, 0).result == M.MAV_RESULT_ACCEPTED  # type: ignore[union-attr]
        assert client.wait_for(lambda m: m.get_type() == "MISSION_ITEM_REACHED" and m.seq == 6, 60.0)
        ap = vt.vehicle.autopilot  # type: ignore[union-attr]
        assert vt.call(lambda: ap.gimbal_pitch_yaw_deg) == (-45.0, 10.0)
    captured = [m for _, m in client.received if m.get_type() == "CAMERA_IMAGE_CAPTURED"]
    # 1 at the start + one per 5 m over the 23 m leg (4: the waypoint is accepted within NAV_ACC_RAD), none on the second leg (trigger off)
    assert len(captured) == 5 and len(camera.captured) == 5, (len(captured), camera.captured)
    assert all(m.capture_result == 1 for m in captured)
    norths = [GEO.global_to_ned(m.lat * 1e-7, m.lon * 1e-7, 0.0)[0] for m in captured]
    # the capture reports where the vehicle is when the camera runs (the housekeeping tick after the trigger, up to
    # ~0.2 s of sim time later at speed 4): check order and span, the exact spacing is tested on DistanceTrigger
    assert norths[0] < 1.0 and all(b > a for a, b in zip(norths, norths[1:], strict=False))
    assert 4.0 < norths[1] < 7.5 and 19.0 < norths[-1] < 23.5, norths
