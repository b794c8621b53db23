"""Scenario drawing for the Gymnasium environments: the landing trials' drawing (viva_sitl.evaluation.spec), not a copy.

    env = gymnasium.make("viva_sitl/Landing-v0", spec="configs/trials/synthetic_emergency.toml")
    env.reset(seed=s)      # the scenario `viva-sitl trials run SPEC --seed s` draws for trial 0
    env.reset()            # ... then trial 1, 2, ... of the same seed (what `--n N` flies, in order)
    env.reset(seed=s, options={"trial": k})   # trial k of seed s

A scenario is `viva_sitl.evaluation.spec.Scenario` (start pose, footage time, wind, PX4 parameters, failures, the
"land now" time, its physics seed): drawn by `draw_scenario(spec, index, seed, ...)`, a pure function of
(spec, seed, index). SEAM: `ScenarioDrawer` (a callable `(seed, index) -> Scenario`) is what the environments call;
`SpecScenarioDrawer` is the default. Without a spec the environments draw from `default_spec(footage)`: an air start
20..40 m high anywhere over the footage (10 m margin), calm air, no failures.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path

from viva_sitl.config import ConfigError
from viva_sitl.evaluation.spec import FootageBox, Scenario, TrialSpec, check_bounds, draw_scenario, load_spec

ScenarioDrawer = Callable[[int, int], Scenario]


def default_spec(footage_name: str) -> TrialSpec:
    """What the environments draw from without a spec: the trials' defaults over this footage."""
    return TrialSpec(name="gym", footage=(footage_name,), land_at_s=(0.0, 0.0))


def resolve_spec(spec: str | Path | TrialSpec) -> TrialSpec:
    return spec if isinstance(spec, TrialSpec) else load_spec(spec)


class SpecScenarioDrawer:
    """The default ScenarioDrawer: trial `index` of `seed` under a TrialSpec, over one footage (`box`: its ground)."""

    def __init__(self, spec: TrialSpec, box: FootageBox) -> None:
        if len(spec.footage) != 1:
            raise ConfigError(
                f"{spec.source or 'spec'}.scenario.footage: a gym environment flies one footage, the spec lists "
                f"{len(spec.footage)} ({', '.join(spec.footage)}): make one environment per footage"
            )
        if spec.start != ("air",):
            raise ConfigError(
                f"{spec.source or 'spec'}.scenario.start: gym environments start in the air (the policy flies the "
                f"landing), got {list(spec.start)}"
            )
        check_bounds(spec, spec.footage[0], box)
        self.spec = spec
        self.box = box
        self._bounds = {spec.footage[0]: box}

    def __call__(self, seed: int, index: int) -> Scenario:
        return draw_scenario(self.spec, index, seed, self._bounds)


def with_footage(spec: TrialSpec, footage_name: str) -> TrialSpec:
    return dataclasses.replace(spec, footage=(footage_name,))


__all__ = [
    "Scenario",
    "ScenarioDrawer",
    "SpecScenarioDrawer",
    "TrialSpec",
    "default_spec",
    "resolve_spec",
    "with_footage",
]
