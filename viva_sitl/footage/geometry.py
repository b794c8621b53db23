"""Where footage pixels lie on the ground: the footage frame as an orthophoto of the plane z_ned = 0.

The NED origin is the ground point under the footage centre (the recording drone's position). Footage pixel
(u right, v down) maps to ground metres through the ground sample distance; footage "up" points along
`heading_deg` (bearing, clockwise from north; 0 = north up).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from viva_sitl.geo import GeoOrigin


@dataclass(frozen=True)
class FootageGeometry:
    width_px: int
    height_px: int
    gsd_m_per_px: float  # ground metres per footage pixel (at the ground plane)
    recording_altitude_m: float  # m above ground of the recording camera
    heading_deg: float = 0.0  # bearing of footage "up", clockwise from north
    geo_origin: GeoOrigin | None = None  # WGS84 of the footage centre, if geo-referenced

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError(f"footage size must be positive, got {self.width_px}x{self.height_px}")
        if not (self.gsd_m_per_px > 0.0 and math.isfinite(self.gsd_m_per_px)):
            raise ValueError(f"gsd_m_per_px must be a positive number, got {self.gsd_m_per_px!r}")
        if not (self.recording_altitude_m > 0.0):
            raise ValueError(f"recording_altitude_m must be > 0, got {self.recording_altitude_m!r}")

    @classmethod
    def from_fov(
        cls,
        width_px: int,
        height_px: int,
        recording_altitude_m: float,
        hfov_deg: float,
        heading_deg: float = 0.0,
        geo_origin: GeoOrigin | None = None,
    ) -> FootageGeometry:
        """GSD of a nadir pinhole camera: ground width 2 z tan(hfov/2) spread over width_px pixels."""
        gsd = 2.0 * recording_altitude_m * math.tan(math.radians(hfov_deg) / 2.0) / width_px
        return cls(width_px, height_px, gsd, recording_altitude_m, heading_deg, geo_origin)

    @property
    def ground_width_m(self) -> float:
        return self.width_px * self.gsd_m_per_px

    @property
    def ground_height_m(self) -> float:
        return self.height_px * self.gsd_m_per_px

    @property
    def recording_hfov_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.ground_width_m / (2.0 * self.recording_altitude_m)))

    @property
    def ground_to_px(self) -> NDArray[np.float64]:
        """3x3 matrix mapping homogeneous ground (north_m, east_m, 1) to footage pixels (u, v, 1)."""
        h = math.radians(self.heading_deg)
        c, s = math.cos(h), math.sin(h)
        g = self.gsd_m_per_px
        cx, cy = (self.width_px - 1) / 2.0, (self.height_px - 1) / 2.0
        # image-aligned coordinates: fwd (up) = c*n + s*e, right = -s*n + c*e
        return np.array(
            [
                [-s / g, c / g, cx],
                [-c / g, -s / g, cy],
                [0.0, 0.0, 1.0],
            ]
        )

    @property
    def px_to_ground(self) -> NDArray[np.float64]:
        return np.asarray(np.linalg.inv(self.ground_to_px), dtype=np.float64)

    def ned_to_px(self, north_m: float, east_m: float) -> tuple[float, float]:
        u, v, w = self.ground_to_px @ np.array([north_m, east_m, 1.0])
        return float(u / w), float(v / w)

    def px_to_ned(self, u: float, v: float) -> tuple[float, float]:
        n, e, w = self.px_to_ground @ np.array([u, v, 1.0])
        return float(n / w), float(e / w)

    def contains_ned(self, north_m: float, east_m: float, margin_m: float = 0.0) -> bool:
        u, v = self.ned_to_px(north_m, east_m)
        m = margin_m / self.gsd_m_per_px
        return bool(m <= u <= self.width_px - 1 - m and m <= v <= self.height_px - 1 - m)
