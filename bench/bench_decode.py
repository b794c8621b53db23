"""Decode cost per footage frame: 1080p (the shared clip), 4K and 8K (the clip upscaled with PyAV/x264), with and
without BGR conversion, through our VideoSource, through the ingest cache, and with cv2.VideoCapture for comparison.

    python bench/bench_decode.py [--frames 30] [--work-dir DIR] [--write bench/results_decode.md]

The 4K/8K clips are encoded once (x264 `superfast`, CABAC on, crf 16: a high bit rate like DJI footage) into
--work-dir (default <cache>/bench-decode) and reused. Every figure is the median over `--frames` sequential frames of
the time to get one frame; the first frame (decoder start-up) is not counted.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable, Iterator
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np

from viva_sitl.footage import open_footage
from viva_sitl.footage.ingest import ingest
from viva_sitl.footage.paths import default_cache_dir
from viva_sitl.footage.source import VideoSource, to_bgr

SHARED_CLIP = (
    Path(__file__).resolve().parents[2] / "shared" / "footage" / "interchange" / "interchange_1080p.mp4"
)
SIZES = {"1080p": (1920, 1080), "4K": (3840, 2160), "8K": (7680, 4320)}


def make_clip(src: Path, dest: Path, size: tuple[int, int], frames: int) -> Path:
    """The first `frames` frames of src upscaled (bicubic) to `size`, x264 superfast crf 16, 25 fps."""
    if dest.exists():
        return dest
    tmp = dest.with_name(dest.stem + ".part.mp4")
    with av.open(str(src)) as ic, av.open(str(tmp), mode="w") as oc:
        ist = ic.streams.video[0]
        ist.thread_type = "AUTO"
        rate = Fraction(ist.average_rate or 25)
        st = oc.add_stream("libx264", rate=rate)
        st.width, st.height, st.pix_fmt = size[0], size[1], "yuv420p"
        st.codec_context.time_base = 1 / rate
        st.options = {"preset": "superfast", "crf": "16", "g": "60"}
        for n, frame in enumerate(ic.decode(ist)):
            if n >= frames:
                break
            big = frame.reformat(width=size[0], height=size[1], format="yuv420p", interpolation="BICUBIC")
            big.pts, big.time_base = n, 1 / rate
            for pkt in st.encode(big):
                oc.mux(pkt)
        for pkt in st.encode(None):
            oc.mux(pkt)
    tmp.replace(dest)
    return dest


def timed(get: Callable[[], object], n: int) -> float:
    """Median ms of n calls after one warm-up call."""
    get()
    samples = []
    for _ in range(n):
        t0 = time.perf_counter()
        get()
        samples.append((time.perf_counter() - t0) * 1e3)
    return statistics.median(samples)


def pyav_frames(path: Path) -> Iterator[av.VideoFrame]:
    with av.open(str(path)) as c:
        st = c.streams.video[0]
        st.thread_type = "AUTO"
        while True:
            yield from c.decode(st)
            c.seek(0, stream=st)  # loop, so n frames are always available


def cv2_bgr(frame: av.VideoFrame) -> np.ndarray:
    return cv2.cvtColor(frame.to_ndarray(), cv2.COLOR_YUV2BGR_I420)


def bench_clip(path: Path, n: int) -> dict[str, float]:
    out: dict[str, float] = {}
    it = pyav_frames(path)
    out["pyav_decode"] = timed(lambda: next(it), n)
    it = pyav_frames(path)
    out["pyav_decode_bgr24"] = timed(lambda: next(it).to_ndarray(format="bgr24"), n)
    it = pyav_frames(path)
    out["pyav_decode_cv2bgr"] = timed(lambda: cv2_bgr(next(it)), n)
    one = next(pyav_frames(path))  # conversion alone, on one decoded frame (no decode noise)
    out["convert_swscale_bgr24"] = timed(lambda: one.to_ndarray(format="bgr24"), 2 * n)
    out["convert_cv2_i420"] = timed(lambda: cv2_bgr(one), 2 * n)
    out["convert_to_bgr"] = timed(lambda: to_bgr(one), 2 * n)
    with open_footage(path, altitude_m=100.0, hfov_deg=82.1) as src:
        assert isinstance(src, VideoSource)
        k = iter(range(10**9))
        out["videosource_seq"] = timed(lambda: src.frame(next(k) % src.frame_count), n)
        rng = np.random.default_rng(0)
        out["videosource_random"] = timed(
            lambda: src.frame(int(rng.integers(0, src.frame_count))), max(5, n // 3)
        )
    cap = cv2.VideoCapture(str(path))
    try:

        def read() -> None:
            ok, _ = cap.read()
            if not ok:
                cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                cap.read()

        out["cv2_videocapture_bgr"] = timed(read, n)
    finally:
        cap.release()
    return out


def bench_ingest(path: Path, work: Path, n: int, repeat: int) -> dict[str, float]:
    dest = work / (path.stem + "-ingest")
    t0 = time.perf_counter()
    built = not (dest / "full.mp4").exists()
    if built:
        if path != SHARED_CLIP:  # the shared clip's metadata is viva_sitl/data/footage/interchange.toml
            path.with_suffix(".toml").write_text("recording_altitude_m = 100.0\nhfov_deg = 82.1\n")
        ingest(path, out_dir=dest, levels=2, show_progress=False, max_frames=n + 1)
    out = {"ingest_build_s": time.perf_counter() - t0 if built else float("nan")}  # nan: cache reused
    with open_footage(dest) as src:
        assert isinstance(src, VideoSource)
        k = iter(range(10**9))
        out["ingest_full_seq"] = timed(lambda: src.frame(next(k) % src.frame_count), n * repeat)
        rng = np.random.default_rng(0)
        out["ingest_full_random"] = timed(
            lambda: src.frame(int(rng.integers(0, src.frame_count))), max(5, n // 3)
        )
        k2 = iter(range(10**9))
        out["ingest_half_seq"] = timed(lambda: src.frame(next(k2) % src.frame_count, level=1), n * repeat)
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=30, help="frames per clip (4K/8K clips are this long)")
    ap.add_argument(
        "--repeat", type=int, default=3, help="passes over the clip per figure (shared machine: noise)"
    )
    ap.add_argument("--work-dir", type=Path, default=default_cache_dir() / "bench-decode")
    ap.add_argument("--sizes", default="1080p,4K,8K")
    ap.add_argument("--write", type=Path, help="write a markdown report here")
    args = ap.parse_args()
    if not SHARED_CLIP.is_file():
        print(f"shared clip missing: {SHARED_CLIP}", file=sys.stderr)
        return 2
    args.work_dir.mkdir(parents=True, exist_ok=True)
    n = args.frames
    results: dict[str, dict[str, float]] = {}
    for name in args.sizes.split(","):
        if name == "1080p":
            clip = SHARED_CLIP
        else:
            t0 = time.perf_counter()
            clip = make_clip(SHARED_CLIP, args.work_dir / f"interchange_{name}.mp4", SIZES[name], n + 1)
            print(f"# {name} clip {clip} ({time.perf_counter() - t0:.1f} s to make/find)", file=sys.stderr)
        r = bench_clip(clip, n * args.repeat)
        r.update(bench_ingest(clip, args.work_dir, n, args.repeat))
        r["size_mb"] = clip.stat().st_size / 1e6
        results[name] = r
        print(f"{name}: " + ", ".join(f"{k} {v:.2f}" for k, v in r.items()), flush=True)
    rows = [
        ("pyav_decode", "PyAV decode only (YUV, no conversion)"),
        ("pyav_decode_bgr24", "PyAV decode + to_ndarray('bgr24') (swscale)"),
        ("pyav_decode_cv2bgr", "PyAV decode + I420 planes + cv2.cvtColor"),
        ("videosource_seq", "VideoSource.frame(i), sequential"),
        ("videosource_random", "VideoSource.frame(i), random index (seek)"),
        ("cv2_videocapture_bgr", "cv2.VideoCapture.read() (BGR)"),
        ("ingest_full_seq", "ingest cache full.mp4, sequential"),
        ("ingest_full_random", "ingest cache full.mp4, random index (seek)"),
        ("ingest_half_seq", "ingest cache half.mp4 (level 1), sequential"),
    ]
    names = list(results)
    lines = ["| ms per frame (median) | " + " | ".join(names) + " |", "|---|" + "---:|" * len(names)]
    for key, label in rows:
        lines.append(f"| {label} | " + " | ".join(f"{results[s][key]:.1f}" for s in names) + " |")
    lines.append("| ratio cv2.VideoCapture / VideoSource (sequential) | " + " | ".join(
        f"{results[s]['cv2_videocapture_bgr'] / results[s]['videosource_seq']:.2f}x" for s in names) + " |")  # fmt: skip
    for key, label in (("convert_swscale_bgr24", "conversion only: PyAV to_ndarray('bgr24')"),
                       ("convert_cv2_i420", "conversion only: I420 planes + cv2.cvtColor"),
                       ("convert_to_bgr", "conversion only: our to_bgr (swscale <= 4096 px wide, else cv2)")):  # fmt: skip
        lines.append(f"| {label} | " + " | ".join(f"{results[s][key]:.1f}" for s in names) + " |")
    lines.append("| ratio swscale / cv2 conversion | " + " | ".join(
        f"{results[s]['convert_swscale_bgr24'] / results[s]['convert_cv2_i420']:.2f}x" for s in names) + " |")  # fmt: skip
    lines.append("| ratio VideoSource / ingest cache (sequential) | " + " | ".join(
        f"{results[s]['videosource_seq'] / results[s]['ingest_full_seq']:.2f}x" for s in names) + " |")  # fmt: skip
    lines.append("| ingest build time, s (frames+1, full + half) | " + " | ".join(f"{results[s]['ingest_build_s']:.1f}".replace("nan", "reused") for s in names) + " |")  # fmt: skip
    lines.append(
        "| source file size, MB | " + " | ".join(f"{results[s]['size_mb']:.1f}" for s in names) + " |"
    )
    table = "\n".join(lines)
    print(table)
    if args.write:
        machine = f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, PyAV {av.__version__}, OpenCV {cv2.__version__}"
        args.write.write_text(
            "# Decode benchmark (bench/bench_decode.py)\n\n"
            f"Command: `python bench/bench_decode.py --frames {n} --repeat {args.repeat} --write {args.write}`  \nMachine: {machine}\n\n"
            + table
            + "\n",
            encoding="utf-8",
        )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
