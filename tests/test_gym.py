"""The Gymnasium landing environments (viva_sitl.gym): API conformance, determinism, action semantics, bad input,
scoring, rendering. Flown over the synthetic field (always available) through the real Vehicle loop."""

from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env  # noqa: E402

import viva_sitl.gym  # noqa: E402,F401  (registers the ids)
from viva_sitl.config import SimConfig  # noqa: E402
from viva_sitl.dynamics import EavParams  # noqa: E402
from viva_sitl.gym import (  # noqa: E402
    LandingEnv,
    LandingScoreConfig,
    Scenario,
    ScenarioRanges,
    StepScore,
)

IDS = [
    "viva_sitl/Landing-v0",
    "viva_sitl/LandingVelocity-v0",
    "viva_sitl/LandingState-v0",
    "viva_sitl/LandingStateVelocity-v0",
]
SMALL = {"image_size": (64, 48)}


def level_start(alt_m: float = 20.0, yaw_rad: float = 0.0) -> dict[str, Any]:
    return {"scenario": Scenario(pos_ned_m=(0.0, 0.0, -alt_m), yaw_rad=yaw_rad, footage_offset_s=0.0)}


@pytest.mark.parametrize("env_id", IDS)
def test_registered_and_passes_env_checker(env_id: str) -> None:
    env = gym.make(env_id, footage="synthetic", **SMALL)
    with warnings.catch_warnings():
        warnings.simplefilter(
            "ignore"
        )  # the state Box is unbounded (positions): the checker warns, not fails
        check_env(env.unwrapped)
    obs, _ = env.reset(seed=3)
    assert obs in env.observation_space
    env.close()


def rollout(env: LandingEnv, seed: int, steps: int) -> list[Any]:
    rng = np.random.default_rng(seed)
    out: list[Any] = [env.reset(seed=seed)]
    for _ in range(steps):
        a = rng.uniform(-1, 1, 4).astype(np.float32)
        a[3] = -0.3 * abs(a[3])
        step = env.step(a)
        out.append(step)
        if step[2] or step[3]:
            out.append(env.reset())
    return out


def same(a: Any, b: Any) -> bool:
    if isinstance(a, dict):
        return a.keys() == b.keys() and all(same(a[k], b[k]) for k in a)
    if isinstance(a, tuple | list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b, strict=True))
    if isinstance(a, np.ndarray):
        return a.dtype == b.dtype and np.array_equal(a, b)
    return bool(a == b) or (isinstance(a, float) and math.isnan(a) and math.isnan(b))


def test_seeded_rollouts_are_bit_identical() -> None:
    ranges = ScenarioRanges(alt_m=(3.0, 6.0), wind_speed_m_s=(0.0, 3.0), gust_std_m_s=(0.0, 0.5))
    a = LandingEnv("synthetic", scenario=ranges, **SMALL)
    b = LandingEnv("synthetic", scenario=ranges, **SMALL)
    b.reset(seed=99)  # b has flown elsewhere first: must not matter
    for _ in range(20):
        b.step(np.array([0.5, -0.5, 1.0, 0.2], np.float32))
    ra, rb = rollout(a, 7, 60), rollout(b, 7, 60)
    assert same(ra, rb)
    # and a different seed gives a different flight
    assert not same(rollout(a, 8, 5)[0][0]["state"], ra[0][0]["state"])
    # wind and gusts were drawn (not a trivially calm scenario)
    assert a.scenario is not None


def test_hover_and_action_directions_follow_viva_safeland() -> None:
    env = LandingEnv("synthetic", observation="state")
    env.reset(seed=0, options=level_start())
    for _ in range(30):
        obs, *_ = env.step(np.zeros(4, np.float32))  # [0, 0, 0, 0] hovers exactly (thrust = m g)
    assert obs[9] == pytest.approx(20.0, abs=1e-6) and np.allclose(obs[3:6], 0.0, atol=1e-9)
    cases = {  # action -> (state index, sign after 1 s): roll right -> east, +pitch -> forward, +yaw rate -> CCW
        (1.0, 0.0, 0.0, 0.0): (4, +1),
        (0.0, 1.0, 0.0, 0.0): (3, +1),
        (0.0, 0.0, 1.0, 0.0): (8, -1),
        (0.0, 0.0, 0.0, 0.5): (5, -1),  # more thrust: climbs (v_down < 0)
        (0.0, 0.0, 0.0, -0.5): (5, +1),
    }
    for action, (idx, sign) in cases.items():
        env.reset(seed=0, options=level_start())
        for _ in range(30):
            obs, *_ = env.step(np.array(action, np.float32))
        assert np.sign(obs[idx]) == sign, (action, obs)
    # yaw rate: 30 deg/s x 1 s with DroneEnv's instant attitude; the default airframe follows the yaw ramp first
    # order (tau = 1/MC_YAW_P): r (t - tau (1 - exp(-t / tau)))
    for physics in (EavParams().with_ideal_attitude(), EavParams()):
        env = LandingEnv("synthetic", observation="state", config=SimConfig(physics=physics))
        env.reset(seed=0, options=level_start())
        for _ in range(30):
            obs, *_ = env.step(np.array([0, 0, 1, 0], np.float32))
        t, tau = env.vehicle.time_s, physics.yaw_tau_s
        ramp_s = t - tau * (1.0 - math.exp(-t / tau)) if tau > 0 else t
        assert math.degrees(obs[8]) == pytest.approx(-30.0 * ramp_s, abs=0.5), physics
        assert t == pytest.approx(1.0, abs=1e-9)  # 30 control steps at 30 Hz of 250 Hz physics


def test_velocity_mode_flies_through_the_autopilot() -> None:
    env = LandingEnv("synthetic", observation="state", action_mode="velocity", max_speed_m_s=4.0)
    env.reset(seed=0, options=level_start())
    assert env.vehicle.autopilot.mode.name == "OFFBOARD"
    for _ in range(90):
        obs, *_ = env.step(np.array([0.5, -0.25, 0.0, 0.0], np.float32))
    assert obs[3] == pytest.approx(2.0, abs=0.15) and obs[4] == pytest.approx(-1.0, abs=0.15)
    assert obs[9] == pytest.approx(20.0, abs=0.5)


def test_bad_actions_get_clear_errors_or_are_clipped() -> None:
    env = LandingEnv("synthetic", observation="state")
    with pytest.raises(RuntimeError, match="reset"):
        env.step(np.zeros(4))
    env.reset(seed=0, options=level_start())
    before = env.vehicle.state
    with pytest.raises(ValueError, match="finite"):
        env.step(np.array([0.0, math.nan, 0.0, 0.0]))
    with pytest.raises(ValueError, match=r"shape \(4,\)"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="4 numbers"):
        env.step("up")
    assert env.vehicle.state is before  # nothing flown
    o_clip, _, _, _, info = env.step(np.array([5.0, 0.0, 0.0, 0.0]))
    assert info["action_clipped"]
    env.reset(seed=0, options=level_start())
    o_one, _, _, _, info = env.step(np.array([1.0, 0.0, 0.0, 0.0]))
    assert not info["action_clipped"] and np.array_equal(o_clip, o_one)
    strict = LandingEnv("synthetic", observation="state", out_of_range="raise")
    strict.reset(seed=0)
    with pytest.raises(ValueError, match="out of"):
        strict.step(np.array([0.0, 0.0, 0.0, -1.5]))
    with pytest.raises(ValueError, match="action_mode"):
        LandingEnv("synthetic", action_mode="rates")


def fly_down(env: LandingEnv, thrust: float, options: dict[str, Any]) -> tuple[float, dict[str, Any], float]:
    env.reset(seed=0, options=options)
    total = 0.0
    for _ in range(3000):
        _, r, term, trunc, info = env.step(np.array([0.0, 0.0, 0.0, thrust], np.float32))
        total += r
        if term or trunc:
            return total, info, env.vehicle.time_s
    raise AssertionError("never ended")


def test_touchdown_scores_safe_and_unsafe_landings() -> None:
    env = LandingEnv("synthetic", observation="state", score=LandingScoreConfig(max_risk_level=5))
    # a gentle touchdown (sink rate limited by a thrust just under hover)
    slow_total, slow, _ = fly_down(env, -0.02, level_start(alt_m=2.0))
    assert slow["score"]["outcome"] == "safe_landing" and slow["score"]["touchdown_speed_m_s"] < 1.0
    fast_total, fast, _ = fly_down(env, -1.0, level_start(alt_m=15.0))  # motors off from 15 m
    assert fast["score"]["outcome"] == "unsafe_landing" and fast["score"]["touchdown_speed_m_s"] > 10.0
    assert slow_total > fast_total + 100.0
    # risk: a limit of 0 people-distance and level 1 turns the same gentle landing unsafe unless the ground is level 1
    strict = LandingEnv("synthetic", observation="state", score=LandingScoreConfig(max_risk_level=1))
    _, info, _ = fly_down(strict, -0.02, level_start(alt_m=2.0))
    expect = "safe_landing" if info["score"]["risk_level"] <= 1 else "unsafe_landing"
    assert info["score"]["outcome"] == expect


def test_truncates_on_time_limit() -> None:
    env = LandingEnv("synthetic", observation="state", max_episode_s=0.5)
    env.reset(seed=0, options=level_start())
    ends = [env.step(np.zeros(4, np.float32))[2:4] for _ in range(15)]
    assert ends[-1] == (False, True) and all(e == (False, False) for e in ends[:-1])


def test_images_grayscale_stack_and_overview() -> None:
    env = LandingEnv("synthetic", image_size=(64, 48), grayscale=True, frame_stack=3, render_mode="rgb_array")
    o0, _ = env.reset(seed=0, options=level_start(alt_m=10.0))
    assert o0["image"].shape == (48, 64, 3) and np.array_equal(o0["image"][..., 0], o0["image"][..., 2])
    o1, *_ = env.step(np.array([1.0, 0.0, 0.0, 0.0], np.float32))
    o2, *_ = env.step(np.array([1.0, 0.0, 0.0, 0.0], np.float32))
    assert np.array_equal(o2["image"][..., 1], o1["image"][..., 2])  # oldest first
    assert not np.array_equal(o2["image"][..., 2], o0["image"][..., 0])  # it moved
    rgb = LandingEnv("synthetic", image_size=(64, 48))
    view = rgb.reset(seed=0, options=level_start(alt_m=10.0))[0]["image"]
    bgr = rgb.vehicle.render(wall_time_s=0.0).image_bgr
    assert np.array_equal(view, bgr[:, :, ::-1])  # observations are RGB
    over = env.render()
    assert over is not None and over.ndim == 3 and over.shape[2] == 3 and over.dtype == np.uint8
    assert LandingEnv("synthetic", observation="state").render() is None  # no render_mode


def test_seams_take_a_custom_scorer_and_scenario_drawer() -> None:
    drawn: list[int] = []

    def drawer(rng: np.random.Generator, geometry: Any, duration_s: float) -> Scenario:
        drawn.append(int(rng.integers(1000)))
        return Scenario(pos_ned_m=(1.0, 2.0, -7.0), yaw_rad=0.5, footage_offset_s=0.25)

    class Constant:
        def reset(self, state: Any, footage_time_s: float) -> None:
            self.t0 = footage_time_s

        def score(self, state: Any, footage_time_s: float, inside: bool) -> StepScore:
            return StepScore(42.0, footage_time_s - self.t0 > 0.2, {"outcome": "custom"})

    env = LandingEnv("synthetic", observation="state", scenario_drawer=drawer, scorer=Constant())
    obs, info = env.reset(seed=5)
    assert drawn and obs[:3].tolist() == [1.0, 2.0, -7.0] and info["footage_time_s"] == 0.25
    r, term = 0.0, False
    while not term:
        _, r, term, _, info = env.step(np.zeros(4, np.float32))
    assert r == 42.0 and info["score"] == {"outcome": "custom"}


def test_leaving_the_footage_ends_the_episode(shared_dir: Path) -> None:
    footage = str(shared_dir / "footage" / "interchange" / "interchange_1080p.mp4")
    env = LandingEnv(footage, image_size=(64, 48), render_mode="rgb_array")
    g = env.footage.geometry
    edge_east_m = 0.5 * g.ground_width_m - 3.0
    start = Scenario(pos_ned_m=(0.0, edge_east_m, -30.0), yaw_rad=0.0, footage_offset_s=0.0)
    env.reset(seed=0, options={"scenario": start})
    over = env.render()
    assert over is not None and over.shape[1] <= 800 and over.shape[2] == 3
    for _ in range(300):
        obs, r, term, trunc, info = env.step(np.array([1.0, 0.0, 0.0, 0.05], np.float32))  # roll right: east
        if term:
            break
    assert term and info["score"]["outcome"] == "left_footage" and r < -50.0
    assert not g.contains_ned(float(obs["state"][0]), float(obs["state"][1]))
    env.close()
