"""The Gymnasium landing environments (viva_sitl.gym): API conformance, determinism, action semantics, bad input,
the trials' scenarios and scores, rendering. Flown over the synthetic field (always available) through the real
Vehicle loop."""

from __future__ import annotations

import math
import warnings
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

from gymnasium.utils.env_checker import check_env  # noqa: E402

import viva_sitl.gym  # noqa: E402,F401  (registers the ids)
import viva_sitl.world  # noqa: E402
from viva_sitl.autopilot import FlightMode, PositionTarget  # noqa: E402
from viva_sitl.config import SimConfig  # noqa: E402
from viva_sitl.dynamics import EavParams  # noqa: E402
from viva_sitl.evaluation import pilots as pilots_mod  # noqa: E402
from viva_sitl.evaluation.runner import run_inprocess_trial  # noqa: E402
from viva_sitl.evaluation.spec import draw_scenarios, load_spec  # noqa: E402
from viva_sitl.gym import (  # noqa: E402
    LandingEnv,
    RewardConfig,
    Scenario,
    StepScore,
    TrialSpec,
    land_assist_limits,
)

REPO = Path(__file__).resolve().parents[1]
SYNTH_SPEC = REPO / "configs" / "trials" / "synthetic_emergency.toml"

IDS = [
    "viva_sitl/Landing-v0",
    "viva_sitl/LandingVelocity-v0",
    "viva_sitl/LandingState-v0",
    "viva_sitl/LandingStateVelocity-v0",
]
SMALL = {"image_size": (64, 48)}


def level_start(alt_m: float = 20.0, yaw_rad: float = 0.0) -> dict[str, Any]:
    return {"scenario": Scenario.air(0.0, 0.0, alt_m, yaw_deg=math.degrees(yaw_rad))}


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
    spec = TrialSpec(altitude_m=(3.0, 6.0), wind_speed_m_s=(0.0, 3.0), gust_std_m_s=(0.0, 0.5))
    a = LandingEnv("synthetic", spec=spec, **SMALL)
    b = LandingEnv("synthetic", spec=spec, **SMALL)
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


def test_touchdown_ends_as_a_trial_and_scores_it() -> None:
    env = LandingEnv("synthetic", observation="state")
    # a gentle touchdown (sink rate limited by a thrust just under hover): the env disarms, the trial is "landed"
    slow_total, slow, _ = fly_down(env, -0.02, level_start(alt_m=2.0))
    row = slow["trial"]
    assert row["end"] == "landed" and row["landed"] and row["touchdown_speed_m_s"] < 1.0
    assert not env.vehicle.autopilot.armed
    # the terminal reward is the row's outcome (RewardConfig defaults), hand-computed from the row
    c = RewardConfig()
    d = row["min_dist_person_m"] if row["min_dist_person_m"] is not None else row["dist_person_m"]
    expect = (c.landed_bonus + (c.success_bonus if row["success"] else 0.0)
              - c.touchdown_weight * row["touchdown_speed_m_s"] - c.touchdown_risk_weight * (row["risk_level"] - 1)
              - c.touchdown_people_weight * max(0.0, 5.0 - d))  # fmt: skip
    assert env.scorer.final(row) == pytest.approx(expect)
    # motors off from 15 m: a crash (touchdown > the spec's crash_speed_m_s), ends on that physics step
    fast_total, fast, _ = fly_down(env, -1.0, level_start(alt_m=15.0))
    assert fast["trial"]["end"] == "crash" and fast["trial"]["touchdown_speed_m_s"] > 10.0
    assert not fast["trial"]["success"]
    assert slow_total > fast_total + 50.0
    # the criterion is the spec's: allowing any risk level and no people distance can only turn failures into
    # successes, never the reverse
    lax = TrialSpec(criterion=replace(TrialSpec().criterion, max_risk_level=None, min_dist_person_m=None))
    _, info, _ = fly_down(
        LandingEnv("synthetic", observation="state", spec=lax), -0.02, level_start(alt_m=2.0)
    )
    assert info["trial"]["success"] is True and info["trial"]["risk_level"] == row["risk_level"]


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
    drawn: list[tuple[int, int]] = []

    def drawer(seed: int, index: int) -> Scenario:
        drawn.append((seed, index))
        return Scenario.air(1.0, 2.0, 7.0, yaw_deg=30.0, footage_time_s=0.25)

    class Constant:
        def reset(self, scenario: Scenario, state: Any, footage_time_s: float) -> None:
            self.t0 = footage_time_s

        def step(self, state: Any, footage_time_s: float) -> StepScore:
            return StepScore(42.0, footage_time_s - self.t0 > 0.2, {"outcome": "custom"})

        def final(self, row: dict[str, Any]) -> float:
            return 1.0 if row["end"] == "scorer" else -1.0

    env = LandingEnv("synthetic", observation="state", scenario_drawer=drawer, scorer=Constant())
    obs, info = env.reset(seed=5)
    env.reset()
    assert (
        drawn == [(5, 0), (5, 1)] and obs[:3].tolist() == [1.0, 2.0, -7.0] and info["footage_time_s"] == 0.25
    )
    r, term = 0.0, False
    while not term:
        _, r, term, _, info = env.step(np.zeros(4, np.float32))
    assert r == 43.0 and info["score"] == {"outcome": "custom"} and info["trial"]["end"] == "scorer"


def test_reset_seed_draws_the_trials_scenarios() -> None:
    """gymnasium.make(id, spec=TOML): reset(seed=s) flies trial 0 of `trials run --seed s`, reset() the next ones, with
    the scenario's start pose, footage time, wind, PX4 parameters and failures."""
    env = gym.make("viva_sitl/LandingStateVelocity-v0", spec=str(SYNTH_SPEC))
    spec = load_spec(SYNTH_SPEC)
    want = draw_scenarios(spec, n=4, seed=7)
    got = []
    for k in range(3):
        obs, info = env.reset(seed=7) if k == 0 else env.reset()
        sc = env.unwrapped.scenario
        got.append(sc)
        w = want[k]
        assert sc == w and info["trial_index"] == k and info["trial_seed"] == 7
        assert obs[:3].tolist() == pytest.approx([w.north_m, w.east_m, -w.altitude_m], abs=1e-5)
        assert obs[8] == pytest.approx(math.radians(w.yaw_deg), abs=1e-5)
        assert info["footage_time_s"] == w.footage_time_s
        veh = env.unwrapped.vehicle
        for name, value in w.all_params():
            assert veh.params.get(name) == pytest.approx(value, abs=1e-6), name
    assert (
        env.reset(seed=7, options={"trial": 3})[1]["trial_index"] == 3 and env.unwrapped.scenario == want[3]
    )
    assert len({(g.north_m, g.footage_time_s) for g in got}) == 3
    # failure injection and "land now" follow the trial's schedule (the trials' monitor): find a scenario with one
    k = next(i for i, sc in enumerate(draw_scenarios(spec, n=40, seed=7)) if sc.failures)
    env.reset(seed=7, options={"trial": k})
    sc = env.unwrapped.scenario
    assert sc.failures
    while env.unwrapped.vehicle.time_s < max(sc.land_at_s, sc.failures[0].at_s) + 0.5:
        env.step(np.zeros(4, np.float32))
    kinds = [e["kind"] for e in env.unwrapped.monitor.log.events]
    assert "land_now" in kinds and "failure" in kinds
    env.close()


class ReplayPilot:
    """An in-process trials pilot flying the same velocity setpoints as the gym test below, at the gym's control
    rate, and disarming at the first control step on the ground as the env does."""

    name = "replay"
    control_hz = 25.0
    frame_hz = 0.0
    uses_ground_truth = False

    def reset(self, scenario: Any, truth: Any) -> None:
        self.k = 0

    def act(self, obs: Any, ctl: Any) -> None:
        ap, t = ctl.autopilot, obs.state.time_s
        if obs.state.landed and obs.armed and self.k > 0:
            ap.disarm(t, force=True)
            return None
        a = replay_action(self.k)
        ap.set_position_target(t, PositionTarget(vel_ned_m_s=(a[0] * 5.0, a[1] * 5.0, a[2] * 3.0),
                                                 yaw_rate_rad_s=a[3] * math.radians(30.0)))  # fmt: skip
        if ap.mode != FlightMode.OFFBOARD:
            ap.set_mode(t, FlightMode.OFFBOARD)
        self.k += 1
        return None


def replay_action(k: int) -> np.ndarray:
    return np.array([0.3 * math.sin(k / 15.0), 0.15, 0.3, 0.2 * math.cos(k / 20.0)], np.float32)


def test_same_trajectory_gets_the_trials_score_row(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    """The gym env and the trials runner fly the same scenario with the same setpoints: the same trajectory, and the
    env's last info["trial"] is the row `trials run` computes (every column but pilot and wall time)."""
    spec = load_spec(SYNTH_SPEC)
    monkeypatch.setitem(pilots_mod.BUILTIN_PILOTS, "replay", ReplayPilot)
    env = LandingEnv(spec=SYNTH_SPEC, observation="state", action_mode="velocity", control_hz=25.0)
    for k in (0, 1):
        sc = draw_scenarios(spec, n=2, seed=3)[k]
        env.reset(seed=3, options={"trial": k})
        assert env.scenario == sc
        n, info, total = 0, {}, 0.0
        while True:
            _, r, term, trunc, info = env.step(replay_action(n))
            n, total = n + 1, total + r
            if term or trunc:
                break
        gym_row = info["trial"]
        ref = run_inprocess_trial(spec, sc, "replay", tmp_path / f"t{k}")
        assert gym_row["end"] == "landed" and gym_row["touchdown_speed_m_s"] is not None
        diff = {c: (gym_row[c], ref[c]) for c in ref if c not in ("pilot", "wall_s") and gym_row[c] != ref[c]}
        assert not diff
        assert math.isfinite(total)


def test_state_only_observation_never_renders(monkeypatch: pytest.MonkeyPatch) -> None:
    """The state-only variants never draw the VAC (the speed RL training needs); the image ones do."""
    calls: list[int] = []
    env = gym.make("viva_sitl/LandingStateVelocity-v0", spec=str(SYNTH_SPEC)).unwrapped
    # every view (Simulator.render and the gym's render_rgb) is drawn by _render_image
    original = env.vehicle.sim._render_image
    monkeypatch.setattr(
        env.vehicle.sim, "_render_image", lambda *a, **k: calls.append(1) or original(*a, **k)
    )
    env.reset(seed=0)
    for _ in range(20):
        env.step(env.action_space.sample())
    env.reset()
    assert calls == []
    img = gym.make("viva_sitl/LandingVelocity-v0", spec=str(SYNTH_SPEC), **SMALL).unwrapped
    original_img = img.vehicle.sim._render_image
    monkeypatch.setattr(
        img.vehicle.sim, "_render_image", lambda *a, **k: calls.append(1) or original_img(*a, **k)
    )
    img.reset(seed=0)
    img.step(img.action_space.sample())
    assert len(calls) == 2


def test_leaving_the_footage_ends_the_episode(shared_dir: Path) -> None:
    footage = str(shared_dir / "footage" / "interchange" / "interchange_1080p.mp4")
    env = LandingEnv(footage, image_size=(64, 48), render_mode="rgb_array")
    g = env.footage.geometry
    edge_east_m = 0.5 * g.ground_width_m - 3.0
    start = Scenario.air(0.0, edge_east_m, 30.0)
    env.reset(seed=0, options={"scenario": start})
    over = env.render()
    assert over is not None and over.shape[1] <= 800 and over.shape[2] == 3
    for _ in range(300):
        obs, r, term, trunc, info = env.step(np.array([1.0, 0.0, 0.0, 0.05], np.float32))  # roll right: east
        if term:
            break
    assert term and info["trial"]["end"] == "left_footage" and r < -50.0
    assert not g.contains_ned(float(obs["state"][0]), float(obs["state"][1]))
    env.close()


def test_landing_assist_limits_sink_and_horizontal_speed_near_the_ground() -> None:
    # the rule: PX4 Land's blend between MPC_LAND_ALT2 (land values) and MPC_LAND_ALT1 (fast values)
    kw = {"land_speed_m_s": 0.7, "fast_down_m_s": 1.5, "alt1_m": 10.0, "alt2_m": 5.0, "xy_land_m_s": 0.2}
    assert land_assist_limits(12.0, xy_fast_m_s=5.0, **kw) == (math.inf, math.inf)
    assert land_assist_limits(7.5, xy_fast_m_s=5.0, **kw) == pytest.approx((1.1, 2.6))
    assert land_assist_limits(3.0, xy_fast_m_s=5.0, **kw) == (0.7, 0.2)

    def fly(mode: str) -> tuple[list[tuple[float, float, float]], dict[str, Any]]:
        env = LandingEnv(
            "synthetic", observation="state", action_mode=mode, max_episode_s=40.0, land_xy_m_s=0.2
        )
        env.reset(seed=0, options=level_start(alt_m=12.0))
        env.vehicle.params.set("MPC_LAND_SPEED", 0.9)  # read live from the vehicle's parameters
        assert env.vehicle.params.get("MPC_LAND_SPEED") == pytest.approx(0.9)
        track = []
        for _ in range(1200):  # full sink and full speed north, all the way down
            obs, _, term, trunc, info = env.step(np.array([1.0, 0.0, 1.0, 0.0], np.float32))
            track.append((float(obs[9]), float(obs[5]), math.hypot(float(obs[3]), float(obs[4]))))
            if term or trunc:
                return track, info
        raise AssertionError("did not land")

    track, info = fly("velocity_land")
    low = [(vd, vh) for alt, vd, vh in track if 0.3 < alt < 3.0]
    assert low and max(vd for vd, _ in low) < 0.9 + 0.08 and max(vh for _, vh in low) < 0.2 + 0.08
    assert min(vd for vd, _ in low) > 0.9 - 0.08  # it does sink at MPC_LAND_SPEED
    # above MPC_LAND_ALT1 only the autopilot's own limit (MPC_Z_VEL_MAX_DN)
    assert max(vd for alt, vd, _ in track if alt > 10.5) > 1.3
    row = info["trial"]
    assert row["end"] == "landed" and row["touchdown_speed_m_s"] < 1.0
    # the default velocity mode is unchanged: the same command sinks at MPC_Z_VEL_MAX_DN and flies at 5 m/s to the
    # ground, touching down far faster
    track, info = fly("velocity")
    low = [(vd, vh) for alt, vd, vh in track if 0.3 < alt < 3.0]
    assert min(vd for vd, _ in low) > 1.2 and min(vh for _, vh in low) > 3.0
    assert info["trial"]["touchdown_speed_m_s"] > 3.0
    # climbing is never limited; by default (land_xy_m_s=0) it holds position below MPC_LAND_ALT2, as PX4's Land
    env = LandingEnv("synthetic", observation="state", action_mode="velocity_land")
    env.reset(seed=0, options=level_start(alt_m=2.0))
    assert env.assisted_velocity((0.0, 0.0, -3.0)) == (0.0, 0.0, -3.0)
    assert env.assisted_velocity((3.0, 4.0, 2.0)) == (0.0, 0.0, pytest.approx(0.7))


def test_privileged_ground_truth_observation_is_the_world_models() -> None:
    """ground_truth_obs=True (off by default) appends the world model's risk grid and the nearest person to the state:
    check_env passes, and right above a person the values are the world model's (risk_at per cell, the person's
    offset from tracks.nearest, level 5 under the vehicle); the plain state observation stays 10 numbers."""
    plain = LandingEnv("synthetic", observation="state", action_mode="velocity_land")
    assert plain.observation_space.shape == (10,)
    env = LandingEnv(
        "synthetic", observation="state", action_mode="velocity_land", ground_truth_obs=True, ground_grid=5,
        ground_cell_m=3.0, people_range_m=25.0,
    )  # fmt: skip
    assert env.observation_space.shape == (10 + 25 + 3,) and len(env.state_fields) == 38
    assert env.state_fields[10] == "risk_0_0" and env.state_fields[-1] == "person_dist_m"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # unbounded Box: the checker warns
        check_env(env)
    world = env.world
    t = 12.0
    person = world.tracks.objects_at(t, viva_sitl.world.PEOPLE)
    assert len(person) > 0
    pn, pe = (float(v) for v in person.ne_m[0])
    obs, _ = env.reset(seed=0, options={"scenario": Scenario.air(pn + 1.0, pe - 2.0, 20.0, footage_time_s=t)})
    assert obs in env.observation_space and env.footage_time_s == pytest.approx(t)
    n, e = float(obs[0]), float(obs[1])
    assert (n, e) == pytest.approx((pn + 1.0, pe - 2.0), abs=1e-4)
    grid = obs[10:35].reshape(5, 5)
    for i in range(5):
        for j in range(5):
            assert grid[i, j] == world.risk_at(n + (i - 2) * 3.0, e + (j - 2) * 3.0, t), (i, j)
    assert grid[2, 2] == 5  # 2.2 m from a person: inside its level-5 buffer
    near = world.tracks.nearest(n, e, t, viva_sitl.world.PEOPLE)
    assert near is not None and near.distance_m <= math.hypot(1.0, 2.0) + 1e-6
    assert obs[35:] == pytest.approx([near.ne_m[0] - n, near.ne_m[1] - e, near.distance_m], abs=1e-4)
    # far from everyone the person fields are clamped to people_range_m, direction kept
    far = env.ground_truth(n + 500.0, e, t)
    assert far[-1] == pytest.approx(25.0) and math.hypot(float(far[-3]), float(far[-2])) == pytest.approx(
        25.0
    )
    obs2, *_ = env.step(np.zeros(4, np.float32))  # updated every step (the obs position is float32: approx)
    s = env.vehicle.state
    want = env.ground_truth(float(s.pos_ned_m[0]), float(s.pos_ned_m[1]), env.footage_time_s)
    assert obs2[10:] == pytest.approx(want, abs=1e-4)
    with pytest.raises(ValueError, match="ground_grid"):
        LandingEnv("synthetic", observation="state", ground_truth_obs=True, ground_grid=0)
    env.close()
    plain.close()
