"""In-process pilots: a Python policy stepped on the one Vehicle loop, no MAVLink, faster than real time.

    class MyPilot:
        name = "mine"
        control_hz = 10.0          # act() calls per sim second
        frame_hz = 30.0            # VAC frames in the observation (0: none, nothing rendered)
        uses_ground_truth = False  # True: reset() gets the WorldModel (reference pilots only: "oracle")

        def reset(self, scenario, truth): ...
        def act(self, obs, ctl):   # obs: Observation; ctl: Control (commands through the autopilot)
            if obs.land_now:
                ctl.land()
            return None            # or an EavCommand: the paper's attitude + thrust, held until the next act()

`viva-sitl trials run SPEC --pilot descend|oracle|package.module:Class` (a class taking no arguments). Anything
else is an external program (see external.py).

Built-ins: `descend` lands straight down where it is (what a plain failsafe does); `oracle` knows the ground truth
and flies to the lowest-risk reachable spot farthest from people before landing, keeping a margin for its own
landing error and the risk map's accuracy (a reference for the others: it still flies what it planned, with
the errors that come with it).
"""

from __future__ import annotations

import importlib
import math
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

from viva_sitl.autopilot import Autopilot, FlightMode, LandedState, Outcome, PositionTarget
from viva_sitl.dynamics import EavCommand, EavState
from viva_sitl.evaluation.spec import Scenario
from viva_sitl.frame import RenderedFrame
from viva_sitl.world import PEOPLE, VEHICLES, WorldModel


@dataclass
class Observation:
    t_s: float  # since the trial start
    state: EavState  # NED pose, velocity, attitude (ground truth of the vehicle)
    armed: bool
    mode: FlightMode
    landed_state: LandedState
    land_now: bool  # the "land now" event has fired
    events: list[
        dict[str, Any]
    ]  # events since the last act(): autopilot texts, failures, land_now, mode changes
    frame: RenderedFrame | None  # the VAC frame (image_bgr + FrameMeta) when the pilot asked for frames
    scenario: Scenario
    battery_remaining: float


class Control:
    """Commands a pilot gives, all through the autopilot (as MAVLink commands would); each returns its Outcome."""

    def __init__(self, autopilot: Autopilot, now: Any) -> None:
        self._ap = autopilot
        self._now = now  # () -> sim time

    @property
    def autopilot(self) -> Autopilot:
        return self._ap

    def arm(self) -> Outcome:
        return self._ap.arm(self._now())

    def disarm(self) -> Outcome:
        return self._ap.disarm(self._now())

    def takeoff(self, altitude_m: float | None = None) -> Outcome:
        return self._ap.takeoff(self._now(), altitude_m)

    def land(self) -> Outcome:
        return self._ap.land(self._now())

    def hold(self) -> Outcome:
        return self._ap.set_mode(self._now(), FlightMode.AUTO_LOITER)

    def goto(self, north_m: float, east_m: float, altitude_m: float, yaw_rad: float | None = None) -> Outcome:
        """Reposition in Hold (MAV_CMD_DO_REPOSITION): fly there and hold."""
        return self._ap.reposition(self._now(), north_m, east_m, -altitude_m, yaw_rad)

    def _offboard(self, target: PositionTarget) -> Outcome:
        out = self._ap.set_position_target(self._now(), target)
        if out.ok and self._ap.mode != FlightMode.OFFBOARD:
            out = self._ap.set_mode(self._now(), FlightMode.OFFBOARD)
        return out

    def velocity(self, vn_m_s: float, ve_m_s: float, vd_m_s: float, yaw_rad: float | None = None) -> Outcome:
        """Offboard velocity setpoint (NED); stream it every act() as over MAVLink."""
        return self._offboard(PositionTarget(vel_ned_m_s=(vn_m_s, ve_m_s, vd_m_s), yaw_rad=yaw_rad))

    def position(self, north_m: float, east_m: float, down_m: float, yaw_rad: float | None = None) -> Outcome:
        """Offboard position setpoint (NED)."""
        return self._offboard(PositionTarget(pos_ned_m=(north_m, east_m, down_m), yaw_rad=yaw_rad))


@runtime_checkable
class Pilot(Protocol):
    name: str
    control_hz: float
    frame_hz: float
    uses_ground_truth: bool

    def reset(self, scenario: Scenario, truth: WorldModel | None) -> None: ...

    def act(self, obs: Observation, ctl: Control) -> EavCommand | None: ...


def _takeoff_then(obs: Observation, ctl: Control, state: dict[str, Any]) -> bool:
    """Ground start: arm and take off to the scenario altitude; True once airborne at altitude (or an air start)."""
    sc = obs.scenario
    if sc.start == "air" or state.get("airborne"):
        return True
    if not obs.armed and not state.get("armed_once"):
        if ctl.arm().ok:
            state["armed_once"] = True
            ctl.takeoff(sc.altitude_m)
        return False
    if -obs.state.pos_ned_m[2] >= sc.altitude_m - 1.0:
        state["airborne"] = True
        ctl.hold()
        return True
    return False


@dataclass
class DescendPilot:
    """Land straight down where it is when told to (PX4's Land mode): what a plain failsafe does."""

    name: str = "descend"
    control_hz: float = 5.0
    frame_hz: float = 0.0
    uses_ground_truth: bool = False
    _s: dict[str, Any] = field(default_factory=dict)

    def reset(self, scenario: Scenario, truth: WorldModel | None) -> None:
        self._s = {}

    def act(self, obs: Observation, ctl: Control) -> EavCommand | None:
        if not _takeoff_then(obs, ctl, self._s):
            return None
        if obs.land_now and not self._s.get("landing"):
            self._s["landing"] = ctl.land().ok
        return None


@dataclass
class OraclePilot:
    """Knows the ground truth. At "land now" it scores every spot on a grid within reach (search_radius_m, inside
    the footage): lowest risk level over the time it would take to get there and land, then the largest distance
    to people and vehicles over that window, then the shortest flight; flies there in Hold at its altitude and
    lands. Not a pilot one could build.

    A spot's risk is the highest level within `margin_m()` of it (the risk map eroded by the margin): its landing
    error (`landing_error_m`: the 0.5 m arrival gate below plus the drift of the descent; measured 0.31 m on the
    interchange trial that landed on a ramp) plus the map's stated accuracy (WorldModel.risk_accuracy_m, from the
    footage's [risk] accuracy_m). Without it the plan took risk-3 cells at a polygon's edge and the touchdown, a
    few decimetres off, fell on the risk-5 side."""

    name: str = "oracle"
    control_hz: float = 5.0
    frame_hz: float = 0.0
    uses_ground_truth: bool = True
    search_radius_m: float = 40.0
    grid_m: float = 2.0
    cruise_m_s: float = 5.0  # the speed it assumes for the plan (MPC_XY_CRUISE default)
    land_speed_m_s: float = 0.7  # MPC_LAND_SPEED default, for the plan
    landing_error_m: float = (
        1.0  # touchdown vs planned spot: 0.5 m arrival gate + descent drift (0.31 m measured)
    )
    _s: dict[str, Any] = field(default_factory=dict)
    _world: WorldModel | None = None

    def reset(self, scenario: Scenario, truth: WorldModel | None) -> None:
        self._s = {}
        self._world = truth

    def margin_m(self) -> float:
        """How far from a higher-risk cell a planned spot must be: landing error + the risk map's accuracy."""
        acc = self._world.risk_accuracy_m if self._world is not None else 0.0
        return self.landing_error_m + acc

    def plan(self, north_m: float, east_m: float, altitude_m: float, t_s: float, footage_t0_s: float,
             inside: Any) -> tuple[float, float]:  # fmt: skip
        """The chosen landing spot (north, east) from (north, east, altitude) at trial time t."""
        w = self._world
        if w is None:
            return north_m, east_m
        r = self.search_radius_m
        g = np.arange(-r, r + 1e-9, self.grid_m)
        dn, de = np.meshgrid(g, g, indexing="ij")
        keep = dn**2 + de**2 <= r * r
        n = (north_m + dn[keep]).astype(np.float64)
        e = (east_m + de[keep]).astype(np.float64)
        ok = np.array([inside(a, b) for a, b in zip(n, e, strict=True)], bool)
        n, e = n[ok], e[ok]
        if n.size == 0:
            return north_m, east_m
        dist = np.hypot(n - north_m, e - east_m)
        t_arrive = t_s + dist / self.cruise_m_s + 2.0
        t_land = t_arrive + altitude_m / self.land_speed_m_s + 2.0
        # the margin: a spot's risk is the worst within margin_m of it (centre, two rings of 12)
        m = self.margin_m()
        ang = np.linspace(0.0, 2.0 * np.pi, 12, endpoint=False)
        rad = np.array([0.0] + [m / 2] * 12 + [m] * 12) if m > 0 else np.zeros(1)
        off_n = rad * np.cos(np.concatenate([[0.0], ang, ang + np.pi / 12]))
        off_e = rad * np.sin(np.concatenate([[0.0], ang, ang + np.pi / 12]))
        # risk and distances at a few times across [arrival, touchdown + a margin], worst case
        risk = np.zeros(n.size, np.uint8)
        dmin = np.full(n.size, np.inf)
        for frac in np.linspace(0.0, 1.0, 6):
            tt = t_arrive + frac * (t_land + 3.0 - t_arrive)
            for k in np.unique(np.round(tt, 1)):
                sel = np.round(tt, 1) == k
                ft = float(k) + footage_t0_s
                pn = (n[sel][:, None] + off_n[None, :]).ravel()
                pe = (e[sel][:, None] + off_e[None, :]).ravel()
                worst = w.risk_levels_at(pn, pe, ft).reshape(-1, off_n.size).max(axis=1)
                risk[sel] = np.maximum(risk[sel], worst)
                if w.has_objects:
                    tvec = np.full(int(sel.sum()), ft)
                    dp = w.tracks.distances_along(n[sel], e[sel], tvec, PEOPLE)
                    dv = w.tracks.distances_along(n[sel], e[sel], tvec, VEHICLES)
                    dmin[sel] = np.minimum(dmin[sel], np.minimum(dp, dv))
        score = np.lexsort((dist, -np.minimum(dmin, 50.0), risk))  # last key sorts first
        best = int(score[0])
        return float(n[best]), float(e[best])

    def act(self, obs: Observation, ctl: Control) -> EavCommand | None:
        s = self._s
        if not _takeoff_then(obs, ctl, s):
            return None
        if not obs.land_now or s.get("landing"):
            return None
        p = obs.state.pos_ned_m
        alt = float(-p[2])
        if "target" not in s:
            inside = ctl.autopilot.inside or (lambda _n, _e: True)
            s["target"] = self.plan(
                float(p[0]), float(p[1]), alt, obs.t_s, obs.scenario.footage_time_s, inside
            )
            ctl.goto(s["target"][0], s["target"][1], alt)
            return None
        tn, te = s["target"]
        v = obs.state.vel_ned_m_s
        if (
            math.hypot(float(p[0]) - tn, float(p[1]) - te) < 0.5
            and math.hypot(float(v[0]), float(v[1])) < 0.3
        ):
            s["landing"] = ctl.land().ok
        return None


BUILTIN_PILOTS: dict[str, type] = {"descend": DescendPilot, "oracle": OraclePilot}


def is_inprocess(name: str) -> bool:
    """True for a built-in name or `module:Class`; anything else is an external command."""
    if name in BUILTIN_PILOTS:
        return True
    mod, sep, cls = name.partition(":")
    return (
        bool(sep)
        and " " not in name
        and mod.replace(".", "").replace("_", "").isalnum()
        and cls.isidentifier()
    )


def make_pilot(name: str) -> Pilot:
    """A fresh in-process pilot by name; ValueError with one line when it cannot be made."""
    if name in BUILTIN_PILOTS:
        pilot = BUILTIN_PILOTS[name]()
    else:
        mod_name, _, cls_name = name.partition(":")
        try:
            cls = getattr(importlib.import_module(mod_name), cls_name)
            pilot = cls()
        except Exception as exc:  # noqa: BLE001 - the user's code: any failure is a one-line error
            raise ValueError(f"pilot {name!r}: cannot load: {type(exc).__name__}: {exc}") from None
    for attr in ("name", "control_hz", "frame_hz", "uses_ground_truth", "reset", "act"):
        if not hasattr(pilot, attr):
            raise ValueError(f"pilot {name!r}: has no {attr!r} (see viva_sitl.evaluation.pilots.Pilot)")
    if not (float(pilot.control_hz) > 0):
        raise ValueError(f"pilot {name!r}: control_hz must be > 0")
    return pilot  # type: ignore[no-any-return]
