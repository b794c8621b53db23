"""Issue 24 part 3, trials: every in-process trial writes a PX4 ULog (trials/NNNN/log.ulg) that pyulog reads and that
matches the trial's own trajectory; the campaign's HTML report links it. The run log's vehicle_attitude_setpoint
(the autopilot's command at every step) is checked here too."""

from __future__ import annotations

import csv
import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
import pyulog
from test_ulog import PX4_TOPICS

from viva_sitl.config import SimConfig
from viva_sitl.evaluation.campaign import run_campaign
from viva_sitl.evaluation.spec import draw_scenarios, spec_from_dict
from viva_sitl.flightlog import FlightLog
from viva_sitl.vehicle import Vehicle

SPEC = {
    "trials": {"name": "ulog", "n": 2, "seed": 3, "timeout_s": 30.0},
    "scenario": {"footage": "synthetic", "start": "air", "north_m": [-20.0, 20.0], "east_m": [-20.0, 20.0],
                 "altitude_m": 8.0, "land_at_s": 0.5},
}  # fmt: skip


def test_each_inprocess_trial_writes_a_ulog_that_the_report_links(tmp_path: Path) -> None:
    spec = spec_from_dict(json.loads(json.dumps(SPEC)), "ulog")
    scen = draw_scenarios(spec)
    camp = run_campaign(spec, "descend", tmp_path / "out", jobs=1, progress=False)
    rows = camp.ordered_rows()
    assert [r["end"] for r in rows] == ["landed", "landed"]
    for s in scen:
        d = camp.out_dir / "trials" / f"{s.index:04d}"
        u = pyulog.ULog(str(d / "log.ulg"))
        names = {x.name for x in u.data_list}
        assert names >= PX4_TOPICS | {"vehicle_attitude_setpoint"}, names
        for x in u.data_list:
            assert np.all(np.diff(x.data["timestamp"].astype(np.int64)) > 0), x.name
        with (d / "trial_trajectory.csv").open() as f:
            traj = list(csv.DictReader(f))
        lp = u.get_dataset("vehicle_local_position").data
        # the air start at the scenario's pose, the touchdown on the ground, over the trial's duration
        assert lp["z"][0] == pytest.approx(float(traj[0]["down_m"]), abs=0.05)
        assert lp["x"][0] == pytest.approx(s.north_m, abs=0.05) and lp["y"][0] == pytest.approx(
            s.east_m, abs=0.05
        )
        assert -lp["z"][0] == pytest.approx(8.0, abs=0.05) and -lp["z"][-1] < 0.3
        assert lp["timestamp"][-1] / 1e6 == pytest.approx(float(traj[-1]["sim_time_s"]), abs=0.05)
        status = u.get_dataset("vehicle_status").data
        assert (
            status["arming_state"][0] == 2 and status["arming_state"][-1] == 1
        )  # armed in the air, disarmed
        sp = u.get_dataset("vehicle_attitude_setpoint").data
        q = np.stack([sp[f"q_d[{i}]"] for i in range(4)])
        assert np.allclose(np.linalg.norm(q, axis=0), 1.0, atol=1e-5)
        assert (
            np.all(sp["thrust_body[2]"] <= 0.0) and sp["thrust_body[2]"].min() < -0.2
        )  # upward thrust, in air
    html = (camp.out_dir / "report.html").read_text()
    for s in scen:
        link = f"trials/{s.index:04d}/log.ulg"
        assert re.search(rf"<a href='{re.escape(link)}'>log.ulg</a>", html), link  # the all-trials table
        assert f"<a href='{link}'>ulog</a>" in html  # the worst-trials logs column


def test_run_log_has_the_autopilots_attitude_setpoint(tmp_path: Path) -> None:
    """FlightLog.step(state, autopilot) as `viva-sitl run` calls it: the attitude setpoint is the autopilot's output."""
    with Vehicle(SimConfig(), geofence=False) as v:
        flog = FlightLog(tmp_path / "log.ulg", v.geo, v.params, start_time_s=v.time_s)
        assert v.autopilot.arm(v.time_s).ok and v.autopilot.takeoff(v.time_s, 4.0).ok
        commands = {}
        for _ in range(int(round(4.0 / v.dt_s))):
            s = v.step(1)
            flog.step(s, v.autopilot)
            cmd = v.autopilot.last_command
            assert cmd is not None
            commands[int(round(s.time_s * 1e6))] = cmd
        flog.close()
        max_thrust = float(v.autopilot.eav_params().max_thrust_n)
    sp = pyulog.ULog(str(tmp_path / "log.ulg")).get_dataset("vehicle_attitude_setpoint").data
    assert 180 <= len(sp["timestamp"]) <= 210  # 50 Hz over 4 s
    for i in range(0, len(sp["timestamp"]), 23):
        cmd = commands[int(sp["timestamp"][i])]
        assert sp["thrust_body[2]"][i] == pytest.approx(-cmd.thrust_n / max_thrust, abs=1e-5)
        w, x, y, z = (float(sp[f"q_d[{k}]"][i]) for k in range(4))
        yaw = math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        assert math.remainder(yaw - cmd.yaw_rad, math.tau) == pytest.approx(0.0, abs=1e-4)
