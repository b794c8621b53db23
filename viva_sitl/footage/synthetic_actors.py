"""People and cars of the synthetic calibration field: analytic paths, drawn into the footage, exact ground truth.

Everything lives near the origin (within +-60 m), where trials fly:
  - a ring road (asphalt annulus, radius 46..54 m) with three cars: two clockwise in the outer lane (r = 52 m),
    one counter-clockwise in the inner lane (r = 48 m), 30 s a lap (~10 m/s);
  - four walking people (1.3 m/s): back and forth on straight lines, or round a circle;
  - a crowd of 16 people on a paved plaza around (N-25, E-15), each milling on a small circle.

Every period divides 60 s (the field's loop), so the footage loops seamlessly. `actor_position_ne_m(a, t)` is the
ground truth; `draw_actors` paints each actor centred exactly there (1/16 px sub-pixel precision), so the colour
centroid of a drawn person or car is its ground-truth point. `scene_risk_polygons_ne_m()` gives the risk map of
the painted ground by construction (the same constants draw it).

Kept separate from synthetic.py: that module calls `draw_scene_ground` once for the background and `draw_actors`
per frame; nothing else couples them.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

PERSON_BGR = (255, 0, 255)  # magenta walkers
CROWD_BGR = (255, 255, 0)  # cyan crowd members
CAR_BGR = (0, 140, 255)  # orange cars
ROAD_BGR = (70, 70, 70)
PLAZA_BGR = (150, 165, 175)

RING_CENTER_NE_M = (0.0, 0.0)
RING_INNER_M, RING_OUTER_M = 46.0, 54.0
PLAZA_CENTER_NE_M = (-25.0, -15.0)
PLAZA_HALF_M = 7.0
PERSON_SIZE_M = 0.7  # disc diameter seen from above
CAR_SIZE_M = (4.5, 1.9)  # length along travel, width


@dataclass(frozen=True)
class Actor:
    """One moving object of the synthetic field. kind: 'line' (a -> b -> a, one round trip per period) or 'circle'."""

    name: str
    object_class: str  # person | car (world classes)
    kind: str
    a_ne_m: tuple[float, float]  # line start or circle centre
    b_ne_m: tuple[float, float] = (0.0, 0.0)  # line end
    radius_m: float = 0.0
    period_s: float = 60.0
    phase_rad: float = 0.0
    clockwise: bool = True  # circle direction seen from above (north up, east right)
    color_bgr: tuple[int, int, int] = PERSON_BGR

    @property
    def size_m(self) -> tuple[float, float]:
        """(length along travel, width) on the ground."""
        return CAR_SIZE_M if self.object_class == "car" else (PERSON_SIZE_M, PERSON_SIZE_M)


def actor_position_ne_m(a: Actor, t_s: float) -> tuple[float, float]:
    """Exact ground position (north, east) of actor `a` at time t."""
    if a.kind == "circle":
        ang = (1.0 if a.clockwise else -1.0) * 2.0 * math.pi * t_s / a.period_s + a.phase_rad
        return a.a_ne_m[0] + a.radius_m * math.cos(ang), a.a_ne_m[1] + a.radius_m * math.sin(ang)
    s = (t_s / a.period_s) % 1.0
    f = 2.0 * s if s < 0.5 else 2.0 - 2.0 * s
    return a.a_ne_m[0] + f * (a.b_ne_m[0] - a.a_ne_m[0]), a.a_ne_m[1] + f * (a.b_ne_m[1] - a.a_ne_m[1])


def actor_heading_rad(a: Actor, t_s: float) -> float:
    """Direction of travel (bearing from north, radians) at time t."""
    if a.kind == "circle":
        ang = (1.0 if a.clockwise else -1.0) * 2.0 * math.pi * t_s / a.period_s + a.phase_rad
        dn, de = -math.sin(ang), math.cos(ang)
        if not a.clockwise:
            dn, de = -dn, -de
        return math.atan2(de, dn)
    s = (t_s / a.period_s) % 1.0
    dn, de = a.b_ne_m[0] - a.a_ne_m[0], a.b_ne_m[1] - a.a_ne_m[1]
    return math.atan2(de, dn) if s < 0.5 else math.atan2(-de, -dn)


def _crowd() -> tuple[Actor, ...]:
    out = []
    golden = math.pi * (3.0 - math.sqrt(5.0))
    for k in range(16):  # a sunflower spiral of base points, >= 1.2 m apart, each milling on a 0.4 m circle
        r = 1.25 * math.sqrt(k + 0.5)
        c = (PLAZA_CENTER_NE_M[0] + r * math.cos(k * golden), PLAZA_CENTER_NE_M[1] + r * math.sin(k * golden))
        out.append(
            Actor(
                f"crowd-{k:02d}",
                "person",
                "circle",
                c,
                radius_m=0.4,
                period_s=30.0 if k % 2 else 60.0,
                phase_rad=k * 0.7,
                clockwise=k % 3 != 0,
                color_bgr=CROWD_BGR,
            )  # fmt: skip
        )
    return tuple(out)


DEFAULT_ACTORS: tuple[Actor, ...] = (
    Actor("walker-1", "person", "line", (10.0, -30.0), (10.0, 9.0), period_s=60.0),
    Actor("walker-2", "person", "circle", (-20.0, 25.0), radius_m=12.4, period_s=60.0),
    Actor("walker-3", "person", "line", (-35.0, -40.0), (4.0, -40.0), period_s=60.0),
    Actor("walker-4", "person", "line", (58.0, -10.0), (58.0, 29.0), period_s=60.0, phase_rad=0.0),
    Actor("car-1", "car", "circle", RING_CENTER_NE_M, radius_m=52.0, period_s=30.0, color_bgr=CAR_BGR),
    Actor(
        "car-2",
        "car",
        "circle",
        RING_CENTER_NE_M,
        radius_m=52.0,
        period_s=30.0,
        phase_rad=math.pi,
        color_bgr=CAR_BGR,
    ),  # fmt: skip
    Actor(
        "car-3",
        "car",
        "circle",
        RING_CENTER_NE_M,
        radius_m=48.0,
        period_s=30.0,
        phase_rad=math.pi / 2,
        clockwise=False,
        color_bgr=CAR_BGR,
    ),  # fmt: skip
    *_crowd(),
)

ToPx = Callable[[float, float], tuple[float, float]]
_SHIFT = 4  # 1/16 px sub-pixel precision
_S = 1 << _SHIFT


def _circle_poly_ne(center: tuple[float, float], r: float, n: int = 360) -> list[tuple[float, float]]:
    return [
        (center[0] + r * math.cos(2 * math.pi * k / n), center[1] + r * math.sin(2 * math.pi * k / n))
        for k in range(n)
    ]


def _plaza_ne() -> list[tuple[float, float]]:
    (n0, e0), h = PLAZA_CENTER_NE_M, PLAZA_HALF_M
    return [(n0 + h, e0 - h), (n0 + h, e0 + h), (n0 - h, e0 + h), (n0 - h, e0 - h)]


def scene_risk_polygons_ne_m() -> list[tuple[str, list[tuple[float, float]]]]:
    """(risk class, polygon in NED metres) in drawing order (later over earlier): exact by construction."""
    return [
        ("busy_road", _circle_poly_ne(RING_CENTER_NE_M, RING_OUTER_M)),
        ("lawn", _circle_poly_ne(RING_CENTER_NE_M, RING_INNER_M)),
        ("plaza", _plaza_ne()),
    ]


def _fill_ne(
    img: NDArray[np.uint8], poly: list[tuple[float, float]], to_px: ToPx, color: tuple[int, ...]
) -> None:
    pts = np.array([to_px(n, e) for n, e in poly])
    cv2.fillPoly(img, [np.round(pts * _S).astype(np.int32)], color, cv2.LINE_AA, _SHIFT)


def draw_scene_ground(img: NDArray[np.uint8], to_px: ToPx) -> None:
    """Paint the ring road and the plaza into the static background (in place)."""
    h, w = img.shape[:2]
    ground = img.copy()
    _fill_ne(img, _circle_poly_ne(RING_CENTER_NE_M, RING_OUTER_M, 360), to_px, ROAD_BGR)
    # the lawn inside the ring keeps the field's own ground (texture included)
    mask = np.zeros((h, w), np.uint8)
    _fill_ne(mask, _circle_poly_ne(RING_CENTER_NE_M, RING_INNER_M, 360), to_px, (255,))
    inside = mask > 127
    img[inside] = ground[inside]
    _fill_ne(img, _plaza_ne(), to_px, PLAZA_BGR)


def draw_actors(img: NDArray[np.uint8], t_s: float, to_px: ToPx, gsd_m_per_px: float, actors: tuple[Actor, ...] = DEFAULT_ACTORS) -> None:  # fmt: skip
    """Paint every actor at its exact position at time t (in place): people as discs, cars as oriented boxes."""
    for a in actors:
        n, e = actor_position_ne_m(a, t_s)
        u, v = to_px(n, e)
        if a.object_class == "car":
            hdg = actor_heading_rad(a, t_s)
            fwd = np.array([math.cos(hdg), math.sin(hdg)])  # (n, e) unit along travel
            right = np.array([-fwd[1], fwd[0]])
            hl, hw = CAR_SIZE_M[0] / 2.0, CAR_SIZE_M[1] / 2.0
            corners = [
                fwd * hl + right * hw,
                fwd * hl - right * hw,
                -fwd * hl - right * hw,
                -fwd * hl + right * hw,
            ]
            pts = np.array([to_px(n + c[0], e + c[1]) for c in corners])
            cv2.fillPoly(img, [np.round(pts * _S).astype(np.int32)], a.color_bgr, cv2.LINE_AA, _SHIFT)
        else:
            r_px = PERSON_SIZE_M / 2.0 / gsd_m_per_px
            cv2.circle(
                img, (round(u * _S), round(v * _S)), round(r_px * _S), a.color_bgr, -1, cv2.LINE_AA, _SHIFT
            )
