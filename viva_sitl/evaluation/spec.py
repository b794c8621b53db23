"""Trial specs (TOML) and scenario drawing: N scenarios, each a deterministic function of (seed, trial index).

    spec = load_spec("configs/trials/synthetic_emergency.toml")
    scenarios = draw_scenarios(spec, n=20, seed=0)     # same (spec, seed) -> same list, trial K alone too
    scenarios[3].to_dict()                             # what the results list and what an external pilot reads

Spec layout (units in the names; a range is `[lo, hi]` drawn uniformly, a number is fixed, a list of strings is a
choice):

    [trials]   name, n, seed, timeout_s (sim s), pilot, speed and frames (external pilots: --speed, and whether
               the VAC is rendered for the frame socket / RTP video),
               end_outside_s (a trial ends after this long with the ground point outside the footage),
               crash_speed_m_s (a touchdown faster than this is a crash), log_hz,
               timing ("realtime" | "lockstep" | "charged", external pilots: viva_sitl.timing; in-process pilots
               are stepped in lockstep always), pilot_cpu_factor (charged: sim s billed per pilot CPU s),
               pilot_latency_ms (charged: what the pilot sends after frame k takes effect at the frame's time + it),
               ulog (default true: each in-process trial writes its PX4 ULog, trials/NNNN/log.ulg; false saves its
               cost, +26-39 % wall per trial; results do not change, so it is not part of the spec's identity)
    [scenario] footage (list), start ("air" | "ground" | both), north_m, east_m (ranges; default: the footage
               minus margin_m), margin_m, altitude_m, yaw_deg, footage_time_s, footage_time_slots (0: footage_time_s
               uniform; K >= 1: one of K evenly spaced times lo + (hi - lo) i / K, so that the copies of a vector
               gym env share footage decodes), land_at_s (the "land now" trigger, s after the start),
               wind_speed_m_s, wind_dir_deg (where the wind blows *from*), gust_std_m_s
    [scenario.params]      PX4 parameter = number or [lo, hi] (e.g. MPC_LAND_SPEED, SIM_MASS)
    [[scenario.failures]]  kind = "gcs_link_lost" | "battery_critical" | "gps_loss" | "motor_failure" | "rc_loss" |
                           "camera_blackout" | "camera_frozen" | "camera_dropped", at_s = [lo, hi], probability = 0..1
    [scoring]  final_descent_below_m, and criterion = {name, landed, max_touchdown_speed_m_s,
               min_dist_person_m, min_dist_vehicle_m, min_dist_object_m (any tracked object, motion-derived
               "moving object" tracks included), max_risk_level}: the checks it names (landed: default true);
               without it: "safe" = landed, touchdown speed < 1 m/s, >= 5 m from people, risk <= 2

Unknown keys and impossible ranges raise ConfigError with the key named (one line).
"""

from __future__ import annotations

import dataclasses
import difflib
import json
import math
import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from viva_sitl.autopilot.params import ParamStore
from viva_sitl.config import ConfigError
from viva_sitl.footage.geometry import FootageGeometry

if TYPE_CHECKING:
    from viva_sitl.footage import FootageSource

SCENARIO_SCHEMA = "vivasitl.scenario.v1"
FAILURE_KINDS = (
    "gcs_link_lost", "battery_critical",
    # MAV_CMD_INJECT_FAILURE's units (autopilot/failures.py; evaluation/monitor.py maps each to its injection)
    "gps_loss", "motor_failure", "rc_loss", "camera_blackout", "camera_frozen", "camera_dropped",
)  # fmt: skip
START_KINDS = ("air", "ground")
# keys the scenario sets through its own fields: never as [scenario.params]
_RESERVED_PARAMS = ("SIM_WIND_N", "SIM_WIND_E", "SIM_WIND_D", "SIM_GUST_STD")

Range = tuple[float, float]


@dataclass(frozen=True)
class FailureSpec:
    kind: str
    at_s: Range
    probability: float = 1.0


@dataclass(frozen=True)
class Criterion:
    """A named success criterion; None = not checked."""

    name: str = "safe"
    landed: bool = True
    max_touchdown_speed_m_s: float | None = 1.0
    min_dist_person_m: float | None = 5.0
    min_dist_vehicle_m: float | None = None
    min_dist_object_m: float | None = None  # any tracked object, derived "moving object" included
    max_risk_level: int | None = 2

    def describe(self) -> str:
        parts = ["landed"] if self.landed else []
        if self.max_touchdown_speed_m_s is not None:
            parts.append(f"touchdown speed < {self.max_touchdown_speed_m_s:g} m/s")
        if self.min_dist_person_m is not None:
            parts.append(f">= {self.min_dist_person_m:g} m from people")
        if self.min_dist_vehicle_m is not None:
            parts.append(f">= {self.min_dist_vehicle_m:g} m from vehicles")
        if self.min_dist_object_m is not None:
            parts.append(f">= {self.min_dist_object_m:g} m from any object")
        if self.max_risk_level is not None:
            parts.append(f"risk <= {self.max_risk_level}")
        return f"{self.name}: " + ", ".join(parts)


@dataclass(frozen=True)
class TrialSpec:
    name: str = "trials"
    n: int = 10
    seed: int = 0
    timeout_s: float = 60.0
    pilot: str = "descend"
    speed: float = 4.0
    end_outside_s: float = 2.0
    crash_speed_m_s: float = 3.0
    log_hz: float = 25.0
    frames: bool = False  # external pilots: render the VAC and serve the frame socket / RTP video
    # external pilots: how sim time relates to the pilot's computing (viva_sitl.timing): realtime | lockstep |
    # charged (lockstep + the pilot's CPU seconds x pilot_cpu_factor billed in sim time, and/or what it sends
    # after frame k taking effect at the frame's time + pilot_latency_ms)
    timing: str = "realtime"
    pilot_cpu_factor: float = 1.0
    pilot_latency_ms: float = 0.0
    ulog: bool = True  # in-process trials: write trials/NNNN/log.ulg (results are the same without it)
    footage: tuple[str, ...] = ("synthetic",)
    start: tuple[str, ...] = ("air",)
    north_m: Range | None = None
    east_m: Range | None = None
    margin_m: float = 10.0
    altitude_m: Range = (20.0, 40.0)
    yaw_deg: Range = (0.0, 360.0)
    footage_time_s: Range = (0.0, 0.0)
    footage_time_slots: int = 0
    land_at_s: Range = (1.0, 1.0)
    wind_speed_m_s: Range = (0.0, 0.0)
    wind_dir_deg: Range = (0.0, 360.0)
    gust_std_m_s: Range = (0.0, 0.0)
    params: tuple[tuple[str, Range], ...] = ()
    failures: tuple[FailureSpec, ...] = ()
    final_descent_below_m: float = 10.0
    criterion: Criterion = field(default_factory=Criterion)
    source: str = ""  # the file it came from

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class Failure:
    kind: str
    at_s: float  # s after the trial start


@dataclass(frozen=True)
class Scenario:
    """One trial's situation: everything the vehicle and the pilot start from. Times are s after the start."""

    index: int
    seed: int  # physics seed (disturbances) of this trial
    footage: str
    start: str  # "air": armed in Hold at the start pose, "land now" at land_at_s; "ground": disarmed on the ground
    north_m: float
    east_m: float
    altitude_m: float  # air: start altitude; ground: the altitude the pilot should take off to
    yaw_deg: float
    footage_time_s: float  # footage clock at the trial start (sim time starts here)
    land_at_s: float
    wind_ned_m_s: tuple[float, float, float]
    gust_std_m_s: float
    params: tuple[tuple[str, float], ...]
    failures: tuple[Failure, ...]
    timeout_s: float

    @classmethod
    def air(
        cls, north_m: float, east_m: float, altitude_m: float, *, yaw_deg: float = 0.0,
        footage_time_s: float = 0.0, footage: str = "synthetic", seed: int = 0, land_at_s: float = 0.0,
        timeout_s: float = 60.0,
    ) -> Scenario:  # fmt: skip
        """A hand-made air start (calm, no failures): e.g. a gym env's reset(options={"scenario": ...})."""
        return cls(
            index=0, seed=seed, footage=footage, start="air", north_m=north_m, east_m=east_m,
            altitude_m=altitude_m, yaw_deg=yaw_deg, footage_time_s=footage_time_s, land_at_s=land_at_s,
            wind_ned_m_s=(0.0, 0.0, 0.0), gust_std_m_s=0.0, params=(), failures=(), timeout_s=timeout_s,
        )  # fmt: skip

    @property
    def start_pos_ned_m(self) -> tuple[float, float, float]:
        return (self.north_m, self.east_m, -self.altitude_m if self.start == "air" else 0.0)

    def all_params(self) -> tuple[tuple[str, float], ...]:
        """PX4 parameters the vehicle starts with: the drawn ones plus the wind (SIM_WIND_*, SIM_GUST_STD)."""
        wind = (
            ("SIM_WIND_N", self.wind_ned_m_s[0]),
            ("SIM_WIND_E", self.wind_ned_m_s[1]),
            ("SIM_WIND_D", self.wind_ned_m_s[2]),
            ("SIM_GUST_STD", self.gust_std_m_s),
        )
        return self.params + wind

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["schema"] = SCENARIO_SCHEMA
        d["params"] = dict(self.params)
        d["failures"] = [dataclasses.asdict(f) for f in self.failures]
        d["start_pos_ned_m"] = list(self.start_pos_ned_m)
        d["wind_ned_m_s"] = list(self.wind_ned_m_s)
        return d  # JSON-normal: equal to its own JSON round trip

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Scenario:
        if d.get("schema") != SCENARIO_SCHEMA:
            raise ConfigError(f"scenario: schema {d.get('schema')!r} is not {SCENARIO_SCHEMA}")
        try:
            return cls(
                index=int(d["index"]), seed=int(d["seed"]), footage=str(d["footage"]), start=str(d["start"]),
                north_m=float(d["north_m"]), east_m=float(d["east_m"]), altitude_m=float(d["altitude_m"]),
                yaw_deg=float(d["yaw_deg"]), footage_time_s=float(d["footage_time_s"]),
                land_at_s=float(d["land_at_s"]),
                wind_ned_m_s=tuple(float(v) for v in d["wind_ned_m_s"]),  # type: ignore[arg-type]
                gust_std_m_s=float(d["gust_std_m_s"]),
                params=tuple((str(k), float(v)) for k, v in dict(d["params"]).items()),
                failures=tuple(Failure(str(f["kind"]), float(f["at_s"])) for f in d["failures"]),
                timeout_s=float(d["timeout_s"]),
            )  # fmt: skip
        except (KeyError, TypeError, ValueError) as exc:
            raise ConfigError(f"scenario: bad or missing field: {exc}") from None

    def write(self, path: Path) -> None:
        path.write_text(json.dumps(self.to_dict(), indent=1))

    @classmethod
    def read(cls, path: str | Path) -> Scenario:
        try:
            return cls.from_dict(json.loads(Path(path).read_text()))
        except FileNotFoundError:
            raise ConfigError(f"scenario file not found: {path}") from None
        except json.JSONDecodeError as exc:
            raise ConfigError(f"scenario {path}: not valid JSON: {exc}") from None


# ------------------------------------------------------------------------------------------ loading


_TABLES = {
    "trials": ("name", "n", "seed", "timeout_s", "pilot", "speed", "end_outside_s", "crash_speed_m_s", "log_hz",
               "frames", "timing", "pilot_cpu_factor", "pilot_latency_ms", "ulog"),
    "scenario": ("footage", "start", "north_m", "east_m", "margin_m", "altitude_m", "yaw_deg", "footage_time_s",
                 "footage_time_slots", "land_at_s", "wind_speed_m_s", "wind_dir_deg", "gust_std_m_s", "params", "failures"),
    "scoring": ("final_descent_below_m", "criterion"),
}  # fmt: skip


def _unknown(where: str, key: str, known: tuple[str, ...] | list[str]) -> ConfigError:
    close = difflib.get_close_matches(key, list(known), n=1)
    hint = f" (did you mean {close[0]!r}?)" if close else f" (known: {', '.join(known)})"
    return ConfigError(f"{where}.{key}: unknown key{hint}")


def _number(v: Any, where: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(float(v)):
        raise ConfigError(f"{where}: expected a finite number, got {v!r}")
    return float(v)


def _range(v: Any, where: str, lo: float = -math.inf, hi: float = math.inf) -> Range:
    """A number (fixed) or [lo, hi] with lo <= hi, both inside [lo, hi] bounds."""
    if isinstance(v, list | tuple):
        if len(v) != 2:
            raise ConfigError(f"{where}: expected a number or [lo, hi], got {v!r}")
        a, b = _number(v[0], where), _number(v[1], where)
    else:
        a = b = _number(v, where)
    if a > b:
        raise ConfigError(f"{where}: empty range [{a:g}, {b:g}] (lo > hi)")
    if a < lo or b > hi:
        raise ConfigError(f"{where}: [{a:g}, {b:g}] is outside the possible range [{lo:g}, {hi:g}]")
    return (a, b)


def _choice(v: Any, where: str, allowed: tuple[str, ...] | None = None) -> tuple[str, ...]:
    items = [v] if isinstance(v, str) else v
    if not isinstance(items, list) or not items or not all(isinstance(x, str) for x in items):
        raise ConfigError(f"{where}: expected a string or a non-empty list of strings, got {v!r}")
    if allowed is not None:
        for x in items:
            if x not in allowed:
                raise ConfigError(f"{where}: {x!r} is not one of {', '.join(allowed)}")
    return tuple(items)


def _positive(v: Any, where: str, allow_zero: bool = False) -> float:
    x = _number(v, where)
    if x < 0 or (x == 0 and not allow_zero):
        raise ConfigError(
            f"{where}: expected a {'non-negative' if allow_zero else 'positive'} number, got {v!r}"
        )
    return x


def spec_from_dict(data: dict[str, Any], where: str = "spec") -> TrialSpec:
    """Validate a parsed TOML document into a TrialSpec (ConfigError naming the key on any problem)."""
    for table in data:
        if table not in _TABLES:
            raise _unknown(where, table, list(_TABLES))
        if not isinstance(data[table], dict):
            raise ConfigError(f"{where}.{table}: expected a table")
        for key in data[table]:
            if key not in _TABLES[table]:
                raise _unknown(f"{where}.{table}", key, _TABLES[table])
    t, s, sc = data.get("trials", {}), data.get("scenario", {}), data.get("scoring", {})
    kw: dict[str, Any] = {"source": where}
    w = f"{where}.trials"
    if "name" in t:
        if not isinstance(t["name"], str):
            raise ConfigError(f"{w}.name: expected a string")
        kw["name"] = t["name"]
    if "pilot" in t:
        if not isinstance(t["pilot"], str) or not t["pilot"].strip():
            raise ConfigError(f"{w}.pilot: expected a pilot name or a command")
        kw["pilot"] = t["pilot"]
    for key in ("n", "seed"):
        if key in t:
            v = t[key]
            if isinstance(v, bool) or not isinstance(v, int) or v < (1 if key == "n" else 0):
                raise ConfigError(f"{w}.{key}: expected an integer >= {1 if key == 'n' else 0}, got {v!r}")
            kw[key] = v
    for key in ("frames", "ulog"):
        if key in t:
            if not isinstance(t[key], bool):
                raise ConfigError(f"{w}.{key}: expected true/false")
            kw[key] = t[key]
    for key in ("timeout_s", "speed", "crash_speed_m_s", "log_hz"):
        if key in t:
            kw[key] = _positive(t[key], f"{w}.{key}")
    if "end_outside_s" in t:
        kw["end_outside_s"] = _positive(t["end_outside_s"], f"{w}.end_outside_s", allow_zero=True)
    if "timing" in t:
        if t["timing"] not in ("realtime", "lockstep", "charged"):
            raise ConfigError(f"{w}.timing: expected realtime, lockstep or charged, got {t['timing']!r}")
        kw["timing"] = t["timing"]
    if "pilot_cpu_factor" in t:
        kw["pilot_cpu_factor"] = _positive(t["pilot_cpu_factor"], f"{w}.pilot_cpu_factor", allow_zero=True)
    if "pilot_latency_ms" in t:
        kw["pilot_latency_ms"] = _positive(t["pilot_latency_ms"], f"{w}.pilot_latency_ms", allow_zero=True)
    w = f"{where}.scenario"
    if "footage" in s:
        kw["footage"] = _choice(s["footage"], f"{w}.footage")
    if "start" in s:
        kw["start"] = _choice(s["start"], f"{w}.start", START_KINDS)
    for key in ("north_m", "east_m"):
        if key in s:
            kw[key] = _range(s[key], f"{w}.{key}")
    if "footage_time_slots" in s:
        v = s["footage_time_slots"]
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise ConfigError(f"{w}.footage_time_slots: expected an integer >= 0, got {v!r}")
        kw["footage_time_slots"] = v
    if "margin_m" in s:
        kw["margin_m"] = _positive(s["margin_m"], f"{w}.margin_m", allow_zero=True)
    limits = {
        "altitude_m": (0.5, 500.0), "yaw_deg": (-360.0, 720.0), "footage_time_s": (0.0, math.inf),
        "land_at_s": (0.0, math.inf), "wind_speed_m_s": (0.0, 30.0), "wind_dir_deg": (-360.0, 720.0),
        "gust_std_m_s": (0.0, 10.0),
    }  # fmt: skip
    for key, (lo, hi) in limits.items():
        if key in s:
            kw[key] = _range(s[key], f"{w}.{key}", lo, hi)
    if "params" in s:
        kw["params"] = _params(s["params"], f"{w}.params")
    if "failures" in s:
        kw["failures"] = _failures(s["failures"], f"{w}.failures")
    w = f"{where}.scoring"
    if "final_descent_below_m" in sc:
        kw["final_descent_below_m"] = _positive(sc["final_descent_below_m"], f"{w}.final_descent_below_m")
    if "criterion" in sc:
        kw["criterion"] = _criterion(sc["criterion"], f"{w}.criterion")
    spec = TrialSpec(**kw)
    lad = spec.land_at_s[1]
    if lad >= spec.timeout_s:
        raise ConfigError(
            f"{where}.scenario.land_at_s: {lad:g} s is not before trials.timeout_s {spec.timeout_s:g}"
        )
    return spec


def _params(table: Any, where: str) -> tuple[tuple[str, Range], ...]:
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table of NAME = number or [lo, hi]")
    store = ParamStore()
    out = []
    for name, v in table.items():
        key = f"{where}.{name}"
        if name not in store:
            close = difflib.get_close_matches(str(name).upper(), store.names(), n=3)
            hint = f" (did you mean {', '.join(close)}?)" if close else ""
            raise ConfigError(f"{key}: unknown PX4 parameter{hint}")
        if name in _RESERVED_PARAMS:
            raise ConfigError(
                f"{key}: set the wind with scenario.wind_speed_m_s / wind_dir_deg / gust_std_m_s"
            )
        spec = store.spec(name)
        r = _range(v, key, spec.min, spec.max)
        for x in r:
            try:
                spec.check(x)
            except ValueError as exc:
                raise ConfigError(f"{key}: {exc}") from None
        out.append((str(name), r))
    return tuple(out)


def _failures(items: Any, where: str) -> tuple[FailureSpec, ...]:
    if not isinstance(items, list):
        raise ConfigError(f"{where}: expected [[scenario.failures]] tables")
    out = []
    for k, item in enumerate(items):
        w = f"{where}[{k}]"
        if not isinstance(item, dict):
            raise ConfigError(f"{w}: expected a table")
        for key in item:
            if key not in ("kind", "at_s", "probability"):
                raise _unknown(w, key, ("kind", "at_s", "probability"))
        if "kind" not in item or "at_s" not in item:
            raise ConfigError(f"{w}: needs kind and at_s")
        kind = _choice(item["kind"], f"{w}.kind", FAILURE_KINDS)
        if len(kind) != 1:
            raise ConfigError(f"{w}.kind: one kind per failure")
        prob = _number(item.get("probability", 1.0), f"{w}.probability")
        if not 0.0 <= prob <= 1.0:
            raise ConfigError(f"{w}.probability: {prob:g} is not in [0, 1]")
        out.append(FailureSpec(kind[0], _range(item["at_s"], f"{w}.at_s", 0.0), prob))
    return tuple(out)


def _criterion(table: Any, where: str) -> Criterion:
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table")
    names = [f.name for f in dataclasses.fields(Criterion)]
    # a criterion written out checks what it names: the checks it leaves out are off (landed stays on)
    kw: dict[str, Any] = {k: None for k in names if k not in ("name", "landed")}
    for key, v in table.items():
        if key not in names:
            raise _unknown(where, key, names)
        if key == "name":
            if not isinstance(v, str):
                raise ConfigError(f"{where}.name: expected a string")
            kw[key] = v
        elif key == "landed":
            if not isinstance(v, bool):
                raise ConfigError(f"{where}.landed: expected true/false")
            kw[key] = v
        elif key == "max_risk_level":
            if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 5:
                raise ConfigError(f"{where}.max_risk_level: expected an integer 1..5, got {v!r}")
            kw[key] = v
        else:
            kw[key] = _positive(v, f"{where}.{key}", allow_zero=True)
    return Criterion(**kw)


def load_spec(path: str | Path) -> TrialSpec:
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"trial spec not found: {p}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise ConfigError(f"cannot read trial spec {p}: {exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{p}: not valid TOML: {exc}") from None
    return spec_from_dict(data, str(p))


# ------------------------------------------------------------------------------------------ drawing


@dataclass(frozen=True)
class FootageBox:
    """A footage's ground: its geometry, the north/east box around its corners, its clock length."""

    geometry: FootageGeometry
    north_m: Range
    east_m: Range
    duration_s: float


def footage_box(name: str) -> FootageBox:
    from viva_sitl.footage import open_footage

    with open_footage(name) as src:
        return footage_box_of(src)


def footage_box_of(src: FootageSource) -> FootageBox:
    """The FootageBox of an open source."""
    g = src.geometry
    corners = [g.px_to_ned(u, v) for u, v in ((0, 0), (g.width_px - 1, 0), (0, g.height_px - 1),
                                                (g.width_px - 1, g.height_px - 1))]  # fmt: skip
    dur = src.frame_count / src.fps if src.frame_count > 1 else math.inf
    ns, es = [c[0] for c in corners], [c[1] for c in corners]
    return FootageBox(g, (min(ns), max(ns)), (min(es), max(es)), dur)


def draw_scenarios(spec: TrialSpec, n: int | None = None, seed: int | None = None) -> list[Scenario]:
    """Scenarios 0..n-1; scenario k depends only on (spec, seed, k). ConfigError when a range cannot be drawn
    (a start range outside a footage, a footage that does not open)."""
    from viva_sitl.footage import FootageError

    n = spec.n if n is None else n
    seed = spec.seed if seed is None else seed
    bounds: dict[str, FootageBox] = {}
    for name in spec.footage:
        try:
            bounds[name] = footage_box(name)
        except FootageError as exc:
            raise ConfigError(f"{spec.source}.scenario.footage: {exc}") from None
        check_bounds(spec, name, bounds[name])
    return [draw_scenario(spec, k, seed, bounds) for k in range(n)]


def check_bounds(spec: TrialSpec, name: str, box: FootageBox) -> None:
    """ConfigError when the spec's start ranges cannot be drawn inside footage `name` (its box)."""
    (n0, n1), (e0, e1) = box.north_m, box.east_m
    for key, rng_ in (("north_m", spec.north_m), ("east_m", spec.east_m)):
        if rng_ is None:
            continue
        lim = (n0, n1) if key == "north_m" else (e0, e1)
        if rng_[0] < lim[0] + spec.margin_m or rng_[1] > lim[1] - spec.margin_m:
            raise ConfigError(
                f"{spec.source}.scenario.{key}: [{rng_[0]:g}, {rng_[1]:g}] leaves footage {name!r} "
                f"(inside: [{lim[0] + spec.margin_m:.1f}, {lim[1] - spec.margin_m:.1f}] with margin_m "
                f"{spec.margin_m:g})"
            )
    if spec.north_m is None and n1 - n0 <= 2 * spec.margin_m:
        raise ConfigError(f"{spec.source}.scenario.margin_m: {spec.margin_m:g} m leaves no room in {name!r}")


def draw_scenario(spec: TrialSpec, index: int, seed: int, bounds: dict[str, FootageBox]) -> Scenario:
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), int(index)]))

    def u(r: Range) -> float:
        x = float(rng.uniform(r[0], r[1])) if r[1] > r[0] else float(r[0])
        return round(x, 6)  # the listed value is the value flown

    footage = spec.footage[int(rng.integers(len(spec.footage)))]
    start = spec.start[int(rng.integers(len(spec.start)))]
    box = bounds[footage]
    (n0, n1), (e0, e1), dur = box.north_m, box.east_m, box.duration_s
    m = spec.margin_m
    nr = spec.north_m or (n0 + m, n1 - m)
    er = spec.east_m or (e0 + m, e1 - m)
    for _ in range(100):  # rejection for rotated footage: the point must be inside with the margin
        north, east = u(nr), u(er)
        if box.geometry.contains_ned(north, east, m) or spec.north_m is not None:
            break
    alt, yaw = u(spec.altitude_m), u(spec.yaw_deg) % 360.0
    ft = u(spec.footage_time_s)
    k = spec.footage_time_slots
    if k > 0:  # the same draw, snapped down to one of k slots: the other draws do not move
        lo, hi = spec.footage_time_s
        ft = (
            round(lo + (hi - lo) * min(k - 1, math.floor((ft - lo) / (hi - lo) * k)) / k, 6)
            if hi > lo
            else lo
        )
    if math.isfinite(dur) and dur > 0:
        ft = round(ft % dur, 6)
    land_at = u(spec.land_at_s)
    ws, wd, gust = u(spec.wind_speed_m_s), u(spec.wind_dir_deg), u(spec.gust_std_m_s)
    # wind blows from wd: the air moves towards wd + 180
    wind = (round(-ws * math.cos(math.radians(wd)), 6), round(-ws * math.sin(math.radians(wd)), 6), 0.0)
    params = tuple((name, u(r)) for name, r in spec.params)
    failures = []
    for f in spec.failures:
        hit = float(rng.uniform())  # always drawn: one failure's probability never shifts the others' draws
        at = u(f.at_s)
        if hit < f.probability:
            failures.append(Failure(f.kind, at))
    phys_seed = int(rng.integers(2**31 - 1))
    return Scenario(
        index=index, seed=phys_seed, footage=footage, start=start, north_m=north, east_m=east, altitude_m=alt,
        yaw_deg=yaw, footage_time_s=ft, land_at_s=land_at, wind_ned_m_s=wind, gust_std_m_s=gust, params=params,
        failures=tuple(failures), timeout_s=spec.timeout_s,
    )  # fmt: skip
