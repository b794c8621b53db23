"""Where does a pilot fail? An adaptive search over a spec's scenario space, shrinking, and a rerunnable spec per
failure.

    viva-sitl trials search configs/trials/synthetic_emergency.toml --pilot descend --budget 60 --seed 0 -o out/s
    viva-sitl trials run out/s/failure-01.toml -o out/s-rerun       # flies the minimal failing scenario again

The space is the spec's own: every range `[lo, hi]` with lo < hi (start north/east -- the footage minus margin_m
when the spec leaves them out --, altitude, yaw, footage time, land-now time, wind speed and direction, gusts,
[scenario.params]), every choice of more than one item (footage, start) and every failure whose probability lies
strictly between 0 and 1 (present or not, and its time). A spec with none of these has nothing to search (one line).

Search: the cross-entropy method (CEM), seeded, in this file (numpy only). A candidate is a fixed spec: the spec
with every range collapsed to the candidate's value, n = 1 and seed = the search seed; it is flown exactly as
`trials run` would fly that spec (draw_scenario, then campaign.run_one), so a candidate found here is a spec a user
can rerun unchanged. Generation 0 (`batch` trials) draws from the spec's own distribution (uniform ranges, the
spec's choice and failure probabilities); after each generation the elite is the best 10 % (at least 4) of every
trial flown so far, by a failure score, and the next generation samples from a mixture around it: a random elite
point, moved by a normal per range in [0, 1]-normalised coordinates (spread: half the elite's, smoothed, never below
0.05 so it keeps exploring), its choices kept or (probability 0.2) redrawn from the elite's smoothed frequencies.
A mixture rather than CEM's single normal: failures lie in several places (next to different people, on the road
ring) and one mean between two of them lands on neither. A failure found 3 times (the same failed checks, touchdown
-- else start -- within 10 m: the same place) leaves the elite, so the search moves on to other failures rather than flying
the same one again. `method="uniform"` keeps drawing from the spec's own
distribution (the baseline of bench/bench_search.py).

Failure score (higher = worse; > 0 exactly when a check of the spec's criterion failed): per check of the
criterion a normalised violation -- not landed: 1; touchdown speed v: v / max - 1; distance d to people / vehicles /
objects (the smaller of the final-descent minimum and the touchdown distance): (min - d) / min; risk level r:
(r - max - 0.5) / (5 - max) --; the largest when one is positive, else their mean (so a trial that passed still
ranks by how close it came, e.g. by its distance to people). A failure is `success == false`; trials the harness
failed (results.INFRA_ENDS: trial_error, worker_died, ...) are not failures of the pilot and never elite.

Shrinking: each failure kept (up to max_failures, distinct: other failed checks or another place) is
moved towards the spec's nominal scenario one parameter at a time -- failures off, gusts and wind speed to the low
end, PX4 parameters to their default (clamped into the range), the first listed footage / start, every other range
to its midpoint -- first all the way, else by bisection (shrink_steps halvings), keeping a move only while the
trial still fails one of the same checks. What is left off nominal is what the failure needs. Each minimal
scenario is written as OUT/failure-NN.toml (n = 1, every range fixed; `trials run` flies it unchanged: checked by
drawing it back from the written file), and OUT/search.json lists every trial flown (no wall times: the same seed
writes the same bytes).

Why not a library: none light is installed (optuna, nevergrad, hyperopt, cma are registry packages this project
does not depend on; optuna and nevergrad pull in dozens of modules for what is ~60 lines here), and the search must
be exactly reproducible from one seed with the spec's own mixed continuous / categorical ranges.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # the rest is imported where used: `viva-sitl trials --help` builds this parser, not numpy
    from concurrent.futures import ProcessPoolExecutor

    import numpy as np

    from viva_sitl.evaluation.spec import FootageBox, Range, Scenario, TrialSpec

SEARCH_SCHEMA = "vivasitl.search.v1"
METHODS = ("cem", "uniform")
_SIGMA_MIN = 0.05  # normalised spread floor: CEM never stops exploring around its elite
_ALPHA = 0.7  # smoothing of the CEM update
_ELITE = 0.1  # elite fraction of every trial flown so far (at least _ELITE_MIN)
_ELITE_MIN = 4
SAME_PLACE_M = 10.0  # two failures of the same checks this close (touchdown, else start) are the same failure
_SPENT = 3  # a failure found this many times is left out of the elite


@dataclass(frozen=True)
class Dim:
    """One free parameter of the scenario space. Real dims live in [0, 1] (u), mapped to [lo, hi]; choice dims
    pick an index into `choices` with the spec's own probabilities `prior`."""

    name: str
    kind: str  # "real" | "choice"
    lo: float = 0.0
    hi: float = 1.0
    nominal: float = 0.5  # real: u of the nominal value; choice: its index
    choices: tuple[str, ...] = ()
    prior: tuple[float, ...] = ()
    integer: bool = False  # an INT32 PX4 parameter: its values are whole numbers


Point = dict[str, Any]  # dim name -> u in [0, 1] (real) or choice index (int)


@dataclass
class Evaluation:
    index: int
    phase: str  # "search" | "shrink"
    generation: int
    values: dict[str, Any]  # the scenario values the fixed spec holds (what a user reads)
    point: Point
    row: dict[str, Any]
    score: float | None  # None: the harness failed (not the pilot)
    failed: bool
    failed_checks: tuple[str, ...]

    def record(self) -> dict[str, Any]:
        keep = ("end", "end_detail", "success", "criterion_failures", "touchdown_north_m", "touchdown_east_m",
                "touchdown_speed_m_s", "min_dist_person_m", "dist_person_m", "risk_level")  # fmt: skip
        return {
            "index": self.index, "phase": self.phase, "generation": self.generation, "values": self.values,
            "score": None if self.score is None else round(self.score, 6), "failed": self.failed,
            "failed_checks": list(self.failed_checks), "result": {k: self.row.get(k) for k in keep},
        }  # fmt: skip


@dataclass
class SearchResult:
    spec: TrialSpec
    pilot: str
    seed: int
    method: str
    budget: int
    evaluations: list[Evaluation] = field(default_factory=list)
    minimal: list[dict[str, Any]] = field(default_factory=list)  # one per shrunk failure (+ its spec path)

    @property
    def search_evals(self) -> list[Evaluation]:
        return [e for e in self.evaluations if e.phase == "search"]

    def trials_to_failures(self, k: int, distinct: bool = False) -> int | None:
        """Search trials flown until the k-th failure (distinct: the k-th that pick_distinct keeps) was found
        (None: fewer than k found)."""
        found: list[Evaluation] = []
        for n, e in enumerate(self.search_evals, 1):
            if e.failed and (not distinct or _is_new(e, found)):
                found.append(e)
            if len(found) >= k:
                return n
        return None


# ------------------------------------------------------------------------------------------ the space


def _unit(v: float, r: Range) -> float:
    return 0.0 if r[1] <= r[0] else min(1.0, max(0.0, (v - r[0]) / (r[1] - r[0])))


def space_of(spec: TrialSpec) -> list[Dim]:
    """The spec's free parameters, in shrinking order (disturbances first, the pose last)."""
    from viva_sitl.autopilot.params import ParamStore, ParamType

    dims: list[Dim] = []
    for k, f in enumerate(spec.failures):
        if 0.0 < f.probability < 1.0:
            dims.append(Dim(f"failures[{k}]", "choice", nominal=0, choices=("absent", f.kind),
                            prior=(1.0 - f.probability, f.probability)))  # fmt: skip
    for key in ("gust_std_m_s", "wind_speed_m_s"):
        r = getattr(spec, key)
        if r[1] > r[0]:
            dims.append(Dim(key, "real", r[0], r[1], nominal=0.0))
    store = ParamStore()
    for name, r in spec.params:
        if r[1] > r[0]:
            integer = store.spec(name).type == ParamType.INT32
            dims.append(Dim(f"params.{name}", "real", r[0], r[1], nominal=_unit(float(store.get(name)), r),
                            integer=integer))  # fmt: skip
    for k, f in enumerate(spec.failures):
        if f.probability > 0.0 and f.at_s[1] > f.at_s[0]:
            dims.append(Dim(f"failures[{k}].at_s", "real", f.at_s[0], f.at_s[1]))
    for key in ("land_at_s", "footage_time_s", "yaw_deg", "wind_dir_deg", "altitude_m"):
        r = getattr(spec, key)
        if r[1] > r[0]:
            dims.append(Dim(key, "real", r[0], r[1]))
    for key in ("north_m", "east_m"):
        r = getattr(spec, key)
        if r is None:  # the footage's box minus margin_m: u maps into the chosen footage's box
            dims.append(Dim(key, "real", 0.0, 1.0))
        elif r[1] > r[0]:
            dims.append(Dim(key, "real", r[0], r[1]))
    for key in ("footage", "start"):
        items = getattr(spec, key)
        if len(items) > 1:
            dims.append(Dim(key, "choice", nominal=0, choices=tuple(items),
                            prior=tuple([1.0 / len(items)] * len(items))))  # fmt: skip
    return dims


def nominal_point(dims: list[Dim]) -> Point:
    return {d.name: (int(d.nominal) if d.kind == "choice" else float(d.nominal)) for d in dims}


def _r6(x: float) -> float:
    return round(float(x), 6)


def _real(spec: TrialSpec, dims_by: dict[str, Dim], point: Point, key: str, r: Range) -> float:
    if key in dims_by:
        v = r[0] + point[key] * (r[1] - r[0])
        if dims_by[key].integer:  # the nearest whole number inside the range
            v = min(math.floor(r[1]), max(math.ceil(r[0]), round(v)))
        return _r6(v)
    return _r6(r[0])


def fixed_spec(spec: TrialSpec, point: Point, dims: list[Dim], seed: int, boxes: dict[str, FootageBox],
               name: str | None = None) -> TrialSpec | None:  # fmt: skip
    """The spec with every range collapsed to the point's value (n = 1, seed = seed); None when the point's start
    lies outside its footage (rotated footage: the box is wider than the ground)."""
    from viva_sitl.evaluation.spec import FailureSpec

    by = {d.name: d for d in dims}

    def choice(key: str, items: tuple[str, ...]) -> str:
        return items[int(point[key])] if key in by else items[0]

    footage = choice("footage", spec.footage)
    start = choice("start", spec.start)
    box = boxes[footage]
    m = spec.margin_m
    ne: list[float] = []
    for key, rng_, lim in (("north_m", spec.north_m, box.north_m), ("east_m", spec.east_m, box.east_m)):
        r = rng_ if rng_ is not None else (lim[0] + m, lim[1] - m)
        ne.append(_real(spec, by, point, key, r))
    if spec.north_m is None and not box.geometry.contains_ned(ne[0], ne[1], m):
        return None
    ft = _real(spec, by, point, "footage_time_s", spec.footage_time_s)
    k = spec.footage_time_slots
    lo, hi = spec.footage_time_s
    if k > 0 and hi > lo:  # the spec's own snapping to one of k slots
        ft = _r6(lo + (hi - lo) * min(k - 1, math.floor((ft - lo) / (hi - lo) * k)) / k)
    fails = []
    for j, f in enumerate(spec.failures):
        on = f.probability >= 1.0 or (f"failures[{j}]" in by and int(point[f"failures[{j}]"]) == 1)
        if on:
            at = _real(spec, by, point, f"failures[{j}].at_s", f.at_s)
            fails.append(FailureSpec(f.kind, (at, at), 1.0))

    def pin(key: str) -> Range:
        v = _real(spec, by, point, key, getattr(spec, key))
        return (v, v)

    params = []
    for pname, r in spec.params:
        v = _real(spec, by, point, f"params.{pname}", r)
        params.append((pname, (v, v)))
    return dataclasses.replace(
        spec, name=name or spec.name, n=1, seed=seed, footage=(footage,), start=(start,),
        north_m=(ne[0], ne[0]), east_m=(ne[1], ne[1]), altitude_m=pin("altitude_m"), yaw_deg=pin("yaw_deg"),
        footage_time_s=(ft, ft), footage_time_slots=0, land_at_s=pin("land_at_s"),
        wind_speed_m_s=pin("wind_speed_m_s"), wind_dir_deg=pin("wind_dir_deg"), gust_std_m_s=pin("gust_std_m_s"),
        params=tuple(params), failures=tuple(fails),
    )  # fmt: skip


def values_of(fixed: TrialSpec) -> dict[str, Any]:
    """The scenario values a fixed spec holds (search.json's readable form)."""
    v: dict[str, Any] = {"footage": fixed.footage[0], "start": fixed.start[0]}
    for key in ("north_m", "east_m", "altitude_m", "yaw_deg", "footage_time_s", "land_at_s", "wind_speed_m_s",
                "wind_dir_deg", "gust_std_m_s"):  # fmt: skip
        v[key] = getattr(fixed, key)[0]
    v["params"] = {k: r[0] for k, r in fixed.params}
    v["failures"] = [{"kind": f.kind, "at_s": f.at_s[0]} for f in fixed.failures]
    return v


# ------------------------------------------------------------------------------------------ scoring


def failure_score(row: dict[str, Any], spec: TrialSpec) -> tuple[float | None, tuple[str, ...]]:
    """(score, failed checks): > 0 exactly when a check failed; None when the harness failed (not the pilot)."""
    from viva_sitl.evaluation.ends import INFRA_ENDS
    from viva_sitl.evaluation.scoring import check_outcomes

    if row.get("end") in INFRA_ENDS:
        return None, ()
    c = spec.criterion
    terms: list[float] = []
    if c.landed:
        terms.append(0.0 if row.get("landed") else 1.0)
    if c.max_touchdown_speed_m_s is not None and c.max_touchdown_speed_m_s > 0:
        v = row.get("touchdown_speed_m_s")
        terms.append(1.0 if v is None else v / c.max_touchdown_speed_m_s - 1.0)
    for lim, keys in ((c.min_dist_person_m, ("min_dist_person_m", "dist_person_m")),
                      (c.min_dist_vehicle_m, ("min_dist_vehicle_m", "dist_vehicle_m")),
                      (c.min_dist_object_m, ("min_dist_object_m", "dist_object_m"))):  # fmt: skip
        ds = [row[k] for k in keys if row.get(k) is not None]
        if lim is not None and lim > 0 and ds:
            terms.append((lim - min(ds)) / lim)
    if c.max_risk_level is not None and row.get("risk_level") is not None and c.max_risk_level < 5:
        terms.append((row["risk_level"] - c.max_risk_level - 0.5) / (5 - c.max_risk_level))
    failed = tuple(name for name, ok, _ in check_outcomes(row, c) if ok is False)
    if not terms:
        return (1.0 if failed else 0.0), failed
    top = max(terms)
    score = top if top > 0 else sum(terms) / len(terms)
    if failed and score <= 0:  # a check the terms do not see (e.g. an object class absent): still a failure
        score = 1.0
    return score, failed


# ------------------------------------------------------------------------------------------ flying


def _fly(job: tuple[TrialSpec, Scenario, str, str]) -> dict[str, Any]:
    from viva_sitl.evaluation.campaign import run_one

    spec, scenario, pilot, out = job
    row = run_one(spec, scenario, pilot, Path(out), 0, False)
    row.pop("wall_s", None)  # the only non-deterministic column
    return row


class _Flyer:
    """Flies batches of fixed specs, in this process (jobs = 1) or a spawn pool; results in input order."""

    def __init__(self, pilot: str, jobs: int, workdir: Path) -> None:
        self.pilot, self.jobs, self.workdir = pilot, jobs, workdir
        self.count = 0
        self.pool: ProcessPoolExecutor | None = None
        if jobs > 1:
            import multiprocessing as mp
            from concurrent.futures import ProcessPoolExecutor

            from viva_sitl.evaluation.campaign import init_trial_worker, worker_threads
            from viva_sitl.footage import autocache
            from viva_sitl.footage.tiles.settings import process_settings

            # its workers open footage as a campaign's do (cache policy, tile settings, the cores left to each)
            self.pool = ProcessPoolExecutor(
                jobs, mp_context=mp.get_context("spawn"), initializer=init_trial_worker,
                initargs=(autocache.policy(), process_settings(), worker_threads(jobs)),
            )  # fmt: skip

    def fly(self, specs: list[TrialSpec], boxes: dict[str, FootageBox]) -> list[dict[str, Any]]:
        from viva_sitl.evaluation.spec import draw_scenario

        jobs = []
        for s in specs:
            sc = draw_scenario(s, 0, s.seed, boxes)  # what `trials run` of this spec draws as its trial 0
            jobs.append((s, sc, self.pilot, str(self.workdir / f"{self.count:05d}")))
            self.count += 1
        if self.pool is None:
            return [_fly(j) for j in jobs]
        return list(self.pool.map(_fly, jobs))

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(cancel_futures=True)


# ------------------------------------------------------------------------------------------ search


class _Cem:
    def __init__(self, dims: list[Dim], rng: np.random.Generator) -> None:
        import numpy as np

        self.dims, self.rng = dims, rng
        self.sigma = {d.name: 0.25 for d in dims if d.kind == "real"}
        self.elite: list[Point] = []
        self.p = {d.name: np.array(d.prior, float) for d in dims if d.kind == "choice"}
        self.fitted = False

    def prior_sample(self) -> Point:
        import numpy as np

        pt: Point = {}
        for d in self.dims:  # one fixed order of draws: the same seed, the same points
            if d.kind == "real":
                pt[d.name] = float(self.rng.uniform())
            else:
                pt[d.name] = int(self.rng.choice(len(d.choices), p=np.array(d.prior, float)))
        return pt

    def sample(self) -> Point:
        """Around one elite point (drawn at random): a normal per range with the elite's (smoothed, halved)
        spread; its choices, or with probability 0.2 one drawn from the elite's smoothed frequencies. A mixture
        keeps several failure regions apart (one mean between two crowds would land between them)."""
        if not self.fitted:
            return self.prior_sample()
        centre = self.elite[int(self.rng.integers(len(self.elite)))]
        pt: Point = {}
        for d in self.dims:
            if d.kind == "real":
                x = self.rng.normal(centre[d.name], self.sigma[d.name])
                pt[d.name] = float(min(1.0, max(0.0, x)))
            else:
                fresh = self.rng.uniform() < 0.2
                pick = int(self.rng.choice(len(d.choices), p=self.p[d.name]))
                pt[d.name] = pick if fresh else int(centre[d.name])
        return pt

    def update(self, elite: list[Point]) -> None:
        import numpy as np

        a = _ALPHA if self.fitted else 1.0
        self.elite = list(elite)
        for d in self.dims:
            if d.kind == "real":
                xs = np.array([pt[d.name] for pt in elite])
                sd = a * 0.5 * float(xs.std()) + (1 - a) * self.sigma[d.name]
                self.sigma[d.name] = max(_SIGMA_MIN, sd)
            else:
                freq = np.bincount([pt[d.name] for pt in elite], minlength=len(d.choices)) / len(elite)
                p = a * freq + (1 - a) * self.p[d.name]
                p = np.maximum(p, 0.05 / len(d.choices))
                self.p[d.name] = p / p.sum()
        self.fitted = True


def check_search_args(spec: TrialSpec, pilot: str, budget: int, method: str) -> list[Dim]:
    from viva_sitl.evaluation.pilots import is_inprocess, make_pilot

    if isinstance(budget, bool) or not isinstance(budget, int) or budget < 1:
        raise ValueError(f"--budget must be an integer >= 1 (trials the search may fly), got {budget!r}")
    if method not in METHODS:
        raise ValueError(f"unknown search method {method!r} ({', '.join(METHODS)})")
    if not is_inprocess(pilot):
        raise ValueError(
            f"pilot {pilot!r}: trials search flies in-process pilots only (descend, oracle, package.module:Class)"
        )
    make_pilot(pilot)  # one line when it cannot be made, not one failed trial per candidate
    dims = space_of(spec)
    if not dims:
        raise ValueError(
            f"{spec.source or spec.name}: no free parameters to search (every range is fixed, every choice has one "
            "item, no failure has a probability strictly between 0 and 1)"
        )
    return dims


def search(
    spec: TrialSpec,
    pilot: str,
    budget: int,
    *,
    seed: int = 0,
    method: str = "cem",
    batch: int = 8,
    max_failures: int = 3,
    shrink_steps: int = 3,
    shrink_budget: int = 40,
    stop_after: int | None = None,
    stop_distinct: bool = False,
    jobs: int = 1,
    progress: Callable[[str], None] | None = None,
) -> SearchResult:
    """Fly up to `budget` search trials (stop early after `stop_after` failures, distinct ones with
    `stop_distinct`), then shrink up to `max_failures`
    distinct failures (each with up to `shrink_budget` more trials). Deterministic in (spec, pilot, seed, method,
    batch, ...): the job count changes nothing but the wall time."""
    import tempfile

    import numpy as np

    from viva_sitl.config import ConfigError
    from viva_sitl.evaluation.campaign import _importable_cwd
    from viva_sitl.evaluation.spec import check_bounds, footage_box

    _importable_cwd()
    dims = check_search_args(spec, pilot, budget, method)
    if batch < 1:
        raise ValueError(f"batch must be >= 1, got {batch}")
    boxes: dict[str, FootageBox] = {}
    from viva_sitl.footage import FootageError

    for name in spec.footage:
        try:
            boxes[name] = footage_box(name)
        except FootageError as exc:
            raise ConfigError(f"{spec.source}.scenario.footage: {exc}") from None
        check_bounds(spec, name, boxes[name])
    say = progress or (lambda _line: None)
    res = SearchResult(spec, pilot, seed, method, budget)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5EA5C4]))
    cem = _Cem(dims, rng)
    with tempfile.TemporaryDirectory(prefix="viva-search-") as tmp:
        flyer = _Flyer(pilot, jobs, Path(tmp))
        try:

            def fly(points: list[Point], phase: str, gen: int) -> list[Evaluation]:
                specs = []
                for pt in points:
                    fs = fixed_spec(spec, pt, dims, seed, boxes)
                    assert fs is not None
                    specs.append(fs)
                out = []
                for pt, fs, row in zip(points, specs, flyer.fly(specs, boxes), strict=True):
                    score, failed = failure_score(row, spec)
                    ev = Evaluation(len(res.evaluations), phase, gen, values_of(fs), dict(pt), row, score,
                                    row.get("success") is False and score is not None, failed)  # fmt: skip
                    res.evaluations.append(ev)
                    out.append(ev)
                return out

            def draw(n: int) -> list[Point]:
                pts: list[Point] = []
                while len(pts) < n:
                    for _ in range(
                        100
                    ):  # a start outside rotated footage: draw again (as draw_scenario does)
                        pt = cem.sample() if method == "cem" else cem.prior_sample()
                        if fixed_spec(spec, pt, dims, seed, boxes) is not None:
                            break
                    else:
                        raise ConfigError(f"{spec.source}: no start inside the footage after 100 draws")
                    pts.append(pt)
                return pts

            gen = 0
            while len(res.evaluations) < budget:
                evs = fly(draw(min(batch, budget - len(res.evaluations))), "search", gen)
                found = sum(e.failed for e in res.evaluations)
                say(f"generation {gen}: {len(res.evaluations)}/{budget} trials, {found} failure(s)")
                if stop_after is not None and res.trials_to_failures(stop_after, stop_distinct) is not None:
                    break
                if method == "cem":
                    spent = _spent(res)
                    valid = [e for e in res.evaluations if e.score is not None and e.index not in spent]
                    if valid:
                        ranked = sorted(valid, key=lambda e: (-(e.score or 0.0), e.index))
                        n_elite = max(_ELITE_MIN, math.ceil(_ELITE * len(valid)))
                        cem.update([e.point for e in ranked[:n_elite]])
                gen += 1
                del evs
            chosen = pick_distinct(res.search_evals, max_failures)
            for k, ev in enumerate(chosen, 1):
                say(f"shrinking failure {k}/{len(chosen)} (trial {ev.index}: {', '.join(ev.failed_checks)})")
                best = _shrink(ev, dims, spec, seed, boxes, fly, shrink_steps, shrink_budget)
                res.minimal.append({"found_at": ev.index, "minimal": best.index})
        finally:
            flyer.close()
    return res


def _where(e: Evaluation) -> tuple[float, float]:
    """Where a trial failed: its touchdown point, else (no touchdown) its start."""
    n, east = e.row.get("touchdown_north_m"), e.row.get("touchdown_east_m")
    if n is None or east is None:
        return float(e.values["north_m"]), float(e.values["east_m"])
    return float(n), float(east)


def _same(a: Evaluation, b: Evaluation) -> bool:
    """The same failure: the same failed checks, at most SAME_PLACE_M apart (touchdown, else start). By outcome,
    not by scenario parameters: two trials that land beside the same person fail the same way, whatever their
    gusts or yaw (a distance over every parameter would call them different)."""
    (an, ae), (bn, be) = _where(a), _where(b)
    return set(a.failed_checks) == set(b.failed_checks) and math.hypot(an - bn, ae - be) <= SAME_PLACE_M


def _is_new(e: Evaluation, found: list[Evaluation]) -> bool:
    return not any(_same(e, o) for o in found)


def pick_distinct(evals: list[Evaluation], k: int) -> list[Evaluation]:
    """Up to k failures in the order found, each a new one (_same: other checks, or another place)."""
    out: list[Evaluation] = []
    for e in evals:
        if len(out) >= k:
            break
        if e.failed and _is_new(e, out):
            out.append(e)
    return out


def _spent(res: SearchResult) -> set[int]:
    """Trials left out of the elite: once a failure has been found _SPENT times, every trial that ended at its
    place (its touchdown, else start, within SAME_PLACE_M: the failures and the near misses around them), so the
    search moves on to other failures instead of flying the same one again (a niche per distinct failure)."""
    niches: list[list[Evaluation]] = []
    for e in res.search_evals:
        if not e.failed:
            continue
        for nb in niches:
            if _same(e, nb[0]):
                nb.append(e)
                break
        else:
            niches.append([e])
    places = [_where(nb[0]) for nb in niches if len(nb) >= _SPENT]
    out = set()
    for e in res.search_evals:
        n, east = _where(e)
        if any(math.hypot(n - pn, east - pe) <= SAME_PLACE_M for pn, pe in places):
            out.add(e.index)
    return out


def _shrink(ev: Evaluation, dims: list[Dim], spec: TrialSpec, seed: int, boxes: dict[str, FootageBox],
            fly: Callable[[list[Point], str, int], list[Evaluation]], steps: int, budget: int) -> Evaluation:  # fmt: skip
    """Move each dim towards nominal while the trial still fails one of ev's checks; the last failing one."""
    want = set(ev.failed_checks)
    best = ev
    spent = 0

    def still_fails(pt: Point) -> Evaluation | None:
        nonlocal spent
        if fixed_spec(spec, pt, dims, seed, boxes) is None or spent >= budget:
            return None
        spent += 1
        e = fly([pt], "shrink", ev.index)[0]
        return e if e.failed and want & set(e.failed_checks) else None

    for d in dims:
        cur, nom = best.point[d.name], (int(d.nominal) if d.kind == "choice" else float(d.nominal))
        if cur == nom:
            continue
        e = still_fails({**best.point, d.name: nom})
        if e is not None:
            best = e
            continue
        if d.kind == "choice":
            continue
        far, near = float(cur), float(nom)  # far fails, near passes: bisect
        for _ in range(steps):
            mid = 0.5 * (far + near)
            e = still_fails({**best.point, d.name: mid})
            if e is None:
                near = mid
            else:
                best, far = e, mid
        if spent >= budget:
            break
    return best


# ------------------------------------------------------------------------------------------ writing


def _toml_str(s: str) -> str:
    return json.dumps(s, ensure_ascii=False)  # a JSON string is a TOML basic string


def _toml_num(x: float | int) -> str:
    if isinstance(x, bool):
        return "true" if x else "false"
    if isinstance(x, int):
        return str(x)
    return repr(float(x))


def _toml_range(r: Range) -> str:
    return f"[{_toml_num(r[0])}, {_toml_num(r[1])}]"


def spec_to_toml(spec: TrialSpec, header: str = "") -> str:
    """A TrialSpec as TOML that spec_from_dict reads back to the same spec (all fields written)."""
    lines = [f"# {ln}" if ln else "#" for ln in header.splitlines()]
    lines += ["[trials]", f"name = {_toml_str(spec.name)}", f"n = {spec.n}", f"seed = {spec.seed}"]
    for key in ("timeout_s", "speed", "end_outside_s", "crash_speed_m_s", "log_hz"):
        lines.append(f"{key} = {_toml_num(getattr(spec, key))}")
    lines += [f"pilot = {_toml_str(spec.pilot)}", f"frames = {_toml_num(spec.frames)}", "", "[scenario]"]
    lines.append(f"footage = [{', '.join(_toml_str(f) for f in spec.footage)}]")
    lines.append(f"start = [{', '.join(_toml_str(s) for s in spec.start)}]")
    for key in ("north_m", "east_m"):
        if getattr(spec, key) is not None:
            lines.append(f"{key} = {_toml_range(getattr(spec, key))}")
    lines.append(f"margin_m = {_toml_num(spec.margin_m)}")
    for key in ("altitude_m", "yaw_deg", "footage_time_s"):
        lines.append(f"{key} = {_toml_range(getattr(spec, key))}")
    lines.append(f"footage_time_slots = {spec.footage_time_slots}")
    for key in ("land_at_s", "wind_speed_m_s", "wind_dir_deg", "gust_std_m_s"):
        lines.append(f"{key} = {_toml_range(getattr(spec, key))}")
    if spec.params:
        lines += ["", "[scenario.params]"] + [f"{k} = {_toml_range(r)}" for k, r in spec.params]
    for f in spec.failures:
        lines += ["", "[[scenario.failures]]", f"kind = {_toml_str(f.kind)}", f"at_s = {_toml_range(f.at_s)}",
                  f"probability = {_toml_num(f.probability)}"]  # fmt: skip
    lines += ["", "[scoring]", f"final_descent_below_m = {_toml_num(spec.final_descent_below_m)}", "",
              "[scoring.criterion]"]  # fmt: skip
    for fld in dataclasses.fields(spec.criterion):
        v = getattr(spec.criterion, fld.name)
        if v is not None:
            lines.append(f"{fld.name} = {_toml_str(v) if isinstance(v, str) else _toml_num(v)}")
    return "\n".join(lines) + "\n"


def write_search(res: SearchResult, out: Path) -> list[Path]:
    """OUT/failure-NN.toml per minimal failure (each checked: drawn back from the file, it is the scenario that
    failed) and OUT/search.json. Returns the spec paths."""
    import tomllib

    from viva_sitl.evaluation.spec import draw_scenario, draw_scenarios, footage_box, spec_from_dict

    out.mkdir(parents=True, exist_ok=True)
    dims = space_of(res.spec)
    boxes = {name: footage_box(name) for name in res.spec.footage}
    paths: list[Path] = []
    minimal = []
    for k, m in enumerate(res.minimal, 1):
        found, ev = res.evaluations[m["found_at"]], res.evaluations[m["minimal"]]
        name = f"{res.spec.name}-fail-{k:02d}"
        fs = fixed_spec(res.spec, ev.point, dims, res.seed, boxes, name=name)
        assert fs is not None
        fs = dataclasses.replace(fs, pilot=res.pilot)
        off = [
            d.name for d in dims if ev.point[d.name] != (int(d.nominal) if d.kind == "choice" else d.nominal)
        ]
        path = out / f"failure-{k:02d}.toml"
        header = (
            f"Minimal failing scenario {k} of `viva-sitl trials search` (pilot {res.pilot}, seed {res.seed}) over\n"
            f"{res.spec.source or res.spec.name}: found at search trial {found.index}, shrunk to trial {ev.index}.\n"
            f"Failed: {ev.row.get('criterion_failures') or ev.row.get('end')}\n"
            f"Off nominal (what the failure needs): {', '.join(off) or 'nothing'}\n"
            f"Rerun: viva-sitl trials run {path} -o <dir>"
        )
        text = spec_to_toml(fs, header)
        back = spec_from_dict(tomllib.loads(text), str(path))
        if back != dataclasses.replace(fs, source=str(path)):
            raise RuntimeError(f"{path}: the written spec does not read back as the scenario flown (a bug)")
        flown = draw_scenario(fs, 0, fs.seed, boxes)
        if draw_scenarios(back)[0] != flown:
            raise RuntimeError(f"{path}: the written spec draws another scenario than the one flown (a bug)")
        path.write_text(text)
        paths.append(path)
        minimal.append({"spec": path.name, "found_at": found.index, "minimal": ev.index, "off_nominal": off,
                        "failed_checks": list(ev.failed_checks), "values": ev.values,
                        "result": ev.record()["result"]})  # fmt: skip
    doc = {
        "schema": SEARCH_SCHEMA,
        "spec": res.spec.source or res.spec.name,
        "pilot": res.pilot,
        "seed": res.seed,
        "method": res.method,
        "budget": res.budget,
        "space": [dataclasses.asdict(d) for d in dims],
        "search_trials": len(res.search_evals),
        "shrink_trials": len(res.evaluations) - len(res.search_evals),
        "failures_found": sum(e.failed for e in res.search_evals),
        "trials_to_first_failure": res.trials_to_failures(1),
        "minimal": minimal,
        "trials": [e.record() for e in res.evaluations],
    }
    (out / "search.json").write_text(json.dumps(doc, indent=1) + "\n")
    return paths


# ------------------------------------------------------------------------------------------ CLI


def add_search_parser(sub: Any) -> None:
    """`viva-sitl trials search` (wired in evaluation/cli.py)."""
    from viva_sitl.cliargs import add_cache_args, nonneg_int, pos_int

    s = sub.add_parser("search", help="search a spec's scenario space for scenarios where a pilot fails")
    s.add_argument("spec", help="trial spec (TOML): its ranges are the space searched")
    s.add_argument(
        "--pilot", help="descend | oracle | package.module:Class (default: the spec's trials.pilot)"
    )
    s.add_argument("--budget", type=int, required=True, help="search trials to fly (shrinking flies more)")
    s.add_argument(
        "--seed",
        type=nonneg_int,
        help="search seed (default: the spec's trials.seed): same seed, same output",
    )
    s.add_argument("-o", "--out", required=True, help="output directory: failure-NN.toml + search.json")
    s.add_argument("--method", choices=METHODS, default="cem", help="cem (default) | uniform (the baseline)")
    s.add_argument("--batch", type=pos_int, default=8, help="trials per CEM generation (default 8)")
    s.add_argument(
        "--max-failures", type=nonneg_int, default=3, help="distinct failures to shrink (default 3)"
    )
    s.add_argument("--shrink-budget", type=nonneg_int, default=40,
                   help="most trials shrinking one failure may fly (default 40)")  # fmt: skip
    s.add_argument(
        "--jobs", type=pos_int, default=1, help="parallel trials (default 1; the result is the same)"
    )
    s.add_argument("--force", action="store_true", help="replace what OUT holds")
    add_cache_args(s)  # --no-cache / --cache-max-gb / --tile-cache-dir, as on `trials run`; its workers' too


def search_main(args: Any) -> int:
    from viva_sitl.footage import autocache

    # `--no-cache / --cache-max-gb / --tile-cache-dir` change this process's automatic-cache policy for this search
    # only (its footage boxes, its trials, the failure specs written); its pool's workers are handed it
    with autocache.using_policy(
        autocache.from_flags(
            args.no_cache, args.cache_max_gb, args.tile_cache_dir, compact=args.cache_compact
        )
    ):
        return _search_main(args)


def _search_main(args: Any) -> int:
    import sys

    from viva_sitl.evaluation.spec import load_spec

    spec = load_spec(args.spec)
    pilot = args.pilot or spec.pilot
    out = Path(args.out)
    seed = spec.seed if args.seed is None else args.seed
    if (out / "search.json").exists() and not args.force:
        raise ValueError(f"{out} holds a search already (search.json): give this one its own -o, or --force")
    try:
        res = search(
            spec, pilot, args.budget, seed=seed, method=args.method, batch=args.batch,
            max_failures=args.max_failures, shrink_budget=args.shrink_budget, jobs=args.jobs,
            progress=lambda line: print(line, file=sys.stderr, flush=True),
        )  # fmt: skip
    except KeyboardInterrupt:
        print(
            f"\ninterrupted: nothing written to {out} (the same command flies the same trials again)",
            file=sys.stderr,
        )
        return 130
    if args.force:
        for old in out.glob("failure-*.toml"):
            old.unlink()
    paths = write_search(res, out)
    n_search = len(res.search_evals)
    found = sum(e.failed for e in res.search_evals)
    first = res.trials_to_failures(1)
    print(f"{spec.name} [{pilot}]: {found} failure(s) in {n_search} search trials"
          f"{f' (the first after {first} trials)' if first else ''}, {len(res.evaluations) - n_search} shrinking trials")  # fmt: skip
    for p, m in zip(paths, res.minimal, strict=True):
        ev = res.evaluations[m["minimal"]]
        print(f"  {p}: {ev.row.get('criterion_failures') or ev.row.get('end')}")
        print(f"    rerun: viva-sitl trials run {p} -o <dir>")
    if not paths:
        print("  no failure found: nothing written but search.json (a larger --budget searches longer)")
    print(f"  every trial: {out / 'search.json'}")
    return 0
