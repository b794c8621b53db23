"""What the run's ULog costs the physics loop: Vehicle.step alone vs Vehicle.step + FlightLog.step, per step.

    python bench/bench_ulog.py                       # 5 rounds of 60 simulated seconds (takeoff, then a hover)
    python bench/bench_ulog.py --rounds 9 --seconds 120

Per round, in the loop thread's CPU time (time.thread_time: the writer thread and other processes do not count) and
in wall time: `step` = Vehicle.step(1) alone, `logged` = Vehicle.step(1) + FlightLog.step (rate-limited tuples put
on the writer's bounded queue; the packing and the file I/O run on the writer thread). Also: the writer's samples,
bytes and drops, and the wall time close() needs to drain the queue. Rounds alternate the two variants.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from viva_sitl.config import SimConfig
from viva_sitl.flightlog import FlightLog
from viva_sitl.vehicle import Vehicle


def run(seconds: float, log_dir: Path | None) -> dict[str, float]:
    with Vehicle(SimConfig(), geofence=False) as v:
        flog = FlightLog(log_dir / "log.ulg", v.geo, v.params, start_time_s=v.time_s) if log_dir else None
        assert v.autopilot.arm(v.time_s).ok and v.autopilot.takeoff(v.time_s, 10.0).ok
        n = int(round(seconds / v.dt_s))
        c0, w0 = time.thread_time(), time.perf_counter()
        if flog is None:
            for _ in range(n):
                v.step(1)
        else:
            for _ in range(n):
                s = v.step(1)
                flog.step(s, v.autopilot)
        cpu, wall = time.thread_time() - c0, time.perf_counter() - w0
        out = {"cpu_us": 1e6 * cpu / n, "wall_us": 1e6 * wall / n}
        if flog is not None:
            t = time.perf_counter()
            flog.close()
            out.update(close_ms=1e3 * (time.perf_counter() - t), samples=float(flog.writer.samples),
                       bytes=float(flog.writer.bytes_written), dropped=float(flog.writer.dropped))  # fmt: skip
        return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated seconds per round")
    args = ap.parse_args()
    if args.rounds < 1 or not args.seconds > 0:
        ap.error("--rounds must be >= 1 and --seconds > 0")
    base: list[dict[str, float]] = []
    logged: list[dict[str, float]] = []
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(args.rounds):
            base.append(run(args.seconds, None))
            d = Path(tmp) / f"r{r}"
            d.mkdir()
            logged.append(run(args.seconds, d))

    def med(rows: list[dict[str, float]], key: str) -> float:
        return statistics.median(row[key] for row in rows)

    print(f"{args.rounds} rounds x {args.seconds:g} sim s (250 Hz steps), medians:")
    print(
        f"  Vehicle.step alone          cpu {med(base, 'cpu_us'):6.1f} us/step   wall {med(base, 'wall_us'):6.1f} us/step"
    )
    print(
        f"  + FlightLog.step            cpu {med(logged, 'cpu_us'):6.1f} us/step   wall {med(logged, 'wall_us'):6.1f} us/step"
    )
    print(f"  logging overhead            cpu {med(logged, 'cpu_us') - med(base, 'cpu_us'):+6.1f} us/step   "
          f"wall {med(logged, 'wall_us') - med(base, 'wall_us'):+6.1f} us/step")  # fmt: skip
    print(f"  writer: {med(logged, 'samples'):.0f} samples, {med(logged, 'bytes') / 1e6:.2f} MB per round, "
          f"dropped {max(row['dropped'] for row in logged):.0f}, close() {med(logged, 'close_ms'):.1f} ms")  # fmt: skip


if __name__ == "__main__":
    main()
