"""Reward of the landing environments: the landing trials' scores (viva_sitl.evaluation.scoring), plus shaping from the
same quantities while flying.

Termination is the trials' TrialMonitor's (viva_sitl.evaluation.monitor): landed (touchdown + disarm; the env
disarms at the first control step on the ground, as a pilot would), crash (touchdown faster than the spec's
crash_speed_m_s), left_footage, and timeout (-> truncated). At the end the env computes the trial's score row with
`score_trial` (the row `viva-sitl trials run` writes; `info["trial"]`) and the Scorer turns it into the terminal
reward.

SEAM: the environments call a `Scorer`: reset(scenario, state, footage_time_s) at the start of an episode,
step(state, footage_time_s) -> StepScore once per env step (shaping; StepScore.terminated = True ends the episode
early, e.g. a custom curriculum), final(row) -> terminal reward once, with the trial's score row.

The default `LandingReward` (weights in RewardConfig, all >= 0; the thresholds are the spec's criterion):
- every step: descent_weight x (altitude lost this step / start altitude) (sums to descent_weight over a full
  descent, whatever the path); - time_weight x dt; - risk_weight x (risk level under the vehicle - 1) / 4 x dt;
  below the spec's final_descent_below_m: - people_weight x max(0, 1 - distance to the nearest person /
  min_dist_person_m) x dt.
- at the end: landed -> + landed_bonus, + success_bonus when the criterion holds (row["success"]); crash ->
  - crash_penalty; left_footage -> - out_penalty; timeout -> - timeout_penalty; with a touchdown: - touchdown_weight
  x touchdown speed (m/s), - touchdown_risk_weight x (risk level - 1), - touchdown_people_weight x metres inside
  min_dist_person_m (minimum over the final descent).
Every component is in `StepScore.info` (the env's info["score"]).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

from viva_sitl.dynamics import EavState
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.spec import Scenario, TrialSpec
from viva_sitl.world import PEOPLE, WorldModel


@dataclass(frozen=True)
class RewardConfig:
    success_bonus: float = 100.0  # the spec's criterion holds (landed, slow, away from people, low risk)
    landed_bonus: float = 20.0  # touchdown + disarm, whatever the criterion says
    crash_penalty: float = 50.0
    out_penalty: float = 100.0  # left the footage
    timeout_penalty: float = 50.0
    touchdown_weight: float = 5.0  # per m/s of touchdown speed
    touchdown_risk_weight: float = 5.0  # per risk level above 1 under the touchdown point
    touchdown_people_weight: float = 5.0  # per metre inside the criterion's min_dist_person_m
    descent_weight: float = 10.0  # total shaping over a full descent from the start altitude
    time_weight: float = 0.1  # per second flown
    risk_weight: float = 1.0  # per second over level-5 ground (scaled by (level - 1) / 4)
    people_weight: float = 2.0  # per second right above a person in the final descent (scaled by closeness)

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"RewardConfig.{name} must be a finite number >= 0, got {value!r}")


@dataclass
class StepScore:
    reward: float
    terminated: bool = False
    info: dict[str, Any] = field(default_factory=dict)


class Scorer(Protocol):
    def reset(self, scenario: Scenario, state: EavState, footage_time_s: float) -> None: ...

    def step(self, state: EavState, footage_time_s: float) -> StepScore: ...

    def final(self, row: dict[str, Any]) -> float: ...


class LandingReward:
    """The default Scorer over a WorldModel (risk map + people tracks) and a TrialSpec's criterion; pure queries."""

    def __init__(self, world: WorldModel, spec: TrialSpec, config: RewardConfig | None = None) -> None:
        self.world = world
        self.config = config or RewardConfig()
        self.criterion = spec.criterion
        self.final_descent_below_m = spec.final_descent_below_m
        self.people_m = spec.criterion.min_dist_person_m or 5.0
        self._start_alt_m = 1.0
        self._prev_alt_m = 0.0
        self._prev_time_s = 0.0

    def reset(self, scenario: Scenario, state: EavState, footage_time_s: float) -> None:
        self._start_alt_m = max(state.altitude_m, 1e-3)
        self._prev_alt_m = state.altitude_m
        self._prev_time_s = state.time_s

    def people_distance_m(self, north_m: float, east_m: float, footage_time_s: float) -> float:
        if not self.world.has_objects:
            return math.inf
        hit = self.world.tracks.nearest(north_m, east_m, footage_time_s, PEOPLE)
        return math.inf if hit is None else hit.distance_m

    def step(self, state: EavState, footage_time_s: float) -> StepScore:
        c = self.config
        n, e = float(state.pos_ned_m[0]), float(state.pos_ned_m[1])
        alt = state.altitude_m
        dt = state.time_s - self._prev_time_s
        risk = self.world.risk_at(n, e, footage_time_s) if self.world.has_risk_map else 1
        descent = c.descent_weight * (self._prev_alt_m - alt) / self._start_alt_m
        risk_cost = c.risk_weight * (risk - 1) / 4.0 * dt
        people_cost = 0.0
        if c.people_weight > 0 and alt < self.final_descent_below_m:
            d = self.people_distance_m(n, e, footage_time_s)
            people_cost = c.people_weight * max(0.0, 1.0 - d / self.people_m) * dt
        self._prev_alt_m, self._prev_time_s = alt, state.time_s
        reward = descent - risk_cost - people_cost - c.time_weight * dt
        info = {"risk_level": risk, "descent": descent, "risk_cost": risk_cost, "people_cost": people_cost}
        return StepScore(reward, False, info)

    def final(self, row: dict[str, Any]) -> float:
        c = self.config
        end = row["end"]
        r = 0.0
        if end == TrialEnd.LANDED:
            r += c.landed_bonus + (c.success_bonus if row["success"] else 0.0)
        elif end == TrialEnd.CRASH:
            r -= c.crash_penalty
        elif end == TrialEnd.LEFT_FOOTAGE:
            r -= c.out_penalty
        elif end == TrialEnd.TIMEOUT:
            r -= c.timeout_penalty
        if row["touchdown_speed_m_s"] is not None:
            r -= c.touchdown_weight * row["touchdown_speed_m_s"]
            if row["risk_level"] is not None:
                r -= c.touchdown_risk_weight * (row["risk_level"] - 1)
            d = row["min_dist_person_m"] if row["min_dist_person_m"] is not None else row["dist_person_m"]
            if d is not None:
                r -= c.touchdown_people_weight * max(0.0, self.people_m - d)
        return r


__all__ = ["LandingReward", "RewardConfig", "Scorer", "StepScore"]
