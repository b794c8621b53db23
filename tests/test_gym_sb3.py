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
