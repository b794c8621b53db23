"""End-to-end wall time of a mission script against `viva-sitl run` at several speed factors.

    python bench/bench_e2e.py                    # speeds 1 2 4, 2 runs each, mavsdk_takeoff_land.py --altitude 5
    python bench/bench_e2e.py --speeds 1 3 --repeat 3 --script pymavlink_gcs_mission.py

For each speed: start viva-sitl (synthetic field, no video) on free ports, run the script, record its wall time,
its RESULT line and the physics steps viva-sitl had to skip (the pacer's count in its exit line); print medians and
the ratio to the first speed. Behaviour must stay the same (same RESULT within tolerance) while wall time shrinks.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
from sitl_process import SitlProcess, run_script  # noqa: E402


def main() -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--speeds", type=float, nargs="+", default=[1.0, 2.0, 4.0])
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--script", default="mavsdk_takeoff_land.py")
    parser.add_argument("--script-args", default="--altitude 5", help="extra arguments for the script")
    args = parser.parse_args()
    print(f"machine: nproc {os.cpu_count()}, load average {os.getloadavg()[0]:.1f}; script {args.script}")
    base: float | None = None
    with tempfile.TemporaryDirectory() as tmp:
        for speed in args.speeds:
            walls: list[float] = []
            skipped: list[int] = []
            results: list[dict[str, str]] = []
            for i in range(args.repeat):
                sitl = SitlProcess(workdir=Path(tmp) / f"s{speed}-{i}", speed=speed)
                with sitl:
                    url = (
                        sitl.ports.pymavlink_url
                        if args.script.startswith("pymavlink")
                        else sitl.ports.mavsdk_url
                    )
                    t0 = time.monotonic()
                    run = run_script(args.script, [url, *args.script_args.split()], timeout_s=600)
                    walls.append(time.monotonic() - t0)
                if run.returncode != 0:
                    print(f"speed {speed}: run {i} failed\n{run.describe()}\n{sitl.logs()}")
                    return 1
                skipped.append(int(sitl.stop_stats().get("skipped_physics_steps", -1)))
                results.append(run.result)
            median = statistics.median(walls)
            base = base or median
            print(
                f"speed {speed:>4}x: median wall {median:6.2f} s (runs {', '.join(f'{w:.2f}' for w in walls)}), "
                f"ratio to {args.speeds[0]}x {median / base:.2f}, skipped physics steps {skipped}, "
                f"RESULT {results[0]}"
            )
    return 0


if __name__ == "__main__":
    sys.exit(main())
