"""End to end, the classic gRPC MAVSDK-Python API (mavsdk-grpc / mavsdk<4): the script most user code looks like."""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
from sitl_process import (
    MODE_AUTO_LAND,
    MODE_AUTO_TAKEOFF,
    MavlinkPeer,
    SitlProcess,
    free_tcp_port,
    is_armed,
    mavsdk_servers_on,
    run_script,
)

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # slow: a flight through mavsdk_server


def test_grpc_takeoff_land_script(sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]) -> None:
    pytest.importorskip("mavsdk_grpc", reason="the classic API needs `pip install mavsdk-grpc`")
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    grpc_port = free_tcp_port()
    run = run_script(
        "grpc_takeoff_land.py",
        [sitl.ports.mavsdk_url, "--grpc-port", str(grpc_port), "--altitude", "3", "--timeout", "90"],
        120,
    )
    assert run.returncode == 0, run.describe()
    assert abs(float(run.result["hover_alt_m"]) - 3.0) < 0.5, run.result
    assert "killed after" not in run.stderr, "the script hung at exit"
    assert mavsdk_servers_on(grpc_port) == [], "the script left its mavsdk_server running"

    heights = [-m.z for m in peer.messages("LOCAL_POSITION_NED")]
    assert 2.6 < max(heights) < 3.6, f"peak height {max(heights):.2f} m for a 3 m takeoff ({peer.lost} lost)"
    modes = [m.custom_mode for m in peer.messages("HEARTBEAT", component=1)]
    assert MODE_AUTO_TAKEOFF in modes and MODE_AUTO_LAND in modes
    hb = peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 5.0)
    assert not is_armed(hb)
    x, y, z = peer.local_position()
    assert math.hypot(x, y) < 1.0 and abs(z) < 0.3, (x, y, z)
