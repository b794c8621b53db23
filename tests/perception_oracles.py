"""Models for the perception-eval tests (`perception_oracles:NAME` factories): oracles that answer from the frame's
pose through `dataset export`'s label geometry (ground_rectangles + project_boxes, risk_mask), so a perfect model's
scores are known exactly, and degraded versions of them."""

from __future__ import annotations

from functools import cache
from typing import Any

import numpy as np

from viva_sitl.camera import CameraParams
from viva_sitl.camera.projection import ground_to_image_homography
from viva_sitl.perception.dataset import ground_rectangles, project_boxes, risk_mask

SHIFT_PX = 6.0  # shifted_detector: every box moved right by this many pixels
SHIFT_FRACTION = 0.2  # fraction_shifted_detector: every box moved right by this share of its width (IoU 2/3)


@cache
def _world(name: str) -> Any:
    from viva_sitl.footage import open_footage
    from viva_sitl.world import world_from_source

    src = open_footage(name)
    try:
        return world_from_source(src)
    finally:
        src.close()


def truth_rows(meta: dict[str, Any]) -> np.ndarray:
    """[x0, y0, x1, y1, class, 1.0] of the objects in the frame, as `dataset export` labels them."""
    params = CameraParams(width_px=meta["width_px"], height_px=meta["height_px"])
    pos, att = np.array(meta["pos_ned_m"]), np.array(meta["att_rpy_rad"])
    h = ground_to_image_homography(pos, att, params)
    boxes = project_boxes(ground_rectangles(_world(meta["footage"]), meta["time_s"]), h, params, 0.5)
    return np.array([[b.x0, b.y0, b.x1, b.y1, b.object_class, 1.0] for b in boxes], np.float64).reshape(-1, 6)


def gt_detector() -> Any:
    return lambda image, meta: truth_rows(meta)


def empty_detector() -> Any:
    return lambda image: np.zeros((0, 6))


def shifted_detector() -> Any:
    def run(image: Any, meta: dict[str, Any]) -> np.ndarray:
        r = truth_rows(meta)
        r[:, [0, 2]] += SHIFT_PX
        return r

    return run


def fraction_shifted_detector() -> Any:
    def run(image: Any, meta: dict[str, Any]) -> np.ndarray:
        r = truth_rows(meta)
        d = SHIFT_FRACTION * (r[:, 2] - r[:, 0])
        r[:, 0] += d
        r[:, 2] += d
        return r

    return run


def gt_segmenter() -> Any:
    def run(image: Any, meta: dict[str, Any]) -> np.ndarray:
        params = CameraParams(width_px=meta["width_px"], height_px=meta["height_px"])
        pos, att = np.array(meta["pos_ned_m"]), np.array(meta["att_rpy_rad"])
        return risk_mask(_world(meta["footage"]), pos, att, meta["time_s"], params)

    return run


def all_safe_segmenter() -> Any:
    return lambda image: np.ones(image.shape[:2], np.uint8)


def broken_factory() -> Any:
    raise RuntimeError("weights file corrupt")


def lens_gt_segmenter() -> Any:
    """gt_segmenter through the lens: the level of the ideal-pinhole pixel each distorted pixel shows."""
    from viva_sitl.camera.effects import distortion_source_map
    from viva_sitl.camera.projection import camera_intrinsics

    def run(image: Any, meta: dict[str, Any]) -> np.ndarray:
        k1, k2 = meta["lens_k1_k2"]
        params = CameraParams(width_px=meta["width_px"], height_px=meta["height_px"], k1=k1, k2=k2)
        pos, att = np.array(meta["pos_ned_m"]), np.array(meta["att_rpy_rad"])
        src = distortion_source_map(params, camera_intrinsics(params)) if params.has_distortion else None
        return risk_mask(_world(meta["footage"]), pos, att, meta["time_s"], params, src)

    return run


SHARPNESS: list[tuple[float, float]] = []  # sharpness_probe: (speed, variance of the Laplacian) per frame


def sharpness_probe() -> Any:
    """Detects nothing; records how sharp each evaluated frame is (blur lowers it, noise raises it)."""
    import cv2

    def run(image: Any, meta: dict[str, Any]) -> np.ndarray:
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        SHARPNESS.append(
            (float(np.hypot(*meta["vel_ned_m_s"][:2])), float(cv2.Laplacian(gray, cv2.CV_64F).var()))
        )
        return np.zeros((0, 6))

    return run
