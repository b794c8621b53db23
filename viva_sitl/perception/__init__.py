"""Perception on the virtual camera (optional extra `perception`): super-resolution, datasets, segmentation, detection.

Light parts import without torch (sr's OpenCV models, dataset export); torch parts (EDSR, U-Net) import it lazily and
raise `PerceptionError` naming the extra to install when it is absent.

    from viva_sitl.perception import SRConfig, SRMethod, load_upscaler, MagnifiedRender
"""

from viva_sitl.perception.errors import INSTALL_HINT, PerceptionError
from viva_sitl.perception.sr import (
    BicubicUpscaler,
    MagnifiedRender,
    OpenCVSR,
    SRConfig,
    SRMethod,
    Upscaler,
    load_upscaler,
)

__all__ = [
    "INSTALL_HINT",
    "BicubicUpscaler",
    "MagnifiedRender",
    "OpenCVSR",
    "PerceptionError",
    "SRConfig",
    "SRMethod",
    "Upscaler",
    "load_upscaler",
]
