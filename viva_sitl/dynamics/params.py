"""Parameters of the Emulated Aerial Vehicle (EAV). Frozen, typed, with units in the comments."""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace


@dataclass(frozen=True)
class WindParams:
    """Seeded aerodynamic disturbance, expressed as a force on the vehicle (the paper's xi_k)."""

    mean_wind_ned_m_s: tuple[float, float, float] = (0.0, 0.0, 0.0)  # m/s, constant wind (NED)
    gust_std_m_s: float = 0.0  # m/s, std-dev of the Ornstein-Uhlenbeck gust velocity per axis
    gust_tau_s: float = 2.0  # s, correlation time of gusts
    force_noise_std_n: float = 0.0  # N, white force noise per axis per step


DEFAULT_THRUST_TO_WEIGHT = 2.0  # max thrust / weight when max_thrust_n is not given


@dataclass(frozen=True)
class EavParams:
    """The paper's discrete model parameters. `paper()` reproduces the reference implementation."""

    mass_kg: float = 0.468  # kg
    drag_kd_n_s_m: float = 0.15  # N·s/m, linear drag coefficient k_d
    gravity_m_s2: float = 9.81  # m/s²
    dt_s: float = 1.0 / 250.0  # s, physics step
    # Attitude response of the airframe (PX4's attitude P controller over an ideal rate loop): each Euler angle
    # follows its command first-order with time constant tau = 1/MC_*_P, its rate clipped to MC_*RATE_MAX.
    # Defaults are PX4's multicopter defaults (MC_ROLL_P = MC_PITCH_P = 6.5, MC_YAW_P = 2.8, MC_ROLLRATE_MAX =
    # MC_PITCHRATE_MAX = 220 deg/s, MC_YAWRATE_MAX = 200 deg/s). `paper()`: all 0 = the ideal, instant attitude.
    attitude_tau_s: float = 1.0 / 6.5  # s, roll/pitch time constant; 0 = instant
    yaw_tau_s: float = 1.0 / 2.8  # s, yaw time constant; 0 = instant
    max_roll_pitch_rate_deg_s: float = 220.0  # deg/s, roll/pitch rate limit; 0 = unlimited
    max_yaw_rate_deg_s: float = 200.0  # deg/s, yaw rate limit; 0 = unlimited
    # N, thrust ceiling (thrust commands are clipped to [0, max]); NaN (default): DEFAULT_THRUST_TO_WEIGHT x weight,
    # so a heavier airframe in [physics] still hovers with the same margin
    max_thrust_n: float = math.nan
    max_tilt_rad: float = 1.0  # rad, commanded roll/pitch are clipped to +-this
    ground_z_ned_m: float = 0.0  # m, ground plane height in NED (z down): the vehicle cannot go below it
    wind: WindParams = field(default_factory=WindParams)

    def __post_init__(self) -> None:
        for name in ("mass_kg", "dt_s", "gravity_m_s2"):
            value = getattr(self, name)
            if not (value > 0.0):
                raise ValueError(f"EavParams.{name} must be > 0, got {value!r}")
        if math.isnan(self.max_thrust_n):
            object.__setattr__(self, "max_thrust_n", DEFAULT_THRUST_TO_WEIGHT * self.hover_thrust_n)
        if self.drag_kd_n_s_m < 0.0 or self.max_thrust_n <= 0.0:
            raise ValueError("EavParams: drag must be >= 0 and max_thrust_n > 0")
        for name in ("attitude_tau_s", "yaw_tau_s", "max_roll_pitch_rate_deg_s", "max_yaw_rate_deg_s"):
            value = getattr(self, name)
            if not (value >= 0.0 and math.isfinite(value)):
                raise ValueError(f"EavParams.{name} must be a finite number >= 0 (0 = ideal), got {value!r}")
        if self.max_thrust_n <= self.hover_thrust_n:
            raise ValueError(
                f"EavParams: max_thrust_n {self.max_thrust_n:.3g} N cannot lift mass_kg {self.mass_kg:g} "
                f"(weight {self.hover_thrust_n:.3g} N); raise max_thrust_n or leave it unset "
                f"({DEFAULT_THRUST_TO_WEIGHT:g} x weight)"
            )

    @property
    def hover_thrust_n(self) -> float:
        return self.mass_kg * self.gravity_m_s2

    @property
    def ideal_attitude(self) -> bool:
        """True when the attitude follows its command instantly (no lag, no rate limit): the paper's model."""
        return (
            self.attitude_tau_s == 0.0
            and self.yaw_tau_s == 0.0
            and self.max_roll_pitch_rate_deg_s == 0.0
            and self.max_yaw_rate_deg_s == 0.0
        )

    @property
    def rate_hz(self) -> float:
        return 1.0 / self.dt_s

    @classmethod
    def paper(cls, dt_s: float = 1.0 / 30.0) -> EavParams:
        """The reference implementation's numbers (m = 0.468 kg, k_d = 0.15, g = 9.81, Δt = 1/30) and its ideal
        attitude (the commanded attitude is the attitude, instantly)."""
        return cls(mass_kg=0.468, drag_kd_n_s_m=0.15, gravity_m_s2=9.81, dt_s=dt_s).with_ideal_attitude()

    def with_ideal_attitude(self) -> EavParams:
        """The same airframe with the paper's ideal attitude controller (no lag, no rate limit)."""
        return replace(
            self, attitude_tau_s=0.0, yaw_tau_s=0.0, max_roll_pitch_rate_deg_s=0.0, max_yaw_rate_deg_s=0.0
        )

    def with_rate(self, rate_hz: float) -> EavParams:
        return replace(self, dt_s=1.0 / rate_hz)
