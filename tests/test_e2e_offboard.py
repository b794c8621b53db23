"""End to end, MAVSDK-Python 4.x offboard scripts (attitude, velocity) against a `viva-sitl run` subprocess.

These stream setpoints at 20 Hz *wall* time, so they run at no more than 2x: at higher factors a scheduling hiccup on a
loaded machine could starve the vehicle of setpoints for COM_OF_LOSS_T (sim time) and trigger PX4's offboard failsafe.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import pytest
from sitl_process import (
    MODE_OFFBOARD,
    MavlinkPeer,
    SitlProcess,
    assert_landed_disarmed,
    e2e_speed,
    modes_seen,
    run_script,
)

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # slow: offboard flights, ~20 s each


@pytest.fixture
def sitl(sitl_factory: Callable[..., SitlProcess]) -> SitlProcess:
    return sitl_factory(speed=min(e2e_speed(), 2.0))


def test_offboard_attitude_script(sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]) -> None:
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    run = run_script("mavsdk_offboard_attitude.py", [sitl.ports.mavsdk_url, "--timeout", "150"], 180)
    assert run.returncode == 0, run.describe()
    r = {k: float(v) for k, v in run.result.items()}
    assert r["hover_max_dev_m"] < 0.75 and r["tilt_forward_m"] >= 5.0 and r["climb_rate_max_m_s"] > 0.5, r
    assert r["hover_thrust"] == pytest.approx(peer.get_param("MPC_THR_HOVER"), abs=1e-4)

    assert MODE_OFFBOARD in modes_seen(peer)
    # The attitude setpoints reached the airframe: it pitched nose-down to the commanded 8 deg and held it while it
    # travelled (the default airframe gets there in a few tenths of a second: tau = 1/MC_PITCH_P; Hold and Land
    # afterwards correct the drift the lagging attitude left, nose-down too, so the whole flight's minimum is not it)
    held_ms, start_ms = 0, None
    for m in peer.messages("ATTITUDE"):
        if abs(math.degrees(m.pitch) + 8.0) < 0.5:
            start_ms = m.time_boot_ms if start_ms is None else start_ms
            held_ms = max(held_ms, m.time_boot_ms - start_ms)
        else:
            start_ms = None
    assert held_ms >= 1000, f"pitch held at -8 +- 0.5 deg for {held_ms} ms, commanded -8 for the forward leg"
    # ... and flew forward along the initial heading (yaw at takeoff), then climbed above the takeoff altitude.
    positions = peer.messages("LOCAL_POSITION_NED")
    yaw0 = peer.messages("ATTITUDE")[0].yaw
    forward = max(p.x * math.cos(yaw0) + p.y * math.sin(yaw0) for p in positions)
    assert forward > 5.0, f"max forward travel {forward:.2f} m"
    assert min(p.z for p in positions) < -12.0, "never climbed above takeoff altitude + 2 m"
    assert_landed_disarmed(peer)


def test_offboard_velocity_script(sitl: SitlProcess, peer_factory: Callable[[int], MavlinkPeer]) -> None:
    peer = peer_factory(sitl.ports.gcs)
    peer.wait_autopilot()
    run = run_script(
        "mavsdk_offboard_velocity.py",
        [sitl.ports.mavsdk_url, "--side", "8", "--speed", "3", "--timeout", "150"],
        180,
    )
    assert run.returncode == 0, run.describe()
    r = {k: float(v) for k, v in run.result.items()}
    assert r["square_closure_m"] < 1.0 and r["max_cross_track_m"] < 1.5 and r["body_dir_err_deg"] < 10.0, r

    # The square spans 8 m north and 8 m east of the start, at constant altitude, in OFFBOARD.
    xs = [p.x for p in peer.messages("LOCAL_POSITION_NED")]
    ys = [p.y for p in peer.messages("LOCAL_POSITION_NED")]
    assert 7.0 < max(xs) < 9.5 and 7.0 < max(ys) < 9.5, (max(xs), max(ys))
    assert MODE_OFFBOARD in modes_seen(peer)
    # After the body-frame leg (8 m towards start heading + 90 deg) the vehicle lands where the script left it.
    final = (r["final_north_m"], r["final_east_m"])
    yaw0 = peer.messages("ATTITUDE")[0].yaw
    expected = (8.0 * math.cos(yaw0 + math.pi / 2), 8.0 * math.sin(yaw0 + math.pi / 2))
    assert math.hypot(final[0] - expected[0], final[1] - expected[1]) < 1.5, (final, expected)
    assert_landed_disarmed(peer, near=final, tol_m=1.0)
