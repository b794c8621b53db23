"""LandingEnv's FuncEnv-style shape: settings as config dataclasses (the flat keyword arguments build the same
config), action modes as objects, and a vector env that drives its copies through public members only."""

from __future__ import annotations

import ast
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import viva_sitl.gym  # noqa: E402,F401  (registers the ids)
from viva_sitl.gym import (  # noqa: E402
    ActionConfig,
    AttitudeMode,
    LandingEnv,
    LandingEnvConfig,
    ObservationConfig,
    SharedFootageVectorEnv,
    TerminationConfig,
    VelocityMode,
)
from viva_sitl.gym.actions import ACTION_MODE_TYPES, action_mode  # noqa: E402
from viva_sitl.gym.config import ACTION_MODES, FLAT_KWARGS  # noqa: E402

VECTOR_PY = Path(viva_sitl.gym.__file__).with_name("vector.py")

CFG = LandingEnvConfig(
    action=ActionConfig(mode="velocity_land", land_xy_m_s=0.5, max_speed_m_s=4.0),
    observation=ObservationConfig(kind="state", ground_truth_obs=True, ground_grid=3),
    termination=TerminationConfig(max_episode_s=8.0),
    control_hz=10.0,
)
FLAT: dict[str, Any] = {
    "action_mode": "velocity_land",
    "land_xy_m_s": 0.5,
    "max_speed_m_s": 4.0,
    "observation": "state",
    "ground_truth_obs": True,
    "ground_grid": 3,
    "max_episode_s": 8.0,
    "control_hz": 10.0,
}


def _flight(env: LandingEnv, steps: int) -> list[tuple[bytes, float, bool, bool]]:
    out = [(env.reset(seed=4)[0].tobytes(), 0.0, False, False)]
    for k in range(steps):
        obs, r, term, trunc, _ = env.step(np.array([0.3, -0.2, 0.9, 0.1 * (k % 3)]))
        out.append((obs.tobytes(), r, term, trunc))
    env.close()
    return out


def test_flat_keyword_arguments_build_the_same_config_and_flight() -> None:
    by_config = LandingEnv("synthetic", env_config=CFG)
    by_kwargs = LandingEnv("synthetic", **FLAT)
    assert by_kwargs.config == by_config.config == CFG
    assert by_kwargs.observation_space == by_config.observation_space
    assert by_config.action_mode == "velocity_land" and by_config.control_hz == 10.0
    assert by_config.max_episode_s == 8.0 and by_config.state_fields[-1] == "person_dist_m"
    assert _flight(by_config, 40) == _flight(by_kwargs, 40)
    # flat keyword arguments override the env_config's fields, the rest of the group kept
    mixed = LandingEnv("synthetic", env_config=CFG, observation="image+state", image_size=(32, 24))
    assert mixed.config.observation == ObservationConfig(
        kind="image+state", image_size=(32, 24), ground_truth_obs=True, ground_grid=3
    )
    assert mixed.config.action == CFG.action
    obs, _ = mixed.reset(seed=1)
    assert obs["image"].shape == (24, 32, 3) and obs["state"].shape == (10 + 9 + 3,)
    mixed.close()
    # gymnasium.make ids take both
    env = gym.make(
        "viva_sitl/LandingStateVelocity-v0", footage="synthetic", env_config=CFG, action_mode="attitude"
    )
    assert env.unwrapped.config.action.mode == "attitude"
    assert (
        env.unwrapped.config.observation.kind == "state"
    )  # the id's own setting (flat) wins over env_config
    env.close()
    # and the vector env's copies
    venv = SharedFootageVectorEnv(2, footage="synthetic", env_config=CFG)
    assert all(e.config.action == CFG.action and e.config.observation == CFG.observation for e in venv.envs)
    venv.reset(seed=0)
    venv.step(np.zeros((2, 4)))
    venv.close()


def test_unknown_settings_and_bad_values_get_one_line() -> None:
    with pytest.raises(TypeError, match="unexpected keyword argument 'actoin_mode'"):
        LandingEnv("synthetic", actoin_mode="velocity")
    with pytest.raises(TypeError, match="actoin_mode"):
        gym.make("viva_sitl/Landing-v0", footage="synthetic", actoin_mode="velocity")
    with pytest.raises(ValueError, match="action_mode must be one of"):
        ActionConfig(mode="rate")
    with pytest.raises(ValueError, match="out_of_range"):
        LandingEnv("synthetic", out_of_range="wrap")
    with pytest.raises(ValueError, match="observation must be one of"):
        ObservationConfig(kind="image")
    with pytest.raises(ValueError, match="8x8"):
        LandingEnv("synthetic", env_config=LandingEnvConfig(), image_size=(4, 4))
    with pytest.raises(ValueError, match="positive"):
        TerminationConfig(max_episode_s=0.0)
    with pytest.raises(ValueError, match="positive"):
        LandingEnvConfig(control_hz=math.nan)
    with pytest.raises(ValueError, match="land_xy_m_s"):
        ActionConfig(land_xy_m_s=-1.0)
    # a FLAT_KWARGS entry names a real field of its group
    for name, (group, attr) in FLAT_KWARGS.items():
        target = LandingEnvConfig() if group is None else getattr(LandingEnvConfig(), group)
        assert hasattr(target, attr), name


def test_action_modes_are_objects_one_per_name() -> None:
    assert set(ACTION_MODE_TYPES) == set(ACTION_MODES)
    for name in ACTION_MODES:
        assert action_mode(ActionConfig(mode=name)).name == name
    assert isinstance(LandingEnv("synthetic", observation="state").actions, AttitudeMode)
    land = LandingEnv("synthetic", observation="state", action_mode="velocity_land").actions
    assert isinstance(land, VelocityMode) and land.land_assist
    plain = LandingEnv("synthetic", observation="state", action_mode="velocity").actions
    assert isinstance(plain, VelocityMode) and not plain.land_assist
    # the attitude mode integrates its yaw command from the scenario's yaw
    env = LandingEnv("synthetic", observation="state", max_yaw_rate_deg_s=90.0)
    env.reset(seed=0)
    mode = env.actions
    assert isinstance(mode, AttitudeMode)
    assert env.scenario is not None and mode.yaw_cmd_rad == pytest.approx(math.radians(env.scenario.yaw_deg))
    env.step(np.array([0.0, 0.0, 1.0, 0.0]))  # +a2: counter-clockwise seen from above (yaw decreases)
    step_s = 9 / 250.0 if env.schedule.steps(0) == 9 else 8 / 250.0
    expected = math.remainder(math.radians(env.scenario.yaw_deg) - math.radians(90.0) * step_s, 2 * math.pi)
    assert mode.yaw_cmd_rad == pytest.approx(expected)
    env.close()


def test_vector_env_drives_its_copies_through_public_members_only() -> None:
    """No `x._name` on anything but the vector env itself, and no attribute written on anything else (the
    copies' clock, footage and view slot go through LandingEnv's footage_clock seam and method arguments)."""
    tree = ast.parse(VECTOR_PY.read_text())
    private, writes = [], []
    for node in ast.walk(tree):
        if isinstance(node, ast.Attribute):
            owner = node.value.id if isinstance(node.value, ast.Name) else ast.unparse(node.value)
            if node.attr.startswith("_") and not node.attr.startswith("__") and owner != "self":
                private.append(f"{node.lineno}: {ast.unparse(node)}")
            if isinstance(node.ctx, ast.Store) and owner != "self":
                writes.append(f"{node.lineno}: {ast.unparse(node)}")
    assert private == [] and writes == []
