"""End to end against a real `viva-sitl run` process, at speed 1 and 4 (the same flow, only the wall clock differs):
a geofence and a rally point uploaded (MISSION_TYPE_FENCE / RALLY) and read back, a mission with a DO_JUMP flown
with PX4's visit count, an orbit flown (DO_ORBIT), then a fence breach returning to the rally point (GF_ACTION 3)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as M
from sitl_process import (
    LANDED_ON_GROUND,
    MODE_AUTO_LOITER,
    MODE_AUTO_MISSION,
    MODE_AUTO_RTL,
    MavlinkPeer,
    SitlProcess,
    home_of,
    offset,
)

pytestmark = pytest.mark.e2e

MODE_ORBIT = (3 << 16) | (1 << 24)  # POSCTL main mode, ORBIT sub mode (PX4)
REL = M.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
NAN = math.nan


def _upload(peer: MavlinkPeer, items: list[tuple[int, int, float, float, float, float, int, int, float]],
            mtype: int, timeout_s: float = 10.0) -> int:  # fmt: skip
    """Upload (frame, command, p1..p4, x, y, z) items of one mission type; the MISSION_ACK type."""
    t0 = time.monotonic()
    peer.send(peer.mav.mission_count_encode(1, 1, len(items), mtype))
    handled = t0
    while True:
        msg = peer.wait(("MISSION_REQUEST_INT", "MISSION_ACK"), lambda m: m.mission_type == mtype, timeout_s,
                        since_s=handled, what=f"mission request/ack (type {mtype})")  # fmt: skip
        handled = time.monotonic()
        if msg.get_type() == "MISSION_ACK":
            return int(msg.type)
        frame, cmd, p1, p2, p3, p4, x, y, z = items[msg.seq]
        peer.send(peer.mav.mission_item_int_encode(1, 1, msg.seq, frame, cmd, 0, 1, p1, p2, p3, p4, x, y, z,
                                                   mtype))  # fmt: skip


def _count(peer: MavlinkPeer, mtype: int) -> int:
    t0 = time.monotonic()
    peer.send(peer.mav.mission_request_list_encode(1, 1, mtype))
    count = peer.wait(
        "MISSION_COUNT", lambda m: m.mission_type == mtype, 3.0, since_s=t0, what="MISSION_COUNT"
    )
    peer.send(peer.mav.mission_ack_encode(1, 1, M.MAV_MISSION_ACCEPTED, mtype))
    return int(count.count)


def _mode(peer: MavlinkPeer, mode: int, timeout_s: float, what: str) -> Any:
    return peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1 and m.custom_mode == mode, timeout_s,
                     what=what)  # fmt: skip


# 1x: ~49 s, 4x: ~13 s; both slow: the same flow (fence + rally round trip, a mission refused outside the fence,
# DO_JUMP visits, DO_ORBIT, breach -> RTL to the rally point) runs in the fast tier on the sim-clock harness
# (test_mavlink_fence.py, `rig` "sim"), and other fast e2e tests start the `viva-sitl run` process
@pytest.mark.slow
@pytest.mark.parametrize("speed", [1.0, 4.0])
def test_fence_rally_do_jump_and_orbit_flown_at_speed(
    sitl_factory: Callable[..., SitlProcess], peer_factory: Callable[[int], MavlinkPeer], speed: float
) -> None:
    sitl = sitl_factory(speed=speed)
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    lat0, lon0 = home_of(peer)

    def ll(north: float, east: float) -> tuple[int, int]:
        return offset(lat0, lon0, north, east)

    def wall(sim_s: float) -> float:  # a sim-time budget in wall seconds, with slack for a loaded machine
        return sim_s / speed + 15.0

    # fence: a 80 m square inclusion polygon; one rally point 25 m north
    square = [(-40.0, -40.0), (40.0, -40.0), (40.0, 40.0), (-40.0, 40.0)]
    vertex = M.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION
    fence = [(M.MAV_FRAME_GLOBAL_INT, vertex, 4.0, 0.0, 0.0, 0.0, *ll(n, e), 0.0) for n, e in square]
    assert _upload(peer, fence, M.MAV_MISSION_TYPE_FENCE) == M.MAV_MISSION_ACCEPTED
    rally = [(REL, M.MAV_CMD_NAV_RALLY_POINT, 0.0, 0.0, 0.0, 0.0, *ll(25.0, 0.0), 0.0)]
    assert _upload(peer, rally, M.MAV_MISSION_TYPE_RALLY) == M.MAV_MISSION_ACCEPTED
    assert _count(peer, M.MAV_MISSION_TYPE_FENCE) == 4 and _count(peer, M.MAV_MISSION_TYPE_RALLY) == 1
    # a mission leaving the fence is refused (PX4's feasibility check)
    outside = [(REL, M.MAV_CMD_NAV_WAYPOINT, 0.0, 0.0, 0.0, NAN, *ll(60.0, 0.0), 5.0)]
    assert _upload(peer, outside, M.MAV_MISSION_TYPE_MISSION) != M.MAV_MISSION_ACCEPTED

    # mission: take off, two waypoints twice (DO_JUMP back once), a last waypoint
    mission = [
        (REL, M.MAV_CMD_NAV_TAKEOFF, 0.0, 0.0, 0.0, NAN, *ll(0.0, 0.0), 5.0),
        (REL, M.MAV_CMD_NAV_WAYPOINT, 0.0, 1.0, 0.0, NAN, *ll(10.0, 0.0), 5.0),
        (REL, M.MAV_CMD_NAV_WAYPOINT, 0.0, 1.0, 0.0, NAN, *ll(10.0, 10.0), 5.0),
        (REL, M.MAV_CMD_DO_JUMP, 1.0, 1.0, 0.0, 0.0, 0, 0, 0.0),
        (REL, M.MAV_CMD_NAV_WAYPOINT, 0.0, 1.0, 0.0, NAN, *ll(0.0, 5.0), 5.0),
    ]
    assert _upload(peer, mission, M.MAV_MISSION_TYPE_MISSION) == M.MAV_MISSION_ACCEPTED
    peer.wait_armable()
    ack = peer.command_long(M.MAV_CMD_DO_SET_MODE, [M.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4.0, 4.0])
    assert ack.result == M.MAV_RESULT_ACCEPTED
    t_start = time.monotonic()
    assert peer.command_long(M.MAV_CMD_COMPONENT_ARM_DISARM, [1.0]).result == M.MAV_RESULT_ACCEPTED
    _mode(peer, MODE_AUTO_MISSION, 5.0, "Mission mode")
    peer.wait(
        "MISSION_ITEM_REACHED", lambda m: m.seq == 4, wall(90.0), since_s=t_start, what="last item reached"
    )
    reached = [m.seq for m in peer.messages("MISSION_ITEM_REACHED", since_s=t_start)]
    visits = [s for i, s in enumerate(reached) if i == 0 or reached[i - 1] != s]  # repeats of one report
    assert visits == [0, 1, 2, 1, 2, 4], visits
    x, y, _ = peer.local_position()
    assert math.hypot(x - 0.0, y - 5.0) < 2.5

    # orbit: 8 m around a point 10 m east, at 6 m (z is AMSL, as PX4's Orbit task reads it)
    home = peer.wait("HOME_POSITION", timeout_s=5.0, since_s=0.0)
    lat, lon = ll(0.0, 10.0)
    t_orbit = time.monotonic()
    peer.send(peer.mav.command_int_encode(1, 1, REL, M.MAV_CMD_DO_ORBIT, 0, 0, 8.0, 2.0, 0, NAN, lat, lon,
                                          home.altitude / 1e3 + 6.0))  # fmt: skip
    ack = peer.wait("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_DO_ORBIT, 3.0, since_s=t_orbit)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    _mode(peer, MODE_ORBIT, 5.0, "Orbit mode")
    on_circle = peer.wait(
        "LOCAL_POSITION_NED",
        lambda m: abs(math.hypot(m.x, m.y - 10.0) - 8.0) < 0.6 and abs(m.z + 6.0) < 0.6
        and math.hypot(m.vx, m.vy) > 1.5,
        wall(40.0), since_s=t_orbit, what="on the 8 m circle at 2 m/s",
    )  # fmt: skip
    assert on_circle is not None
    status = peer.wait("ORBIT_EXECUTION_STATUS", timeout_s=3.0)
    assert status.radius == pytest.approx(8.0) and (status.x, status.y) == (lat, lon)

    # breach: GF_ACTION 3 returns, to the rally point (closer than home from 60 m north)
    assert peer.set_param_int("GF_ACTION", 3) == 3
    peer.set_param("RTL_RETURN_ALT", 8.0)
    peer.set_param("RTL_DESCEND_ALT", 4.0)
    lat, lon = ll(60.0, 0.0)
    t_out = time.monotonic()
    peer.send(
        peer.mav.command_int_encode(1, 1, REL, M.MAV_CMD_DO_REPOSITION, 0, 0, -1, 1, 0, NAN, lat, lon, 6.0)
    )
    ack = peer.wait("COMMAND_ACK", lambda m: m.command == M.MAV_CMD_DO_REPOSITION, 3.0, since_s=t_out)
    assert ack.result == M.MAV_RESULT_ACCEPTED
    _mode(peer, MODE_AUTO_LOITER, 5.0, "Hold flying the reposition")
    peer.wait("STATUSTEXT", lambda m: m.text.startswith("Geofence breached"), wall(30.0), since_s=t_out,
              what="the breach report")  # fmt: skip
    _mode(peer, MODE_AUTO_RTL, 5.0, "Return after the breach")
    peer.wait("EXTENDED_SYS_STATE", lambda m: m.landed_state == LANDED_ON_GROUND, wall(90.0), since_s=t_out,
              what="landed")  # fmt: skip
    x, y, _ = peer.local_position()
    assert math.hypot(x - 25.0, y) < 1.5, f"landed at ({x:.1f}, {y:.1f}), not at the rally point (25, 0)"
