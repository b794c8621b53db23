"""The stable-baselines3 example (examples/train_sb3_landing.py) trains a few hundred steps, and the saved policy loads
and flies the trials' scenarios through bench/bench_rl.py's evaluation (the trials' score rows). The real training
and its comparison with random and `descend` are bench/bench_rl.py's (bench/results_gym.md), not CI's."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

pytest.importorskip("gymnasium")
pytest.importorskip(
    "stable_baselines3", reason="stable-baselines3 not installed (pip install 'viva-sitl[rl]')"
)

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples"))
sys.path.insert(0, str(REPO / "bench"))

import bench_rl  # noqa: E402
import train_sb3_landing as example  # noqa: E402

from viva_sitl.evaluation.scoring import COLUMNS  # noqa: E402
from viva_sitl.evaluation.spec import draw_scenarios, load_spec  # noqa: E402


def test_example_trains_saves_and_the_bench_evaluates_the_policy(tmp_path: Path) -> None:
    out = tmp_path / "policy"
    meta = example.train(out, total_steps=200, minutes=10.0, learning_starts=50, log_every_s=1e9)
    assert meta["steps"] == 200 and (tmp_path / "policy.zip").is_file()
    assert json.loads((tmp_path / "policy.json").read_text())["steps"] == 200
    spec = load_spec(example.SPEC)
    scenarios = draw_scenarios(spec, n=2, seed=0)
    policy = bench_rl.sb3_policy(tmp_path / "policy.zip")
    rows = bench_rl.evaluate_gym(policy, example.SPEC, 2, 0, scenarios, max_episode_s=5.0)
    assert [r["trial"] for r in rows] == [0, 1] and [r["seed"] for r in rows] == [s.seed for s in scenarios]
    assert all(set(COLUMNS) <= set(r) for r in rows)
    assert all(r["end"] in ("landed", "crash", "left_footage", "timeout") for r in rows)
    # deterministic policy, same scenarios: the same rows again
    again = bench_rl.evaluate_gym(policy, example.SPEC, 2, 0, scenarios, max_episode_s=5.0)
    assert again == rows
    summary = bench_rl.summary(rows, spec.criterion.describe())
    assert summary["n"] == 2 and 0.0 <= summary["landed_rate"] <= 1.0


def test_privileged_ground_truth_policy_trains_checkpoints_and_flies_in_the_bench(tmp_path: Path) -> None:
    """--ground-truth-obs: the example trains on the 62-number observation (state + the env's privileged risk grid and
    nearest person), checkpoints, and the bench flies the saved policy in the env it was trained in (its .json)."""
    out = tmp_path / "gt"
    kw = {**example.ENV_KWARGS, "action_mode": "velocity_land", "land_xy_m_s": 0.0, "ground_truth_obs": True}
    meta = example.train(
        out, total_steps=120, minutes=10.0, learning_starts=40, log_every_s=1e9, env_kwargs=kw,
        net_arch=(32, 32), checkpoint_every_s=0.0,
    )  # fmt: skip
    assert meta["steps"] == 120 and meta["env_kwargs"]["ground_truth_obs"] is True
    assert list(tmp_path.glob("gt_*.zip")), "no checkpoint written"
    env_kw = bench_rl.model_env_kwargs(tmp_path / "gt.zip")
    assert env_kw == kw
    env = example.make_env(env_kwargs=env_kw)
    assert env.observation_space.shape == (62,)
    obs, _ = env.reset(seed=0)
    assert float(obs[10:59].min()) >= 0.2 and float(obs[10:59].max()) <= 1.0  # risk levels 1..5 / 5
    env.close()
    spec = load_spec(example.SPEC)
    scenarios = draw_scenarios(spec, n=1, seed=0)
    policy = bench_rl.sb3_policy(tmp_path / "gt.zip")
    rows = bench_rl.evaluate_gym(policy, example.SPEC, 1, 0, scenarios, max_episode_s=3.0, env_kwargs=env_kw)
    assert rows[0]["trial"] == 0 and rows[0]["end"] in ("landed", "crash", "left_footage", "timeout")
