"""`trials compare`: are two (or more) runs comparable, and the ranked table of many pilots against a baseline.

    diffs = run_mismatches(doc_a, doc_b)       # [] or one line per difference (timing, CPU factor, speed, spec, version)
    board = leaderboard([(dir, doc), ...], baseline=0)   # paired statistics of every run against the baseline

Two runs are comparable when they ran under the same conditions: the same timing mode and declared pilot CPU factor
(issue 19), the same speed factor where both pilots were paced by it (external programs and people; an in-process
pilot is not paced), the same spec apart from n, seed, default pilot, speed and frames (the scenarios and the
scoring: what `spec_hash` covers, less what is compared on its own or does not change the scenarios), and the same
viva-sitl version. An in-process pilot counts as lockstep whatever its file says (it is stepped synchronously; files
before schema v4 wrote "realtime"); a person (`trials fly`) flies on the wall clock, and against a program that is
the comparison asked for: timing is not compared when one side is human. Results written before the run record
(results.json "run") read as timing "realtime", factor null, and the version and spec that results.json names.
"""

from __future__ import annotations

import hashlib
import html
import json
import math
from pathlib import Path
from typing import Any

from viva_sitl.evaluation.stats import BOOTSTRAP_SEED, RESAMPLES, _r, holm, paired, wilson_ci

# spec keys left out of the spec identity: recorded on their own (n, seed, pilot), where it came from (source),
# compared on its own where it matters (speed), or not a change of the scenarios (frames)
_SPEC_NOT_COMPARED = ("source", "n", "seed", "pilot", "speed", "frames", "timing", "pilot_cpu_factor",
                      "pilot_latency_ms", "ulog")  # fmt: skip


def _run(doc: dict[str, Any]) -> dict[str, Any]:
    run = doc.get("run")
    return run if isinstance(run, dict) else {}


def spec_identity(doc: dict[str, Any]) -> tuple[str, dict[str, Any]]:
    """(sha256 of the spec's scenarios and scoring, that part of the spec) of a results.json."""
    spec = doc.get("spec") if isinstance(doc.get("spec"), dict) else {}
    assert isinstance(spec, dict)
    core = {k: v for k, v in spec.items() if k not in _SPEC_NOT_COMPARED}
    text = json.dumps(core, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest(), core


def conditions(doc: dict[str, Any]) -> dict[str, Any]:
    """What a comparison must find equal, as this run recorded it (see the module's docstring for older files)."""
    run = _run(doc)
    spec = doc.get("spec") if isinstance(doc.get("spec"), dict) else {}
    assert isinstance(spec, dict)
    kind = run.get("pilot_kind")
    versions = run.get("versions") if isinstance(run.get("versions"), dict) else {}
    assert isinstance(versions, dict)
    paced = kind != "in-process" if kind is not None else not _inprocess(str(doc.get("pilot", "")))
    # an in-process pilot is stepped in lockstep whatever its file says (files before v4 wrote "realtime")
    return {
        "timing": run.get("timing", "realtime") if paced else "lockstep",
        "pilot_cpu_factor": run.get("pilot_cpu_factor") if paced else None,
        "pilot_latency_ms": run.get("pilot_latency_ms") if paced else None,
        "human": kind == "human",
        "speed": run.get("speed", spec.get("speed")),
        "paced": paced,
        "spec": spec_identity(doc)[0],
        "spec_hash": run.get("spec_hash"),
        "viva-sitl": versions.get("viva-sitl", doc.get("viva_sitl_version")),
    }


def _inprocess(pilot: str) -> bool:
    from viva_sitl.evaluation.pilots import is_inprocess

    return is_inprocess(pilot)


def run_mismatches(a: dict[str, Any], b: dict[str, Any], name_a: str = "A", name_b: str = "B") -> list[str]:
    """One line per condition under which the two runs differ ([] = comparable)."""
    ca, cb = conditions(a), conditions(b)
    out: list[str] = []
    for key in ("timing", "pilot_cpu_factor", "pilot_latency_ms"):
        if ca["human"] or cb["human"]:
            break  # a person flies on the wall clock: against a program, that is the comparison asked for
        if ca[key] != cb[key]:
            out.append(f"{key}: {ca[key]!r} in {name_a}, {cb[key]!r} in {name_b}")
    if ca["paced"] and cb["paced"] and ca["speed"] != cb["speed"]:
        out.append(
            f"speed: {ca['speed']!r} in {name_a}, {cb['speed']!r} in {name_b} (both pilots were paced by it)"
        )
    if ca["spec"] != cb["spec"]:
        _, sa = spec_identity(a)
        _, sb = spec_identity(b)
        keys = sorted(k for k in set(sa) | set(sb) if sa.get(k) != sb.get(k))
        out.append(
            f"spec: hash {str(ca['spec_hash'] or ca['spec'])[:12]} in {name_a}, {str(cb['spec_hash'] or cb['spec'])[:12]} "
            f"in {name_b} (differs in {', '.join(keys)})"
        )
    if ca["viva-sitl"] != cb["viva-sitl"]:
        out.append(f"viva-sitl version: {ca['viva-sitl']!r} in {name_a}, {cb['viva-sitl']!r} in {name_b}")
    return out


# --------------------------------------------------------------------------------------------- many pilots


def _key(r: dict[str, Any]) -> tuple[int, int]:
    return int(r["trial"]), int(r["seed"])


def _scenarios(doc: dict[str, Any]) -> dict[tuple[int, int], Any]:
    return {(int(s["index"]), int(s["seed"])): s for s in doc.get("scenarios", [])}


PAIRED_SCORES = ("min_dist_person_m", "min_dist_vehicle_m", "time_to_land_s", "touchdown_speed_m_s")


def leaderboard(runs: list[tuple[str, dict[str, Any]]], baseline: int = 0) -> dict[str, Any]:
    """Every run against runs[baseline] on the scenarios all runs share (same trial index, seed and scenario):
    success with its Wilson interval, the paired success difference to the baseline (bootstrap CI), McNemar's
    exact p and its Holm-adjusted value over the runs compared, win / loss / tie per scenario, paired score
    differences (and the risk level as lower / same / higher), ranked by success rate (then wins - losses)."""
    if len(runs) < 2:
        raise ValueError("a leaderboard needs at least two runs")
    keysets = [{_key(r) for r in doc["rows"]} for _, doc in runs]
    shared = set.intersection(*keysets)
    scen = [_scenarios(doc) for _, doc in runs]
    # the same scenario, not only the same index and seed: a run over another spec would pair by accident
    same = all(all(sc.get(k) == scen[0].get(k) for sc in scen) for k in shared)
    keys = sorted(shared)
    rows = [{_key(r): r for r in doc["rows"] if _key(r) in shared} for _, doc in runs]
    base_rows = rows[baseline]
    entries: list[dict[str, Any]] = []
    for i, (path, doc) in enumerate(runs):
        mine = rows[i]
        judged = [k for k in keys if mine[k].get("success") is not None]
        k_ok = sum(1 for k in judged if mine[k]["success"])
        lo, hi = wilson_ci(k_ok, len(judged)) if judged else (math.nan, math.nan)
        e: dict[str, Any] = {
            "run": path, "pilot": doc["pilot"], "baseline": i == baseline, "trials": len(keys),
            "judged": len(judged), "success": k_ok, "rate": _r(k_ok / len(judged)) if judged else None,
            "rate_ci95_wilson": [_r(lo), _r(hi)] if judged else None,
        }  # fmt: skip
        if i != baseline:
            p = paired([base_rows[k] for k in keys], [mine[k] for k in keys])
            s = p["success"]
            e["vs_baseline"] = {
                "judged_pairs": s["judged_pairs"], "wins": s["only_b"], "losses": s["only_a"],
                "ties": s["both"] + s["neither"], "diff": s.get("diff_b_minus_a"), "diff_ci95": s.get("diff_ci95"),
                "mcnemar_p": s["mcnemar_p"], "scores": {c: p["scores"][c] for c in (*PAIRED_SCORES, "risk_level")},
            }  # fmt: skip
        entries.append(e)
    others = [e for e in entries if not e["baseline"]]
    for e, adj in zip(others, holm([float(e["vs_baseline"]["mcnemar_p"]) for e in others]), strict=True):
        e["vs_baseline"]["holm_p"] = _r(adj, 6)
    ranked = sorted(
        entries,
        key=lambda e: (
            -(e["rate"] if e["rate"] is not None else -1.0),
            -((e.get("vs_baseline") or {}).get("wins", 0) - (e.get("vs_baseline") or {}).get("losses", 0)),
        ),
    )
    for rank, e in enumerate(ranked, 1):
        e["rank"] = rank
    per_scenario = []
    for k in keys:
        per_scenario.append({
            "trial": k[0], "seed": k[1],
            "success": [rows[i][k].get("success") for i in range(len(runs))],
            "end": [rows[i][k].get("end") for i in range(len(runs))],
        })  # fmt: skip
    return {
        "baseline": runs[baseline][0], "baseline_pilot": runs[baseline][1]["pilot"], "shared_trials": len(keys),
        "same_scenarios": bool(keys) and same, "runs": ranked, "order": [p for p, _ in runs],
        "per_scenario": per_scenario, "bootstrap": {"seed": BOOTSTRAP_SEED, "resamples": RESAMPLES},
        "multiple_comparisons": "Holm-Bonferroni over the runs compared with the baseline (McNemar exact p)",
    }  # fmt: skip


# --------------------------------------------------------------------------------------------- the page

MAX_MAPS = 6  # touchdown maps side by side: at most this many runs (the first ones of the ranking)


def _pct(x: float | None) -> str:
    return "—" if x is None else f"{100 * x:.1f} %"


def _ci_pct(ci: list[float | None] | None, signed: bool = False) -> str:
    if not ci or ci[0] is None or ci[1] is None:
        return "—"
    f = "{:+.1f}" if signed else "{:.1f}"
    return f"{f.format(100 * ci[0])}–{f.format(100 * ci[1])}"


def figure_success(board: dict[str, Any]) -> str:
    """Success rate per run with its Wilson 95 % interval (ranked, baseline in grey)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from viva_sitl.evaluation.report import _png

    runs = [e for e in board["runs"] if e["rate"] is not None]
    fig, ax = plt.subplots(figsize=(7, 0.5 * len(runs) + 1.2))
    for y, e in enumerate(runs):
        lo, hi = e["rate_ci95_wilson"]
        c = "#808080" if e["baseline"] else "#4575b4"
        ax.errorbar([100 * e["rate"]], [y], xerr=[[100 * (e["rate"] - lo)], [100 * (hi - e["rate"])]], fmt="o",
                    color=c, capsize=4)  # fmt: skip
    ax.set_yticks(range(len(runs)), [f"{e['rank']}. {e['pilot'][:40]}" for e in runs], fontsize=8)
    ax.invert_yaxis()
    ax.set_xlim(0, 100)
    ax.set_xlabel(f"success over {board['shared_trials']} shared scenarios (%), 95 % CI (Wilson)")
    ax.grid(axis="x", alpha=0.3)
    return _png(fig)


def figure_paired(board: dict[str, Any]) -> str:
    """Paired differences to the baseline with 95 % bootstrap intervals: success (points), and the mean
    differences of the paired scores."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from viva_sitl.evaluation.report import _png

    others = [e for e in board["runs"] if not e["baseline"]]
    panels = [("success", "success − baseline (points)")] + [(c, f"{c} − baseline") for c in PAIRED_SCORES]
    fig, axes = plt.subplots(
        1, len(panels), figsize=(4 * len(panels), 0.5 * len(others) + 1.6), squeeze=False
    )
    for ax, (key, label) in zip(axes[0], panels, strict=True):
        for y, e in enumerate(others):
            v = e["vs_baseline"]
            if key == "success":
                m, ci, k = v["diff"], v["diff_ci95"], 100.0
            else:
                d = v["scores"][key]
                m, ci, k = d.get("mean_diff_b_minus_a"), d.get("diff_ci95"), 1.0
            if m is None or not ci or ci[0] is None:
                ax.text(0, y, "n/a", ha="center", va="center", fontsize=8)
                continue
            ax.errorbar([k * m], [y], xerr=[[k * (m - ci[0])], [k * (ci[1] - m)]], fmt="o", color="#4575b4",
                        capsize=4)  # fmt: skip
        ax.axvline(0.0, color="#808080", lw=1)
        ax.set_yticks(range(len(others)), [e["pilot"][:30] for e in others] if ax is axes[0][0] else [],
                      fontsize=8)  # fmt: skip
        ax.set_ylim(len(others) - 0.5, -0.5)
        ax.set_title(label, fontsize=9)
    fig.subplots_adjust(top=0.8 if len(others) < 4 else 0.9, wspace=0.25)
    fig.suptitle(f"paired with the baseline {board['baseline_pilot']} on the same scenarios (95 % CI, bootstrap)",
                 fontsize=9, y=1.0)  # fmt: skip
    return _png(fig)


def render_leaderboard_html(
    board: dict[str, Any], docs: dict[str, dict[str, Any]], mismatches: list[str]
) -> str:
    """The leaderboard page (self-contained): ranked table, per-scenario outcomes, figures."""
    from viva_sitl.evaluation.report import _CSS, FIGURES_HINT, _fmt, figure_touchdowns, figures_missing_note

    esc = html.escape
    parts = [f"<!doctype html><html><head><meta charset='utf-8'><title>viva-sitl trials leaderboard</title>"
             f"<style>{_CSS}</style></head><body><h1>Leaderboard against <code>{esc(board['baseline_pilot'])}</code>"
             f"</h1><p id='about'>{len(board['runs'])} runs, each paired with the baseline "
             f"<code>{esc(board['baseline'])}</code> on the <b>{board['shared_trials']}</b> scenarios all runs share "
             f"(same trial index, seed and scenario: <b>{board['same_scenarios']}</b>). Success rates with 95 % "
             "Wilson intervals; differences to the baseline with 95 % bootstrap intervals over the pairs; McNemar's "
             "exact test on the discordant pairs, p-values adjusted with Holm's method over the runs compared "
             "(family-wise error). Ranked by success rate, then wins − losses.</p>"]  # fmt: skip
    if mismatches:
        parts.append("<p class='bad' id='mismatch'><b>WARNING: the runs were not made under the same conditions</b> "
                     "(compared with --allow-mismatch): " + "; ".join(esc(x) for x in mismatches) + ".</p>")  # fmt: skip
    if not board["same_scenarios"]:
        parts.append("<p class='bad'>The runs were drawn from different scenarios: pairs match by index and seed "
                     "only.</p>")  # fmt: skip
    parts.append("<h2>Ranking</h2><div class='scroll'><table id='leaderboard'><tr><th>rank</th><th class='l'>pilot"
                 "</th><th class='l'>run</th><th>success</th><th>95 % CI (Wilson)</th><th>− baseline (points)</th>"
                 "<th>95 % CI</th><th>wins / losses / ties</th><th>McNemar p</th><th>Holm p</th>"
                 "<th>min dist person − baseline (m)</th><th>time to land − baseline (s)</th>"
                 "<th class='l'>risk level vs baseline</th></tr>")  # fmt: skip
    for e in board["runs"]:
        v = e.get("vs_baseline")
        head = (f"<tr data-run='{esc(e['run'])}'><td>{e['rank']}</td><td class='l'><code>{esc(e['pilot'])}</code>"
                f"{' (baseline)' if e['baseline'] else ''}</td><td class='l'>{esc(e['run'])}</td>"
                f"<td>{e['success']}/{e['judged']} = {_pct(e['rate'])}</td><td>{_ci_pct(e['rate_ci95_wilson'])} %</td>")  # fmt: skip
        if v is None:
            parts.append(head + "<td colspan=8 class='l'>baseline</td></tr>")
            continue
        sc = v["scores"]

        def md(key: str, sc: dict[str, Any] = sc) -> str:
            d = sc[key]
            if not d.get("pairs"):
                return "n/a"
            return f"{_fmt(d['mean_diff_b_minus_a'])} ({_fmt(d['diff_ci95'][0])} – {_fmt(d['diff_ci95'][1])})"

        rk = sc["risk_level"]
        risk = (f"lower {rk['b_lower']}, same {rk['same']}, higher {rk['b_higher']} (sign p {rk['sign_test_p']})"
                if rk.get("pairs") else "n/a")  # fmt: skip
        diff = "—" if v["diff"] is None else f"{100 * v['diff']:+.1f}"
        parts.append(head + f"<td>{diff}</td><td>{_ci_pct(v['diff_ci95'], True)}</td><td>{v['wins']} / "
                     f"{v['losses']} / {v['ties']}</td><td>{v['mcnemar_p']}</td><td>{v['holm_p']}</td>"
                     f"<td>{md('min_dist_person_m')}</td><td>{md('time_to_land_s')}</td><td class='l'>{risk}</td></tr>")  # fmt: skip
    parts.append("</table></div>")
    figs = figures_missing_note() is None
    if not figs:
        parts.append(f"<p>(figures need matplotlib: <code>{FIGURES_HINT}</code>)</p>")
    else:
        parts.append("<h2>Success</h2><img alt='success with confidence intervals' src='data:image/png;base64,"
                     f"{figure_success(board)}'><h2>Paired differences</h2><img alt='paired differences' "
                     f"src='data:image/png;base64,{figure_paired(board)}'>")  # fmt: skip
    # per scenario: each run's outcome; win / loss against the baseline marked
    order = board["order"]
    base = order.index(board["baseline"])
    parts.append("<h2>Per scenario</h2><p>Success per shared scenario (yes / no / unscored); <b>W</b>: success where "
                 "the baseline failed, <b>L</b>: failure where it succeeded.</p><div class='scroll'><table id='scenarios'>"
                 "<tr><th>trial</th><th>seed</th>" + "".join(f"<th data-run='{esc(p)}'>{esc(docs[p]['pilot'][:24])}"
                 "</th>" for p in order) + "</tr>")  # fmt: skip
    for sc_ in board["per_scenario"]:
        cells = []
        b = sc_["success"][base]
        for i, ok in enumerate(sc_["success"]):
            mark = ""
            if i != base and ok is not None and b is not None and ok != b:
                mark = " W" if ok else " L"
            cls = "ok" if ok else "bad" if ok is False else ""
            txt = "unscored" if ok is None else "yes" if ok else "no"
            cells.append(f"<td class='{cls}' title='{esc(str(sc_['end'][i]))}'>{txt}{mark}</td>")
        parts.append(f"<tr data-trial='{sc_['trial']}'><td>{sc_['trial']}</td><td>{sc_['seed']}</td>"
                     + "".join(cells) + "</tr>")  # fmt: skip
    parts.append("</table></div>")
    if figs:
        parts.append(
            "<h2>Touchdowns side by side</h2><div id='maps' style='display:flex;flex-wrap:wrap;gap:8px'>"
        )
        for e in board["runs"][:MAX_MAPS]:
            doc = docs[e["run"]]
            footages = sorted({r["footage"] for r in doc["rows"]})
            if not footages:
                continue
            try:
                b64 = figure_touchdowns(doc, Path(e["run"]), footages[0])
            except Exception as exc:  # noqa: BLE001 - a figure must never lose the page
                parts.append(f"<p>touchdowns of {esc(e['pilot'])}: {esc(str(exc))}</p>")
                continue
            if b64:
                parts.append(f"<figure style='margin:0;width:32%;min-width:300px'><img alt='touchdowns of "
                             f"{esc(e['pilot'])}' src='data:image/png;base64,{b64}'><figcaption>{e['rank']}. "
                             f"<code>{esc(e['pilot'])}</code> over {esc(footages[0])}</figcaption></figure>")  # fmt: skip
        parts.append("</div>")
    parts.append("</body></html>")
    return "\n".join(parts)


__all__ = ["conditions", "leaderboard", "render_leaderboard_html", "run_mismatches", "spec_identity"]
