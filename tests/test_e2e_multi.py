"""End to end, two vehicles side by side (`--instance 0` and `--instance 1`), as PX4 SITL runs them: each has its own API
port (MAVSDK, 14540 + N), and both send to ONE ground-station port (14550). On that shared port a GCS must see two
distinct system ids, and a command addressed to one system id must not move the other vehicle, although both receive
every datagram the GCS sends (a GCS's UDP link sends to every vehicle it has heard from)."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest
from pymavlink.dialects.v20 import common as mavlink2
from sitl_process import (
    LANDED_ON_GROUND,
    MavlinkPeer,
    SitlError,
    SitlPorts,
    SitlProcess,
    free_udp_ports,
    is_armed,
    run_script,
)

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # slow: two viva-sitl processes


def autopilot_heartbeat(
    peer: MavlinkPeer, sysid: int, timeout_s: float = 5.0, since_s: float | None = None
) -> Any:
    return peer.wait(
        "HEARTBEAT",
        lambda m: m.get_srcSystem() == sysid and m.get_srcComponent() == 1,
        timeout_s,
        since_s=since_s,
        what=f"heartbeat of system {sysid}",
    )


def command(peer: MavlinkPeer, sysid: int, cmd: int, params: list[float], timeout_s: float = 5.0) -> Any:
    """COMMAND_LONG to (sysid, 1), sent to every vehicle on the link; returns the ACK from sysid (resent each 0.5 s)."""
    p = (params + [0.0] * 7)[:7]
    deadline = time.monotonic() + timeout_s
    while True:
        t0 = time.monotonic()
        peer.send(peer.mav.command_long_encode(sysid, 1, cmd, 0, *p))
        try:
            return peer.wait(
                "COMMAND_ACK",
                lambda m: m.get_srcSystem() == sysid and m.command == cmd,
                min(0.5, max(0.01, deadline - t0)),
                since_s=t0,
                what=f"ACK of command {cmd} from system {sysid}",
            )
        except SitlError:
            if time.monotonic() >= deadline:
                raise


def param_of(peer: MavlinkPeer, sysid: int, name: str, value: float | None = None) -> list[Any]:
    """PARAM_SET (value given) or PARAM_REQUEST_READ to (sysid, 1); every PARAM_VALUE of `name` that answered it."""
    t0 = time.monotonic()
    if value is None:
        peer.send(peer.mav.param_request_read_encode(sysid, 1, name.encode(), -1))
    else:
        peer.send(peer.mav.param_set_encode(sysid, 1, name.encode(), value, mavlink2.MAV_PARAM_TYPE_REAL32))
    peer.wait(
        "PARAM_VALUE",
        lambda m: m.get_srcSystem() == sysid and m.param_id == name,
        5.0,
        since_s=t0,
        what=f"PARAM_VALUE {name} from system {sysid}",
    )
    # the other vehicle had every chance to answer as well: its telemetry kept arriving after the answer
    other = 3 - sysid
    autopilot_heartbeat(peer, other, since_s=time.monotonic())
    return [m for m in peer.messages("PARAM_VALUE", since_s=t0) if m.param_id == name]


def positions(peer: MavlinkPeer, sysid: int, since_s: float = 0.0) -> list[Any]:
    return [m for m in peer.messages("LOCAL_POSITION_NED", since_s=since_s) if m.get_srcSystem() == sysid]


def test_two_instances_share_the_gcs_port_and_stay_apart(
    sitl_factory: Callable[..., SitlProcess], peer_factory: Callable[[int], MavlinkPeer]
) -> None:
    api0, api1, local0, local1, gcs_local0, gcs_local1, gcs = free_udp_ports(7)
    vehicles = [
        sitl_factory(instance=0, name="veh0", ports=SitlPorts(api0, gcs, local0, gcs_local0)),
        sitl_factory(instance=1, name="veh1", ports=SitlPorts(api1, gcs, local1, gcs_local1)),
    ]
    gcs_peer = peer_factory(gcs)  # ONE ground station for both, like QGroundControl on 14550
    gcs_peer.send_to_all = True
    # Instance N is MAVLink system N+1, as PX4 SITL -i N; both are seen on the one port, from two addresses.
    for sysid in (1, 2):
        autopilot_heartbeat(gcs_peer, sysid, 15.0, since_s=0.0)
    assert {m.get_srcSystem() for m in gcs_peer.messages("HEARTBEAT", component=1)} == {1, 2}
    assert len(gcs_peer.remotes) == 2, gcs_peer.remotes

    # A parameter set on system 2 changes system 2 only; each system answers only what is addressed to it.
    before = param_of(gcs_peer, 1, "MIS_TAKEOFF_ALT")
    assert {m.get_srcSystem() for m in before} == {1}, "system 2 answered a read addressed to system 1"
    alt1 = float(before[-1].param_value)
    alt2 = alt1 + 2.0
    echo = param_of(gcs_peer, 2, "MIS_TAKEOFF_ALT", alt2)
    assert {m.get_srcSystem() for m in echo} == {2} and echo[-1].param_value == pytest.approx(alt2)
    after = param_of(gcs_peer, 1, "MIS_TAKEOFF_ALT")
    assert {m.get_srcSystem() for m in after} == {1}
    assert after[-1].param_value == pytest.approx(alt1), "a PARAM_SET to system 2 changed system 1"

    # Arm and take off system 2 only: system 1 stays disarmed on the ground, and does not even acknowledge.
    gcs_peer.wait(
        "SYS_STATUS",
        lambda m: m.get_srcSystem() == 2 and bool(m.onboard_control_sensors_health & 0x10000000),
        15.0,
        since_s=0.0,
        what="system 2 armable",
    )
    t_cmd = time.monotonic()
    assert command(gcs_peer, 2, mavlink2.MAV_CMD_COMPONENT_ARM_DISARM, [1.0]).result == 0
    assert command(gcs_peer, 2, mavlink2.MAV_CMD_NAV_TAKEOFF, [math.nan] * 7).result == 0
    top = gcs_peer.wait(
        "LOCAL_POSITION_NED",
        lambda m: m.get_srcSystem() == 2 and m.z < -(alt2 - 0.3),
        60.0,
        what=f"system 2 at {alt2} m",
    )
    acks_from_1 = [m for m in gcs_peer.messages("COMMAND_ACK", since_s=t_cmd) if m.get_srcSystem() == 1]
    assert not acks_from_1, f"system 1 answered commands addressed to system 2: {acks_from_1}"
    hb1 = autopilot_heartbeat(gcs_peer, 1, since_s=time.monotonic())
    assert not is_armed(hb1), "a command to system 2 armed system 1"
    ground1 = positions(gcs_peer, 1, since_s=t_cmd)
    assert ground1 and max(abs(m.z) for m in ground1) < 0.05, "system 1 moved while system 2 took off"
    assert top.get_srcSystem() == 2

    assert command(gcs_peer, 2, mavlink2.MAV_CMD_NAV_LAND, [math.nan] * 7).result == 0
    gcs_peer.wait(
        "EXTENDED_SYS_STATE",
        lambda m: m.get_srcSystem() == 2 and m.landed_state == LANDED_ON_GROUND,
        60.0,
        since_s=time.monotonic() + 0.5,
        what="system 2 landed",
    )

    # Both fly at once, each from its own MAVSDK on its own API port; the shared GCS port sees each at its altitude.
    altitudes = ("3", "5")
    t_fly = time.monotonic()
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
    for sysid, alt in zip((1, 2), altitudes, strict=True):
        flown = positions(gcs_peer, sysid, since_s=t_fly)
        assert flown, f"no telemetry from system {sysid} on the shared GCS port"
        peak = -min(m.z for m in flown)
        assert abs(peak - float(alt)) < 0.6, (
            f"system {sysid}: peak {peak:.2f} m, commanded {alt} m ({gcs_peer.lost} lost)"
        )
        assert not is_armed(autopilot_heartbeat(gcs_peer, sysid, since_s=time.monotonic()))
    for v in vehicles:
        assert v.alive, f"{v.name} died\n{v.logs()}"
