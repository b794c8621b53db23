"""Per-view render cost over ONE decoded footage frame: what each copy of a vector env pays on top of the shared decode.

    /work/venv/bin/python bench/bench_views.py
    /work/venv/bin/python bench/bench_views.py --base /tmp/base-worktree --rounds 6 --cv-threads 1

One Simulator over the 4K bench clip of bench_core.py (video), footage frame 0 decoded once, renders --views views
(640x480 by default) at --z m, each at its own drawn north/east (+-40 m) and yaw, in turn, --reps times: each render
plans its region, converts that crop of the decoded frame, fills the region buffers and warps (no decode, no
physics). Prints wall and CPU ms per view (median of --rounds runs, each in its own process). With --base (a
worktree of another commit, with ../shared beside it like this checkout) the two trees run in alternating processes
in the same rounds, and the ratio new / base is printed: the way to see a change of a few percent on a noisy
machine. CPU > wall: OpenCV's warp runs on its worker threads too (`--cv-threads 1` to see one thread's cost).
`--split` (this tree only) times the two halves of each render apart: the region (plan, crop conversion, buffer
fill: `Simulator._region_pyramid`) and the warp (`Renderer.render` over that region).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

from bench_core import size_arg  # noqa: E402

CHILD = r"""
import json, sys, time
repo, views, reps, z, size, cv_threads = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), float(sys.argv[4]), sys.argv[5], int(sys.argv[6])
split = sys.argv[7] == "1"
sys.path.insert(0, repo); sys.path.insert(0, repo + "/bench")
from dataclasses import replace
import cv2
import numpy as np
if cv_threads > 0:
    cv2.setNumThreads(cv_threads)
import bench_core as core
from viva_sitl.camera import CameraParams
from viva_sitl.footage import open_footage
from viva_sitl.sim import SimConfig, Simulator
clip = core.make_clip(core.DEFAULT_CACHE, 60, rel_alt_m=core.DEFAULT_REL_ALT_M)
w, h = (int(v) for v in size.lower().split("x"))
sim = Simulator(SimConfig(camera=CameraParams(width_px=w, height_px=h)), footage=open_footage(str(clip)))
rng = np.random.default_rng(0)
poses = [(np.array([rng.uniform(-40, 40), rng.uniform(-40, 40), -z]), np.array([0.0, 0.0, rng.uniform(-3.1, 3.1)]))
         for _ in range(views)]
sim.reset(seed=0)
def once():
    for pos, att in poses:
        sim.render(replace(sim.state, pos_ned_m=pos, att_rpy_rad=att, time_s=0.0), wall_time_s=0.0)
for _ in range(3):
    once()
n = reps * views
if split:
    states = [replace(sim.state, pos_ned_m=pos, att_rpy_rad=att, time_s=0.0) for pos, att in poses]
    index = sim.footage.frame_index_at(0.0)
    acc = [0.0, 0.0, 0.0, 0.0]  # region wall, region CPU, warp wall, warp CPU
    for _ in range(reps):
        for s in states:
            c0, t0 = time.process_time(), time.perf_counter()
            planned = sim._region_pyramid(index, s)
            if planned is None:
                sys.exit(f"--split: the view at {s.pos_ned_m.tolist()} renders from the whole frame, not a region")
            c1, t1 = time.process_time(), time.perf_counter()
            sim.renderer.render(planned[0], s.pos_ned_m, s.att_rpy_rad, s.vel_ned_m_s, sim.camera_rng)
            c2, t2 = time.process_time(), time.perf_counter()
            acc = [acc[0] + t1 - t0, acc[1] + c1 - c0, acc[2] + t2 - t1, acc[3] + c2 - c1]
    print(json.dumps([1e3 * (acc[0] + acc[2]) / n, 1e3 * (acc[1] + acc[3]) / n] + [1e3 * a / n for a in acc]))
else:
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in range(reps):
        once()
    print(json.dumps([1e3 * (time.perf_counter() - t0) / n, 1e3 * (time.process_time() - c0) / n]))
sim.close()
"""


def run(repo: Path, args: argparse.Namespace) -> list[float]:
    out = subprocess.run(
        [sys.executable, "-c", CHILD, str(repo), str(args.views), str(args.reps), str(args.z), args.image_size,
         str(args.cv_threads or 0), "1" if args.split else "0"],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    if out.returncode != 0:
        tail = (out.stderr.strip().splitlines() or ["no output"])[-1]
        raise SystemExit(f"bench_views.py: the run in {repo} failed: {tail}")
    return [float(v) for v in json.loads(out.stdout.strip().splitlines()[-1])]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--base", type=Path, default=None, help="a worktree of another commit to compare with")
    ap.add_argument("--views", type=int, default=8)
    ap.add_argument("--reps", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--z", type=float, default=50.0)
    ap.add_argument("--image-size", type=size_arg, default="640x480")
    ap.add_argument("--cv-threads", type=int, default=None, help="cv2.setNumThreads in the runs")
    ap.add_argument("--split", action="store_true", help="also time region (plan, crop, fill) and warp apart")
    args = ap.parse_args()
    if args.base is not None and not (args.base / "viva_sitl").is_dir():
        ap.error(f"--base {args.base} is not a viva-sitl checkout")
    if args.base is not None and args.split:
        ap.error("--split times this tree only (it calls Simulator internals): leave out --base")
    trees = {"new": REPO} if args.base is None else {"base": args.base, "new": REPO}
    res: dict[str, list[list[float]]] = {k: [] for k in trees}
    try:
        for r in range(args.rounds):
            load = " ".join(f"{v:.2f}" for v in os.getloadavg())
            for k, tree in trees.items():
                res[k].append(run(tree, args))
            print(f"# round {r + 1}/{args.rounds} load {load}: "
                  + ", ".join(f"{k} {v[-1][0]:.3f} / {v[-1][1]:.3f} ms" for k, v in res.items()), file=sys.stderr)  # fmt: skip
    except KeyboardInterrupt:
        print("bench_views.py: interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    print(f"{args.views} views of {args.image_size} at z {args.z} m over one decoded 4K frame, {args.reps} reps, "
          f"{args.rounds} rounds, {os.cpu_count()} cores")  # fmt: skip
    if args.split:
        print("| tree | wall ms / view | CPU ms / view | region wall | region CPU | warp wall | warp CPU |\n"
              "|---|---:|---:|---:|---:|---:|---:|")  # fmt: skip
    else:
        print("| tree | wall ms / view | CPU ms / view |\n|---|---:|---:|")
    for k, v in res.items():
        print(
            f"| {k} | "
            + " | ".join(f"{statistics.median(r[j] for r in v):.3f}" for j in range(len(v[0])))
            + " |"
        )
    if args.base is not None:
        rw = statistics.median(n[0] / b[0] for n, b in zip(res["new"], res["base"], strict=True))
        rc = statistics.median(n[1] / b[1] for n, b in zip(res["new"], res["base"], strict=True))
        print(f"\nnew / base, median of the per-round ratios: wall {rw:.3f}, CPU {rc:.3f}")


if __name__ == "__main__":
    main()
