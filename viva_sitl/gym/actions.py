"""Action modes of the landing environments: how an action in [-1, 1]^4 is flown for one control period, one small
object per mode (ActionMode) instead of branches on the mode's name. The semantics are in viva_sitl.gym.env's
docstring; `action_mode(ActionConfig)` builds the mode a config names (ACTION_MODE_TYPES).

A mode is one env's: `start` is called when an episode starts (after the vehicle is set up), `fly` once per control
period with the checked action and the period's physics steps; it steps the episode (Episode.step) and stops early
when the trial ends.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from viva_sitl.autopilot.types import FlightMode, PositionTarget
from viva_sitl.dynamics import EavCommand
from viva_sitl.evaluation.episode import Episode
from viva_sitl.evaluation.spec import Scenario
from viva_sitl.gym.config import ActionConfig
from viva_sitl.vehicle import Vehicle


class ActionMode(Protocol):
    """How one env flies its actions."""

    name: str

    def start(self, vehicle: Vehicle, scenario: Scenario) -> None:
        """A new episode starts (the vehicle is in the scenario's start situation)."""
        ...

    def fly(self, episode: Episode, vehicle: Vehicle, a: NDArray[np.float64], n: int) -> None:
        """Fly checked action `a` for `n` physics steps (fewer when the trial ends)."""
        ...


class AttitudeMode:
    """viva-safeland DroneEnv's normalised [roll, pitch, yaw-rate, thrust], flown with the autopilot bypassed
    (Episode.step with an EavCommand). Keeps the commanded yaw (integrated from the yaw-rate action)."""

    name = "attitude"

    def __init__(self, max_tilt_deg: float, max_yaw_rate_deg_s: float) -> None:
        self.max_tilt_rad = math.radians(max_tilt_deg)
        self.max_yaw_rate_rad_s = math.radians(max_yaw_rate_deg_s)
        self.yaw_cmd_rad = 0.0

    def start(self, vehicle: Vehicle, scenario: Scenario) -> None:
        self.yaw_cmd_rad = math.radians(scenario.yaw_deg)

    def fly(self, episode: Episode, vehicle: Vehicle, a: NDArray[np.float64], n: int) -> None:
        dt_ctrl = n * vehicle.dt_s
        self.yaw_cmd_rad = math.remainder(
            self.yaw_cmd_rad - float(a[2]) * self.max_yaw_rate_rad_s * dt_ctrl, 2.0 * math.pi
        )
        cmd = EavCommand(
            roll_rad=float(a[0]) * self.max_tilt_rad,
            pitch_rad=-float(a[1]) * self.max_tilt_rad,
            yaw_rad=self.yaw_cmd_rad,
            thrust_n=vehicle.sim.params.hover_thrust_n * (1.0 + float(a[3])),
        )
        log = episode.monitor.log
        for _ in range(n):
            episode.step(cmd)
            if log.end is not None:
                break


class VelocityMode:
    """[v_north, v_east, v_down, yaw-rate] as an OFFBOARD velocity setpoint to the autopilot, set once per control
    period; with `land_assist` ("velocity_land") limited at every physics step by assisted_velocity."""

    def __init__(
        self,
        max_speed_m_s: float,
        max_vspeed_m_s: float,
        max_yaw_rate_deg_s: float,
        *,
        land_assist: bool = False,
        land_xy_m_s: float = 0.0,
    ) -> None:
        self.max_speed_m_s, self.max_vspeed_m_s = float(max_speed_m_s), float(max_vspeed_m_s)
        self.max_yaw_rate_rad_s = math.radians(max_yaw_rate_deg_s)
        self.land_assist = land_assist
        self.land_xy_m_s = float(land_xy_m_s)
        self.name = "velocity_land" if land_assist else "velocity"

    def start(self, vehicle: Vehicle, scenario: Scenario) -> None:
        ap = vehicle.autopilot
        hold = PositionTarget(vel_ned_m_s=(0.0, 0.0, 0.0), yaw_rate_rad_s=0.0)
        for out in (
            ap.set_position_target(vehicle.time_s, hold),
            ap.set_mode(vehicle.time_s, FlightMode.OFFBOARD),
        ):
            if not out.ok:
                raise RuntimeError(f"cannot start offboard control: {out.reason}")

    def fly(self, episode: Episode, vehicle: Vehicle, a: NDArray[np.float64], n: int) -> None:
        vel = (
            float(a[0]) * self.max_speed_m_s,
            float(a[1]) * self.max_speed_m_s,
            float(a[2]) * self.max_vspeed_m_s,
        )
        yaw_rate = float(a[3]) * self.max_yaw_rate_rad_s
        assist = self.land_assist
        log = episode.monitor.log
        for i in range(n):
            if i == 0 or assist:
                v = assisted_velocity(vehicle, vel, self.land_xy_m_s, self.max_speed_m_s) if assist else vel
                out = vehicle.autopilot.set_position_target(
                    vehicle.time_s, PositionTarget(vel_ned_m_s=v, yaw_rate_rad_s=yaw_rate)
                )
                if not out.ok:
                    raise ValueError(f"velocity setpoint refused: {out.reason}")
            episode.step(None)
            if log.end is not None:
                break


def _attitude(cfg: ActionConfig) -> ActionMode:
    return AttitudeMode(cfg.max_tilt_deg, cfg.max_yaw_rate_deg_s)


def _velocity(cfg: ActionConfig) -> ActionMode:
    return VelocityMode(cfg.max_speed_m_s, cfg.max_vspeed_m_s, cfg.max_yaw_rate_deg_s)


def _velocity_land(cfg: ActionConfig) -> ActionMode:
    return VelocityMode(
        cfg.max_speed_m_s,
        cfg.max_vspeed_m_s,
        cfg.max_yaw_rate_deg_s,
        land_assist=True,
        land_xy_m_s=cfg.land_xy_m_s,
    )


# mode name (ActionConfig.mode, viva_sitl.gym.config.ACTION_MODES) -> its builder
ACTION_MODE_TYPES: dict[str, Callable[[ActionConfig], ActionMode]] = {
    "attitude": _attitude,
    "velocity": _velocity,
    "velocity_land": _velocity_land,
}


def action_mode(cfg: ActionConfig) -> ActionMode:
    """The ActionMode `cfg.mode` names, with cfg's scales."""
    return ACTION_MODE_TYPES[cfg.mode](cfg)


def assisted_velocity(
    vehicle: Vehicle, vel_ned_m_s: tuple[float, float, float], land_xy_m_s: float, max_speed_m_s: float
) -> tuple[float, float, float]:
    """A commanded NED velocity limited by the landing assist at the vehicle's current altitude above ground
    ("velocity_land" mode; land_assist_limits over the vehicle's MPC_LAND_* / MPC_Z_VEL_MAX_DN; `land_xy_m_s` the
    horizontal speed below MPC_LAND_ALT2, blended up to `max_speed_m_s` at MPC_LAND_ALT1)."""
    p, s = vehicle.params, vehicle.state
    alt = vehicle.sim.params.ground_z_ned_m - float(s.pos_ned_m[2])
    max_down, max_xy = land_assist_limits(
        alt, land_speed_m_s=p.get("MPC_LAND_SPEED"), fast_down_m_s=p.get("MPC_Z_VEL_MAX_DN"),
        alt1_m=p.get("MPC_LAND_ALT1"), alt2_m=p.get("MPC_LAND_ALT2"),
        xy_land_m_s=land_xy_m_s, xy_fast_m_s=max_speed_m_s,
    )  # fmt: skip
    vn, ve, vd = vel_ned_m_s
    h = math.hypot(vn, ve)
    if h > max_xy:
        vn, ve = vn * max_xy / h, ve * max_xy / h
    return (vn, ve, min(vd, max_down))


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


__all__ = [
    "ACTION_MODE_TYPES",
    "ActionMode",
    "AttitudeMode",
    "VelocityMode",
    "action_mode",
    "assisted_velocity",
    "land_assist_limits",
]
