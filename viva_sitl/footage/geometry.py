"""Where footage pixels lie on the ground: the footage frame as an orthophoto of the plane z_ned = 0.

The NED origin is the ground point under the footage centre (the recording drone's position), unless `center_ne_m`
says where the centre lies (a window cut from a larger ground, e.g. the synthetic field drawn around the camera).
Footage pixel (u right, v down) maps to ground metres through the ground sample distance; footage "up" points along
`heading_deg` (bearing, clockwise from north; 0 = north up). `unbounded` marks a ground that exists everywhere
(the procedural synthetic field): `contains_ned` is then True for every point.
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
    center_ne_m: tuple[float, float] = (0.0, 0.0)  # ground (north, east) under the centre pixel
    unbounded: bool = False  # ground everywhere (procedural): contains_ned is always True

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
        n0, e0 = self.center_ne_m
        # image-aligned coordinates: fwd (up) = c*n + s*e, right = -s*n + c*e (n, e relative to the centre)
        return np.array(
            [
                [-s / g, c / g, cx - (-s * n0 + c * e0) / g],
                [-c / g, -s / g, cy - (-c * n0 - s * e0) / g],
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
        """True when the ground point lies on the footage (always, for an unbounded ground)."""
        if self.unbounded:
            return True
        u, v = self.ned_to_px(north_m, east_m)
        m = margin_m / self.gsd_m_per_px
        return bool(m <= u <= self.width_px - 1 - m and m <= v <= self.height_px - 1 - m)

    # --- added by the footage helper (additive): geo-reference from the frame's 4 corner coordinates -----------------
    @classmethod
    def from_corners(
        cls,
        width_px: int,
        height_px: int,
        corners_lonlat: tuple[tuple[float, float], ...] | list[tuple[float, float]],
        *,
        recording_altitude_m: float | None = None,
        hfov_deg: float | None = None,
        ground_alt_amsl_m: float = 0.0,
    ) -> FootageGeometry:
        """Geometry from the (lon, lat) of the frame corners in the order top-left, top-right, bottom-right, bottom-left.

        A least-squares similarity (scale = GSD, rotation = heading, translation = centre) from the pixel-area corners
        to local ground metres; the centre pixel's WGS84 becomes `geo_origin`. The recording altitude is given, or
        derived from a recording horizontal FoV: z = ground width / (2 tan(hfov/2)).
        """
        gsd, heading_deg, origin, _ = corners_fit(width_px, height_px, corners_lonlat, ground_alt_amsl_m)
        if recording_altitude_m is None:
            if hfov_deg is None or not 0.0 < hfov_deg < 180.0:
                raise ValueError(
                    "from_corners needs recording_altitude_m or a recording hfov_deg in (0, 180)"
                )
            recording_altitude_m = width_px * gsd / (2.0 * math.tan(math.radians(hfov_deg) / 2.0))
        return cls(width_px, height_px, gsd, recording_altitude_m, heading_deg, origin)


def corners_fit(
    width_px: int,
    height_px: int,
    corners_lonlat: tuple[tuple[float, float], ...] | list[tuple[float, float]],
    ground_alt_amsl_m: float = 0.0,
) -> tuple[float, float, GeoOrigin, float]:
    """(gsd_m_per_px, heading_deg in [0, 360), geo origin of the frame centre, worst corner residual in m).

    Complex-number similarity fit: ground (n + i e) = a * image (fwd + i right) + b with a = gsd * exp(i heading);
    this is the same convention as `ground_to_px` (footage up = bearing `heading_deg`, footage right = heading + 90).
    """
    if len(corners_lonlat) != 4:
        raise ValueError(
            f"need 4 corners (top-left, top-right, bottom-right, bottom-left), got {len(corners_lonlat)}"
        )
    lons = [float(c[0]) for c in corners_lonlat]
    lats = [float(c[1]) for c in corners_lonlat]
    if not all(-180.0 <= lo <= 180.0 for lo in lons) or not all(-90.0 <= la <= 90.0 for la in lats):
        raise ValueError(f"corner coordinates must be (lon, lat) in degrees, got {list(corners_lonlat)!r}")
    mean = GeoOrigin(sum(lats) / 4.0, sum(lons) / 4.0, ground_alt_amsl_m)
    ned = [mean.global_to_ned(la, lo, ground_alt_amsl_m) for lo, la in zip(lons, lats, strict=True)]
    z_ground = np.array([n + 1j * e for n, e, _ in ned])
    w, h = float(width_px), float(height_px)
    # corners of the pixel area, relative to the centre: (fwd, right) = (-(v - h/2), u - w/2)
    z_image = np.array([h / 2 + 1j * -w / 2, h / 2 + 1j * w / 2, -h / 2 + 1j * w / 2, -h / 2 + 1j * -w / 2])
    zg_c = z_ground - z_ground.mean()
    a = complex(np.sum(np.conj(z_image) * zg_c) / np.sum(np.abs(z_image) ** 2))
    b = complex(z_ground.mean())
    residual = float(np.max(np.abs(a * z_image + b - z_ground)))
    gsd = abs(a)
    if not gsd > 0.0:
        raise ValueError("degenerate corners: all four at the same place")
    heading_deg = math.degrees(math.atan2(a.imag, a.real)) % 360.0
    lat, lon, _ = mean.ned_to_global(b.real, b.imag, 0.0)
    return gsd, heading_deg, GeoOrigin(lat, lon, ground_alt_amsl_m), residual
