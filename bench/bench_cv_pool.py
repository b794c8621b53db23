"""The full step over the 4K bench clip's automatic cache under OpenCV's thread-pool settings and the tile decode
threads, each configuration in its own process (OpenCV reads its pool settings once, when it is loaded).

Configurations (`--configs`):
  sleep   what a user gets: viva_sitl sets OPENCV_THREAD_POOL_ACTIVE_WAIT_* = 0 when imported (viva_sitl.opencv_pool)
  spin    OpenCV's own defaults (the variables set to them: PAUSE_LIMIT 16, WORKER 2000, MAIN 10000)
  cv1     cv2.setNumThreads(1): no OpenCV pool at all
each with 1 and 2 tile decode threads (`--decode-threads`). Steps as bench_tiles.py's (bench_core.Ours: 1/30 s of
physics + one 640x480 render per step, hovering at --z), the clip by path under the automatic cache, the decoded-tile
LRU at `--tile-cache-mb` (default 2 MiB: every frame decoded, as over a long clip). Prints one line per
configuration and a markdown table; `--json` keeps the figures. No reference here: bench_tiles.py times the same step
against viva-safeland in the same rounds.

    python bench/bench_cv_pool.py --z 50 300 --rounds 5
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

SPIN = {  # OpenCV's defaults (modules/core/src/parallel_impl.cpp)
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_PAUSE_LIMIT": "16",
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER": "2000",
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN": "10000",
}
CONFIGS = ("sleep", "spin", "cv1")


def child(args: argparse.Namespace) -> None:
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import bench_core as core  # imports viva_sitl before cv2, as a user's program would
    import cv2

    from viva_sitl.footage import autocache

    if args.child == "cv1":
        cv2.setNumThreads(1)
    clip = core.make_clip(args.cache_dir, args.frames)
    autocache.set_policy(autocache.CachePolicy(root=args.cache_dir / "tiles-auto", show_progress=False))
    core.apply_tile_environment()
    ns = argparse.Namespace(
        out_size="640x480", rel_alt=core.DEFAULT_REL_ALT_M, z=args.z[0], yaw_deg=30.0, steps=args.steps
    )
    ours = core.Ours(clip, ns, paper=False, render=True)
    try:
        ours.run()  # warm-up: packs into the page cache, buffers allocated
        runs = [ours.run() for _ in range(args.rounds)]
    finally:
        ours.sim.close()
    print(json.dumps({"steps_per_s": statistics.median(r[0] for r in runs),
                      "cpu_ms_per_step": statistics.median(r[1] for r in runs),
                      "runs": runs, "cv2_threads": cv2.getNumThreads()}))  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--z", type=float, nargs="+", default=[50.0, 300.0])
    ap.add_argument("--configs", nargs="+", choices=CONFIGS, default=list(CONFIGS))
    ap.add_argument("--decode-threads", type=int, nargs="+", default=[2, 1])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--steps", type=int, default=120)
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--tile-cache-mb", type=float, default=2.0)
    ap.add_argument("--cache-dir", type=Path, default=Path("/tmp/viva-sitl-bench"))
    ap.add_argument("--json", type=Path)
    ap.add_argument("--child", choices=CONFIGS, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args)
        return 0
    from viva_sitl import opencv_pool

    base = opencv_pool.user_environ()  # a fresh shell's environment (no OPENCV_* set by this process)
    rows: list[dict[str, Any]] = []
    for z in args.z:
        for cfg in args.configs:
            for threads in args.decode_threads:
                env = dict(base, VIVA_SITL_TILE_CACHE_MB=f"{args.tile_cache_mb:g}",
                           VIVA_SITL_TILE_DECODE_THREADS=str(threads), **(SPIN if cfg == "spin" else {}))  # fmt: skip
                cmd = [sys.executable, __file__, "--child", cfg, "--z", f"{z:g}", "--rounds", str(args.rounds),
                       "--steps", str(args.steps), "--frames", str(args.frames), "--cache-dir", str(args.cache_dir)]  # fmt: skip
                t0 = time.perf_counter()
                out = subprocess.run(cmd, env=env, capture_output=True, text=True)
                if out.returncode != 0:
                    print(out.stderr, file=sys.stderr)
                    raise SystemExit(
                        f"bench_cv_pool: the {cfg} child at {z:g} m failed (exit {out.returncode})"
                    )
                res = json.loads(out.stdout.strip().splitlines()[-1])
                row = {"z": z, "config": cfg, "decode_threads": threads, **res,
                       "load": os.getloadavg()[0], "wall_s": time.perf_counter() - t0}  # fmt: skip
                rows.append(row)
                print(f"z {z:g} m  {cfg:5s} decode {threads}: {res['steps_per_s']:7.1f} steps/s  "
                      f"{res['cpu_ms_per_step']:.2f} ms CPU/step  (load {row['load']:.2f})", file=sys.stderr)  # fmt: skip
    print("| z | OpenCV pool | decode threads | steps/s | CPU ms/step |\n|---|---|---:|---:|---:|")
    for r in rows:
        print(f"| {r['z']:g} m | {r['config']} | {r['decode_threads']} | {r['steps_per_s']:.1f} | "
              f"{r['cpu_ms_per_step']:.2f} |")  # fmt: skip
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
