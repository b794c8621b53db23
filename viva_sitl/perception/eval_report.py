"""The self-contained HTML report of `perception eval` (and of `--compare`): no file beside it, no script, no network.

    html = build_html(results, worst_frames, timing)      # curves over altitude (inline SVG, 95 % CI bands), a table
                                                          # per cell, the worst frames (JPEG, base64) and the command
    diff = compare(load_results(a), load_results(b))     # paired differences per cell (compare.json)
    html = compare_html(diff)

Curves: one chart per headline metric, one line per (footage, tilt, speed, SR) over altitude; a null value
(unavailable) is a gap, never drawn as 0.
"""

from __future__ import annotations

import base64
import html
import shlex
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.perception.errors import PerceptionError

U8 = NDArray[np.uint8]
PALETTE = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#17becf", "#8c564b", "#e377c2", "#7f7f7f")
LEVEL_BGR = ((0, 0, 0), (80, 175, 76), (59, 235, 255), (0, 152, 255), (34, 87, 255), (28, 28, 183))


def level_colours() -> U8:
    """(6, 3) BGR colour of risk levels 0 (no ground: black), 1 (green) .. 5 (dark red), for a lookup `lut[mask]`."""
    return np.array(LEVEL_BGR, np.uint8)


def _fmt(v: Any) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.3f}"
    return html.escape(str(v))


def _series_key(c: dict[str, Any]) -> str:
    return f"{c['footage']} tilt {c['tilt_deg']:g} deg, {c['speed_m_s']:g} m/s, SR {c['sr']}"


def svg_curve(cells: list[dict[str, Any]], metric: str, value_key: str = "metrics", title: str = "") -> str:
    """An inline SVG: `metric` over altitude, one line (and CI band) per series; gaps where the value is null."""
    w, h, ml, mr, mt, mb = 560, 300, 50, 200, 24, 36
    series: dict[str, list[tuple[float, float | None, float | None, float | None]]] = {}
    for c in cells:
        m = c[value_key][metric]
        series.setdefault(_series_key(c), []).append((c["altitude_m"], m["value"], m.get("lo"), m.get("hi")))
    alts = sorted({a for s in series.values() for a, *_ in s})
    vals = [v for s in series.values() for _, *vs in s for v in vs if v is not None]
    if not alts:
        return ""
    lo_v, hi_v = (min(vals + [0.0]), max(vals + [1.0])) if vals else (0.0, 1.0)
    if not metric.startswith("size_px") and value_key != "diff":
        lo_v, hi_v = min(lo_v, 0.0), max(hi_v, 1.0)
    if hi_v - lo_v < 1e-9:
        hi_v = lo_v + 1.0
    a0, a1 = alts[0], alts[-1] if alts[-1] > alts[0] else alts[0] + 1.0

    def x(a: float) -> float:
        return ml + (a - a0) / (a1 - a0) * (w - ml - mr)

    def y(v: float) -> float:
        return mt + (hi_v - v) / (hi_v - lo_v) * (h - mt - mb)

    parts = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" font-size="11">',
             f'<text x="{ml}" y="14" font-weight="bold">{html.escape(title or metric)}</text>',
             f'<line x1="{ml}" y1="{h - mb}" x2="{w - mr}" y2="{h - mb}" stroke="#444"/>',
             f'<line x1="{ml}" y1="{mt}" x2="{ml}" y2="{h - mb}" stroke="#444"/>']  # fmt: skip
    for t in np.linspace(lo_v, hi_v, 5):
        parts.append(f'<text x="{ml - 4}" y="{y(t) + 4:.1f}" text-anchor="end">{t:.2f}</text>')
        parts.append(f'<line x1="{ml}" y1="{y(t):.1f}" x2="{w - mr}" y2="{y(t):.1f}" stroke="#eee"/>')
    for a in alts:
        parts.append(f'<text x="{x(a):.1f}" y="{h - mb + 14}" text-anchor="middle">{a:g}</text>')
    parts.append(f'<text x="{(ml + w - mr) / 2:.0f}" y="{h - 4}" text-anchor="middle">altitude (m)</text>')
    for si, (name, pts) in enumerate(sorted(series.items())):
        col = PALETTE[si % len(PALETTE)]
        pts = sorted(pts, key=lambda p: p[0])
        runs: list[list[tuple[float, float, float | None, float | None]]] = [[]]
        for a, v, lo, hi in pts:
            if v is None:
                runs.append([])
            else:
                runs[-1].append((a, v, lo, hi))
        for run in runs:
            band = [(a, lo, hi) for a, _, lo, hi in run if lo is not None and hi is not None]
            if len(band) >= 2:
                poly = [f"{x(a):.1f},{y(hi):.1f}" for a, _, hi in band]
                poly += [f"{x(a):.1f},{y(lo):.1f}" for a, lo, _ in reversed(band)]
                parts.append(f'<polygon points="{" ".join(poly)}" fill="{col}" fill-opacity="0.15"/>')
            for a, _, lo, hi in run:
                if lo is not None and hi is not None:
                    parts.append(f'<line x1="{x(a):.1f}" y1="{y(lo):.1f}" x2="{x(a):.1f}" y2="{y(hi):.1f}" '
                                 f'stroke="{col}" stroke-opacity="0.5"/>')  # fmt: skip
            if len(run) >= 2:
                line = " ".join(f"{x(a):.1f},{y(v):.1f}" for a, v, *_ in run)
                parts.append(f'<polyline points="{line}" fill="none" stroke="{col}" stroke-width="1.5"/>')
            for a, v, *_ in run:
                parts.append(f'<circle cx="{x(a):.1f}" cy="{y(v):.1f}" r="2.5" fill="{col}"/>')
        parts.append(f'<rect x="{w - mr + 8}" y="{mt + 14 * si}" width="10" height="10" fill="{col}"/>')
        parts.append(f'<text x="{w - mr + 22}" y="{mt + 14 * si + 9}">{html.escape(name)}</text>')
    parts.append("</svg>")
    return "\n".join(parts)


def _jpeg_b64(img: U8) -> str:
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 85])
    if not ok:
        raise PerceptionError("cannot encode a report image")
    return base64.b64encode(buf.tobytes()).decode("ascii")


def _page(title: str, body: list[str]) -> str:
    style = ("body{font-family:sans-serif;margin:1.5em;max-width:1400px}table{border-collapse:collapse;"
             "font-size:12px}td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
             "figure{display:inline-block;margin:4px}figcaption{font-size:11px}pre{background:#f4f4f4;"
             "padding:6px;white-space:pre-wrap}")  # fmt: skip
    return (f"<!DOCTYPE html>\n<html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{style}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")  # fmt: skip


def _cell_table(cells: list[dict[str, Any]], metrics: list[str], key: str = "metrics") -> str:
    rows = ["<table><tr><th>footage</th><th>alt m</th><th>tilt</th><th>speed</th><th>SR</th><th>frames</th>"
            + "".join(f"<th>{html.escape(m)} [95% CI]</th>" for m in metrics) + "</tr>"]  # fmt: skip
    for c in cells:
        tds = [
            c["footage"],
            f"{c['altitude_m']:g}",
            f"{c['tilt_deg']:g}",
            f"{c['speed_m_s']:g}",
            c["sr"],
            c["frames"],
        ]
        row = "".join(f"<td>{html.escape(str(t))}</td>" for t in tds)
        for m in metrics:
            v = c[key][m]
            ci = f" [{_fmt(v.get('lo'))}, {_fmt(v.get('hi'))}]" if v.get("lo") is not None else ""
            row += f"<td>{_fmt(v['value'])}{ci}</td>"
        rows.append(f"<tr>{row}</tr>")
    return "\n".join(rows) + "</table>"


def build_html(results: dict[str, Any], worst: list[tuple[str, U8]], timing: dict[str, float]) -> str:
    det = results["task"] == "detection"
    s = results["settings"]
    cmd = " ".join(shlex.quote(a) for a in results["command"]) or "(called from Python)"
    body = [f"<h1>Perception evaluation: {html.escape(results['task'])}</h1>",
            f"<p>Model <code>{html.escape(results['model']['spec'])}</code> ({html.escape(results['model']['kind'])})"
            f" on {html.escape(', '.join(s['footages']))}; {s['n_per_cell']} frames per cell, seed {s['seed']}, "
            f"{s['width_px']}x{s['height_px']}, effects: {html.escape(', '.join(s['effects']['names']) or 'none')}."
            " n/a = unavailable (not annotated in the footage, or no ground truth in the cell).</p>",
            f"<h2>Command</h2><pre>{html.escape(cmd)}</pre>"]  # fmt: skip
    if timing.get("seconds"):
        body.append(
            f"<p>{int(timing['frames'])} frames in {timing['seconds']:.1f} s "
            f"({timing['frames'] / timing['seconds']:.2f} frames/s, render + model + scoring).</p>"
        )
    for name, info in results["footages"].items():
        avail = ", ".join(info["classes_available"]) or "none"
        body.append(f"<p>{html.escape(name)}: classes annotated: {html.escape(avail)}; risk map: "
                    f"{'yes' if info['risk_map'] else 'no'}.</p>")  # fmt: skip
    body.append("<h2>Curves over altitude</h2>")
    for m in results["metrics"]:
        body.append(svg_curve(results["cells"], m))
    body.append("<h2>Cells</h2>" + _cell_table(results["cells"], results["metrics"]))
    if det:
        body.append("<h2>Per class (AP50 / recall at conf)</h2>")
        labels = list(results["cells"][0]["per_class"]) if results["cells"] else []
        rows = [
            "<table><tr><th>cell</th>" + "".join(f"<th>{html.escape(lb)}</th>" for lb in labels) + "</tr>"
        ]
        for c in results["cells"]:
            tds = "".join(
                f"<td>{_fmt(r['ap50'])} / {_fmt(r['recall'])} (n={r['n_gt'] if r['n_gt'] is not None else 'n/a'})"
                "</td>"
                if r["available"]
                else "<td>not annotated</td>"
                for r in c["per_class"].values()
            )
            rows.append(f"<tr><td>{html.escape(_series_key(c))}, {c['altitude_m']:g} m</td>{tds}</tr>")
        body.append("\n".join(rows) + "</table>")
    else:
        body.append("<h2>Per level IoU</h2>")
        rows = ["<table><tr><th>cell</th>" + "".join(f"<th>level {lv}</th>" for lv in range(1, 6)) + "</tr>"]
        for c in results["cells"]:
            tds = "".join(f"<td>{_fmt(r['iou'])} (px {r['n_px']})</td>" for r in c["per_level"].values())
            rows.append(f"<tr><td>{html.escape(_series_key(c))}, {c['altitude_m']:g} m</td>{tds}</tr>")
        body.append("\n".join(rows) + "</table>")
    if worst:
        what = (
            "ground truth green, predictions (score >= conf) red"
            if det
            else "left: ground-truth levels, right: predicted levels (1 green .. 5 dark red, black: no ground)"
        )
        body.append(f"<h2>Worst frames</h2><p>{what}</p>")
        for cap, img in worst:
            body.append(f"<figure><img src='data:image/jpeg;base64,{_jpeg_b64(img)}' width='{min(img.shape[1], 640)}'>"
                        f"<figcaption>{html.escape(cap)}</figcaption></figure>")  # fmt: skip
    return _page(f"perception eval: {results['task']}", body)


# --- compare ----------------------------------------------------------------------------------------------------


def _cell_key(c: dict[str, Any]) -> tuple[Any, ...]:
    return (c["footage"], c["altitude_m"], c["tilt_deg"], c["speed_m_s"], c["sr"])


def compare(a: dict[str, Any], b: dict[str, Any], bootstrap: int = 1000, seed: int = 0) -> dict[str, Any]:
    """Paired differences B - A per cell: of each headline metric, and of the per-frame score over the frames both
    runs rendered at the same pose (same footage, cell, seed), with a paired bootstrap 95 % CI of its mean."""
    if a["task"] != b["task"]:
        raise PerceptionError(f"cannot compare a {a['task']} evaluation with a {b['task']} one")
    sa, sb = a["settings"], b["settings"]
    same = ("footages", "seed", "n_per_cell", "width_px", "height_px", "effects")
    diff_keys = [k for k in same if sa.get(k) != sb.get(k)]
    if diff_keys:
        raise PerceptionError(
            f"the two evaluations differ in {', '.join(diff_keys)}: their frames are not paired"
        )
    cells_b = {_cell_key(c): c for c in b["cells"]}
    frames_a = {f["id"]: f for f in a["frames"]}
    frames_b = {f["id"]: f for f in b["frames"]}
    rng = np.random.default_rng(seed)
    out_cells = []
    for ca in a["cells"]:
        cb = cells_b.get(_cell_key(ca))
        if cb is None:
            continue
        row = {k: ca[k] for k in ("footage", "altitude_m", "tilt_deg", "speed_m_s", "sr", "frames")}
        row["diff"] = {}
        for m in a["metrics"]:
            va, vb = ca["metrics"][m]["value"], cb["metrics"][m]["value"]
            row["diff"][m] = {"a": va, "b": vb, "value": None if va is None or vb is None else vb - va,
                              "lo": None, "hi": None}  # fmt: skip
        ids = [f["id"] for f in a["frames"] if f["cell"] == ca["index"] and f["id"] in frames_b]
        d = [frames_b[i]["score"] - frames_a[i]["score"] for i in ids
             if frames_a[i]["score"] is not None and frames_b[i]["score"] is not None]  # fmt: skip
        lo = hi = None
        if len(d) >= 2:
            arr = np.array(d)
            means = [float(arr[rng.integers(0, len(arr), len(arr))].mean()) for _ in range(bootstrap)]
            lo, hi = (float(v) for v in np.percentile(means, [2.5, 97.5]))
        row["diff"]["frame_score"] = {"a": None, "b": None, "value": float(np.mean(d)) if d else None,
                                      "lo": lo, "hi": hi, "pairs": len(d)}  # fmt: skip
        out_cells.append(row)
    if not out_cells:
        raise PerceptionError("the two evaluations share no cell (footage, altitude, tilt, speed, SR)")
    return {"schema": "viva-sitl/perception-compare", "version": 1, "task": a["task"],
            "a": a["model"], "b": b["model"], "metrics": list(a["metrics"]) + ["frame_score"],
            "cells": out_cells}  # fmt: skip


def compare_html(diff: dict[str, Any]) -> str:
    body = [f"<h1>Perception evaluation compared: B - A ({html.escape(diff['task'])})</h1>",
            f"<p>A: <code>{html.escape(diff['a']['spec'])}</code>; B: <code>{html.escape(diff['b']['spec'])}</code>. "
            "Differences per cell, B minus A; frame_score is the mean paired per-frame difference with a paired "
            "bootstrap 95 % CI.</p>"]  # fmt: skip
    for m in diff["metrics"]:
        body.append(svg_curve(diff["cells"], m, value_key="diff", title=f"{m}: B - A"))
    body.append(_cell_table(diff["cells"], diff["metrics"], key="diff"))
    return _page("perception eval compare", body)
