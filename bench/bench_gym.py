"""Gymnasium env steps/s: a single LandingEnv, SharedFootageVectorEnv at N = 1, 2, 4, 8, and viva-safeland's DroneEnv.

    /work/venv/bin/python bench/bench_gym.py --markdown /tmp/gym.md
    /work/venv/bin/python bench/bench_gym.py --ns 1 8 --rounds 2 --footage tiles

One env step = 1/30 s of 250 Hz physics (attitude action [0, 0, 0, 0]: hover, via Vehicle.step_command) + the footage
frame for that time + the VAC view (`--image-size`, default 640x480 as bench_core's "full step") + state, reward
(LandingReward: risk + people queries) and termination (the trials' TrialMonitor). Footage: the 4K bench clip of bench_core.py (the shared
interchange clip upscaled to 3840x2160, 60 frames, 25 fps) as video, or its jpeg tile cache (`--footage tiles`,
built by bench_tiles.py / `viva-sitl footage ingest --tiles`). Every copy hovers at --z over its own drawn start
(a TrialSpec: north/east within +-15 % of the footage's smaller side, yaw drawn, footage time 0), so N copies render N
different regions from the shared decode. The reference (`DroneEnv.step`, its own interpreter, same clip, hover at the
same z, 640x480 view) runs in the same rounds, interleaved; the order of the variants rotates by one each round.
Reported: median env steps/s, median wall and CPU ms per env step, ratios (per-env step cost vs a single env; steps/s
vs the reference). Load average printed per round: on a shared machine wall figures are depressed, CPU ms per step
is the steadier figure. `--ref-python-also PY ...`: further references (e.g. viva-safeland 0.2.5 beside 0.2.0), run
`ref_<version>` in the same rounds; the table then gives steps/s and CPU (reference CPU ms / ours) vs each version.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

import bench_core as core  # noqa: E402

from viva_sitl.evaluation.spec import footage_box  # noqa: E402
from viva_sitl.gym import LandingEnv, SharedFootageVectorEnv, TrialSpec  # noqa: E402


def loadavg() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def env_kwargs(args: argparse.Namespace, footage: str) -> dict[str, Any]:
    w, h = (int(v) for v in args.image_size.lower().split("x"))
    g = footage_box(footage).geometry
    half = 0.15 * min(g.ground_width_m, g.ground_height_m)
    return {
        "image_size": (w, h),
        "observation": "image+state",
        "max_episode_s": 1e6,
        "spec": TrialSpec(
            altitude_m=(args.z, args.z), north_m=(-half, half), east_m=(-half, half), margin_m=0.0
        ),
    }


def time_single(footage: str, args: argparse.Namespace) -> tuple[float, float]:
    """(wall ms, CPU ms) per env step of one LandingEnv."""
    env = LandingEnv(footage, **env_kwargs(args, footage))
    env.reset(seed=0)
    a = np.zeros(4, np.float32)
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in range(args.steps):
        env.step(a)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    env.close()
    return 1e3 * wall / args.steps, 1e3 * cpu / args.steps


def time_vector(footage: str, n: int, args: argparse.Namespace) -> tuple[float, float]:
    """(wall ms, CPU ms) per env step (one vector step = n env steps)."""
    venv = SharedFootageVectorEnv(n, footage=footage, **env_kwargs(args, footage))
    venv.reset(seed=0)
    a = np.zeros((n, 4), np.float32)
    c0, t0 = time.process_time(), time.perf_counter()
    for _ in range(args.steps):
        venv.step(a)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    venv.close()
    return 1e3 * wall / (args.steps * n), 1e3 * cpu / (args.steps * n)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--footage", choices=("video", "tiles"), default="video")
    ap.add_argument("--image-size", type=core.size_arg, default="640x480")
    ap.add_argument("--z", type=float, default=50.0, help="hover altitude, m")
    ap.add_argument("--ns", type=int, nargs="+", default=[1, 2, 4, 8])
    ap.add_argument("--steps", type=int, default=60, help="env steps (vector: vector steps) per timed run")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--ref-python", default="/work/refvenv/bin/python")
    ap.add_argument("--no-ref", action="store_true")
    ap.add_argument("--ref-python-also", nargs="*", default=[],
                    help="further reference interpreters timed in the same rounds (e.g. viva-safeland 0.2.5's beside "
                         "0.2.0's): runs ref_<version>, every ratio also vs each of them")  # fmt: skip
    ap.add_argument("--cache-dir", type=Path, default=core.DEFAULT_CACHE)
    ap.add_argument("--markdown", type=Path, default=None)
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--cv-threads", type=int, default=None,
                    help="cv2.setNumThreads for this process (default: OpenCV's own); the reference is unchanged")  # fmt: skip
    core.add_tile_cache_arg(ap)  # the clip by path opens through the automatic tile cache: see its help
    args = ap.parse_args()
    core.apply_tile_cache(ap, args)
    if args.cv_threads is not None:
        import cv2

        cv2.setNumThreads(args.cv_threads)
    clip = core.make_clip(args.cache_dir, 60, rel_alt_m=core.DEFAULT_REL_ALT_M)
    if args.footage == "tiles":
        import bench_tiles

        footage = str(bench_tiles.make_tiles(clip, "jpeg"))
    else:
        footage = str(clip)
    ns = SimpleNamespace(z=args.z, yaw_deg=30.0, out_size=args.image_size, steps=args.steps,
                         rel_alt=core.DEFAULT_REL_ALT_M)  # fmt: skip
    refs: dict[str, core.Reference] = {}  # run name ("ref", "ref_<version>") -> the reference
    labels: dict[str, str] = {}  # "vs" label (the viva-safeland version the interpreter reports) -> run name
    for i, python in enumerate([args.ref_python, *args.ref_python_also]):
        why = "--no-ref" if args.no_ref else core.reference_available(python)
        if why is not None:
            print(f"# reference skipped: {why}" if i == 0 else f"# reference {python} skipped: {why}",
                  file=sys.stderr)  # fmt: skip
            continue
        ref_run = core.Reference(python, clip, ns)  # type: ignore[arg-type]
        label = core.reference_label(str(ref_run.info.get("version", "unknown")), labels)
        labels[label] = "ref" if i == 0 else f"ref_{label}"
        refs[labels[label]] = ref_run
    runs: dict[str, list[tuple[float, float]]] = {"single": [], **{f"vec{n}": [] for n in args.ns}, "ref": [],
                                                  **{k: [] for k in refs if k != "ref"}}  # fmt: skip
    loads = []
    order = [k for k in runs if not k.startswith("ref") or k in refs]
    try:
        # warm-up (imports, world build, first decode) untimed
        time_single(footage, replace_steps(args, 5))
        for r in range(args.rounds):
            loads.append(loadavg())
            # the variants' order rotates from round to round: none is always the one timed right after the
            # reference's process or first after a warm-up (on this VM the variant after the reference ran slower)
            for k in order[r % len(order) :] + order[: r % len(order)]:
                if k in refs:
                    sps, cpu_ms = refs[k].run()
                    runs[k].append((1e3 / sps, cpu_ms))
                elif k == "single":
                    runs["single"].append(time_single(footage, args))
                else:
                    runs[k].append(time_vector(footage, int(k[3:]), args))
            print(f"# round {r + 1}/{args.rounds} load {loads[-1]}: "
                  + ", ".join(f"{k} {v[-1][0]:.1f} ms" for k, v in runs.items() if v), file=sys.stderr)  # fmt: skip
    except KeyboardInterrupt:
        print("bench_gym.py: interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    finally:
        for ref in refs.values():
            ref.close()
    med = {
        k: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v))
        for k, v in runs.items()
        if v
    }
    single_w, single_c = med["single"]
    rows: list[dict[str, Any]] = []
    for k, (w, c) in med.items():
        rows.append({
            "variant": k, "env_steps_per_s": 1e3 / w, "wall_ms_per_env_step": w, "cpu_ms_per_env_step": c,
            "cost_vs_single_wall": w / single_w, "cost_vs_single_cpu": c / single_c,
            "x_ref_steps_per_s": (med["ref"][0] / w) if "ref" in med else None,
        })  # fmt: skip
        # --ref-python-also: steps/s (wall) and CPU (reference CPU ms / ours) vs each reference, by its version
        if args.ref_python_also:
            rows[-1]["x_steps_per_s_vs"] = {lb: med[rk][0] / w for lb, rk in labels.items() if rk in med}
            rows[-1]["x_cpu_vs"] = {lb: med[rk][1] / c for lb, rk in labels.items() if rk in med}
    cv = "" if args.cv_threads is None else f", cv2 threads {args.cv_threads}"
    head = (f"footage: {args.footage} ({footage}), view {args.image_size}, z {args.z} m{cv}, {args.steps} steps per run, "
            f"{args.rounds} rounds, machine: {os.cpu_count()} cores, load per round: {'; '.join(loads)}")  # fmt: skip
    lines = [head, "", "| variant | env steps/s | wall ms / env step | CPU ms / env step | cost vs single (wall) "
             "| cost vs single (CPU) | steps/s vs ref |", "|---|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    if args.ref_python_also:
        head += "; references: " + ", ".join(f"viva-safeland {lb} ({rk})" for lb, rk in labels.items())
        lines = [head, "", "| variant | env steps/s | wall ms / env step | CPU ms / env step | cost vs single (wall) "
                 "| cost vs single (CPU) | " + " | ".join(f"steps/s vs {lb} | CPU vs {lb}" for lb in labels) + " |",
                 "|---|---:|---:|---:|---:|---:|" + "---:|---:|" * len(labels)]  # fmt: skip
    for row in rows:
        x = row["x_ref_steps_per_s"]
        last = f"{'' if x is None else f'{x:.2f}x'} |"
        if args.ref_python_also:
            last = " | ".join(f"{row['x_steps_per_s_vs'][lb]:.2f}x | {row['x_cpu_vs'][lb]:.2f}x"
                              if lb in row["x_steps_per_s_vs"] else " | " for lb in labels) + " |"  # fmt: skip
        lines.append(f"| {row['variant']} | {row['env_steps_per_s']:.1f} | {row['wall_ms_per_env_step']:.2f} | "
                     f"{row['cpu_ms_per_env_step']:.2f} | {row['cost_vs_single_wall']:.3f} | "
                     f"{row['cost_vs_single_cpu']:.3f} | {last}")  # fmt: skip
    text = "\n".join(lines)
    print(text)
    if args.markdown:
        args.markdown.write_text(text + "\n")
    if args.json:
        more = {"references": labels} if args.ref_python_also else {}  # "vs" label -> run name
        args.json.write_text(json.dumps({"head": head, "rows": rows, "runs": runs, **more}, indent=1))


def replace_steps(args: argparse.Namespace, steps: int) -> argparse.Namespace:
    out = argparse.Namespace(**vars(args))
    out.steps = steps
    return out


if __name__ == "__main__":
    main()
