"""Local tangent plane <-> WGS84 (flat-earth, accurate to cm over a few km, as PX4's map_projection)."""

from __future__ import annotations

import math
from dataclasses import dataclass

EARTH_RADIUS_M = 6371000.0


@dataclass(frozen=True)
class GeoOrigin:
    """The NED origin on the ground: latitude, longitude (deg) and AMSL altitude (m)."""

    lat_deg: float = 47.397742  # PX4 SITL's default home (Zurich) when footage has no geo-reference
    lon_deg: float = 8.545594
    alt_amsl_m: float = 488.0

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
