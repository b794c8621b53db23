"""What would make the tile cache cheaper: tile size, JPEG variants, the warp, and where one trial's time goes.

    /work/venv/bin/python bench/bench_tile_options.py                       # every part
    /work/venv/bin/python bench/bench_tile_options.py --only sizes --z 20 50 120 300

sizes   The bench_core.py full step (1/30 s of physics + the footage frame + a 640x480 view, hover, yaw 30 deg) over
        jpeg tile caches of the 4K bench clip with 256 (the default), 192 and 128 px tiles, interleaved in rounds:
        median CPU ms per step per altitude (the caches are built once with `footage ingest --tiles --tile-px`).
jpeg    One 256 px level-0 tile from each of 10 frames of the clip, encoded as JPEG variants (quality, chroma
        subsampling): single-thread cv2.imdecode ms per tile, KiB, PSNR against the raw tile.
warp    One 640x480 bilinear warp of a 4K frame at several scales, single thread: warpPerspective of 3- and 4-channel
        images, cv2.remap with float and 16-bit fixed-point maps of the same homography (maps precomputed).
trial   One in-process landing trial of bench_trials.py (VisionDescend, 31 s of flight, 931 frames) over the raw and
        the jpeg tile cache, with perf_counter wrappers on the stages (after a warm-up trial): seconds per trial.

Every part runs single-threaded (cv2.setNumThreads(1), one tile decode thread) with the decoded-tile LRU at
--tile-cache-mb (default 2 MiB: every frame decoded), as the trials' pool workers run. Results in
bench/results_tiles.md (Session 7).
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import os
import statistics
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

import bench_core as core  # noqa: E402
from bench_tiles import make_tiles  # noqa: E402

TILE_SIZES = (256, 192, 128)


def part_sizes(args: argparse.Namespace, clip: Path) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for z in args.z:
        a = argparse.Namespace(**{**vars(args), "z": z})
        runners = {
            px: core.Ours(make_tiles(clip, "jpeg", tile_px=px), a, paper=False, render=True)
            for px in TILE_SIZES
        }
        cpu: dict[int, list[float]] = {px: [] for px in TILE_SIZES}
        try:
            for _ in range(args.rounds):
                for px, o in runners.items():
                    cpu[px].append(o.run()[1])
        finally:
            for o in runners.values():
                o.close()
        out[f"z{z:g}"] = {f"{px}px_cpu_ms_per_step": statistics.median(v) for px, v in cpu.items()}
        print(f"sizes z={z:g} m: " + ", ".join(f"{k} {v:.2f}" for k, v in out[f"z{z:g}"].items()), flush=True)
    return out


def part_jpeg(clip: Path) -> dict[str, Any]:
    import cv2
    import numpy as np

    from viva_sitl.footage.tiles import TileCache

    raw = TileCache(make_tiles(clip, "raw"), cache_bytes=1 << 20, decode_threads=1)
    try:
        tiles = [np.ascontiguousarray(raw.region(f, 0, 1024, 512, 1280, 768)) for f in range(0, 60, 6)]
    finally:
        raw.close()
    q, sf = cv2.IMWRITE_JPEG_QUALITY, cv2.IMWRITE_JPEG_SAMPLING_FACTOR
    variants = {
        "q95 4:4:4 (ours)": ([q, 95, sf, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444], cv2.IMREAD_COLOR),
        "q95 4:4:4, EXIF orientation ignored": (
            [q, 95, sf, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444],
            cv2.IMREAD_COLOR | cv2.IMREAD_IGNORE_ORIENTATION,
        ),
        "q95 4:2:2": ([q, 95, sf, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_422], cv2.IMREAD_COLOR),
        "q95 4:2:0": ([q, 95, sf, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420], cv2.IMREAD_COLOR),
        "q90 4:4:4": ([q, 90, sf, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444], cv2.IMREAD_COLOR),
    }
    out: dict[str, Any] = {}
    for name, (params, flag) in variants.items():
        enc = [cv2.imencode(".jpg", t, params)[1] for t in tiles]
        t0 = time.perf_counter()
        for _ in range(20):
            for e in enc:
                cv2.imdecode(e, flag)
        ms = (time.perf_counter() - t0) / (20 * len(enc)) * 1e3
        psnr = statistics.mean(
            cv2.PSNR(cv2.imdecode(e, cv2.IMREAD_COLOR), t) for e, t in zip(enc, tiles, strict=True)
        )
        out[name] = {"decode_ms": ms, "kib": statistics.mean(len(e) for e in enc) / 1024, "psnr_db": psnr}
        print(f"jpeg {name}: {ms:.3f} ms, {out[name]['kib']:.1f} KiB, {psnr:.1f} dB", flush=True)
    return out


def part_warp() -> dict[str, Any]:
    import cv2
    import numpy as np

    rng = np.random.default_rng(0)
    src3 = rng.integers(0, 255, (2160, 3840, 3), dtype=np.uint8)
    src4 = cv2.cvtColor(src3, cv2.COLOR_BGR2BGRA)
    xs, ys = np.meshgrid(np.arange(640, dtype=np.float64), np.arange(480, dtype=np.float64))
    flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
    out: dict[str, Any] = {}

    def ms(fn: Callable[[], object], n: int = 100) -> float:
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        return (time.perf_counter() - t0) / n * 1e3

    for s in (0.2, 0.5, 1.0, 1.5, 2.0):  # footage px per VAC px
        c, si = math.cos(0.5), math.sin(0.5)
        h = np.array([[s * c, -s * si, 1900.0], [s * si, s * c, 1000.0], [1e-6, 2e-6, 1.0]])
        w = h[2, 0] * xs + h[2, 1] * ys + h[2, 2]
        mx = ((h[0, 0] * xs + h[0, 1] * ys + h[0, 2]) / w).astype(np.float32)
        my = ((h[1, 0] * xs + h[1, 1] * ys + h[1, 2]) / w).astype(np.float32)
        m1, m2 = cv2.convertMaps(mx, my, cv2.CV_16SC2)
        row = {
            "warpPerspective_3ch_ms": ms(
                lambda src3=src3, h=h: cv2.warpPerspective(src3, h, (640, 480), flags=flags)
            ),
            "warpPerspective_4ch_ms": ms(
                lambda src4=src4, h=h: cv2.warpPerspective(src4, h, (640, 480), flags=flags)
            ),
            "remap_float_maps_4ch_ms": ms(lambda mx=mx, my=my: cv2.remap(src4, mx, my, cv2.INTER_LINEAR)),
            "remap_16bit_maps_4ch_ms": ms(lambda m1=m1, m2=m2: cv2.remap(src4, m1, m2, cv2.INTER_LINEAR)),
        }
        out[f"scale{s:g}"] = row
        print(f"warp scale {s:g}: " + ", ".join(f"{k} {v:.3f}" for k, v in row.items()), flush=True)
    return out


def part_trial(clip: Path) -> dict[str, Any]:
    from bench_trials import bench_spec

    import viva_sitl.camera.renderer as renderer
    import viva_sitl.footage.tiles as tiles
    import viva_sitl.sim as sim
    import viva_sitl.vehicle as vehicle
    from viva_sitl.evaluation.runner import run_inprocess_trial
    from viva_sitl.evaluation.spec import draw_scenarios

    acc: dict[str, float] = {}
    wrapped = [
        (tiles.TileCache, "region", "tile region (read, CRC, decode, copy)"),
        (renderer.Renderer, "render", "renderer (warp, level choice, BGRA->BGR)"),
        (sim.Simulator, "render", "whole render"),
        (vehicle.Vehicle, "step", "vehicle step (physics + autopilot, 250 Hz)"),
    ]
    originals = [(cls, name, getattr(cls, name)) for cls, name, _ in wrapped]

    def timed(fn: Callable[..., Any], label: str) -> Callable[..., Any]:
        @functools.wraps(fn)
        def g(*a: Any, **k: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return fn(*a, **k)
            finally:
                acc[label] = acc.get(label, 0.0) + time.perf_counter() - t0

        return g

    for cls, name, label in wrapped:
        setattr(cls, name, timed(getattr(cls, name), label))
    out: dict[str, Any] = {}
    try:
        for codec in ("raw", "jpeg"):
            spec = bench_spec(str(make_tiles(clip, codec)), 4)
            sc = draw_scenarios(spec)
            with tempfile.TemporaryDirectory() as d:
                run_inprocess_trial(spec, sc[0], "bench.bench_trials:VisionDescend", Path(d) / "warm")
                acc.clear()
                walls = []
                for i in range(1, 4):
                    t0 = time.perf_counter()
                    run_inprocess_trial(spec, sc[i], "bench.bench_trials:VisionDescend", Path(d) / f"t{i}")
                    walls.append(time.perf_counter() - t0)
            out[codec] = {"whole trial": statistics.mean(walls), **{k: v / 3 for k, v in acc.items()}}
            print(f"trial {codec}: " + ", ".join(f"{k} {v:.2f} s" for k, v in out[codec].items()), flush=True)
    finally:
        for cls, name, fn in originals:
            setattr(cls, name, fn)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--only", nargs="*", default=["sizes", "jpeg", "warp", "trial"],
                    choices=["sizes", "jpeg", "warp", "trial"])  # fmt: skip
    ap.add_argument("--cache-dir", type=Path, default=core.DEFAULT_CACHE)
    ap.add_argument("--frames", type=int, default=60, help="frames of the 4K clip")
    ap.add_argument("--rel-alt", type=float, default=core.DEFAULT_REL_ALT_M)
    ap.add_argument("--z", type=float, nargs="*", default=[20.0, 50.0, 120.0, 300.0])
    ap.add_argument("--yaw-deg", type=float, default=30.0)
    ap.add_argument("--out-size", default="640x480")
    ap.add_argument("--steps", type=int, default=120)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--json", type=Path)
    core.add_tile_cache_arg(ap)
    args = ap.parse_args()
    core.apply_tile_cache(ap, args)
    os.environ["VIVA_SITL_TILE_DECODE_THREADS"] = "1"
    core.apply_tile_environment()
    import cv2

    cv2.setNumThreads(1)
    clip = core.make_clip(args.cache_dir, args.frames, rel_alt_m=args.rel_alt)
    res: dict[str, Any] = {"machine": core.machine(), "command": " ".join(sys.argv)}
    parts: dict[str, Callable[[], dict[str, Any]]] = {
        "sizes": lambda: part_sizes(args, clip),
        "jpeg": lambda: part_jpeg(clip),
        "warp": part_warp,
        "trial": lambda: part_trial(clip),
    }
    try:
        for name in args.only:
            res[name] = parts[name]()
    except KeyboardInterrupt:
        print("interrupted: parts measured so far are printed above; no JSON written", file=sys.stderr)
        return 130
    if args.json:
        args.json.write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
