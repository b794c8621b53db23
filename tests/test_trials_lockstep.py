"""Lockstep and charged timing (viva_sitl.timing) with real external pilots: real `viva-sitl run` processes, real
pymavlink programs as pilots, real busy processes loading the machine (started and stopped by pid)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from viva_sitl.evaluation.campaign import MEASURED_COLUMNS, rows_equal, run_campaign
from viva_sitl.evaluation.spec import spec_from_dict
from viva_sitl.pilotwatch import supported

pytestmark = [
    pytest.mark.e2e,
    pytest.mark.skipif(bool(supported()), reason=supported() or "Linux /proc with schedstat"),
]

PILOTS = Path(__file__).parent / "pilots"
BUSY_PILOT = (PILOTS / "pymavlink_busy.py").read_text()  # pymavlink, LO,HI ms of CPU per LOCAL_POSITION_NED
FRAME_PILOT = (PILOTS / "frame_busy.py").read_text()  # frame socket, 20-40 ms of CPU per frame
SPINNER_PILOT = (PILOTS / "spinner.py").read_text()  # busy polling


def _spec(timing: str, n: int = 2, factor: float = 1.0, speed: float = 2.0, frames: bool = False) -> object:
    return spec_from_dict(
        {"trials": {"name": "lockstep", "n": n, "seed": 3, "timeout_s": 60.0, "speed": speed, "timing": timing,
                    "pilot_cpu_factor": factor, "frames": frames},
         "scenario": {"footage": "synthetic", "start": "air", "north_m": [-20.0, 20.0], "east_m": [-20.0, 20.0],
                      "altitude_m": [8.0, 10.0], "land_at_s": [1.0, 2.0]}},
        "lockstep",
    )  # fmt: skip


@contextmanager
def _busy_loops(n: int) -> Iterator[list[int]]:
    """n processes that each keep a CPU busy (the machine's load), stopped by pid."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield [p.pid for p in procs]
    finally:
        for p in procs:
            p.kill()
            p.wait(5)


def _strip(rows: list[dict[str, object]]) -> list[dict[str, object]]:
    return [{k: v for k, v in r.items() if k not in MEASURED_COLUMNS} for r in rows]


@pytest.mark.slow  # four campaigns of two external trials
def test_lockstep_rows_do_not_depend_on_load_jobs_or_compute_time(tmp_path: Path) -> None:
    script = tmp_path / "busy_pilot.py"
    script.write_text(BUSY_PILOT)
    spec = _spec("lockstep")
    runs = []
    for k, (jobs, busy, ms) in enumerate([(1, 0, "5,15"), (2, 2, "5,15"), (1, 0, "30,60")]):
        with _busy_loops(busy):
            camp = run_campaign(spec, f"{{python}} {script} {{pymavlink_url}} {ms}", tmp_path / f"o{k}",
                                jobs=jobs, progress=False)  # fmt: skip
        rows = camp.ordered_rows()
        assert [r["end"] for r in rows] == ["landed", "landed"], [(r["end"], r["end_detail"]) for r in rows]
        assert all(r["timing"] == "lockstep" and r["timing_ok"] is True for r in rows), rows
        runs.append(rows)
    # quiet at jobs 1 and loaded (2 busy loops) at jobs 2: the same trials, to the last digit
    assert rows_equal(runs[0], runs[1]), (_strip(runs[0]), _strip(runs[1]))
    # 3-6x the computing per message (the pilot command's argument): the clock stood still for it, so the pilot
    # flew the same
    same_pilot = [{**r, "pilot": runs[0][0]["pilot"]} for r in runs[2]]
    assert rows_equal(runs[0], same_pilot), (_strip(runs[0]), _strip(same_pilot))
    timing = json.loads((tmp_path / "o2" / "trials" / "0000" / "end.json").read_text())["timing"]
    assert timing["mode"] == "lockstep" and timing["waited"] > 50 and timing["lockstep_held"] is True
    assert timing["pilot_cpu_s"] > 1.0  # ~45 ms per setpoint, ~20 setpoints per sim second
    run = json.loads((tmp_path / "o0" / "results.json").read_text())["run"]
    assert run["timing"] == "lockstep" and run["pilot_cpu_factor"] is None


@pytest.mark.slow
def test_charged_timing_bills_the_pilots_computing(tmp_path: Path) -> None:
    script = tmp_path / "busy_pilot.py"
    script.write_text(BUSY_PILOT)
    out = {}
    for factor in (0.0, 4.0):
        camp = run_campaign(_spec("charged", n=1, factor=factor), f"{{python}} {script} {{pymavlink_url}} 20,30",
                            tmp_path / f"f{factor:g}", progress=False)  # fmt: skip
        (row,) = camp.ordered_rows()
        assert row["end"] == "landed" and row["timing"] == "charged" and row["pilot_cpu_factor"] == factor, (
            row
        )
        out[factor] = row
    ends = {f: json.loads((tmp_path / f"f{f:g}" / "trials" / "0000" / "end.json").read_text()) for f in out}
    rec = ends[4.0]["timing"]
    assert rec["charged_sim_s"] > 1.0 and rec["lockstep_held"] is True
    assert ends[0.0]["timing"]["charged_sim_s"] == 0.0
    # factor 0 is lockstep: the pilot's first setpoint acts within a quantum of "land now"; at factor 4 each one
    # takes effect 4 x its 20-30 ms of computing later (plus its share of the pilot's other CPU)
    delay = {f: e["reaction_t_s"] - e["land_now_t_s"] for f, e in ends.items()}
    assert delay[0.0] <= 0.1 and delay[4.0] >= delay[0.0] + 0.08, delay
    run = json.loads((tmp_path / "f4" / "results.json").read_text())["run"]
    assert run["timing"] == "charged" and run["pilot_cpu_factor"] == 4.0


@pytest.mark.slow
def test_a_pilot_that_never_waits_ends_its_lockstep_trial_with_the_reason(tmp_path: Path) -> None:
    script = tmp_path / "spinner.py"
    script.write_text(SPINNER_PILOT)
    camp = run_campaign(_spec("lockstep", n=1), f"{{python}} {script} {{pymavlink_url}}", tmp_path / "o",
                        progress=False)  # fmt: skip
    (row,) = camp.ordered_rows()
    assert row["end"] == "pilot_error" and "never became idle" in row["end_detail"], row
    assert row["timing_ok"] is False


@pytest.mark.slow
def test_lockstep_frame_socket_pilot_is_load_independent(tmp_path: Path) -> None:
    """Frames are rendered at exact sim times in lockstep and the clock waits until the pilot is done with each."""
    script = tmp_path / "frame_pilot.py"
    script.write_text(FRAME_PILOT)
    spec = _spec("lockstep", n=1, frames=True)
    runs = []
    for k, (jobs, busy) in enumerate([(1, 0), (1, 2)]):
        with _busy_loops(busy):
            camp = run_campaign(spec, f"{{python}} {script} {{pymavlink_url}} {{frame_socket}}", tmp_path / f"o{k}",
                                jobs=jobs, progress=False)  # fmt: skip
        rows = camp.ordered_rows()
        assert [r["end"] for r in rows] == ["landed"], [(r["end"], r["end_detail"]) for r in rows]
        runs.append(rows)
    assert rows_equal(runs[0], runs[1]), (_strip(runs[0]), _strip(runs[1]))
    assert abs(runs[0][0]["touchdown_north_m"] - (runs[0][0]["start_north_m"] - 5.0)) < 1.0


# BUSY_PILOT with its computing done by a child process it spawned: the parent sends the child each job through a
# pipe and blocks (sleeping, not computing) until the child answers. Watching the parent alone would let the clock
# run while the child computes; lockstep watches the pilot's whole process group.
CHILD_PILOT = BUSY_PILOT.replace(
    "import time\n",
    "import time\nimport subprocess\n"
    "child = subprocess.Popen([sys.executable, '-c', 'import sys, time\\nfor line in sys.stdin:\\n"
    "    end = time.thread_time() + float(line) / 1000.0\\n    while time.thread_time() < end: pass\\n"
    '    print("ok", flush=True)\'], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)\n',
    1,
).replace(
    "        end = time.thread_time() + rng.uniform(lo, hi) / 1000.0  # a fixed amount of work, however loaded\n"
    "        while time.thread_time() < end:\n            pass\n",
    "        child.stdin.write(f'{rng.uniform(lo, hi)}\\n'); child.stdin.flush()\n"
    "        assert child.stdout.readline().strip() == 'ok'\n",
)

# Exits with an error half a wall second after "land now" (its last words on stderr)
EXITING_PILOT = BUSY_PILOT.replace(
    '        state = "offboard"\n',
    '        state = "offboard"\n        died_at = time.monotonic()\n',
).replace(
    "    if time.monotonic() - last_hb > 1.0:\n",
    "    if state != 'wait' and time.monotonic() - died_at > 0.5:\n"
    "        print('pilot: lost the target, giving up', file=sys.stderr, flush=True)\n        sys.exit(3)\n"
    "    if time.monotonic() - last_hb > 1.0:\n",
)


@pytest.mark.slow
def test_lockstep_waits_for_a_child_the_pilot_spawned_to_compute(tmp_path: Path) -> None:
    assert (
        "child.stdin.write" in CHILD_PILOT
        and "while time.thread_time() < end:\n            pass" not in CHILD_PILOT
    )
    script = tmp_path / "child_pilot.py"
    script.write_text(CHILD_PILOT)
    spec = _spec("lockstep", n=1)
    runs = []
    for k, (busy, ms) in enumerate([(0, "5,15"), (2, "40,60")]):
        with _busy_loops(busy):
            camp = run_campaign(spec, f"{{python}} {script} {{pymavlink_url}} {ms}", tmp_path / f"o{k}",
                                progress=False)  # fmt: skip
        rows = camp.ordered_rows()
        assert [r["end"] for r in rows] == ["landed"], [(r["end"], r["end_detail"]) for r in rows]
        assert rows[0]["timing_ok"] is True
        runs.append([{**r, "pilot": "child"} for r in rows])
    # 4x the child's computing and a loaded machine: the clock stood still for the child, so the flight is the same
    assert rows_equal(runs[0], runs[1]), (_strip(runs[0]), _strip(runs[1]))
    timing = json.loads((tmp_path / "o1" / "trials" / "0000" / "end.json").read_text())["timing"]
    assert timing["waited"] > 20 and timing["pilot_cpu_s"] > 1.0, timing  # the child's CPU is the pilot's


@pytest.mark.slow
def test_lockstep_pilot_that_ignores_the_frame_socket_or_exits_midway(tmp_path: Path) -> None:
    # frames are rendered and published, nobody reads them: the clock does not wait for a reader
    busy = tmp_path / "busy_pilot.py"
    busy.write_text(BUSY_PILOT)
    camp = run_campaign(_spec("lockstep", n=1, frames=True), f"{{python}} {busy} {{pymavlink_url}} 5,15",
                        tmp_path / "ignores", progress=False)  # fmt: skip
    (row,) = camp.ordered_rows()
    assert row["end"] == "landed" and row["timing_ok"] is True, row
    # a pilot that exits with an error mid-flight: pilot_error at once, with its last words
    assert "sys.exit(3)" in EXITING_PILOT and "died_at = time.monotonic()" in EXITING_PILOT
    dying = tmp_path / "exiting_pilot.py"
    dying.write_text(EXITING_PILOT)
    camp = run_campaign(_spec("lockstep", n=1), f"{{python}} {dying} {{pymavlink_url}} 5,15", tmp_path / "exits",
                        progress=False)  # fmt: skip
    (row,) = camp.ordered_rows()
    assert row["end"] == "pilot_error" and "lost the target" in row["end_detail"], row
    assert row["flight_time_s"] < 20.0, row  # not the 60 s timeout


@pytest.mark.slow
def test_charged_fixed_latency_per_frame_delays_what_the_pilot_answers(tmp_path: Path) -> None:
    script = tmp_path / "frame_pilot.py"
    script.write_text(FRAME_PILOT)
    ends, rows = {}, {}
    for ms in (0.0, 250.0):
        spec = dataclasses.replace(_spec("charged", n=1, factor=0.0, frames=True), pilot_latency_ms=ms)
        out = tmp_path / f"l{ms:g}"
        camp = run_campaign(
            spec, f"{{python}} {script} {{pymavlink_url}} {{frame_socket}}", out, progress=False
        )
        (rows[ms],) = camp.ordered_rows()
        assert rows[ms]["end"] == "landed" and rows[ms]["pilot_latency_ms"] == ms, rows[ms]
        ends[ms] = json.loads((out / "trials" / "0000" / "end.json").read_text())
    # the switch to offboard, computed from the first frame after "land now", takes effect 250 ms after that frame
    delay = {ms: e["reaction_t_s"] - e["land_now_t_s"] for ms, e in ends.items()}
    assert delay[0.0] <= 0.12 and 0.2 <= delay[250.0] - delay[0.0] <= 0.35, delay
    assert ends[250.0]["timing"]["pilot_latency_ms"] == 250.0
    run = json.loads((tmp_path / "l250" / "results.json").read_text())["run"]
    assert run["timing"] == "charged" and run["pilot_latency_ms"] == 250.0


@pytest.mark.slow
def test_lockstep_holds_through_a_pilots_slow_first_frame(tmp_path: Path) -> None:
    """A companion whose first frame costs 3 s of CPU (a model's warm-up on its first input) keeps lockstep: the
    never-idle give-up (10 CPU s per quantum) is for busy polling, not for one long computation. With the give-up at
    2 CPU s (before), that quantum ran without it (never_idle 1, timing_ok false)."""
    script = tmp_path / "frame_pilot.py"
    script.write_text(FRAME_PILOT)
    camp = run_campaign(_spec("lockstep", n=1, frames=True),
                        f"{{python}} {script} {{pymavlink_url}} {{frame_socket}} 20,40 3000", tmp_path / "o",
                        progress=False)  # fmt: skip
    (row,) = camp.ordered_rows()
    assert row["end"] == "landed", (row["end"], row["end_detail"])
    assert row["timing_ok"] is True, row
    (end,) = (tmp_path / "o" / "trials").glob("*/end.json")
    timing = json.loads(end.read_text())["timing"]
    assert timing["never_idle"] == 0 and timing["lockstep_held"] is True, timing
    assert timing["max_busy_wall_s"] >= 1.0, timing  # the clock did stand still through the 3 s computation
