"""The tile read-ahead on and off, in alternated child processes (pairs), over the 4K bench clip's automatic cache.

Each child is one simulator alone in its process (bench_core.Ours: 1/30 s of physics + one 640x480 render per step,
hovering at --z, yaw 30 deg/s), the decoded-tile LRU at --tile-cache-mb (default 2 MiB: every frame decoded, as over
a long clip), 2 decode threads, $VIVA_SITL_TILE_READ_AHEAD 1 or 0; a warm-up run, then --rounds runs of --steps
steps. It prints steps/s, CPU ms per step and the voluntary context switches per step (getrusage: each wait of a
thread for another, the OpenCV pool's and the decode pool's hand-offs) as medians over its rounds. The parent
alternates on/off --pairs times per codec and z (the machine's state moves between processes: compare pairs), then
prints the medians of each side and their ratio.

    python bench/bench_read_ahead.py --pairs 6
    python bench/bench_read_ahead.py --pairs 6 --codecs yuv420z yuv420zg --z 50 300
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_core as core  # noqa: E402 - imports viva_sitl before cv2, as a user's program would

CODECS = ("yuv420z", "yuv420zg")


def child(args: argparse.Namespace) -> None:
    from viva_sitl.footage import autocache

    clip = core.make_clip(args.cache_dir, args.frames)
    autocache.set_policy(
        autocache.CachePolicy(root=args.cache_dir / "tiles-auto", show_progress=False, codec=args.child)
    )
    core.apply_tile_environment()
    step = argparse.Namespace(
        out_size="640x480", rel_alt=core.DEFAULT_REL_ALT_M, z=args.z[0], yaw_deg=30.0, steps=args.steps
    )
    ours = core.Ours(clip, step, paper=False, render=True)
    try:
        ours.run()  # warm-up
        r0 = resource.getrusage(resource.RUSAGE_SELF)
        runs = [ours.run() for _ in range(args.rounds)]
        r1 = resource.getrusage(resource.RUSAGE_SELF)
        cache = getattr(ours.sim.footage, "cache", None)
        jobs = getattr(cache, "ahead_jobs", 0)
    finally:
        ours.sim.close()
    n = args.rounds * args.steps
    print(json.dumps({"steps_per_s": statistics.median(r[0] for r in runs),
                      "cpu_ms_per_step": statistics.median(r[1] for r in runs),
                      "vcsw_per_step": (r1.ru_nvcsw - r0.ru_nvcsw) / n, "ahead_jobs": jobs}))  # fmt: skip


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--pairs", type=int, default=6)
    ap.add_argument("--z", type=float, nargs="+", default=[50.0])
    ap.add_argument("--codecs", nargs="+", choices=CODECS, default=[CODECS[0]])
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--steps", type=int, default=240)
    ap.add_argument("--frames", type=int, default=60)
    core.add_tile_cache_arg(ap)
    ap.add_argument("--cache-dir", type=Path, default=Path("/tmp/viva-sitl-bench"))
    ap.add_argument("--json", type=Path)
    ap.add_argument("--child", choices=CODECS, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        child(args)
        return 0
    if min(args.pairs, args.rounds, args.steps, args.frames) < 1:
        ap.error("--pairs, --rounds, --steps and --frames must be >= 1")
    core.apply_tile_cache(ap, args)  # --tile-cache-mb into the environment the children get
    out = []
    print("| z | cache | pairs | on: steps/s | off: steps/s | on / off | on: CPU ms/step | off: CPU ms/step | "
          "on: waits/step | off: waits/step |\n|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")  # fmt: skip
    try:
        for z in args.z:
            for codec in args.codecs:
                sides: dict[str, list[dict[str, float]]] = {"on": [], "off": []}
                for _ in range(args.pairs):
                    for side in ("on", "off"):
                        env = dict(os.environ, VIVA_SITL_TILE_DECODE_THREADS="2",
                                   VIVA_SITL_TILE_READ_AHEAD="1" if side == "on" else "0")  # fmt: skip
                        cmd = [sys.executable, __file__, "--child", codec, "--z", f"{z:g}", "--rounds",
                               str(args.rounds), "--steps", str(args.steps), "--frames", str(args.frames),
                               "--cache-dir", str(args.cache_dir)]  # fmt: skip
                        res = subprocess.run(cmd, env=env, capture_output=True, text=True)
                        if res.returncode != 0:
                            print(res.stderr, file=sys.stderr)
                            raise SystemExit(f"bench_read_ahead: the {codec} child at {z:g} m failed")
                        row = json.loads(res.stdout.strip().splitlines()[-1])
                        sides[side].append(row)
                        print(f"z {z:g} m {codec:8s} read-ahead {side:3s}: {row['steps_per_s']:7.1f} steps/s "
                              f"{row['cpu_ms_per_step']:.2f} ms CPU  {row['vcsw_per_step']:.1f} waits/step  "
                              f"{row['ahead_jobs']} jobs", file=sys.stderr)  # fmt: skip
                med = {
                    s: {k: statistics.median(r[k] for r in rows) for k in rows[0]}
                    for s, rows in sides.items()
                }
                print(f"| {z:g} m | {codec} | {args.pairs} | {med['on']['steps_per_s']:.1f} | "
                      f"{med['off']['steps_per_s']:.1f} | {med['on']['steps_per_s'] / med['off']['steps_per_s']:.3f} | "
                      f"{med['on']['cpu_ms_per_step']:.3f} | {med['off']['cpu_ms_per_step']:.3f} | "
                      f"{med['on']['vcsw_per_step']:.1f} | {med['off']['vcsw_per_step']:.1f} |")  # fmt: skip
                out.append({"z": z, "codec": codec, "on": sides["on"], "off": sides["off"]})
    except KeyboardInterrupt:
        print("bench_read_ahead: interrupted; nothing written", file=sys.stderr)
        return 130
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
