"""Curves of our own perception models through `viva-sitl perception eval` (issue 23's bench).

    python bench/bench_perception_curves.py --segmenter /work/models/segmenter_synthetic.pt \\
        [--detector /work/models/detector_synthetic.pt --imgsz 480] [--n-per-cell 4] [--only NAME,...] -o OUT [--md FILE]

Runs the curve set below, one `perception eval` each (run_eval + write_outputs: OUT/<name>/results.json, cells.csv,
report.html, exactly what the CLI writes), and prints one markdown table per curve: the headline metrics of each
cell with their 95 % bootstrap CI, then the frames, seconds, frames/s and load average of the run. A curve that the
footage cannot answer (no ground truth of the kind, a view that never fits) prints the evaluator's one-line reason
instead of a table. The detector needs the perception-yolo extra (a .pt) or perception-onnx (an .onnx).

Curves (per model): altitude 10..120 m on the synthetic field; tilt 0/15/30 deg and speed 0/5/10 m/s with motion
blur (at 20 and 60 m; exposure 0.02 s, the default, and 0.1 s) on the synthetic field; altitude on the Songdo stills with SR none vs bicubic (SR only
applies where the VAC magnifies the still: the low altitudes); altitude on the interchange video (20..120 m) and on
the two SDD scenes (their footprint is ~60-80 m, so 10..30 m).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from viva_sitl.perception.effects import EffectSpec  # noqa: E402
from viva_sitl.perception.errors import PerceptionError  # noqa: E402
from viva_sitl.perception.evaluate import EvalSpec, run_eval, write_outputs  # noqa: E402

SHARED = ROOT.parent / "shared"
ALT_SYNTH = tuple(float(a) for a in range(10, 121, 10))


def curves(n: int) -> list[tuple[str, str, dict[str, Any]]]:
    """(name, what varies, EvalSpec keyword arguments without task/model)."""
    return [
        ("synth_altitude", "altitude", {"footages": ("synthetic",), "altitudes_m": ALT_SYNTH}),
        ("synth_tilt", "tilt", {"footages": ("synthetic",), "altitudes_m": (20.0, 60.0),
                                "tilts_deg": (0.0, 15.0, 30.0)}),
        ("synth_blur_speed", "speed", {"footages": ("synthetic",), "altitudes_m": (20.0, 60.0),
                                       "speeds_m_s": (0.0, 5.0, 10.0), "effects": EffectSpec.parse("blur")}),
        ("synth_blur_long", "speed", {"footages": ("synthetic",), "altitudes_m": (20.0, 60.0),
                                      "speeds_m_s": (0.0, 5.0, 10.0),
                                      "effects": EffectSpec.parse("blur", exposure_s=0.1)}),
        ("songdo_sr", "sr", {"footages": ("songdo-00003", "songdo-00972", "songdo-03936"),
                             "altitudes_m": (10.0, 20.0, 40.0, 60.0), "sr": ("none", "bicubic")}),
        ("interchange_altitude", "altitude", {"footages": ("interchange",), "altitudes_m": (20.0, 40.0, 80.0, 120.0)}),
        ("sdd_altitude", "altitude", {"footages": ("sdd-deathcircle-4", "sdd-nexus-5"),
                                      "altitudes_m": (10.0, 20.0, 30.0)}),
    ]  # fmt: skip


def cli_command(spec: EvalSpec) -> list[str]:
    """The `viva-sitl perception eval` argv that runs the same evaluation (for the report's "exact command")."""

    def vals(v: tuple[float, ...]) -> str:
        return ",".join(f"{x:g}" for x in v)

    flag = "--detector" if spec.task == "detection" else "--segmenter"
    argv = ["viva-sitl", "perception", "eval", flag, spec.model, "--footage", ",".join(spec.footages),
            "--altitudes", vals(spec.altitudes_m), "--tilt-deg", vals(spec.tilts_deg),
            "--speed-m-s", vals(spec.speeds_m_s), "--sr", ",".join(spec.sr)]  # fmt: skip
    if spec.effects.names:
        argv += ["--effects", ",".join(spec.effects.names), "--exposure-s", f"{spec.effects.exposure_s:g}"]
    argv += ["--n-per-cell", str(spec.n_per_cell), "--bootstrap", str(spec.bootstrap)]
    if spec.task == "detection":
        argv += ["--imgsz", str(spec.imgsz)]
    return argv


def _fmt(m: dict[str, Any]) -> str:
    v = m["value"]
    if v is None:
        return "n/a"
    if m["lo"] is None:
        return f"{v:.3f}"
    return f"{v:.3f} [{m['lo']:.2f}, {m['hi']:.2f}]"


def table(results: dict[str, Any], columns: list[str]) -> list[str]:
    heads = ["footage", "alt m", "tilt", "m/s", "SR", "SR applied"] + columns
    lines = ["| " + " | ".join(heads) + " |", "|" + "---|" * len(heads)]
    for c in results["cells"]:
        row = [c["footage"], f"{c['altitude_m']:g}", f"{c['tilt_deg']:g}", f"{c['speed_m_s']:g}", c["sr"],
               f"{c['sr_applied_frames']}/{c['frames']}"]  # fmt: skip
        row += [_fmt(c["metrics"][k]) for k in columns]
        lines.append("| " + " | ".join(row) + " |")
    return lines


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument(
        "--segmenter", default="", help="risk segmenter weights (.pt U-Net, .onnx, module:factory)"
    )
    ap.add_argument(
        "--detector", default="", help="detector weights (.pt ultralytics, .onnx, module:factory)"
    )
    ap.add_argument("--imgsz", type=int, default=640, help="the .pt detector's inference size")
    ap.add_argument("--n-per-cell", type=int, default=4)
    ap.add_argument("--bootstrap", type=int, default=200)
    ap.add_argument("--only", default="", help="comma-separated curve names (default: all)")
    ap.add_argument("-o", "--output", required=True, help="new directory for the per-curve outputs")
    ap.add_argument("--md", default="", help="also append the tables to this markdown file")
    args = ap.parse_args()
    if not args.segmenter and not args.detector:
        ap.error("name --segmenter and/or --detector")
    only = {s.strip() for s in args.only.split(",") if s.strip()}
    out = Path(args.output)
    models = [("segmentation", args.segmenter), ("detection", args.detector)]
    cols = {"segmentation": ["miou", "missed_danger", "lost_landing", "pixel_acc"],
            "detection": ["map50", "map50_95", "recall", "recall_near_people", "recall_near_vehicles",
                          "size_px_people", "size_px_vehicles"]}  # fmt: skip
    text: list[str] = []
    for task, weights in models:
        if not weights:
            continue
        for name, _varies, kw in curves(args.n_per_cell):
            if only and name not in only:
                continue
            spec = EvalSpec(task, weights, n_per_cell=args.n_per_cell, bootstrap=args.bootstrap,
                            imgsz=args.imgsz, **kw)  # fmt: skip
            head = (f"### {task}, {name} ({Path(weights).name}, {args.n_per_cell} frames per cell)\n\n"
                    f"`{' '.join(cli_command(spec))} -o OUT`")  # fmt: skip
            t0 = time.perf_counter()
            try:
                results, worst, timing = run_eval(spec, cli_command(spec))
            except PerceptionError as exc:
                block = [head, "", f"cannot answer: {exc}", ""]
            else:
                wall = time.perf_counter() - t0
                write_outputs(out / f"{task[:3]}_{name}", results, worst, timing)
                nfr = int(timing["frames"])
                block = [head, "", *table(results, cols[task]), "",
                         f"{nfr} frames, eval {timing['seconds']:.1f} s ({nfr / timing['seconds']:.2f} frames/s "
                         f"incl. the model), {wall:.1f} s with the model load and CIs; load avg "
                         f"{os.getloadavg()[0]:.1f}", ""]  # fmt: skip
            print("\n".join(block), flush=True)
            text += block
    if args.md:
        with open(args.md, "a") as fh:
            fh.write("\n".join(text) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
