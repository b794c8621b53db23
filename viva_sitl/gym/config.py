"""The landing environments' settings as frozen dataclasses (Gymnasium FuncEnv's "params"): what a LandingEnv is
built from, grouped by what it configures.

    cfg = LandingEnvConfig(action=ActionConfig(mode="velocity_land", land_xy_m_s=0.5),
                           observation=ObservationConfig(kind="state", ground_truth_obs=True))
    env = LandingEnv("synthetic", env_config=cfg)
    # the flat keyword arguments build the same config (gymnasium.make ids, examples and benches use them):
    env = LandingEnv("synthetic", action_mode="velocity_land", land_xy_m_s=0.5, observation="state",
                     ground_truth_obs=True)

Each group checks its own values (ValueError with one line); `LandingEnvConfig.from_kwargs` maps the flat names
(FLAT_KWARGS) onto the groups. Objects that are not settings (the footage source, the world model, a Scorer, a
ScenarioDrawer) stay LandingEnv's constructor arguments.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from gymnasium import spaces
from numpy.typing import NDArray

from viva_sitl.config import SimConfig
from viva_sitl.gym.scenario import TrialSpec
from viva_sitl.gym.scoring import RewardConfig

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


@dataclass(frozen=True)
class ObservationConfig:
    """What the policy observes: `kind` "image+state" (Dict(image, state)) or "state" (the state Box only, nothing
    rendered); the view's `image_size` (w, h), `grayscale`, `frame_stack`; the PRIVILEGED ground truth
    (`ground_truth_obs`: the risk grid ground_grid x ground_grid, ground_cell_m apart, and the nearest person
    clamped to people_range_m)."""

    kind: str = "image+state"
    image_size: tuple[int, int] = (160, 120)
    grayscale: bool = False
    frame_stack: int = 1
    ground_truth_obs: bool = False
    ground_grid: int = 7
    ground_cell_m: float = 4.0
    people_range_m: float = 30.0

    def __post_init__(self) -> None:
        if self.kind not in OBSERVATIONS:
            raise ValueError(f"observation must be one of {OBSERVATIONS}, got {self.kind!r}")
        w, h = (int(v) for v in self.image_size)
        if w < 8 or h < 8 or self.frame_stack < 1:
            raise ValueError(
                f"image_size must be at least 8x8 and frame_stack >= 1, got {self.image_size}, {self.frame_stack}"
            )
        if self.ground_truth_obs and not (
            isinstance(self.ground_grid, int)
            and self.ground_grid >= 1
            and self.ground_cell_m > 0.0
            and self.people_range_m > 0.0
        ):
            raise ValueError(
                "ground_grid must be an integer >= 1, ground_cell_m and people_range_m positive, got "
                f"{self.ground_grid!r}, {self.ground_cell_m!r}, {self.people_range_m!r}"
            )
        object.__setattr__(self, "image_size", (w, h))
        object.__setattr__(self, "frame_stack", int(self.frame_stack))
        object.__setattr__(self, "grayscale", bool(self.grayscale))
        object.__setattr__(self, "ground_truth_obs", bool(self.ground_truth_obs))
        object.__setattr__(self, "ground_grid", int(self.ground_grid))
        object.__setattr__(self, "ground_cell_m", float(self.ground_cell_m))
        object.__setattr__(self, "people_range_m", float(self.people_range_m))

    @property
    def images(self) -> bool:
        """Whether the observation has an image (views are rendered)."""
        return self.kind == "image+state"

    @property
    def state_fields(self) -> tuple[str, ...]:
        return STATE_FIELDS + (ground_truth_fields(self.ground_grid) if self.ground_truth_obs else ())

    @property
    def channels(self) -> int:
        """Image channels: 1 or 3 per view, times frame_stack."""
        return (1 if self.grayscale else 3) * self.frame_stack

    def space(self) -> spaces.Space[Any]:
        """The observation space: Dict(image HxWxC uint8, state float32[len(state_fields)]), or the state Box."""
        state = spaces.Box(-np.inf, np.inf, shape=(len(self.state_fields),), dtype=np.float32)
        if not self.images:
            return state
        w, h = self.image_size
        image = spaces.Box(0, 255, shape=(h, w, self.channels), dtype=np.uint8)
        return spaces.Dict({"image": image, "state": state})

    def ground_offsets_m(self) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """(north, east) offsets (m) of the ground-truth risk grid's points from the vehicle, row-major."""
        half = (self.ground_grid - 1) / 2.0
        idx = (np.arange(self.ground_grid, dtype=np.float64) - half) * self.ground_cell_m
        dn, de = np.meshgrid(idx, idx, indexing="ij")
        return dn.ravel(), de.ravel()


@dataclass(frozen=True)
class ActionConfig:
    """How an action in [-1, 1]^4 is flown (viva_sitl.gym.actions): `mode` "attitude", "velocity" or
    "velocity_land", its scales, and `out_of_range` "clip" or "raise"."""

    mode: str = "attitude"
    max_tilt_deg: float = 15.0
    max_yaw_rate_deg_s: float = 30.0
    max_speed_m_s: float = 5.0
    max_vspeed_m_s: float = 3.0
    land_xy_m_s: float = 0.0
    out_of_range: str = "clip"

    def __post_init__(self) -> None:
        if self.mode not in ACTION_MODES:
            raise ValueError(f"action_mode must be one of {ACTION_MODES}, got {self.mode!r}")
        if self.out_of_range not in ("clip", "raise"):
            raise ValueError(f"out_of_range must be 'clip' or 'raise', got {self.out_of_range!r}")
        if not (self.land_xy_m_s >= 0.0 and math.isfinite(self.land_xy_m_s)):
            raise ValueError(f"land_xy_m_s must be a finite speed >= 0, got {self.land_xy_m_s!r}")


@dataclass(frozen=True)
class TerminationConfig:
    """When an episode ends besides the trial's own ends: `max_episode_s` (truncation; None: the spec's timeout_s)."""

    max_episode_s: float | None = None

    def __post_init__(self) -> None:
        if not (self.max_episode_s is None or self.max_episode_s > 0.0):
            raise ValueError("control_hz and max_episode_s must be positive")


@dataclass(frozen=True)
class ScenarioConfig:
    """What the episodes fly: `spec` a trials TOML path or TrialSpec (None: default_spec over the footage)."""

    spec: str | Path | TrialSpec | None = None


@dataclass(frozen=True)
class LandingEnvConfig:
    """All of a LandingEnv's settings. `control_hz`: env steps per second of sim time; `sim`: the vehicle's
    SimConfig (None: the defaults; the camera takes the observation's image size); `reward`: LandingReward's
    weights (None: the defaults; unused with a custom Scorer); `overview_px`: render()'s size."""

    observation: ObservationConfig = field(default_factory=ObservationConfig)
    action: ActionConfig = field(default_factory=ActionConfig)
    termination: TerminationConfig = field(default_factory=TerminationConfig)
    scenario: ScenarioConfig = field(default_factory=ScenarioConfig)
    reward: RewardConfig | None = None
    sim: SimConfig | None = None
    control_hz: float = 30.0
    overview_px: int = 800

    def __post_init__(self) -> None:
        if not (self.control_hz > 0.0 and math.isfinite(self.control_hz)):
            raise ValueError("control_hz and max_episode_s must be positive")
        object.__setattr__(self, "control_hz", float(self.control_hz))

    @classmethod
    def from_kwargs(cls, base: LandingEnvConfig | None = None, **kwargs: Any) -> LandingEnvConfig:
        """`base` (default: the defaults) with the flat keyword arguments (FLAT_KWARGS) set; TypeError naming an
        unknown one."""
        cfg = base if base is not None else cls()
        groups: dict[str | None, dict[str, Any]] = {}
        for name, value in kwargs.items():
            if name not in FLAT_KWARGS:
                raise TypeError(f"LandingEnv got an unexpected keyword argument {name!r}")
            group, attr = FLAT_KWARGS[name]
            groups.setdefault(group, {})[attr] = value
        top = groups.pop(None, {})
        for group, values in groups.items():
            assert group is not None
            top[group] = dataclasses.replace(getattr(cfg, group), **values)
        return dataclasses.replace(cfg, **top) if top else cfg


# flat keyword argument -> (group field of LandingEnvConfig or None for a top-level one, field name)
FLAT_KWARGS: dict[str, tuple[str | None, str]] = {
    "observation": ("observation", "kind"),
    "image_size": ("observation", "image_size"),
    "grayscale": ("observation", "grayscale"),
    "frame_stack": ("observation", "frame_stack"),
    "ground_truth_obs": ("observation", "ground_truth_obs"),
    "ground_grid": ("observation", "ground_grid"),
    "ground_cell_m": ("observation", "ground_cell_m"),
    "people_range_m": ("observation", "people_range_m"),
    "action_mode": ("action", "mode"),
    "max_tilt_deg": ("action", "max_tilt_deg"),
    "max_yaw_rate_deg_s": ("action", "max_yaw_rate_deg_s"),
    "max_speed_m_s": ("action", "max_speed_m_s"),
    "max_vspeed_m_s": ("action", "max_vspeed_m_s"),
    "land_xy_m_s": ("action", "land_xy_m_s"),
    "out_of_range": ("action", "out_of_range"),
    "max_episode_s": ("termination", "max_episode_s"),
    "spec": ("scenario", "spec"),
    "reward": (None, "reward"),
    "config": (None, "sim"),
    "control_hz": (None, "control_hz"),
    "overview_px": (None, "overview_px"),
}

__all__ = [
    "ACTION_MODES",
    "FLAT_KWARGS",
    "OBSERVATIONS",
    "STATE_FIELDS",
    "ActionConfig",
    "LandingEnvConfig",
    "ObservationConfig",
    "ScenarioConfig",
    "TerminationConfig",
    "ground_truth_fields",
]
