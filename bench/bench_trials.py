"""Landing trials per hour: viva-sitl's in-process trials (local pool) vs the same loop written with viva-safeland's
DroneEnv (the reference), measured in the same run, over the 4K bench clip, 640x480 VAC at 30 fps.

    /work/venv/bin/python bench/bench_trials.py                          # defaults: 4 trials per side, jobs = cores
    /work/venv/bin/python bench/bench_trials.py --trials 6 --jobs 2 --ref-python /work/refvenv/bin/python
    nice -n 10 /work/venv/bin/python bench/bench_trials.py --trials 2 --jobs 2 --rounds 2 --variants video tiles

One trial = a 60 s (sim) emergency landing: air start at 30 m over the clip, "land now" at 1 s.
  ours: `run_campaign(spec, "bench.bench_trials:VisionDescend", jobs=J)`: the Vehicle (250 Hz EAV + autopilot) with
        an in-process pilot that asks for every VAC frame (640x480 at 30 fps) and reads it (mean brightness), and
        lands through the autopilot; trajectory/events written and scored as in any campaign.
  the pilot's read (--read, both sides the same): "cv2" (default) cv2.mean of the frame, 0.04 ms per 640x480 frame;
        "numpy" frame.mean(), 0.39 ms (numpy sums uint8 through float64). What a pilot computes is the user's cost,
        not the simulator's: the read only makes sure every frame is produced and touched. With "numpy" the pilot's
        own arithmetic is ~15 % of our per-frame cost and ~1.5 % of the reference's (bench/results_trials.md).
  ref:  DroneEnv(render_mode="rgb_array", render_fps=30) with its drone view set to 640x480, reset at z = 30 m,
        then env.step() with a proportional descent policy (reads the observation the same way) until it
        terminates (z <= 2 m) or 60 s (1800 steps) pass: J such loops in J processes at once.
Variants of ours (--variants): "default" opens the clip by path as `trials run` does for a new user: the automatic
tile cache (viva_sitl.footage.autocache, default settings; only its folder is --auto-cache-dir, not ~/.cache), built
once before the rounds, its build time reported apart ("auto_cache"); "compact" the same with `--cache-compact`'s
codec (yuv420zg: level 0 gradient-coded, the same pixels in a smaller cache; "auto_cache_compact"); "video" flies over the H.264 clip itself
(`--no-cache`); "tiles" over its `footage ingest --tiles` cache (jpeg q95, bench_tiles.make_tiles; a trial's footage
may be any tile cache folder); "tiles-raw" over its raw (uncompressed, lossless: renders bit-identical to the
video's) tile cache. --ref-python-also: a second reference (e.g. viva-safeland 0.2.5 beside 0.2.0), same rounds.
Tile LRU (--tile-cache-mb, default 2 MiB, this process's tile settings, handed to the pool's workers): the bench clip
is 60 frames (2 s) and loops ~15 times in a trial; with the library's default 256 MiB cap every tile under the views
is decoded once and then served from the LRU on every later loop, which a real 60 s clip (1800 distinct frames)
never gets. 2 MiB (~10 tiles) keeps nothing from one frame to the next, so every frame is decoded as over a long
clip. Tiles read by 4 trials (one process): 256 MiB 600 decoded / 7228 LRU hits; 16 MiB 5897 / 1931 (a loop's
tail still fits); 2 MiB and 1 MiB 7033 / 795 (the same: only reads within one frame hit).
Both are normalised to 60 s of simulated flight per trial (a reference loop that terminates early counts the
seconds it flew). Memory: peak RSS (VmHWM: ru_maxrss would carry the parent's peak across fork + exec) of one
process running one trial (ours: a fresh process that imports, opens the footage and flies; ref: its process).
Floor (--floor): CPU ms of what no trial with a 30 fps 640x480 VAC can skip, measured in this process: one
cv2.warpPerspective to 640x480 (the renderer's flags, from a 1280x960 level), and 1/30 s of the vehicle loop
(250 Hz EAV + autopilot + monitor: a trial of the `descend` pilot, which asks for no frames); against the
reference's CPU ms per step (its process_time / steps) it bounds the ratio any speed-up of the rest can reach.
Prints a JSON report; bench/results_trials.md records a run.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:  # the pilot class below is imported by name in the pool's workers
    sys.path.insert(0, str(REPO))

from viva_sitl import opencv_pool  # noqa: E402, I001 - before cv2, as the `viva-sitl` commands (opencv_pool)
import cv2  # noqa: E402
import numpy as np  # noqa: E402

from viva_sitl.dynamics import EavCommand  # noqa: E402

TRIAL_S = 60.0

REF_LOOP = r"""
import contextlib, io, json, sys, time
import numpy as np
with contextlib.redirect_stdout(io.StringIO()):
    from viva import DroneEnv
video, trials, trial_s, seed = sys.argv[1], int(sys.argv[2]), float(sys.argv[3]), int(sys.argv[4])
if sys.argv[5] == "cv2":
    import cv2
    read = lambda img: sum(cv2.mean(img)[:3]) / 3.0
else:
    read = lambda img: float(img.mean())
with contextlib.redirect_stdout(sys.stderr):
    env = DroneEnv(render_mode="rgb_array", video=video, render_fps=30, terminated_step=10**9, fixed=False)
env.drone_view_size = np.array((640, 480))
env.simulator.camera.output = np.array((640, 480), dtype=np.int32)
rng = np.random.default_rng(seed)
t0, c0 = time.perf_counter(), time.process_time()
flown = 0.0
steps = 0
brightness = 0.0
for k in range(trials):
    with contextlib.redirect_stdout(sys.stderr):
        obs, _ = env.reset(x=0.0, y=0.0, z=30.0, psi_deg_init=float(rng.uniform(0, 360)))
    vz = 0.0
    for step in range(int(trial_s * 30)):
        brightness += read(obs)
        thrust = float(np.clip(0.3 * (-0.5 - vz), -0.5, 0.5))  # descend at 0.5 m/s (z up in viva)
        obs, term, info = env.step(np.array([0.0, 0.0, 0.0, thrust]))
        vz = float(info["drone_state"].vel.z)
        steps += 1
        if term:
            break
    flown += (step + 1) / 30.0
wall, cpu = time.perf_counter() - t0, time.process_time() - c0
hwm = next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM:"))
print(json.dumps({"trials": trials, "wall_s": wall, "sim_s": flown, "max_rss_mb": hwm / 1024, "cpu_s": cpu,
                  "steps": steps}))
"""


READ_ENV = "VIVA_BENCH_READ"  # the pool's workers inherit it


def read_cv2(img: Any) -> float:
    return float(sum(cv2.mean(img)[:3]) / 3.0)


def read_numpy(img: Any) -> float:
    return float(img.mean())


class VisionDescend:
    """The bench's in-process pilot: every VAC frame at 30 fps is read (as a vision policy would), then Land."""

    name, control_hz, frame_hz, uses_ground_truth = "vision-descend", 30.0, 30.0, False

    def reset(self, scenario: Any, truth: Any) -> None:
        self.brightness = 0.0
        self.landing = False
        self.read = read_cv2 if os.environ.get(READ_ENV, "cv2") == "cv2" else read_numpy

    def act(self, obs: Any, ctl: Any) -> EavCommand | None:
        if obs.frame is not None:
            self.brightness += self.read(obs.frame.image_bgr)
        if obs.land_now and not self.landing:
            self.landing = ctl.land().ok
        return None


def bench_spec(clip: Path, n: int) -> Any:
    from viva_sitl.evaluation.spec import spec_from_dict

    return spec_from_dict(
        {
            "trials": {"name": "bench", "n": n, "seed": 0, "timeout_s": TRIAL_S, "end_outside_s": 1000.0},
            "scenario": {"footage": str(clip), "start": "air", "north_m": [-50.0, 50.0], "east_m": [-50.0, 50.0],
                         "altitude_m": 30.0, "land_at_s": 1.0, "params": {"MPC_LAND_SPEED": 0.6}},
        },
        "bench",
    )  # fmt: skip


def ours(clip: Path, n: int, jobs: int, policy: Any = None) -> dict[str, Any]:
    """`n` trials over `clip` in a local pool of `jobs`, the campaign under automatic-cache policy `policy`
    (viva_sitl.footage.autocache.CachePolicy; None: this process's), which it hands to its workers."""
    import contextlib

    from viva_sitl.evaluation.campaign import run_campaign
    from viva_sitl.footage import autocache

    spec = bench_spec(clip, n)
    with (
        tempfile.TemporaryDirectory() as d,
        autocache.using_policy(policy) if policy is not None else contextlib.nullcontext(),
    ):
        t0 = time.perf_counter()
        camp = run_campaign(spec, "bench.bench_trials:VisionDescend", Path(d), jobs=jobs, progress=False)
        wall = time.perf_counter() - t0
    rows = camp.ordered_rows()
    sim = sum(float(r["end_t_s"] or 0.0) for r in rows)
    return {"trials": n, "wall_s": wall, "sim_s": sim, "ends": [r["end"] for r in rows],
            "trial_wall_s": [r["wall_s"] for r in rows]}  # fmt: skip


def ours_memory(clip: Path) -> float:
    from viva_sitl.footage import autocache

    pol = autocache.policy()  # this process's, handed on as a campaign hands it to its workers
    root = None if pol.root is None else str(pol.root)
    code = "\n".join([
        f"import sys; sys.path.insert(0, {str(REPO)!r})",
        "from pathlib import Path", "import tempfile",
        "from viva_sitl.footage import autocache",
        f"autocache.set_policy(autocache.CachePolicy(enabled={pol.enabled!r}, "
        f"root=None if {root!r} is None else Path({root!r}), show_progress=False))",
        "from bench.bench_trials import bench_spec",
        "from viva_sitl.evaluation.spec import draw_scenarios",
        "from viva_sitl.evaluation.runner import run_inprocess_trial",
        f"spec = bench_spec(Path({str(clip)!r}), 1)",
        "with tempfile.TemporaryDirectory() as d:",
        "    run_inprocess_trial(spec, draw_scenarios(spec)[0], 'bench.bench_trials:VisionDescend', Path(d))",
        "print(next(int(x.split()[1]) for x in open('/proc/self/status') if x.startswith('VmHWM:')) / 1024)",
    ])  # fmt: skip
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=REPO)
    return float(out.stdout.strip().splitlines()[-1])


def ref(ref_python: str, clip: Path, n: int, jobs: int, read: str = "cv2") -> dict[str, Any]:
    per = [n // jobs + (1 if k < n % jobs else 0) for k in range(jobs)]
    t0 = time.perf_counter()
    procs = [subprocess.Popen([ref_python, "-c", REF_LOOP, str(clip), str(m), str(TRIAL_S), str(k), read],
                              stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=opencv_pool.user_environ())
             for k, m in enumerate(per) if m > 0]  # fmt: skip
    outs = [json.loads(p.communicate()[0].strip().splitlines()[-1]) for p in procs]
    wall = time.perf_counter() - t0
    return {"trials": n, "wall_s": wall, "sim_s": sum(o["sim_s"] for o in outs),
            "max_rss_mb": max(o["max_rss_mb"] for o in outs),
            "cpu_ms_per_step": 1000 * sum(o["cpu_s"] for o in outs) / max(1, sum(o["steps"] for o in outs))}  # fmt: skip


def floor(footage: Path) -> dict[str, float]:
    """CPU ms per 1/30 s of sim that no trial with a 30 fps 640x480 VAC can skip (see the module doc)."""
    import cv2

    from viva_sitl.evaluation.runner import run_inprocess_trial
    from viva_sitl.evaluation.spec import draw_scenarios

    rng = np.random.default_rng(0)
    src = rng.integers(0, 255, (960, 1280, 3), dtype=np.uint8)
    h = np.array([[1.9, 0.3, 20.0], [-0.3, 1.9, 30.0], [0.0, 0.0, 1.0]])
    cv2.warpPerspective(src, h, (640, 480), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
    c0 = time.process_time()
    for _ in range(200):
        cv2.warpPerspective(src, h, (640, 480), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                            borderMode=cv2.BORDER_CONSTANT, borderValue=(0, 0, 0))  # fmt: skip
    warp_ms = 1000 * (time.process_time() - c0) / 200
    spec = bench_spec(footage, 1)
    with tempfile.TemporaryDirectory() as d:
        sc = draw_scenarios(spec)[0]
        run_inprocess_trial(spec, sc, "descend", Path(d) / "warm")
        c0 = time.process_time()
        row = run_inprocess_trial(spec, sc, "descend", Path(d) / "t")
        loop_cpu = time.process_time() - c0
    loop_ms = 1000 * loop_cpu / (float(row["end_t_s"]) * 30.0)
    return {"warp_640x480_cpu_ms": round(warp_ms, 3), "vehicle_loop_cpu_ms_per_frame": round(loop_ms, 3),
            "floor_cpu_ms_per_frame": round(warp_ms + loop_ms, 3)}  # fmt: skip


def build_auto_cache(clip: Path, policy: Any) -> dict[str, Any]:
    """Open `clip` by path under `policy` (builds its automatic cache the first time, as a new user's first trial
    does): the wall seconds that took, and the cache's size."""
    from viva_sitl.footage import autocache
    from viva_sitl.footage.loader import open_footage

    t0 = time.perf_counter()
    open_footage(clip, cache=policy).close()
    build_s = time.perf_counter() - t0
    entry = max((e for e in autocache.list_caches(policy.directory())
                 if e.source == str(clip.resolve()) and e.codec == policy.codec), key=lambda e: e.last_used)  # fmt: skip
    return {"open_or_build_s": build_s, "mib": entry.bytes / 2**20, "frames": entry.frames,
            "mib_per_frame": entry.bytes / 2**20 / entry.frames, "folder": str(entry.folder)}  # fmt: skip


def ref_version(python: str) -> str:
    from bench.bench_core import viva_safeland_version

    version = viva_safeland_version(python)
    if version is None:
        raise SystemExit(f"bench_trials: viva-safeland is not installed in {python}")
    return version


def per_hour(r: dict[str, Any]) -> tuple[float, float]:
    """(trials per hour as run, 60 s trials per hour: normalised to 60 s of flight each)."""
    return 3600.0 * r["trials"] / r["wall_s"], 3600.0 * (r["sim_s"] / TRIAL_S) / r["wall_s"]


def main() -> int:
    from bench.bench_core import DEFAULT_CACHE, add_tile_cache_arg, apply_tile_cache, make_clip

    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trials", type=int, default=4, help="trials per side per round")
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--rounds", type=int, default=1, help="rounds, interleaved ref ours ref ours ...")
    ap.add_argument("--ref-python", default="/work/refvenv/bin/python")
    ap.add_argument(
        "--frames", type=int, default=60, help="frames of the 4K bench clip (bench_core.make_clip)"
    )
    ap.add_argument(
        "--variants",
        nargs="+",
        default=["default", "video"],
        choices=["default", "compact", "video", "tiles", "tiles-raw"],
    )
    ap.add_argument(
        "--ref-python-also",
        nargs="*",
        default=[],
        help="more reference interpreters (e.g. viva-safeland 0.2.5), timed in the same rounds",
    )
    ap.add_argument("--auto-cache-dir", type=Path, default=DEFAULT_CACHE / "tiles-auto",
                    help="folder of the 'default' variant's automatic cache (a fresh folder: the first build)")  # fmt: skip
    ap.add_argument("--no-floor", action="store_true", help="skip the floor measurement")
    add_tile_cache_arg(ap)  # the pool's workers inherit it
    ap.add_argument("--read", choices=["cv2", "numpy"], default="cv2",
                    help="how both sides' pilots read each frame (see above)")  # fmt: skip
    args = ap.parse_args()
    os.environ[READ_ENV] = args.read
    apply_tile_cache(ap, args)
    from bench.bench_tiles import make_tiles
    from viva_sitl.footage import autocache, tiles

    clip = make_clip(DEFAULT_CACHE, args.frames)
    footage = {"video": clip, "default": clip, "compact": clip}
    policies: dict[str, Any] = {v: None for v in args.variants}
    policies["video"] = autocache.CachePolicy(enabled=False)  # the video itself (`--no-cache`)
    policies["default"] = autocache.CachePolicy(root=args.auto_cache_dir, show_progress=False)
    # nothing this bench opens writes to the user's ~/.cache: the process's policy is the default one, in its folder
    autocache.set_policy(policies["default"])
    policies["compact"] = replace(policies["default"], codec=tiles.COMPACT_CODEC)  # `--cache-compact`
    auto_cache = build_auto_cache(clip, policies["default"]) if "default" in args.variants else None
    compact = build_auto_cache(clip, policies["compact"]) if "compact" in args.variants else None
    refs = {"ref": args.ref_python, **{f"ref_{ref_version(py)}": py for py in args.ref_python_also}}
    if "tiles" in args.variants:
        footage["tiles"] = make_tiles(clip, "jpeg")
    if "tiles-raw" in args.variants:
        footage["tiles-raw"] = make_tiles(clip, "raw")
    res: dict[str, Any] = {
        "machine": f"{platform.node()} {platform.machine()} {os.cpu_count()} cpus, {platform.python_version()}",
        "load_avg_before": os.getloadavg(), "clip": str(clip), "jobs": args.jobs, "read": args.read,
        "tile_cache_mb": args.tile_cache_mb, "ref_version": ref_version(args.ref_python), "auto_cache": auto_cache,
        "auto_cache_compact": compact,
        "rounds": [],
    }  # fmt: skip
    for _ in range(args.rounds):
        rnd: dict[str, Any] = {"load_avg": os.getloadavg()}
        for k, py in refs.items():
            rnd[k] = ref(py, clip, args.trials, args.jobs, args.read)
        for v in args.variants:
            rnd[f"ours_{v}"] = ours(footage[v], args.trials, args.jobs, policies[v])
        rnd["load_avg_after"] = os.getloadavg()
        res["rounds"].append(rnd)
    res["load_avg_after"] = os.getloadavg()
    med = lambda xs: float(np.median(xs))  # noqa: E731
    ref_h = [per_hour(r["ref"]) for r in res["rounds"]]
    res["ref_trials_per_hour"] = med([h[0] for h in ref_h])
    res["ref_60s_trials_per_hour"] = med([h[1] for h in ref_h])
    for v in args.variants:
        ours_h = [per_hour(r[f"ours_{v}"]) for r in res["rounds"]]
        res[f"ours_{v}_trials_per_hour"] = med([h[0] for h in ours_h])
        res[f"ours_{v}_60s_trials_per_hour"] = med([h[1] for h in ours_h])
        # per round (same-run pairs), then the median of the ratios
        res[f"ratio_{v}_60s"] = med([o[1] / r[1] for o, r in zip(ours_h, ref_h, strict=True)])
        for k in list(refs)[1:]:
            k_h = [per_hour(r[k]) for r in res["rounds"]]
            res[f"ratio_{v}_60s_vs_{k}"] = med([o[1] / r[1] for o, r in zip(ours_h, k_h, strict=True)])
        with autocache.using_policy(policies[v] or policies["default"]):
            res[f"ours_{v}_rss_mb_per_trial_process"] = ours_memory(footage[v])
    res["ref_rss_mb_per_process"] = max(r["ref"]["max_rss_mb"] for r in res["rounds"])
    res["ref_cpu_ms_per_step"] = med([r["ref"]["cpu_ms_per_step"] for r in res["rounds"]])
    if not args.no_floor:
        fl = floor(footage.get("tiles", clip))
        fl["max_ratio_vs_ref_cpu"] = round(res["ref_cpu_ms_per_step"] / fl["floor_cpu_ms_per_frame"], 2)
        res["floor"] = fl
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
