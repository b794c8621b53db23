"""Ground-truth layers of the overview, from the footage's world model (viva_sitl/world).

`ObjectsLayer`: the tracked objects present at the current sim time (the world's own track clock), one box per
object, coloured by class. `RiskMapLayer`: the static risk map as semi-transparent polygons, one colour per SORA-style
level 1..5; ground no polygon covers (the map's default level) is left clear. Both speak LayerProvider
(overview.py): features in footage pixels (pixel centres at integers).

The risk polygons are traced once from the map's own level raster (whatever the map was made from: polygon files in
footage pixels or NED metres, or a raster), so what is drawn is what `world.static_risk_at` answers, to within one
raster cell.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from viva_sitl.dashboard.overview import LayerProvider
from viva_sitl.world import ObjectClass, WorldModel

MAX_OBJECTS = 500  # drawn per update (the densest annotated crowds stay readable and the JSON small)
MAX_RISK_POLYGONS = 2000
# the world overlay's colours (world/overlay.py), as CSS
LEVEL_RGB: dict[int, tuple[int, int, int]] = {
    1: (60, 180, 60), 2: (200, 220, 90), 3: (250, 210, 40), 4: (255, 140, 0), 5: (230, 40, 40),
}  # fmt: skip
CLASS_COLOR: dict[ObjectClass, str] = {
    ObjectClass.PERSON: "#ff00ff",
    ObjectClass.BICYCLE: "#0080ff",
    ObjectClass.CAR: "#00ffff",
    ObjectClass.BUS: "#ffff00",
    ObjectClass.TRUCK: "#78c800",
    ObjectClass.OTHER: "#c8c8c8",
    ObjectClass.MOVING: "#ffffff",
}
RISK_ALPHA = 0.3


class ObjectsLayer:
    """The world's objects at the current sim time (boxes in footage pixels, labelled with class and track id)."""

    name = "objects"

    def __init__(self, world: WorldModel) -> None:
        self.world = world
        self._cache: tuple[int, list[dict[str, Any]]] | None = None

    def features(self, time_s: float, footage_frame_index: int) -> list[dict[str, Any]]:
        tracks = self.world.tracks
        objs = tracks.objects_at(time_s)
        if self._cache is not None and self._cache[0] == objs.frame:  # the track clock's frame: same objects
            return self._cache[1]
        g = self.world.geometry
        to_px = g.ground_to_px
        out: list[dict[str, Any]] = []
        for k in range(min(len(objs), MAX_OBJECTS)):
            u, v, w = to_px @ np.array([objs.ne_m[k, 0], objs.ne_m[k, 1], 1.0])
            u, v = float(u / w), float(v / w)
            hu = max(1.0, float(objs.size_m[k, 0]) / g.gsd_m_per_px / 2.0)
            hv = max(1.0, float(objs.size_m[k, 1]) / g.gsd_m_per_px / 2.0)
            cls = ObjectClass(int(objs.object_class[k]))
            info = tracks.tracks[int(objs.track[k])]
            ident = info.source_id if info.source_id is not None else int(objs.track[k])
            out.append({
                "kind": "box",
                "points": [[round(u - hu, 1), round(v - hv, 1)], [round(u + hu, 1), round(v + hv, 1)]],
                "label": f"{cls.label} {ident}",
                "color": CLASS_COLOR[cls],
                "track": int(objs.track[k]),
            })  # fmt: skip
        self._cache = (objs.frame, out)
        return out


def risk_polygons_px(world: WorldModel) -> list[dict[str, Any]]:
    """The risk map's levels as polygon features (footage pixels), lowest level first (higher levels drawn over)."""
    rm = world.risk_map
    raster = rm.raster
    if raster.size <= 1 or not raster.any():
        return []
    # footage px (centres) -> ground -> raster cell; its inverse maps traced cell outlines back to footage pixels
    px_to_cell = rm.ned_to_cell @ world.geometry.px_to_ground
    cell_to_px = np.linalg.inv(px_to_cell)
    out: list[dict[str, Any]] = []
    for level in range(1, 6):
        mask = (raster == level).astype(np.uint8)
        if not mask.any():
            continue
        contours, hierarchy = cv2.findContours(mask, cv2.RETR_CCOMP, cv2.CHAIN_APPROX_SIMPLE)
        if hierarchy is None:
            continue
        r, g, b = LEVEL_RGB[level]

        def to_px(c: Any) -> list[list[float]]:
            pts = cv2.approxPolyDP(c, 0.75, True).reshape(-1, 2).astype(np.float64)
            h = np.c_[pts, np.ones(len(pts))] @ cell_to_px.T
            return [[round(float(x), 1), round(float(y), 1)] for x, y in h[:, :2] / h[:, 2:3]]

        for i, c in enumerate(contours):
            if hierarchy[0][i][3] != -1:  # a hole: drawn with its outer ring
                continue
            holes = []
            child = hierarchy[0][i][2]
            while child != -1:
                holes.append(to_px(contours[child]))
                child = hierarchy[0][child][0]
            out.append({
                "kind": "polygon",
                "points": to_px(c),
                "holes": holes,
                "label": f"risk {level}",
                "level": level,
                "color": f"rgb({r},{g},{b})",
                "fill": f"rgba({r},{g},{b},{RISK_ALPHA})",
            })  # fmt: skip
            if len(out) >= MAX_RISK_POLYGONS:
                return out
    return out


class RiskMapLayer:
    """The static risk map (traced once; the same features at every time)."""

    name = "risk map"
    static = True

    def __init__(self, world: WorldModel) -> None:
        self.world = world
        self._features = risk_polygons_px(world)

    def features(self, time_s: float, footage_frame_index: int) -> list[dict[str, Any]]:
        return self._features


def world_layers(world: WorldModel) -> list[LayerProvider]:
    """The layers a world has ground truth for (none when it has neither objects nor a risk map)."""
    out: list[LayerProvider] = []
    if world.has_objects and len(world.tracks.tracks) > 0:
        out.append(ObjectsLayer(world))
    if world.has_risk_map:
        out.append(RiskMapLayer(world))
    return out


__all__ = ["ObjectsLayer", "RiskMapLayer", "risk_polygons_px", "world_layers"]
