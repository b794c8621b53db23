"""Local tangent plane <-> WGS84 (flat-earth, accurate to cm over a few km, as PX4's map_projection), and the home.

Where the NED origin (the ground under the footage centre) lies on Earth, first match wins:
  1. `--home LAT,LON[,ALT]` (CLI), 2. `[sim] home` (config), 3. PX4_HOME_LAT / PX4_HOME_LON / PX4_HOME_ALT
  (environment, as PX4 SITL), 4. the footage's own geo-reference, 5. PX4 SITL's default home (47.397742, 8.545594,
  488 m AMSL). 1-3 place ANY footage there; without them geo-referenced footage keeps its true place.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping
from dataclasses import dataclass

EARTH_RADIUS_M = 6371000.0
PX4_DEFAULT_HOME = (47.397742, 8.545594, 488.0)  # PX4 SITL's default world home (lat, lon, alt AMSL)


@dataclass(frozen=True)
class GeoOrigin:
    """The NED origin on the ground: latitude, longitude (deg) and AMSL altitude (m)."""

    lat_deg: float = 47.397742  # PX4 SITL's default home (Zurich) when footage has no geo-reference
    lon_deg: float = 8.545594
    alt_amsl_m: float = 488.0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.lat_deg) and -90.0 <= self.lat_deg <= 90.0):
            raise ValueError(f"home latitude must be in [-90, 90] degrees, got {self.lat_deg!r}")
        if not (math.isfinite(self.lon_deg) and -180.0 <= self.lon_deg <= 180.0):
            raise ValueError(f"home longitude must be in [-180, 180] degrees, got {self.lon_deg!r}")
        if not math.isfinite(self.alt_amsl_m):
            raise ValueError(f"home altitude must be a finite number of metres, got {self.alt_amsl_m!r}")

    def ned_to_global(self, north_m: float, east_m: float, down_m: float) -> tuple[float, float, float]:
        """(lat_deg, lon_deg, alt_amsl_m) of a NED point, azimuthal-equidistant projection as PX4."""
        lat0, lon0 = math.radians(self.lat_deg), math.radians(self.lon_deg)
        x, y = north_m / EARTH_RADIUS_M, east_m / EARTH_RADIUS_M
        c = math.hypot(x, y)
        if c < 1e-15:
            return self.lat_deg, self.lon_deg, self.alt_amsl_m - down_m
        sin_c, cos_c = math.sin(c), math.cos(c)
        lat = math.asin(cos_c * math.sin(lat0) + x * sin_c * math.cos(lat0) / c)
        lon = lon0 + math.atan2(y * sin_c, c * math.cos(lat0) * cos_c - x * math.sin(lat0) * sin_c)
        return math.degrees(lat), math.degrees(lon), self.alt_amsl_m - down_m

    def global_to_ned(self, lat_deg: float, lon_deg: float, alt_amsl_m: float) -> tuple[float, float, float]:
        lat0, lon0 = math.radians(self.lat_deg), math.radians(self.lon_deg)
        lat, lon = math.radians(lat_deg), math.radians(lon_deg)
        cos_d_lon = math.cos(lon - lon0)
        arg = math.sin(lat0) * math.sin(lat) + math.cos(lat0) * math.cos(lat) * cos_d_lon
        c = math.acos(max(-1.0, min(1.0, arg)))
        k = c / math.sin(c) if abs(c) > 1e-12 else 1.0
        north = (
            k * (math.cos(lat0) * math.sin(lat) - math.sin(lat0) * math.cos(lat) * cos_d_lon) * EARTH_RADIUS_M
        )
        east = k * math.cos(lat) * math.sin(lon - lon0) * EARTH_RADIUS_M
        return north, east, self.alt_amsl_m - alt_amsl_m


def parse_home(text: str) -> GeoOrigin:
    """ "LAT,LON[,ALT]" (degrees, degrees, metres AMSL; ALT defaults to PX4's 488 m) -> GeoOrigin; ValueError if bad."""
    parts = [p.strip() for p in str(text).split(",")]
    if len(parts) not in (2, 3):
        raise ValueError(f"home must be LAT,LON or LAT,LON,ALT (degrees, degrees, m AMSL), got {text!r}")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"home must be numbers LAT,LON[,ALT], got {text!r}") from None
    alt = values[2] if len(values) == 3 else PX4_DEFAULT_HOME[2]
    return GeoOrigin(values[0], values[1], alt)


def home_from_env(env: Mapping[str, str] | None = None) -> GeoOrigin | None:
    """PX4_HOME_LAT / PX4_HOME_LON (both, or neither) and optional PX4_HOME_ALT, as PX4 SITL reads them."""
    env = os.environ if env is None else env
    lat, lon, alt = (env.get(k, "").strip() for k in ("PX4_HOME_LAT", "PX4_HOME_LON", "PX4_HOME_ALT"))
    if not lat and not lon:
        if alt:
            raise ValueError("PX4_HOME_ALT is set but PX4_HOME_LAT / PX4_HOME_LON are not")
        return None
    if not (lat and lon):
        raise ValueError("set both PX4_HOME_LAT and PX4_HOME_LON (or neither)")
    try:
        return parse_home(",".join([lat, lon] + ([alt] if alt else [])))
    except ValueError as exc:
        raise ValueError(f"PX4_HOME_LAT/LON/ALT: {exc}") from None
