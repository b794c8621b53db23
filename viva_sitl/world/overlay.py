"""Overview picture for humans: the footage frame at time t, the risk map (semi-transparent) and the objects."""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.footage.source import FootageSource
from viva_sitl.world.classes import ObjectClass
from viva_sitl.world.model import WorldModel

LEVEL_BGR = {1: (60, 180, 60), 2: (90, 220, 200), 3: (40, 210, 250), 4: (0, 140, 255), 5: (40, 40, 230)}
CLASS_BGR = {
    ObjectClass.PERSON: (255, 0, 255),
    ObjectClass.BICYCLE: (255, 128, 0),
    ObjectClass.CAR: (255, 255, 0),
    ObjectClass.BUS: (0, 255, 255),
    ObjectClass.TRUCK: (0, 200, 120),
    ObjectClass.OTHER: (200, 200, 200),
    ObjectClass.MOVING: (255, 255, 255),
}


def render_overview(
    world: WorldModel,
    src: FootageSource,
    t_s: float,
    max_size_px: int = 1600,
    risk_alpha: float = 0.35,
    show_risk: bool = True,
    show_ids: bool = True,
) -> NDArray[np.uint8]:
    """BGR image: frame at t (scaled to fit max_size_px), risk levels at t blended in, objects as boxes with ids."""
    g = src.geometry
    frame = src.frame(src.frame_index_at(t_s))
    s = min(1.0, max_size_px / max(g.width_px, g.height_px))
    w, h = max(1, round(g.width_px * s)), max(1, round(g.height_px * s))
    img = cv2.resize(np.asarray(frame), (w, h), interpolation=cv2.INTER_AREA).astype(np.uint8)
    # output pixel centre (x, y) -> footage pixel centre u = (x + 0.5) / s - 0.5 -> ground
    xs, ys = np.meshgrid((np.arange(w) + 0.5) / s - 0.5, (np.arange(h) + 0.5) / s - 0.5)
    m = g.px_to_ground
    den = m[2, 0] * xs + m[2, 1] * ys + m[2, 2]
    n = (m[0, 0] * xs + m[0, 1] * ys + m[0, 2]) / den
    e = (m[1, 0] * xs + m[1, 1] * ys + m[1, 2]) / den
    if show_risk:  # the level at t (static map raised around moving objects) at every output pixel
        levels = world.risk_levels_at(n, e, t_s)
        color = np.zeros_like(img)
        for lv, bgr in LEVEL_BGR.items():
            color[levels == lv] = bgr
        img = np.asarray(cv2.addWeighted(img, 1.0 - risk_alpha, color, risk_alpha, 0.0), np.uint8)
    objs = world.tracks.objects_at(t_s)
    to_px = g.ground_to_px
    font = cv2.FONT_HERSHEY_SIMPLEX
    for k in range(len(objs)):
        u, v, ww = to_px @ np.array([objs.ne_m[k, 0], objs.ne_m[k, 1], 1.0])
        x, y = (u / ww + 0.5) * s - 0.5, (v / ww + 0.5) * s - 0.5
        hw = max(2.0, objs.size_m[k, 0] / g.gsd_m_per_px * s / 2.0)
        hh = max(2.0, objs.size_m[k, 1] / g.gsd_m_per_px * s / 2.0)
        cls = ObjectClass(int(objs.object_class[k]))
        bgr = CLASS_BGR[cls]
        cv2.rectangle(
            img, (round(x - hw), round(y - hh)), (round(x + hw), round(y + hh)), bgr, 1, cv2.LINE_AA
        )
        cv2.circle(img, (round(x), round(y)), 2, bgr, -1, cv2.LINE_AA)
        if show_ids:
            info = world.tracks.tracks[int(objs.track[k])]
            label = f"{info.source_id if info.source_id is not None else int(objs.track[k])}"
            cv2.putText(img, label, (round(x + hw) + 2, round(y - hh)), font, 0.35, bgr, 1, cv2.LINE_AA)
    # legend
    counts: dict[str, int] = {}
    for c in objs.object_class:
        counts[ObjectClass(int(c)).label] = counts.get(ObjectClass(int(c)).label, 0) + 1
    lines = [
        f"{world.name}  t = {t_s:.2f} s  footage frame {src.frame_index_at(t_s)}  track frame {objs.frame}",
        "objects: " + (", ".join(f"{v} {k}" for k, v in sorted(counts.items())) or "none"),
    ]
    y0 = 8
    cv2.rectangle(img, (0, 0), (min(w - 1, 520), 84), (0, 0, 0), -1)
    for line in lines:
        y0 += 16
        cv2.putText(img, line, (6, y0), font, 0.45, (255, 255, 255), 1, cv2.LINE_AA)
    x = 6
    y0 += 22
    for lv, bgr in LEVEL_BGR.items():
        cv2.rectangle(img, (x, y0 - 11), (x + 14, y0 + 1), bgr, -1)
        cv2.putText(img, f"risk {lv}", (x + 18, y0), font, 0.4, (255, 255, 255), 1, cv2.LINE_AA)
        x += 68
    y0 += 18
    x = 6
    for cls, bgr in CLASS_BGR.items():
        cv2.circle(img, (x + 4, y0 - 4), 4, bgr, -1)
        cv2.putText(img, cls.label, (x + 11, y0), font, 0.35, (255, 255, 255), 1, cv2.LINE_AA)
        x += 18 + 6 * len(cls.label)
    return img
