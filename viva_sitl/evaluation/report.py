"""Reports of a campaign in OUT_DIR: results.json (schema vivasitl.trials.v2: spec, scenarios, rows, aggregates),
results.csv (one row per trial, scoring.COLUMNS), report.html (self-contained: matplotlib figures as base64 PNG).

    write_reports(campaign)               # after (or during an interrupted) run_campaign
    rows = read_results(OUT_DIR)          # the rows back, for `trials compare` / `trials show`
"""

from __future__ import annotations

import base64
import csv
import html
import io
import json
import math
import time
from pathlib import Path
from typing import Any

import numpy as np

from viva_sitl import __version__
from viva_sitl.evaluation.results import Campaign, Row, is_infra
from viva_sitl.evaluation.scoring import COLUMNS, OLDER_SCHEMAS, SCHEMA
from viva_sitl.evaluation.spec import Criterion
from viva_sitl.evaluation.stats import aggregate, paired

FIGURES_HINT = "pip install 'viva-sitl[trials]'"  # matplotlib, which draws the report's figures


def figures_missing_note() -> str | None:
    """One line for the console when matplotlib is absent (report.html then has its tables but no figures)."""
    try:
        import matplotlib  # noqa: F401
    except ImportError:
        return f"note: report.html has no figures: they need matplotlib ({FIGURES_HINT})"
    return None


def write_reports(camp: Campaign) -> None:
    out = camp.out_dir
    rows = camp.ordered_rows()
    agg = infra_aggregate(rows, camp.spec.criterion.describe(), camp.spec.criterion)
    doc = {
        "schema": SCHEMA,
        "viva_sitl_version": __version__,
        "created_utc": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
        "pilot": camp.pilot,
        "backend": camp.backend,
        "jobs": camp.jobs,
        "run": camp.run_record(),
        "complete": camp.complete and not camp.interrupted,
        "trials_total": len(camp.scenarios),
        "trials_done": len(rows),
        "spec": camp.spec.to_dict(),
        "columns": list(COLUMNS),
        "scenarios": [s.to_dict() for s in camp.scenarios],
        "rows": rows,
        "aggregate": agg,
    }
    tmp = out / "results.json.tmp"
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(out / "results.json")
    with (out / "results.csv.tmp").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(COLUMNS), extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in COLUMNS})
    (out / "results.csv.tmp").replace(out / "results.csv")
    (out / "report.html").write_text(render_html(doc, out))


def infra_aggregate(rows: list[Row], criterion: str, crit: Criterion | None = None) -> dict[str, Any]:
    """The aggregate over the trials that flew: infrastructure errors (results.INFRA_ENDS, the harness's failure,
    not the pilot's) are left out of the success rate and the scores and counted in `infra_errors`; `ends` still
    counts every trial."""
    infra = [r for r in rows if is_infra(r)]
    agg = aggregate([r for r in rows if not is_infra(r)], criterion, crit)
    ends: dict[str, int] = {}
    for r in rows:
        ends[str(r.get("end"))] = ends.get(str(r.get("end")), 0) + 1
    agg["ends"] = dict(sorted(ends.items()))
    by_end: dict[str, int] = {}
    for r in infra:
        by_end[str(r["end"])] = by_end.get(str(r["end"]), 0) + 1
    agg["infra_errors"] = {"n": len(infra), "trials": [r["trial"] for r in infra], "ends": by_end}
    return agg


def infra_line(agg: dict[str, Any]) -> str | None:
    """'2 trials failed in the harness, not the pilot (trial_error 1, worker_died 1: trials 3, 5)', or None."""
    inf = agg.get("infra_errors") or {}
    if not inf.get("n"):
        return None
    ends = ", ".join(f"{k} {v}" for k, v in inf["ends"].items())
    trials = ", ".join(map(str, inf["trials"][:10])) + (", ..." if len(inf["trials"]) > 10 else "")
    return (f"{inf['n']} trial{'s' if inf['n'] != 1 else ''} failed in the harness, not the pilot ({ends}: "
            f"trial{'s' if inf['n'] != 1 else ''} {trials})")  # fmt: skip


def read_results(out_dir: str | Path) -> dict[str, Any]:
    """A run's results.json (OUT_DIR, or the results.json file itself); ValueError with one line if none."""
    p = Path(out_dir)
    if p.is_dir() or p.name != "results.json":
        p = p / "results.json"
    try:
        doc: dict[str, Any] = json.loads(p.read_text())
    except (FileNotFoundError, NotADirectoryError):
        raise ValueError(f"{p}: no results (run `viva-sitl trials run` first)") from None
    except IsADirectoryError:
        raise ValueError(f"{p}: a directory, not a results file") from None
    except json.JSONDecodeError as exc:
        raise ValueError(f"{p}: not valid JSON: {exc}") from None
    if doc.get("schema") in OLDER_SCHEMAS:  # the columns added since read as unavailable
        doc["rows"] = [{c: r.get(c) for c in COLUMNS} | r for r in doc.get("rows", [])]
    elif doc.get("schema") != SCHEMA:
        raise ValueError(f"{p}: schema {doc.get('schema')!r}, expected {SCHEMA}")
    return doc


# ----------------------------------------------------------------------------------------------- figures


def _png(fig: Any, tight: bool = True) -> str:
    """The figure as base64 PNG; `tight`: trimmed to what is drawn (bbox_inches="tight", which draws the figure a
    second time to measure it: ~0.1 s for the 8-panel distributions, whose margins are set and need no trim)."""
    buf = io.BytesIO()
    # zlib level 1: ~25 % less time per figure than the default 6, for a PNG ~10-20 % bigger (plots, few colours)
    fig.savefig(
        buf, format="png", dpi=100, bbox_inches="tight" if tight else None, pil_kwargs={"compress_level": 1}
    )
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _outcome_color(r: Row) -> str:
    if r.get("success") is True:
        return "#1a9850"
    if r.get("success") is False:
        return "#d73027"
    return "#808080"


MAX_RISK_PANELS = 6  # the touchdown figure draws the risk map at most at this many footage times


def touchdown_footage_time_s(r: Row) -> float:
    """The footage clock at touchdown (trial time: "land now" + time to land; else the end)."""
    if r.get("time_to_land_s") is not None and r.get("land_at_s") is not None:
        return float(r["footage_time_s"]) + float(r["land_at_s"]) + float(r["time_to_land_s"])
    return float(r["footage_time_s"]) + float(r.get("end_t_s") or 0.0)


def risk_panels(
    rows: list[Row], frame_of: Any, max_panels: int = MAX_RISK_PANELS
) -> list[tuple[float, list[Row]]]:
    """Group the touchdowns by the footage frame they happened at (`frame_of(t) -> frame`): one panel per distinct
    frame, drawn at that frame's time; more than max_panels: max_panels of those frames spread over them
    (quantiles) and each touchdown goes to the panel of the nearest frame (the caption says so)."""
    # by time only: two touchdowns at the same footage time must not compare their rows (dicts)
    times = sorted(
        ((touchdown_footage_time_s(r), r) for r in rows if r.get("touchdown_north_m") is not None),
        key=lambda tr: tr[0],
    )
    if not times:
        return []
    by_frame: dict[int, list[tuple[float, Row]]] = {}
    for t, r in times:
        by_frame.setdefault(int(frame_of(t)), []).append((t, r))
    if len(by_frame) <= max_panels:
        return [(v[0][0], [r for _, r in v]) for _, v in sorted(by_frame.items(), key=lambda kv: kv[1][0][0])]
    # more frames than panels: panels at max_panels frames spread over the touchdowns' frames (the footage loops,
    # so frames, not absolute times), each touchdown on the panel of the nearest frame
    frames = sorted(by_frame)
    picks = sorted({frames[int(round(q * (len(frames) - 1)))] for q in np.linspace(0.0, 1.0, max_panels)})
    panels: list[tuple[float, list[Row]]] = [(by_frame[f][0][0], []) for f in picks]
    for f, v in by_frame.items():
        panels[int(np.argmin([abs(f - c) for c in picks]))][1].extend(r for _, r in v)
    return [p for p in panels if p[1]]


def figure_touchdowns(doc: dict[str, Any], out_dir: Path, footage: str) -> str | None:
    """Touchdown points (and start points) over the footage overview with the risk map drawn at the touchdown
    times (small multiples: one panel per distinct footage frame of a touchdown, at most MAX_RISK_PANELS),
    coloured by outcome."""
    import cv2
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from viva_sitl.footage import open_footage
    from viva_sitl.world import world_from_source
    from viva_sitl.world.overlay import render_overview

    rows = [r for r in doc["rows"] if r["footage"] == footage]
    if not rows:
        return None
    with open_footage(footage) as src:
        world = world_from_source(src)
        panels = risk_panels(rows, world.tracks.frame_at)
        exact = len(
            {world.tracks.frame_at(touchdown_footage_time_s(r)) for _, rs in panels for r in rs}
        ) == len(panels)
        if not panels:  # no touchdown at all: the starts over the map at the first trial's start time
            panels = [(float(rows[0]["footage_time_s"]), [])]
        px = 1000 if len(panels) == 1 else 600
        imgs = [render_overview(world, src, t, max_size_px=px, show_ids=False) for t, _ in panels]
        g = src.geometry
    img0 = imgs[0]
    s = img0.shape[1] / g.width_px
    traj_xy: dict[int, np.ndarray] = {}
    for r in rows:
        p = out_dir / "trials" / f"{int(r['trial']):04d}" / "trial_trajectory.csv"
        try:
            a = np.genfromtxt(p, delimiter=",", skip_header=1, usecols=(2, 3))
        except (OSError, ValueError):
            continue
        a = np.atleast_2d(a)
        if a.size:
            pxy = np.array([g.ned_to_px(n, e) for n, e in a[:: max(1, len(a) // 200)]])
            traj_xy[int(r["trial"])] = (pxy + 0.5) * s - 0.5
    cols = min(3, len(panels))
    nrows = (len(panels) + cols - 1) // cols
    aspect = img0.shape[0] / img0.shape[1]
    fig, axes = plt.subplots(nrows, cols, figsize=(8 if cols == 1 else 5 * cols, (8 if cols == 1 else 5) * nrows * aspect + 0.8),
                             squeeze=False)  # fmt: skip
    in_panel = {int(r["trial"]) for _, rs in panels for r in rs}
    for ax, img, (t, prs) in zip(axes.ravel(), imgs, panels, strict=False):
        ax.imshow(cv2.cvtColor(img, cv2.COLOR_BGR2RGB))
        shown = prs if in_panel else rows  # no touchdowns: every start on the one panel
        for r in shown:
            xy = traj_xy.get(int(r["trial"]))
            if xy is not None:
                ax.plot(xy[:, 0], xy[:, 1], color="white", lw=0.6, alpha=0.6)
            u0, v0 = g.ned_to_px(r["start_north_m"], r["start_east_m"])
            ax.plot((u0 + 0.5) * s - 0.5, (v0 + 0.5) * s - 0.5, marker="^", ms=4, color="white", alpha=0.8)
            if r.get("touchdown_north_m") is None:
                continue
            u, v = g.ned_to_px(r["touchdown_north_m"], r["touchdown_east_m"])
            ax.plot((u + 0.5) * s - 0.5, (v + 0.5) * s - 0.5, marker="o", ms=7, mec="black", mew=0.8,
                    color=_outcome_color(r))  # fmt: skip
            ax.annotate(str(r["trial"]), ((u + 0.5) * s + 4, (v + 0.5) * s - 4), color="white", fontsize=7)
        trials = ", ".join(str(r["trial"]) for r in prs)
        ax.set_title(
            f"risk map at footage t = {t:.2f} s" + (f": trials {trials}" if trials else ""), fontsize=8
        )
        ax.set_axis_off()
    for ax in axes.ravel()[len(panels) :]:
        ax.set_axis_off()
    note = (
        "each panel: the touchdowns at that footage frame"
        if exact
        else (f"more than {MAX_RISK_PANELS} touchdown frames: each touchdown on the panel nearest its time")
    )
    fig.suptitle(
        f"{footage}: touchdowns (green success, red failure, grey unscored), starts ^; {note}", fontsize=9
    )
    return _png(fig)


def figure_distributions(rows: list[Row], criterion: dict[str, Any] | None) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    keys = [("touchdown_speed_m_s", "touchdown speed (m/s)"),
            ("min_dist_person_m", "min distance to people, final descent (m)"),
            ("min_dist_vehicle_m", "min distance to vehicles, final descent (m)"),
            ("min_dist_object_m", "min distance to any object, final descent (m)"),
            ("risk_level", "risk level at touchdown"), ("time_to_land_s", "time to land (s)"),
            ("path_length_m", "path length (m)"), ("energy_wh", "energy used (Wh)")]  # fmt: skip
    fig, axes = plt.subplots(2, 4, figsize=(16, 6))
    for ax, (key, label) in zip(axes.ravel(), keys, strict=True):
        x = np.array([r[key] for r in rows if r.get(key) is not None], float)
        if x.size == 0:
            ax.text(0.5, 0.5, "unavailable", ha="center", va="center", transform=ax.transAxes)
        elif key == "risk_level":
            ax.bar(range(1, 6), [int(np.sum(x == lv)) for lv in range(1, 6)], color="#4575b4")
            ax.set_xticks(range(1, 6))
        else:
            ax.hist(x, bins=min(30, max(5, x.size // 2)), color="#4575b4")
        if criterion:
            lim = {"touchdown_speed_m_s": criterion.get("max_touchdown_speed_m_s"),
                   "min_dist_person_m": criterion.get("min_dist_person_m"),
                   "min_dist_vehicle_m": criterion.get("min_dist_vehicle_m"),
                   "min_dist_object_m": criterion.get("min_dist_object_m"),
                   "risk_level": criterion.get("max_risk_level")}.get(key)  # fmt: skip
            if lim is not None:
                ax.axvline(float(lim), color="#d73027", ls="--", lw=1)
        ax.set_title(label, fontsize=9)
    # fixed margins: tight_layout measured every tick label (~0.2 s of the report's ~1 s), and a tight bbox in _png
    # a second full draw (0.31-0.33 -> 0.20 s CPU for this figure without it)
    fig.subplots_adjust(left=0.04, right=0.99, bottom=0.06, top=0.94, wspace=0.22, hspace=0.35)
    return _png(fig, tight=False)


def _pct(lo_hi: list[float | None] | None) -> str:
    """A 95 % interval of a proportion in percent, one style for every method: "a–b %"."""
    if not lo_hi or lo_hi[0] is None or lo_hi[1] is None:
        return "—"
    return f"{100 * lo_hi[0]:.1f}–{100 * lo_hi[1]:.1f} %"


def _success_section(agg: dict[str, Any], spec: dict[str, Any], n_rows: int) -> list[str]:
    """Success over the judged trials (Wilson and bootstrap intervals, both in percent), the unscored trials,
    the landed count, the ends, and each check's rate over the trials that could judge it."""
    rate = agg["success_rate"]
    landed = agg.get("landed")
    if landed is None and agg.get("landed_rate") is not None:  # results written before the count was kept
        landed = round(agg["landed_rate"] * n_rows)
    unscored = agg.get("success_unscored", n_rows - agg["success_judged"])
    text = (f"<h2>Success</h2><p id='success'>Criterion <b>{html.escape(agg['criterion'])}</b> (minimum distance "
            f"over the final descent below {spec['final_descent_below_m']:g} m): ")  # fmt: skip
    if rate is not None:
        text += (f"<b>{agg['success']} of {agg['success_judged']} judged trials = {100 * rate:.1f} %</b> (95 % CI "
                 f"{_pct(agg['success_rate_ci95_wilson'])} Wilson; {_pct(agg['success_rate_ci95_bootstrap'])} "
                 "bootstrap)")  # fmt: skip
    else:
        text += "<b>unavailable</b> (no trial could be judged)"
    if unscored:
        text += (f"; <b>{unscored} unscored</b> (no check failed but one could not be judged: see "
                 "<code>criterion_unavailable</code>; not counted as successes nor failures)")  # fmt: skip
    text += (f". Landed: {landed if landed is not None else '—'} of {n_rows} trials. Ends: "
             + ", ".join(f"{k} {v}" for k, v in agg["ends"].items()) + ".</p>")  # fmt: skip
    out = [text]
    checks = agg.get("checks")
    if checks:
        out.append("<div class='scroll'><table id='checks'><tr><th class='l'>check</th><th>passed</th>"
                   "<th>judged</th><th>rate</th><th>95 % CI (Wilson)</th><th>n/a (unavailable)</th></tr>")  # fmt: skip
        for name, c in checks.items():
            rate_c = "n/a" if c["rate"] is None else f"{100 * c['rate']:.1f} %"
            out.append(f"<tr data-check='{html.escape(name)}'><td class='l'>{html.escape(name)}</td>"
                       f"<td>{c['passed']}</td><td>{c['judged']}</td><td>{rate_c}</td>"
                       f"<td>{_pct(c['rate_ci95_wilson'])}</td><td>{c['unavailable']}</td></tr>")  # fmt: skip
        out.append("</table></div><p>Each check over the trials that could judge it; <i>n/a</i>: the footage's "
                   "ground truth cannot answer it (no tracks or risk map, or the class was not annotated: see "
                   "the footage metadata's <code>annotated</code>).</p>")  # fmt: skip
    return out


def _fmt(v: Any) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:.3g}" if math.isfinite(v) else "—"
    return html.escape(str(v))


_CSS = """body{font-family:sans-serif;margin:24px;max-width:1200px;color:#222}table{border-collapse:collapse;
font-size:13px}td,th{border:1px solid #ccc;padding:3px 6px;text-align:right}th{background:#eee}
td.l,th.l{text-align:left}.ok{color:#1a9850;font-weight:bold}.bad{color:#d73027;font-weight:bold}img{max-width:100%}
code{background:#f4f4f4;padding:1px 4px}.scroll{overflow-x:auto;max-width:100%}#pairs td{white-space:nowrap}"""


def render_html(doc: dict[str, Any], out_dir: Path) -> str:
    rows: list[Row] = doc["rows"]
    agg = doc["aggregate"]
    spec = doc["spec"]
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>viva-sitl trials: "
             f"{html.escape(spec['name'])} [{html.escape(doc['pilot'])}]</title><style>{_CSS}</style></head><body>",
             f"<h1>Landing trials: {html.escape(spec['name'])} — pilot <code>{html.escape(doc['pilot'])}</code></h1>",
             f"<p>{doc['trials_done']} of {doc['trials_total']} trials"
             f"{'' if doc['complete'] else ' (incomplete: <code>--resume</code> completes the rest)'}; seed "
             f"{spec['seed']}; spec <code>{html.escape(spec['source'])}</code>; backend {doc['backend']} × "
             f"{doc['jobs']}; viva-sitl {doc['viva_sitl_version']}; {doc['created_utc']}. Files: "
             f"<a href='results.json'>results.json</a>, <a href='results.csv'>results.csv</a> "
             f"(schema <code>{doc['schema']}</code>).</p>"]  # fmt: skip
    parts.append(_provenance_html(doc))
    n_flown = len(rows) - int((agg.get("infra_errors") or {}).get("n", 0))
    parts.extend(_success_section(agg, spec, n_flown))
    infra = infra_line(agg)
    if infra is not None:
        parts.append(f"<p class='bad' id='infra'>{html.escape(infra)}: left out of the success rate and the "
                     "scores, which count only the trials that flew; <code>--resume</code> runs them again.</p>")  # fmt: skip
    parts.append("<h2>Scores</h2><p>Over the trials where a score is available: <i>n</i> counts them (a distance "
                 "needs the footage's object tracks and an object of that class in them, touchdown scores a "
                 "touchdown); <i>unavailable</i> = no trial has it, never 0. <code>dist_*</code>: at touchdown, "
                 "<code>min_dist_*</code>: minimum over the final descent; <code>*_object_m</code>: the nearest "
                 "tracked object of any class, motion-derived tracks included. <code>risk_level</code> is ordinal: trials per "
                 "level and the median, no mean.</p>"
                 "<div class='scroll'><table id='scores'><tr><th class='l'>score</th><th>n</th><th>mean</th><th>95 % CI (bootstrap)</th>"
                 "<th>median</th><th>p10</th><th>p90</th><th>min</th><th>max</th></tr>")  # fmt: skip
    for key, s in agg["scores"].items():
        if s["n"] and "counts" in s:  # ordinal (risk level): trials per level and the median, never a mean
            dist = ", ".join(f"{lv}: {c}" for lv, c in s["counts"].items())
            parts.append(f"<tr data-score='{key}'><td class='l'>{key}</td><td>{s['n']}</td>"
                         f"<td colspan=2 class='l'>trials per level {dist}</td><td>{_fmt(s['median'])}</td>"
                         f"<td>—</td><td>—</td><td>{_fmt(s['min'])}</td><td>{_fmt(s['max'])}</td></tr>")  # fmt: skip
            continue
        if s["n"] == 0:
            parts.append(
                f"<tr data-score='{key}'><td class='l'>{key}</td><td>0</td>"
                "<td colspan=7 class='l'>unavailable</td></tr>"
            )
            continue
        parts.append(f"<tr data-score='{key}'><td class='l'>{key}</td><td>{s['n']}</td><td>{_fmt(s['mean'])}</td><td>"
                     f"{_fmt(s['mean_ci95'][0])} – {_fmt(s['mean_ci95'][1])}</td><td>{_fmt(s['median'])}</td>"
                     f"<td>{_fmt(s['p10'])}</td><td>{_fmt(s['p90'])}</td><td>{_fmt(s['min'])}</td>"
                     f"<td>{_fmt(s['max'])}</td></tr>")  # fmt: skip
    parts.append("</table></div>")
    figs = figures_missing_note() is None
    if not figs:
        parts.append(f"<p>(figures need matplotlib: <code>{FIGURES_HINT}</code>)</p>")
    if figs and rows:
        parts.append("<h2>Touchdown points</h2>")
        for footage in sorted({r["footage"] for r in rows}):
            try:
                b64 = figure_touchdowns(doc, out_dir, footage)
            except Exception as exc:  # noqa: BLE001 - a figure must never lose the report
                parts.append(f"<p>figure for {html.escape(footage)} failed: {html.escape(str(exc))}</p>")
                continue
            if b64:
                parts.append(
                    f"<img alt='touchdowns over {html.escape(footage)}' src='data:image/png;base64,{b64}'>"
                )
        parts.append("<h2>Distributions</h2>")
        parts.append(f"<img alt='distributions' src='data:image/png;base64,"
                     f"{figure_distributions(rows, spec.get('criterion'))}'>")  # fmt: skip
    worst = sorted(rows, key=_badness)[:15]
    parts.append("<h2>Worst trials</h2><div class='scroll'><table id='worst'><tr><th>trial</th><th class='l'>end</th><th>success</th>"
                 "<th>touchdown speed (m/s)</th><th>min dist person (m)</th><th>min dist object (m)</th><th>risk</th>"
                 "<th>time to land (s)</th><th class='l'>why</th><th class='l'>logs</th></tr>")  # fmt: skip
    for r in worst:
        d = f"trials/{int(r['trial']):04d}"
        ok = r.get("success")
        cls = "ok" if ok else "bad" if ok is False else ""
        parts.append(
            f"<tr><td>{r['trial']}</td><td class='l'>{_fmt(r['end'])}</td><td class='{cls}'>{_fmt(ok)}</td>"
            f"<td>{_fmt(r['touchdown_speed_m_s'])}</td><td>{_fmt(r['min_dist_person_m'])}</td>"
            f"<td>{_fmt(r.get('min_dist_object_m'))}</td><td>{_fmt(r['risk_level'])}</td><td>{_fmt(r['time_to_land_s'])}</td>"
            f"<td class='l'>{_fmt(r.get('criterion_failures') or r.get('end_detail'))}</td>"
            f"<td class='l'><a href='{d}/trial_trajectory.csv'>trajectory</a> <a href='{d}/events.jsonl'>events</a> "
            f"<a href='{d}/scenario.json'>scenario</a>"
            + (f" <a href='{d}/telemetry.tlog'>tlog</a>" if (out_dir / d / "telemetry.tlog").exists() else "")
            + (f" <a href='{d}/vac.mp4'>video</a>" if (out_dir / d / "vac.mp4").exists() else "")
            + (f" <a href='{d}/log.ulg'>ulog</a>" if (out_dir / d / "log.ulg").exists() else "")
            + "</td></tr>"
        )  # fmt: skip
    parts.append("</table></div>")
    parts.extend(_all_trials_table(rows, out_dir))
    parts.append("</body></html>")
    return "\n".join(parts)


def _provenance_html(doc: dict[str, Any]) -> str:
    """What ran (results.json "run"): the pilot command, spec hash, seed, n, timing, speed, versions."""
    run = doc.get("run")
    if not isinstance(run, dict):
        return "<p id='provenance'>What ran: not recorded (results written before viva-sitl recorded it).</p>"
    vers = ", ".join(
        f"{html.escape(str(k))} {html.escape(str(v))}" for k, v in (run.get("versions") or {}).items()
    )
    return (f"<p id='provenance'>What ran: {html.escape(str(run.get('pilot_kind')))} pilot "
            f"<code>{html.escape(str(run.get('pilot')))}</code>; spec hash <code>{str(run.get('spec_hash'))[:16]}"
            f"</code>; seed {run.get('seed')}; n {run.get('n')}; timing {html.escape(str(run.get('timing')))}"
            + (f" (pilot CPU factor {run.get('pilot_cpu_factor')})" if run.get("pilot_cpu_factor") is not None else "")
            + (f" (latency per frame {run.get('pilot_latency_ms')} ms)" if run.get("pilot_latency_ms") else "")
            + f"; speed {run.get('speed')}; versions: {vers}.</p>")  # fmt: skip


# the per-trial table: the scenario's key, the outcome and every score a benchmark user compares (headers are the
# results.csv column names; cells are the results.json values unrounded, so both can be matched one to one)
TRIAL_TABLE_COLUMNS = (
    "trial", "footage", "end", "landed", "success", "touchdown_speed_m_s", "dist_person_m", "min_dist_person_m",
    "dist_vehicle_m", "min_dist_vehicle_m", "dist_object_m", "min_dist_object_m", "risk_level", "time_to_land_s",
    "path_length_m", "energy_wh", "criterion_failures", "criterion_unavailable",
)  # fmt: skip
_LEFT = {"footage", "end", "criterion_failures", "criterion_unavailable"}


_PRESENT = {"person": "persons_present", "vehicle": "vehicles_present", "object": "objects_present"}


def unavailable(r: Row, key: str) -> bool:
    """A null score the footage's ground truth cannot answer: no tracks / risk map, or the class not annotated."""
    if key == "risk_level":
        return not r.get("gt_risk")
    if "dist_" in key:
        group = key.rsplit("_", 2)[-2]  # dist_person_m -> person
        return not r.get("gt_objects") or r.get(_PRESENT.get(group, "")) is None
    return False


def _cell(r: Row, key: str) -> str:
    """One per-trial cell: the exact value; null is "n/a" when the footage's ground truth cannot answer it (no
    ground truth of that kind, or the class was not annotated), "—" when it can but the score does not apply
    (no touchdown, nobody of that class); success null is "unscored"."""
    v = r.get(key)
    if v is None:
        if key == "success":
            return "unscored"
        return "n/a" if unavailable(r, key) else "—"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return json.dumps(v) if math.isfinite(v) else "—"
    return html.escape(str(v))


def _all_trials_table(rows: list[Row], out_dir: Path | None = None) -> list[str]:
    out = ["<h2>All trials</h2><p>One row per trial (as in <a href='results.csv'>results.csv</a>; units in the "
           "column names). <i>n/a</i>: the footage's ground truth cannot answer that score (none of that kind, "
           "or the class was not annotated); —: it does not apply (no touchdown, nobody of that class in the "
           "footage); <i>unscored</i>: no check failed but one was n/a (<code>criterion_unavailable</code> says "
           "which).</p><div class='scroll'><table id='trials'><tr>"
           + "".join(f"<th{' class=l' if k in _LEFT else ''} data-col='{k}'>{k}</th>" for k in TRIAL_TABLE_COLUMNS)
           + "<th class='l' data-col='ulog'>ulog</th></tr>"]  # fmt: skip
    for r in rows:
        ok = r.get("success")
        cells = []
        for k in TRIAL_TABLE_COLUMNS:
            c = " class='l'" if k in _LEFT else ""
            if k == "success" and ok is not None:
                c = " class='ok'" if ok else " class='bad'"
            cells.append(f"<td{c}>{_cell(r, k)}</td>")
        ulog = f"trials/{int(r['trial']):04d}/log.ulg"  # the trial's PX4 ULog, linked when it was written
        has_ulog = out_dir is not None and (out_dir / ulog).exists()
        cells.append(
            f"<td class='l'><a href='{ulog}'>log.ulg</a></td>" if has_ulog else "<td class='l'>—</td>"
        )
        out.append(f"<tr data-trial='{int(r['trial'])}'>" + "".join(cells) + "</tr>")
    out.append("</table></div>")
    return out


def _badness(r: Row) -> tuple[int, float]:
    rank = 0 if r.get("success") is False else 1 if r.get("success") is None else 2
    d = r.get("min_dist_person_m")
    return rank, (d if d is not None else math.inf)


def compare_docs(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    res = paired(a["rows"], b["rows"])
    res["a"] = {"pilot": a["pilot"], "spec": a["spec"]["source"], "seed": a["spec"]["seed"]}
    res["b"] = {"pilot": b["pilot"], "spec": b["spec"]["source"], "seed": b["spec"]["seed"]}
    sa = {(s["index"], s["seed"]): s for s in a["scenarios"]}
    sb = {(s["index"], s["seed"]): s for s in b["scenarios"]}
    # the pairs' scenarios are identical (a one-trial run, e.g. `trials fly --trial K`, pairs with trial K of a
    # campaign: the trials only one side has are counted in unmatched_a / unmatched_b, not compared)
    both = set(sa) & set(sb)
    res["same_scenarios"] = bool(both) and all(sa[k] == sb[k] for k in both)
    res["per_trial"] = paired_trials(a["rows"], b["rows"])
    return res


# the per-pair differences `trials compare` lists (B - A; null when either side lacks the score)
PAIRED_TRIAL_COLUMNS = (
    "touchdown_speed_m_s", "dist_person_m", "min_dist_person_m", "dist_vehicle_m", "min_dist_vehicle_m",
    "dist_object_m", "min_dist_object_m", "risk_level", "time_to_land_s",
)  # fmt: skip


def paired_trials(rows_a: list[Row], rows_b: list[Row]) -> list[Row]:
    """One entry per pair (trial index and seed in both runs): each side's end, success and scores, and B - A."""
    a = {(r["trial"], r["seed"]): r for r in rows_a}
    b = {(r["trial"], r["seed"]): r for r in rows_b}
    out: list[Row] = []
    for key in sorted(set(a) & set(b)):
        ra, rb = a[key], b[key]
        e: Row = {"trial": key[0], "seed": key[1], "end_a": ra.get("end"), "end_b": rb.get("end"),
                  "success_a": ra.get("success"), "success_b": rb.get("success")}  # fmt: skip
        for c in PAIRED_TRIAL_COLUMNS:
            va, vb = ra.get(c), rb.get(c)
            e[c + "_a"], e[c + "_b"] = va, vb
            e[c + "_diff"] = None if va is None or vb is None else round(float(vb) - float(va), 4)
        out.append(e)
    return out


def render_compare_html(res: dict[str, Any], a_dir: str, b_dir: str) -> str:
    """`trials compare --html`: the paired statistics and every pair's scores side by side (self-contained)."""
    pa, pb = html.escape(str(res["a"]["pilot"])), html.escape(str(res["b"]["pilot"]))
    s = res["success"]
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>viva-sitl trials compare: {pa} vs {pb}"
             f"</title><style>{_CSS}</style></head><body><h1>Paired comparison: A = <code>{pa}</code>, "
             f"B = <code>{pb}</code></h1><p>A: <code>{html.escape(a_dir)}</code> (spec "
             f"<code>{html.escape(str(res['a']['spec']))}</code>, seed {res['a']['seed']}); B: "
             f"<code>{html.escape(b_dir)}</code> (spec <code>{html.escape(str(res['b']['spec']))}</code>, seed "
             f"{res['b']['seed']}). {res['pairs']} pairs (same trial index and scenario seed); same scenarios: "
             f"<b>{res['same_scenarios']}</b>; only in A {res['unmatched_a']}, only in B {res['unmatched_b']} "
             "(left out).</p>"]  # fmt: skip
    if res.get("mismatches"):
        parts.append("<p class='bad' id='mismatch'><b>WARNING: the runs were not made under the same conditions"
                     "</b> (compared with --allow-mismatch): "
                     + "; ".join(html.escape(x) for x in res["mismatches"]) + ".</p>")  # fmt: skip
    if not res["same_scenarios"]:
        parts.append("<p class='bad'>The runs were drawn from different scenarios: the pairs match by trial index "
                     "and seed only.</p>")  # fmt: skip
    if s["judged_pairs"]:
        parts.append(f"<h2>Success</h2><p id='success'>A {100 * s['rate_a']:.1f} %, B {100 * s['rate_b']:.1f} % "
                     f"over {s['judged_pairs']} judged pairs; B − A {100 * s['diff_b_minus_a']:+.1f} points (95 % CI "
                     f"{100 * s['diff_ci95'][0]:+.1f} … {100 * s['diff_ci95'][1]:+.1f}, bootstrap); both {s['both']}, "
                     f"only A {s['only_a']}, only B {s['only_b']}, neither {s['neither']}; McNemar exact p = "
                     f"{s['mcnemar_p']}.</p>")  # fmt: skip
    else:
        parts.append("<h2>Success</h2><p id='success'><b>unavailable</b> (no ground truth)</p>")
    parts.append("<h2>Scores (paired, B − A)</h2><div class='scroll'><table id='scores'><tr><th class='l'>score</th><th>pairs</th>"
                 "<th>mean A</th><th>mean B</th><th>mean B − A</th><th>95 % CI (bootstrap)</th></tr>")  # fmt: skip
    for key, d in res["scores"].items():
        if not d["pairs"]:
            parts.append(f"<tr data-score='{key}'><td class='l'>{key}</td><td>0</td>"
                         "<td colspan=4 class='l'>unavailable</td></tr>")  # fmt: skip
            continue
        if d.get(
            "ordinal"
        ):  # risk level: the pairs where B is lower / same / higher, never a mean difference
            parts.append(f"<tr data-score='{key}'><td class='l'>{key}</td><td>{d['pairs']}</td>"
                         f"<td>median {_fmt(d['median_a'])}</td><td>median {_fmt(d['median_b'])}</td>"
                         f"<td class='l' colspan=2>B lower in {d['b_lower']}, same {d['same']}, higher "
                         f"{d['b_higher']} (sign test p = {d['sign_test_p']})</td></tr>")  # fmt: skip
            continue
        parts.append(f"<tr data-score='{key}'><td class='l'>{key}</td><td>{d['pairs']}</td>"
                     f"<td>{_fmt(d['mean_a'])}</td><td>{_fmt(d['mean_b'])}</td><td>{_fmt(d['mean_diff_b_minus_a'])}"
                     f"</td><td>{_fmt(d['diff_ci95'][0])} – {_fmt(d['diff_ci95'][1])}</td></tr>")  # fmt: skip
    parts.append("</table></div><h2>Pairs</h2><p>Per pair: A / B / B − A (exact values from the runs' results.json; "
                 "— = unavailable on either side).</p><div class='scroll'><table id='pairs'><tr><th data-col='trial'>trial</th>"
                 "<th class='l' data-col='end'>end A / B</th><th data-col='success'>success A / B</th>"
                 + "".join(f"<th data-col='{c}'>{c}</th>" for c in PAIRED_TRIAL_COLUMNS) + "</tr>")  # fmt: skip

    def v(x: Any) -> str:
        if x is None:
            return "—"
        if isinstance(x, bool):
            return "yes" if x else "no"
        return json.dumps(x) if isinstance(x, float | int) else html.escape(str(x))

    for e in res["per_trial"]:
        cells = [f"<td>{e['trial']}</td>", f"<td class='l'>{v(e['end_a'])} / {v(e['end_b'])}</td>",
                 f"<td>{v(e['success_a'])} / {v(e['success_b'])}</td>"]  # fmt: skip
        for c in PAIRED_TRIAL_COLUMNS:
            cells.append(f"<td>{v(e[c + '_a'])} / {v(e[c + '_b'])} / {v(e[c + '_diff'])}</td>")
        parts.append(f"<tr data-trial='{e['trial']}'>" + "".join(cells) + "</tr>")
    parts.append("</table></div></body></html>")
    return "\n".join(parts)
