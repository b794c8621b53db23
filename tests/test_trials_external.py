"""External pilots (issue 8 §2/§4): unchanged MAVLink programs flown per trial against their own `viva-sitl run
--scenario`, on ports nobody else uses; crashing and hanging pilots fail their own trial only; no process is left."""

from __future__ import annotations

import csv
import json
import subprocess
import sys
from pathlib import Path

import pytest

from viva_sitl.evaluation.campaign import run_campaign
from viva_sitl.evaluation.spec import spec_from_dict

REPO = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.e2e

# index 0 crashes at once, index 1 hangs, the others land when told to ("Emergency: land now" STATUSTEXT)
PYMAVLINK_PILOT = r"""
import json, os, sys, time
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
scenario = json.load(open(os.environ["VIVA_SITL_SCENARIO"]))
if scenario["index"] == 0:
    raise SystemExit("my pilot crashed: no camera")
if scenario["index"] == 1:
    time.sleep(3600)
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
        tlogs = list(tdir.glob("*.tlog"))
        if tlogs:  # `viva-sitl run` records a .tlog in its run directory (when that helper's work is merged)
            assert tlogs[0].stat().st_size > 1000
    assert _leftovers(str(tmp_path)) == []


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
    assert (
        r0["end"] == "timeout" and "pilot exited with code 1: my pilot crashed: no camera" in r0["end_detail"]
    )
    assert (
        r1["end"] == "timeout" and "pilot still running at the end of the trial (stopped" in r1["end_detail"]
    )
    assert r2["end"] == "landed" and r2["time_to_land_s"] > 0, r2
    assert "told to land" in (tmp_path / "out" / "trials" / "0002" / "pilot.log").read_text()
    assert _leftovers(str(tmp_path)) == []


def test_sitl_scenario_flag_rejects_a_bad_file(tmp_path: Path) -> None:
    bad = tmp_path / "s.json"
    bad.write_text('{"schema": "something-else"}')
    r = subprocess.run([sys.executable, "-m", "viva_sitl", "run", "--no-video", "--scenario", str(bad)],
                       capture_output=True, text=True, timeout=60, cwd=REPO)  # fmt: skip
    assert r.returncode == 2
    assert r.stderr.strip() == "viva-sitl: scenario: schema 'something-else' is not vivasitl.scenario.v1"
