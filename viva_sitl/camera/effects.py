"""Optional VAC effects the paper names as extensions: motion blur, sensor noise, radial lens distortion."""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.camera.params import CameraParams

U8 = NDArray[np.uint8]
F32 = NDArray[np.float32]

MAX_BLUR_PX = 128.0  # longer blur streaks are clipped to this length (px)


def motion_blur_kernel(shift_px: tuple[float, float]) -> F32 | None:
    """Normalised line kernel for a straight blur streak of `shift_px` (dx, dy) pixels; None below half a pixel."""
    dx, dy = float(shift_px[0]), float(shift_px[1])
    length = math.hypot(dx, dy)
    if not math.isfinite(length) or length < 0.5:
        return None
    if length > MAX_BLUR_PX:
        dx, dy = dx * MAX_BLUR_PX / length, dy * MAX_BLUR_PX / length
    # Hand-written (OpenCV's anti-aliased lines are ~2 px wide): splat dense samples of the streak bilinearly, so a
    # streak along an axis stays exactly one pixel wide.
    size = 2 * math.ceil(max(abs(dx), abs(dy)) / 2.0) + 3  # odd, with a margin for the bilinear splat
    c = (size - 1) / 2.0
    t = np.linspace(-0.5, 0.5, max(2, math.ceil(4.0 * math.hypot(dx, dy)) + 1))
    xs, ys = c + t * dx, c + t * dy
    x0, y0 = np.floor(xs).astype(int), np.floor(ys).astype(int)
    fx, fy = xs - x0, ys - y0
    k = np.zeros((size, size), np.float64)
    np.add.at(k, (y0, x0), (1 - fx) * (1 - fy))
    np.add.at(k, (y0, x0 + 1), fx * (1 - fy))
    np.add.at(k, (y0 + 1, x0), (1 - fx) * fy)
    np.add.at(k, (y0 + 1, x0 + 1), fx * fy)
    return np.asarray(k / k.sum(), dtype=np.float32)


def apply_motion_blur(image_bgr: U8, shift_px: tuple[float, float]) -> U8:
    """Blur `image_bgr` along the streak (dx, dy) in pixels that a point travels during the exposure."""
    k = motion_blur_kernel(shift_px)
    if k is None:
        return image_bgr
    return np.asarray(cv2.filter2D(image_bgr, -1, k, borderType=cv2.BORDER_REPLICATE), dtype=np.uint8)


def add_sensor_noise(image_bgr: U8, noise_std: float, rng: np.random.Generator) -> U8:
    """Additive Gaussian noise of `noise_std` 8-bit levels, drawn from `rng` (never the global RNG), clipped."""
    if noise_std <= 0.0:
        return image_bgr
    noise = rng.standard_normal(image_bgr.shape, dtype=np.float32)
    noise *= np.float32(noise_std)
    noise += image_bgr
    np.clip(noise, 0.0, 255.0, out=noise)
    return np.asarray(np.rint(noise), dtype=np.uint8)


def distortion_source_map(params: CameraParams, k_matrix: NDArray[np.float64]) -> NDArray[np.float64]:
    """For every pixel of the distorted VAC image, the ideal-pinhole pixel it shows: (H, W, 2) float64.

    Distorted normalised coordinates x_d = x_u (1 + k1 r^2 + k2 r^4) (OpenCV's model); inverted per pixel with
    cv2.undistortPoints (iterative, 50 steps), computed once per camera.
    """
    w, h = params.width_px, params.height_px
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    pts = np.stack([uu.ravel(), vv.ravel()], axis=1).reshape(-1, 1, 2)
    dist = np.array([params.k1, params.k2, 0.0, 0.0], dtype=np.float64)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-9)
    und = cv2.undistortPoints(pts, k_matrix, dist, None, k_matrix, criteria=criteria)
    return np.asarray(und, dtype=np.float64).reshape(h, w, 2)
