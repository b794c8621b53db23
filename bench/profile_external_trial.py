"""Where the wall time of one external lockstep trial goes (issue 19's speed target): phases from this process's
view of `viva-sitl run` and the pilot, and the vehicle's own timing record.

    nice -n 5 .venv/bin/python bench/profile_external_trial.py --speed 16 --n 2

The pilot is mission_scripts/mavsdk_precision_land.py, unchanged, on the scenarios of bench/bench_trials_external.py
(ground start, seed 3). Per trial (one at a time, in this process, as a campaign worker runs it):
    sitl_ready_s      `viva-sitl run` started -> its ready line (imports, world, footage, sockets)
    pilot_connect_s   the pilot started -> its first MAVLink message reached the vehicle (the script's imports,
                      mavsdk_server's start, discovery; pilot_wait_wall_s of the vehicle's stop stats in sitl.log)
    flight_s          the rest until the trial-end line: the quanta, split into gate_s (the clock stood still for the
                      pilot: end.json timing.busy_wall_s) and clock_s (the sim time / speed and the physics)
    pilot_exit_s      trial-end line -> the script exited by itself (it waits for the disarm)
    stop_s            -> both process groups stopped and the row scored (the rest of run_external_trial)
    children_cpu_s    CPU seconds of the trial's processes (viva-sitl run, the script, its mavsdk_server)
Prints a JSON report.
"""

from __future__ import annotations

import argparse
import json
import re
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

PILOT = "{python} mission_scripts/mavsdk_precision_land.py {mavsdk_url} --north 8 --east 5 --altitude 10"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--speed", type=float, default=16.0)
    ap.add_argument("--n", type=int, default=2)
    ap.add_argument("--timing", default="lockstep")
    a = ap.parse_args()

    from viva_sitl.evaluation import external
    from viva_sitl.evaluation.campaign import run_one
    from viva_sitl.evaluation.spec import draw_scenarios, spec_from_dict

    marks: dict[str, float] = {}
    real_start = external._start
    real_run = external._Pump.run

    def start(cmd: list[str], *args: Any, **kw: Any) -> subprocess.Popen[bytes]:
        marks["pilot_start" if "mission_scripts" in " ".join(cmd) else "sitl_start"] = time.perf_counter()
        p = real_start(cmd, *args, **kw)
        if "mission_scripts" in " ".join(cmd):

            def waiter() -> None:
                p.wait()
                marks.setdefault("pilot_exit", time.perf_counter())

            import threading

            threading.Thread(target=waiter, daemon=True).start()
        return p

    def pump_run(self: Any) -> None:
        set_event = self.event.set

        def mark() -> None:
            for w in self.watch:
                if w in self.hits:
                    marks.setdefault(w, time.perf_counter())
            set_event()

        self.event.set = mark  # type: ignore[method-assign]
        real_run(self)

    external._start = start  # type: ignore[assignment]
    external._Pump.run = pump_run  # type: ignore[method-assign]
    spec = spec_from_dict(
        {"trials": {"name": "ext-profile", "n": a.n, "seed": 3, "timeout_s": 150.0, "speed": a.speed,
                    "timing": a.timing},
         "scenario": {"footage": "synthetic", "start": "ground", "north_m": [-30.0, 30.0], "east_m": [-30.0, 30.0],
                      "altitude_m": 10.0, "yaw_deg": [0.0, 360.0], "land_at_s": 149.0}},
        "ext-profile",
    )  # fmt: skip
    trials = []
    with tempfile.TemporaryDirectory(prefix="viva-extprof-") as d:
        for sc in draw_scenarios(spec):
            marks.clear()
            r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
            t0 = time.perf_counter()
            row = run_one(spec, sc, PILOT, Path(d), 0, False)
            t_end = time.perf_counter()
            r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
            end = json.loads((Path(d) / "trials" / f"{sc.index:04d}" / "end.json").read_text())
            tm = end.get("timing") or {}
            ready = marks.get(external.READY_PREFIX, t0)
            trial_line = marks.get(external.TRIAL_PREFIX, t_end)
            sitl_log = (Path(d) / "trials" / f"{sc.index:04d}" / "sitl.log").read_text(errors="replace")
            found = re.search(r"pilot_wait_wall_s\W+([0-9.]+)", sitl_log)  # in `viva-sitl run`'s stop stats
            connect = float(found.group(1)) if found else float("nan")
            flight = trial_line - marks.get("pilot_start", ready) - connect
            gate = float(tm.get("busy_wall_s") or 0.0)
            trials.append({
                "trial": sc.index, "end": row["end"], "wall_s": round(t_end - t0, 3),
                "setup_s": round(marks.get("sitl_start", t0) - t0, 3),
                "sitl_ready_s": round(ready - marks.get("sitl_start", t0), 3),
                "pilot_connect_s": connect, "flight_s": round(flight, 3), "gate_s": round(gate, 3),
                "clock_s": round(flight - gate, 3), "sim_s": row.get("end_t_s"), "quanta": tm.get("quanta"),
                "pilot_cpu_s": tm.get("pilot_cpu_s"),
                "pilot_exit_s": round(marks.get("pilot_exit", trial_line) - trial_line, 3),
                "stop_s": round(t_end - max(marks.get("pilot_exit", trial_line), trial_line), 3),
                "children_cpu_s": round(r1.ru_utime + r1.ru_stime - r0.ru_utime - r0.ru_stime, 3),
            })  # fmt: skip
            print(json.dumps(trials[-1]), file=sys.stderr, flush=True)
    keys = [k for k in trials[0] if k.endswith("_s") and k != "sim_s"]
    report = {"speed": a.speed, "timing": a.timing, "trials": trials,
              "median": {k: round(statistics.median(float(t[k] or 0.0) for t in trials), 3) for k in keys}}  # fmt: skip
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
