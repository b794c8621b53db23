"""Where one in-process 60 s landing trial spends its time: bench_trials.py's VisionDescend over the 4K bench clip.

    nice -n 10 /work/venv/bin/python bench/profile_trial.py                       # from the video (H.264)
    nice -n 10 /work/venv/bin/python bench/profile_trial.py --footage /tmp/viva-sitl-bench/interchange_3840x2160_60f_tiles_jpeg

Runs `run_inprocess_trial` once under cProfile (after one warm-up trial that opens the footage and fills caches,
as a pool worker's later trials see them) and sums the profile into stages by the functions that own them
(inclusive time of the stage's entry points, so a stage's figure contains what it calls; stages do not overlap by
construction of the list below). The profiler clock is the main thread's CPU time (thread_time), so shares hold on
a loaded machine; CPU spent in other threads (PyAV's frame threads, the tile decode pool) is reported apart.
Prints a JSON report: wall, CPU, and per stage seconds, share and ms per call (profiling inflates the Python parts).
"""

from __future__ import annotations

import argparse
import cProfile
import json
import os
import pstats
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

# stage -> (file suffix, function name) entry points; inclusive times summed (none calls another listed one)
STAGES: dict[str, list[tuple[str, str]]] = {
    "footage region: decode + colour conversion + crop + pyramid": [("viva_sitl/sim.py", "_region_pyramid")],
    "render planning (homographies, footprint)": [("viva_sitl/sim.py", "_plan_region")],
    "warp (cv2.warpPerspective + AA)": [("camera/renderer.py", "render")],
    "physics 250 Hz (EAV + wind)": [("viva_sitl/sim.py", "step")],
    "autopilot 250 Hz (modes, position/velocity/attitude control, failsafes)": [("autopilot/autopilot.py", "update")],
    "trial monitor (events, trajectory log)": [("evaluation/monitor.py", "after_step")],
    "pilot act (mean of the frame)": [("bench/bench_trials.py", "act")],
    "scoring + log write": [("evaluation/scoring.py", "score_trial"), ("evaluation/monitor.py", "write")],
}  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--footage", default=None, help="footage (default: the 4K bench clip from bench_core)")
    ap.add_argument("--top", type=int, default=25, help="also list the top N functions by own time")
    args = ap.parse_args()
    from bench.bench_core import DEFAULT_CACHE, make_clip
    from bench.bench_trials import bench_spec
    from viva_sitl.evaluation.runner import run_inprocess_trial
    from viva_sitl.evaluation.spec import draw_scenarios

    footage = Path(args.footage) if args.footage else make_clip(DEFAULT_CACHE, 60)
    spec = bench_spec(footage, 2)
    sc = draw_scenarios(spec)
    with tempfile.TemporaryDirectory() as d:
        run_inprocess_trial(spec, sc[0], "bench.bench_trials:VisionDescend", Path(d) / "warm")
        prof = cProfile.Profile(time.thread_time)  # this thread's CPU: shares hold on a loaded machine
        w0, c0, m0 = time.perf_counter(), time.process_time(), time.thread_time()
        prof.enable()
        row = run_inprocess_trial(spec, sc[1], "bench.bench_trials:VisionDescend", Path(d) / "t")
        prof.disable()
        wall, cpu = time.perf_counter() - w0, time.process_time() - c0
        main_cpu = time.thread_time() - m0
    st = pstats.Stats(prof)
    raw: dict[Any, Any] = st.stats  # type: ignore[attr-defined]
    total = sum(v[2] for v in raw.values())  # own times: the profiled total
    stages: dict[str, Any] = {}
    for stage, entries in STAGES.items():
        t = 0.0
        calls = 0
        for (file, _line, func), (_cc, nc, _tt, ct, _callers) in raw.items():
            if any(file.endswith(suf) and func == fn for suf, fn in entries):
                t += ct
                calls += nc
        stages[stage] = {"s": round(t, 3), "share": round(t / total, 3), "calls": calls,
                         "ms_per_call": round(1000 * t / calls, 3) if calls else None}  # fmt: skip
    stages["other threads (PyAV frame threads / tile decode pool)"] = {
        "s": round(cpu - main_cpu, 3), "share_of_process_cpu": round((cpu - main_cpu) / cpu, 3)}  # fmt: skip
    top = sorted(raw.items(), key=lambda kv: kv[1][2], reverse=True)[: args.top]
    res = {
        "footage": str(footage), "sim_s": row["end_t_s"], "end": row["end"], "wall_s": round(wall, 2),
        "cpu_s": round(cpu, 2), "main_thread_cpu_s": round(main_cpu, 2), "profiled_s": round(total, 2), "load_avg": os.getloadavg(), "stages": stages,
        "top_own_time": [{"fn": f"{Path(k[0]).name}:{k[1]}:{k[2]}", "own_s": round(v[2], 3), "calls": v[1]}
                         for k, v in top],
    }  # fmt: skip
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
