"""`viva-sitl run --scenario FILE`: one trial inside the real-time (or --speed S) app, for external pilots.

The scenario file is what `viva-sitl trials run` writes per trial (trials/NNNN/scenario.json, schema
vivasitl.scenario.v1, plus "limits"); an external pilot reads the same file (VIVA_SITL_SCENARIO). The app builds its
vehicle from `scenario_config` (footage, seed, start pose, yaw, PX4 parameters) and ScenarioSession runs the same
Episode as an in-process trial (viva_sitl.evaluation.episode: set-up, footage clock, the referee, "land now" and
failures announced as STATUSTEXT and "land now" repeated, the end); the app steps the vehicle at real time and calls
`after_step`. At the end: trial_trajectory.csv / events.jsonl / end.json in the run directory and
`viva-sitl trial: {json}` (the end summary) on stdout; the app stops LINGER_S later (a pilot can still close its
connection cleanly).
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from viva_sitl.config import ConfigError
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.episode import Episode
from viva_sitl.evaluation.monitor import Limits
from viva_sitl.evaluation.spec import Scenario
from viva_sitl.vehicle import Vehicle

TRIAL_PREFIX = "viva-sitl trial:"
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


class ScenarioSession:
    """The app's side of a trial: the Episode on the app's vehicle (built from episode.scenario_config)."""

    def __init__(self, scenario: Scenario, limits: Limits, vehicle: Vehicle, run_dir: Path) -> None:
        self.vehicle = vehicle
        self.run_dir = run_dir
        self.episode = Episode(vehicle, scenario, limits, gcs=False)  # the pilot is the ground station
        self.scenario = self.episode.scenario
        self.monitor = self.episode.monitor
        self.finished = False
        self._ended_wall_s: float | None = None
        # what the pilot's clock was (viva_sitl.timing.TimingStats.to_dict), into end.json at the end
        self.timing: Callable[[], dict[str, Any]] | None = None

    @property
    def done(self) -> bool:
        return self.episode.done

    def after_step(self) -> bool:
        """Call after every physics step; True LINGER_S wall seconds after the trial ended (the logs and the
        `viva-sitl trial:` line are written at the end itself; the vehicle keeps answering meanwhile, so a pilot
        that waits for the disarm and then closes its connection ends cleanly)."""
        if not self.episode.done:
            self.episode.after_step()
            if self.episode.done:
                self._write()
        return self._ended_wall_s is not None and time.monotonic() - self._ended_wall_s >= LINGER_S

    def _write(self) -> None:
        self.finished = True
        self._ended_wall_s = time.monotonic()
        if self.timing is not None:
            self.monitor.log.timing = self.timing()
        self.monitor.log.write(self.run_dir)
        print(f"{TRIAL_PREFIX} {json.dumps(self.monitor.log.summary())}", flush=True)

    def on_statustext(self, text: str, severity: int) -> None:
        """The endpoint's event listener: every STATUSTEXT the vehicle sends goes into the trial's events."""
        self.episode.record_autopilot_event(int(severity), text)

    def abort(self, end: TrialEnd, reason: str) -> None:
        """End the trial now from the app (e.g. a pilot lockstep cannot wait for): logs written at once."""
        if not self.episode.done:
            self.episode.end(end, reason)
            self._write()

    def finish(self, reason: str = "viva-sitl run stopped before the trial ended") -> None:
        """At the app's exit: the logs of a trial cut short (Ctrl-C, --duration) are written too."""
        if not self.finished:
            self.episode.end(TrialEnd.SITL_STOPPED, reason)
            self._write()
