"""Golden rollouts of the Gymnasium landing environments: each case's observations, rewards, terminated / truncated
flags, info times and end-of-episode score rows, for a fixed seed and action sequence, hash to the value recorded
from the code BEFORE LandingEnv's FuncEnv-style reshaping (issue 21 §3: config dataclasses, action-mode objects,
public initial / transition / observation / reward / terminal). A behaviour change in any env path (single env, each
action mode, each observation kind, ground truth, frame stacks, clipping, autoreset of the vector env, failures and
wind from a spec) changes a hash. Re-record only on a deliberate behaviour change (print `CASES[name]()` and paste it; say why in the
commit)."""

from __future__ import annotations

import hashlib
import json
import warnings
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env  # noqa: E402

import viva_sitl.gym  # noqa: E402,F401  (registers the ids)
from viva_sitl.evaluation.spec import spec_from_dict  # noqa: E402
from viva_sitl.gym import LandingEnv, SharedFootageVectorEnv  # noqa: E402

# a low start (episodes end within the rollouts: landings, crashes), wind and gusts, both failure kinds
SPEC = spec_from_dict(
    {
        "trials": {"name": "golden", "timeout_s": 12.0},
        "scenario": {
            "footage": "synthetic", "start": "air", "north_m": [-40.0, 40.0], "east_m": [-40.0, 40.0],
            "altitude_m": [3.0, 6.0], "footage_time_s": [0.0, 60.0], "land_at_s": 0.0,
            "wind_speed_m_s": [0.0, 3.0], "gust_std_m_s": [0.0, 0.5],
            "failures": [{"kind": "battery_critical", "at_s": 1.0}, {"kind": "gcs_link_lost", "at_s": 2.0}],
        },
    },
    "golden",
)  # fmt: skip


def _update(h: Any, x: Any) -> None:
    if isinstance(x, dict):
        for k in sorted(x):
            h.update(k.encode())
            _update(h, x[k])
    elif isinstance(x, np.ndarray):
        h.update(str(x.dtype).encode() + str(x.shape).encode() + np.ascontiguousarray(x).tobytes())
    else:
        h.update(np.asarray(x, dtype=np.float64).tobytes())


def _info(h: Any, info: dict[str, Any]) -> None:
    """The info's times, and the trial's score row when it ended (json: the row is numbers, strings and None)."""
    for k in ("time_s", "footage_time_s", "footage_offset_s"):
        if k in info:
            _update(h, np.asarray(info[k], dtype=np.float64))
    if "trial" in info:
        rows = info["trial"]
        h.update(json.dumps(rows, sort_keys=True, default=_jsonable).encode())


def _jsonable(x: Any) -> Any:
    return x.tolist() if isinstance(x, np.ndarray) else str(x)


def single_rollout(
    env: LandingEnv, seed: int, steps: int, action: Callable[[np.random.Generator], Any]
) -> str:
    h = hashlib.sha256()
    rng = np.random.default_rng(seed)
    obs, info = env.reset(seed=seed)
    _update(h, obs)
    _info(h, info)
    ends = 0
    for _ in range(steps):
        obs, r, term, trunc, info = env.step(action(rng))
        _update(h, obs)
        _update(h, np.array([r, term, trunc], np.float64))
        _info(h, info)
        if term or trunc:
            ends += 1
            obs, info = env.reset()
            _update(h, obs)
            _info(h, info)
    env.close()
    return f"{h.hexdigest()[:32]}/{ends}"


def vector_rollout(venv: SharedFootageVectorEnv, seed: int, steps: int, action: Callable[[np.random.Generator], Any]) -> str:  # fmt: skip
    h = hashlib.sha256()
    rng = np.random.default_rng(seed)
    obs, infos = venv.reset(seed=seed)
    _update(h, obs)
    ends = 0
    for _ in range(steps):
        obs, r, term, trunc, infos = venv.step(action(rng))
        _update(h, obs)
        _update(h, r)
        _update(h, np.concatenate([term, trunc]).astype(np.float64))
        _info(h, {k: infos[k] for k in ("time_s", "footage_time_s", "footage_offset_s")})
        if "trial" in infos:
            h.update(json.dumps(infos["trial"], sort_keys=True, default=_jsonable).encode())
        ends += int(np.count_nonzero(term | trunc))
    venv.close()
    return f"{h.hexdigest()[:32]}/{ends}"


def _attitude(rng: np.random.Generator) -> Any:
    a = rng.uniform(-1.0, 1.0, 4).astype(np.float32)
    a[3] = -0.3 * abs(a[3])
    return a


def _descend(rng: np.random.Generator) -> Any:
    a = rng.uniform(-0.4, 0.4, 4)
    a[2] = 0.8
    return a


def _wild(rng: np.random.Generator) -> Any:
    return rng.uniform(-1.6, 1.6, 4)  # clipped, info["action_clipped"]


CASES: dict[str, Callable[[], str]] = {
    "attitude-image": lambda: single_rollout(
        LandingEnv("synthetic", spec=SPEC, image_size=(64, 48)), 7, 150, _attitude
    ),
    "velocity_land-state-ground_truth": lambda: single_rollout(
        LandingEnv("synthetic", spec=SPEC, action_mode="velocity_land", observation="state",
                   ground_truth_obs=True, ground_grid=3, land_xy_m_s=0.5),
        11, 420, _descend,
    ),
    "velocity-grayscale-stack-clipped": lambda: single_rollout(
        LandingEnv("synthetic", spec=SPEC, action_mode="velocity", image_size=(48, 40), grayscale=True,
                   frame_stack=3, max_speed_m_s=4.0, max_vspeed_m_s=2.0),
        3, 400, _wild,
    ),
    "vector-velocity_land-image": lambda: vector_rollout(
        SharedFootageVectorEnv(3, footage="synthetic", spec=SPEC, image_size=(64, 48), action_mode="velocity_land"),
        2, 400, lambda rng: np.stack([_descend(rng) for _ in range(3)]),
    ),
    "vector-attitude-state-clipped": lambda: vector_rollout(
        SharedFootageVectorEnv(2, footage="synthetic", spec=SPEC, observation="state", max_tilt_deg=20.0),
        5, 150, lambda rng: np.stack([_wild(rng) * np.array([1, 1, 1, 0.4]) - np.array([0, 0, 0, 0.2])
                                      for _ in range(2)]),
    ),
}  # fmt: skip

# recorded from the pre-reshape code (6160a78), then re-recorded once for the score row's new null column
# pilot_latency_ms (schema v4; with that column removed the 6160a78 hashes matched exactly); "/n": how many episodes
# ended in the rollout
GOLDEN = {
    "attitude-image": "32b83a47d1f07a1eb2d22ebc39168c37/1",
    "velocity_land-state-ground_truth": "57a88592f89fedf915846f343b562e3f/1",
    "velocity-grayscale-stack-clipped": "76b42f3275098f3fd7a2ca26a7d2fbbd/1",
    "vector-velocity_land-image": "24200ee4982daf4373c454d96c0f8890/5",
    "vector-attitude-state-clipped": "6a92bdd7627d4d97b32fff5a89c908a8/3",
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_rollout_is_bit_identical_to_the_recorded_one(case: str) -> None:
    got = CASES[case]()
    assert not got.endswith("/0"), f"{case}: no episode ended, the case would not cover the trial's end"
    assert got == GOLDEN[case], f"{case}: rollout hash {got} != recorded {GOLDEN[case]}"


@pytest.mark.parametrize(
    "kwargs",
    [
        {"action_mode": "velocity_land", "ground_truth_obs": True, "ground_grid": 3},
        {"grayscale": True, "frame_stack": 2},
        {"action_mode": "attitude", "observation": "state", "out_of_range": "raise"},
    ],
)
def test_env_checker_passes_other_configurations(kwargs: dict[str, Any]) -> None:
    env = LandingEnv("synthetic", image_size=(48, 40), **kwargs)
    with warnings.catch_warnings():
        warnings.simplefilter(
            "ignore"
        )  # the state Box is unbounded (positions): the checker warns, not fails
        check_env(env)
    env.close()
