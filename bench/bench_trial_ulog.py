"""What the per-trial ULog costs an in-process trial: wall time of one trial with and without its log.ulg.

    python bench/bench_trial_ulog.py                  # 4 alternating rounds, a `descend` landing from 20 m

The same scenario (synthetic field, air start at 20 m, told to land at 0.5 s) flown by run_inprocess_trial, once as
it is (FlightLog.step after every physics step, the writer thread packing and writing) and once with the ULog
switched off (the runner's _open_flight_log replaced by one that opens nothing). Trials run as fast as the CPU
allows, so any per-step cost shows in their wall time.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
from pathlib import Path

import viva_sitl.evaluation.runner as runner
from viva_sitl.evaluation.spec import draw_scenarios, spec_from_dict

SPEC = {
    "trials": {"name": "ulog-cost", "n": 1, "seed": 3, "timeout_s": 60.0},
    "scenario": {"footage": "synthetic", "start": "air", "north_m": 0.0, "east_m": 0.0, "altitude_m": 20.0,
                 "land_at_s": 0.5},
}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=4)
    args = ap.parse_args()
    if args.rounds < 1:
        ap.error("--rounds must be >= 1")
    spec = spec_from_dict(SPEC, "ulog-cost")
    sc = draw_scenarios(spec)[0]
    with_log = runner._open_flight_log
    walls: dict[str, list[float]] = {"without ULog": [], "with ULog": []}
    with tempfile.TemporaryDirectory() as tmp:
        runner.run_inprocess_trial(spec, sc, "descend", Path(tmp) / "warm-up")
        for r in range(args.rounds):
            for name in walls:
                runner._open_flight_log = with_log if name == "with ULog" else (lambda d, v: None)  # type: ignore[assignment]
                row = runner.run_inprocess_trial(spec, sc, "descend", Path(tmp) / f"{r}-{name}")
                walls[name].append(float(row["wall_s"]))
        runner._open_flight_log = with_log
        ulg = Path(tmp) / f"{args.rounds - 1}-with ULog" / "log.ulg"
        size = ulg.stat().st_size
    for name, w in walls.items():
        print(
            f"{name:<13} wall {statistics.median(w) * 1e3:7.1f} ms median  ({', '.join(f'{x * 1e3:.0f}' for x in w)})"
        )
    base, logged = (statistics.median(w) for w in walls.values())
    print(f"ULog overhead {100 * (logged / base - 1):+.0f} % of the trial's wall time; log.ulg {size / 1e3:.0f} kB; "
          f"end {row['end']}")  # fmt: skip


if __name__ == "__main__":
    main()
