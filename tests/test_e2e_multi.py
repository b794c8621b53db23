"""End to end, two vehicles side by side (`--instance 0` and `--instance 1` on distinct ports): both fly at once."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import pytest
from sitl_process import MavlinkPeer, SitlProcess, is_armed, run_script

pytestmark = pytest.mark.e2e


def test_two_instances_fly_side_by_side(
    sitl_factory: Callable[..., SitlProcess], peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    vehicles = [sitl_factory(instance=0, name="veh0"), sitl_factory(instance=1, name="veh1")]
    peers = [peer_factory(v.ports.gcs) for v in vehicles]
    heartbeats = [p.wait_autopilot() for p in peers]
    # Instance N is MAVLink system N+1, as PX4 SITL -i N.
    assert [hb.get_srcSystem() for hb in heartbeats] == [1, 2]

    altitudes = ("3", "5")
    with ThreadPoolExecutor(max_workers=2) as pool:
        runs = list(
            pool.map(
                lambda va: run_script(
                    "mavsdk_takeoff_land.py",
                    [va[0].ports.mavsdk_url, "--altitude", va[1], "--timeout", "100"],
                    130,
                ),
                zip(vehicles, altitudes, strict=True),
            )
        )
    for run in runs:
        assert run.returncode == 0, run.describe()
    for peer, alt, sysid in zip(peers, altitudes, (1, 2), strict=True):
        positions = peer.messages("LOCAL_POSITION_NED")
        assert {m.get_srcSystem() for m in positions} == {sysid}, "telemetry from the other vehicle leaked in"
        peak = -min(m.z for m in positions)
        assert abs(peak - float(alt)) < 0.6, (
            f"vehicle {sysid}: peak {peak:.2f} m, commanded {alt} m ({peer.lost} lost)"
        )
        assert not is_armed(peer.wait("HEARTBEAT", lambda m: m.get_srcComponent() == 1, 5.0))
    for v in vehicles:
        assert v.alive, f"{v.name} died\n{v.logs()}"
