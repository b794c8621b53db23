"""Static ground risk: SORA-style levels 1..5 as a label raster, rasterised from polygons (footage pixels or NED m).

Levels (ground risk to people if the vehicle comes down there):
  1  open ground, lawn, field, empty roof          (nobody expected)
  2  roof, trees, water, building                   (nobody on it, but a bad landing surface)
  3  path, sidewalk, parking                        (people pass by)
  4  road, plaza, railway                           (people/vehicles often)
  5  busy road, crowd                               (people/vehicles almost always)
Moving objects add their own level around them (world/model.py): person/bicycle 5 within 5 m, vehicles 4 within 3 m
by default. Ground no polygon covers has `default_level`; outside the raster (beyond the footage) too.

Polygon file (json, hand-made or generated), drawn in order (later polygons over earlier ones):
    {"units": "px" | "ned_m", "hand_made": true, "notes": "...", "image_size": [w, h],
     "polygons": [{"class": "road", "points": [[x, y], ...]}, ...]}
An entry with "width": w > 0 is an open polyline w wide (units of the file): roads and ramps drawn as lines.
"px" points are footage pixel-area coordinates (x right, y down; as box edges); "ned_m" points are (north, east).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.geometry import FootageGeometry

DEFAULT_CLASS_LEVELS: dict[str, int] = {
    "open_ground": 1, "lawn": 1, "grass": 1, "field": 1, "empty_roof": 1, "sand": 1,
    "roof": 2, "building": 2, "trees": 2, "water": 2,
    "path": 3, "sidewalk": 3, "parking": 3, "construction": 3,
    "road": 4, "plaza": 4, "railway": 4,
    "busy_road": 5, "crowd": 5,
}  # fmt: skip
MAX_RASTER_SIDE = 4096  # footage rasters are downscaled to at most this many cells a side
NED_CELL_M = 0.1


@dataclass(frozen=True)
class RiskPolygon:
    risk_class: str
    level: int
    points: NDArray[np.float64]  # (k, 2) in the file's units
    width: float = 0.0  # > 0: an open polyline this wide (a road drawn as a line), in the file's units


class RiskMap:
    """A level raster plus the affine map from ground (north, east) to raster cells; queries are pure."""

    def __init__(
        self,
        raster: NDArray[np.uint8],
        ned_to_cell: NDArray[np.float64],
        default_level: int,
        polygons: Sequence[RiskPolygon] = (),
        units: str = "px",
        hand_made: bool = False,
        notes: str = "",
    ) -> None:
        self.raster = raster  # 0 = default_level
        self.ned_to_cell = ned_to_cell  # 3x3: (north, east, 1) -> (col, row, 1), cell centres at integers
        self.default_level = int(default_level)
        self.polygons = tuple(polygons)
        self.units = units
        self.hand_made = hand_made
        self.notes = notes
        self._lut = np.arange(256, dtype=np.uint8)
        self._lut[0] = self.default_level

    def levels_at(self, north_m: NDArray[np.float64], east_m: NDArray[np.float64]) -> NDArray[np.uint8]:
        """Static level at each (north, east) (arrays of one shape)."""
        n = np.asarray(north_m, np.float64)
        e = np.asarray(east_m, np.float64)
        m = self.ned_to_cell
        col = np.rint(m[0, 0] * n + m[0, 1] * e + m[0, 2])
        row = np.rint(m[1, 0] * n + m[1, 1] * e + m[1, 2])
        h, w = self.raster.shape
        inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
        out = np.full(n.shape, self.default_level, np.uint8)
        if np.any(inside):
            out[inside] = self._lut[self.raster[row[inside].astype(np.intp), col[inside].astype(np.intp)]]
        return out

    def level_at(self, north_m: float, east_m: float) -> int:
        m = self.ned_to_cell
        col = round(m[0, 0] * north_m + m[0, 1] * east_m + m[0, 2])
        row = round(m[1, 0] * north_m + m[1, 1] * east_m + m[1, 2])
        h, w = self.raster.shape
        if 0 <= col < w and 0 <= row < h:
            return int(self._lut[self.raster[row, col]])
        return self.default_level

    @classmethod
    def uniform(cls, level: int) -> RiskMap:
        return cls(np.zeros((1, 1), np.uint8), np.zeros((3, 3)), level)


def read_polygons(path: Path, class_levels: dict[str, int]) -> tuple[list[RiskPolygon], str, bool, str, tuple[int, int] | None]:  # fmt: skip
    """(polygons, units, hand_made, notes, image_size) of a polygon json; one-line errors."""
    try:
        data = json.loads(Path(path).read_text(encoding="utf-8"))
    except OSError as exc:
        raise FootageError(f"cannot read risk polygons {path}: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise FootageError(f"risk polygons {path} is not valid json: {exc}") from None
    if not isinstance(data, dict) or not isinstance(data.get("polygons"), list):
        raise FootageError(f'{path}: expected {{"units": ..., "polygons": [...]}}')
    units = str(data.get("units", "px"))
    if units not in ("px", "ned_m"):
        raise FootageError(f"{path}: units must be px or ned_m, got {units!r}")
    out: list[RiskPolygon] = []
    for k, p in enumerate(data["polygons"]):
        cls_name = str(p.get("class", "")) if isinstance(p, dict) else ""
        if cls_name not in class_levels:
            raise FootageError(
                f"{path}: polygon #{k} class {cls_name!r} has no risk level (known: {', '.join(sorted(class_levels))})"
            )
        try:
            pts = np.array(p["points"], np.float64)
        except (KeyError, TypeError, ValueError):
            raise FootageError(f"{path}: polygon #{k} needs points [[x, y], ...]") from None
        width = p.get("width", 0.0)
        if isinstance(width, bool) or not isinstance(width, int | float) or not 0 <= width < math.inf:
            raise FootageError(f"{path}: polygon #{k} width must be a number >= 0, got {width!r}")
        need = 2 if width > 0 else 3
        if pts.ndim != 2 or pts.shape[1] != 2 or pts.shape[0] < need or not np.all(np.isfinite(pts)):
            raise FootageError(f"{path}: polygon #{k} needs at least {need} finite [x, y] points")
        out.append(RiskPolygon(cls_name, class_levels[cls_name], pts, float(width)))
    size = data.get("image_size")
    image_size = (int(size[0]), int(size[1])) if isinstance(size, list) and len(size) == 2 else None
    return out, units, bool(data.get("hand_made", False)), str(data.get("notes", "")), image_size


def _fill(raster: NDArray[np.uint8], polys: Sequence[RiskPolygon], to_cell: NDArray[np.float64]) -> None:
    cells_per_unit = math.sqrt(abs(np.linalg.det(to_cell[:2, :2])))
    for p in polys:
        hom = np.column_stack([p.points, np.ones(len(p.points))]) @ to_cell.T
        pts = [np.round(hom[:, :2] / hom[:, 2:3] * 16).astype(np.int32)]
        if p.width > 0:
            thick = max(1, round(p.width * cells_per_unit))
            cv2.polylines(raster, pts, False, int(p.level), thick, cv2.LINE_8, 4)
        else:
            cv2.fillPoly(raster, pts, int(p.level), cv2.LINE_8, 4)


def risk_map_from_polygons(
    polygons: Sequence[RiskPolygon],
    geometry: FootageGeometry,
    default_level: int,
    units: str = "px",
    hand_made: bool = False,
    notes: str = "",
    image_size: tuple[int, int] | None = None,
) -> RiskMap:
    if units == "ned_m":
        if not polygons:
            return RiskMap.uniform(default_level)
        allp = np.concatenate([p.points for p in polygons])
        n_max, e_min = float(allp[:, 0].max()), float(allp[:, 1].min())
        w = int(math.ceil((allp[:, 1].max() - e_min) / NED_CELL_M)) + 2
        h = int(math.ceil((n_max - allp[:, 0].min()) / NED_CELL_M)) + 2
        c = 1.0 / NED_CELL_M
        to_cell = np.array([[0.0, c, -e_min * c + 0.5], [-c, 0.0, n_max * c + 0.5], [0, 0, 1.0]])
        raster = np.zeros((h, w), np.uint8)
        _fill(raster, polygons, to_cell)
        return RiskMap(raster, to_cell, default_level, polygons, units, hand_made, notes)
    # footage pixels (pixel-area coordinates); a polygon file made on a resized image is scaled to the footage
    sx = sy = 1.0
    if image_size is not None:
        sx, sy = geometry.width_px / image_size[0], geometry.height_px / image_size[1]
    s = min(1.0, MAX_RASTER_SIDE / max(geometry.width_px, geometry.height_px))
    w, h = max(1, round(geometry.width_px * s)), max(1, round(geometry.height_px * s))
    area_to_cell = np.array([[s * sx, 0.0, -0.5], [0.0, s * sy, -0.5], [0, 0, 1.0]])
    raster = np.zeros((h, w), np.uint8)
    _fill(raster, polygons, area_to_cell)
    # ned -> footage pixel centre (u, v) -> area (u + 0.5) -> cell (area * s - 0.5)
    centre_to_cell = np.array([[s, 0.0, 0.5 * s - 0.5], [0.0, s, 0.5 * s - 0.5], [0, 0, 1.0]])
    return RiskMap(
        raster, centre_to_cell @ geometry.ground_to_px, default_level, polygons, units, hand_made, notes
    )


def risk_map_from_raster(path: Path, geometry: FootageGeometry, default_level: int) -> RiskMap:
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise FootageError(f"cannot read risk raster {path} (a single-channel PNG: pixel value = level 0..5)")
    if int(img.max()) > 5:
        raise FootageError(f"risk raster {path}: pixel values must be levels 0..5, found {int(img.max())}")
    h, w = img.shape
    sx, sy = w / geometry.width_px, h / geometry.height_px
    centre_to_cell = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0, 0, 1.0]])
    return RiskMap(img.astype(np.uint8), centre_to_cell @ geometry.ground_to_px, default_level)
