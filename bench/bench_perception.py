"""Perception benchmarks: super-resolution quality and cost (more parts: see --help).

    python bench/bench_perception.py sr [--edsr-steps 400] [--out bench/results_perception_sr.md]

SR: held-out footage = Songdo 03936 and interchange frames 120/170 (EDSR trains on Songdo 00003/00972 and interchange
frames 0..60 only). Each test image gives 640x480 high-resolution crops; the low-resolution input is their area
downscale by the model's scale (what the VAC reads when it magnifies the footage by that factor at 640x480), and each
method upscales it back; PSNR / SSIM on luma against the crop (scale px border ignored), medians over crops. ms per
frame: one upscale of that input (640x480 output), median of N after a warm-up, OpenCV/torch threads as set. End to end:
Simulator.render over the interchange at 40 m (x4 magnification), with and without the hook, medians interleaved.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from viva_sitl.perception import BicubicUpscaler, MagnifiedRender, OpenCVSR, Upscaler  # noqa: E402
from viva_sitl.perception.quality import degrade_area, psnr_db, ssim  # noqa: E402

SHARED = ROOT.parent / "shared"
SR_DIR = SHARED / "models" / "sr"
SONGDO = SHARED / "footage" / "songdo"
CLIP = SHARED / "footage" / "interchange" / "interchange_1080p.mp4"


def _median_ms(fn: Callable[[], object], n: int) -> float:
    fn()
    out = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t) * 1e3)
    return statistics.median(out)


def _video_frames(indices: list[int]) -> dict[int, np.ndarray]:
    cap = cv2.VideoCapture(str(CLIP))
    out: dict[int, np.ndarray] = {}
    i = 0
    while len(out) < len(indices):
        ok, frame = cap.read()
        if not ok:
            break
        if i in indices:
            out[i] = frame
        i += 1
    cap.release()
    return out


def _crops(img: np.ndarray, n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    h, w = img.shape[:2]
    out = []
    for _ in range(n):
        y, x = int(rng.integers(0, h - 480 + 1)), int(rng.integers(0, w - 640 + 1))
        out.append(np.ascontiguousarray(img[y : y + 480, x : x + 640]))
    return out


def bench_sr(args: argparse.Namespace) -> str:
    cv2.setNumThreads(args.threads)
    frames = _video_frames(list(range(0, 61, 10)) + [120, 170])
    train = [cv2.imread(str(SONGDO / f"{k}.jpg")) for k in ("00003", "00972")] + [
        frames[i] for i in range(0, 61, 10)
    ]
    test = {"songdo 03936": cv2.imread(str(SONGDO / "03936.jpg")), "interchange f120": frames[120],
            "interchange f170": frames[170]}  # fmt: skip
    methods: dict[str, Upscaler] = {}
    for s in (2, 3, 4):
        methods[f"bicubic_x{s}"] = BicubicUpscaler(s)
    for name in (
        "FSRCNN_x2",
        "FSRCNN-small_x2",
        "ESPCN_x2",
        "FSRCNN_x3",
        "ESPCN_x3",
        "FSRCNN_x4",
        "ESPCN_x4",
    ):
        methods[name] = OpenCVSR(SR_DIR / f"{name}.pb")
    edsr_note = "EDSR: not measured (torch absent: pip install 'viva-sitl[perception]')"
    try:
        import torch

        from viva_sitl.perception.edsr import EDSRUpscaler, train_edsr

        torch.set_num_threads(args.threads)
        t0 = time.perf_counter()
        model, losses = train_edsr(
            train,
            scale=2,
            steps=args.edsr_steps,
            patch_px=24,
            batch=16,
            seed=0,
            n_feats=args.edsr_feats,
            n_resblocks=args.edsr_blocks,
        )
        train_s = time.perf_counter() - t0
        methods["EDSR_x2 (ours)"] = EDSRUpscaler(model)
        n_params = sum(p.numel() for p in model.parameters())
        edsr_note = (
            f"EDSR (ours): {args.edsr_feats} features, {args.edsr_blocks} residual blocks, {n_params} parameters, bicubic global residual; trained "
            f"self-supervised for {args.edsr_steps} steps (batch 16, 48 px HR patches, L1, Adam 1e-3 cosine) on "
            f"Songdo 00003/00972 + interchange frames 0..60 in {train_s:.0f} s on this CPU (torch {torch.__version__}, "
            f"{args.threads} threads); L1 loss first/last 20 steps {np.mean(losses[:20]):.4f} / {np.mean(losses[-20:]):.4f}"
        )
    except ImportError:
        pass
    rows = []
    for name, up in methods.items():
        s = up.scale
        psnrs, ssims, gains = [], [], []
        for k, img in enumerate(test.values()):
            for crop in _crops(img, args.crops, seed=k):
                lr = degrade_area(crop, s)
                hr = crop[: lr.shape[0] * s, : lr.shape[1] * s]
                out = up.upscale(lr)
                p, q = psnr_db(out, hr, s), ssim(out, hr, s)
                b = psnr_db(BicubicUpscaler(s).upscale(lr), hr, s)
                psnrs.append(p)
                ssims.append(q)
                gains.append(p - b)
        lr0 = degrade_area(_crops(test["songdo 03936"], 1, 0)[0], s)
        ms = _median_ms(lambda up=up, lr0=lr0: up.upscale(lr0), args.n)  # type: ignore[misc]
        rows.append(
            (name, s, statistics.median(psnrs), statistics.median(gains), statistics.median(ssims), ms)
        )
    lines = [
        "## Super-resolution (held-out footage)",
        "",
        f"- {edsr_note}",
        f"- {len(test)} held-out images x {args.crops} crops of 640x480; input = area downscale by the scale; "
        f"ms = one upscale to ~640x480 (median of {args.n}), cv2/torch threads {args.threads}",
        "",
        "| method | scale | PSNR dB (median) | gain over bicubic dB (median) | SSIM (median) | ms per 640x480 output |",
        "|---|---|---|---|---|---|",
    ]
    for name, s, p, g, q, ms in rows:
        lines.append(f"| {name} | x{s} | {p:.2f} | {g:+.2f} | {q:.4f} | {ms:.1f} |")
    print("\n".join(lines), flush=True)  # the quality table survives a failure of the end-to-end part
    lines += ["", _bench_sr_sim(args, methods)]
    return "\n".join(lines)


def _bench_sr_sim(args: argparse.Namespace, methods: dict[str, Upscaler]) -> str:
    from viva_sitl.sim import Simulator

    out = [
        "### End to end: Simulator.render at 40 m over the interchange (x4 magnification, 640x480), ms per frame",
        "",
        "| hook | ms per frame (median) | ratio to no SR |",
        "|---|---|---|",
    ]
    with Simulator(footage="interchange") as sim:
        sim.reset(pos_ned_m=(0.0, 0.0, -40.0))
        sim.render()
        choice = ["none"] + [k for k in ("bicubic_x2", "FSRCNN-small_x2", "FSRCNN_x2", "ESPCN_x2", "ESPCN_x4",
                                         "EDSR_x2 (ours)") if k in methods]  # fmt: skip
        times: dict[str, list[float]] = {k: [] for k in choice}
        hooks = {k: (None if k == "none" else MagnifiedRender(methods[k], 1.0)) for k in choice}
        for _ in range(args.n):
            for k in choice:
                sim.super_resolution = hooks[k]
                t = time.perf_counter()
                sim.render()
                times[k].append((time.perf_counter() - t) * 1e3)
        base = statistics.median(times["none"])
        for k in choice:
            m = statistics.median(times[k])
            out.append(f"| {k} | {m:.1f} | {m / base:.1f}x |")
    return "\n".join(out)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("part", choices=["sr"])
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--crops", type=int, default=4)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--edsr-steps", type=int, default=200)
    ap.add_argument("--edsr-feats", type=int, default=24)
    ap.add_argument("--edsr-blocks", type=int, default=4)
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    body = bench_sr(args)
    head = (
        f"# Perception benchmark: {args.part} (bench/bench_perception.py)\n\n"
        f"- Command: `python bench/bench_perception.py {' '.join(sys.argv[1:])}`\n"
        f"- Machine: {platform.processor() or platform.machine()}, nproc {os.cpu_count()}, Python "
        f"{platform.python_version()}, OpenCV {cv2.__version__}; shared with other jobs while it ran (noisy ms)\n\n"
    )
    text = head + body + "\n"
    print(text)
    if args.out:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
