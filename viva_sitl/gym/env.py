"""Gymnasium landing environments over the ONE vehicle loop (viva_sitl.vehicle.Vehicle).

    import gymnasium as gym, viva_sitl.gym
    env = gym.make("viva_sitl/Landing-v0", footage="synthetic", image_size=(160, 120))
    obs, info = env.reset(seed=0)            # obs = {"image": HxWxC uint8 (RGB), "state": float32[10]}
    obs, reward, terminated, truncated, info = env.step(env.action_space.sample())

Actions (`action_mode`):
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

import math
from collections import deque
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import cv2
import gymnasium as gym
import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from viva_sitl.autopilot.types import FlightMode, PositionTarget
from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavCommand, EavState
from viva_sitl.evaluation.ends import TrialEnd
from viva_sitl.evaluation.episode import ControlSchedule, Episode, limits_of, prepare
from viva_sitl.evaluation.monitor import Limits, TrialMonitor
from viva_sitl.evaluation.spec import Scenario, TrialSpec, footage_box_of
from viva_sitl.footage import FootageSource, open_footage
from viva_sitl.footage.synthetic import SyntheticField
from viva_sitl.gym.scenario import (
    ScenarioDrawer,
    SpecScenarioDrawer,
    default_spec,
    resolve_spec,
    with_footage,
)
from viva_sitl.gym.scoring import LandingReward, RewardConfig, Scorer
from viva_sitl.vehicle import Vehicle
from viva_sitl.world import PEOPLE, WorldModel, world_from_source

ACTION_MODES = ("attitude", "velocity", "velocity_land")
OBSERVATIONS = ("image+state", "state")
STATE_FIELDS = ("north_m", "east_m", "down_m", "v_north_m_s", "v_east_m_s", "v_down_m_s",
                "roll_rad", "pitch_rad", "yaw_rad", "alt_agl_m")  # fmt: skip


def ground_truth_fields(grid: int) -> tuple[str, ...]:
    """Names of the PRIVILEGED fields `ground_truth_obs=True` appends to the state vector (risk grid row-major from
    the north-west corner, then the nearest person's offset and distance)."""
    return tuple(f"risk_{i}_{j}" for i in range(grid) for j in range(grid)) + (
        "person_north_m", "person_east_m", "person_dist_m",
    )  # fmt: skip


class LandingEnv(gym.Env[Any, NDArray[np.float32]]):
    """Land the EAV over footage. See the module docstring for spaces, actions, reward and seams."""

    metadata: dict[str, Any] = {"render_modes": ["rgb_array"], "render_fps": 30}

    def __init__(
        self,
        footage: str | Path | FootageSource | None = None,
        *,
        spec: str | Path | TrialSpec | None = None,
        action_mode: str = "attitude",
        observation: str = "image+state",
        image_size: tuple[int, int] = (160, 120),
        grayscale: bool = False,
        frame_stack: int = 1,
        control_hz: float = 30.0,
        max_episode_s: float | None = None,
        config: SimConfig | None = None,
        scenario_drawer: ScenarioDrawer | None = None,
        reward: RewardConfig | None = None,
        scorer: Scorer | None = None,
        world: WorldModel | None = None,
        max_tilt_deg: float = 15.0,
        max_yaw_rate_deg_s: float = 30.0,
        max_speed_m_s: float = 5.0,
        max_vspeed_m_s: float = 3.0,
        land_xy_m_s: float = 0.0,
        ground_truth_obs: bool = False,
        ground_grid: int = 7,
        ground_cell_m: float = 4.0,
        people_range_m: float = 30.0,
        out_of_range: str = "clip",
        render_mode: str | None = None,
        overview_px: int = 800,
    ) -> None:
        if action_mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {action_mode!r}")
        if observation not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {OBSERVATIONS}, got {observation!r}")
        if out_of_range not in ("clip", "raise"):
            raise ValueError(f"out_of_range must be 'clip' or 'raise', got {out_of_range!r}")
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        w, h = (int(v) for v in image_size)
        if w < 8 or h < 8 or frame_stack < 1:
            raise ValueError(
                f"image_size must be at least 8x8 and frame_stack >= 1, got {image_size}, {frame_stack}"
            )
        if not (control_hz > 0.0 and math.isfinite(control_hz)) or not (
            max_episode_s is None or max_episode_s > 0.0
        ):
            raise ValueError("control_hz and max_episode_s must be positive")
        if not (land_xy_m_s >= 0.0 and math.isfinite(land_xy_m_s)):
            raise ValueError(f"land_xy_m_s must be a finite speed >= 0, got {land_xy_m_s!r}")
        if ground_truth_obs and not (
            isinstance(ground_grid, int) and ground_grid >= 1 and ground_cell_m > 0.0 and people_range_m > 0.0
        ):
            raise ValueError(
                "ground_grid must be an integer >= 1, ground_cell_m and people_range_m positive, got "
                f"{ground_grid!r}, {ground_cell_m!r}, {people_range_m!r}"
            )
        trial_spec = resolve_spec(spec) if spec is not None else None
        if footage is None:
            footage = trial_spec.footage[0] if trial_spec is not None else "synthetic"
        if trial_spec is None:
            trial_spec = default_spec(
                footage.metadata.name if isinstance(footage, FootageSource) else str(footage)
            )
        elif not isinstance(footage, FootageSource):
            trial_spec = with_footage(trial_spec, str(footage))
        self.action_mode, self.observation, self.render_mode = action_mode, observation, render_mode
        self.grayscale, self.frame_stack, self.control_hz = grayscale, int(frame_stack), float(control_hz)
        self.trial_spec = trial_spec
        self.max_episode_s = float(trial_spec.timeout_s if max_episode_s is None else max_episode_s)
        self.limits: Limits = replace(limits_of(trial_spec), timeout_s=self.max_episode_s)
        self.out_of_range, self.overview_px = out_of_range, overview_px
        self.max_tilt_rad = math.radians(max_tilt_deg)
        self.max_yaw_rate_rad_s = math.radians(max_yaw_rate_deg_s)
        self.max_speed_m_s, self.max_vspeed_m_s = float(max_speed_m_s), float(max_vspeed_m_s)
        self.land_xy_m_s = float(land_xy_m_s)
        self.ground_truth_obs = bool(ground_truth_obs)
        self.ground_grid, self.ground_cell_m = int(ground_grid), float(ground_cell_m)
        self.people_range_m = float(people_range_m)
        half = (self.ground_grid - 1) / 2.0
        idx = (np.arange(self.ground_grid, dtype=np.float64) - half) * self.ground_cell_m
        self._grid_dn_m, self._grid_de_m = (a.ravel() for a in np.meshgrid(idx, idx, indexing="ij"))
        self.state_fields = STATE_FIELDS + (
            ground_truth_fields(self.ground_grid) if self.ground_truth_obs else ()
        )
        self.metadata = {**self.metadata, "render_fps": self.control_hz}

        base = config or SimConfig()
        cfg = replace(base, camera=replace(base.camera, width_px=w, height_px=h))
        # footage by name/path: this env owns it; a FootageSource passed in is shared (vector env) and not closed
        self._owns_footage = not isinstance(footage, FootageSource)
        source = footage if isinstance(footage, FootageSource) else open_footage(
            footage, altitude_m=cfg.footage_alt_m, hfov_deg=cfg.footage_hfov_deg, gsd_m_per_px=cfg.footage_gsd_m_per_px
        )  # fmt: skip
        if isinstance(source, SyntheticField) and source.params.draw_ahead:
            # which window the draw-ahead thread delivers depends on thread timing (a busy worker skips one), and
            # windows differ by a grey level: draw in line so that seeded rollouts are bit-identical
            source.params = replace(source.params, draw_ahead=False)
        self.footage = source
        self.vehicle = Vehicle(cfg, footage=source, geofence=True, super_resolution=_super_resolution(cfg))
        self._params0 = {n: self.vehicle.params.stored(n) for n in self.vehicle.params.names()}
        self.world = world if world is not None else world_from_source(source)
        self.scorer: Scorer = scorer if scorer is not None else LandingReward(self.world, trial_spec, reward)
        self.scenario_drawer: ScenarioDrawer = scenario_drawer or SpecScenarioDrawer(
            trial_spec, footage_box_of(source)
        )
        # the scenario flown (footage_time_s: the footage clock at the start)
        self.scenario: Scenario | None = None
        self.episode: Episode | None = None  # the trial being flown (viva_sitl.evaluation.episode)
        self.trial_seed: int | None = None
        self.trial_index = 0
        self.rate_hz = 1.0 / self.vehicle.dt_s
        self.schedule = ControlSchedule(self.rate_hz, self.control_hz)  # physics steps per env step

        self.action_space = spaces.Box(-1.0, 1.0, shape=(4,), dtype=np.float32)
        state_space = spaces.Box(-np.inf, np.inf, shape=(len(self.state_fields),), dtype=np.float32)
        self.image_size_hw = (h, w)
        c = (1 if grayscale else 3) * self.frame_stack
        image_space = spaces.Box(0, 255, shape=(h, w, c), dtype=np.uint8)
        self.observation_space: spaces.Space[Any] = (
            spaces.Dict({"image": image_space, "state": state_space})
            if observation == "image+state"
            else state_space
        )
        self._frames: deque[NDArray[np.uint8]] = deque(maxlen=self.frame_stack)
        self._k = 0  # control steps this episode
        # set by a vector env (bind_footage): (env, scenario) -> None puts this copy on its shared source, sets
        # its footage offset and its schedule's phase on the vector env's global clock
        self.footage_binder: Callable[[LandingEnv, Scenario], None] | None = None
        # set by a vector env before each observation (frame_stack 1, RGB): where to write the view
        self.view_out: NDArray[np.uint8] | None = None
        self._yaw_cmd_rad = 0.0
        self._done = True

    # --- helpers ----------------------------------------------------------------------------
    @property
    def footage_time_s(self) -> float:
        return self.vehicle.time_s + self.vehicle.sim.footage_offset_s

    def assisted_velocity(self, vel_ned_m_s: tuple[float, float, float]) -> tuple[float, float, float]:
        """A commanded NED velocity limited by the landing assist at the vehicle's current altitude above ground
        ("velocity_land" mode; land_assist_limits over the vehicle's MPC_LAND_* / MPC_Z_VEL_MAX_DN)."""
        p, s = self.vehicle.params, self.vehicle.state
        alt = self.vehicle.sim.params.ground_z_ned_m - float(s.pos_ned_m[2])
        max_down, max_xy = land_assist_limits(
            alt, land_speed_m_s=p.get("MPC_LAND_SPEED"), fast_down_m_s=p.get("MPC_Z_VEL_MAX_DN"),
            alt1_m=p.get("MPC_LAND_ALT1"), alt2_m=p.get("MPC_LAND_ALT2"),
            xy_land_m_s=self.land_xy_m_s, xy_fast_m_s=self.max_speed_m_s,
        )  # fmt: skip
        vn, ve, vd = vel_ned_m_s
        h = math.hypot(vn, ve)
        if h > max_xy:
            vn, ve = vn * max_xy / h, ve * max_xy / h
        return (vn, ve, min(vd, max_down))

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
        if not self.ground_truth_obs:
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
        r = self.people_range_m
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
        if self.grayscale:
            rgb = veh.sim.render_rgb()  # the image only (no frame metadata), converted once to RGB
            return np.asarray(cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)[:, :, None], dtype=np.uint8)
        return veh.sim.render_rgb(out=out)

    def _obs(self, new_view: NDArray[np.uint8] | None = None) -> Any:
        state = self._state_vec(self.vehicle.state)
        if self.observation == "state":
            return state
        out, self.view_out = self.view_out, None  # one observation only
        self._frames.append(self.view(out) if new_view is None else new_view)
        while len(self._frames) < self.frame_stack:
            self._frames.appendleft(self._frames[0])
        image = self._frames[0] if self.frame_stack == 1 else np.concatenate(list(self._frames), axis=2)
        return {"image": image, "state": state}

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
            if self.out_of_range == "raise":
                raise ValueError(f"action out of [-1, 1]: {a.tolist()}")
            a = np.clip(a, -1.0, 1.0)
        return a, clipped

    # --- gymnasium API ---------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[Any, dict[str, Any]]:
        """A new episode: trial 0 of `seed` (the trials' drawing), or the next trial without a seed. options:
        {"trial": k} flies trial k of the current seed; {"scenario": Scenario} flies that scenario."""
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
        return self._start(sc)

    def _start(self, sc: Scenario) -> tuple[Any, dict[str, Any]]:
        """Set the vehicle up as every trial is (viva_sitl.evaluation.episode.prepare: the PX4 parameters back to the
        env's, then the scenario's, the footage clock, the physics seed, the start pose), a vector env's binder
        putting the copy on its shared footage and clock first."""
        veh = self.vehicle
        veh.sim.footage_offset_s = sc.footage_time_s
        self.schedule = ControlSchedule(self.rate_hz, self.control_hz)
        if self.footage_binder is not None:
            self.footage_binder(
                self, sc
            )  # a vector env: its shared source, the global footage clock and phase
        if isinstance(self.footage, SyntheticField):
            self.footage.forget_windows()  # the views depend on this episode's poses only
        prepare(veh, sc, baseline_params=self._params0, footage_offset_s=veh.sim.footage_offset_s)
        self.episode = Episode(veh, sc, self.limits, gcs=True, prepare_vehicle=False)
        sc = self.scenario = self.episode.scenario  # its footage_time_s: the footage clock this copy flies
        state = veh.state
        yaw_rad = math.radians(sc.yaw_deg)
        self._yaw_cmd_rad = yaw_rad
        if self.action_mode != "attitude":
            ap = veh.autopilot
            hold = PositionTarget(vel_ned_m_s=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0)
            for out in (
                ap.set_position_target(veh.time_s, hold),
                ap.set_mode(veh.time_s, FlightMode.OFFBOARD),
            ):
                if not out.ok:
                    raise RuntimeError(f"cannot start offboard control: {out.reason}")
        self.scorer.reset(sc, state, self.footage_time_s)
        self._k = 0
        self._done = False
        self._frames.clear()
        info = self._info({})
        info.update(trial_seed=self.trial_seed, trial_index=sc.index)
        return self._obs(), info

    def _info(self, score: dict[str, Any], clipped: bool = False) -> dict[str, Any]:
        return {
            "time_s": self.vehicle.time_s,
            "footage_time_s": self.footage_time_s,
            "footage_offset_s": self.vehicle.sim.footage_offset_s,
            "score": score,
            "action_clipped": clipped,
        }

    def step(self, action: Any) -> tuple[Any, float, bool, bool, dict[str, Any]]:
        if self.scenario is None:
            raise RuntimeError("call reset() before step()")
        a, clipped = self.check_action(action)
        self.transition(a)
        return self.step_result(clipped)

    def transition(self, a: NDArray[np.float64]) -> None:
        """Fly one control period with a checked action (check_action), each physics step the episode's (the
        Vehicle loop, judged by the trial's referee as in the trials runner); the period stops early when the
        trial ends. On the ground afterwards: disarm (force, as a pilot's disarm/kill at touchdown), the trial
        ends "landed" one physics step later."""
        veh = self.vehicle
        ep = self.episode
        assert ep is not None
        mon = ep.monitor
        n = self.schedule.steps(self._k)
        dt_ctrl = n * veh.dt_s
        if self.action_mode == "attitude":
            self._yaw_cmd_rad = math.remainder(
                self._yaw_cmd_rad - float(a[2]) * self.max_yaw_rate_rad_s * dt_ctrl, 2.0 * math.pi
            )
            cmd = EavCommand(
                roll_rad=float(a[0]) * self.max_tilt_rad,
                pitch_rad=-float(a[1]) * self.max_tilt_rad,
                yaw_rad=self._yaw_cmd_rad,
                thrust_n=veh.sim.params.hover_thrust_n * (1.0 + float(a[3])),
            )
            for _ in range(n):
                ep.step(cmd)
                if mon.log.end is not None:
                    break
        else:
            vel = (
                float(a[0]) * self.max_speed_m_s,
                float(a[1]) * self.max_speed_m_s,
                float(a[2]) * self.max_vspeed_m_s,
            )
            yaw_rate = float(a[3]) * self.max_yaw_rate_rad_s
            assist = self.action_mode == "velocity_land"
            for i in range(n):
                if i == 0 or assist:
                    v = self.assisted_velocity(vel) if assist else vel
                    out = veh.autopilot.set_position_target(
                        veh.time_s, PositionTarget(vel_ned_m_s=v, yaw_rate_rad_s=yaw_rate)
                    )
                    if not out.ok:
                        raise ValueError(f"velocity setpoint refused: {out.reason}")
                ep.step(None)
                if mon.log.end is not None:
                    break
        if mon.log.end is None and veh.state.landed and veh.autopilot.armed:
            veh.autopilot.disarm(veh.time_s, force=True)
            ep.step(None)
        self._k += 1

    def step_result(self, clipped: bool, new_view: NDArray[np.uint8] | None = None) -> tuple[Any, float, bool, bool, dict[str, Any]]:  # fmt: skip
        """After `transition`: the observation, the reward, terminated / truncated and the info (the trial's score
        row once it ended) — `step` is check_action + transition + step_result."""
        veh, mon, sc = self.vehicle, self.monitor, self.scenario
        assert mon is not None and sc is not None
        step = self.scorer.step(veh.state, self.footage_time_s)
        if step.terminated and mon.log.end is None:
            mon.end(veh, TrialEnd.SCORER, "the scorer ended the episode")
        info = self._info(step.info, clipped)
        reward = float(step.reward)
        end = mon.log.end
        if end is not None:
            row = self.trial_row()
            reward += float(self.scorer.final(row))
            info["trial"] = row
        return (
            self._obs(new_view),
            reward,
            end is not None and end != TrialEnd.TIMEOUT,
            end == TrialEnd.TIMEOUT,
            info,
        )

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
        return overview_rgb(self, self.overview_px)

    def close(self) -> None:
        if self._owns_footage:
            self.vehicle.close()


def _super_resolution(config: SimConfig) -> Any:
    """The config's [perception.sr] render hook (None without one), loaded once per env."""
    if config.perception.sr.method.value == "none":
        return None
    from viva_sitl.perception.from_config import super_resolution_from_config

    return super_resolution_from_config(config)


def land_assist_limits(
    alt_agl_m: float,
    *,
    land_speed_m_s: float,
    fast_down_m_s: float,
    alt1_m: float,
    alt2_m: float,
    xy_land_m_s: float,
    xy_fast_m_s: float,
) -> tuple[float, float]:
    """(max descent, max horizontal speed) in m/s at `alt_agl_m` above ground, PX4 Land's altitude blend (as
    viva_sitl.autopilot.tasks.land): at or below alt2_m the land values, at or above alt1_m no limit (inf, inf; the
    autopilot's own limits apply), linear in between from the land values to the fast ones."""
    if alt_agl_m >= alt1_m and alt1_m > alt2_m:
        return math.inf, math.inf
    if alt_agl_m <= alt2_m or alt1_m <= alt2_m:
        return land_speed_m_s, xy_land_m_s
    f = (alt_agl_m - alt2_m) / (alt1_m - alt2_m)
    down = land_speed_m_s + (max(fast_down_m_s, land_speed_m_s) - land_speed_m_s) * f
    return down, xy_land_m_s + (max(xy_fast_m_s, xy_land_m_s) - xy_land_m_s) * f


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
    "OBSERVATIONS",
    "STATE_FIELDS",
    "LandingEnv",
    "ground_truth_fields",
    "land_assist_limits",
    "overview_rgb",
]
