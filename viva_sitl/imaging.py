"""Image primitives shared by the camera, the footage tile caches and perception (the ground floor: numpy + OpenCV).

    half_size(image) -> the next pyramid level (2x2 box average, INTER_AREA, odd sizes rounded up)
    max_pyramid_level(width_px, height_px) -> the deepest useful level (halve while the smaller side is > 1 px)
    check_bgr(image, what, error) -> the image as an HxWx3 uint8 array, else `error` with one line

camera/pyramid.py builds its mip-maps and footage/tiles.py its stored levels with the same two functions, so a tile
cache's levels stay bit-identical to the levels the renderer would build from the frame itself.
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

U8 = NDArray[np.uint8]


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


def check_bgr(image: Any, what: str = "image", error: type[Exception] = ValueError) -> U8:
    """`image` as an HxWx3 uint8 (BGR) array; anything else raises `error` naming `what`, its dtype and shape."""
    a = np.asarray(image)
    if a.dtype != np.uint8 or a.ndim != 3 or a.shape[2] != 3 or a.shape[0] < 1 or a.shape[1] < 1:
        raise error(f"{what} must be an HxWx3 uint8 BGR array, got {a.dtype} {a.shape}")
    return a
