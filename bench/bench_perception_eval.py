"""Throughput of `viva-sitl perception eval` on this CPU: frames/s of render + ground truth + scoring per setting.

    python bench/bench_perception_eval.py [--n-per-cell 2] [--out FILE]

The models are the free ones of tests/perception_oracles.py (an empty detector, an all-level-1 segmenter), so the
figure is the evaluator's own cost per frame: a user's model adds its own inference time on top. Settings: the
synthetic field at 10..60 m (6 altitudes x n frames, 640x480) for detection and segmentation, with no effect, with
blur + noise at 5 m/s and with lens distortion; a Songdo still (needs ../shared) at 10 and 20 m without and with
bicubic super-resolution. Each setting runs once after a warm-up run of the first; load average printed with it.
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests"))

from viva_sitl.perception.effects import EffectSpec  # noqa: E402
from viva_sitl.perception.evaluate import EvalSpec, run_eval  # noqa: E402

SHARED = ROOT.parent / "shared"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n-per-cell", type=int, default=2)
    ap.add_argument("--out", default="", help="also append the table to this file")
    args = ap.parse_args()
    synth = {"footages": ("synthetic",), "altitudes_m": (10.0, 20.0, 30.0, 40.0, 50.0, 60.0),
             "n_per_cell": args.n_per_cell, "bootstrap": 200}  # fmt: skip
    blur = EffectSpec.parse("blur,noise")
    cases: list[tuple[str, EvalSpec]] = [
        ("detection, synthetic, no effect", EvalSpec("detection", "perception_oracles:empty_detector", **synth)),
        ("detection, synthetic, blur+noise 5 m/s",
         EvalSpec("detection", "perception_oracles:empty_detector", **synth, effects=blur, speeds_m_s=(5.0,))),
        ("detection, synthetic, lens distortion",
         EvalSpec("detection", "perception_oracles:empty_detector", **synth,
                  effects=EffectSpec.parse("distortion"))),
        ("segmentation, synthetic, no effect",
         EvalSpec("segmentation", "perception_oracles:all_safe_segmenter", **synth)),
        ("segmentation, synthetic, lens distortion",
         EvalSpec("segmentation", "perception_oracles:all_safe_segmenter", **synth,
                  effects=EffectSpec.parse("distortion"))),
    ]  # fmt: skip
    if (SHARED / "footage" / "songdo" / "00003.jpg").is_file():
        songdo = {
            "footages": ("songdo-00003",),
            "altitudes_m": (10.0, 20.0),
            "n_per_cell": 3 * args.n_per_cell,
        }
        cases += [
            ("detection, Songdo 00003, SR none", EvalSpec("detection", "perception_oracles:empty_detector", **songdo)),
            ("detection, Songdo 00003, SR bicubic",
             EvalSpec("detection", "perception_oracles:empty_detector", **songdo, sr=("bicubic",))),
        ]  # fmt: skip
    run_eval(cases[0][1])  # warm-up: imports, the synthetic field's textures
    lines = [f"{platform.processor() or platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}",
             "", "| setting | frames | s | frames/s | SR applied | load avg |", "| --- | ---: | ---: | ---: | ---: | ---: |"]  # fmt: skip
    for name, spec in cases:
        t0 = time.perf_counter()
        res, _, timing = run_eval(spec)
        wall = time.perf_counter() - t0
        applied = sum(c["sr_applied_frames"] for c in res["cells"])
        n = int(timing["frames"])
        lines.append(
            f"| {name} | {n} | {wall:.2f} | {n / wall:.1f} | {applied}/{n} | {os.getloadavg()[0]:.1f} |"
        )
        print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    print(text)
    if args.out:
        with open(args.out, "a") as fh:
            fh.write(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
