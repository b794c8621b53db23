"""Configuration: one TOML file, one table per part, each table built into that part's frozen dataclass.

    [sim]      footage, seed, speed, initial pose, home,       -> SimConfig's own fields
               footage_alt_m, footage_hfov_deg, footage_gsd_m_per_px
    [physics]  EavParams fields (rate_hz accepted for dt_s)    -> viva_sitl.dynamics.EavParams
    [physics.wind]                                             -> viva_sitl.dynamics.WindParams
    [camera]   CameraParams fields                             -> viva_sitl.camera.CameraParams
    [mavlink]  MavlinkConfig fields                            -> viva_sitl.mavlink.config.MavlinkConfig
    [video]    VideoConfig fields                              -> viva_sitl.video.config.VideoConfig
    [params]   PX4 parameter overrides (NAME = number), checked against the PX4 parameter set at load
    [perception.sr]  method (none|bicubic|fsrcnn|espcn|edsr), model_path, scale, min_magnification
                                                               -> viva_sitl.perception.config.SRConfig (the simulator's
                                                                  super-resolution; the model loads at start-up)

Unknown tables or keys are errors with the exact key named: a typo never silently falls back to a default.
"""

from __future__ import annotations

import dataclasses
import difflib
import enum
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

from viva_sitl.autopilot.params import ParamStore
from viva_sitl.camera import CameraParams
from viva_sitl.dynamics import EavParams
from viva_sitl.geo import GeoOrigin, parse_home
from viva_sitl.mavlink.config import MavlinkConfig
from viva_sitl.perception.config import SRConfig
from viva_sitl.video.config import VideoConfig

T = TypeVar("T")


class ConfigError(ValueError):
    """A configuration file or value that cannot be used; the message names the file and key."""


def _coerce(value: Any, annotation: Any, where: str) -> Any:
    origin = typing.get_origin(annotation)
    args = typing.get_args(annotation)
    if annotation is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errors = []
        for arg in args:
            if arg is type(None):
                continue
            try:
                return _coerce(value, arg, where)
            except ConfigError as exc:
                errors.append(str(exc))
        raise ConfigError(errors[0] if errors else f"{where}: bad value {value!r}")
    if origin is tuple:
        if not isinstance(value, list | tuple):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        if len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], where) for v in value)
        if len(value) != len(args):
            raise ConfigError(f"{where}: expected {len(args)} values, got {len(value)}")
        return tuple(_coerce(v, a, where) for v, a in zip(value, args, strict=True))
    if isinstance(annotation, type) and dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return build(annotation, value, where)
    if isinstance(annotation, type) and issubclass(annotation, enum.Enum):
        try:
            if isinstance(value, str):
                return annotation[value.upper()]
            return annotation(value)
        except (KeyError, ValueError):
            names = ", ".join(m.name.lower() for m in annotation)
            raise ConfigError(f"{where}: {value!r} is not one of {names}") from None
    if annotation is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where}: expected true/false, got {value!r}")
        return value
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        if not math.isfinite(float(value)):
            raise ConfigError(f"{where}: expected a finite number, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if annotation is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where}: expected a string, got {value!r}")
        return value
    return value


def build(cls: type[T], table: dict[str, Any], where: str = "") -> T:
    """Build frozen dataclass `cls` from a TOML table, rejecting unknown keys and ill-typed values."""
    assert dataclasses.is_dataclass(cls)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        if key not in fields:
            known = ", ".join(sorted(fields))
            raise ConfigError(f"{where or cls.__name__}: unknown key {key!r} (known: {known})")
        kwargs[key] = _coerce(value, hints[key], f"{where}.{key}" if where else key)
    try:
        return cls(**kwargs)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where or cls.__name__}: {exc}") from exc


@dataclass(frozen=True)
class PerceptionConfig:
    """`[perception]`: what the simulator itself runs of the perception extra (only super-resolution)."""

    # low flight: render from a super-resolved footage crop when the VAC magnifies the footage more than
    # sr.min_magnification VAC px per footage px (method none: off, the default)
    sr: SRConfig = field(default_factory=SRConfig)


@dataclass(frozen=True)
class SimConfig:
    """Everything a run needs. Defaults: synthetic field, 250 Hz physics, 640x480 VAC, PX4 SITL ports."""

    footage: str = "synthetic"  # catalog name or path
    seed: int = 0
    speed: float = 1.0  # sim seconds per wall second for `run`
    # how sim time relates to an external pilot's computing (viva_sitl.timing): realtime | lockstep | charged;
    # charged bills the pilot's CPU seconds x pilot_cpu_factor in sim time (2: a computer 2x slower than this one)
    timing: str = "realtime"
    pilot_cpu_factor: float = 1.0
    # charged: a fixed perception-to-action latency: what the pilot sends after frame k takes effect no earlier
    # than the frame's sim time + pilot_latency_ms (with pilot_cpu_factor, the later of the two)
    pilot_latency_ms: float = 0.0
    initial_pos_ned_m: tuple[float, float, float] = (0.0, 0.0, 0.0)  # start on the ground at the origin
    initial_yaw_deg: float = 0.0
    # where the NED origin (footage centre) is on Earth: places ANY footage there (None: the footage's own
    # geo-reference, else PX4's default home). TOML: "LAT,LON[,ALT]", [lat, lon(, alt)] or a table.
    home: GeoOrigin | None = None
    # the footage's recording scale, beating its metadata (None: metadata, DJI SRT/XMP/EXIF, else defaults)
    footage_alt_m: float | None = None
    footage_hfov_deg: float | None = None
    footage_gsd_m_per_px: float | None = None
    physics: EavParams = field(default_factory=EavParams)
    camera: CameraParams = field(default_factory=CameraParams)
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)
    video: VideoConfig = field(default_factory=VideoConfig)
    params: tuple[tuple[str, float], ...] = ()  # PX4 parameter overrides
    perception: PerceptionConfig = field(default_factory=PerceptionConfig)

    def __post_init__(self) -> None:
        if not (self.speed > 0.0 and math.isfinite(self.speed)):
            raise ConfigError(f"sim.speed must be a positive number, got {self.speed!r}")
        if self.timing not in ("realtime", "lockstep", "charged"):
            raise ConfigError(f"sim.timing must be realtime, lockstep or charged, got {self.timing!r}")
        if not (self.pilot_cpu_factor >= 0.0 and math.isfinite(self.pilot_cpu_factor)):
            raise ConfigError(f"sim.pilot_cpu_factor must be a number >= 0, got {self.pilot_cpu_factor!r}")
        if not (self.pilot_latency_ms >= 0.0 and math.isfinite(self.pilot_latency_ms)):
            raise ConfigError(f"sim.pilot_latency_ms must be a number >= 0, got {self.pilot_latency_ms!r}")
        for key in ("footage_alt_m", "footage_hfov_deg", "footage_gsd_m_per_px"):
            v = getattr(self, key)
            if v is not None and not (v > 0.0 and math.isfinite(v)):
                raise ConfigError(f"sim.{key} must be a positive number, got {v!r}")
        if self.footage_hfov_deg is not None and self.footage_hfov_deg >= 180.0:
            raise ConfigError(f"sim.footage_hfov_deg must be < 180, got {self.footage_hfov_deg!r}")

    @classmethod
    def load(cls, path: str | Path | None = None) -> SimConfig:
        """Read a TOML config (None: all defaults). Raises ConfigError with the file and key on any problem."""
        if path is None:
            return cls()
        p = Path(path)
        try:
            data = tomllib.loads(p.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise ConfigError(f"config file not found: {p}") from None
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"cannot read config {p}: {exc}") from exc
        except tomllib.TOMLDecodeError as exc:
            raise ConfigError(f"{p}: not valid TOML: {exc}") from exc
        return cls.from_dict(data, str(p))

    @classmethod
    def from_dict(cls, data: dict[str, Any], where: str = "config") -> SimConfig:
        sections = {"physics", "camera", "mavlink", "video", "params", "perception"}
        unknown = set(data) - sections - {"sim"}
        if unknown:
            raise ConfigError(
                f"{where}: unknown table(s) {sorted(unknown)} (known: sim, {', '.join(sorted(sections))})"
            )
        sim = dict(data.get("sim", {}))
        misplaced = sections & set(sim)
        if misplaced:
            raise ConfigError(f"{where}[sim]: {sorted(misplaced)} must be tables of their own")
        home = sim.get("home")
        if isinstance(home, str | list):
            try:
                sim["home"] = dataclasses.asdict(
                    parse_home(home if isinstance(home, str) else ",".join(str(v) for v in home))
                )
            except ValueError as exc:
                raise ConfigError(f"{where}[sim].home: {exc}") from None
        merged: dict[str, Any] = {**sim, **{k: data[k] for k in sections - {"params"} if k in data}}
        physics = dict(merged.get("physics", {}))
        if "rate_hz" in physics:
            rate = physics.pop("rate_hz")
            if isinstance(rate, bool) or not isinstance(rate, int | float) or not rate > 0:
                raise ConfigError(f"{where}[physics].rate_hz: expected a positive number, got {rate!r}")
            physics["dt_s"] = 1.0 / float(rate)
            merged["physics"] = physics
        merged["params"] = [list(item) for item in _check_params(data.get("params", {}), where)]
        return build(cls, merged, where)


def _check_params(params: Any, where: str) -> list[tuple[str, float]]:
    """`[params]` NAME = number: every name a parameter the vehicle has, every value one it can hold."""
    if not isinstance(params, dict):
        raise ConfigError(f"{where}[params]: expected a table of NAME = number")
    store = ParamStore()
    out: list[tuple[str, float]] = []
    for name, value in params.items():
        key = f"{where}[params].{name}"
        if name not in store:
            close = difflib.get_close_matches(str(name).upper(), store.names(), n=3)
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            raise ConfigError(f"{key}: unknown PX4 parameter{hint}")
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"{key}: expected a number, got {value!r}")
        try:
            out.append((str(name), store.spec(name).check(value)))
        except ValueError as exc:
            raise ConfigError(f"{key}: {exc}") from None
    return out
