"""External MAVSDK pilot trials per hour vs the speed factor, and the highest speed that keeps the script's behaviour.

    nice -n 10 /work/venv/bin/python bench/bench_trials_external.py                  # 3 scenarios, speeds 1 2 4 8 16
    nice -n 10 /work/venv/bin/python bench/bench_trials_external.py --n 4 --speeds 1 4 8 --jobs 2

The pilot is `mission_scripts/mavsdk_precision_land.py`, unchanged, as `viva-sitl trials run --pilot "CMD"` would
run it (same placeholders, through run_campaign): take off to 10 m (AUTO.TAKEOFF), OFFBOARD position setpoints
streamed at 20 Hz *wall* time to a spot 8 m north / 5 m east of home, descend there to 3 m, Hold, AUTO.LAND, wait
for the disarm. The offboard stream is what makes it speed-sensitive: 20 Hz of wall time is 20/S Hz of sim time.

The same N scenarios (ground start over the synthetic field, drawn from one seed) are flown at every speed S; each
trial is compared with the same scenario at speed 1:
    landed            the same end ("landed") and the script exited 0 (its own checks passed)
    touchdown point   within --tol-point-m (default 0.5 m) of the speed-1 touchdown
    time to land      touchdown - arming, sim seconds, within --tol-time-s (default 2.0 s) of speed 1
The highest safe speed is the largest S at which every scenario passes all three (and every lower S passed too).

Trials per hour: N / wall time of the campaign (`--jobs` parallel trials, start-up of `viva-sitl run` and the
script included). Memory per parallel trial: the peak RSS (VmHWM) of each process of the trial (`viva-sitl run`,
the Python script, the mavsdk_server it starts), summed per trial, sampled from /proc every 0.2 s; the max over
trials is reported. Prints a JSON report; bench/results_trials.md records a run.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import platform
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

PILOT = "{python} mission_scripts/mavsdk_precision_land.py {mavsdk_url} --north 8 --east 5 --altitude 10"


TIMING = "realtime"  # --timing: the trials' clock (viva_sitl.timing)


def bench_spec(n: int, speed: float, seed: int) -> Any:
    from viva_sitl.evaluation.spec import spec_from_dict

    return spec_from_dict(
        {
            "trials": {"name": "ext-bench", "n": n, "seed": seed, "timeout_s": 150.0, "speed": speed,
                       "timing": TIMING},
            "scenario": {"footage": "synthetic", "start": "ground", "north_m": [-30.0, 30.0],
                         "east_m": [-30.0, 30.0], "altitude_m": 10.0, "yaw_deg": [0.0, 360.0],
                         "land_at_s": 149.0},  # not reached: the script lands on its own
        },
        "ext-bench",
    )  # fmt: skip


class MemorySampler(threading.Thread):
    """Per trial directory: the sum over its processes of each one's peak RSS (VmHWM), from /proc."""

    def __init__(self, marker: str) -> None:
        super().__init__(daemon=True)
        self.marker = marker
        self.hwm_kb: dict[tuple[int, str], tuple[str, int]] = {}  # (pid, start) -> (trial dir, VmHWM kB)
        self.cmds: dict[tuple[int, str], str] = {}
        self.stop_event = threading.Event()

    def _trial_of(self, pid: str) -> str | None:
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            env = Path(f"/proc/{pid}/environ").read_bytes().decode(errors="replace")
        except OSError:
            return None
        for text, sep in ((cmd, " "), (env, "\0")):
            k = text.find(self.marker)
            if k >= 0:
                rest = text[k + len(self.marker) :]
                return rest.split("/")[0].split(sep)[0]
        return None

    def run(self) -> None:
        while not self.stop_event.wait(0.2):
            for pid in os.listdir("/proc"):
                if not pid.isdigit():
                    continue
                trial = self._trial_of(pid)
                if trial is None:
                    continue
                try:
                    status = Path(f"/proc/{pid}/status").read_text()
                    start = Path(f"/proc/{pid}/stat").read_text().split()[21]
                except OSError:
                    continue
                hwm = next((int(x.split()[1]) for x in status.splitlines() if x.startswith("VmHWM:")), 0)
                key = (int(pid), start)
                if key not in self.cmds:
                    with contextlib.suppress(OSError):
                        self.cmds[key] = (
                            Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")[:90].decode()
                        )
                self.hwm_kb[key] = (trial, max(hwm, self.hwm_kb.get(key, (trial, 0))[1]))

    def detail(self) -> dict[str, list[str]]:
        """Per trial: each counted process, its peak RSS and the start of its command line."""
        out: dict[str, list[str]] = {}
        for key, (trial, kb) in sorted(self.hwm_kb.items()):
            out.setdefault(trial, []).append(f"{key[0]} {kb / 1024:.0f} MB {self.cmds.get(key, '?')}")
        return out

    def per_trial_mb(self) -> dict[str, float]:
        out: dict[str, float] = {}
        for trial, kb in self.hwm_kb.values():
            out[trial] = out.get(trial, 0.0) + kb / 1024
        return out


def events(tdir: Path) -> list[dict[str, Any]]:
    try:
        return [json.loads(x) for x in (tdir / "events.jsonl").read_text().splitlines()]
    except (OSError, ValueError):
        return []


def arm_time_s(evs: list[dict[str, Any]]) -> float | None:
    return next((float(e["t_s"]) for e in evs if e.get("kind") == "armed"), None)


def run_speed(n: int, speed: float, seed: int, jobs: int) -> dict[str, Any]:
    from viva_sitl.evaluation.campaign import run_campaign

    spec = bench_spec(n, speed, seed)
    with tempfile.TemporaryDirectory(prefix="viva-extbench-") as d:
        out = Path(d)
        sampler = MemorySampler(str(out / "trials") + "/")
        sampler.start()
        t0 = time.perf_counter()
        camp = run_campaign(spec, PILOT, out, jobs=jobs, progress=False)
        wall = time.perf_counter() - t0
        sampler.stop_event.set()
        sampler.join()
        trials = []
        for r in camp.ordered_rows():
            tdir = out / "trials" / f"{r['trial']:04d}"
            evs = events(tdir)
            armed = arm_time_s(evs)
            script_ok = any(
                e.get("kind") == "pilot" and e.get("text") == "pilot exited with code 0" for e in evs
            )
            td_t = r["end_t_s"] if r["landed"] else None
            trials.append({
                "trial": r["trial"], "end": r["end"], "script_ok": script_ok,
                "touchdown_north_m": r["touchdown_north_m"], "touchdown_east_m": r["touchdown_east_m"],
                "armed_t_s": armed, "time_to_land_s": (round(td_t - armed, 3) if td_t is not None and armed is not None
                                                       else None),
                "touchdown_speed_m_s": r["touchdown_speed_m_s"], "wall_s": r["wall_s"],
                "end_detail": r["end_detail"][:160],
            })  # fmt: skip
        mem = sampler.per_trial_mb()
        mem_detail = sampler.detail()
    return {"speed": speed, "wall_s": round(wall, 2), "trials_per_hour": round(3600.0 * n / wall, 1),
            "trials": trials, "mem_mb_per_trial": sorted(round(v, 1) for v in mem.values()),
            "mem_detail": mem_detail}  # fmt: skip


def compare(base: dict[str, Any], other: dict[str, Any], tol_point_m: float, tol_time_s: float) -> list[str]:
    """Why `other` does not keep the behaviour of `base` (empty: it does)."""
    fails: list[str] = []
    for a, b in zip(base["trials"], other["trials"], strict=True):
        k = a["trial"]
        if b["end"] != a["end"] or not b["script_ok"]:
            fails.append(
                f"trial {k}: end {b['end']} (script ok {b['script_ok']}) vs {a['end']}: {b['end_detail']}"
            )
            continue
        if a["touchdown_north_m"] is None or b["touchdown_north_m"] is None:
            continue
        dp = ((a["touchdown_north_m"] - b["touchdown_north_m"]) ** 2
              + (a["touchdown_east_m"] - b["touchdown_east_m"]) ** 2) ** 0.5  # fmt: skip
        if dp > tol_point_m:
            fails.append(f"trial {k}: touchdown {dp:.2f} m from speed 1's")
        if a["time_to_land_s"] is not None and b["time_to_land_s"] is not None:
            dt = abs(a["time_to_land_s"] - b["time_to_land_s"])
            if dt > tol_time_s:
                fails.append(
                    f"trial {k}: time to land {b['time_to_land_s']:.1f} s vs {a['time_to_land_s']:.1f} s"
                )
    return fails


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--n", type=int, default=3, help="scenarios (the same at every speed)")
    ap.add_argument("--speeds", type=float, nargs="+", default=[1.0, 2.0, 4.0, 8.0, 16.0])
    ap.add_argument("--jobs", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--seed", type=int, default=3)
    ap.add_argument("--tol-point-m", type=float, default=0.5)
    ap.add_argument("--tol-time-s", type=float, default=2.0)
    ap.add_argument("--timing", choices=("realtime", "lockstep", "charged"), default="realtime")
    args = ap.parse_args()
    global TIMING
    TIMING = args.timing
    speeds = sorted(set(args.speeds))
    if speeds[0] != 1.0:
        speeds = [1.0, *speeds]
    res: dict[str, Any] = {
        "machine": f"{platform.node()} {platform.machine()} {os.cpu_count()} cpus, {platform.python_version()}",
        "load_avg_before": os.getloadavg(), "pilot": PILOT, "n": args.n, "jobs": args.jobs, "timing": args.timing,
        "tolerances": {"touchdown_point_m": args.tol_point_m, "time_to_land_s": args.tol_time_s}, "runs": [],
    }  # fmt: skip
    base: dict[str, Any] | None = None
    safe = None
    for s in speeds:
        r = run_speed(args.n, s, args.seed, args.jobs)
        r["load_avg_after"] = os.getloadavg()
        if base is None:
            base = r
            r["behaviour_failures"] = [f"trial {t['trial']}: {t['end']}" for t in r["trials"]
                                       if t["end"] != "landed" or not t["script_ok"]]  # fmt: skip
        else:
            r["behaviour_failures"] = compare(base, r, args.tol_point_m, args.tol_time_s)
        r["keeps_behaviour"] = not r["behaviour_failures"]
        if r["keeps_behaviour"] and (safe is None or safe == speeds[speeds.index(s) - 1]):
            safe = s
        res["runs"].append(r)
        print(json.dumps({k: r[k] for k in ("speed", "wall_s", "trials_per_hour", "keeps_behaviour",
                                            "behaviour_failures", "mem_mb_per_trial")}), flush=True)  # fmt: skip
    res["highest_safe_speed"] = safe
    res["load_avg_after"] = os.getloadavg()
    print(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
