"""End to end, pymavlink as a ground station: the mission script, the mission protocol, parameters and rejections."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from sitl_process import (
    EARTH_RADIUS_M,
    MODE_AUTO_LOITER,
    MODE_AUTO_MISSION,
    MavlinkPeer,
    SitlProcess,
    finite,
    home_of,
    is_armed,
    offset,
    run_script,
)

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # slow: flights of a viva-sitl process

ON_GROUND, IN_AIR, LANDING = 1, 2, 4
ACCEPTED, TEMPORARILY_REJECTED, DENIED, UNSUPPORTED = 0, 1, 2, 3


def wait_landed_disarmed(peer: MavlinkPeer, timeout_s: float) -> None:
    peer.wait(
        "HEARTBEAT",
        lambda m: (
            m.get_srcComponent() == 1
            and not is_armed(m)
            and (ext := peer.latest("EXTENDED_SYS_STATE")) is not None
            and ext.landed_state == ON_GROUND
        ),
        timeout_s,
        what="landed and disarmed",
    )


def has_seq(seq: int) -> Callable[[Any], bool]:
    return lambda m: bool(m.seq == seq)


def test_gcs_mission_script(sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]) -> None:
    # The script owns the GCS link; this test watches the flight on the API link.
    watcher = peer_factory(sitl.ports.api)
    watcher.wait_autopilot()
    run = run_script(
        "pymavlink_gcs_mission.py",
        [sitl.ports.pymavlink_url, "--altitude", "6", "--north", "10", "--east", "8", "--timeout", "150"],
        180,
    )
    assert run.returncode == 0, run.describe()
    reached = [int(s) for s in run.result["reached"].split(",")]
    assert reached == sorted(reached) and {1, 2} <= set(reached), reached
    assert float(run.result["landing_error_m"]) < 2.0, run.result

    assert MODE_AUTO_MISSION in [m.custom_mode for m in watcher.messages("HEARTBEAT", component=1)]
    currents = [m.seq for m in watcher.messages("MISSION_CURRENT")]
    assert currents == sorted(currents) and max(currents) == 3, (
        f"MISSION_CURRENT went {sorted(set(currents))}"
    )
    positions = watcher.messages("LOCAL_POSITION_NED")
    assert 9.0 < max(p.x for p in positions) < 11.5, "never reached the waypoints 10 m north"
    assert 7.0 < max(p.y for p in positions) < 9.5, "never reached 8 m east"
    assert 5.3 < -min(p.z for p in positions) < 6.8, "mission altitude 6 m not flown"
    x, y, z = watcher.local_position()
    assert math.hypot(x - 0.0, y - 8.0) < 2.0 and abs(z) < 0.3, (x, y, z)


def test_mission_upload_download_and_mission_start(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    lat0, lon0 = home_of(peer)
    assert finite(lat0, lon0) and (lat0, lon0) != (0.0, 0.0)

    def item(seq: int, cmd: int, north: float, east: float, alt: float, p2: float = 0.0) -> Any:
        lat, lon = offset(lat0, lon0, north, east)
        return peer.mav.mission_item_int_encode(
            1,
            1,
            seq,
            mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
            cmd,
            0,
            1,
            0.0,
            p2,
            0.0,
            math.nan,
            lat,
            lon,
            alt,
            0,
        )

    items = [
        item(0, mavlink2.MAV_CMD_NAV_TAKEOFF, 0, 0, 5.0),
        item(1, mavlink2.MAV_CMD_NAV_WAYPOINT, 8, 0, 5.0, p2=1.0),
        item(2, mavlink2.MAV_CMD_NAV_WAYPOINT, 8, -6, 5.0, p2=1.0),
        item(3, mavlink2.MAV_CMD_NAV_LAND, 0, -6, 0.0),
    ]
    ack = peer.upload_mission(items)
    assert ack.type == mavlink2.MAV_MISSION_ACCEPTED, f"MISSION_ACK type {ack.type}"

    # Download it back and compare item by item.
    t0 = time.monotonic()
    peer.send(peer.mav.mission_request_list_encode(1, 1, 0))
    count = peer.wait("MISSION_COUNT", timeout_s=3.0, since_s=t0).count
    assert count == len(items)
    for sent in items:
        t0 = time.monotonic()
        peer.send(peer.mav.mission_request_int_encode(1, 1, sent.seq, 0))
        got = peer.wait("MISSION_ITEM_INT", has_seq(sent.seq), 3.0, since_s=t0)
        assert (got.command, got.x, got.y) == (sent.command, sent.x, sent.y), (got, sent)
        assert abs(got.z - sent.z) < 0.01 and got.frame in (mavlink2.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, 3)
    peer.send(peer.mav.mission_ack_encode(1, 1, mavlink2.MAV_MISSION_ACCEPTED, 0))

    peer.wait_armable()
    assert peer.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, [1.0]).result == ACCEPTED
    start = time.monotonic()
    ack = peer.command_long(mavlink2.MAV_CMD_MISSION_START, [0.0, 3.0])
    assert ack.result == ACCEPTED, f"MISSION_START: MAV_RESULT {ack.result}"
    wait_landed_disarmed(peer, 120.0)

    reached = [m.seq for m in peer.messages("MISSION_ITEM_REACHED", since_s=start)]
    assert reached == sorted(reached) and {1, 2} <= set(reached), f"MISSION_ITEM_REACHED order {reached}"
    assert MODE_AUTO_MISSION in [
        m.custom_mode for m in peer.messages("HEARTBEAT", since_s=start, component=1)
    ]
    x, y, z = peer.local_position()
    assert math.hypot(x - 0.0, y + 6.0) < 1.5 and abs(z) < 0.3, f"landed at ({x:.2f}, {y:.2f}, {z:.2f})"
    gpi = peer.latest("GLOBAL_POSITION_INT")
    land_lat, land_lon = offset(lat0, lon0, 0, -6)
    err_m = math.hypot(
        math.radians((gpi.lat - land_lat) / 1e7) * EARTH_RADIUS_M,
        math.radians((gpi.lon - land_lon) / 1e7) * EARTH_RADIUS_M * math.cos(math.radians(lat0)),
    )
    assert err_m < 1.5, f"GLOBAL_POSITION_INT {err_m:.2f} m from the LAND item"


def test_takeoff_altitude_param_land_speed_and_rejections(
    sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    value = peer.set_param("MIS_TAKEOFF_ALT", 4.0)
    assert abs(value.param_value - 4.0) < 1e-6
    assert abs(peer.get_param("MIS_TAKEOFF_ALT") - 4.0) < 1e-6
    land_speed = peer.get_param("MPC_LAND_SPEED")
    assert 0.1 < land_speed < 3.0

    # Unknown command: UNSUPPORTED. OFFBOARD without any setpoint stream: refused, mode unchanged.
    assert peer.command_long(31999, [1.0]).result == UNSUPPORTED
    mode_before = peer.latest("HEARTBEAT", component=1).custom_mode
    assert peer.command_long(mavlink2.MAV_CMD_DO_SET_MODE, [1.0, 6.0, 0.0]).result in (
        TEMPORARILY_REJECTED,
        DENIED,
    )
    assert peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 3.0).custom_mode == mode_before

    peer.wait_armable()
    assert peer.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, [1.0, math.nan]).result == ACCEPTED
    peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1 and is_armed(m), 3.0, what="armed heartbeat")
    ack = peer.command_long(mavlink2.MAV_CMD_NAV_TAKEOFF, [math.nan] * 7)  # as MAVSDK sends it
    assert ack.result == ACCEPTED, f"NAV_TAKEOFF: MAV_RESULT {ack.result}"

    # Takeoff ends at MIS_TAKEOFF_ALT, in Hold (AUTO.LOITER), as PX4.
    peer.wait(
        "HEARTBEAT",
        lambda m: m.get_srcComponent() == 1 and m.custom_mode == MODE_AUTO_LOITER,
        60.0,
        what="AUTO.LOITER after takeoff",
    )
    settled = peer.wait("LOCAL_POSITION_NED", lambda m: abs(m.vz) < 0.1, 30.0, what="settled hover")
    assert abs(settled.z + 4.0) < 0.3, f"hover z {settled.z:.2f} m, MIS_TAKEOFF_ALT 4 m"
    assert peer.wait("EXTENDED_SYS_STATE", timeout_s=3.0).landed_state == IN_AIR

    # Disarm in the air without force: refused, still armed.
    ack = peer.command_long(mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, [0.0])
    assert ack.result in (TEMPORARILY_REJECTED, DENIED), f"disarm in air: MAV_RESULT {ack.result}"
    assert is_armed(peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 3.0))

    land_start = time.monotonic()
    assert peer.command_long(mavlink2.MAV_CMD_NAV_LAND, [math.nan] * 7).result == ACCEPTED
    wait_landed_disarmed(peer, 60.0)
    states = [m.landed_state for m in peer.messages("EXTENDED_SYS_STATE", since_s=land_start)]
    assert LANDING in states and states[-1] == ON_GROUND, states
    # Descent at MPC_LAND_SPEED: the steady sink rate between 3 m and 1 m height.
    sinks = [m.vz for m in peer.messages("LOCAL_POSITION_NED", since_s=land_start) if -3.0 < m.z < -1.0]
    assert sinks, "no samples between 3 m and 1 m during the landing"
    mean_sink = sum(sinks) / len(sinks)
    assert abs(mean_sink - land_speed) < 0.3, (
        f"landing sink rate {mean_sink:.2f} m/s, MPC_LAND_SPEED {land_speed}"
    )
