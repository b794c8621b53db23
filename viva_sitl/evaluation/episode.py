"""One episode: where a scenario meets a vehicle. The one place that sets a vehicle up from a Scenario, keeps the
control schedule, steps it under the trial's referee, delivers the scenario's events and computes the score row.

    cfg = scenario_config(SimConfig(), scenario)            # before the vehicle exists (footage, seed, pose, params)
    ep = Episode(Vehicle(cfg, footage=src), scenario, limits)   # set-up: params, footage clock, reset, referee
    for k in itertools.count():                             # a pilot acting at its own rate
        cmd = pilot(ep)
        for _ in range(ep.schedule.steps(k)):
            ep.step(cmd)                                    # one physics step, judged
            if ep.done: break
    row = ep.row(world, spec)

Its users are thin: the in-process trials runner (runner.py), `viva-sitl run --scenario` for external pilots
(session.py: the app steps the vehicle at real time and calls `after_step`), `trials fly`, and the Gymnasium
environments (gym/env.py, gym/vector.py). Nothing here reads a clock or does I/O.

- Set-up (`prepare`): the vehicle's PX4 parameters back to a baseline (a reused vehicle, e.g. a gym env), then the
  scenario's (drawn ones + wind); the footage clock through ONE mechanism, `Simulator.footage_offset_s` (footage
  time = sim time + offset; a FootageSource is never patched, so one source may serve many vehicles); the physics
  seed and the start pose (Vehicle.reset: a new autopilot, armed in Hold for an air start).
- Events: the TrialMonitor applies the scenario's schedule through the autopilot's public API
  (`Autopilot.inject_failure`, the path MAV_CMD_INJECT_FAILURE takes); "land now" and injected failures are
  announced as the vehicle's STATUSTEXT (`Autopilot.announce`). "Land now" is repeated every LAND_NOW_REPEAT_S
  (0.5 s) until the pilot reacts, so a pilot that starts listening late still hears it within half a second: the
  pilot's reaction is its first flight command after "land now" (arm, disarm, takeoff, land, RTL, mode, reposition,
  orbit, speed, mission start: Autopilot.commands; setpoint streams do not count, they flow before and after) or a
  change of flight mode (a failsafe's, too: the vehicle is then landing anyway). The first command is recorded as
  the event "reaction" and TrialLog.reaction_t_s (end.json "reaction_t_s"). The episode's own announcements are
  not recorded a second time as autopilot events.
- Schedule: control step k of a pilot acting at control_hz over physics at rate_hz lasts
  round((k + 1) r) - round(k r) physics steps, r = rate_hz / control_hz: exactly control_hz on average (30 Hz over
  250 Hz physics alternates 8 and 9 steps), and the same as a fixed step count where r is a whole number.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass

from viva_sitl.autopilot import Severity
from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavCommand
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.events import EventKind
from viva_sitl.evaluation.monitor import INJECTED_PREFIX, LAND_NOW_TEXT, Limits, TrialLog, TrialMonitor
from viva_sitl.evaluation.scoring import ScoreRow, score_trial
from viva_sitl.evaluation.spec import Scenario, TrialSpec
from viva_sitl.vehicle import Vehicle
from viva_sitl.world import WorldModel

LAND_NOW_REPEAT_S = 0.5  # sim seconds between repeats of the "land now" STATUSTEXT until the pilot reacts


def limits_of(spec: TrialSpec) -> Limits:
    """The referee's limits a trial spec sets."""
    return Limits(spec.timeout_s, spec.end_outside_s, spec.crash_speed_m_s, spec.log_hz)


def scenario_config(cfg: SimConfig, scenario: Scenario) -> SimConfig:
    """`cfg` with the scenario's start (footage, seed, pose, yaw; its parameters override the config's): what a
    vehicle built for this scenario is built from."""
    names = {n for n, _ in scenario.all_params()}
    params = tuple(p for p in cfg.params if p[0] not in names) + scenario.all_params()
    return dataclasses.replace(
        cfg, footage=scenario.footage, seed=scenario.seed, initial_pos_ned_m=scenario.start_pos_ned_m,
        initial_yaw_deg=scenario.yaw_deg, params=params,
    )  # fmt: skip


@dataclass(frozen=True)
class ControlSchedule:
    """Physics steps per control step for a pilot at control_hz over physics at rate_hz (see the module doc).
    `k0`: the phase on a longer global schedule (a vector env's copies step on one clock)."""

    rate_hz: float
    control_hz: float
    k0: int = 0

    def __post_init__(self) -> None:
        if not (
            self.rate_hz > 0.0 and self.control_hz > 0.0 and math.isfinite(self.rate_hz / self.control_hz)
        ):
            raise ValueError(f"control schedule needs positive rates, got {self.rate_hz}, {self.control_hz}")

    def steps(self, k: int) -> int:
        """Physics steps in control step k (counted from this schedule's k0)."""
        r = self.rate_hz / self.control_hz
        g = self.k0 + k
        return max(1, round((g + 1) * r) - round(g * r))


def prepare(
    vehicle: Vehicle,
    scenario: Scenario,
    *,
    baseline_params: Mapping[str, float] | None = None,
    footage_offset_s: float | None = None,
) -> None:
    """Put `vehicle` in the scenario's start situation: parameters (back to `baseline_params` first, for a vehicle
    that flew before), the footage clock (`footage_offset_s`, default the scenario's footage_time_s), physics seed,
    start pose and a fresh autopilot."""
    params = vehicle.params
    if baseline_params is not None:
        for name, value in baseline_params.items():
            if params.stored(name) != value:
                params.set(name, value)
    for name, value in scenario.all_params():
        params.set(name, value)
    vehicle.sim.footage_offset_s = scenario.footage_time_s if footage_offset_s is None else footage_offset_s
    vehicle.reset(
        seed=scenario.seed, pos_ned_m=scenario.start_pos_ned_m, yaw_rad=math.radians(scenario.yaw_deg)
    )


class Episode:
    """A scenario flown on a vehicle, judged by a TrialMonitor. `gcs=True`: the episode is the ground station
    whose heartbeats a gcs_link_lost failure stops (in-process pilots); over MAVLink the pilot is the ground
    station (gcs=False). `prepare_vehicle=False`: the caller already called `prepare` (a vector env binding the
    copy's footage first)."""

    def __init__(
        self,
        vehicle: Vehicle,
        scenario: Scenario,
        limits: Limits,
        *,
        gcs: bool = True,
        baseline_params: Mapping[str, float] | None = None,
        prepare_vehicle: bool = True,
    ) -> None:
        if prepare_vehicle:
            prepare(vehicle, scenario, baseline_params=baseline_params)
        if vehicle.sim.footage_offset_s != scenario.footage_time_s:
            # the footage clock this vehicle flies is the one the scores are judged against
            scenario = dataclasses.replace(scenario, footage_time_s=vehicle.sim.footage_offset_s)
        self.vehicle = vehicle
        self.scenario = scenario
        self.limits = limits
        self.monitor = TrialMonitor(scenario, limits, gcs=gcs)
        self.monitor.start(vehicle)
        self._announced = 0  # monitor events already announced
        self._repeat_s = math.inf
        self._awaiting: tuple[int, str] | None = None  # since "land now": (autopilot commands, mode) then

    # --- state ----------------------------------------------------------------------------------------
    @property
    def log(self) -> TrialLog:
        return self.monitor.log

    @property
    def done(self) -> bool:
        return self.monitor.log.end is not None

    @property
    def t_s(self) -> float:
        """Seconds since the episode started (the scenario's clock)."""
        return self.monitor.t_of(self.vehicle.state)

    @property
    def footage_time_s(self) -> float:
        return self.vehicle.sim.footage_time_s()

    def schedule(self, control_hz: float, k0: int = 0) -> ControlSchedule:
        return ControlSchedule(1.0 / self.vehicle.dt_s, control_hz, k0)

    # --- stepping -------------------------------------------------------------------------------------
    def step(self, cmd: EavCommand | None = None) -> None:
        """One physics step (the autopilot's, or `cmd` with the autopilot bypassed), the autopilot's events into
        the trial's, then the referee's judgement and the scenario's announcements."""
        v = self.vehicle
        if cmd is None:
            v.step()
        else:
            v.step_command(cmd)
        for e in v.autopilot.pop_events():
            self.record_autopilot_event(int(e.severity), e.text)
        self.after_step()

    def after_step(self) -> None:
        """The referee after a physics step someone else took (the app's paced loop), then the announcements."""
        m = self.monitor
        if m.log.end is not None:
            return
        m.after_step(self.vehicle)
        ev = m.log.events
        ap = self.vehicle.autopilot
        while self._announced < len(ev):  # land-now and injected failures: told as PX4 would tell a pilot
            e = ev[self._announced]
            self._announced += 1
            if e["kind"] in (EventKind.LAND_NOW, EventKind.FAILURE):
                ap.announce(Severity(e["severity"]), e["text"])
            if e["kind"] == EventKind.LAND_NOW:
                self._repeat_s = e["t_s"] + LAND_NOW_REPEAT_S
                self._awaiting = (ap.commands, ap.mode.name)
        if self._awaiting is not None and m.log.end is None:
            t = m.t_of(self.vehicle.state)
            commands, mode = self._awaiting
            if ap.commands != commands:
                self._awaiting = None
                m.log.reaction_t_s = round(t, 6)
                m.event(
                    t,
                    EventKind.REACTION,
                    f"the pilot's first command after land now: {t - (m.log.land_now_t_s or 0.0):.3f} s later",
                )
            elif ap.mode.name != mode:
                self._awaiting = (
                    None  # landing already (the pilot's mode change is a command; a failsafe's is not)
                )
            elif t >= self._repeat_s:  # not heard yet, or not acted on: say it again
                self._repeat_s = t + LAND_NOW_REPEAT_S
                ap.announce(Severity.ALERT, LAND_NOW_TEXT)

    def record_autopilot_event(self, severity: int, text: str) -> None:
        """A STATUSTEXT the vehicle sent (popped by the stepper, or heard by the MAVLink endpoint's listener) into
        the trial's events; the episode's own announcements are already there."""
        if text == LAND_NOW_TEXT or text.startswith(INJECTED_PREFIX):
            return
        self.monitor.record_autopilot_event(self.vehicle.time_s, severity, text)

    def end(self, end: TrialEnd, detail: str) -> None:
        """End the episode from outside (a pilot error, an interrupted run)."""
        self.monitor.end(self.vehicle, end, detail)

    # --- result ---------------------------------------------------------------------------------------
    def row(self, world: WorldModel, spec: TrialSpec) -> ScoreRow:
        """The score row of the trial (final once `done`): viva_sitl.evaluation.scoring.score_trial."""
        return score_trial(self.scenario, self.monitor.log, world, spec)


__all__ = [
    "LAND_NOW_REPEAT_S",
    "ControlSchedule",
    "Episode",
    "limits_of",
    "prepare",
    "scenario_config",
]
