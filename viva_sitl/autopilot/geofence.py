"""PX4's geofence and rally points as pure geometry: validation, containment, breach evaluation, RTL destination.

Everything is in the local NED frame (metres north/east of the origin; down positive). The MAVLink layer converts
MISSION_TYPE_FENCE / MISSION_TYPE_RALLY items into these shapes.

PX4 semantics (navigator/geofence.cpp, facts only):
- A position is inside the fence when it is inside at least one inclusion shape (if any exist) and inside no
  exclusion shape. Polygons and circles may be mixed; the fence return point is stored and reported, not flown.
- GF_MAX_HOR_DIST / GF_MAX_VER_DIST (0 = off): a cylinder around home (horizontal distance, height above home).
- GF_ACTION: 0 none, 1 warning, 2 Hold, 3 Return, 4 Terminate, 5 Land.
- RTL_TYPE 0: return to the closest of home and the rally points.

Deliberate addition: a self-intersecting polygon is refused at upload (PX4 stores it and its even-odd inside test
gives surprising regions); PX4 refuses polygons with fewer than 3 vertices too.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from viva_sitl.autopilot.setpoints import MAX_ABS_POS_M

PointNE = tuple[float, float]
Pos3 = Sequence[float] | NDArray[np.float64]  # NED metres
MAX_FENCE_VERTICES = 500  # per polygon: bounds the O(n^2) self-intersection test


@dataclass(frozen=True)
class PolygonFence:
    vertices_ne_m: tuple[PointNE, ...]
    inclusion: bool = True

    def contains(self, north_m: float, east_m: float) -> bool:
        return point_in_polygon(north_m, east_m, self.vertices_ne_m)


@dataclass(frozen=True)
class CircleFence:
    center_ne_m: PointNE
    radius_m: float
    inclusion: bool = True

    def contains(self, north_m: float, east_m: float) -> bool:
        if self.radius_m <= 0.0:  # PX4: a zero-radius circle contains nothing
            return False
        dn, de = north_m - self.center_ne_m[0], east_m - self.center_ne_m[1]
        return dn * dn + de * de <= self.radius_m * self.radius_m


@dataclass(frozen=True)
class Geofence:
    polygons: tuple[PolygonFence, ...] = ()
    circles: tuple[CircleFence, ...] = ()
    return_point_ned_m: tuple[float, float, float] | None = None

    @property
    def empty(self) -> bool:
        return not self.polygons and not self.circles

    def contains(self, north_m: float, east_m: float) -> bool:
        """PX4: inside one inclusion shape (when there are any) and inside no exclusion shape."""
        shapes: list[PolygonFence | CircleFence] = [*self.polygons, *self.circles]
        inclusions = [s for s in shapes if s.inclusion]
        if inclusions and not any(s.contains(north_m, east_m) for s in inclusions):
            return False
        return not any(s.contains(north_m, east_m) for s in shapes if not s.inclusion)


@dataclass(frozen=True)
class RallyPoint:
    north_m: float
    east_m: float
    down_m: float


# --- geometry -------------------------------------------------------------------------------------
def point_in_polygon(north_m: float, east_m: float, vertices: Sequence[PointNE]) -> bool:
    """Even-odd ray casting (east-going ray); points exactly on an edge may fall either way."""
    inside = False
    n = len(vertices)
    j = n - 1
    for i in range(n):
        ni, ei = vertices[i]
        nj, ej = vertices[j]
        if (ni > north_m) != (nj > north_m):
            e_cross = ei + (north_m - ni) * (ej - ei) / (nj - ni)
            if east_m < e_cross:
                inside = not inside
        j = i
    return inside


def _orient(a: PointNE, b: PointNE, c: PointNE) -> float:
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def _on_segment(a: PointNE, b: PointNE, p: PointNE) -> bool:
    return min(a[0], b[0]) <= p[0] <= max(a[0], b[0]) and min(a[1], b[1]) <= p[1] <= max(a[1], b[1])


def segments_intersect(a: PointNE, b: PointNE, c: PointNE, d: PointNE) -> bool:
    """Closed segments ab and cd share at least one point."""
    o1, o2, o3, o4 = _orient(a, b, c), _orient(a, b, d), _orient(c, d, a), _orient(c, d, b)
    if ((o1 > 0 and o2 < 0) or (o1 < 0 and o2 > 0)) and ((o3 > 0 and o4 < 0) or (o3 < 0 and o4 > 0)):
        return True
    return (
        (o1 == 0 and _on_segment(a, b, c))
        or (o2 == 0 and _on_segment(a, b, d))
        or (o3 == 0 and _on_segment(c, d, a))
        or (o4 == 0 and _on_segment(c, d, b))
    )


def polygon_self_intersects(vertices: Sequence[PointNE]) -> bool:
    """True when two non-adjacent edges touch (or adjacent edges overlap / a vertex repeats)."""
    n = len(vertices)
    edges = [(vertices[i], vertices[(i + 1) % n]) for i in range(n)]
    for i in range(n):
        for j in range(i + 1, n):
            adjacent = j == i + 1 or (i == 0 and j == n - 1)
            a, b = edges[i]
            c, d = edges[j]
            if adjacent:
                # sharing one vertex is normal; folding back onto each other (collinear overlap) is not
                shared = b if j == i + 1 else a
                other_i = a if shared is b else b
                other_j = d if shared is c else c
                if _orient(other_i, shared, other_j) == 0 and _on_segment(shared, other_i, other_j):
                    return True
                if _orient(other_j, shared, other_i) == 0 and _on_segment(shared, other_j, other_i):
                    return True
                continue
            if segments_intersect(a, b, c, d):
                return True
    return False


def validate_polygon(vertices: Sequence[PointNE], index: int = 0) -> None:
    """Raise ValueError (one line, the reason a pilot sees) for a polygon PX4 (or we) would not use."""
    if len(vertices) < 3:
        raise ValueError(f"Geofence rejected: polygon {index} has {len(vertices)} vertices (at least 3)")
    if len(vertices) > MAX_FENCE_VERTICES:
        raise ValueError(f"Geofence rejected: polygon {index} has more than {MAX_FENCE_VERTICES} vertices")
    for n, e in vertices:
        if not (math.isfinite(n) and math.isfinite(e)) or abs(n) > MAX_ABS_POS_M or abs(e) > MAX_ABS_POS_M:
            raise ValueError(f"Geofence rejected: polygon {index} has a vertex that is not finite")
    if len({(round(n, 6), round(e, 6)) for n, e in vertices}) < 3:
        raise ValueError(f"Geofence rejected: polygon {index} is degenerate")
    if polygon_self_intersects(vertices):
        raise ValueError(f"Geofence rejected: polygon {index} self-intersects")


def validate_circle(center_ne_m: PointNE, radius_m: float, index: int = 0) -> None:
    if not (math.isfinite(center_ne_m[0]) and math.isfinite(center_ne_m[1])):
        raise ValueError(f"Geofence rejected: circle {index} centre is not finite")
    # PX4 stores a zero-radius circle (MAVSDK's geofence plugin sends one, at lat/lon 0/0, as "no circle"): it
    # contains no point, so next to a polygon it changes nothing.
    if not (math.isfinite(radius_m) and 0.0 <= radius_m <= MAX_ABS_POS_M):
        raise ValueError(f"Geofence rejected: circle {index} radius {radius_m} m must be >= 0")


# --- breach evaluation ------------------------------------------------------------------------------
@dataclass(frozen=True)
class FenceLimits:
    """GF_MAX_HOR_DIST / GF_MAX_VER_DIST (m, 0 or less = off)."""

    max_hor_dist_m: float = 0.0
    max_ver_dist_m: float = 0.0


def breach_reason(
    fence: Geofence,
    pos_ned_m: Pos3,
    home_ned_m: Pos3,
    limits: FenceLimits | None = None,
) -> str | None:
    """None when the position respects the fence and the home cylinder, else PX4's reason text."""
    limits = limits or FenceLimits()
    n, e, d = float(pos_ned_m[0]), float(pos_ned_m[1]), float(pos_ned_m[2])
    if limits.max_hor_dist_m > 0 and math.hypot(n - home_ned_m[0], e - home_ned_m[1]) > limits.max_hor_dist_m:
        return "maximum distance from home exceeded"
    if limits.max_ver_dist_m > 0 and (home_ned_m[2] - d) > limits.max_ver_dist_m:
        return "maximum altitude exceeded"
    if not fence.empty and not fence.contains(n, e):
        return "outside the fence"
    return None


def rtl_destination(
    pos_ned_m: Pos3, home_ned_m: Pos3, rally: Sequence[RallyPoint]
) -> tuple[tuple[float, float, float], int | None]:
    """PX4 RTL_TYPE 0: the closest of home and the rally points (horizontal distance). Returns (NED, rally index)."""
    best: tuple[float, float, float] = (float(home_ned_m[0]), float(home_ned_m[1]), float(home_ned_m[2]))
    best_d = math.hypot(pos_ned_m[0] - best[0], pos_ned_m[1] - best[1])
    best_i: int | None = None
    for i, r in enumerate(rally):
        d = math.hypot(pos_ned_m[0] - r.north_m, pos_ned_m[1] - r.east_m)
        if d < best_d:
            best, best_d, best_i = (r.north_m, r.east_m, r.down_m), d, i
    return best, best_i
