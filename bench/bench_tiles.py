"""Tiled footage cache: full steps/s vs viva-safeland's DroneEnv, 8K vs 1080p render cost, memory, trilinear AA.

    /work/venv/bin/python bench/bench_tiles.py --markdown /tmp/tiles.md            # everything below
    /work/venv/bin/python bench/bench_tiles.py --only steps --z 50 300
    /work/venv/bin/python bench/bench_tiles.py --only aa

steps   The bench_core.py "full step" (1/30 s of 250 Hz physics + the footage frame for that time + a 640x480 VAC
        view) over the 4K bench clip, interleaved in rounds with the reference (`DroneEnv.step`, its own
        interpreter, same clip, same pose): ours by the default path (the clip by path: the automatic yuv420z tile
        cache, viva_sitl.footage.autocache, built once before the rounds), over the video itself (--no-cache),
        over a jpeg tile cache and over a raw tile cache (`viva-sitl footage ingest --tiles`). Median steps/s
        and ratios.
scale   The same full step over the same ground (the interchange clip at 1080p, 4K and 8K, recording altitude 471 m)
        from tile caches and from the videos: ms per step, 8K / 1080p ratio.
mem     Peak RSS (VmHWM) of a child process flying 300 steps over the 8K tile cache, with the decoded-tile LRU cap.
aa      PSNR vs an area-averaged reference (8x8 supersampled warp) over the 4K still, at recording-altitude
        fractions: ours trilinear (default), ours single mip level (trilinear=False), ours plain warp
        (antialias=False) and the reference's warp (run_reference.py `quality`, same run).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

import bench_core as core  # noqa: E402


def make_tiles(clip: Path, codec: str, frames: int | None = None, tile_px: int = 256) -> Path:
    """`viva-sitl footage ingest --tiles` of the bench clip, once (resumes if interrupted)."""
    from viva_sitl.footage.ingest import ingest_tiles
    from viva_sitl.footage.tiles import FORMAT_VERSION

    dest = clip.with_name(f"{clip.stem}_tiles_{codec}" + ("" if tile_px == 256 else f"_{tile_px}"))
    try:
        current = json.loads((dest / "tiles" / "meta.json").read_text()).get("version") == FORMAT_VERSION
    except (OSError, ValueError):
        current = False
    if (
        not current or not (dest / "footage.toml").exists()
    ):  # absent, unfinished or an older format: (re)build
        t0 = time.perf_counter()
        res = ingest_tiles(
            str(clip.with_suffix(".toml")), out_dir=dest, codec=codec, show_progress=False, max_frames=frames,
            tile_px=tile_px,
        )  # fmt: skip
        print(
            f"# tiled {clip.name} ({codec}): {res.disk_bytes / 2**20:.0f} MiB in {time.perf_counter() - t0:.0f} s "
            f"(video {clip.stat().st_size / 2**20:.0f} MiB)",
            file=sys.stderr,
        )
    return dest


def disk_mib(folder: Path) -> float:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file()) / 2**20


def loadavg() -> str:
    return " ".join(f"{v:.2f}" for v in os.getloadavg())


def _ours(clip: Path, a: argparse.Namespace, policy: Any) -> core.Ours:
    """core.Ours over `clip` opened under the automatic-cache policy `policy` (viva_sitl.footage.autocache)."""
    from viva_sitl.footage import autocache

    before = autocache.policy()
    autocache.set_policy(policy)
    try:
        return core.Ours(clip, a, paper=False, render=True)
    finally:
        autocache.set_policy(before)


def bench_steps(args: argparse.Namespace, clip: Path) -> dict[str, Any]:
    from viva_sitl.footage import autocache

    tiles = {c: make_tiles(clip, c) for c in ("jpeg", "raw")}
    # the default path of a fresh install: the clip by path, the automatic cache (default settings; only its
    # folder is the bench's, not ~/.cache), built here once before the timed rounds
    auto = autocache.CachePolicy(root=args.cache_dir / "tiles-auto", show_progress=False)
    no_cache = autocache.CachePolicy(enabled=False)
    t0 = time.perf_counter()
    _ours(clip, replace_ns(args, z=args.z[0]), auto).sim.close()
    build_s = time.perf_counter() - t0
    # the one just opened (caches of an older layout of the same clip may lie beside it until the LRU drops them)
    entry = max((e for e in autocache.list_caches(auto.directory()) if e.source == str(clip.resolve())),
                key=lambda e: e.last_used)  # fmt: skip
    out: dict[str, Any] = {
        "disk_mib": {"video": clip.stat().st_size / 2**20, **{c: disk_mib(p) for c, p in tiles.items()},
                     "auto_yuv420z": entry.bytes / 2**20},
        "auto_cache": {"mib_per_frame": entry.bytes / 2**20 / entry.frames, "frames": entry.frames,
                       "open_or_build_s": build_s, "folder": str(entry.folder)},
    }  # fmt: skip
    for z in args.z:
        a = replace_ns(args, z=z)
        why = None if args.no_ref else core.reference_available(args.ref_python)
        ref = core.Reference(args.ref_python, clip, a) if why is None else None
        # a second reference (e.g. viva-safeland 0.2.5 beside 0.2.0), timed in the same rounds
        refs2 = {f"ref_{_ref_version(py)}": core.Reference(py, clip, a) for py in args.ref_python_also
                 if not args.no_ref and core.reference_available(py) is None}  # fmt: skip
        variants = {
            "ours_default_auto_cache": _ours(clip, a, auto),
            "ours_video_no_cache": _ours(clip, a, no_cache),
            "ours_tiles_jpeg": core.Ours(tiles["jpeg"], a, paper=False, render=True),
            "ours_tiles_raw": core.Ours(tiles["raw"], a, paper=False, render=True),
        }
        runs: dict[str, list[float]] = {k: [] for k in ["ref", *refs2, *variants]}
        cpu: dict[str, list[float]] = {
            k: [] for k in ["ref", *refs2, *variants]
        }  # CPU ms per step (all threads)
        loads = []
        try:
            for _ in range(args.rounds):
                if ref is not None:
                    r = ref.run()
                    runs["ref"].append(r[0])
                    cpu["ref"].append(r[1])
                for name, o2 in refs2.items():
                    r = o2.run()
                    runs[name].append(r[0])
                    cpu[name].append(r[1])
                for name, o in variants.items():
                    r = o.run()
                    runs[name].append(r[0])
                    cpu[name].append(r[1])
                loads.append(loadavg())
        finally:
            if ref is not None:
                ref.close()
            for o2 in refs2.values():
                o2.close()
            for o in variants.values():
                o.close()
        med = {k: statistics.median(v) for k, v in runs.items() if v}
        med_cpu = {k: statistics.median(v) for k, v in cpu.items() if v}
        out[f"z{z:g}"] = {
            "median_steps_per_s": med,
            "ratio_to_ref": {k: v / med["ref"] for k, v in med.items() if "ref" in med and k != "ref"},
            "median_cpu_ms_per_step": med_cpu,
            "cpu_ratio_to_ref": {
                k: med_cpu["ref"] / v for k, v in med_cpu.items() if "ref" in med_cpu and k != "ref"
            },
            # the same ratios against each further reference (per round, then the median: same-run pairs)
            **{
                f"cpu_ratio_to_{r2}": {
                    k: statistics.median(a2 / b2 for a2, b2 in zip(cpu[r2], cpu[k], strict=True))
                    for k in variants
                }
                for r2 in refs2
            },  # fmt: skip
            **{
                f"ratio_to_{r2}": {
                    k: statistics.median(b2 / a2 for a2, b2 in zip(runs[r2], runs[k], strict=True))
                    for k in variants
                }
                for r2 in refs2
            },  # fmt: skip
            "runs": runs,
            "loadavg": loads,
            "reference": why or "viva-safeland 0.2.0 DroneEnv.step",
        }
    return out


def _ref_version(python: str) -> str:
    """The viva-safeland version installed in interpreter `python` (e.g. "0.2.5")."""
    return core.viva_safeland_version(python) or "other"


def replace_ns(ns: argparse.Namespace, **kw: Any) -> argparse.Namespace:
    d = vars(ns).copy()
    d.update(kw)
    return argparse.Namespace(**d)


def _time_steps(folder_or_clip: Path, args: argparse.Namespace, rounds: int) -> float:
    o = core.Ours(folder_or_clip, args, paper=False, render=True)
    try:
        return statistics.median(1e3 / o.run()[0] for _ in range(rounds))
    finally:
        o.close()


def bench_scale(args: argparse.Namespace) -> dict[str, Any]:
    """ms per full step over 1080p / 4K / 8K versions of the same ground (tiles and videos)."""
    sizes = {"1080p": (1920, 1080), "4K": (3840, 2160), "8K": (7680, 4320)}
    out: dict[str, Any] = {}
    for z in args.z:
        a = replace_ns(args, z=z)
        row: dict[str, Any] = {}
        kinds = [f"tiles_{c}" for c in args.scale_codecs] + ["video"]
        for name, (w, h) in sizes.items():
            clip = core.make_clip(args.cache_dir, args.scale_frames, w, h, args.rel_alt)
            for codec in args.scale_codecs:
                tiles = make_tiles(clip, codec)
                row[f"tiles_{codec}_{name}_ms"] = _time_steps(tiles, a, args.rounds)
                row[f"tiles_{codec}_{name}_disk_mib"] = disk_mib(tiles)
            row[f"video_{name}_ms"] = _time_steps(clip, a, args.rounds)
        for kind in kinds:
            row[f"{kind}_8K_over_1080p"] = row[f"{kind}_8K_ms"] / row[f"{kind}_1080p_ms"]
        row["loadavg"] = loadavg()
        out[f"z{z:g}"] = row
    return out


def bench_mem(args: argparse.Namespace) -> dict[str, Any]:
    clip = core.make_clip(args.cache_dir, args.scale_frames, 7680, 4320, args.rel_alt)
    tiles = make_tiles(clip, "jpeg")
    out = {}
    for cap_mib in (64, 256):
        r = subprocess.run(
            [sys.executable, __file__, "--child-mem", str(tiles), "--cap-mib", str(cap_mib)],
            capture_output=True, text=True, check=True, env={**os.environ, "PYTHONPATH": str(REPO)},
        )  # fmt: skip
        out[f"cap_{cap_mib}_mib"] = json.loads(r.stdout.strip().splitlines()[-1])
    return out


def child_mem(folder: Path, cap_mib: int) -> None:
    """300 steps over the tile cache (climb 20 -> 400 m while yawing: every level, many tiles); print peak RSS."""
    from viva_sitl.camera import CameraParams
    from viva_sitl.config import SimConfig
    from viva_sitl.footage import open_footage
    from viva_sitl.sim import Simulator

    def rss(key: str) -> float:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key):
                return int(line.split()[1]) / 1024
        return math.nan

    base = rss("VmRSS:")
    src = open_footage(str(folder))
    src.cache.cache_bytes = cap_mib << 20  # type: ignore[attr-defined]
    sim = Simulator(
        SimConfig(camera=CameraParams(width_px=1280, height_px=720, hfov_deg=core.DEFAULT_HFOV_DEG)),
        footage=src,
    )
    sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -20.0))
    lru_max = 0
    for k in range(300):
        s = replace(
            sim.state,
            time_s=k / 30.0,
            pos_ned_m=sim.state.pos_ned_m * 0 + [30 * math.sin(k / 40), 0.0, -(20 + 380 * k / 300)],
        )
        sim.render(s, wall_time_s=0.0)
        lru_max = max(lru_max, src.cache.lru_bytes)  # type: ignore[attr-defined]
    sim.close()
    print(json.dumps({"peak_rss_mib": rss("VmHWM:"), "rss_before_open_mib": base, "lru_peak_mib": lru_max / 2**20,
                      "lru_cap_mib": cap_mib}))  # fmt: skip


def bench_aa(args: argparse.Namespace, clip: Path) -> dict[str, Any]:
    import cv2
    import numpy as np

    from viva_sitl.camera import CameraParams, LazyPyramid, Renderer

    still = core.make_still(clip, args.rel_alt)
    fr = args.quality_frac
    zs = [f * args.rel_alt for f in fr]
    out: dict[str, Any] = {}
    why = None if args.no_ref else core.reference_available(args.ref_python)
    if why is None:
        ref = core.Reference(args.ref_python, still, replace_ns(args, z=50.0), fixed=True)
        try:
            out["ref_plain_warp"] = ref.ask("quality " + " ".join(str(z) for z in zs))
        finally:
            ref.close()
    w, h = (int(v) for v in args.out_size.lower().split("x"))
    src = core.open_bench_footage(still, args)
    image = np.ascontiguousarray(src.frame(0))
    base = CameraParams(width_px=w, height_px=h, hfov_deg=core.DEFAULT_HFOV_DEG)
    modes = {
        "ours_trilinear": base,
        "ours_mip": replace(base, trilinear=False),
        "ours_plain_warp": replace(base, antialias=False),
    }
    pyr = LazyPyramid(image)
    for name, cam in modes.items():
        r = Renderer(cam, src.geometry)
        rows = []
        for z in zs:
            t0 = time.perf_counter()
            res = r.render(pyr, (0.0, 0.0, -z), (0.0, 0.0, 0.0))
            ms = 1e3 * (time.perf_counter() - t0)
            k = 8
            t = np.array([[k, 0, (k - 1) / 2], [0, k, (k - 1) / 2], [0, 0, 1]], np.float64)
            big = cv2.warpPerspective(image, t @ res.homography, (w * k, h * k), flags=cv2.INTER_LINEAR,
                                      borderMode=cv2.BORDER_CONSTANT, borderValue=(255, 0, 255))  # fmt: skip
            truth = cv2.resize(big, (w, h), interpolation=cv2.INTER_AREA)
            rows.append({"z_m": z, "footage_px_per_output_px": res.footage_px_per_vac_px,
                         "psnr_db": core.psnr_db(res.image_bgr, truth), "render_ms": ms})  # fmt: skip
        out[name] = rows
    src.close()
    return out


def to_markdown(res: dict[str, Any]) -> str:
    lines = [f"machine: {res['machine']}", ""]
    st = res.get("steps")
    if st:
        lines += [f"disk: {json.dumps({k: round(v, 1) for k, v in st['disk_mib'].items()})} MiB", ""]
        if "auto_cache" in st:
            ac = st["auto_cache"]
            lines += [f"automatic cache (yuv420z): {ac['mib_per_frame']:.2f} MiB per frame, {ac['frames']} frames, "
                      f"first open (build) {ac['open_or_build_s']:.1f} s", ""]  # fmt: skip
        lines += [
            "| z | variant | median steps/s | ratio to ref | median CPU ms/step | CPU ratio (ref / ours) "
            "| load avg (per round) |",
            "|---|---|---:|---:|---:|---:|---|",
        ]
        for key, v in st.items():
            if not key.startswith("z"):
                continue
            for name, m in v["median_steps_per_s"].items():
                ratio = v["ratio_to_ref"].get(name)
                c = v.get("median_cpu_ms_per_step", {}).get(name, math.nan)
                cr = v.get("cpu_ratio_to_ref", {}).get(name)
                lines.append(f"| {key[1:]} m | {name} | {m:.1f} | {'' if ratio is None else f'{ratio:.2f}x'} | "
                             f"{c:.2f} | {'' if cr is None else f'{cr:.2f}x'} | {'; '.join(v['loadavg'])} |")  # fmt: skip
        lines.append("")
        more = [(key, k[len("cpu_ratio_to_") :]) for key, v in st.items() if key.startswith("z")
                for k in v if k.startswith("cpu_ratio_to_ref_")]  # fmt: skip
        if more:
            lines += ["Against the further references (median of the per-round ratios):", "",
                      "| z | variant | reference | wall ratio | CPU ratio |", "|---|---|---|---:|---:|"]  # fmt: skip
            for key, r2 in more:
                v = st[key]
                for name, cr in v[f"cpu_ratio_to_{r2}"].items():
                    lines.append(
                        f"| {key[1:]} m | {name} | {r2} | {v[f'ratio_to_{r2}'][name]:.2f}x | {cr:.2f}x |"
                    )
            lines.append("")
    sc = res.get("scale")
    if sc:
        codecs = [k[len("tiles_") : -len("_1080p_ms")] for k in next(iter(sc.values())) if k.endswith("_1080p_ms")
                  and k.startswith("tiles_")]  # fmt: skip
        lines += [
            "| z | footage | "
            + " | ".join(f"tiles {c} ms/step" for c in codecs)
            + " | video ms/step | "
            + " | ".join(f"{c} cache MiB" for c in codecs)
            + " |",
            "|---|---|" + "---:|" * (2 * len(codecs) + 1),
        ]
        for key, row in sc.items():
            for name in ("1080p", "4K", "8K"):
                cells = [f"{row[f'tiles_{c}_{name}_ms']:.2f}" for c in codecs] + [
                    f"{row[f'video_{name}_ms']:.2f}"
                ]
                cells += [f"{row[f'tiles_{c}_{name}_disk_mib']:.0f}" for c in codecs]
                lines.append(f"| {key[1:]} m | {name} | " + " | ".join(cells) + " |")
            ratios = [f"**{row[f'tiles_{c}_8K_over_1080p']:.2f}x**" for c in codecs]
            lines.append(f"| {key[1:]} m | **8K / 1080p** | " + " | ".join(ratios)
                         + f" | {row['video_8K_over_1080p']:.2f}x | load {row['loadavg']} |" + " |" * (len(codecs) - 1))  # fmt: skip
        lines.append("")
    mem = res.get("mem")
    if mem:
        lines += ["| LRU cap | LRU peak | process peak RSS (VmHWM) |", "|---:|---:|---:|"]
        for v in mem.values():
            lines.append(
                f"| {v['lru_cap_mib']} MiB | {v['lru_peak_mib']:.0f} MiB | {v['peak_rss_mib']:.0f} MiB |"
            )
        lines.append("")
    aa = res.get("aa")
    if aa:
        names = list(aa)
        lines += ["| footage px / VAC px | " + " | ".join(names) + " |", "|---:|" + "---:|" * len(names)]
        base = aa["ours_trilinear"]
        for i, row in enumerate(base):
            cells = [f"{aa[n][i]['psnr_db']:.2f}" for n in names]
            lines.append(f"| {row['footage_px_per_output_px']:.2f} | " + " | ".join(cells) + " |")
        lines.append("")
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="*", default=["steps", "scale", "mem", "aa"])
    ap.add_argument("--ref-python", default="/work/refvenv/bin/python")
    ap.add_argument("--no-ref", action="store_true")
    ap.add_argument("--ref-python-also", nargs="*", default=[],
                    help="further reference interpreters timed in the same rounds (steps), e.g. viva-safeland 0.2.5's")  # fmt: skip
    ap.add_argument("--cache-dir", type=Path, default=core.DEFAULT_CACHE)
    ap.add_argument("--frames", type=int, default=60, help="frames of the 4K clip")
    ap.add_argument("--scale-frames", type=int, default=30, help="frames of the 1080p/4K/8K scale clips")
    ap.add_argument("--scale-steps", type=int, default=60, help="steps per timed run in the scale part")
    ap.add_argument("--scale-codecs", nargs="+", default=["jpeg", "raw"], choices=["jpeg", "png", "raw"],
                    help="tile codecs of the scale part (raw at 8K: ~4 GiB for 30 frames)")  # fmt: skip
    ap.add_argument("--rel-alt", type=float, default=core.DEFAULT_REL_ALT_M)
    ap.add_argument("--z", type=float, nargs="*", default=[50.0, 300.0])
    ap.add_argument("--yaw-deg", type=float, default=30.0)
    ap.add_argument("--out-size", type=core.size_arg, default="640x480")
    ap.add_argument("--steps", type=int, default=120)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument(
        "--quality-frac",
        type=float,
        nargs="*",
        default=[0.05, 0.1, 0.15, 0.2, 0.25, 0.3, 0.4, 0.5, 0.6, 0.7, 0.9],
    )
    ap.add_argument("--markdown", type=Path)
    ap.add_argument("--json", type=Path)
    ap.add_argument("--child-mem", type=Path, help=argparse.SUPPRESS)
    ap.add_argument("--cap-mib", type=int, default=256, help=argparse.SUPPRESS)
    core.add_tile_cache_arg(ap)  # steps and scale; mem sets its own caps
    args = ap.parse_args()
    core.apply_tile_cache(ap, args)
    from viva_sitl.footage import autocache

    # "video" variants read the video: the automatic cache only where a variant names it (`_ours`)
    autocache.set_policy(autocache.CachePolicy(enabled=False))
    if args.child_mem:
        child_mem(args.child_mem, args.cap_mib)
        return 0
    clip = core.make_clip(args.cache_dir, args.frames, rel_alt_m=args.rel_alt)
    res: dict[str, Any] = {"machine": core.machine(), "command": " ".join(sys.argv),
                           "tile_cache_mb": args.tile_cache_mb}  # fmt: skip
    parts = {
        "steps": lambda: bench_steps(args, clip),
        "aa": lambda: bench_aa(args, clip),
        "mem": lambda: bench_mem(args),
        "scale": lambda: bench_scale(replace_ns(args, steps=args.scale_steps)),
    }
    for name, run in parts.items():
        if name not in args.only:
            continue
        res[name] = run()
        md = to_markdown(res)  # written after each part: a later failure keeps what was measured
        if args.markdown:
            args.markdown.write_text(md, encoding="utf-8")
        if args.json:
            args.json.write_text(json.dumps(res, indent=1, default=str), encoding="utf-8")
    print(to_markdown(res))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
