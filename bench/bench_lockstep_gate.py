"""What the lockstep gate (viva_sitl.timing.PilotGate) costs per quantum, and external lockstep trials per hour, for
two checkouts of viva-sitl in the same run, alternated (issue 19: gate cost, the >= 5x speed target).

    nice -n 5 .venv/bin/python bench/bench_lockstep_gate.py --trees base=/work/wt/h19base new=. --rounds 3
    nice -n 5 .venv/bin/python bench/bench_lockstep_gate.py --trees base=/work/wt/h19base new=. --skip-micro \\
        --trial-pilot mavsdk --n 4 --jobs 2 --speed 16 --rounds 3 --rows

Each side runs in its own subprocess with PYTHONPATH set to its tree (`--trees NAME=PATH ...`); the sides alternate
round by round (A B, B A, A B, ...) and the medians are reported, with the machine's load average before each run.

- **micro** (per side, per round): a real pilot process (a Python program with a UDP socket and 4 idle threads, as a
  MAVSDK script has timer threads) and `--quanta` gate waits. Per quantum the bench sends the pilot one datagram
  and waits at the gate; the pilot either answers it at once (`echo`: ~50 us of CPU, as a pilot that reads its
  telemetry and sends nothing much) or does not read (`idle`: nothing to do; the gate's floor). Figures: median and
  p90 wall microseconds per gate wait, the gate's own CPU per quantum (this process's thread CPU), and (echo) the
  quanta after which the pilot's answer had not been read when the gate returned (must be 0).
- **trial** (unless --skip-trial): a lockstep campaign of `--n` external trials (`--trial-pilot mavsdk`:
  mission_scripts/mavsdk_precision_land.py, unchanged, ground start, as bench/bench_trials_external.py; `pymavlink`:
  tests/pilots/pymavlink_busy.py, air start with "land now") at `--speed`, `--jobs`; campaign wall seconds, trials
  per hour, and from each trial's end.json: quanta, gate wall per quantum (busy_wall_s / quanta), the pilot's CPU.
  `--rows` also checks that every side's results.csv rows equal the first side's on every column but the measured
  ones (wall_s, pilot_cpu_s, pilot_run_delay_s), via viva_sitl.evaluation.campaign.rows_equal.
Prints a JSON report.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]

PILOT_SRC = r"""
import socket, sys, threading, time
mode = sys.argv[1]
def idle():
    while True:
        time.sleep(3600)
for _ in range(4):
    threading.Thread(target=idle, daemon=True).start()
s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
s.bind(("127.0.0.1", 0))
print(s.getsockname()[1], flush=True)
if mode == "idle":
    time.sleep(3600)
while True:
    data, addr = s.recvfrom(2048)
    s.sendto(data, addr)
"""

MAVSDK_PILOT = (
    "{python} mission_scripts/mavsdk_precision_land.py {mavsdk_url} --north 8 --east 5 --altitude 10"
)
PYMAVLINK_PILOT = "{python} tests/pilots/pymavlink_busy.py {pymavlink_url} 5,15"


def one_micro(mode: str, quanta: int) -> dict[str, Any]:
    """In the side's own process: gate waits against a real pilot process."""
    import asyncio
    import socket

    from viva_sitl.pilotwatch import PilotTree
    from viva_sitl.timing import PilotGate, Timing, TimingStats

    proc = subprocess.Popen([sys.executable, "-c", PILOT_SRC, mode], stdout=subprocess.PIPE, text=True,
                            start_new_session=True)  # fmt: skip
    try:
        assert proc.stdout is not None
        port = int(proc.stdout.readline())
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        sock.setblocking(False)
        got = [0]
        late = [0]

        async def main() -> list[float]:
            loop = asyncio.get_running_loop()
            loop.add_reader(sock.fileno(), lambda: (sock.recv(2048), got.__setitem__(0, got[0] + 1)))
            tree = PilotTree(proc.pid)
            stats = TimingStats(Timing.LOCKSTEP, 16.0, None, pilot_pid=proc.pid)
            gate = PilotGate(tree, stats)
            walls = []
            for k in range(quanta):
                sock.sendto(b"x" * 60, ("127.0.0.1", port))
                t0 = time.perf_counter()
                await gate.wait_idle()
                walls.append(time.perf_counter() - t0)
                if mode == "echo" and got[0] != k + 1:  # the answer was not read when the gate let time go on
                    late[0] += 1
                    got[0] = k + 1
            loop.remove_reader(sock.fileno())
            tree.close()
            return walls

        c0 = time.thread_time()
        walls = asyncio.run(main())
        cpu = time.thread_time() - c0
    finally:
        proc.kill()
        proc.wait()
    us = sorted(w * 1e6 for w in walls[10:])  # the first few include the first /proc scan
    return {
        "mode": mode, "quanta": quanta, "median_us": round(statistics.median(us), 1),
        "p90_us": round(us[int(0.9 * (len(us) - 1))], 1), "mean_us": round(statistics.fmean(us), 1),
        "gate_cpu_us_per_quantum": round(cpu / quanta * 1e6, 1),
        "answers_unread_at_gate_end": late[0] if mode == "echo" else None,
    }  # fmt: skip


def one_trial(pilot: str, n: int, jobs: int, speed: float, out: str) -> dict[str, Any]:
    from viva_sitl.evaluation.campaign import run_campaign
    from viva_sitl.evaluation.spec import spec_from_dict

    if pilot == "mavsdk":
        cmd = MAVSDK_PILOT
        scenario: dict[str, Any] = {"footage": "synthetic", "start": "ground", "north_m": [-30.0, 30.0],
                                    "east_m": [-30.0, 30.0], "altitude_m": 10.0, "yaw_deg": [0.0, 360.0],
                                    "land_at_s": 149.0}  # fmt: skip
        seed = 3
    else:
        cmd = PYMAVLINK_PILOT
        scenario = {"footage": "synthetic", "start": "air", "north_m": [-20.0, 20.0], "east_m": [-20.0, 20.0],
                    "altitude_m": [8.0, 10.0], "land_at_s": [1.0, 2.0]}  # fmt: skip
        seed = 7
    spec = spec_from_dict(
        {"trials": {"name": "gate-bench", "n": n, "seed": seed, "timeout_s": 150.0, "speed": speed,
                    "timing": "lockstep"}, "scenario": scenario},
        "gate-bench",
    )  # fmt: skip
    t0 = time.perf_counter()
    camp = run_campaign(spec, cmd, Path(out), jobs=jobs, progress=False)
    wall = time.perf_counter() - t0
    rows = camp.ordered_rows()
    per = []
    for r in rows:
        try:
            end = json.loads((Path(out) / "trials" / f"{r['trial']:04d}" / "end.json").read_text())
        except (OSError, ValueError):
            end = {}
        tm = end.get("timing") or {}
        q = tm.get("quanta") or 0
        per.append({
            "trial": r["trial"], "end": r["end"], "end_detail": str(r.get("end_detail", ""))[:200], "wall_s": r["wall_s"],
            "quanta": q,
            "gate_ms_per_quantum": round(1000 * tm.get("busy_wall_s", 0.0) / q, 3) if q else None,
            "gate_wall_s": tm.get("busy_wall_s"), "waited": tm.get("waited"), "pilot_cpu_s": tm.get("pilot_cpu_s"),
            "pilot_wait_wall_s": end.get("pilot_wait_wall_s"),
        })  # fmt: skip
    return {"wall_s": round(wall, 2), "trials_per_hour": round(3600.0 * n / wall, 1), "trials": per,
            "rows": rows}  # fmt: skip


def loadavg() -> float:
    return os.getloadavg()[0]


def run_side(tree: str, args: list[str]) -> dict[str, Any]:
    env = {**os.environ, "PYTHONPATH": str(Path(tree).resolve())}
    p = subprocess.run([sys.executable, __file__, "--one", *args], env=env, capture_output=True, text=True,
                       cwd=str(Path(tree).resolve()))  # fmt: skip
    if p.returncode != 0:
        raise SystemExit(f"side {tree} failed ({p.returncode}): {p.stderr[-2000:]}")
    return dict(json.loads(p.stdout.strip().splitlines()[-1]))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--trees", nargs="+", default=[f"this={REPO}"], help="NAME=PATH of each checkout")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--quanta", type=int, default=2000)
    ap.add_argument("--skip-micro", action="store_true")
    ap.add_argument("--skip-trial", action="store_true")
    ap.add_argument("--trial-pilot", choices=["mavsdk", "pymavlink"], default="mavsdk")
    ap.add_argument("--n", type=int, default=2)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--speed", type=float, default=16.0)
    ap.add_argument("--rows", action="store_true", help="compare every side's rows with the first side's")
    ap.add_argument("--one", nargs="+", help=argparse.SUPPRESS)
    a = ap.parse_args()
    if a.one:  # inside one side's subprocess
        kind = a.one[0]
        if kind == "micro":
            res = one_micro(a.one[1], int(a.one[2]))
        else:
            res = one_trial(a.one[1], int(a.one[2]), int(a.one[3]), float(a.one[4]), a.one[5])
        print(json.dumps(res))
        return 0
    trees = dict(t.split("=", 1) for t in a.trees)
    names = list(trees)
    report: dict[str, Any] = {"machine": platform.node(), "cpus": os.cpu_count(), "trees": trees,
                              "started": time.strftime("%H:%M:%S"), "rounds": []}  # fmt: skip
    with tempfile.TemporaryDirectory(prefix="viva-gatebench-") as d:
        for rnd in range(a.rounds):
            order = names if rnd % 2 == 0 else names[::-1]
            entry: dict[str, Any] = {}
            for name in order:
                side: dict[str, Any] = {"load_before": round(loadavg(), 2)}
                if not a.skip_micro:
                    for mode in ("idle", "echo"):
                        side[f"micro_{mode}"] = run_side(trees[name], ["micro", mode, str(a.quanta)])
                if not a.skip_trial:
                    out = str(Path(d) / f"{name}-{rnd}")
                    side["trial"] = run_side(
                        trees[name], ["trial", a.trial_pilot, str(a.n), str(a.jobs), str(a.speed), out]
                    )
                entry[name] = side
                print(f"round {rnd} {name}: {json.dumps({k: v for k, v in side.items() if k != 'trial'})}"
                      + (f" trial wall {side['trial']['wall_s']} s, {side['trial']['trials_per_hour']}/h, gate ms/q "
                         f"{[t['gate_ms_per_quantum'] for t in side['trial']['trials']]}" if "trial" in side else ""),
                      file=sys.stderr, flush=True)  # fmt: skip
            report["rounds"].append(entry)
    summary: dict[str, Any] = {}
    for name in names:
        sides = [r[name] for r in report["rounds"]]
        s: dict[str, Any] = {"load": [x["load_before"] for x in sides]}
        for mode in ("idle", "echo"):
            key = f"micro_{mode}"
            if key in sides[0]:
                s[f"{key}_median_us"] = statistics.median(x[key]["median_us"] for x in sides)
                s[f"{key}_p90_us"] = statistics.median(x[key]["p90_us"] for x in sides)
                s[f"{key}_gate_cpu_us"] = statistics.median(x[key]["gate_cpu_us_per_quantum"] for x in sides)
        if "trial" in sides[0]:
            s["trial_wall_s"] = [x["trial"]["wall_s"] for x in sides]
            s["trials_per_hour_median"] = statistics.median(x["trial"]["trials_per_hour"] for x in sides)
            s["gate_ms_per_quantum_median"] = statistics.median(
                t["gate_ms_per_quantum"]
                for x in sides
                for t in x["trial"]["trials"]
                if t["gate_ms_per_quantum"]
            )
            s["trial_wall_s_median"] = statistics.median(
                t["wall_s"] for x in sides for t in x["trial"]["trials"]
            )
            s["ends"] = sorted({t["end"] for x in sides for t in x["trial"]["trials"]})
        summary[name] = s
    if a.rows and not a.skip_trial:
        sys.path.insert(0, str(REPO))
        from viva_sitl.evaluation.campaign import rows_equal

        ref = report["rounds"][0][names[0]]["trial"]["rows"]
        summary["rows_identical_to_" + names[0]] = {
            f"{name} round {k}": rows_equal(ref, r[name]["trial"]["rows"])
            for k, r in enumerate(report["rounds"])
            for name in names
        }
    for r in report["rounds"]:
        for side in r.values():
            if "trial" in side:
                side["trial"].pop("rows")
    report["summary"] = summary
    report["finished"] = time.strftime("%H:%M:%S")
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
