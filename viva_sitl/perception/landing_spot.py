"""Landing-spot planning on the ground under the camera: risk levels on a north/east grid, and the spot to land on.

What a vision landing companion (mission_scripts/vision_landing.py) decides with, as library code it and the tests
import: `Eyes` turns one frame and its pose into a `RiskView` (risk level 1..5 per ground cell from the segmenter,
keep-out discs of level 5 around detected people and vehicles); `choose_spot` picks the lowest-risk reachable
spot in it, `check_spot` re-checks a chosen spot in a newer view.

Needs only numpy and OpenCV at import: the segmenter's module (torch) is imported when `Eyes.look` first runs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.perception.detect import Detector

# detector class names: a derived "moving object" counts as a person (careful)
PERSON_NAMES = frozenset({"person", "bicycle", "moving object"})
VEHICLE_NAMES = frozenset({"car", "bus", "truck"})


@dataclass(frozen=True)
class PlanConfig:
    cell_m: float = 0.5  # ground grid cell
    margin_m: float = 2.0  # landing precision: the spot's level is the worst within this disc
    clearance_cap_m: float = 15.0  # clearance from level >= 4 beyond this does not matter
    search_radius_m: float = 40.0  # reachable: at most this far from where it is
    person_buffer_m: float = 6.0  # keep-out disc (level 5) around a detected person
    vehicle_buffer_m: float = 4.0  # ... around a detected vehicle
    accept_level: int = 2  # a spot whose level rises above max(planned, this) is re-planned


@dataclass(frozen=True)
class Spot:
    north_m: float
    east_m: float
    level: int  # worst predicted level within margin_m
    clearance_m: float  # distance to the nearest predicted level >= 4 (capped)
    distance_m: float  # from where it looked


@dataclass
class RiskView:
    """Predicted levels on a north/east grid (0 = not seen) and what went into them."""

    levels: NDArray[np.uint8]
    north0_m: float
    east0_m: float
    cell_m: float
    people: int
    vehicles: int
    sim_time_s: float

    def cell_of(self, north_m: float, east_m: float) -> tuple[int, int]:
        return round((north_m - self.north0_m) / self.cell_m), round((east_m - self.east0_m) / self.cell_m)


class Eyes:
    """The segmenter and/or detector, turning one frame + its pose into a RiskView."""

    def __init__(self, segmenter: Any | None, detector: Any | None, cfg: PlanConfig) -> None:
        self.segmenter, self.detector, self.cfg = segmenter, detector, cfg

    def look(self, image_bgr: NDArray[np.uint8], meta: dict[str, Any]) -> RiskView:
        from viva_sitl.perception.segment import Segmenter  # torch: only once there is something to look at

        cfg = self.cfg
        if self.segmenter is not None:
            img_levels = cv2.medianBlur(self.segmenter.predict(image_bgr), 5)  # speckle is not ground
        else:  # detector only: every seen pixel is open ground unless a detection says otherwise
            img_levels = np.ones(image_bgr.shape[:2], np.uint8)
        ground = Segmenter.on_ground(img_levels, cell_m=cfg.cell_m, meta=meta)
        levels = ground.levels.copy()
        people = vehicles = 0
        if self.detector is not None:
            dets = self.detector.detect(image_bgr)
            ne = Detector.on_ground(dets, meta=meta)
            rows, cols = levels.shape
            nn, ee = np.meshgrid(
                ground.north0_m + cfg.cell_m * np.arange(rows),
                ground.east0_m + cfg.cell_m * np.arange(cols),
                indexing="ij",
            )
            for d, (n, e) in zip(dets, ne, strict=True):
                name = d.name.lower()
                if not (math.isfinite(n) and math.isfinite(e)):
                    continue
                if name in PERSON_NAMES:
                    people, r = people + 1, cfg.person_buffer_m
                elif name in VEHICLE_NAMES:
                    vehicles, r = vehicles + 1, cfg.vehicle_buffer_m
                else:
                    continue
                levels[(nn - n) ** 2 + (ee - e) ** 2 <= r * r] = 5
        return RiskView(levels, ground.north0_m, ground.east0_m, cfg.cell_m, people, vehicles,
                        float(meta.get("sim_time_s", math.nan)))  # fmt: skip


def _disc(radius_cells: int) -> NDArray[np.uint8]:
    k = 2 * radius_cells + 1
    return np.asarray(cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (k, k)), np.uint8)


def spot_maps(view: RiskView, cfg: PlanConfig) -> tuple[NDArray[np.uint8], NDArray[np.float32], NDArray[np.float32]]:  # fmt: skip
    """(worst level within margin_m, clearance from level >= 4 in m, distance to unseen ground in m) per cell."""
    lv = view.levels
    r = max(1, round(cfg.margin_m / view.cell_m))
    worst = np.asarray(cv2.dilate(lv, _disc(r)), np.uint8)
    pad = 1  # outside the grid is unseen
    safe = np.pad((lv < 4).astype(np.uint8), pad, constant_values=1)
    seen = np.pad((lv > 0).astype(np.uint8), pad, constant_values=0)
    clear = cv2.distanceTransform(safe, cv2.DIST_L2, 5)[pad:-pad, pad:-pad] * view.cell_m
    edge = cv2.distanceTransform(seen, cv2.DIST_L2, 5)[pad:-pad, pad:-pad] * view.cell_m
    return worst, np.asarray(clear, np.float32), np.asarray(edge, np.float32)


def choose_spot(view: RiskView, here_ne: tuple[float, float], cfg: PlanConfig) -> Spot | None:
    """The best seen spot within reach (None: nothing seen far enough from the edge of the view)."""
    worst, clear, edge = spot_maps(view, cfg)
    rows, cols = view.levels.shape
    n = view.north0_m + view.cell_m * np.arange(rows)[:, None] + np.zeros((1, cols))
    e = view.east0_m + view.cell_m * np.arange(cols)[None, :] + np.zeros((rows, 1))
    dist = np.hypot(n - here_ne[0], e - here_ne[1])
    ok = (view.levels > 0) & (edge >= cfg.margin_m) & (dist <= cfg.search_radius_m)
    if not ok.any():
        return None
    w, c, d = worst[ok], np.minimum(clear[ok], cfg.clearance_cap_m), dist[ok]
    best = int(np.lexsort((d, -np.round(c), w))[0])  # last key first: level, clearance (1 m steps), distance
    return Spot(float(n[ok][best]), float(e[ok][best]), int(w[best]), float(c[best]), float(d[best]))


def check_spot(view: RiskView, spot: Spot, cfg: PlanConfig) -> tuple[int, float] | None:
    """(worst level within margin, clearance) at the spot in a new view; None when the spot is not in it."""
    r, c = view.cell_of(spot.north_m, spot.east_m)
    rows, cols = view.levels.shape
    if not (0 <= r < rows and 0 <= c < cols) or view.levels[r, c] == 0:
        return None
    worst, clear, _ = spot_maps(view, cfg)
    return int(worst[r, c]), float(min(clear[r, c], cfg.clearance_cap_m))
