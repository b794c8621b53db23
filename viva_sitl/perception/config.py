"""The `[perception.sr]` table: which super-resolution method magnifies the footage the VAC sees up close.

A leaf (no OpenCV, no torch) so that viva_sitl.config can build it without importing the perception code; the
models themselves load in perception/sr.py (`load_upscaler`, `magnified_render_from_config`).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from viva_sitl.perception.errors import PerceptionError


class SRMethod(enum.Enum):
    NONE = "none"
    BICUBIC = "bicubic"
    FSRCNN = "fsrcnn"
    ESPCN = "espcn"
    EDSR = "edsr"


@dataclass(frozen=True)
class SRConfig:
    """What upscales the magnified footage. `min_magnification`: VAC px per footage px above which SR runs."""

    method: SRMethod = SRMethod.NONE
    model_path: str = ""  # .pb for fsrcnn/espcn, an EDSR checkpoint (.pt) for edsr
    scale: int = 2  # for bicubic only (the models carry their own)
    min_magnification: float = 1.0

    def __post_init__(self) -> None:
        if not isinstance(self.method, SRMethod):
            try:
                object.__setattr__(self, "method", SRMethod(str(self.method).lower()))
            except ValueError:
                names = ", ".join(m.value for m in SRMethod)
                raise PerceptionError(
                    f"unknown super-resolution method {self.method!r} (known: {names})"
                ) from None
        if not (math.isfinite(self.min_magnification) and self.min_magnification > 0.0):
            raise PerceptionError(
                f"min_magnification must be a positive number, got {self.min_magnification!r}"
            )
        if self.scale not in (2, 3, 4):
            raise PerceptionError(f"scale must be 2, 3 or 4, got {self.scale!r}")
