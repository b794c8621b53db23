"""The mission scripts fail loudly: with no vehicle they exit non-zero with a clear message within their timeouts,
and leave no helper process (mavsdk_server) behind. Needs no viva-sitl."""

from __future__ import annotations

import pytest
from sitl_process import free_tcp_port, free_udp_ports, mavsdk_servers_on, run_script

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # slow: each script waits out its own timeouts

SCRIPTS = [
    ("mavsdk_takeoff_land.py", "udpin://127.0.0.1:{port}", "no autopilot heartbeat"),
    ("mavsdk_offboard_attitude.py", "udpin://127.0.0.1:{port}", "no autopilot heartbeat"),
    ("mavsdk_offboard_velocity.py", "udpin://127.0.0.1:{port}", "no autopilot heartbeat"),
    ("mavsdk_precision_land.py", "udpin://127.0.0.1:{port}", "no autopilot heartbeat"),
    ("grpc_takeoff_land.py", "udpin://127.0.0.1:{port}", "timed out after 2 s waiting for a vehicle"),
    (
        "pymavlink_gcs_mission.py",
        "udpin:127.0.0.1:{port}",
        "timed out after 2 s waiting for an autopilot HEARTBEAT",
    ),
]


@pytest.mark.parametrize(("script", "url", "message"), SCRIPTS, ids=[s[0] for s in SCRIPTS])
def test_script_without_vehicle_fails_with_message(script: str, url: str, message: str) -> None:
    (port,) = free_udp_ports(1)
    args = [url.format(port=port), "--step-timeout", "2", "--timeout", "6"]
    grpc_port = free_tcp_port()
    if script.startswith("grpc"):
        args += ["--grpc-port", str(grpc_port)]
    run = run_script(script, args, timeout_s=30)
    assert run.returncode == 1, run.describe()
    assert "FAILED:" in run.stderr and message in run.stderr, run.describe()
    assert "killed after" not in run.stderr, "the script did not end by itself"
    assert mavsdk_servers_on(grpc_port) == []
