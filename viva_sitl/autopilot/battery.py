"""A simple battery: coulomb counting with current proportional to thrust, linear cell voltage, sag with current."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class BatteryConfig:
    capacity_mah: float = 5000.0  # BAT1_CAPACITY
    n_cells: int = 4  # BAT1_N_CELLS
    v_charged: float = 4.05  # BAT1_V_CHARGED, per cell (V)
    v_empty: float = 3.6  # BAT1_V_EMPTY, per cell (V)
    r_internal_ohm: float = 0.005  # BAT1_R_INTERNAL, per cell
    hover_current_a: float = 10.0  # SIM_BAT_HOV_A: current at hover thrust
    min_remaining: float = 0.5  # SIM_BAT_MIN_PCT / 100: PX4 SITL never drains below this

    def __post_init__(self) -> None:
        if self.capacity_mah <= 0 or self.n_cells < 1 or self.v_empty >= self.v_charged:
            raise ValueError(f"invalid battery configuration: {self}")


@dataclass
class Battery:
    """State: used charge. Pure given inputs: `update(dt, thrust_ratio, armed, cfg)`."""

    used_mah: float = 0.0
    current_a: float = 0.0
    forced_empty: bool = False  # an injected SYSTEM_BATTERY OFF failure (autopilot/failures.py): reads empty

    def remaining(self, cfg: BatteryConfig) -> float:
        if self.forced_empty:
            return 0.0
        r = 1.0 - self.used_mah / cfg.capacity_mah
        return max(cfg.min_remaining, min(1.0, r))

    def voltage_v(self, cfg: BatteryConfig) -> float:
        cell = cfg.v_empty + (cfg.v_charged - cfg.v_empty) * self.remaining(cfg)
        return cfg.n_cells * (cell - cfg.r_internal_ohm * self.current_a)

    def update(self, dt_s: float, thrust_over_hover: float, armed: bool, cfg: BatteryConfig) -> None:
        # Current ~ thrust (brief's model); a small avionics draw when disarmed.
        self.current_a = cfg.hover_current_a * max(0.0, thrust_over_hover) if armed else 0.2
        if self.remaining(cfg) > cfg.min_remaining:
            self.used_mah += self.current_a * dt_s / 3.6  # A*s -> mAh
