"""Cost of the virtual PX4's control loop (Autopilot.update) per physics step, and its share of one core at 250 Hz.

    /work/venv/bin/python bench/bench_autopilot.py                # defaults: 5 rounds of 2 s simulated per scenario
    /work/venv/bin/python bench/bench_autopilot.py --rounds 9 --seconds 4

Scenarios (each after a take-off to 5 m, 250 Hz EAV, no disturbance):
    hold          AUTO_LOITER at a fixed point
    mission       AUTO_MISSION flying between two waypoints
    offboard_vel  OFFBOARD velocity setpoints streamed at 20 Hz (set_position_target cost included)
    offboard_att  OFFBOARD attitude + thrust at 50 Hz
    geofence      hold with an `inside` callback (FootageGeometry-like rectangle test, run at 10 Hz)
    fence_poly    hold with an uploaded 64-vertex inclusion polygon + 2 exclusion circles (checked at 10 Hz)
    orbit         ORBIT mode: 15 m radius at 3 m/s (orbit.py setpoint generator)
The EAV step (viva_sitl.dynamics.step) is timed alongside as the reference: the autopilot should cost the same order.
Printed: median µs per update, median µs per EAV step, ratio, and the CPU share at 250 Hz (update µs * 250 / 1e6).
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import time
from collections.abc import Callable

from viva_sitl.autopilot import (
    AttitudeTarget,
    Autopilot,
    FlightMode,
    MissionCommand,
    MissionItem,
    ParamStore,
    PositionTarget,
)
from viva_sitl.autopilot.geofence import CircleFence, Geofence, PolygonFence
from viva_sitl.dynamics import EavCommand, EavParams, EavState, quat_from_euler, step

Setup = Callable[[Autopilot, float], None]
PerStep = Callable[[Autopilot, float, int], None]


def _airborne(inside: Callable[[float, float], bool] | None = None) -> tuple[Autopilot, EavState, EavParams]:
    eav = EavParams()
    ap = Autopilot(ParamStore(), eav, inside=inside)
    s = EavState.at_rest(dt_s=eav.dt_s)
    ap.update(0.0, s)
    ap.arm(0.0)
    ap.takeoff(0.0, 5.0)
    for _ in range(int(8.0 / eav.dt_s)):
        s = step(s, ap.update(s.time_s, s), eav)
    return ap, s, eav


def _mission(ap: Autopilot, now: float) -> None:
    items = [
        MissionItem(0, MissionCommand.NAV_WAYPOINT, 30.0, 0.0, -5.0),
        MissionItem(1, MissionCommand.NAV_WAYPOINT, 0.0, 0.0, -5.0),
    ]
    ap.set_mission(items)
    ap.set_mode(now, FlightMode.AUTO_MISSION)


def _fence_poly(ap: Autopilot, now: float) -> None:
    verts = tuple(
        (200.0 * math.cos(2 * math.pi * i / 64), 200.0 * math.sin(2 * math.pi * i / 64)) for i in range(64)
    )
    circles = (
        CircleFence((50.0, 50.0), 10.0, inclusion=False),
        CircleFence((-50.0, 50.0), 10.0, inclusion=False),
    )
    ap.set_geofence(Geofence(polygons=(PolygonFence(verts),), circles=circles))


def _orbit(ap: Autopilot, now: float) -> None:
    ap.orbit(now, 15.0, 3.0, 0, (10.0, 0.0), None)


def _vel_stream(ap: Autopilot, now: float, k: int) -> None:
    if k % 12 == 0:  # 250 / 12 ~ 20 Hz
        ap.set_position_target(now, PositionTarget(vel_ned_m_s=(1.0, 0.5, 0.0), yaw_rad=0.3))


def _att_stream(ap: Autopilot, now: float, k: int) -> None:
    if k % 5 == 0:  # 50 Hz
        ap.set_attitude_target(now, AttitudeTarget(quat_from_euler(0.02, -0.02, 0.1), None, 0.5))


def _offboard(per_step: PerStep) -> Setup:
    def setup(ap: Autopilot, now: float) -> None:
        per_step(ap, now, 0)
        ap.set_mode(now, FlightMode.OFFBOARD)

    return setup


SCENARIOS: dict[str, tuple[Setup | None, PerStep | None, bool]] = {
    "hold": (None, None, False),
    "mission": (_mission, None, False),
    "offboard_vel": (_offboard(_vel_stream), _vel_stream, False),
    "offboard_att": (_offboard(_att_stream), _att_stream, False),
    "geofence": (None, None, True),
    "fence_poly": (_fence_poly, None, False),
    "orbit": (_orbit, None, False),
}


def run(name: str, seconds: float) -> tuple[float, float]:
    setup, per_step, fence = SCENARIOS[name]
    inside = (lambda n, e: -500.0 < n < 500.0 and -400.0 < e < 400.0) if fence else None
    ap, s, eav = _airborne(inside)
    if setup is not None:
        setup(ap, s.time_s)
    n = int(seconds / eav.dt_s)
    t_ap = t_eav = 0.0
    cmd = EavCommand(0.0, 0.0, 0.0, 0.0)
    for k in range(n):
        t0 = time.perf_counter()
        if per_step is not None:
            per_step(ap, s.time_s, k)
        cmd = ap.update(s.time_s, s)
        t1 = time.perf_counter()
        s = step(s, cmd, eav)
        t2 = time.perf_counter()
        t_ap += t1 - t0
        t_eav += t2 - t1
    ap.pop_events()
    return t_ap / n * 1e6, t_eav / n * 1e6


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per round (250 Hz)")
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, Python {platform.python_version()}")
    print(f"{'scenario':<14} {'update µs':>10} {'EAV step µs':>12} {'ratio':>6} {'CPU @250 Hz':>12}")
    for name in SCENARIOS:
        res = [run(name, args.seconds) for _ in range(args.rounds)]
        up = statistics.median(r[0] for r in res)
        ev = statistics.median(r[1] for r in res)
        print(f"{name:<14} {up:>10.1f} {ev:>12.1f} {up / ev:>6.2f} {up * 250 / 1e6 * 100:>11.2f}%")


if __name__ == "__main__":
    main()
