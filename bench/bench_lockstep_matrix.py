"""Do lockstep / charged trial rows depend on the machine's load, the job count or the run? (issue 19, section 3)

    nice -n 5 .venv/bin/python bench/bench_lockstep_matrix.py --pilots pymavlink frame --n 12
    nice -n 5 .venv/bin/python bench/bench_lockstep_matrix.py --pilots frame --n 4 --loads 0 2 --jobs 1 2 --runs 1
    nice -n 5 .venv/bin/python bench/bench_lockstep_matrix.py --pilots frame --n 4 --charged 1 2

Each pilot flies the same N scenarios (synthetic field, air start at 8-10 m, "land now" at 1-2 s, seed 7) under
every condition {busy loops} x {--jobs} x {run}; the busy loops are `while True: pass` processes this script starts
and kills by pid (the machine's load). The first condition is the reference; every other one is compared with it:
    identical   rows_equal: every column but the measured ones (wall_s, pilot_cpu_s, pilot_run_delay_s)
    same end    the same `end` and `success` in every trial
    max |dtd|   the largest touchdown-point difference (m), and the largest time-to-land difference (s)
Pilots (real programs, real processes, as `trials run --pilot` runs them):
    pymavlink   tests/pilots/pymavlink_busy.py: starts with wait_heartbeat(), one setpoint per LOCAL_POSITION_NED,
                5-15 ms of CPU each (seeded)
    frame       tests/pilots/frame_busy.py: the frame-and-pose socket, --frame-ms (default 50-300) ms of CPU per
                frame (seeded), every frame
    mavsdk      mission_scripts/mavsdk_precision_land.py (MAVSDK, its own wall-clock timers; ground start)
--charged F1 F2 instead runs each pilot quiet at jobs 1 in charged timing with each factor and reports the mean time
to land, touchdown and the reaction to "land now" (sim s until its first command took effect) per factor. Prints a
JSON report.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

PILOTS = {
    "pymavlink": ("{python} " + str(REPO / "tests/pilots/pymavlink_busy.py") + " {pymavlink_url} 5,15", False),
    "frame": ("{python} " + str(REPO / "tests/pilots/frame_busy.py") + " {pymavlink_url} {frame_socket} FRAME_MS", True),
    "mavsdk": (
        "{python} " + str(REPO / "mission_scripts/mavsdk_precision_land.py")
        + " {mavsdk_url} --north 8 --east 5 --altitude 10",
        False,
    ),
}  # fmt: skip


def spec_for(pilot: str, n: int, timing: str, factor: float, speed: float, frames: bool) -> Any:
    from viva_sitl.evaluation.spec import spec_from_dict

    scenario: dict[str, Any] = {"footage": "synthetic", "north_m": [-20.0, 20.0], "east_m": [-20.0, 20.0]}
    if pilot == "mavsdk":  # it takes off itself and lands on its own
        scenario.update(start="ground", altitude_m=10.0, yaw_deg=[0.0, 360.0], land_at_s=149.0)
    else:
        scenario.update(start="air", altitude_m=[8.0, 10.0], land_at_s=[1.0, 2.0])
    return spec_from_dict(
        {"trials": {"name": f"matrix-{pilot}", "n": n, "seed": 7, "timeout_s": 150.0, "speed": speed,
                    "timing": timing, "pilot_cpu_factor": factor, "frames": frames},
         "scenario": scenario},
        "matrix",
    )  # fmt: skip


@contextmanager
def busy_loops(n: int) -> Iterator[None]:
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for p in procs:
            p.kill()
            p.wait(5)


def fly(spec: Any, cmd: str, jobs: int, busy: int) -> tuple[list[dict[str, Any]], float]:
    """The campaign's rows (each with `_reaction_s`: sim seconds from "land now" to the pilot's first command taking
    effect, from its end.json) and its wall time."""
    from viva_sitl.evaluation.campaign import run_campaign

    with tempfile.TemporaryDirectory(prefix="viva-matrix-") as d, busy_loops(busy):
        t0 = time.perf_counter()
        camp = run_campaign(spec, cmd, Path(d) / "o", jobs=jobs, progress=False)
        wall = time.perf_counter() - t0
        rows = camp.ordered_rows()
        for r in rows:
            try:
                end = json.loads((Path(d) / "o" / "trials" / f"{r['trial']:04d}" / "end.json").read_text())
                r["_reaction_s"] = round(end["reaction_t_s"] - end["land_now_t_s"], 4)
            except (OSError, KeyError, TypeError, ValueError):
                r["_reaction_s"] = None
        return rows, wall


def compare(ref: list[dict[str, Any]], rows: list[dict[str, Any]]) -> dict[str, Any]:
    from viva_sitl.evaluation.campaign import rows_equal

    def num(r: dict[str, Any], k: str) -> float:
        v = r.get(k)
        return float(v) if isinstance(v, (int, float)) else float("nan")

    dtd = [
        ((num(a, "touchdown_north_m") - num(b, "touchdown_north_m")) ** 2
         + (num(a, "touchdown_east_m") - num(b, "touchdown_east_m")) ** 2) ** 0.5
        for a, b in zip(ref, rows, strict=True)
    ]  # fmt: skip
    dt = [abs(num(a, "time_to_land_s") - num(b, "time_to_land_s")) for a, b in zip(ref, rows, strict=True)]
    finite = [x for x in dtd if x == x]
    finite_t = [x for x in dt if x == x]
    return {
        "identical": rows_equal(ref, rows),
        "same_end_success": all(
            (a["end"], a["success"]) == (b["end"], b["success"]) for a, b in zip(ref, rows, strict=True)
        ),
        "max_touchdown_diff_m": round(max(finite), 6) if finite else None,
        "max_time_to_land_diff_s": round(max(finite_t), 4) if finite_t else None,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--pilots", nargs="+", choices=sorted(PILOTS), default=["pymavlink", "frame"])
    ap.add_argument("--n", type=int, default=12)
    ap.add_argument("--loads", type=int, nargs="+", default=[0, 2, 4], help="busy loops per condition")
    ap.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--runs", type=int, default=2)
    ap.add_argument("--speed", type=float, default=4.0)
    ap.add_argument("--timing", choices=["lockstep", "charged"], default="lockstep")
    ap.add_argument("--factor", type=float, default=1.0, help="--pilot-cpu-factor for --timing charged")
    ap.add_argument("--frame-ms", default="50,300", help="the frame pilot's CPU per frame, LO,HI ms")
    ap.add_argument(
        "--charged", type=float, nargs=2, metavar=("F1", "F2"), help="compare two CPU factors instead"
    )
    args = ap.parse_args()
    report: dict[str, Any] = {
        "machine": f"{platform.node()} {platform.machine()} python {platform.python_version()}",
        "argv": sys.argv[1:],
        "pilots": {},
    }
    for pilot in args.pilots:
        template, frames = PILOTS[pilot]
        cmd = template.replace("FRAME_MS", args.frame_ms)
        if args.charged:
            out: dict[str, Any] = {}
            for f in args.charged:
                rows, wall = fly(spec_for(pilot, args.n, "charged", f, args.speed, frames), cmd, 1, 0)
                ttl = [r["time_to_land_s"] for r in rows if isinstance(r.get("time_to_land_s"), (int, float))]
                out[f"factor {f:g}"] = {
                    "ends": [r["end"] for r in rows], "wall_s": round(wall, 1),
                    "mean_time_to_land_s": round(sum(ttl) / len(ttl), 3) if ttl else None,
                    "time_to_land_s": ttl, "charged_cpu_s": [r.get("pilot_cpu_s") for r in rows],
                    "reaction_s": [r["_reaction_s"] for r in rows],
                }  # fmt: skip
                print(pilot, f, json.dumps(out[f"factor {f:g}"]), flush=True)
            report["pilots"][pilot] = out
            continue
        spec = spec_for(pilot, args.n, args.timing, args.factor, args.speed, frames)
        ref: list[dict[str, Any]] | None = None
        conds = []
        for busy in args.loads:
            for jobs in args.jobs:
                for run in range(args.runs):
                    rows, wall = fly(spec, cmd, jobs, busy)
                    c: dict[str, Any] = {"busy_loops": busy, "jobs": jobs, "run": run, "wall_s": round(wall, 1),
                                         "ends": sorted({r["end"] for r in rows}),
                                         "timing_ok": sum(r.get("timing_ok") is True for r in rows)}  # fmt: skip
                    if ref is None:
                        ref = rows
                        c["reference"] = True
                    else:
                        c.update(compare(ref, rows))
                    conds.append(c)
                    print(pilot, json.dumps(c), flush=True)
        report["pilots"][pilot] = conds
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
