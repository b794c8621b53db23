"""Scenario drawing for the Gymnasium environments: everything `reset(seed)` randomises, drawn in ONE place.

    ranges = ScenarioRanges(alt_m=(20.0, 60.0))
    scenario = draw_scenario(np.random.default_rng(seed), ranges, footage.geometry, footage.duration_s)

SEAM: `ScenarioDrawer` (a callable `(rng, geometry, duration_s) -> Scenario`) is what the environments call;
`RangeScenarioDrawer` (this module) is the default. The landing-trials runner's scenario drawer
(viva_sitl.evaluation) can replace it by passing `scenario_drawer=` to the environment, so that `reset(seed=k)` flies
trial k's scenario. Pure: no I/O, the only randomness is the generator passed in.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from viva_sitl.footage.geometry import FootageGeometry


@dataclass(frozen=True)
class Scenario:
    """One episode's start: NED pose (air start, at rest), footage time offset (s) and the wind (SIM_* values)."""

    pos_ned_m: tuple[float, float, float]
    yaw_rad: float
    footage_offset_s: float
    wind_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)
    gust_std_m_s: float = 0.0


@dataclass(frozen=True)
class ScenarioRanges:
    """Uniform ranges of the default drawer. `xy_frac`: start north/east within +-xy_frac x half the footage's
    smaller ground side (`xy_m` instead for an unbounded ground, e.g. the synthetic field). `footage_offsets_s`: the
    footage time offsets a start may take (None: [0, 0] only; a small set keeps vector copies sharing decoded
    frames, see viva_sitl.gym.vector); `offset_slots` > 0 instead spreads that many offsets evenly over the
    footage's duration."""

    alt_m: tuple[float, float] = (20.0, 40.0)
    xy_frac: float = 0.5
    xy_m: float = 30.0
    yaw_rad: tuple[float, float] = (-math.pi, math.pi)
    footage_offsets_s: tuple[float, ...] | None = None
    offset_slots: int = 1
    wind_speed_m_s: tuple[float, float] = (0.0, 0.0)
    gust_std_m_s: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        lo, hi = self.alt_m
        if not (0.0 < lo <= hi and math.isfinite(hi)):
            raise ValueError(f"ScenarioRanges.alt_m must be 0 < low <= high, got {self.alt_m}")
        if not (0.0 <= self.xy_frac <= 1.0) or not (self.xy_m >= 0.0):
            raise ValueError("ScenarioRanges: xy_frac must be in [0, 1] and xy_m >= 0")
        if self.offset_slots < 1:
            raise ValueError(f"ScenarioRanges.offset_slots must be >= 1, got {self.offset_slots}")
        for name in ("yaw_rad", "wind_speed_m_s", "gust_std_m_s"):
            a, b = getattr(self, name)
            if not (math.isfinite(a) and math.isfinite(b) and a <= b):
                raise ValueError(f"ScenarioRanges.{name} must be finite with low <= high, got {(a, b)}")
        if self.wind_speed_m_s[0] < 0.0 or self.gust_std_m_s[0] < 0.0:
            raise ValueError("ScenarioRanges: wind speed and gust std must be >= 0")

    def offsets(self, duration_s: float) -> tuple[float, ...]:
        """The footage time offsets a start may take."""
        if self.footage_offsets_s is not None:
            return self.footage_offsets_s or (0.0,)
        k = self.offset_slots
        return tuple(duration_s * i / k for i in range(k))


ScenarioDrawer = Callable[[np.random.Generator, FootageGeometry, float], Scenario]


class RangeScenarioDrawer:
    """The default ScenarioDrawer: uniform draws from ScenarioRanges (order of draws fixed: see __call__)."""

    def __init__(self, ranges: ScenarioRanges | None = None) -> None:
        self.ranges = ranges or ScenarioRanges()

    def __call__(self, rng: np.random.Generator, geometry: FootageGeometry, duration_s: float) -> Scenario:
        r = self.ranges
        half = (
            r.xy_m
            if geometry.unbounded
            else r.xy_frac * 0.5 * min(geometry.ground_width_m, geometry.ground_height_m)
        )
        north, east = (float(v) for v in rng.uniform(-half, half, 2))
        alt = float(rng.uniform(*r.alt_m))
        yaw = float(rng.uniform(*r.yaw_rad))
        offsets = r.offsets(duration_s)
        offset = float(offsets[int(rng.integers(len(offsets)))])
        speed = float(rng.uniform(*r.wind_speed_m_s))
        heading = float(rng.uniform(-math.pi, math.pi))
        gust = float(rng.uniform(*r.gust_std_m_s))
        return Scenario(
            pos_ned_m=(north, east, -alt),
            yaw_rad=yaw,
            footage_offset_s=offset,
            wind_ned_m_s=(speed * math.cos(heading), speed * math.sin(heading), 0.0),
            gust_std_m_s=gust,
        )


__all__ = ["RangeScenarioDrawer", "Scenario", "ScenarioDrawer", "ScenarioRanges"]
