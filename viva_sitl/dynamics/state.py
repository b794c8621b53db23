"""Frozen state and command of the EAV. Velocity is derived, never stored twice."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray


def floats3(x: object) -> tuple[float, float, float]:
    """The three components of a 3-vector (array, list, tuple) as Python floats."""
    v: Any = x  # a flat array, tuple or list as it is (the render path calls this per frame); anything else reshaped
    if not (
        (isinstance(v, np.ndarray) and v.shape == (3,)) or (isinstance(v, (tuple, list)) and len(v) == 3)
    ):
        v = np.asarray(x, dtype=np.float64).reshape(3)
    return float(v[0]), float(v[1]), float(v[2])


def vec3(x: object) -> NDArray[np.float64]:
    """A read-only float64 3-vector (so frozen states stay frozen)."""
    a = np.array(x, dtype=np.float64).reshape(3)
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class EavCommand:
    """The paper's inputs: desired attitude R_k (roll, pitch, yaw; FRD->NED, rad) and total thrust T_k (N)."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    thrust_n: float


@dataclass(frozen=True)
class EavState:
    """X_{k-1} and X_{k-2} of the paper's second-order recursion (NED, metres), plus attitude and contact."""

    time_s: float
    step: int
    pos_ned_m: NDArray[np.float64]  # X_{k-1}: position now
    prev_pos_ned_m: NDArray[np.float64]  # X_{k-2}: position one step earlier
    att_rpy_rad: NDArray[np.float64]  # actual attitude (roll, pitch, yaw), FRD->NED
    thrust_n: float  # thrust applied during the last step
    gust_ned_m_s: NDArray[np.float64]  # current gust velocity (disturbance state)
    landed: bool
    touchdown_speed_m_s: float | None  # speed at the last ground contact, None if never touched down
    dt_s: float

    @property
    def vel_ned_m_s(self) -> NDArray[np.float64]:
        return (self.pos_ned_m - self.prev_pos_ned_m) / self.dt_s

    @property
    def altitude_m(self) -> float:
        """Height above the ground plane z = 0 (positive up)."""
        return -float(self.pos_ned_m[2])

    @property
    def roll_rad(self) -> float:
        return float(self.att_rpy_rad[0])

    @property
    def pitch_rad(self) -> float:
        return float(self.att_rpy_rad[1])

    @property
    def yaw_rad(self) -> float:
        return float(self.att_rpy_rad[2])

    @classmethod
    def at_rest(
        cls,
        pos_ned_m: object = (0.0, 0.0, 0.0),
        yaw_rad: float = 0.0,
        dt_s: float = 1.0 / 250.0,
        roll_rad: float = 0.0,
        pitch_rad: float = 0.0,
        vel_ned_m_s: object = (0.0, 0.0, 0.0),
        ground_z_ned_m: float = 0.0,
    ) -> EavState:
        pos = vec3(pos_ned_m)
        if not np.all(np.isfinite(pos)):
            raise ValueError("initial position must be finite")
        prev = vec3(pos - vec3(vel_ned_m_s) * dt_s)
        landed = bool(pos[2] >= ground_z_ned_m - 1e-9)
        return cls(
            time_s=0.0,
            step=0,
            pos_ned_m=pos,
            prev_pos_ned_m=prev,
            att_rpy_rad=vec3((roll_rad, pitch_rad, yaw_rad)),
            thrust_n=0.0,
            gust_ned_m_s=vec3((0.0, 0.0, 0.0)),
            landed=landed,
            touchdown_speed_m_s=None,
            dt_s=dt_s,
        )
