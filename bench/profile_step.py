"""Where one full step's time goes over one footage: steps/s, tiles read per frame, the level read, a cProfile split.

    /work/venv/bin/python bench/profile_step.py /tmp/viva-sitl-bench/interchange_3840x2160_60f_tiles_raw --z 50
    /work/venv/bin/python bench/profile_step.py /tmp/viva-sitl-bench/interchange_7680x4320_30f_tiles_raw --top 12
    /work/venv/bin/python bench/profile_step.py /tmp/viva-sitl-bench/interchange_3840x2160_60f_tiles_raw --read-check

The step is bench_core.py's "full step" (1/30 s of 250 Hz physics + the footage frame for that time + a 640x480
view, hover, yaw rate 30 deg/s), as bench_tiles.py times it, with the decoded-tile LRU at --tile-cache-mb (default
2 MiB: every frame decoded). FOOTAGE is a tile cache folder or a clip with its .toml beside it. Prints plain runs'
steps/s (--runs, after one warm-up run), the tiles decoded per frame and the level / footage px per VAC px the view
reads, then the top --top functions by own time of one run under cProfile (0: none; profiling inflates Python).
--read-check: reading and checking 3000 raw tiles with `read` vs through `mmap` (first and second touch), us/tile.
--sweep-mem: peak RSS (VmHWM) of a child process flying 1280x720 views east across the whole footage at 30 m and
back 300 m north (600 renders, 64 MiB tile LRU), with the region buffers' bound (RegionPyramid._buffer) and with
it disabled: what the bound saves on a long flight.
"""

from __future__ import annotations

import argparse
import cProfile
import mmap
import os
import pstats
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

import bench_core as core  # noqa: E402


def read_check(folder: Path, n: int = 3000) -> None:
    """us per tile: read() + checksum vs mmap slice + checksum (pages already in the page cache after pass 1)."""
    import json

    import numpy as np

    from viva_sitl.footage.errors import FootageError
    from viva_sitl.footage.tiles import FORMATS

    tdir = folder / "tiles"
    try:
        dtype, tile_checksum = FORMATS[int(json.loads((tdir / "meta.json").read_text())["version"])]
    except (OSError, ValueError, KeyError, TypeError):
        raise FootageError(
            f"--read-check needs a tile cache folder (with a readable tiles/meta.json): {folder}"
        ) from None
    idx = np.fromfile(tdir / "index.bin", dtype)
    sel = np.flatnonzero(idx["length"] >= np.max(idx["length"]) * 0.9)[:n]  # full-size tiles
    packs = sorted(tdir.glob("pack-*.bin"))

    def via_read() -> float:
        files = [open(p, "rb") for p in packs]  # noqa: SIM115
        t0 = time.perf_counter()
        for i in sel:
            r = idx[i]
            f = files[int(r["pack"])]
            f.seek(int(r["offset"]))
            tile_checksum(f.read(int(r["length"])))
        dt = time.perf_counter() - t0
        for f in files:
            f.close()
        return dt / len(sel) * 1e6

    def via_mmap() -> tuple[float, float]:
        maps = []
        for p in packs:
            with open(p, "rb") as f:
                maps.append(mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ))
        out = []
        for _ in range(2):  # first touch (page faults), then mapped
            t0 = time.perf_counter()
            for i in sel:
                r = idx[i]
                o = int(r["offset"])
                tile_checksum(memoryview(maps[int(r["pack"])])[o : o + int(r["length"])])
            out.append((time.perf_counter() - t0) / len(sel) * 1e6)
        return out[0], out[1]

    for k in range(2):  # pass 1 may read from disk; pass 2 is the page-cache case
        rd = via_read()
        first, second = via_mmap()
        print(f"pass {k + 1}: read {rd:.1f} us/tile; mmap first touch {first:.1f}, second {second:.1f}")


def sweep_child(footage: Path, bound: bool) -> None:
    from dataclasses import replace

    import viva_sitl.camera.pyramid as pyramid
    from viva_sitl.camera import CameraParams
    from viva_sitl.config import SimConfig
    from viva_sitl.sim import Simulator

    if not bound:
        pyramid.RESET_REGIONS = 10**9
    sim = Simulator(SimConfig(camera=CameraParams(width_px=1280, height_px=720)), footage=str(footage))
    cache = getattr(sim.footage, "cache", None)
    if cache is not None:
        cache.cache_bytes = 64 << 20
    half_w = sim.footage.geometry.ground_width_m / 2 - 30.0
    sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -30.0))
    for k in range(600):
        east = -half_w + 2 * half_w * (k % 300) / 300
        pos = sim.state.pos_ned_m * 0 + [-150.0 + 300.0 * (k // 300), east, -30.0]
        sim.render(replace(sim.state, time_s=k / 30.0, pos_ned_m=pos), wall_time_s=0.0)
    sim.close()
    hwm = [ln for ln in Path("/proc/self/status").read_text().splitlines() if ln.startswith("VmHWM")][0]
    print(f"{'with' if bound else 'without'} the bound: {hwm.split(':')[1].strip()} peak RSS")


def main() -> int:
    from viva_sitl.footage.errors import FootageError

    try:
        return _main()
    except (FootageError, OSError) as exc:
        print(f"profile_step.py: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        if "--sweep-child" not in sys.argv:  # the parent of a --sweep-mem child says it once
            print("profile_step.py: interrupted (nothing is written)", file=sys.stderr)
        return 130


def _main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("footage", type=Path)
    ap.add_argument("--z", type=float, default=50.0)
    ap.add_argument("--steps", type=int, default=240)
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--top", type=int, default=20)
    ap.add_argument("--out-size", default="640x480")
    ap.add_argument("--rel-alt", type=float, default=core.DEFAULT_REL_ALT_M)
    ap.add_argument("--read-check", action="store_true")
    ap.add_argument("--sweep-mem", action="store_true")
    ap.add_argument("--sweep-child", choices=["bound", "unbound"], help=argparse.SUPPRESS)
    core.add_tile_cache_arg(ap)
    args = ap.parse_args()
    core.apply_tile_cache(ap, args)
    if args.sweep_child:
        sweep_child(args.footage, args.sweep_child == "bound")
        return 0
    if args.sweep_mem:
        import subprocess

        for mode in ("bound", "unbound"):
            subprocess.run([sys.executable, __file__, str(args.footage), "--sweep-child", mode], check=True)
        return 0
    if args.read_check:
        read_check(args.footage)
        return 0
    ns = argparse.Namespace(
        out_size=args.out_size, steps=args.steps, z=args.z, yaw_deg=30.0, rel_alt=args.rel_alt
    )
    o = core.Ours(args.footage, ns, paper=False, render=True)
    try:
        o.run()  # warm-up
        runs = [o.run()[0] for _ in range(args.runs)]
        print(f"steps/s: {', '.join(f'{r:.1f}' for r in runs)}  (load {os.getloadavg()[0]:.2f})")
        cache = getattr(o.sim.footage, "cache", None)
        if cache is not None:
            before = cache.tiles_decoded
            o.run()
            print(f"tiles decoded per frame: {(cache.tiles_decoded - before) / args.steps:.1f}")
        _, res = o.sim._render_image(o.sim.state)
        print(f"level {res.pyramid_level}, blend {res.lod_blend:.2f}, {res.footage_px_per_vac_px:.2f} footage px "
              "per VAC px")  # fmt: skip
        if args.top > 0:
            pr = cProfile.Profile()
            pr.enable()
            o.run()
            pr.disable()
            pstats.Stats(pr).sort_stats("tottime").print_stats(args.top)
    finally:
        o.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
