"""Reward and termination of the landing environments, from the world's ground truth (viva_sitl.world).

SEAM: the environments call a `Scorer` (reset(state, footage_time_s) at the start of an episode, then
score(state, footage_time_s, inside) -> StepScore once per environment step). `LandingScorer` (this module) is the
default; the landing-trials runner's scorer (viva_sitl.evaluation) can replace it via `scorer=` as long as it
follows this protocol.

The default landing score (all weights and limits in LandingScoreConfig):
- every step: -step_penalty, plus shaping: descent_weight x (altitude lost this step / start altitude) (sums to
  descent_weight over a full descent, whatever the path), minus risk_weight x (risk level under the vehicle - 1) / 4
  x dt (flying over risky ground costs, per second).
- touchdown (first ground contact) ends the episode: +land_bonus when SAFE (touchdown speed <= max_touchdown_m_s,
  risk level at the touchdown point <= max_risk_level, nearest person >= min_people_distance_m), else
  -unsafe_penalty; in both cases minus speed_weight x touchdown speed and minus people_weight x max(0,
  min_people_distance_m - distance to the nearest person).
- leaving the footage (the geofence) ends the episode with -out_penalty.
Every component is in `StepScore.info` (what the env puts in `info["score"]`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any, Protocol

from viva_sitl.dynamics import EavState
from viva_sitl.world import PEOPLE, WorldModel


@dataclass(frozen=True)
class LandingScoreConfig:
    max_touchdown_m_s: float = 1.0  # a safe touchdown is at most this fast (m/s)
    max_risk_level: int = 2  # ... on ground of at most this risk level (1..5)
    min_people_distance_m: float = 5.0  # ... at least this far from the nearest person (m)
    land_bonus: float = 100.0
    unsafe_penalty: float = 50.0
    out_penalty: float = 100.0
    speed_weight: float = 10.0  # per m/s of touchdown speed
    people_weight: float = 10.0  # per metre inside min_people_distance_m
    risk_weight: float = 1.0  # per second over level-5 ground (scaled by (level - 1) / 4)
    descent_weight: float = 10.0  # total shaping over a full descent from the start altitude
    step_penalty: float = 0.01

    def __post_init__(self) -> None:
        for name, value in vars(self).items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"LandingScoreConfig.{name} must be a finite number >= 0, got {value!r}")
        if not 1 <= self.max_risk_level <= 5:
            raise ValueError(f"LandingScoreConfig.max_risk_level must be 1..5, got {self.max_risk_level}")


@dataclass
class StepScore:
    reward: float
    terminated: bool
    info: dict[str, Any] = field(default_factory=dict)


class Scorer(Protocol):
    def reset(self, state: EavState, footage_time_s: float) -> None: ...

    def score(self, state: EavState, footage_time_s: float, inside: bool) -> StepScore: ...


class LandingScorer:
    """The default Scorer over a WorldModel (risk map + people tracks); pure queries, no I/O."""

    def __init__(self, world: WorldModel, config: LandingScoreConfig | None = None) -> None:
        self.world = world
        self.config = config or LandingScoreConfig()
        self._start_alt_m = 1.0
        self._prev_alt_m = 0.0
        self._prev_time_s = 0.0

    def reset(self, state: EavState, footage_time_s: float) -> None:
        self._start_alt_m = max(state.altitude_m, 1e-3)
        self._prev_alt_m = state.altitude_m
        self._prev_time_s = state.time_s

    def people_distance_m(self, north_m: float, east_m: float, footage_time_s: float) -> float:
        hit = self.world.tracks.nearest(north_m, east_m, footage_time_s, PEOPLE)
        return math.inf if hit is None else hit.distance_m

    def score(self, state: EavState, footage_time_s: float, inside: bool) -> StepScore:
        c = self.config
        n, e = float(state.pos_ned_m[0]), float(state.pos_ned_m[1])
        risk = self.world.risk_at(n, e, footage_time_s)
        dt = state.time_s - self._prev_time_s
        descent = c.descent_weight * (self._prev_alt_m - state.altitude_m) / self._start_alt_m
        risk_cost = c.risk_weight * (risk - 1) / 4.0 * dt
        self._prev_alt_m, self._prev_time_s = state.altitude_m, state.time_s
        reward = descent - risk_cost - c.step_penalty
        info: dict[str, Any] = {"risk_level": risk, "descent": descent, "risk_cost": risk_cost}
        if state.touchdown_speed_m_s is not None:
            speed = float(state.touchdown_speed_m_s)
            people = self.people_distance_m(n, e, footage_time_s)
            safe = (
                speed <= c.max_touchdown_m_s
                and risk <= c.max_risk_level
                and people >= c.min_people_distance_m
            )
            outcome = c.land_bonus if safe else -c.unsafe_penalty
            too_close = max(0.0, c.min_people_distance_m - people)
            reward += outcome - c.speed_weight * speed - c.people_weight * too_close
            info.update(
                outcome="safe_landing" if safe else "unsafe_landing",
                touchdown_speed_m_s=speed,
                people_distance_m=people,
                safe=safe,
            )
            return StepScore(reward, True, info)
        if not inside:
            info["outcome"] = "left_footage"
            return StepScore(reward - c.out_penalty, True, info)
        return StepScore(reward, False, info)


__all__ = ["LandingScoreConfig", "LandingScorer", "Scorer", "StepScore"]
