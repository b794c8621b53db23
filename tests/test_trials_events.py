"""'Land now' reaches every external pilot (issue 19 §2): the trial's clock waits for the pilot's first message, the
STATUSTEXT is repeated every 0.5 s until the pilot acts, and the reaction is recorded. Real processes, real UDP."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from viva_sitl.evaluation.campaign import run_campaign
from viva_sitl.evaluation.episode import LAND_NOW_REPEAT_S
from viva_sitl.evaluation.spec import spec_from_dict

pytestmark = [pytest.mark.e2e, pytest.mark.slow]  # two trials with a 3 s pilot start each

# A pymavlink pilot that starts slowly (a 3 s import), then lands on the N-th "land now" it hears (argv[2]).
SLOW_PILOT = r"""
import os, sys, time
time.sleep(3.0)  # a heavy import (torch, a model) before the pilot opens its link
os.environ["MAVLINK20"] = "1"
from pymavlink import mavutil
m = mavutil.mavlink_connection(sys.argv[1], source_system=255)
m.wait_heartbeat(timeout=30)
m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
want, heard, landing, last = int(sys.argv[2]), 0, False, time.monotonic()
while True:
    if time.monotonic() - last > 1.0:
        m.mav.heartbeat_send(mavutil.mavlink.MAV_TYPE_GCS, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0)
        last = time.monotonic()
    msg = m.recv_match(type=["STATUSTEXT", "HEARTBEAT"], blocking=True, timeout=0.5)
    if msg is None:
        continue
    if msg.get_type() == "STATUSTEXT" and "land now" in msg.text and not landing:
        heard += 1
        if heard >= want:
            m.mav.command_long_send(m.target_system, 1, mavutil.mavlink.MAV_CMD_NAV_LAND, 0, 0, 0, 0, 0, 0, 0, 0)
            landing = True
    if msg.get_type() == "HEARTBEAT" and msg.get_srcSystem() == m.target_system and landing:
        if not msg.base_mode & mavutil.mavlink.MAV_MODE_FLAG_SAFETY_ARMED:
            break
"""


def _events(trial_dir: Path) -> list[dict[str, object]]:
    return [json.loads(x) for x in (trial_dir / "events.jsonl").read_text().splitlines()]


@pytest.mark.parametrize("nth", [1, 3])
def test_a_slow_starting_pilot_hears_land_now_and_its_reaction_is_recorded(tmp_path: Path, nth: int) -> None:
    script = tmp_path / "slow_pilot.py"
    script.write_text(SLOW_PILOT)
    spec = spec_from_dict(
        {"trials": {"name": "slow", "n": 1, "seed": 4, "timeout_s": 30.0, "speed": 4.0},
         "scenario": {"footage": "synthetic", "start": "air", "north_m": [-20.0, 20.0], "east_m": [-20.0, 20.0],
                      "altitude_m": 5.0, "land_at_s": 1.0}},
        "slow",
    )  # fmt: skip
    camp = run_campaign(spec, f"{{python}} {script} {{pymavlink_url}} {nth}", tmp_path / "out", jobs=1,
                        progress=False)  # fmt: skip
    (row,) = camp.ordered_rows()
    trial = tmp_path / "out" / "trials" / "0000"
    assert row["end"] == "landed", (row, (trial / "pilot.log").read_text())
    ev = _events(trial)
    land_now = next(e for e in ev if e["kind"] == "land_now")
    reaction = next(e for e in ev if e["kind"] == "reaction")
    # the clock waited for the pilot: "land now" came land_at_s after it connected, not while it was importing
    assert land_now["t_s"] == pytest.approx(1.0, abs=0.01)
    delay = float(reaction["t_s"]) - float(land_now["t_s"])  # type: ignore[arg-type]
    # heard at once (nth 1), or on the (nth - 1)-th repeat 0.5 s apart: the STATUSTEXT keeps coming until it acts
    assert (nth - 1) * LAND_NOW_REPEAT_S - 0.05 <= delay <= (nth - 1) * LAND_NOW_REPEAT_S + 0.45, ev
    end = json.loads((trial / "end.json").read_text())
    assert end["reaction_t_s"] == reaction["t_s"] and end["land_now_t_s"] == land_now["t_s"]
