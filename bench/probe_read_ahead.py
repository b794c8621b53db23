"""Why the tile read-ahead helps where it does (bench/results_tiles.md, session 19): three probes over the 4K bench
clip's automatic cache, the full step of bench_core.Ours (1/30 s of physics + one 640x480 render, hovering at --z,
yaw 30 deg/s), the decoded-tile LRU at 2 MiB (every frame decoded), 2 decode threads.

  --phases         ms per step in the physics, the footage region read (decode + paste), the warp(s), the rest of
                   the render; read-ahead off (the split it has to work with)
  --done-fraction  with read-ahead on and never paused: of each job, the fraction of its tiles the worker had
                   decoded when the region came, as a histogram (quarters)
  --gil            one thread decoding the region's level-0 tiles (us per tile) alone, beside a thread running
                   OpenCV's 2-thread warp, and beside a thread running pure Python (the GIL is handed over only
                   at the switch interval, 5 ms)

    python bench/probe_read_ahead.py --phases --done-fraction --gil --codecs yuv420z yuv420zg --z 50 300
"""

from __future__ import annotations

import argparse
import collections
import os
import statistics
import sys
import threading
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
os.environ.setdefault("VIVA_SITL_TILE_CACHE_MB", "2")
os.environ["VIVA_SITL_TILE_DECODE_THREADS"] = "2"
import bench_core as core  # noqa: E402 - imports viva_sitl before cv2, as a user's program would


def _ours(args: argparse.Namespace, codec: str, z: float, read_ahead: bool) -> Any:
    from viva_sitl.footage import autocache

    os.environ["VIVA_SITL_TILE_READ_AHEAD"] = "1" if read_ahead else "0"
    clip = core.make_clip(args.cache_dir, 60)
    autocache.set_policy(
        autocache.CachePolicy(root=args.cache_dir / "tiles-auto", show_progress=False, codec=codec)
    )
    core.apply_tile_environment()
    step = argparse.Namespace(
        out_size="640x480", rel_alt=core.DEFAULT_REL_ALT_M, z=z, yaw_deg=30.0, steps=240
    )
    return core.Ours(clip, step, paper=False, render=True)


def phases(args: argparse.Namespace, codec: str, z: float) -> None:
    import cv2

    import viva_sitl.camera.renderer as renderer

    ours = _ours(args, codec, z, read_ahead=False)
    acc = dict.fromkeys(("physics", "region", "warp", "render"), 0.0)
    src = ours.sim.footage
    region, warp = src.region, cv2.warpPerspective

    def timed(fn: Any, key: str) -> Any:
        def call(*a: Any, **k: Any) -> Any:
            t = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                acc[key] += time.perf_counter() - t

        return call

    src.region = timed(region, "region")
    renderer.cv2.warpPerspective = timed(warp, "warp")
    try:
        ours.run()  # warm-up
        for key in acc:
            acc[key] = 0.0
        sim, n = ours.sim, 0
        for _ in range(3):
            sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -z), yaw_rad=ours.yaw_rad)
            sim.render()
            for k in ours.schedule:
                t0 = time.perf_counter()
                sim.step(ours.cmd, k)
                t1 = time.perf_counter()
                sim.render()
                acc["physics"] += t1 - t0
                acc["render"] += time.perf_counter() - t1
                n += 1
    finally:
        renderer.cv2.warpPerspective = warp
        ours.sim.close()
    rest = acc["render"] - acc["region"] - acc["warp"]
    print(f"phases  {codec:8s} {z:5g} m: physics {acc['physics'] / n * 1e3:.3f}  region {acc['region'] / n * 1e3:.3f}"
          f"  warp {acc['warp'] / n * 1e3:.3f}  rest of render {rest / n * 1e3:.3f}  ms per step")  # fmt: skip


def done_fraction(args: argparse.Namespace, codec: str, z: float) -> None:
    from viva_sitl.footage.tiles import read

    ours = _ours(args, codec, z, read_ahead=True)
    fractions: list[float] = []
    take = read.TileCache._take_ahead
    window = read.AHEAD_WINDOW

    def watched(self: Any, frame: int, level: int, bgra: bool) -> Any:
        job = self._ahead.get(level)
        if job is not None and job.frame == frame and job.bgra == bgra:
            fractions.append(len(job.done) / job.total)
        return take(self, frame, level, bgra)

    read.TileCache._take_ahead = watched  # type: ignore[method-assign]
    read.AHEAD_WINDOW = 1 << 30  # never judged: never paused
    try:
        ours.run()
        fractions.clear()
        runs = [ours.run() for _ in range(3)]
    finally:
        read.TileCache._take_ahead = take  # type: ignore[method-assign]
        read.AHEAD_WINDOW = window
        ours.sim.close()
    quarters = collections.Counter(min(int(f * 4), 3) for f in fractions)
    print(f"done    {codec:8s} {z:5g} m: {statistics.median(r[0] for r in runs):7.1f} steps/s never paused; "
          f"{len(fractions)} jobs, done when the region came 0-25 / 25-50 / 50-75 / 75-100 %: "
          + " / ".join(str(quarters[q]) for q in range(4)))  # fmt: skip


def gil(args: argparse.Namespace, codec: str) -> None:
    import cv2
    import numpy as np

    from viva_sitl.footage.tiles.format import _decode

    ours = _ours(args, codec, 50.0, read_ahead=False)
    try:
        ours.run()
        cache = ours.sim.footage.cache
        nx, ny = cache.layout.grid[0]
        blobs = [
            cache._read(10, 0, tx, ty)
            for tx in range(nx // 2 - 2, nx // 2 + 2)
            for ty in range(ny // 2 - 1, ny // 2 + 2)
        ]
    finally:
        ours.sim.close()

    def per_tile() -> float:
        times = []
        for _ in range(20):
            for b in blobs:
                t = time.perf_counter()
                _decode(b, codec, True)
                times.append(time.perf_counter() - t)
        return statistics.median(times) * 1e6

    src = np.random.default_rng(0).integers(0, 255, (1000, 1000, 4), dtype=np.uint8)
    m = np.array([[0.6, 0.3, 100.0], [-0.3, 0.6, 300.0], [0.0, 0.0, 1.0]])
    out = np.empty((480, 640, 4), np.uint8)
    line = f"gil     {codec:8s}: decode alone {per_tile():.1f} us/tile"
    for kind in ("an OpenCV warp", "pure Python"):
        stop = threading.Event()

        def busy(kind: str = kind, stop: threading.Event = stop) -> None:
            while not stop.is_set():
                if kind == "pure Python":
                    sum(i * i for i in range(2000))
                else:
                    cv2.warpPerspective(src, m, (640, 480), dst=out, flags=cv2.WARP_INVERSE_MAP)

        th = threading.Thread(target=busy)
        th.start()
        try:
            line += f", beside {kind} {per_tile():.1f}"
        finally:
            stop.set()
            th.join()
    print(line)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--phases", action="store_true")
    ap.add_argument("--done-fraction", action="store_true")
    ap.add_argument("--gil", action="store_true")
    ap.add_argument("--codecs", nargs="+", choices=("yuv420z", "yuv420zg"), default=["yuv420z"])
    ap.add_argument("--z", type=float, nargs="+", default=[50.0])
    ap.add_argument("--cache-dir", type=Path, default=Path("/tmp/viva-sitl-bench"))
    args = ap.parse_args()
    if not (args.phases or args.done_fraction or args.gil):
        ap.error("choose at least one of --phases, --done-fraction, --gil")
    try:
        for codec in args.codecs:
            for z in args.z:
                if args.phases:
                    phases(args, codec, z)
                if args.done_fraction:
                    done_fraction(args, codec, z)
            if args.gil:
                gil(args, codec)
    except KeyboardInterrupt:
        print(
            "probe_read_ahead: interrupted; the probes above are complete, nothing else was written",
            file=sys.stderr,
        )
        return 130
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
