"""N landing environments over ONE footage, each footage frame decoded once for all of them.

    venv = SharedFootageVectorEnv(8, footage="interchange", image_size=(160, 120))
    # or gymnasium.make_vec("viva_sitl/Landing-v0", num_envs=8, vectorization_mode="vector_entry_point", ...)
    obs, infos = venv.reset(seed=0)          # copy i flies scenario seed + i: the same as LandingEnv.reset(seed=seed + i)
    obs, rewards, terminated, truncated, infos = venv.step(actions)   # actions: (N, 4)

How the decode is shared:
- The copies are LandingEnvs (each its own Vehicle: the ONE vehicle loop) built over SHARED FootageSources. A
  FootageSource keeps its recently decoded frames (a video's decoder keeps the last raw frames; a tile cache its
  decoded-tile LRU), so copies that render the same footage frame one after another decode it once; each copy then
  converts/warps only the region its own view reads (N views from one decoded frame).
- Footage time = episode sim time + the copy's footage offset (Simulator.footage_offset_s). Randomised start times
  share through a SMALL SET of offset slots (the spec's footage_time_slots; a spec drawing footage_time_s
  uniformly gives each copy its own source, correct but not shared): one FootageSource
  (one sequential decoder) per slot, so N copies decode at most K frames per step (K = number of slots), never seek.
- The copies step in lockstep on one global control clock (same physics steps per control step for all), and a
  copy that starts an episode at global time g gets offset = slot offset + g: copies of a slot stay on the same
  footage frame whatever their episode start. At the first reset (g = 0) the offsets equal a single LandingEnv's,
  so images equal the single env's for the same seeds (tests/test_gym_vector.py).
- `convert_shared=True`: when two or more copies render one video frame, convert it to BGR once (their region reads
  become slices of it) instead of each converting its own region: pays off only when the copies' regions together
  cover much of the frame (high altitudes, large views); off by default (bench/results_gym.md).
Autoreset: gymnasium's NEXT_STEP mode (the step after a terminated/truncated one resets that copy; reward 0).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any, cast

import numpy as np
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space, concatenate, create_empty_array
from numpy.typing import NDArray

from viva_sitl.evaluation.episode import ControlSchedule
from viva_sitl.footage import FootageSource, VideoSource, open_footage
from viva_sitl.footage.synthetic import SyntheticField
from viva_sitl.gym.config import FLAT_KWARGS, LandingEnvConfig, ScenarioConfig
from viva_sitl.gym.env import FootageBinding, LandingEnv, gym_tile_settings
from viva_sitl.gym.scenario import Scenario, default_spec, resolve_spec, with_footage
from viva_sitl.world import world_from_source


class SharedFootageVectorEnv(VectorEnv[Any, Any, Any]):
    """`num_envs` LandingEnv copies sharing the footage decode; `env_kwargs` are LandingEnv's keyword arguments
    (env_config= and/or the flat settings, scorer=, scenario_drawer=). Drives the copies through their public
    FuncEnv-style split (next_scenario + initial, check_action + transition + step_result), and shares the clock
    through their footage_clock seam."""

    def __init__(
        self,
        num_envs: int,
        footage: str | Path | None = None,
        render_mode: str | None = None,
        convert_shared: bool = False,
        **env_kwargs: Any,
    ) -> None:
        if int(num_envs) < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        env_kwargs.pop("max_episode_steps", None)  # make_vec adds it; the env truncates on max_episode_s
        self.num_envs = int(num_envs)
        self.render_mode = render_mode
        self.convert_shared = convert_shared
        # the copies' settings (LandingEnvConfig from env_config= and the flat keyword arguments); the rest of
        # env_kwargs are LandingEnv's seams (scorer, scenario_drawer)
        settings = {k: env_kwargs.pop(k) for k in list(env_kwargs) if k in FLAT_KWARGS}
        config = LandingEnvConfig.from_kwargs(env_kwargs.pop("env_config", None), **settings)
        spec = config.scenario.spec
        trial_spec = resolve_spec(spec) if spec is not None else None
        if footage is None:
            footage = trial_spec.footage[0] if trial_spec is not None else "synthetic"
        spec = default_spec(str(footage)) if trial_spec is None else with_footage(trial_spec, str(footage))
        self.config = replace(config, scenario=ScenarioConfig(spec))
        cfg = config.sim
        opts: dict[str, Any] = {"tiles": gym_tile_settings()}
        if cfg is not None:
            opts |= {"altitude_m": cfg.footage_alt_m, "hfov_deg": cfg.footage_hfov_deg,
                     "gsd_m_per_px": cfg.footage_gsd_m_per_px}  # fmt: skip
        self._open = lambda: open_footage(footage, **opts)
        first = self._open()
        self._sources: dict[float, FootageSource] = {0.0: first}  # slot offset (s) -> its shared source
        world = world_from_source(first)
        # a procedural ground (the synthetic field) has nothing to decode, and its window follows ONE view: each
        # copy gets its own; footage that is decoded is shared
        self._per_copy = isinstance(first, SyntheticField)
        self._owned: list[FootageSource] = [first]
        sources = (
            [first] + [self._open() for _ in range(self.num_envs - 1)]
            if self._per_copy
            else [first] * self.num_envs
        )
        if self._per_copy:
            self._owned = list(sources)
        self.envs = [
            LandingEnv(src, env_config=self.config, render_mode=render_mode, world=world,
                       footage_clock=self._bind, **env_kwargs)
            for src in sources
        ]  # fmt: skip
        e0 = self.envs[0]
        self.single_observation_space = e0.observation_space
        self.single_action_space = e0.action_space
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.metadata = {**e0.metadata, "autoreset_mode": AutoresetMode.NEXT_STEP}
        self._global_k = 0  # control steps since the last reset() (the shared schedule and clock)
        self._schedule = ControlSchedule(e0.rate_hz, self.config.control_hz)  # the global control schedule
        self._global_steps = 0  # physics steps since then
        self._autoreset = np.zeros(self.num_envs, dtype=np.bool_)
        obs_cfg = self.config.observation
        self._direct_views = obs_cfg.images and obs_cfg.frame_stack == 1 and not obs_cfg.grayscale
        self._raise_out_of_range = self.config.action.out_of_range == "raise"

    # --- sharing ----------------------------------------------------------------------------------
    def _source_for(self, offset_s: float) -> FootageSource:
        src = self._sources.get(offset_s)
        if src is None:
            src = self._sources[offset_s] = self._open()
        return src

    def _bind(self, scenario: Scenario, dt_s: float) -> FootageBinding:
        """The copies' footage clock (LandingEnv.initial asks it): a copy starting `scenario` flies its offset
        slot's source (its own for per-copy footage), with the footage offset and control phase of the global
        clock."""
        base = scenario.footage_time_s
        source = None if self._per_copy else self._source_for(base)
        return FootageBinding(source, base + self._global_steps * dt_s, self._global_k)

    # --- VectorEnv API ----------------------------------------------------------------------------
    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        if seed is None:
            seeds: list[int | None] = [None] * self.num_envs
        elif isinstance(seed, int):
            seeds = [seed + i for i in range(self.num_envs)]
        else:
            seeds = list(seed)
            if len(seeds) != self.num_envs:
                raise ValueError(f"reset: {len(seeds)} seeds for {self.num_envs} environments")
        self._global_k, self._global_steps = 0, 0
        infos: dict[str, Any] = {}
        obs = []
        out = self._new_batch()
        for i, env in enumerate(self.envs):
            o, info = env.initial(env.next_scenario(seed=seeds[i], options=options), self._slot(out, i))
            obs.append(o)
            infos = self._add_info(infos, info, i)
        self._autoreset[:] = False
        return self._batch(obs, out), infos

    def step(self, actions: Any) -> tuple[Any, NDArray[np.float64], NDArray[np.bool_], NDArray[np.bool_], dict[str, Any]]:  # fmt: skip
        a = np.asarray(actions, dtype=np.float64)
        if a.shape != (self.num_envs, 4):
            raise ValueError(f"actions must have shape ({self.num_envs}, 4), got {a.shape}")
        checked = self._check_actions(a)
        # physics of every copy first, then the views grouped by footage source (each frame decoded once)
        for i, env in enumerate(self.envs):
            c = checked[i]
            if c is not None:
                env.transition(c[0])
        rewards = np.zeros(self.num_envs, dtype=np.float64)
        terminated = np.zeros(self.num_envs, dtype=np.bool_)
        truncated = np.zeros(self.num_envs, dtype=np.bool_)
        infos: dict[str, Any] = {}
        obs: list[Any] = [None] * self.num_envs
        self._global_steps += self._schedule.steps(self._global_k)
        self._global_k += 1
        order = sorted(range(self.num_envs), key=lambda j: id(self.envs[j].footage))
        self._convert_shared_frames(order, checked)
        out = self._new_batch()
        for i in order:
            env = self.envs[i]
            c = checked[i]
            if c is None:
                obs[i], info = env.initial(env.next_scenario(), self._slot(out, i))
            else:
                obs[i], r, term, trunc, info = env.step_result(c[1], self._slot(out, i))
                rewards[i], terminated[i], truncated[i] = r, term, trunc
            infos = self._add_info(infos, info, i)
        self._autoreset = terminated | truncated
        return self._batch(obs, out), rewards, terminated, truncated, infos

    def _check_actions(self, a: NDArray[np.float64]) -> list[tuple[NDArray[np.float64], bool] | None]:
        """LandingEnv.check_action of each copy's row (None for a copy that autoresets this step), tested for the
        whole batch at once: two numpy reductions per vector step instead of two per copy. A row that fails (not
        finite, or out of range with out_of_range="raise") goes through the copy's own check for its error."""
        finite = cast(list[bool], np.isfinite(a).all(axis=1).tolist())
        over = cast(list[bool], (np.abs(a) > 1.0).any(axis=1).tolist())
        checked: list[tuple[NDArray[np.float64], bool] | None] = []
        for i, env in enumerate(self.envs):
            if self._autoreset[i]:
                checked.append(None)
            elif not finite[i] or (over[i] and self._raise_out_of_range):
                checked.append(env.check_action(a[i]))  # raises ValueError with the single env's message
            else:
                checked.append((np.clip(a[i], -1.0, 1.0), True) if over[i] else (a[i], False))
        return checked

    def _convert_shared_frames(self, order: list[int], checked: list[Any]) -> None:
        """Convert each shared video frame to BGR once when two or more copies will render it: their region reads
        are then slices of that one conversion (the decoder's own reuse, bit-identical to converting each region)
        instead of one YUV->BGR conversion per copy."""
        if not self.convert_shared or self._per_copy or not self.config.observation.images:
            return
        users: dict[tuple[int, int], list[int]] = {}
        for i in order:
            env = self.envs[i]
            if checked[i] is None or not isinstance(env.footage, VideoSource):
                continue
            users.setdefault((id(env.footage), env.footage.frame_index_at(env.footage_time_s)), []).append(i)
        for (_, index), copies in users.items():
            if len(copies) >= 2:
                self.envs[copies[0]].footage.frame(index)

    def _new_batch(self) -> Any:
        """A new batched observation to fill (each step's is the caller's to keep). With one RGB view per copy
        (frame_stack 1) the copies convert their views straight into its image slots (`LandingEnv.view(out=)`)."""
        if not self._direct_views:
            return None
        e0 = self.envs[0]
        h, w = e0.image_size_hw
        return {"image": np.empty((self.num_envs, h, w, 3), np.uint8),
                "state": np.empty((self.num_envs, len(e0.state_fields)), np.float32)}  # fmt: skip

    @staticmethod
    def _slot(out: Any, i: int) -> NDArray[np.uint8] | None:
        """Copy i's image slot in the batch (where its view is rendered), None without a direct batch."""
        return None if out is None else cast(NDArray[np.uint8], out["image"][i])

    def _batch(self, obs: list[Any], out: Any = None) -> Any:
        if out is None:
            out = create_empty_array(self.single_observation_space, self.num_envs)
            return concatenate(self.single_observation_space, obs, out)
        images = out["image"]
        for i, o in enumerate(obs):
            if o["image"].ctypes.data != images[i].ctypes.data:
                images[i] = o["image"]  # not written in place
        np.stack([o["state"] for o in obs], out=out["state"])
        return out

    def render(self) -> tuple[NDArray[np.uint8], ...] | None:
        if self.render_mode is None:
            return None
        return tuple(img for env in self.envs if (img := env.render()) is not None)

    def close_extras(self, **kwargs: Any) -> None:
        for src in {id(s): s for s in [*self._owned, *self._sources.values()]}.values():
            src.close()
        self._sources.clear()
        self._owned.clear()

    @property
    def decoded_sources(self) -> int:
        """How many FootageSources (offset slots) are open: each decodes at most one frame per step."""
        return len(self._sources)


__all__ = ["SharedFootageVectorEnv"]
