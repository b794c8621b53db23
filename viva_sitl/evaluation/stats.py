"""Aggregates with bootstrap confidence intervals, and paired statistics of two pilots on the same scenarios.

Deterministic: every bootstrap uses its own numpy Generator seeded from BOOTSTRAP_SEED (same rows -> same numbers).
Percentile bootstrap, 95 % by default, 2000 resamples; success rates also get the Wilson score interval (exact
enough at small N where the bootstrap of a proportion collapses to a point when all trials agree).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from viva_sitl.evaluation.scoring import check_outcomes
from viva_sitl.evaluation.spec import Criterion

BOOTSTRAP_SEED = 20240513
RESAMPLES = 2000
SUMMARY_COLUMNS = (
    "touchdown_speed_m_s", "touchdown_vertical_speed_m_s", "touchdown_horizontal_speed_m_s", "dist_person_m",
    "min_dist_person_m", "dist_vehicle_m", "min_dist_vehicle_m", "dist_object_m",
    "min_dist_object_m", "risk_level", "time_to_land_s", "path_length_m",
    "energy_wh", "time_outside_footage_s", "flight_time_s",
)  # fmt: skip
ORDINAL_COLUMNS = ("risk_level",)  # levels 1..5: counts per level and the median, never a mean


def bootstrap_ci(values: np.ndarray, stat: Any = np.mean, level: float = 0.95,
                 resamples: int = RESAMPLES) -> tuple[float, float]:  # fmt: skip
    x = np.asarray(values, np.float64)
    if x.size == 0:
        return (math.nan, math.nan)
    rng = np.random.default_rng(BOOTSTRAP_SEED)
    idx = rng.integers(0, x.size, size=(resamples, x.size))
    s = stat(x[idx], axis=1)
    a = (1.0 - level) / 2.0
    return float(np.quantile(s, a)), float(np.quantile(s, 1.0 - a))


def wilson_ci(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    if n == 0:
        return (math.nan, math.nan)
    z = {0.9: 1.6448536, 0.95: 1.959964, 0.99: 2.5758293}.get(level, 1.959964)
    p = k / n
    den = 1 + z * z / n
    c = (p + z * z / (2 * n)) / den
    h = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / den
    return max(0.0, c - h), min(1.0, c + h)


def _num(rows: list[dict[str, Any]], key: str) -> np.ndarray:
    return np.array([float(r[key]) for r in rows if r.get(key) is not None], np.float64)


def _r(x: float, nd: int = 4) -> float | None:
    return None if not math.isfinite(x) else round(x, nd)


def aggregate(
    rows: list[dict[str, Any]], criterion_name: str, criterion: Criterion | None = None
) -> dict[str, Any]:
    """Success (over the judged trials), per-check rates of `criterion` (each over the trials where it could be
    judged; `unavailable` counts the others), ends, and a summary of every score (risk level: a distribution)."""
    n = len(rows)
    judged = [r for r in rows if r.get("success") is not None]
    k = sum(1 for r in judged if r["success"])
    ends: dict[str, int] = {}
    for r in rows:
        ends[str(r.get("end"))] = ends.get(str(r.get("end")), 0) + 1
    out: dict[str, Any] = {
        "n": n,
        "criterion": criterion_name,
        "success_judged": len(judged),  # trials the criterion could be evaluated on (ground truth available)
        "success": k,
        "success_unscored": n
        - len(judged),  # no check failed but one could not be judged (criterion_unavailable)
        "success_rate": _r(k / len(judged)) if judged else None,
        "success_rate_ci95_wilson": [_r(v) for v in wilson_ci(k, len(judged))] if judged else None,
        "success_rate_ci95_bootstrap": (
            [_r(v) for v in bootstrap_ci(np.array([1.0 if r["success"] else 0.0 for r in judged]))]
            if judged
            else None
        ),
        "landed": sum(1 for r in rows if r.get("landed")),
        "landed_rate": _r(sum(1 for r in rows if r.get("landed")) / n) if n else None,
        "ends": dict(sorted(ends.items())),
        "scores": {},
    }
    if criterion is not None:
        out["checks"] = check_rates(rows, criterion)
    for key in SUMMARY_COLUMNS:
        x = _num(rows, key)
        if x.size == 0:
            out["scores"][key] = {"n": 0}
            continue
        if key in ORDINAL_COLUMNS:
            out["scores"][key] = {
                "n": int(x.size), "counts": {str(lv): int(np.sum(x == lv)) for lv in range(1, 6)},
                "median": _r(float(np.median(x))), "min": _r(float(x.min())), "max": _r(float(x.max())),
            }  # fmt: skip
            continue
        lo, hi = bootstrap_ci(x)
        out["scores"][key] = {
            "n": int(x.size), "mean": _r(float(x.mean())), "mean_ci95": [_r(lo), _r(hi)],
            "median": _r(float(np.median(x))), "min": _r(float(x.min())), "max": _r(float(x.max())),
            "p10": _r(float(np.quantile(x, 0.1))), "p90": _r(float(np.quantile(x, 0.9))),
        }  # fmt: skip
    return out


def check_rates(rows: list[dict[str, Any]], criterion: Criterion) -> dict[str, Any]:
    """Per check of the criterion: passed / judged (Wilson 95 %), and how many trials could not judge it."""
    acc: dict[str, list[int]] = {}
    for r in rows:
        for name, ok, _ in check_outcomes(r, criterion):
            a = acc.setdefault(name, [0, 0, 0])  # passed, judged, unavailable
            if ok is None:
                a[2] += 1
            else:
                a[1] += 1
                a[0] += int(ok)
    return {
        name: {
            "passed": p,
            "judged": j,
            "unavailable": u,
            "rate": _r(p / j) if j else None,
            "rate_ci95_wilson": [_r(v) for v in wilson_ci(p, j)] if j else None,
        }  # fmt: skip
        for name, (p, j, u) in acc.items()
    }


def paired(rows_a: list[dict[str, Any]], rows_b: list[dict[str, Any]]) -> dict[str, Any]:
    """Two runs over the same scenarios (matched by trial index and scenario seed): success both/only A/only B,
    McNemar's exact test, and per-score mean differences (B - A) with bootstrap CIs over the pairs."""
    a = {(r["trial"], r["seed"]): r for r in rows_a}
    b = {(r["trial"], r["seed"]): r for r in rows_b}
    keys = sorted(set(a) & set(b))
    out: dict[str, Any] = {
        "pairs": len(keys),
        "unmatched_a": len(a) - len(keys),
        "unmatched_b": len(b) - len(keys),
    }
    judged = [k for k in keys if a[k].get("success") is not None and b[k].get("success") is not None]
    both = sum(1 for k in judged if a[k]["success"] and b[k]["success"])
    only_a = sum(1 for k in judged if a[k]["success"] and not b[k]["success"])
    only_b = sum(1 for k in judged if b[k]["success"] and not a[k]["success"])
    out["success"] = {
        "judged_pairs": len(judged), "both": both, "only_a": only_a, "only_b": only_b,
        "neither": len(judged) - both - only_a - only_b,
        "rate_a": _r((both + only_a) / len(judged)) if judged else None,
        "rate_b": _r((both + only_b) / len(judged)) if judged else None,
        "mcnemar_p": _r(mcnemar_exact(only_a, only_b), 6),
    }  # fmt: skip
    if judged:
        d = np.array([float(bool(b[k]["success"])) - float(bool(a[k]["success"])) for k in judged])
        lo, hi = bootstrap_ci(d)
        out["success"]["diff_b_minus_a"] = _r(float(d.mean()))
        out["success"]["diff_ci95"] = [_r(lo), _r(hi)]
    out["scores"] = {}
    for key in SUMMARY_COLUMNS:
        pairs = [
            (a[k][key], b[k][key]) for k in keys if a[k].get(key) is not None and b[k].get(key) is not None
        ]
        if not pairs:
            out["scores"][key] = {"pairs": 0}
            continue
        if key in ORDINAL_COLUMNS:  # levels, not quantities: how many pairs B ranks lower / same / higher
            out["scores"][key] = paired_ordinal(pairs)
            continue
        d = np.array([float(y) - float(x) for x, y in pairs])
        lo, hi = bootstrap_ci(d)
        out["scores"][key] = {
            "pairs": len(pairs), "mean_a": _r(float(np.mean([p[0] for p in pairs]))),
            "mean_b": _r(float(np.mean([p[1] for p in pairs]))), "mean_diff_b_minus_a": _r(float(d.mean())),
            "diff_ci95": [_r(lo), _r(hi)],
        }  # fmt: skip
    return out


def paired_ordinal(pairs: list[tuple[Any, Any]]) -> dict[str, Any]:
    """An ordinal score (risk level) over pairs (A, B): a difference of levels has no unit, so no mean: the pairs
    where B is lower / the same / higher than A, each side's median, and the exact two-sided sign test on the
    pairs that differ (the binomial test McNemar's is)."""
    lower = sum(1 for x, y in pairs if float(y) < float(x))
    higher = sum(1 for x, y in pairs if float(y) > float(x))
    return {
        "pairs": len(pairs), "ordinal": True, "b_lower": lower, "same": len(pairs) - lower - higher,
        "b_higher": higher, "median_a": _r(float(np.median([float(p[0]) for p in pairs]))),
        "median_b": _r(float(np.median([float(p[1]) for p in pairs]))), "sign_test_p": _r(mcnemar_exact(lower, higher), 6),
    }  # fmt: skip


def holm(pvalues: list[float]) -> list[float]:
    """Holm-Bonferroni adjusted p-values (step-down; same order as given): controls the family-wise error rate
    over the m tests without assuming them independent."""
    m = len(pvalues)
    order = sorted(range(m), key=lambda i: pvalues[i])
    out = [1.0] * m
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * pvalues[i]))
        out[i] = running
    return out


def mcnemar_exact(b: int, c: int) -> float:
    """Two-sided exact McNemar p-value on the discordant pairs (binomial, p = 1/2)."""
    n = b + c
    if n == 0:
        return 1.0
    k = min(b, c)
    tail = sum(math.comb(n, i) for i in range(k + 1)) / 2.0**n
    return min(1.0, 2.0 * tail)
