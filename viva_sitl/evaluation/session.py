"""`viva-sitl run --scenario FILE`: one trial inside the real-time (or --speed S) app, for external pilots.

The scenario file is what `viva-sitl trials run` writes per trial (trials/NNNN/scenario.json, schema
vivasitl.scenario.v1, plus "limits"); an external pilot reads the same file (VIVA_SITL_SCENARIO). Applied:

  - by `scenario_config` (before the vehicle exists): footage, seed, start pose (an air start is armed in Hold
    there), yaw, PX4 parameters (drawn ones + SIM_WIND_* / SIM_GUST_STD);
  - by ScenarioSession (app.py calls it after every physics step): the footage clock (footage_time_s), the
    TrialMonitor ("land now" and failures at their times, sent as STATUSTEXT, "land now" repeated every
    LAND_NOW_REPEAT_S; the trajectory; the end), and at the
    end trial_trajectory.csv / events.jsonl / end.json in the run directory and `viva-sitl trial: {json}` (the end
    summary) on stdout; the app stops LINGER_S later (a pilot can still close its connection cleanly).
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

from viva_sitl.autopilot import Severity
from viva_sitl.config import ConfigError, SimConfig
from viva_sitl.evaluation.monitor import LAND_NOW_TEXT, Limits, TrialMonitor
from viva_sitl.evaluation.spec import Scenario

TRIAL_PREFIX = "viva-sitl trial:"
LAND_NOW_REPEAT_S = 5.0  # sim seconds between repeats of the "land now" STATUSTEXT until the trial ends
LINGER_S = 10.0  # wall seconds the app keeps running after the trial ended (`trials run` stops it sooner)


def read_scenario_file(path: str | Path) -> tuple[Scenario, Limits]:
    sc = Scenario.read(path)
    d = json.loads(Path(path).read_text())
    lim = d.get("limits", {})
    try:
        limits = Limits(
            timeout_s=float(lim.get("timeout_s", sc.timeout_s)),
            end_outside_s=float(lim.get("end_outside_s", Limits.end_outside_s)),
            crash_speed_m_s=float(lim.get("crash_speed_m_s", Limits.crash_speed_m_s)),
            log_hz=float(lim.get("log_hz", Limits.log_hz)),
        )
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"scenario {path}: bad limits: {exc}") from None
    return sc, limits


def write_scenario_file(path: Path, scenario: Scenario, limits: Limits) -> None:
    d = scenario.to_dict()
    d["limits"] = dataclasses.asdict(limits)
    path.write_text(json.dumps(d, indent=1))


def scenario_config(cfg: SimConfig, scenario: Scenario) -> SimConfig:
    """The run's config with the scenario's start applied (its parameters override the config's)."""
    names = {n for n, _ in scenario.all_params()}
    params = tuple(p for p in cfg.params if p[0] not in names) + scenario.all_params()
    return dataclasses.replace(
        cfg, footage=scenario.footage, seed=scenario.seed, initial_pos_ned_m=scenario.start_pos_ned_m,
        initial_yaw_deg=scenario.yaw_deg, params=params,
    )  # fmt: skip


class ScenarioSession:
    """The app's side of a trial. `vehicle`: viva_sitl.vehicle.Vehicle (already built from scenario_config)."""

    def __init__(self, scenario: Scenario, limits: Limits, vehicle: Any, run_dir: Path) -> None:
        from viva_sitl.evaluation.runner import shift_footage_clock

        self.scenario = scenario
        self.vehicle = vehicle
        self.run_dir = run_dir
        shift_footage_clock(vehicle.sim.footage, scenario.footage_time_s)
        self.monitor = TrialMonitor(scenario, limits, gcs=False)  # the pilot is the ground station
        self.monitor.start(vehicle)
        self._sent = 0
        self.finished = False
        self._ended_wall_s: float | None = None
        self._repeat_s = math.inf

    @property
    def done(self) -> bool:
        return self.monitor.log.end is not None

    def after_step(self) -> bool:
        """Call after every physics step; True LINGER_S wall seconds after the trial ended (the logs and the
        `viva-sitl trial:` line are written at the end itself; the vehicle keeps answering meanwhile, so a pilot
        that waits for the disarm and then closes its connection ends cleanly)."""
        m = self.monitor
        if m.log.end is None:
            m.after_step(self.vehicle)
            if m.log.end is not None:
                self._write()
            ev = m.log.events
            while self._sent < len(ev):  # land-now and injected failures: tell the pilot as PX4 would
                e = ev[self._sent]
                self._sent += 1
                if e["kind"] in ("land_now", "failure"):
                    self.vehicle.autopilot.ctx.event(Severity(e["severity"]), e["text"])
                if e["kind"] == "land_now":
                    self._repeat_s = e["t_s"] + LAND_NOW_REPEAT_S
            t = m.t_of(self.vehicle.state)
            if t >= self._repeat_s and m.log.end is None:  # a pilot that connected late still hears it
                self._repeat_s = t + LAND_NOW_REPEAT_S
                self.vehicle.autopilot.ctx.event(Severity.ALERT, LAND_NOW_TEXT)
        return self._ended_wall_s is not None and time.monotonic() - self._ended_wall_s >= LINGER_S

    def _write(self) -> None:
        self.finished = True
        self._ended_wall_s = time.monotonic()
        self.monitor.log.write(self.run_dir)
        print(f"{TRIAL_PREFIX} {json.dumps(self.monitor.log.summary())}", flush=True)

    def on_statustext(self, text: str, severity: int) -> None:
        """The endpoint's event listener: every STATUSTEXT the vehicle sends goes into the trial's events."""
        if text == LAND_NOW_TEXT or text.startswith("injected:"):
            return  # our own, already logged
        self.monitor.record_autopilot_event(self.vehicle.time_s, int(severity), text)

    def finish(self, reason: str = "viva-sitl run stopped before the trial ended") -> None:
        """At the app's exit: the logs of a trial cut short (Ctrl-C, --duration) are written too."""
        if not self.finished:
            self.monitor.end(self.vehicle, "sitl_stopped", reason)
            self._write()
