"""Image quality figures for super-resolution benchmarks: PSNR and SSIM (Wang et al. 2004, Gaussian window)."""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray


def _luma(image: NDArray[np.uint8]) -> NDArray[np.float64]:
    if image.ndim == 3:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2YCrCb)[..., 0], np.float64)
    return np.asarray(image, np.float64)


def psnr_db(test: NDArray[np.uint8], reference: NDArray[np.uint8], border_px: int = 0) -> float:
    """PSNR (dB) on the luma channel, ignoring `border_px` at each edge (as SR papers do)."""
    if test.shape != reference.shape:
        raise ValueError(f"images differ in size: {test.shape} vs {reference.shape}")
    a, b = _luma(test), _luma(reference)
    if border_px:
        a, b = a[border_px:-border_px, border_px:-border_px], b[border_px:-border_px, border_px:-border_px]
    mse = float(np.mean((a - b) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0**2 / mse)


def ssim(test: NDArray[np.uint8], reference: NDArray[np.uint8], border_px: int = 0) -> float:
    """Mean SSIM on the luma channel (11x11 Gaussian window, sigma 1.5, K1 0.01, K2 0.03)."""
    if test.shape != reference.shape:
        raise ValueError(f"images differ in size: {test.shape} vs {reference.shape}")
    a, b = _luma(test), _luma(reference)
    if border_px:
        a, b = a[border_px:-border_px, border_px:-border_px], b[border_px:-border_px, border_px:-border_px]
    c1, c2 = (0.01 * 255) ** 2, (0.03 * 255) ** 2

    def blur(x: NDArray[np.float64]) -> NDArray[np.float64]:
        return np.asarray(cv2.GaussianBlur(x, (11, 11), 1.5), np.float64)

    mu_a, mu_b = blur(a), blur(b)
    s_aa = blur(a * a) - mu_a**2
    s_bb = blur(b * b) - mu_b**2
    s_ab = blur(a * b) - mu_a * mu_b
    num = (2 * mu_a * mu_b + c1) * (2 * s_ab + c2)
    den = (mu_a**2 + mu_b**2 + c1) * (s_aa + s_bb + c2)
    return float(np.mean(num / den))


def degrade_area(image_bgr: NDArray[np.uint8], scale: int) -> NDArray[np.uint8]:
    """The low-resolution version SR learns to invert: area downscale (anti-aliased), floor(w/s) x floor(h/s)."""
    h, w = image_bgr.shape[:2]
    hr = image_bgr[: h - h % scale, : w - w % scale]
    return np.asarray(
        cv2.resize(hr, (hr.shape[1] // scale, hr.shape[0] // scale), interpolation=cv2.INTER_AREA)
    )
