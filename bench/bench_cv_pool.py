"""The full step over the 4K bench clip's automatic cache under OpenCV's thread-pool settings and the tile decode
threads, each configuration in its own process (OpenCV reads its pool settings once, when it is loaded).

Configurations (`--configs`):
  sleep   what a user gets: viva_sitl sets OPENCV_THREAD_POOL_ACTIVE_WAIT_* = 0 when imported (viva_sitl.opencv_pool)
  spin    OpenCV's own defaults (the variables set to them: PAUSE_LIMIT 16, WORKER 2000, MAIN 10000)
  cv1     cv2.setNumThreads(1): no OpenCV pool at all
each with 1 and 2 tile decode threads (`--decode-threads`), over the automatic cache of each of `--codecs` (yuv420z,
the default; yuv420zg, what `--cache-compact` builds: both caches sit in the same folder under their own keys), with
the tile read-ahead on and/or off (`--read-ahead on off`: $VIVA_SITL_TILE_READ_AHEAD in the child's environment;
default on, as a user gets it). Steps as bench_tiles.py's (bench_core.Ours: 1/30 s of
physics + one 640x480 render per step, hovering at --z), the clip by path under the automatic cache, the decoded-tile
LRU at `--tile-cache-mb` (default 2 MiB: every frame decoded, as over a long clip). Prints one line per
configuration and a markdown table; `--json` keeps the figures. `--ref-python PY ...`: viva-safeland interpreters
timed in the same run (bench_core.Reference, its own process, one round before each configuration's process and one
after the last), each configuration's wall and CPU ratio to each. Unlike bench_tiles.py, which runs its four variants
in one process, each configuration here runs alone in its process, as a user's program does.

    python bench/bench_cv_pool.py --z 50 300 --rounds 5
    python bench/bench_cv_pool.py --configs sleep --ref-python /tmp/ref020/bin/python /tmp/ref025/bin/python
    python bench/bench_cv_pool.py --configs sleep --decode-threads 2 --codecs yuv420z yuv420zg --ref-python ...
    python bench/bench_cv_pool.py --configs sleep --decode-threads 2 --read-ahead on off --ref-python ...
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

# this checkout's viva_sitl (not an installed one: a second clone measures its own code), then bench_core
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_core as core  # noqa: E402 - imports viva_sitl before cv2, as a user's program would

SPIN = {  # OpenCV's defaults (modules/core/src/parallel_impl.cpp)
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_PAUSE_LIMIT": "16",
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_WORKER": "2000",
    "OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN": "10000",
}
CONFIGS = ("sleep", "spin", "cv1")
CACHE_CODECS = ("yuv420z", "yuv420zg")


def _step_args(z: float, steps: int) -> argparse.Namespace:
    """The step both sides fly (bench_core.Ours / Reference): 640x480 view, hovering at z, yaw 30 deg."""
    return argparse.Namespace(
        out_size="640x480", rel_alt=core.DEFAULT_REL_ALT_M, z=z, yaw_deg=30.0, steps=steps
    )


def child(args: argparse.Namespace) -> None:
    import cv2

    from viva_sitl.footage import autocache

    if args.child == "cv1":
        cv2.setNumThreads(1)
    clip = core.make_clip(args.cache_dir, args.frames)
    autocache.set_policy(
        autocache.CachePolicy(root=args.cache_dir / "tiles-auto", show_progress=False, codec=args.codecs[0])
    )
    core.apply_tile_environment()  # the decode threads and LRU the parent put in this process's environment
    ours = core.Ours(clip, _step_args(args.z[0], args.steps), paper=False, render=True)
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
    ap.add_argument("--codecs", nargs="+", choices=CACHE_CODECS, default=[CACHE_CODECS[0]],
                    help="the automatic cache's codec: yuv420z (the default) and/or yuv420zg (--cache-compact); "
                         "each configuration is run over each")  # fmt: skip
    ap.add_argument("--read-ahead", nargs="+", choices=("on", "off"), default=["on"],
                    help="the tile read-ahead (TileSettings.read_ahead) on and/or off; each configuration is run "
                         "with each")  # fmt: skip
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--steps", type=int, default=120)
    ap.add_argument("--frames", type=int, default=60)
    core.add_tile_cache_arg(ap)
    ap.add_argument("--cache-dir", type=Path, default=Path("/tmp/viva-sitl-bench"))
    ap.add_argument("--json", type=Path)
    ap.add_argument("--ref-python", nargs="*", default=[],
                    help="viva-safeland interpreters to time in the same run: one round of each before every "
                         "configuration's process and after the last, at the same z (bench_core.Reference)")  # fmt: skip
    ap.add_argument("--child", choices=CONFIGS, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args)
        return 0
    if min(args.rounds, args.steps, args.frames, *args.decode_threads) < 1:
        ap.error("--rounds, --steps, --frames and --decode-threads must be >= 1")
    core.apply_tile_cache(ap, args)  # --tile-cache-mb checked, and in the environment the children get
    try:
        return _run(args)
    except KeyboardInterrupt:
        print("bench_cv_pool: interrupted; nothing written", file=sys.stderr)
        return 130


def _run(args: argparse.Namespace) -> int:
    from viva_sitl import opencv_pool

    base = opencv_pool.user_environ()  # a fresh shell's environment (no OPENCV_* set by this process)
    rows: list[dict[str, Any]] = []
    refs_out: list[dict[str, Any]] = []
    for z in args.z:
        refs = _references(args, z)
        ref_runs: dict[str, list[tuple[float, float]]] = {name: [] for name in refs}
        try:
            for cfg in args.configs:
                for threads in args.decode_threads:
                    for codec in args.codecs:
                        for ahead in args.read_ahead:
                            _time_refs(refs, ref_runs)
                            rows.append(_config(args, base, z, cfg, threads, codec, ahead))
            _time_refs(refs, ref_runs)
        finally:
            for ref in refs.values():
                ref.close()
        for name, runs in ref_runs.items():
            ref_row = {"z": z, "reference": name, "steps_per_s": statistics.median(r[0] for r in runs),
                       "cpu_ms_per_step": statistics.median(r[1] for r in runs), "runs": runs}  # fmt: skip
            refs_out.append(ref_row)
            print(f"z {z:g} m  viva-safeland {name}: {ref_row['steps_per_s']:7.1f} steps/s  {ref_row['cpu_ms_per_step']:.2f} ms "
                  f"CPU/step (median of {len(runs)} rounds)", file=sys.stderr)  # fmt: skip
    _table(rows, refs_out)
    if args.json:
        args.json.write_text(json.dumps({"configs": rows, "references": refs_out}, indent=1))
    return 0


def _time_refs(refs: dict[str, core.Reference], runs: dict[str, list[tuple[float, float]]]) -> None:
    """One round of each reference (steps/s, CPU ms per step)."""
    for name, ref in refs.items():
        runs[name].append(ref.run())


def _references(args: argparse.Namespace, z: float) -> dict[str, core.Reference]:
    """The viva-safeland references of --ref-python at z, ready to run, by the version each reports ("0.2.0", made
    unique: "0.2.0#2")."""
    clip = core.make_clip(args.cache_dir, args.frames) if args.ref_python else None
    out: dict[str, core.Reference] = {}
    try:
        for py in args.ref_python:
            why = core.reference_available(py)
            if why is not None:
                raise SystemExit(f"bench_cv_pool: {why}")
            assert clip is not None
            ref = core.Reference(py, clip, _step_args(z, args.steps))
            out[core.reference_label(str(ref.info.get("version", "unknown")), out)] = ref
    except BaseException:
        for ref in out.values():
            ref.close()
        raise
    return out


def _config(
    args: argparse.Namespace,
    base: dict[str, str],
    z: float,
    cfg: str,
    threads: int,
    codec: str,
    ahead: str = "on",
) -> dict[str, Any]:
    """One configuration's child process at z over the automatic cache of `codec`, read-ahead `ahead`: its
    medians."""
    env = dict(base, VIVA_SITL_TILE_DECODE_THREADS=str(threads), VIVA_SITL_TILE_READ_AHEAD=str(int(ahead == "on")),
               **(SPIN if cfg == "spin" else {}))  # fmt: skip
    cmd = [sys.executable, __file__, "--child", cfg, "--z", f"{z:g}", "--rounds", str(args.rounds),
           "--steps", str(args.steps), "--frames", str(args.frames), "--cache-dir", str(args.cache_dir),
           "--codecs", codec]  # fmt: skip
    t0 = time.perf_counter()
    out = subprocess.run(cmd, env=env, capture_output=True, text=True)
    if out.returncode != 0:
        print(out.stderr, file=sys.stderr)
        raise SystemExit(f"bench_cv_pool: the {cfg} child at {z:g} m failed (exit {out.returncode})")
    res = json.loads(out.stdout.strip().splitlines()[-1])
    row = {"z": z, "config": cfg, "decode_threads": threads, "codec": codec, "read_ahead": ahead, **res,
           "load": os.getloadavg()[0], "wall_s": time.perf_counter() - t0}  # fmt: skip
    print(f"z {z:g} m  {cfg:5s} decode {threads} {codec:8s} read-ahead {ahead:3s}: {res['steps_per_s']:7.1f} steps/s  "
          f"{res['cpu_ms_per_step']:.2f} ms CPU/step  (load {row['load']:.2f})", file=sys.stderr)  # fmt: skip
    return row


def _table(rows: list[dict[str, Any]], refs: list[dict[str, Any]]) -> None:
    """The markdown table: each configuration, and its wall / CPU ratio to each reference at its z."""
    names = list(dict.fromkeys(r["reference"] for r in refs))
    head = "| z | OpenCV pool | decode threads | cache | read-ahead | steps/s | CPU ms/step |"
    head += "".join(f" vs viva-safeland {n} wall / CPU |" for n in names)
    print(head + "\n|---|---|---:|---|---|---:|---:|" + "---|" * len(names))
    for r in rows:
        line = (f"| {r['z']:g} m | {r['config']} | {r['decode_threads']} | {r['codec']} | {r['read_ahead']} | "
                f"{r['steps_per_s']:.1f} | "
                f"{r['cpu_ms_per_step']:.2f} |")  # fmt: skip
        for n in names:
            ref = next(x for x in refs if x["reference"] == n and x["z"] == r["z"])
            line += (f" {r['steps_per_s'] / ref['steps_per_s']:.2f}x / "
                     f"{ref['cpu_ms_per_step'] / r['cpu_ms_per_step']:.2f}x |")  # fmt: skip
        print(line)
    for ref in refs:
        print(
            f"| {ref['z']:g} m | viva-safeland {ref['reference']} | | | | {ref['steps_per_s']:.1f} | {ref['cpu_ms_per_step']:.2f} |"
            + " |" * len(names)
        )


if __name__ == "__main__":
    raise SystemExit(main())
