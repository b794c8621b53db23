"""Cost of the trajectory log (recording.py) on the physics loop: SitlApp._step_once with and without sampling.

    python bench/bench_trajectory.py [--steps 20000] [--rounds 5]

In-process, no video, nothing started (MAVLink telemetry builds still run in on_sim_step as in a run). Phases are
interleaved (off, on) per round; the figure is the median wall time and physics-thread CPU time per physics step. The writer thread's flushes
(every 250 steps here, ~1 wall second in a run) are included in "on".
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from viva_sitl.app import SitlApp
from viva_sitl.config import SimConfig


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--rounds", type=int, default=5)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        app = SitlApp(SimConfig(), video=False, run_dir=Path(tmp))
        off: list[float] = []
        on: list[float] = []
        off_cpu: list[float] = []
        on_cpu: list[float] = []
        rec = app.trajectory
        for _ in range(args.rounds):
            for phase, out, cpu in (("off", off, off_cpu), ("on", on, on_cpu)):
                rec._next_s = float("inf") if phase == "off" else app.sim.state.time_s  # noqa: SLF001
                t0, c0 = time.perf_counter(), time.thread_time()
                for k in range(args.steps):
                    app._step_once()  # noqa: SLF001
                    if phase == "on" and k % 250 == 0:
                        rec.flush()
                out.append((time.perf_counter() - t0) / args.steps * 1e6)
                cpu.append((time.thread_time() - c0) / args.steps * 1e6)
        rec.close()
        rows = rec.rows_written
        app.sim.close()
    m_off, m_on = statistics.median(off), statistics.median(on)
    print(f"steps/phase {args.steps}, rounds {args.rounds}, rows written {rows}")
    print(f"off: median {m_off:.2f} us/step  ({', '.join(f'{v:.2f}' for v in off)})")
    print(f"on:  median {m_on:.2f} us/step  ({', '.join(f'{v:.2f}' for v in on)})")
    print(f"ratio on/off {m_on / m_off:.3f}  (+{m_on - m_off:.2f} us/step)")
    c_off, c_on = statistics.median(off_cpu), statistics.median(on_cpu)
    print(
        f"physics-thread CPU: off {c_off:.2f}, on {c_on:.2f} us/step, ratio {c_on / c_off:.3f} (+{c_on - c_off:.2f})"
    )


if __name__ == "__main__":
    main()
