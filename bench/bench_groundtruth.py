"""World-model queries at the physics rate: the vectorised per-frame store vs a brute-force per-track loop.

    PYTHONPATH=. python bench/bench_groundtruth.py [--queries 20000]

Worlds: the synthetic field (23 exact actors), SDD deathCircle (real tracks, ~30 objects a frame; skipped when
../shared is absent) and a stress table (2000 random tracks, ~500 objects a frame). Reference, measured in the same
run: a brute-force query that loops over every track (dict frame -> position) in Python. Every query's answer is
checked equal between the two. Prints median microseconds per query and the ratio; results in
bench/results_groundtruth.md.
"""

from __future__ import annotations

import argparse
import math
import platform
import statistics
import time
from collections.abc import Callable

import numpy as np

from viva_sitl.footage import FootageError, FootageGeometry
from viva_sitl.footage.boxfiles import BoxRow
from viva_sitl.world import PEOPLE, TrackSource, TrackTable, WorldModel, build_tracks, load_world
from viva_sitl.world.risk import RiskMap


class Brute:
    """The reference: one dict per track, a Python loop over all tracks per query."""

    def __init__(self, tt: TrackTable) -> None:
        self.fps, self.fc = tt.fps, tt.frame_count
        self.tracks = []
        for info in tt.tracks:
            frames, ne = tt.track_path(info.index)
            self.tracks.append((info.object_class, {int(f): (float(p[0]), float(p[1])) for f, p in zip(frames, ne, strict=True)}))  # fmt: skip

    def nearest(self, n: float, e: float, t: float, classes: frozenset) -> float:
        f = int(math.floor(t * self.fps + 1e-9)) % self.fc if self.fc > 1 else 0
        best = math.inf
        for cls, pos in self.tracks:
            if cls in classes and f in pos:
                p = pos[f]
                best = min(best, math.hypot(p[0] - n, p[1] - e))
        return best

    def within(self, n: float, e: float, r: float, t: float) -> int:
        f = int(math.floor(t * self.fps + 1e-9)) % self.fc if self.fc > 1 else 0
        return sum(1 for _, pos in self.tracks if f in pos and math.hypot(pos[f][0] - n, pos[f][1] - e) <= r)


def timed(fn: Callable[[int], object], n: int, reps: int = 5) -> tuple[float, list[object]]:
    """Median over reps of the mean time per call (s), and the answers of the last rep."""
    per: list[float] = []
    out: list[object] = []
    for _ in range(reps):
        out = []
        t0 = time.perf_counter()
        for k in range(n):
            out.append(fn(k))
        per.append((time.perf_counter() - t0) / n)
    return statistics.median(per), out


def stress_world() -> WorldModel:
    rng = np.random.default_rng(0)
    g = FootageGeometry(4000, 3000, 0.05, 100.0)
    rows = []
    for tid in range(2000):
        f0 = int(rng.integers(0, 1400))
        x, y = rng.uniform(0, 4000), rng.uniform(0, 3000)
        vx, vy = rng.normal(0, 3, 2)
        label = ("Pedestrian", "Biker", "Car")[tid % 3]
        for f in range(f0, min(1800, f0 + 400), 3):
            rows.append(BoxRow(f, tid, label, x + vx * (f - f0), y + vy * (f - f0), x + vx * (f - f0) + 20, y + vy * (f - f0) + 20))  # fmt: skip
    tt = build_tracks([TrackSource("stress", rows)], g, 30.0, 1800)
    return WorldModel("stress (2000 tracks)", g, tt, RiskMap.uniform(3))


def bench_one(w: WorldModel, n_queries: int) -> None:
    tt = w.tracks
    brute = Brute(tt)
    rng = np.random.default_rng(1)
    n = n_queries
    half = 0.4 * max(w.geometry.ground_width_m, w.geometry.ground_height_m) / 2
    qn, qe = rng.uniform(-half, half, n).tolist(), rng.uniform(-half, half, n).tolist()
    qt = (
        np.arange(n) / 250.0
    ).tolist()  # the physics rate: one query per 4 ms step (Python floats, as a sim)
    per_frame = statistics.median(len(tt.objects_at(t)) for t in qt[:: max(1, n // 200)])
    cases: list[tuple[str, Callable[[int], object], Callable[[int], object]]] = [
        ("nearest person", lambda k: tt.distance_m(qn[k], qe[k], qt[k], PEOPLE),
         lambda k: brute.nearest(qn[k], qe[k], qt[k], PEOPLE)),
        ("within 10 m", lambda k: len(tt.within(qn[k], qe[k], 10.0, qt[k])),
         lambda k: brute.within(qn[k], qe[k], 10.0, qt[k])),
    ]  # fmt: skip
    for name, fast, slow in cases:
        tf, af = timed(fast, n)
        ts, as_ = timed(slow, n if len(tt.tracks) < 500 else n // 10)
        m = len(as_)
        assert all(
            (a == b) or (isinstance(a, float) and isinstance(b, float) and abs(a - b) < 1e-9)
            for a, b in zip(af[:m], as_, strict=True)
        ), f"{w.name} {name}: vectorised and brute force disagree"
        print(
            f"| {w.name} | {per_frame:g} | {name} | {tf * 1e6:.1f} | {ts * 1e6:.1f} | {ts / tf:.1f}x | {1 / tf:,.0f} |"
        )
    tr, _ = timed(lambda k: w.risk_at(qn[k], qe[k], qt[k]), n)
    print(f"| {w.name} | {per_frame:g} | risk_at | {tr * 1e6:.1f} | - | - | {1 / tr:,.0f} |")
    tb0 = time.perf_counter()
    tt.distances_along(np.array(qn), np.array(qe), np.array(qt), PEOPLE)
    tb = (time.perf_counter() - tb0) / n
    print(
        f"| {w.name} | {per_frame:g} | distances_along (batch of {n}) | {tb * 1e6:.2f} per sample | - | - | {1 / tb:,.0f} |"
    )


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--queries", type=int, default=20000)
    args = ap.parse_args()
    print(
        f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}, numpy {np.__version__}"
    )
    worlds: list[WorldModel] = [load_world("synthetic")]
    try:
        worlds.append(load_world("sdd-deathcircle-4"))
    except FootageError as exc:
        print(f"sdd-deathcircle-4 skipped: {exc}")
    worlds.append(stress_world())
    print(
        "| world | objects/frame | query | vectorised µs | brute-force µs | ratio | queries/s (vectorised) |"
    )
    print("|---|---|---|---|---|---|---|")
    for w in worlds:
        bench_one(w, args.queries)


if __name__ == "__main__":
    main()
