"""Gymnasium environments (optional extra `gym`): importing this module registers them.

    import gymnasium as gym
    import viva_sitl.gym  # noqa: F401  (registers the ids below)
    env = gym.make("viva_sitl/Landing-v0", footage="synthetic")

- viva_sitl/Landing-v0: Dict(image, state) observation, viva-safeland's normalised attitude/thrust actions.
- viva_sitl/LandingVelocity-v0: the same observation, velocity setpoints through the autopilot (OFFBOARD).
- viva_sitl/LandingState-v0: state vector only (nothing rendered), attitude actions.
- viva_sitl/LandingStateVelocity-v0: state vector only, velocity setpoints.
Vectorized over one shared footage decode: `SharedFootageVectorEnv` (or gymnasium.make_vec(id, num_envs,
vectorization_mode="vector_entry_point")).
Scenarios, termination and scores are the landing trials' (viva_sitl.evaluation): `spec=` a trials TOML or
TrialSpec, reset(seed=s) flies what `viva-sitl trials run SPEC --seed s` flies, info["trial"] at the end is its score
row. Seams: `Scorer` (scoring.py: reward) and `ScenarioDrawer` (scenario.py). Settings: `LandingEnvConfig`
(config.py: observation / action / termination / scenario groups; the flat keyword arguments build it); action
modes: `ActionMode` objects (actions.py).
"""

from __future__ import annotations

try:
    import gymnasium
except ImportError as exc:  # pragma: no cover - depends on the install
    raise ImportError("viva_sitl.gym needs gymnasium: pip install 'viva-sitl[gym]'") from exc

from viva_sitl.gym.actions import ActionMode, AttitudeMode, VelocityMode, land_assist_limits
from viva_sitl.gym.config import (
    STATE_FIELDS,
    ActionConfig,
    LandingEnvConfig,
    ObservationConfig,
    ScenarioConfig,
    TerminationConfig,
    ground_truth_fields,
)
from viva_sitl.gym.env import FootageBinding, LandingEnv, overview_rgb
from viva_sitl.gym.scenario import Scenario, ScenarioDrawer, SpecScenarioDrawer, TrialSpec, default_spec
from viva_sitl.gym.scoring import LandingReward, RewardConfig, Scorer, StepScore
from viva_sitl.gym.vector import SharedFootageVectorEnv

_VARIANTS = {
    "viva_sitl/Landing-v0": {},
    "viva_sitl/LandingVelocity-v0": {"action_mode": "velocity"},
    "viva_sitl/LandingState-v0": {"observation": "state"},
    "viva_sitl/LandingStateVelocity-v0": {"observation": "state", "action_mode": "velocity"},
}

for _id, _kwargs in _VARIANTS.items():
    if _id not in gymnasium.registry:
        gymnasium.register(
            id=_id,
            entry_point="viva_sitl.gym.env:LandingEnv",
            vector_entry_point="viva_sitl.gym.vector:SharedFootageVectorEnv",
            kwargs=dict(_kwargs),
        )

__all__ = [
    "STATE_FIELDS",
    "ActionConfig",
    "ActionMode",
    "AttitudeMode",
    "FootageBinding",
    "LandingEnv",
    "LandingEnvConfig",
    "LandingReward",
    "ObservationConfig",
    "RewardConfig",
    "Scenario",
    "ScenarioConfig",
    "ScenarioDrawer",
    "Scorer",
    "SharedFootageVectorEnv",
    "SpecScenarioDrawer",
    "StepScore",
    "TerminationConfig",
    "TrialSpec",
    "VelocityMode",
    "default_spec",
    "ground_truth_fields",
    "land_assist_limits",
    "overview_rgb",
]
