"""The vectorized landing env (SharedFootageVectorEnv): N copies over ONE footage decode, images equal to single envs
for the same seeds, autoreset on one clock, make_vec."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")

import viva_sitl.gym  # noqa: E402,F401
from viva_sitl.evaluation.spec import footage_box  # noqa: E402
from viva_sitl.gym import LandingEnv, SharedFootageVectorEnv, TrialSpec  # noqa: E402


def actions(n: int, k: int) -> np.ndarray:
    rng = np.random.default_rng(1000 + k)
    a = rng.uniform(-1, 1, (n, 4))
    a[:, 3] = -0.2 * np.abs(a[:, 3])
    return a.astype(np.float32)


def singles(footage: Any, seed: int, n: int, steps: int, **kw: Any) -> list[list[Any]]:
    """What n independent LandingEnvs (seeds seed..seed+n-1) observe under the same actions."""
    out = []
    for i in range(n):
        env = LandingEnv(footage, **kw)
        obs = [env.reset(seed=seed + i)[0]]
        for k in range(steps):
            obs.append(env.step(actions(n, k)[i])[0])
        out.append(obs)
        env.close()
    return out


def check_equal(vec_obs: list[Any], single: list[list[Any]]) -> None:
    for i, per_env in enumerate(single):
        for k, o in enumerate(per_env):
            assert np.array_equal(vec_obs[k]["image"][i], o["image"]), (i, k)
            assert np.array_equal(vec_obs[k]["state"][i], o["state"]), (i, k)


def test_vector_over_video_shares_decode_and_equals_single_envs(shared_dir: Path) -> None:
    footage = str(shared_dir / "footage" / "interchange" / "interchange_1080p.mp4")
    kw: dict[str, Any] = {
        "image_size": (64, 48),
        # footage start times in 2 slots over the clip: copies share a decoder per slot
        "spec": TrialSpec(
            altitude_m=(40.0, 80.0),
            footage_time_s=(0.0, footage_box(footage).duration_s),
            footage_time_slots=2,
        ),
    }
    n, steps = 4, 12
    venv = SharedFootageVectorEnv(n, footage=footage, **kw)
    obs = [venv.reset(seed=10)[0]]
    for k in range(steps):
        obs.append(venv.step(actions(n, k))[0])
    # the copies drew both offset slots; one decoder per slot, each decoding what ONE env would decode
    assert venv.decoded_sources == 2
    decoded = sorted(s.decoder_stats["decoded"] for s in venv._sources.values())  # type: ignore[attr-defined]
    single_decoded = []
    for i in range(n):
        e = LandingEnv(footage, **kw)
        e.reset(seed=10 + i)
        for k in range(steps):
            e.step(actions(n, k)[i])
        single_decoded.append(e.footage.decoder_stats["decoded"])  # type: ignore[attr-defined]
        e.close()
    assert decoded == sorted(set(single_decoded))  # N copies cost K decodes, not N
    check_equal(obs, singles(footage, 10, n, steps, **kw))
    venv.close()


def test_autoreset_keeps_a_slot_on_one_footage_frame(shared_dir: Path) -> None:
    footage = str(shared_dir / "footage" / "interchange" / "interchange_1080p.mp4")
    venv = SharedFootageVectorEnv(
        3, footage=footage, observation="state", max_episode_s=2.0, spec=TrialSpec(altitude_m=(1.0, 1.5)),
    )  # fmt: skip
    venv.reset(seed=1)
    act = np.zeros((3, 4), np.float32)
    act[
        0, 3
    ] = -1.0  # copy 0 falls and crashes (~0.5 s), restarts, falls again; the others hover to the time limit
    ends = np.zeros(3, np.int64)
    for _ in range(90):
        _, _, term, trunc, info = venv.step(act)
        ends += term | trunc
        ft = info["footage_time_s"]
        # one slot (offset 0): every running copy on the same footage frame (a trial that ended did so on the
        # physics step it ended, e.g. a crash part-way through the control period)
        idx = {venv.envs[i].footage.frame_index_at(ft[i]) for i in range(3) if not (term[i] or trunc[i])}
        assert len(idx) <= 1, ft
    assert ends[0] >= 3 and ends[1] == 1  # copy 0 restarted at other global times than copy 1
    assert venv.envs[0].vehicle.sim.footage_offset_s > 0.0  # its offset follows the global clock
    assert venv.decoded_sources == 1
    venv.close()


def test_make_vec_entry_point_over_synthetic_equals_single_envs() -> None:
    kw: dict[str, Any] = {"image_size": (64, 48)}
    n, steps = 3, 8
    venv = gym.make_vec("viva_sitl/Landing-v0", num_envs=n, vectorization_mode="vector_entry_point",
                        footage="synthetic", **kw)  # fmt: skip
    assert isinstance(venv, SharedFootageVectorEnv)
    assert venv.observation_space["image"].shape == (n, 48, 64, 3)
    obs = [venv.reset(seed=5)[0]]
    for k in range(steps):
        obs.append(venv.step(actions(n, k))[0])
    check_equal(obs, singles("synthetic", 5, n, steps, **kw))
    with pytest.raises(ValueError, match=r"shape \(3, 4\)"):
        venv.step(np.zeros((2, 4)))
    with pytest.raises(ValueError, match="finite"):
        venv.step(np.full((3, 4), np.nan))
    venv.close()


def test_batched_action_check_acts_as_each_copys_own() -> None:
    """The vector env checks the whole action batch at once: out-of-range rows are clipped and flagged per copy
    (as LandingEnv.step does), a non-finite row or, with out_of_range="raise", an out-of-range row raises the single
    env's ValueError and steps no copy."""
    kw: dict[str, Any] = {"image_size": (32, 24), "observation": "state"}
    venv = SharedFootageVectorEnv(3, footage="synthetic", **kw)
    venv.reset(seed=2)
    single = LandingEnv("synthetic", **kw)
    single.reset(seed=3)
    a = np.array([[0.0, 0.0, 0.0, 0.0], [1.5, -2.0, 0.0, 0.2], [0.1, 0.0, 0.0, 0.0]])
    obs, _, _, _, info = venv.step(a)
    assert info["action_clipped"].tolist() == [False, True, False]
    s_obs, _, _, _, s_info = single.step(a[1])
    # the clipped row flies as the single env's
    assert s_info["action_clipped"] and np.array_equal(obs[1], s_obs)
    t0 = [e.vehicle.time_s for e in venv.envs]
    bad = a.copy()
    bad[2, 1] = np.inf
    with pytest.raises(ValueError, match="finite"):
        venv.step(bad)
    assert [e.vehicle.time_s for e in venv.envs] == t0  # nothing stepped
    venv.close()
    strict = SharedFootageVectorEnv(2, footage="synthetic", out_of_range="raise", **kw)
    strict.reset(seed=0)
    with pytest.raises(ValueError, match=r"out of \[-1, 1\]"):
        strict.step(np.array([[0.0, 0.0, 0.0, 0.0], [0.0, 1.01, 0.0, 0.0]]))
    strict.step(np.zeros((2, 4)))
    strict.close()
    single.close()


@pytest.mark.parametrize("kw", [{"frame_stack": 2}, {"grayscale": True}, {"ground_truth_obs": True}],
                         ids=["frame_stack", "grayscale", "ground_truth_obs"])  # fmt: skip
def test_stacked_and_grayscale_views_equal_single_envs(kw: dict[str, Any]) -> None:
    """The batch is assembled two ways (RGB views converted straight into their batch slots; stacked or grayscale
    views copied in): both equal single envs, and each step's batch is a new array (earlier ones stay as returned)."""
    kw = {"image_size": (32, 24), **kw}
    n, steps = 2, 4
    venv = SharedFootageVectorEnv(n, footage="synthetic", **kw)
    obs = [venv.reset(seed=7)[0]]
    for k in range(steps):
        obs.append(venv.step(actions(n, k))[0])
    check_equal(obs, singles("synthetic", 7, n, steps, **kw))
    venv.close()
