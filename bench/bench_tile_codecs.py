"""Tile codecs on the size/speed curve (issue 22 §1): bytes per footage pixel, decode time per tile, PSNR.

    .venv/bin/python bench/bench_tile_codecs.py [--markdown out.md]

For each test image (a frame of the 4K bench clip of bench_core.py, upscaled from the 1080p interchange clip, so
smoother than real 4K; and the songdo 00003 still, a real 3840 px photo) the full mip pyramid is cut into 256 px
tiles as the tile cache does (`viva_sitl.footage.tiles.encode_frame`), and every codec is timed on one thread
(`cv2.setNumThreads(1)`), in this thread's CPU time (time.thread_time: what load barely changes):

- bytes/px: encoded bytes of the whole pyramid / level-0 pixels (the issue's bound: ~8 MiB per 4K frame = 1.0);
- decode µs per tile: median over the level-0 tiles and over the coarse levels (into a BGR tile, the cache's LRU);
- PSNR dB of the decoded level 0 against the raw one, and the worst of levels 1-3 (what views from 50-500 m read).

Codecs are the ones `viva_sitl.footage.tiles` can write, plus lossless zstd on BGR for comparison.
`--yuvz-levels 3 -5 -50`: yuv420z again with its zstd tiles written at each of these zstd levels (the cache uses
YUVZ_LEVEL; negative levels are zstd's fast modes: larger, decoded faster), the points between yuv420z and raw on
the size/speed curve. "level 0 into BGRA" is what the renderer's region read costs per level-0 tile (yuv420z
converts YUV straight to BGRA; the others decode BGR, then a BGR -> BGRA pass). yuv420zg (`--cache-compact`'s): yuv420z
with level 0's planes gradient-coded (left + up - up-left residuals, zstd level 1, undone by cv2.integral).

    .venv/bin/python bench/bench_tile_codecs.py --yuvz-levels 3 1 -1 -5 -20 -50
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from pathlib import Path

import cv2
import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "bench"))

import bench_core as core  # noqa: E402

from viva_sitl.footage import tiles  # noqa: E402
from viva_sitl.footage.tiles import format as tiles_format  # noqa: E402


def psnr(a: np.ndarray, b: np.ndarray) -> float:
    d = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return float("inf") if d == 0 else 10 * np.log10(255.0**2 / d)


def images(args: argparse.Namespace) -> dict[str, np.ndarray]:
    out = {}
    clip = core.make_clip(args.cache_dir, 60, rel_alt_m=core.DEFAULT_REL_ALT_M)
    cap = cv2.VideoCapture(str(clip))
    for _ in range(10):
        ok, frame = cap.read()
    cap.release()
    if ok:
        out["4K bench clip, frame 9"] = frame
    if core.SONGDO_STILL.exists():
        out["songdo 00003 (3840 px photo)"] = cv2.imread(str(core.SONGDO_STILL))
    return out


def measure(img: np.ndarray, codec: str, quality: int) -> dict[str, float]:
    layout = tiles.TileLayout.of(img.shape[1], img.shape[0], tiles.DEFAULT_TILE_PX)
    pyr = tiles.frame_pyramid(img)
    t0 = time.thread_time()
    blobs = tiles.encode_frame(img, layout, codec, quality)
    enc_s = time.thread_time() - t0
    fine: list[float] = []
    fine_bgra: list[float] = []
    coarse: list[float] = []
    worst = l0 = float("inf")
    i = 0
    ts = layout.tile_px
    for level, lv in enumerate(pyr):
        nx, ny = layout.grid[level]
        dec = np.empty_like(lv)
        for ty in range(ny):
            for tx in range(nx):
                b = blobs[i]
                i += 1
                t = time.thread_time()
                tile = tiles._decode(b, codec)
                dt = time.thread_time() - t
                assert tile is not None
                (fine if level == 0 else coarse).append(dt)
                if (
                    level == 0
                ):  # the renderer's read: BGRA (straight from YUV for yuv420z, else one more pass)
                    t = time.thread_time()
                    four = tiles._decode(b, codec, bgra=True)
                    assert four is not None
                    if four.shape[2] == 3:
                        four = cv2.cvtColor(four, cv2.COLOR_BGR2BGRA)
                    fine_bgra.append(time.thread_time() - t)
                dec[ty * ts : ty * ts + tile.shape[0], tx * ts : tx * ts + tile.shape[1]] = tile
        if level == 0:
            l0 = psnr(dec, lv)
        elif level <= 3:
            worst = min(worst, psnr(dec, lv))
    px = img.shape[0] * img.shape[1]
    return {
        "bytes_per_px": sum(len(b) for b in blobs) / px,
        "mib_per_4k_frame": sum(len(b) for b in blobs) / px * 3840 * 2160 / 2**20,
        "decode_us_l0": 1e6 * statistics.median(fine),
        "decode_us_l0_bgra": 1e6 * statistics.median(fine_bgra),
        "decode_us_coarse": 1e6 * statistics.median(coarse),
        "encode_s_per_frame": enc_s,
        "psnr_l0_db": l0,
        "worst_psnr_l1_l3_db": worst,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache-dir", type=Path, default=core.DEFAULT_CACHE)
    ap.add_argument("--markdown", type=Path)
    ap.add_argument(
        "--yuvz-levels", type=int, nargs="*", default=[],
        help="also yuv420z with its zstd tiles at these zstd levels (negative: zstd's fast modes)",
    )  # fmt: skip
    args = ap.parse_args()
    cv2.setNumThreads(1)
    codecs: list[tuple[str, int, int | None]] = [("raw", 0, None), ("jpeg", 95, None), ("png", 0, None),
                                                 ("yuv420z", 95, None), ("yuv420zg", 95, None)]  # fmt: skip
    codecs += [("yuv420z", 95, lv) for lv in args.yuvz_levels]
    lines = [
        f"machine: {core.machine()}",
        "",
        "| image | codec | bytes/px (pyramid / level-0 px) | MiB per 4K frame | decode µs/tile, level 0 | "
        "level 0 into BGRA µs/tile | decode µs/tile, coarse | encode s/frame | PSNR dB level 0 | "
        "worst PSNR dB levels 1-3 |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    default_level = tiles_format.YUVZ_LEVEL
    for name, img in images(args).items():
        for codec, q, zlevel in codecs:
            tiles_format.YUVZ_LEVEL = default_level if zlevel is None else zlevel
            try:
                m = measure(img, codec, q)
            finally:
                tiles_format.YUVZ_LEVEL = default_level
            label = f"{codec} q{q}" if codec != "raw" and codec != "png" else codec
            if codec == "yuv420z":
                label += f", zstd level {default_level if zlevel is None else zlevel}"
            elif codec == "yuv420zg":  # level 0 gradient-coded (--cache-compact), level 1 as yuv420z's
                label += f", level 0 gradient + zstd level {tiles_format.YUVG_LEVEL}"
            lines.append(
                f"| {name} | {label} | {m['bytes_per_px']:.3f} | {m['mib_per_4k_frame']:.1f} | "
                f"{m['decode_us_l0']:.0f} | {m['decode_us_l0_bgra']:.0f} | {m['decode_us_coarse']:.0f} | "
                f"{m['encode_s_per_frame']:.2f} | {m['psnr_l0_db']:.2f} | {m['worst_psnr_l1_l3_db']:.2f} |"
            )
            print(lines[-1], flush=True)
    if args.markdown:
        args.markdown.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
