"""External pilots (issue 8 §2/§4): unchanged MAVLink programs flown per trial against their own `viva-sitl run
--scenario`, on ports nobody else uses; crashing and hanging pilots fail their own trial only; no process is left."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import pytest

from viva_sitl import opencv_pool
from viva_sitl.dashboard.replay import load_recording
from viva_sitl.evaluation.campaign import run_campaign
from viva_sitl.evaluation.spec import spec_from_dict

REPO = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.e2e

# index 0 crashes at once (a package it needs is missing), index 1 hangs, the others land when told to ("Emergency:
# land now" STATUSTEXT); index 2 first prints bytes that are not UTF-8, more than a pipe holds, on both streams
PYMAVLINK_PILOT = r"""
import json, os, sys, time
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
scenario = json.load(open(os.environ["VIVA_SITL_SCENARIO"]))
if scenario["index"] == 0:
    import viva_no_such_package_for_my_camera
if scenario["index"] == 1:
    time.sleep(3600)
if scenario["index"] == 2:
    print("opencv pool env:", sorted(k for k in os.environ if k.startswith(("OPENCV_THREAD_POOL", "VIVA_SITL_OPENCV"))),
          flush=True)
    for stream in (sys.stdout.buffer, sys.stderr.buffer):
        stream.write(b"\xff\xfe\x80 not utf-8\n" * 5000)
        stream.flush()
m = mavutil.mavlink_connection(sys.argv[1], source_system=255)
hb = m.wait_heartbeat(timeout=30)
last = 0.0
landing = False
while True:
    if time.monotonic() - last > 1.0:
        m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        last = time.monotonic()
    msg = m.recv_match(type=["STATUSTEXT", "HEARTBEAT"], blocking=True, timeout=0.5)
    if msg is None:
        continue
    if msg.get_type() == "STATUSTEXT" and "land now" in msg.text and not landing:
        print("told to land at", scenario["land_at_s"], flush=True)
        m.mav.command_long_send(m.target_system, 1, mavutil.mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0)
        landing = True
    if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == m.target_system and landing:
        if not msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED:
            print("disarmed: done", flush=True)
            break
"""


def _leftovers(marker: str) -> list[str]:
    ps = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
    return [line for line in ps.splitlines() if marker in line and "ps -eo" not in line]


@pytest.mark.slow  # a MAVSDK script as pilot
def test_mavsdk_script_unchanged_as_pilot(tmp_path: Path) -> None:
    spec = spec_from_dict(
        {"trials": {"name": "mavsdk", "n": 2, "seed": 5, "timeout_s": 60.0, "speed": 4.0},
         "scenario": {"footage": "synthetic", "start": "ground", "north_m": [-30.0, 30.0], "east_m": [-30.0, 30.0],
                      "altitude_m": 6.0, "land_at_s": 30.0}},
        "mavsdk",
    )  # fmt: skip
    pilot = "{python} mission_scripts/mavsdk_takeoff_land.py {mavsdk_url} --altitude 6"
    camp = run_campaign(spec, pilot, tmp_path, jobs=2, progress=False)
    rows = camp.ordered_rows()
    assert [r["end"] for r in rows] == ["landed", "landed"], rows
    for r in rows:
        tdir = tmp_path / "trials" / f"{r['trial']:04d}"
        with (tdir / "trial_trajectory.csv").open() as f:
            traj = list(csv.DictReader(f))
        assert max(-float(x["down_m"]) for x in traj) == pytest.approx(6.0, abs=0.7)  # the script's takeoff
        assert abs(r["touchdown_north_m"] - r["start_north_m"]) < 1.5 and r["touchdown_speed_m_s"] < 1.2
        assert "RESULT" in (tdir / "pilot.log").read_text()  # the script ran to its end
        kinds = [json.loads(x)["kind"] for x in (tdir / "events.jsonl").read_text().splitlines()]
        assert "armed" in kinds and "touchdown" in kinds
        rec = load_recording(
            tdir
        )  # the trial folder opens in `viva-sitl replay`, on the trial's footage clock
        sc = json.loads((tdir / "scenario.json").read_text())
        assert rec.source == "trajectory" and rec.footage_offset_s == sc["footage_time_s"]
        assert rec.config.footage == "synthetic" and max(-s.pos_ned_m[2] for s in rec.samples) > 5.0
        tlogs = list(tdir.glob("*.tlog"))
        if tlogs:  # `viva-sitl run` records a .tlog in its run directory (when that helper's work is merged)
            assert tlogs[0].stat().st_size > 1000
    assert _leftovers(str(tmp_path)) == []


@pytest.mark.slow  # external pilots, each with its own viva-sitl
def test_crashing_hanging_and_landing_external_pilots(tmp_path: Path) -> None:
    script = tmp_path / "pilot.py"
    script.write_text(PYMAVLINK_PILOT)
    spec = spec_from_dict(
        {"trials": {"name": "bad", "n": 3, "seed": 2, "timeout_s": 25.0, "speed": 4.0},
         "scenario": {"footage": "synthetic", "start": "air", "north_m": [-30.0, 30.0], "east_m": [-30.0, 30.0],
                      "altitude_m": 6.0, "land_at_s": 6.0}},
        "bad",
    )  # fmt: skip
    camp = run_campaign(
        spec, f"{{python}} {script} {{pymavlink_url}}", tmp_path / "out", jobs=2, progress=False
    )
    r0, r1, r2 = camp.ordered_rows()
    # the crash ends its trial at once (not at the 25 s timeout) with the pilot's last stderr lines
    assert r0["end"] == "pilot_error" and r0["end_t_s"] < 12.0, r0
    assert r0["end_detail"].startswith("pilot exited with code 1 before the trial ended: ")
    assert "ModuleNotFoundError: No module named 'viva_no_such_package_for_my_camera'" in r0["end_detail"]
    assert (
        r1["end"] == "timeout" and "pilot still running at the end of the trial (stopped" in r1["end_detail"]
    )
    assert r2["end"] == "landed" and r2["time_to_land_s"] > 0, r2
    log2 = (tmp_path / "out" / "trials" / "0002" / "pilot.log").read_bytes()
    assert b"told to land" in log2 and log2.count(b"\xff\xfe\x80 not utf-8\n") == 10000  # kept as printed
    # the OpenCV settings viva_sitl made for itself (this process has them) are not the user's program's
    assert os.environ.get("OPENCV_THREAD_POOL_ACTIVE_WAIT_MAIN") is not None
    mine = sorted(
        k for k in opencv_pool.user_environ() if k.startswith(("OPENCV_THREAD_POOL", "VIVA_SITL_OPENCV"))
    )
    assert f"opencv pool env: {mine}".encode() in log2
    assert _leftovers(str(tmp_path)) == []
    # a pilot script that is not there: pilot_error at once, with what Python said
    camp = run_campaign(spec, f"{{python}} {tmp_path / 'no_such_pilot.py'}", tmp_path / "missing", n=1, jobs=1,
                        progress=False)  # fmt: skip
    (row,) = camp.ordered_rows()
    assert row["end"] == "pilot_error" and row["end_t_s"] < 12.0, row
    assert "code 2 before the trial ended" in row["end_detail"] and "can't open file" in row["end_detail"]
    assert not camp.infra_errors()  # the pilot's failure, not the harness's


def test_sitl_scenario_flag_rejects_a_bad_file(tmp_path: Path) -> None:
    bad = tmp_path / "s.json"
    bad.write_text('{"schema": "something-else"}')
    r = subprocess.run([sys.executable, "-m", "viva_sitl", "run", "--no-video", "--scenario", str(bad)],
                       capture_output=True, text=True, timeout=60, cwd=REPO)  # fmt: skip
    assert r.returncode == 2
    assert r.stderr.strip() == "viva-sitl: scenario: schema 'something-else' is not vivasitl.scenario.v1"


# ----------------------------------------------------------------------- Ctrl-C, resume, hung pilots (issue 8 §4)

_MISBEHAVIOUR = PYMAVLINK_PILOT[
    PYMAVLINK_PILOT.index('if scenario["index"] == 0:') : PYMAVLINK_PILOT.index(
        "m = mavutil.mavlink_connection"
    )
]
LANDING_PILOT = PYMAVLINK_PILOT.replace(_MISBEHAVIOUR, "")
assert "index" not in LANDING_PILOT.split("scenario = json.load")[1].split("m = mavutil")[0]

# connects, keeps the link alive, never lands: only a limit can end its trial
NEVER_LANDS_PILOT = r"""
import os, sys, time
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
m = mavutil.mavlink_connection(sys.argv[1], source_system=255)
m.wait_heartbeat(timeout=60)
print("connected, hovering forever", flush=True)
while True:
    m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
    m.recv_match(blocking=True, timeout=0.5)
"""


def _procs(marker: str) -> dict[tuple[int, str], str]:
    """Live processes whose command line holds `marker`: (pid, start time) -> command line."""
    out: dict[tuple[int, str], str] = {}
    for pid in os.listdir("/proc"):
        if not pid.isdigit() or int(pid) == os.getpid():
            continue
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if marker in cmd and stat[0] != "Z":
            out[(int(pid), stat[19])] = cmd
    return out


def _alive(key: tuple[int, str]) -> bool:
    try:
        stat = Path(f"/proc/{key[0]}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return False
    return stat[19] == key[1] and stat[0] != "Z"


def _wait_for(cond: Any, timeout_s: float, what: str) -> Any:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        got = cond()
        if got:
            return got
        time.sleep(0.1)  # polling a condition, not a fixed wait
    raise AssertionError(f"timed out after {timeout_s:.0f} s waiting for {what}")


@pytest.mark.slow  # Ctrl-C of a campaign, ~35 s
def test_ctrl_c_keeps_finished_trials_leaves_no_process_and_resume_completes(tmp_path: Path) -> None:
    script = tmp_path / "pilot.py"
    script.write_text(LANDING_PILOT)
    spec_file = tmp_path / "spec.toml"
    spec_file.write_text(
        '[trials]\nname = "ctrlc"\nn = 4\nseed = 11\ntimeout_s = 40.0\nspeed = 4.0\n'
        '[scenario]\nfootage = "synthetic"\nstart = "air"\nnorth_m = [-30.0, 30.0]\neast_m = [-30.0, 30.0]\n'
        "altitude_m = [5.0, 8.0]\nland_at_s = [3.0, 6.0]\n"
    )
    out = tmp_path / "out"
    cmd = [sys.executable, "-m", "viva_sitl", "trials", "run", str(spec_file), "--pilot",
           f"{{python}} {script} {{pymavlink_url}}", "--jobs", "2", "-o", str(out), "--no-progress"]  # fmt: skip
    # its own process group, signalled as a whole: what Ctrl-C in a terminal does to the foreground job
    cli = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           start_new_session=True)  # fmt: skip
    try:
        trials = out / "trials"

        def first_done_and_another_flying() -> bool:
            done = list(trials.glob("*/result.json"))
            flying = [
                d for d in trials.glob("*") if (d / "pilot.log").exists() and not (d / "result.json").exists()
            ]
            return bool(done) and bool(flying) and bool(_procs(str(script)))

        _wait_for(first_done_and_another_flying, 240, "one finished trial and another one's pilot running")
        running = _procs(str(tmp_path))  # viva-sitl run (--scenario under tmp_path) and the pilot scripts
        assert any("viva_sitl" in c and " run " in c for c in running.values()), running
        kept = {p.parent.name: p.read_text() for p in trials.glob("*/result.json")}
        t_int = time.monotonic()
        os.killpg(cli.pid, signal.SIGINT)
        _, err = cli.communicate(timeout=60)
        took = time.monotonic() - t_int
    finally:
        if cli.poll() is None:
            os.killpg(cli.pid, signal.SIGKILL)
    assert cli.returncode == 130, err
    assert took < 30.0, f"Ctrl-C took {took:.1f} s to end the command"
    last = err.strip().splitlines()[-1]
    assert re.fullmatch(
        rf"interrupted: (\d) of 4 trials kept in {re.escape(str(out))}; rerun with --resume to complete the rest",
        last,
    ), err
    n_kept = int(last.split()[1])
    assert n_kept >= len(kept) >= 1
    doc = json.loads((out / "results.json").read_text())
    assert doc["complete"] is False and doc["trials_done"] == n_kept
    for name, text in kept.items():  # finished before Ctrl-C: kept as they were
        assert (trials / name / "result.json").read_text() == text
    assert [k for k in running if _alive(k)] == [], "processes left after Ctrl-C"
    assert _procs(str(tmp_path)) == {}

    r = subprocess.run([*cmd, "--resume"], cwd=REPO, capture_output=True, text=True, timeout=400)
    assert r.returncode == 0, r.stderr
    doc2 = json.loads((out / "results.json").read_text())
    assert doc2["complete"] is True and doc2["trials_done"] == 4
    assert doc2["scenarios"] == doc["scenarios"]  # the same draw: resume completes, it does not redraw
    ref = subprocess.run([sys.executable, "-m", "viva_sitl", "trials", "scenarios", str(spec_file)], cwd=REPO,
                         capture_output=True, text=True, timeout=60, check=True)  # fmt: skip
    assert [json.loads(x) for x in ref.stdout.splitlines()] == doc2["scenarios"]
    assert all(r["end"] == "landed" for r in doc2["rows"]), [
        (r["end"], r["end_detail"]) for r in doc2["rows"]
    ]
    for name, text in kept.items():  # not flown again
        assert (trials / name / "result.json").read_text() == text
    assert _procs(str(tmp_path)) == {}


@pytest.mark.slow  # waits out the wall limit, ~35 s
def test_pilot_that_never_lands_is_stopped_at_the_wall_limit_with_its_processes(tmp_path: Path) -> None:
    script = tmp_path / "hover.py"
    script.write_text(NEVER_LANDS_PILOT)
    spec = spec_from_dict(
        {"trials": {"name": "hang", "n": 1, "seed": 1, "timeout_s": 3000.0, "speed": 1.0},
         "scenario": {"footage": "synthetic", "start": "air", "north_m": [-10.0, 10.0], "east_m": [-10.0, 10.0],
                      "altitude_m": 6.0, "land_at_s": 2.0}},
        "hang",
    )  # fmt: skip
    seen: dict[tuple[int, str], str] = {}
    box: dict[str, Any] = {}

    def run() -> None:
        box["camp"] = run_campaign(spec, f"{{python}} {script} {{pymavlink_url}}", tmp_path / "out", jobs=1,
                                   progress=False, wall_limit_s=25.0)  # fmt: skip

    th = threading.Thread(target=run)
    th.start()

    def both_running() -> bool:
        seen.update(_procs(str(tmp_path)))
        pilot_log = tmp_path / "out" / "trials" / "0000" / "pilot.log"
        return (
            any(str(script) in c for c in seen.values())
            and pilot_log.exists()
            and ("hovering forever" in pilot_log.read_text())
        )

    _wait_for(both_running, 45, "the pilot connected to its viva-sitl run")
    th.join(120)
    assert not th.is_alive()
    (row,) = box["camp"].ordered_rows()
    assert row["end"] == "wall_timeout" and "pilot hung?" in row["end_detail"], row
    assert any("viva_sitl" in c and " run " in c for c in seen.values()), seen
    assert [k for k in seen if _alive(k)] == [], "processes left after the wall limit"
