"""Failure search vs uniform sampling: trials of `descend` flown until the first k failures are found, on the
synthetic field (exact ground truth), both methods in the same run over the same seeds.

    .venv/bin/python bench/bench_search.py --seeds 5 --k 1 3 5 --budget 64 --uniform-budget 240

The space: configs/trials/synthetic_emergency.toml with its start box widened to the whole field (north/east left
to the footage minus the 10 m margin, about +-92 m): the people, the plaza and the ring road take a small part of
it, so failures are rarer than in the spec as shipped (printed: the uniform failure rate). `--spec PATH` benches any
other spec. Both methods fly real in-process trials through viva_sitl.evaluation.search (`method="cem"` and
`method="uniform"`: the spec's own distribution, what `trials run` draws); for a seed, uniform's first 8 trials
are CEM's generation 0 (one seeded stream). A method that finds fewer than k failures in its budget counts as
"> budget" (the median then reads "> budget" when half the seeds did).

Two counts: any failures (every failing trial), and distinct failures (search.pick_distinct: other failed checks,
or a touchdown -- else start -- more than 10 m from every earlier failure's: another place). Each run stops at
the k-th distinct failure, so "any" also reads past k when duplicates came first.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from viva_sitl.evaluation.search import pick_distinct, search, space_of  # noqa: E402
from viva_sitl.evaluation.spec import Criterion, TrialSpec, load_spec  # noqa: E402


def field_spec(people_only: bool) -> TrialSpec:
    """synthetic_emergency over the whole field; people_only: the criterion keeps landed, touchdown speed and
    >= 5 m from people (risk check off): "where does descend land next to someone?", a rarer failure."""
    spec = load_spec(REPO / "configs" / "trials" / "synthetic_emergency.toml")
    spec = dataclasses.replace(spec, name="synthetic-emergency-field", north_m=None, east_m=None,
                               source="synthetic_emergency.toml, start box = the whole field")  # fmt: skip
    if people_only:
        crit = Criterion(name="people", max_risk_level=None)
        spec = dataclasses.replace(spec, criterion=crit, source=spec.source + ", criterion: people only")
    return spec


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", help="a trial spec (default: synthetic_emergency over the whole field)")
    ap.add_argument(
        "--people-only", action="store_true", help="the default spec with the people criterion only"
    )
    ap.add_argument("--pilot", default="descend")
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--k", type=int, nargs="+", default=[1, 3, 5])
    ap.add_argument("--budget", type=int, default=64, help="CEM trials per seed")
    ap.add_argument("--uniform-budget", type=int, default=240, help="uniform trials per seed")
    ap.add_argument("--batch", type=int, default=8)
    ap.add_argument("--jobs", type=int, default=1)
    a = ap.parse_args()
    spec = load_spec(a.spec) if a.spec else field_spec(a.people_only)
    kmax = max(a.k)
    load0 = os.getloadavg()[0]
    print(f"spec: {spec.source}  pilot: {a.pilot}  free dims: {len(space_of(spec))}  seeds: {a.seeds}  "
          f"k: {a.k}  budgets: cem {a.budget}, uniform {a.uniform_budget}  batch {a.batch}  jobs {a.jobs}  "
          f"load {load0:.1f}", flush=True)  # fmt: skip
    rows: dict[str, dict[int, list[float]]] = {m: {k: [] for k in a.k} for m in ("cem", "uniform")}
    drows: dict[str, dict[int, list[float]]] = {m: {k: [] for k in a.k} for m in ("cem", "uniform")}
    flown = {"cem": 0, "uniform": 0}
    failed = {"cem": 0, "uniform": 0}
    distinct: dict[str, list[int]] = {"cem": [], "uniform": []}
    wall = {"cem": 0.0, "uniform": 0.0}
    for seed in range(a.seeds):
        for method, budget in (("cem", a.budget), ("uniform", a.uniform_budget)):
            t0 = time.perf_counter()
            res = search(spec, a.pilot, budget, seed=seed, method=method, batch=a.batch, max_failures=0,
                         stop_after=kmax, stop_distinct=True, jobs=a.jobs)  # fmt: skip
            wall[method] += time.perf_counter() - t0
            evs = res.search_evals
            flown[method] += len(evs)
            failed[method] += sum(e.failed for e in evs)
            distinct[method].append(len(pick_distinct(evs, len(evs))))
            got = {k: res.trials_to_failures(k) for k in a.k}
            dgot = {k: res.trials_to_failures(k, distinct=True) for k in a.k}
            for k in a.k:
                rows[method][k].append(float(got[k]) if got[k] is not None else float("inf"))
                drows[method][k].append(float(dgot[k]) if dgot[k] is not None else float("inf"))
            print(f"seed {seed} {method:7s}: any " + ", ".join(f"k={k}: {got[k] or '>' + str(len(evs))}" for k in a.k)
                  + "; distinct " + ", ".join(f"k={k}: {dgot[k] or '>' + str(budget)}" for k in a.k)
                  + f"  ({len(evs)} trials, {time.perf_counter() - t0:.0f} s)", flush=True)  # fmt: skip

    def fmt(x: float, budget: int) -> str:
        return f"> {budget}" if x == float("inf") else f"{x:g}"

    for title, table in (("distinct failures (the search's stop condition)", drows), ("any failures", rows)):
        print(f"\n{title}:\n")
        print(
            "| k | CEM: trials to k failures (median; per seed) | uniform: same | uniform / CEM (medians) |"
        )
        print("|---:|---|---|---:|")
        for k in a.k:
            c, u = table["cem"][k], table["uniform"][k]
            mc, mu = statistics.median(c), statistics.median(u)
            if mc == float("inf"):
                ratio = "n/a"
            else:
                ratio = ("> " if mu == float("inf") else "") + f"{min(mu, a.uniform_budget) / mc:.1f}x"
            print(f"| {k} | **{fmt(mc, a.budget)}** ({', '.join(fmt(x, a.budget) for x in c)}) | "
                  f"**{fmt(mu, a.uniform_budget)}** ({', '.join(fmt(x, a.uniform_budget) for x in u)}) | {ratio} |")  # fmt: skip
    print()
    for m in ("cem", "uniform"):
        rate = failed[m] / flown[m] if flown[m] else 0.0
        print(f"{m}: {flown[m]} trials flown in all, {failed[m]} failures ({100 * rate:.1f} %), "
              f"distinct per seed {distinct[m]}, wall {wall[m]:.0f} s ({wall[m] / max(1, flown[m]):.2f} s "
              "per trial)")  # fmt: skip
    print(f"load average before -> after: {load0:.1f} -> {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
