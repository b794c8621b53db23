"""Camera effects for perception evaluation: which of the VAC's effects an evaluated view gets, and the ground truth
seen through them.

    fx = EffectSpec.parse("blur,noise,distortion")          # --effects; "" or "none": a clean pinhole view
    params = fx.camera(CameraParams(width_px=640, height_px=480))

The effects are the renderer's own (viva_sitl/camera/effects.py, applied by `Renderer.render` exactly as the SITL
streams them), so a score measured here is the score of the frames a companion receives:
- blur: motion blur along the image-projected velocity of the vehicle over the exposure (`exposure_s`; the frame's
  speed comes from the evaluation cell's --speed-m-s, in a seeded random horizontal direction);
- noise: additive Gaussian sensor noise of `noise_std` 8-bit levels, drawn from a per-frame seeded generator;
- distortion: radial lens distortion (OpenCV/Brown k1, k2). Unlike blur and noise it moves pixels, so the ground
  truth moves with it: masks are sampled at the ideal-pinhole pixel each distorted pixel shows
  (`distortion_source_map`, the renderer's own inverse) and box outlines are distorted with the forward model
  (`distort_px`) before their bounding boxes are taken.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from viva_sitl.camera import CameraParams
from viva_sitl.camera.projection import camera_intrinsics
from viva_sitl.perception.errors import PerceptionError

F64 = NDArray[np.float64]
EFFECTS = ("blur", "noise", "distortion")


@dataclass(frozen=True)
class EffectSpec:
    """Which effects, and their strengths (defaults: a 1/50 s exposure, 3 levels of noise, mild barrel k1 = -0.1)."""

    blur: bool = False
    noise: bool = False
    distortion: bool = False
    exposure_s: float = 0.02
    noise_std: float = 3.0
    k1: float = -0.1
    k2: float = 0.0

    @classmethod
    def parse(
        cls, text: str, exposure_s: float = 0.02, noise_std: float = 3.0, k1: float = -0.1, k2: float = 0.0
    ) -> EffectSpec:
        names = [p.strip().lower() for p in text.split(",") if p.strip() and p.strip().lower() != "none"]
        bad = [n for n in names if n not in EFFECTS]
        if bad:
            raise PerceptionError(
                f"unknown effect {bad[0]!r} in --effects (known: {', '.join(EFFECTS)}, none)"
            )
        out = cls("blur" in names, "noise" in names, "distortion" in names, exposure_s, noise_std, k1, k2)
        out.check()
        return out

    def check(self) -> None:
        if not (math.isfinite(self.exposure_s) and 0.0 <= self.exposure_s <= 1.0):
            raise PerceptionError(f"--exposure-s must be in [0, 1] s, got {self.exposure_s}")
        if not (math.isfinite(self.noise_std) and 0.0 <= self.noise_std <= 128.0):
            raise PerceptionError(f"--noise-std must be in [0, 128] levels, got {self.noise_std}")
        if not (
            math.isfinite(self.k1) and math.isfinite(self.k2) and abs(self.k1) < 1.0 and abs(self.k2) < 1.0
        ):
            raise PerceptionError(f"lens distortion k1, k2 must be in (-1, 1), got {self.k1}, {self.k2}")

    @property
    def names(self) -> list[str]:
        return [n for n in EFFECTS if getattr(self, n)]

    def camera(self, params: CameraParams) -> CameraParams:
        """The VAC parameters that make the renderer apply these effects."""
        return replace(
            params,
            motion_blur=self.blur,
            exposure_s=self.exposure_s if self.blur else params.exposure_s,
            noise_std=self.noise_std if self.noise else 0.0,
            k1=self.k1 if self.distortion else 0.0,
            k2=self.k2 if self.distortion else 0.0,
        )

    def as_dict(self) -> dict[str, object]:
        return {
            "names": self.names,
            "exposure_s": self.exposure_s if self.blur else None,
            "noise_std": self.noise_std if self.noise else None,
            "k1": self.k1 if self.distortion else None,
            "k2": self.k2 if self.distortion else None,
        }


def distort_px(px: F64, params: CameraParams) -> F64:
    """Ideal-pinhole pixel centres (k, 2) -> where the distorted VAC shows them (OpenCV's radial model: x_d = x_u
    (1 + k1 r^2 + k2 r^4) in normalised coordinates). The inverse of `distortion_source_map`."""
    p = np.asarray(px, np.float64).reshape(-1, 2)
    if not params.has_distortion:
        return p.copy()
    k = camera_intrinsics(params)
    x = (p[:, 0] - k[0, 2]) / k[0, 0]
    y = (p[:, 1] - k[1, 2]) / k[1, 1]
    r2 = x * x + y * y
    f = 1.0 + params.k1 * r2 + params.k2 * r2 * r2
    return np.column_stack([x * f * k[0, 0] + k[0, 2], y * f * k[1, 1] + k[1, 2]])
