"""PX4's Orbit flight task (MAV_CMD_DO_ORBIT) as a pure setpoint generator.

Facts from PX4 (FlightTaskOrbit, facts only): the signed radius gives the direction (positive = clockwise seen from
above), the commanded radius must lie in [1 m, MC_ORBIT_RAD_MAX] ("Orbit radius limit exceeded" otherwise), the
default tangential speed is 1 m/s, NaN parameters keep the previous value (centre: the vehicle's position, altitude:
the current one). The vehicle first approaches the closest point of the circle (facing the centre), then circles with
a tangential velocity plus a radial correction and the centripetal acceleration as feed-forward. Yaw follows
ORBIT_YAW_BEHAVIOUR. The speed is limited so the centripetal acceleration stays below ORBIT_ACC_MAX_M_S2.
"""

from __future__ import annotations

import enum
import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from viva_sitl.autopilot.control import TrajectorySetpoint

NAN = math.nan
Pos3 = Sequence[float] | NDArray[np.float64]  # NED metres
ORBIT_RADIUS_MIN_M = 1.0
ORBIT_VEL_MAX_M_S = 10.0
ORBIT_ACC_MAX_M_S2 = 2.0  # centripetal limit: the speed is reduced (not the radius) when exceeded
ORBIT_DEFAULT_VEL_M_S = 1.0
ON_CIRCLE_TOL_M = 1.0  # |distance - radius| below this: on the circle (approach ends)
OFF_CIRCLE_TOL_M = 6.0  # above this while circling: approach again


class OrbitYaw(enum.IntEnum):
    """ORBIT_YAW_BEHAVIOUR."""

    HOLD_FRONT_TO_CIRCLE_CENTER = 0
    HOLD_INITIAL_HEADING = 1
    UNCONTROLLED = 2
    HOLD_FRONT_TANGENT_TO_CIRCLE = 3
    RC_CONTROLLED = 4
    UNCHANGED = 5


@dataclass(frozen=True)
class Orbit:
    """An orbit in local NED. velocity_m_s is signed: > 0 clockwise (as PX4 stores it)."""

    center_n_m: float
    center_e_m: float
    center_down_m: float
    radius_m: float
    velocity_m_s: float
    yaw_behaviour: OrbitYaw
    initial_yaw_rad: float

    @property
    def clockwise(self) -> bool:
        return self.velocity_m_s >= 0.0

    @property
    def signed_radius_m(self) -> float:
        return self.radius_m if self.clockwise else -self.radius_m


def sanitize(radius_m: float, velocity_m_s: float) -> tuple[float, float]:
    """Clamp the speed to ±ORBIT_VEL_MAX_M_S and to the centripetal limit (sign kept)."""
    v = max(-ORBIT_VEL_MAX_M_S, min(ORBIT_VEL_MAX_M_S, velocity_m_s))
    if v * v >= ORBIT_ACC_MAX_M_S2 * radius_m:
        v = math.copysign(math.sqrt(ORBIT_ACC_MAX_M_S2 * radius_m), v)
    return radius_m, v


def apply_command(
    previous: Orbit | None,
    pos_ned_m: Pos3,
    yaw_rad: float,
    radius_m: float,
    velocity_m_s: float,
    yaw_behaviour: float,
    center_ne_m: tuple[float, float] | None,
    center_down_m: float | None,
    radius_max_m: float,
) -> Orbit:
    """A DO_ORBIT applied on top of the current orbit (or a fresh one at the vehicle). Raises ValueError with the
    pilot's text when the radius is out of range; NaN fields keep what was there."""
    if previous is None:
        previous = Orbit(float(pos_ned_m[0]), float(pos_ned_m[1]), float(pos_ned_m[2]), ORBIT_RADIUS_MIN_M,
                         ORBIT_DEFAULT_VEL_M_S, OrbitYaw.HOLD_FRONT_TO_CIRCLE_CENTER, yaw_rad)  # fmt: skip
    clockwise = previous.clockwise
    radius = previous.radius_m
    speed = abs(previous.velocity_m_s)
    if math.isfinite(radius_m):
        clockwise = radius_m > 0.0
        radius = abs(radius_m)
    if math.isfinite(velocity_m_s):
        speed = abs(velocity_m_s)
    if not (ORBIT_RADIUS_MIN_M <= radius <= radius_max_m):
        raise ValueError("Orbit radius limit exceeded")
    radius, vel = sanitize(radius, speed if clockwise else -speed)
    yaw_b = previous.yaw_behaviour
    if math.isfinite(yaw_behaviour):
        try:
            yaw_b = OrbitYaw(int(yaw_behaviour))
        except ValueError:
            raise ValueError(f"Orbit: unknown yaw behaviour {yaw_behaviour:g}") from None
    out = replace(previous, radius_m=radius, velocity_m_s=vel, yaw_behaviour=yaw_b, initial_yaw_rad=yaw_rad)
    if center_ne_m is not None:
        out = replace(out, center_n_m=center_ne_m[0], center_e_m=center_ne_m[1])
    if center_down_m is not None:
        out = replace(out, center_down_m=center_down_m)
    return out


@dataclass(frozen=True)
class OrbitStep:
    setpoint: TrajectorySetpoint
    yaw_rad: float | None  # None: keep the current yaw setpoint
    approaching: bool


def orbit_step(orbit: Orbit, pos_ned_m: Pos3, approaching: bool, alt_acc_rad_m: float) -> OrbitStep:
    """The trajectory setpoint for one control step at `pos_ned_m` (pure)."""
    dn = float(pos_ned_m[0]) - orbit.center_n_m
    de = float(pos_ned_m[1]) - orbit.center_e_m
    dist = math.hypot(dn, de)
    if dist < 1e-6:  # at the centre: leave northward
        un, ue = 1.0, 0.0
    else:
        un, ue = dn / dist, de / dist
    radial_err = orbit.radius_m - dist
    alt_err = abs(float(pos_ned_m[2]) - orbit.center_down_m)
    if approaching and abs(radial_err) < ON_CIRCLE_TOL_M and alt_err < max(alt_acc_rad_m, 0.5):
        approaching = False
    elif not approaching and abs(radial_err) > OFF_CIRCLE_TOL_M:
        approaching = True
    if approaching:
        target = (
            orbit.center_n_m + un * orbit.radius_m,
            orbit.center_e_m + ue * orbit.radius_m,
            orbit.center_down_m,
        )
        return OrbitStep(TrajectorySetpoint(pos_ned_m=target), math.atan2(-ue, -un), True)
    v = orbit.velocity_m_s
    # tangent of a clockwise (increasing bearing) motion is (-e, n); radial correction toward the circle
    vel_n = -ue * v + radial_err * un
    vel_e = un * v + radial_err * ue
    acc = v * v / orbit.radius_m
    sp = TrajectorySetpoint(
        pos_ned_m=(NAN, NAN, orbit.center_down_m),
        vel_ned_m_s=(vel_n, vel_e, NAN),
        acc_ned_m_s2=(-un * acc, -ue * acc, NAN),
    )
    yaw_b = orbit.yaw_behaviour
    yaw: float | None
    if yaw_b == OrbitYaw.HOLD_INITIAL_HEADING:
        yaw = orbit.initial_yaw_rad
    elif yaw_b == OrbitYaw.HOLD_FRONT_TANGENT_TO_CIRCLE:
        s = 1.0 if orbit.clockwise else -1.0
        yaw = math.atan2(s * un, -s * ue)
    elif yaw_b == OrbitYaw.HOLD_FRONT_TO_CIRCLE_CENTER:
        yaw = math.atan2(-ue, -un)
    else:  # uncontrolled / RC / unchanged: keep the yaw setpoint
        yaw = None
    return OrbitStep(sp, yaw, False)
