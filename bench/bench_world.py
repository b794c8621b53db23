"""Render cost of the edgeless synthetic field wherever the vehicle flies (issue 7: bounded cost 2 km away, 300 m up).

    python bench/bench_world.py [--frames 60] [--rounds 5]

For each pose, a `Simulator` over the default (unbounded) synthetic field renders `--frames` consecutive VAC frames
(640x480, footage frame advancing at 30 fps as in `run`); reported: median ms per frame in steady state (the window
already drawn), the one-off cost of drawing a new window (first frame at a new place, texture norm cached), and the
window size. Reference measured in the same run: the old path, a fixed 2048x2048 field rendered with
`Renderer.render(LazyPyramid(field.frame(i)))` at the centre (what every frame cost before), and a finite
(`unbounded=False`) field through the same Simulator.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

from viva_sitl.camera import LazyPyramid, Renderer
from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavState
from viva_sitl.footage import SyntheticField, SyntheticFieldParams
from viva_sitl.sim import Simulator

POSES = {
    "centre, 50 m": (0.0, 0.0, -50.0),
    "2 km away, 50 m": (2000.0, -1500.0, -50.0),
    "centre, 300 m": (0.0, 0.0, -300.0),
    "10 km away, 300 m": (7000.0, 7000.0, -300.0),
    "centre, 10 m": (0.0, 0.0, -10.0),
}


def steady_ms(sim: Simulator, pos: tuple[float, float, float], frames: int) -> tuple[float, float]:
    """(first-frame ms at this place, median ms of the following frames)."""
    state = EavState.at_rest(pos, dt_s=sim.params.dt_s)
    t0 = time.perf_counter()
    sim.render(state)
    first = (time.perf_counter() - t0) * 1e3
    times = []
    for k in range(1, frames + 1):
        s = EavState.at_rest(pos, dt_s=sim.params.dt_s)
        s = type(s)(**{**s.__dict__, "time_s": k / 30.0})
        t0 = time.perf_counter()
        sim.render(s)
        times.append((time.perf_counter() - t0) * 1e3)
    return first, statistics.median(times)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}; {args.rounds} rounds x {args.frames} frames, 640x480 VAC")
    results: dict[str, list[tuple[float, float]]] = {name: [] for name in POSES}
    ref: list[float] = []
    finite: list[float] = []
    windows: dict[str, str] = {}
    for _ in range(args.rounds):
        with Simulator(SimConfig()) as sim:
            sim.render()  # texture norm, first window
            for name, pos in POSES.items():
                results[name].append(steady_ms(sim, pos, args.frames))
                g = sim.renderer.geometry
                windows[name] = f"{g.width_px}x{g.height_px} px at {g.gsd_m_per_px:g} m/px"
        # reference: the old fixed-field path (whole 2048x2048 frame, a pyramid per footage frame)
        field = SyntheticField(SyntheticFieldParams(unbounded=False))
        renderer = Renderer(SimConfig().camera, field.geometry)
        times = []
        for k in range(args.frames):
            t0 = time.perf_counter()
            renderer.render(LazyPyramid(field.frame(k)), (0.0, 0.0, -50.0), (0.0, 0.0, 0.0))
            times.append((time.perf_counter() - t0) * 1e3)
        ref.append(statistics.median(times[1:]))
        with Simulator(SimConfig(), footage=SyntheticField(SyntheticFieldParams(unbounded=False))) as sim:
            finite.append(steady_ms(sim, (0.0, 0.0, -50.0), args.frames)[1])
    # a flight: north at 10 m/s, 50 m up, one frame per 1/30 s (the windows come from the background thread)
    flight: list[float] = []
    with Simulator(SimConfig()) as sim:
        for k in range(args.frames * args.rounds * 3):
            s = EavState.at_rest((10.0 * k / 30.0, 0.0, -50.0), dt_s=sim.params.dt_s)
            s = type(s)(**{**s.__dict__, "time_s": k / 30.0})
            t0 = time.perf_counter()
            sim.render(s)
            flight.append((time.perf_counter() - t0) * 1e3)
        field = sim.footage
        assert isinstance(field, SyntheticField)
        drawn, ahead = field.windows_drawn, field.windows_ahead
    flight.sort()
    print(
        f"flight north 10 m/s at 50 m, {len(flight)} frames: median {statistics.median(flight):.2f} ms, "
        f"p99 {flight[int(0.99 * (len(flight) - 1))]:.2f} ms, max {flight[-1]:.2f} ms; "
        f"{drawn} windows, {ahead} drawn ahead"
    )
    ref_ms = statistics.median(ref)
    print(
        f"reference: fixed 2048x2048 field, Renderer only, centre 50 m: {ref_ms:.2f} ms/frame (rounds {ref})"
    )
    print(f"finite field through Simulator, centre 50 m: {statistics.median(finite):.2f} ms/frame")
    print(
        "| pose | steady ms/frame (median of rounds) | ratio to reference | new-window first frame ms | window |"
    )
    print("|---|---|---|---|---|")
    for name, vals in results.items():
        steady = statistics.median(v[1] for v in vals)
        first = statistics.median(v[0] for v in vals)
        print(f"| {name} | {steady:.2f} | {steady / ref_ms:.2f} | {first:.1f} | {windows[name]} |")


if __name__ == "__main__":
    main()
