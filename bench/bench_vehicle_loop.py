"""CPU cost of the vehicle loop per physics step: autopilot.update, the EAV physics, the whole Vehicle.step.

    python bench/bench_vehicle_loop.py                          # this tree
    python bench/bench_vehicle_loop.py --base /tmp/apbase       # before/after, side by side, alternating rounds

Scenarios (synthetic footage, no rendering; 250 Hz): `hover` (air start at 20 m, Hold), `offboard` (a velocity
setpoint stream, re-sent every 12 steps as a 20 Hz MAVLink stream would), `mission` (four waypoints from the air).
Per scenario and round, in thread CPU time (time.thread_time: other processes on a loaded machine do not count):
  step       Vehicle.step over `--steps` steps, per step
  autopilot  autopilot.update alone, replayed on the states of that run by a second, identically set-up vehicle
  physics    Simulator.step alone, replayed on the (state, command) pairs of that run
Each tree runs in its own process (PYTHONPATH = that tree); with --base the trees alternate round by round and the
medians over the rounds are printed with the ratio base/new.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

SCENARIOS = ("hover", "offboard", "mission")


def _setup(name: str) -> tuple[Any, Any]:
    """A fresh vehicle in the scenario and its per-step input hook (called with the step index before the step)."""
    from viva_sitl.autopilot.types import FlightMode, MissionCommand, MissionItem, PositionTarget
    from viva_sitl.vehicle import Vehicle

    v = Vehicle(footage="synthetic", geofence=False)
    v.reset(seed=0, pos_ned_m=(0.0, 0.0, -20.0))
    ap = v.autopilot

    def nothing(i: int) -> None:
        return None

    if name == "hover":
        return v, nothing
    if name == "offboard":
        target = PositionTarget(vel_ned_m_s=(2.0, 1.0, -0.2), yaw_rate_rad_s=0.2)
        ap.set_position_target(v.time_s, target)
        ap.set_mode(v.time_s, FlightMode.OFFBOARD)

        def stream(i: int) -> None:
            if i % 12 == 0:
                ap.set_position_target(v.time_s, target)

        return v, stream
    wps = [(30.0, 0.0), (30.0, 30.0), (0.0, 30.0), (0.0, 0.0)] * 3
    items = [
        MissionItem(
            seq=i, command=MissionCommand.NAV_WAYPOINT, north_m=n, east_m=e, down_m=-20.0, raw_command=16
        )
        for i, (n, e) in enumerate(wps)
    ]
    ap.set_mission(items)
    ap.set_mode(v.time_s, FlightMode.AUTO_MISSION)
    return v, nothing


def measure(name: str, steps: int) -> dict[str, float]:
    v, hook = _setup(name)
    v.step(250)  # settle, warm the caches
    # whole loop
    t0 = time.thread_time()
    for i in range(steps):
        hook(i)
        v.step(1)
    whole = time.thread_time() - t0
    # record the (state, command) pairs of a second run, then replay each half alone
    v, hook = _setup(name)
    v.step(250)
    pairs = []
    ap_update = v.autopilot.update
    for i in range(steps):
        hook(i)
        s = v.state
        cmd = ap_update(s.time_s, s)
        pairs.append((s, cmd))
        v.sim.step(cmd)
    v2, hook2 = _setup(name)
    v2.step(250)
    update = v2.autopilot.update
    t_ap = 0.0
    for i, (s, _) in enumerate(pairs):
        hook2(i)  # (outside the timed call: the MAVLink stream is not the loop's cost)
        t0 = time.thread_time()
        update(s.time_s, s)
        t_ap += time.thread_time() - t0
    sim = v.sim
    t0 = time.thread_time()
    for s, cmd in pairs:
        sim.state = s
        sim.step(cmd)
    phys = time.thread_time() - t0
    v.close()
    v2.close()
    return {"step": whole / steps * 1e6, "autopilot": t_ap / steps * 1e6, "physics": phys / steps * 1e6}


def _timer_overhead_us() -> float:
    t0 = time.thread_time()
    for _ in range(20000):
        time.thread_time()
        time.thread_time()
    return (time.thread_time() - t0) / 20000 * 1e6 / 2


def run_here(steps: int) -> dict[str, Any]:
    out: dict[str, Any] = {name: measure(name, steps) for name in SCENARIOS}
    overhead = _timer_overhead_us()
    for name in SCENARIOS:  # the per-call timing of the autopilot replay includes ~one timer call
        out[name]["autopilot"] = max(0.0, out[name]["autopilot"] - overhead)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, help="a second tree measured side by side (e.g. the base commit)")
    ap.add_argument("--new", type=Path, default=Path(__file__).resolve().parents[1])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--steps", type=int, default=2500)
    ap.add_argument("--json", action="store_true", help="(internal) measure this PYTHONPATH once, print JSON")
    args = ap.parse_args()
    for tree in (args.base, args.new):
        if tree is not None and not (tree / "viva_sitl" / "__init__.py").is_file():
            ap.error(f"{tree} is not a viva-sitl source tree (no viva_sitl/__init__.py)")
    if args.json:
        print(json.dumps(run_here(args.steps)))
        return 0
    trees = [("new", args.new)] + ([("base", args.base)] if args.base else [])
    results: dict[str, list[dict[str, Any]]] = {label: [] for label, _ in trees}
    for _ in range(args.rounds):
        for label, tree in trees:
            env = {**os.environ, "PYTHONPATH": str(tree.resolve()), "OMP_NUM_THREADS": "1"}
            cmd = [sys.executable, __file__, "--json", "--steps", str(args.steps)]
            proc = subprocess.run(cmd, env=env, check=True, capture_output=True, text=True)
            results[label].append(json.loads(proc.stdout.strip().splitlines()[-1]))
    print(f"load average {os.getloadavg()[0]:.2f}; {args.rounds} rounds x {args.steps} steps; us per physics step "
          "(thread CPU time, median of rounds)")  # fmt: skip
    header = f"{'scenario':10s} {'part':10s}" + "".join(f" {label:>8s}" for label, _ in trees)
    print(header + ("  base/new" if args.base else ""))
    for name in SCENARIOS:
        for part in ("autopilot", "physics", "step"):
            med = {label: statistics.median(r[name][part] for r in results[label]) for label, _ in trees}
            row = f"{name:10s} {part:10s}" + "".join(f" {med[label]:8.1f}" for label, _ in trees)
            if args.base:
                row += f"  {med['base'] / med['new']:7.2f}x"
            print(row)
    return 0


if __name__ == "__main__":
    sys.exit(main())
