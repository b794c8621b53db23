"""`DashboardConfig`: where the dashboard listens and how often it talks (no aiohttp import: cheap to load)."""

from __future__ import annotations

import math
from dataclasses import dataclass

DEFAULT_PORT = 8080  # + the vehicle instance, as every other port


@dataclass(frozen=True)
class DashboardConfig:
    enabled: bool = True
    host: str = "127.0.0.1"  # loopback by default, like every other port
    # None: DEFAULT_PORT + instance (busy: any free port, with a warning); 0: any free port
    port: int | None = None
    instance: int = 0
    telemetry_hz: float = 10.0  # HUD / overview state pushed to each page
    stick_timeout_s: float = 0.5  # wall seconds without a stick message from the pilot page -> sticks centred
    jpeg_quality: int = 80  # VAC panel
    overview_max_px: int = 2048  # largest overview image (either side) a page may ask for

    def __post_init__(self) -> None:
        if self.port is not None and not 0 <= self.port <= 65535:
            raise ValueError(f"dashboard port must be in 0..65535, got {self.port}")
        if not (math.isfinite(self.telemetry_hz) and 0.5 <= self.telemetry_hz <= 60.0):
            raise ValueError(f"dashboard telemetry_hz must be in 0.5..60, got {self.telemetry_hz}")
        if not (math.isfinite(self.stick_timeout_s) and 0.05 <= self.stick_timeout_s <= 5.0):
            raise ValueError(f"dashboard stick_timeout_s must be in 0.05..5, got {self.stick_timeout_s}")
        if not 10 <= self.jpeg_quality <= 100:
            raise ValueError(f"dashboard jpeg_quality must be in 10..100, got {self.jpeg_quality}")
        if not 64 <= self.overview_max_px <= 8192:
            raise ValueError(f"dashboard overview_max_px must be in 64..8192, got {self.overview_max_px}")

    @property
    def port_resolved(self) -> int:
        return self.port if self.port is not None else DEFAULT_PORT + self.instance

    @property
    def port_explicit(self) -> bool:
        """True when the user chose the port: a busy port is then an error, not a fallback."""
        return self.port is not None
