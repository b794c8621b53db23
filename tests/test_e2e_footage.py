"""End to end over real footage (../shared): the interchange video's geo-reference becomes the vehicle's home, and a
ground-station mission flies and lands there. Skipped with a reason when ../shared is absent."""

from __future__ import annotations

import math
import socket
import threading
from collections.abc import Callable
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from sitl_process import MavlinkPeer, SitlProcess, free_udp_ports, run_script

pytestmark = [pytest.mark.e2e, pytest.mark.footage, pytest.mark.slow]  # slow: flights over 1080p footage

# Interchange footprint corners (lon, lat) from ../shared/footage/README.md
CORNERS_LON_LAT = [
    (36.3034739, 49.9671879),
    (36.3063206, 49.9743221),
    (36.3125578, 49.9732927),
    (36.3097064, 49.9661625),
]


def inside_footprint(lat: float, lon: float) -> bool:
    """Point in the (convex) footprint quadrilateral: same side of every edge."""
    signs = []
    for (x1, y1), (x2, y2) in zip(CORNERS_LON_LAT, CORNERS_LON_LAT[1:] + CORNERS_LON_LAT[:1], strict=True):
        signs.append((x2 - x1) * (lat - y1) - (y2 - y1) * (lon - x1) > 0)
    return all(signs) or not any(signs)


def test_mission_over_interchange_footage(
    interchange_video: Path,
    sitl_factory: Callable[..., SitlProcess],
    peer_factory: Callable[[int], MavlinkPeer],
) -> None:
    sitl = sitl_factory(footage="interchange")
    watcher = peer_factory(sitl.ports.api)
    watcher.wait_autopilot()
    ack = watcher.command_long(
        mavlink2.MAV_CMD_REQUEST_MESSAGE, [float(mavlink2.MAVLINK_MSG_ID_HOME_POSITION)]
    )
    assert ack.result == mavlink2.MAV_RESULT_ACCEPTED
    home = watcher.wait("HOME_POSITION", timeout_s=5.0, since_s=0.0)
    lat0, lon0 = home.latitude / 1e7, home.longitude / 1e7
    assert inside_footprint(lat0, lon0), f"home {lat0}, {lon0} is not inside the interchange footage"
    centre_lat = sum(c[1] for c in CORNERS_LON_LAT) / 4
    centre_lon = sum(c[0] for c in CORNERS_LON_LAT) / 4
    assert abs(lat0 - centre_lat) < 1e-3 and abs(lon0 - centre_lon) < 1e-3, "home is not the footage centre"

    run = run_script(
        "pymavlink_gcs_mission.py",
        [
            sitl.ports.pymavlink_url,
            "--altitude",
            "8",
            "--north",
            "12",
            "--east",
            "10",
            "--start",
            "mission-start",
        ],
        180,
    )
    assert run.returncode == 0, run.describe()
    assert float(run.result["landing_error_m"]) < 2.0
    gpi = watcher.wait("GLOBAL_POSITION_INT", timeout_s=3.0)
    assert inside_footprint(gpi.lat / 1e7, gpi.lon / 1e7)
    x, y, z = watcher.local_position()
    assert math.hypot(x, y - 10.0) < 2.0 and abs(z) < 0.3, (x, y, z)


def test_takeoff_land_with_video_over_interchange(
    interchange_video: Path,
    sitl_factory: Callable[..., SitlProcess],
    peer_factory: Callable[[int], MavlinkPeer],
) -> None:
    """With the VAC rendering and H.264 streaming over the real footage, MAVLink flight is unaffected."""
    (video_port,) = free_udp_ports(1)
    rtp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rtp.bind(("127.0.0.1", video_port))
    rtp.settimeout(0.2)
    packets = 0
    stop = threading.Event()

    def count_rtp() -> None:
        nonlocal packets
        while not stop.is_set():
            try:
                data = rtp.recv(65536)
            except TimeoutError:
                continue
            if len(data) >= 12 and data[0] >> 6 == 2:  # RTP version 2
                packets += 1

    counter = threading.Thread(target=count_rtp, daemon=True)
    counter.start()
    try:
        sitl = sitl_factory(footage="interchange", video_port=video_port)
        peer = peer_factory(sitl.ports.gcs)
        peer.wait_autopilot()
        run = run_script("mavsdk_takeoff_land.py", [sitl.ports.mavsdk_url, "--altitude", "5"], 150)
        assert run.returncode == 0, run.describe()
        assert abs(float(run.result["hover_alt_m"]) - 5.0) < 0.5
        peak = -min(m.z for m in peer.messages("LOCAL_POSITION_NED"))
        assert abs(peak - 5.0) < 0.6, f"peak {peak:.2f} m ({peer.lost} messages lost)"
        sitl.stop()
        assert sitl.returncode == 0, sitl.logs()
    finally:
        stop.set()
        counter.join(timeout=2.0)
        rtp.close()
    assert packets > 50, f"only {packets} RTP packets reached port {video_port}"
    stats = sitl.stop_stats()
    rendered = stats.get("render", {}).get(
        "rendered", stats.get("rendered", 0)
    )  # the stats line's layout may evolve
    assert rendered > 0, f"no VAC frames rendered: {stats}"
