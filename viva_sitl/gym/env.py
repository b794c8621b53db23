"""Gymnasium landing environments over the ONE vehicle loop (viva_sitl.vehicle.Vehicle).

    import gymnasium as gym, viva_sitl.gym
    env = gym.make("viva_sitl/Landing-v0", footage="synthetic", image_size=(160, 120))
    obs, info = env.reset(seed=0)            # obs = {"image": HxWxC uint8 (RGB), "state": float32[10]}
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Settings: a LandingEnvConfig (viva_sitl.gym.config: observation / action / termination / scenario groups, `env_config=`)
and/or the flat keyword arguments named below (action_mode, observation, image_size, spec, config, ...), which set
its fields. The step is split as Gymnasium's FuncEnv, public: reset = next_scenario + initial; step = check_action +
transition + step_result, step_result = reward + terminal + observation (SharedFootageVectorEnv drives these).

Actions (`action_mode`, one viva_sitl.gym.actions.ActionMode object each):
- "attitude" (default): viva-safeland DroneEnv's normalised [roll, pitch, yaw-rate, thrust] in [-1, 1]: roll =
  max_tilt_deg x a0, pitch = max_tilt_deg x a1 (its sign convention: +a1 = its +theta = nose down in NED terms is
  -pitch), yaw rate = max_yaw_rate_deg_s x a2 (its +psi is counter-clockwise seen from above), thrust = m g (1 + a3);
  [0, 0, 0, 0] hovers. Flown with Vehicle.step_command (autopilot bypassed) for one control period, through the
  airframe's attitude response (default: a small PX4 quadcopter's lag and rate limits; DroneEnv's instant attitude
  with config=SimConfig(physics=EavParams().with_ideal_attitude())).
- "velocity": [v_north, v_east, v_down, yaw-rate] in [-1, 1] x (max_speed_m_s, max_speed_m_s, max_vspeed_m_s,
  max_yaw_rate_deg_s): an offboard velocity setpoint to the autopilot (OFFBOARD mode, as MAVSDK's
  set_velocity_ned), flown with Vehicle.step.
- "velocity_land": "velocity" with a landing assist (the autopilot's land phase, for policies that should learn WHERE
  to land and leave the touchdown to the autopilot): at every physics step, below MPC_LAND_ALT1 above ground the
  commanded descent is limited as PX4's Land limits it (MPC_LAND_SPEED below MPC_LAND_ALT2, blended linearly up to
  MPC_Z_VEL_MAX_DN at MPC_LAND_ALT1; the vehicle's parameters, so a scenario's drawn MPC_LAND_SPEED counts) and the
  horizontal speed likewise (`land_xy_m_s` below MPC_LAND_ALT2, blended up to max_speed_m_s at MPC_LAND_ALT1;
  a command over it is scaled down, direction kept). Climbing is never limited. land_assist_limits() is the rule.
Each env step is one control period (1/control_hz s) of physics: n = 8 or 9 steps of 250 Hz physics at 30 Hz, the
same schedule as viva-safeland-comparison benches (round((k+1) rate/hz) - round(k rate/hz)).

Bad actions: a NaN/inf or wrongly shaped action raises ValueError with a one-line message (the vehicle is not
stepped); an out-of-range action is clipped to [-1, 1] (`info["action_clipped"]` says so) or, with
out_of_range="raise", raises ValueError.

Observation (`observation`): "image+state" -> Dict(image, state); "state" -> the state Box only (no rendering).
image: the VAC view, `image_size` (w, h), RGB (or grayscale HxWx1), `frame_stack` k > 1 concatenates the last k
views along the channel axis (oldest first). state (float32): north, east, down (m), v_north, v_east, v_down (m/s),
roll, pitch, yaw (rad), altitude above ground (m).
PRIVILEGED ground truth (`ground_truth_obs=True`, off by default; like the oracle pilot, NOT something a real vehicle's
sensors give): the state vector is extended by ground_truth_fields(ground_grid): the world model's risk level
(1..5, WorldModel.risk_levels_at: the ground's, raised near people and cars) at a ground_grid x ground_grid grid of
points ground_cell_m apart centred under the vehicle, NED axes (row-major, north first: risk[i][j] at north offset
(i - (g-1)/2) x cell, east offset (j - (g-1)/2) x cell), then the nearest person's north, east offset and distance
(m, centres; clamped to people_range_m along the same direction, distance people_range_m when nobody is nearer),
all at the footage time the scorer judges. For policies that should learn what ground-aware landing buys before a
perception model provides it (bench/results_gym.md); a non-privileged policy uses the image.

Scenarios (viva_sitl.gym.scenario): the landing trials' (`spec=` a trials TOML or TrialSpec): reset(seed=s) flies
the scenario `viva-sitl trials run SPEC --seed s` flies as trial 0, each reset() without a seed the next trial
(options={"trial": k}: trial k; options={"scenario": Scenario}: that one). The scenario's start pose, footage time,
wind, PX4 parameters, physics seed and failures (failure injection, "land now" event: the trials' TrialMonitor
applies them) are flown as in the trials; the policy is in control from the start (air start; OFFBOARD in velocity
mode).
Termination and scores: the trials' (viva_sitl.gym.scoring): the episode ends when the trial would (landed =
touchdown + disarm: the env disarms at the first control step on the ground; crash; left_footage; timeout ->
truncated; max_episode_s overrides the spec's timeout_s), and the last step's info["trial"] is the trial's score
row (viva_sitl.evaluation.scoring, the row `trials run` writes). Reward: the Scorer seam (default LandingReward:
shaping + the row's outcome, RewardConfig).
`render()` (render_mode="rgb_array"): the overview, the footage frame at the current footage time with the risk map,
the objects, the vehicle and its camera footprint (RGB).
"""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any, NamedTuple

import cv2
import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavState
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.episode import ControlSchedule, Episode, limits_of, prepare
from viva_sitl.evaluation.monitor import Limits, TrialMonitor
from viva_sitl.evaluation.spec import Scenario, TrialSpec, footage_box_of
from viva_sitl.footage import FootageSource, open_footage
from viva_sitl.footage.synthetic import SyntheticField
from viva_sitl.footage.tiles.settings import TileSettings
from viva_sitl.gym.actions import ActionMode, action_mode, assisted_velocity, land_assist_limits
from viva_sitl.gym.config import (
    ACTION_MODES,
    OBSERVATIONS,
    STATE_FIELDS,
    LandingEnvConfig,
    ground_truth_fields,
)
from viva_sitl.gym.scenario import (
    ScenarioDrawer,
    SpecScenarioDrawer,
    default_spec,
    resolve_spec,
    with_footage,
)
from viva_sitl.gym.scoring import LandingReward, Scorer
from viva_sitl.vehicle import Vehicle
from viva_sitl.world import PEOPLE, WorldModel, world_from_source


class FootageBinding(NamedTuple):
    """Where an episode's views come from: `source` (None: the env's own), the footage offset (footage time at sim
    time 0) and the control schedule's phase `k0`."""

    source: FootageSource | None
    offset_s: float
    k0: int = 0


# a vector env's seam: (the scenario starting, the physics step) -> the copy's binding on the shared clock
FootageClock = Callable[[Scenario, float], FootageBinding]

StepResult = tuple[Any, float, bool, bool, dict[str, Any]]


class LandingEnv(gym.Env[Any, NDArray[np.float32]]):
    """Land the EAV over footage. See the module docstring for spaces, actions, reward and seams.

    Settings: `env_config` (LandingEnvConfig) and/or the flat keyword arguments (FLAT_KWARGS: action_mode,
    observation, image_size, spec, config, ...), which set its fields. Seams: `footage` (a name, path or a shared
    FootageSource), `world`, `scorer`, `scenario_drawer`, `footage_clock` (a vector env's shared clock).
    The step split as Gymnasium's FuncEnv: `reset` = next_scenario + initial; `step` = check_action + transition +
    step_result, where step_result = reward + terminal + observation (the vector env drives these)."""

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        footage: str | Path | FootageSource | None = None,
        *,
        env_config: LandingEnvConfig | None = None,
        render_mode: str | None = None,
        scenario_drawer: ScenarioDrawer | None = None,
        scorer: Scorer | None = None,
        world: WorldModel | None = None,
        footage_clock: FootageClock | None = None,
        **settings: Any,
    ) -> None:
        cfg = LandingEnvConfig.from_kwargs(env_config, **settings)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.config, self.render_mode, self.footage_clock = cfg, render_mode, footage_clock
        obs_cfg = cfg.observation
        self.trial_spec = self._trial_spec(footage, cfg.scenario.spec)
        if footage is None:
            footage = self.trial_spec.footage[0]
        self.max_episode_s = float(
            self.trial_spec.timeout_s
            if cfg.termination.max_episode_s is None
            else cfg.termination.max_episode_s
        )
        self.limits: Limits = replace(limits_of(self.trial_spec), timeout_s=self.max_episode_s)
        self._grid_dn_m, self._grid_de_m = obs_cfg.ground_offsets_m()
        self.state_fields = obs_cfg.state_fields
        self.metadata = {**self.metadata, "render_fps": cfg.control_hz}

        w, h = obs_cfg.image_size
        base = cfg.sim or SimConfig()
        sim_cfg = replace(base, camera=replace(base.camera, width_px=w, height_px=h))
        # footage by name/path: this env owns it; a FootageSource passed in is shared (vector env) and not closed
        self._owns_footage = not isinstance(footage, FootageSource)
        self.footage = source = _env_footage(footage, sim_cfg)
        self.vehicle = Vehicle(
            sim_cfg, footage=source, geofence=True, super_resolution=_super_resolution(sim_cfg)
        )
        self._params0 = {n: self.vehicle.params.stored(n) for n in self.vehicle.params.names()}
        self.world = world if world is not None else world_from_source(source)
        self.scorer: Scorer = (
            scorer if scorer is not None else LandingReward(self.world, self.trial_spec, cfg.reward)
        )
        self.scenario_drawer: ScenarioDrawer = scenario_drawer or SpecScenarioDrawer(
            self.trial_spec, footage_box_of(source)
        )
        self.actions: ActionMode = action_mode(cfg.action)
        # the scenario flown (footage_time_s: the footage clock at the start)
        self.scenario: Scenario | None = None
        self.episode: Episode | None = None  # the trial being flown (viva_sitl.evaluation.episode)
        self.trial_seed: int | None = None
        self.trial_index = 0
        self.rate_hz = 1.0 / self.vehicle.dt_s
        self.schedule = ControlSchedule(self.rate_hz, cfg.control_hz)  # physics steps per env step

        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        self.observation_space: spaces.Space[Any] = obs_cfg.space()
        self.image_size_hw = (h, w)
        self._frames: deque[NDArray[np.uint8]] = deque(maxlen=obs_cfg.frame_stack)
        self._k = 0  # control steps this episode

    @staticmethod
    def _trial_spec(
        footage: str | Path | FootageSource | None, spec: str | Path | TrialSpec | None
    ) -> TrialSpec:
        """The spec the episodes draw from: `spec` over `footage` (the spec's own footage without one), or the
        default spec over `footage` (synthetic without one)."""
        trial_spec = resolve_spec(spec) if spec is not None else None
        if footage is None:
            footage = trial_spec.footage[0] if trial_spec is not None else "synthetic"
        if trial_spec is None:
            return default_spec(footage.metadata.name if isinstance(footage, FootageSource) else str(footage))
        if not isinstance(footage, FootageSource):
            return with_footage(trial_spec, str(footage))
        return trial_spec

    # --- settings (read-only views of self.config) --------------------------------------------------
    @property
    def action_mode(self) -> str:
        return self.config.action.mode

    @property
    def out_of_range(self) -> str:
        return self.config.action.out_of_range

    @property
    def control_hz(self) -> float:
        return self.config.control_hz

    @property
    def grayscale(self) -> bool:
        return self.config.observation.grayscale

    @property
    def frame_stack(self) -> int:
        return self.config.observation.frame_stack

    @property
    def ground_truth_obs(self) -> bool:
        return self.config.observation.ground_truth_obs

    # --- helpers ----------------------------------------------------------------------------
    @property
    def footage_time_s(self) -> float:
        return self.vehicle.time_s + self.vehicle.sim.footage_offset_s

    def assisted_velocity(self, vel_ned_m_s: tuple[float, float, float]) -> tuple[float, float, float]:
        """A commanded NED velocity limited by the landing assist at the vehicle's current altitude above ground
        ("velocity_land" mode; viva_sitl.gym.actions.assisted_velocity with this env's land_xy_m_s, max_speed_m_s)."""
        a = self.config.action
        return assisted_velocity(self.vehicle, vel_ned_m_s, float(a.land_xy_m_s), float(a.max_speed_m_s))

    @property
    def monitor(self) -> TrialMonitor | None:
        """The trial's referee (the episode's)."""
        return None if self.episode is None else self.episode.monitor

    def _state_vec(self, s: EavState) -> NDArray[np.float32]:
        v = s.vel_ned_m_s
        p = s.pos_ned_m
        ground = self.vehicle.sim.params.ground_z_ned_m
        vec = np.array([p[0], p[1], p[2], v[0], v[1], v[2], s.roll_rad, s.pitch_rad, s.yaw_rad, ground - p[2]],
                       dtype=np.float32)  # fmt: skip
        if not self.config.observation.ground_truth_obs:
            return vec
        return np.concatenate([vec, self.ground_truth(float(p[0]), float(p[1]), self.footage_time_s)])

    def ground_truth(self, north_m: float, east_m: float, footage_time_s: float) -> NDArray[np.float32]:
        """The PRIVILEGED ground-truth fields (ground_truth_fields) at a point and footage time, from the world
        model: the risk grid around (north, east), then the nearest person's offset and distance (clamped to
        people_range_m)."""
        risk = self.world.risk_levels_at(north_m + self._grid_dn_m, east_m + self._grid_de_m, footage_time_s)
        near = (
            self.world.tracks.nearest(north_m, east_m, footage_time_s, PEOPLE)
            if self.world.has_objects
            else None
        )
        r = self.config.observation.people_range_m
        if near is None:
            person = (0.0, 0.0, r)
        else:
            dn, de, d = near.ne_m[0] - north_m, near.ne_m[1] - east_m, near.distance_m
            f = min(1.0, r / d) if d > 0.0 else 1.0
            person = (dn * f, de * f, min(d, r))
        return np.concatenate([risk.astype(np.float32), np.array(person, np.float32)])

    def view(self, out: NDArray[np.uint8] | None = None) -> NDArray[np.uint8]:
        """The VAC image as observed (RGB or grayscale HxWx1), one view (no stacking). `out`: an HxWx3 uint8
        C-contiguous array to convert the RGB view into (a vector env's batch slot: no second copy)."""
        veh = self.vehicle
        veh.apply_gimbal()  # as Vehicle.render
        if self.config.observation.grayscale:
            rgb = veh.sim.render_rgb()  # the image only (no frame metadata), converted once to RGB
            return np.asarray(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)[:, :, None], dtype=np.uint8)
        return veh.sim.render_rgb(out=out)

    def check_action(self, action: Any) -> tuple[NDArray[np.float64], bool]:
        """The action as flown (float64, clipped unless out_of_range='raise') and whether it was clipped; ValueError
        with one line for a malformed one."""
        try:
            a = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(f"action must be 4 numbers in [-1, 1], got {action!r}") from None
        if a.shape != (4,):
            raise ValueError(f"action must have shape (4,), got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"action must be finite, got {a.tolist()}")
        clipped = bool(np.any(np.abs(a) > 1.0))
        if clipped:
            if self.config.action.out_of_range == "raise":
                raise ValueError(f"action out of [-1, 1]: {a.tolist()}")
            a = np.clip(a, -1.0, 1.0)
        return a, clipped

    # --- gymnasium API ---------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """A new episode: trial 0 of `seed` (the trials' drawing), or the next trial without a seed. options:
        {"trial": k} flies trial k of the current seed; {"scenario": Scenario} flies that scenario."""
        return self.initial(self.next_scenario(seed=seed, options=options))

    def next_scenario(self, *, seed: int | None = None, options: dict[str, Any] | None = None) -> Scenario:
        """The scenario reset(seed=, options=) flies (seeds the env's np_random as gymnasium's reset does)."""
        super().reset(seed=seed)
        opts = options or {}
        if seed is not None:
            self.trial_seed, self.trial_index = int(seed), 0
        elif self.trial_seed is None:
            self.trial_seed, self.trial_index = int(self.np_random.integers(2**31 - 1)), 0
        else:
            self.trial_index += 1
        if "trial" in opts:
            k = opts["trial"]
            if isinstance(k, bool) or not isinstance(k, int | np.integer) or k < 0:
                raise ValueError(f"options['trial'] must be an integer >= 0, got {k!r}")
            self.trial_index = int(k)
        sc = opts.get("scenario")
        if sc is None:
            sc = self.scenario_drawer(self.trial_seed, self.trial_index)
        elif not isinstance(sc, Scenario):
            raise ValueError(
                f"options['scenario'] must be a viva_sitl.evaluation.spec.Scenario, got {type(sc).__name__}"
            )
        if sc.start != "air":
            raise ValueError(
                f"gym environments start in the air, scenario {sc.index} starts on the {sc.start}"
            )
        return sc

    def initial(self, sc: Scenario, out: NDArray[np.uint8] | None = None) -> tuple[Any, dict[str, Any]]:
        """Start an episode of scenario `sc` (FuncEnv's initial): the vehicle set up as every trial is
        (viva_sitl.evaluation.episode.prepare: the PX4 parameters back to the env's, then the scenario's, the
        footage clock, the physics seed, the start pose) on the footage binding (the footage clock's, a vector
        env's shared source and clock; else this env's footage at the scenario's footage time), the action mode
        started. Returns the first observation (its view rendered into `out`, see observation) and info."""
        veh = self.vehicle
        binding = (
            FootageBinding(None, sc.footage_time_s)
            if self.footage_clock is None
            else self.footage_clock(sc, veh.dt_s)
        )
        if binding.source is not None and veh.sim.footage is not binding.source:
            # the same file, so the same geometry: renderer and region buffers stay valid
            veh.sim.footage = self.footage = binding.source
        veh.sim.footage_offset_s = binding.offset_s
        self.schedule = ControlSchedule(self.rate_hz, self.config.control_hz, k0=binding.k0)
        if isinstance(self.footage, SyntheticField):
            self.footage.forget_windows()  # the views depend on this episode's poses only
        prepare(veh, sc, baseline_params=self._params0, footage_offset_s=veh.sim.footage_offset_s)
        self.episode = Episode(veh, sc, self.limits, gcs=True, prepare_vehicle=False)
        sc = self.scenario = self.episode.scenario  # its footage_time_s: the footage clock this copy flies
        state = veh.state
        self.actions.start(veh, sc)
        self.scorer.reset(sc, state, self.footage_time_s)
        self._k = 0
        self._frames.clear()
        info = self._info({})
        info.update(trial_seed=self.trial_seed, trial_index=sc.index)
        return self.observation(out), info

    def _info(self, score: dict[str, Any], clipped: bool = False) -> dict[str, Any]:
        return {
            "time_s": self.vehicle.time_s,
            "footage_time_s": self.footage_time_s,
            "footage_offset_s": self.vehicle.sim.footage_offset_s,
            "score": score,
            "action_clipped": clipped,
        }

    def step(self, action: Any) -> StepResult:
        if self.scenario is None:
            raise RuntimeError("call reset() before step()")
        a, clipped = self.check_action(action)
        self.transition(a)
        return self.step_result(clipped)

    def transition(self, a: NDArray[np.float64]) -> None:
        """Fly one control period with a checked action (check_action) through the action mode, each physics step
        the episode's (the Vehicle loop, judged by the trial's referee as in the trials runner); the period stops
        early when the trial ends. On the ground afterwards: disarm (force, as a pilot's disarm/kill at touchdown),
        the trial ends "landed" one physics step later."""
        veh = self.vehicle
        ep = self.episode
        assert ep is not None
        n = self.schedule.steps(self._k)
        self.actions.fly(ep, veh, a, n)
        if ep.monitor.log.end is None and veh.state.landed and veh.autopilot.armed:
            veh.autopilot.disarm(veh.time_s, force=True)
            ep.step(None)
        self._k += 1

    def reward(self) -> tuple[float, dict[str, Any]]:
        """After a transition, once: the Scorer's reward for the state reached (the scorer may end the trial), plus
        its final reward over the trial's score row once the trial ended. Returns (reward, info): info["score"] the
        scorer's step info, info["trial"] the score row when the trial ended."""
        veh, mon = self.vehicle, self.monitor
        assert mon is not None
        step = self.scorer.step(veh.state, self.footage_time_s)
        if step.terminated and mon.log.end is None:
            mon.end(veh, TrialEnd.SCORER, "the scorer ended the episode")
        info: dict[str, Any] = {"score": step.info}
        reward = float(step.reward)
        if mon.log.end is not None:
            row = self.trial_row()
            reward += float(self.scorer.final(row))
            info["trial"] = row
        return reward, info

    def terminal(self) -> tuple[bool, bool]:
        """(terminated, truncated): the trial ended, by its time limit (truncated) or otherwise (terminated)."""
        mon = self.monitor
        end = None if mon is None else mon.log.end
        return end is not None and end != TrialEnd.TIMEOUT, end == TrialEnd.TIMEOUT

    def observation(self, out: NDArray[np.uint8] | None = None) -> Any:
        """The observation of the state reached (after initial or a transition, once: with images, it renders the
        new view and stacks it). `out`: where to render an RGB view (see view)."""
        state = self._state_vec(self.vehicle.state)
        if not self.config.observation.images:
            return state
        self._frames.append(self.view(out))
        while len(self._frames) < self.config.observation.frame_stack:
            self._frames.appendleft(self._frames[0])
        stack = self.config.observation.frame_stack
        image = self._frames[0] if stack == 1 else np.concatenate(list(self._frames), axis=2)
        return {"image": image, "state": state}

    def step_result(self, clipped: bool, out: NDArray[np.uint8] | None = None) -> StepResult:
        """After `transition`: reward, terminal, info (the trial's score row once it ended) and observation (its
        view rendered into `out`) — `step` is check_action + transition + step_result."""
        reward, extra = self.reward()
        terminated, truncated = self.terminal()
        info = self._info(extra["score"], clipped)
        if "trial" in extra:
            info["trial"] = extra["trial"]
        return self.observation(out), reward, terminated, truncated, info

    def trial_row(self) -> dict[str, Any]:
        """The trial's score row so far (final once the episode ended): viva_sitl.evaluation.scoring.score_trial over
        the monitor's log, as `viva-sitl trials run` computes it (pilot "gym", wall_s null)."""
        assert self.episode is not None
        row = self.episode.row(self.world, self.trial_spec)
        row["pilot"] = "gym"
        return dict(row)

    def render(self) -> NDArray[np.uint8] | None:  # type: ignore[override]
        if self.render_mode is None:
            return None
        return overview_rgb(self, self.config.overview_px)

    def close(self) -> None:
        if self._owns_footage:
            self.vehicle.close()


def gym_tile_settings() -> TileSettings:
    """How a gym environment reads tile caches: the documented $VIVA_SITL_TILE_CACHE_MB /
    $VIVA_SITL_TILE_DECODE_THREADS / $VIVA_SITL_TILE_READ_AHEAD, read here (the gym is the top floor for its users;
    the footage layer reads no environment); a bad value is one FootageError line."""
    return TileSettings.from_environ(os.environ)


def _env_footage(footage: str | Path | FootageSource, cfg: SimConfig) -> FootageSource:
    """`footage` opened with the config's footage geometry (a FootageSource as it is), a synthetic field drawn in
    line."""
    source = footage if isinstance(footage, FootageSource) else open_footage(
        footage, altitude_m=cfg.footage_alt_m, hfov_deg=cfg.footage_hfov_deg, gsd_m_per_px=cfg.footage_gsd_m_per_px,
        tiles=gym_tile_settings(),
    )  # fmt: skip
    if isinstance(source, SyntheticField) and source.params.draw_ahead:
        # which window the draw-ahead thread delivers depends on thread timing (a busy worker skips one), and
        # windows differ by a grey level: draw in line so that seeded rollouts are bit-identical
        source.params = replace(source.params, draw_ahead=False)
    return source


def _super_resolution(config: SimConfig) -> Any:
    """The config's [perception.sr] render hook (None without one), loaded once per env."""
    if config.perception.sr.method.value == "none":
        return None
    from viva_sitl.perception.from_config import super_resolution_from_config

    return super_resolution_from_config(config)


def overview_rgb(env: LandingEnv, max_px: int) -> NDArray[np.uint8]:
    """The footage frame at the env's footage time (risk + objects, viva_sitl.world.overlay), the vehicle and its
    camera footprint drawn on it; RGB."""
    from viva_sitl.camera.projection import footprint_px
    from viva_sitl.world.overlay import render_overview

    t = env.footage_time_s
    img = render_overview(env.world, env.footage, t, max_size_px=max_px, show_ids=False)
    g = env.footage.geometry
    scale = img.shape[1] / g.width_px
    s = env.vehicle.state
    quad = footprint_px(g, env.vehicle.sim.camera, s.pos_ned_m, s.att_rpy_rad)
    if quad is not None:
        pts = np.array([[(u + 0.5) * scale - 0.5, (v + 0.5) * scale - 0.5] for u, v in quad], np.float64)
        cv2.polylines(
            img, [np.round(pts * 16).astype(np.int32)], True, (0, 255, 255), 2, cv2.LINE_AA, shift=4
        )
    u, v = g.ned_to_px(float(s.pos_ned_m[0]), float(s.pos_ned_m[1]))
    c = (round((u + 0.5) * scale - 0.5), round((v + 0.5) * scale - 0.5))
    cv2.circle(img, c, 6, (0, 0, 255), 2, cv2.LINE_AA)
    cv2.putText(img, f"alt {s.altitude_m:.1f} m", (c[0] + 8, c[1] - 8), cv2.FONT_HERSHEY_SIMPLEX, 0.45,
                (0, 0, 255), 1, cv2.LINE_AA)  # fmt: skip
    return np.ascontiguousarray(img[:, :, ::-1])


__all__ = [
    "ACTION_MODES",
    "FootageBinding",
    "FootageClock",
    "LandingEnvConfig",
    "OBSERVATIONS",
    "STATE_FIELDS",
    "LandingEnv",
    "ground_truth_fields",
    "land_assist_limits",
    "overview_rgb",
]
