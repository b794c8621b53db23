"""Mip-map pyramids of a footage frame, full or built lazily down to the needed level.

Each level halves the previous one with cv2.resize(INTER_AREA) (a 2x2 box average; size ((w + 1) // 2, (h + 1) // 2)).
Why box and not cv2.pyrDown's Gaussian: against an area-averaged reference (what a real sensor integrates), over a
sweep of 2-7 footage px per VAC px, the box mip-map is as good or better on average and clearly better in the worst
case, and it builds about 2x faster (bench/bench_render.py, "Sweep" in bench/results_render.md).
Levels are edge-aligned with level 0: u_l + 0.5 = (u_0 + 0.5) * w_l / w_0 (see `level_from_source`).
"""

from __future__ import annotations

import threading
import time

import cv2
import numpy as np
from numpy.typing import NDArray

U8 = NDArray[np.uint8]


def check_image(image_bgr: NDArray[np.generic]) -> None:
    if not isinstance(image_bgr, np.ndarray) or image_bgr.ndim not in (2, 3) or image_bgr.size == 0:
        raise ValueError("pyramid source must be a non-empty (h, w) or (h, w, c) array")
    if image_bgr.dtype != np.uint8:
        raise ValueError(f"pyramid source must be uint8, got {image_bgr.dtype}")


def max_pyramid_level(width_px: int, height_px: int) -> int:
    """Deepest useful level: halve while the smaller side is still above 1 px."""
    level = 0
    w, h = width_px, height_px
    while min(w, h) > 1:
        w, h = (w + 1) // 2, (h + 1) // 2
        level += 1
    return level


def half_size(image: U8) -> U8:
    """The next pyramid level: a 2x2 box average (INTER_AREA), odd sizes rounded up."""
    h, w = image.shape[:2]
    return np.asarray(
        cv2.resize(image, ((w + 1) // 2, (h + 1) // 2), interpolation=cv2.INTER_AREA), dtype=np.uint8
    )


def level_from_source(src_w: int, src_h: int, level_w: int, level_h: int) -> NDArray[np.float64]:
    """3x3 mapping level-0 pixel coordinates to those of a level of size level_w x level_h (pixel edges aligned)."""
    sx, sy = level_w / src_w, level_h / src_h
    return np.array([[sx, 0.0, 0.5 * (sx - 1.0)], [0.0, sy, 0.5 * (sy - 1.0)], [0.0, 0.0, 1.0]])


def build_pyramid(image_bgr: U8, levels: int) -> list[U8]:
    """[level 0 (the image itself), level 1, ..., level `levels`] by repeated halving (clamped to the deepest)."""
    check_image(image_bgr)
    if levels < 0:
        raise ValueError(f"levels must be >= 0, got {levels}")
    levels = min(levels, max_pyramid_level(image_bgr.shape[1], image_bgr.shape[0]))
    out = [image_bgr]
    for _ in range(levels):
        out.append(half_size(out[-1]))
    return out


class LazyPyramid:
    """A pyramid that builds levels on first use and keeps them (one per footage frame, cached by the caller).

    `level(l)` is thread-safe; the level-0 array is the caller's image (not copied: do not modify it afterwards).
    """

    def __init__(self, image_bgr: U8) -> None:
        check_image(image_bgr)
        self._levels: list[U8] = [image_bgr]
        self._lock = threading.Lock()
        self.max_level = max_pyramid_level(image_bgr.shape[1], image_bgr.shape[0])
        self.build_s = 0.0  # time spent building levels so far (s), for benchmarks

    @property
    def width_px(self) -> int:
        return int(self._levels[0].shape[1])

    @property
    def height_px(self) -> int:
        return int(self._levels[0].shape[0])

    @property
    def built_levels(self) -> int:
        """Number of levels built so far (1 = only the source)."""
        return len(self._levels)

    def level(self, index: int) -> U8:
        """Image of level `index` (clamped to max_level), building the missing levels."""
        if index < 0:
            raise ValueError(f"pyramid level must be >= 0, got {index}")
        index = min(index, self.max_level)
        if index < len(self._levels):
            return self._levels[index]
        with self._lock:
            t0 = time.perf_counter()
            while len(self._levels) <= index:
                self._levels.append(half_size(self._levels[-1]))
            self.build_s += time.perf_counter() - t0
            return self._levels[index]

    def __len__(self) -> int:
        return self.max_level + 1
