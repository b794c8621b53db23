"""Perception on the virtual camera (optional extra `perception`): super-resolution, datasets, segmentation, detection.

Light parts import without torch (sr's OpenCV models, dataset export); torch parts (EDSR, U-Net) import it lazily and
raise `PerceptionError` naming the extra to install when it is absent.

    from viva_sitl.perception import SRConfig, SRMethod                                # config.py (the [perception.sr] table)
    from viva_sitl.perception import load_upscaler, MagnifiedRender                    # sr.py
    from viva_sitl.perception import Detector, train_detector                          # detect.py (perception-yolo)
    from viva_sitl.perception.dataset import ExportSpec, export_dataset                # dataset.py
    from viva_sitl.perception.segment import Segmenter, train_segmenter                # segment.py (torch)
    from viva_sitl.perception.landing_spot import Eyes, PlanConfig, choose_spot         # landing_spot.py (no torch)

This face imports the config and the errors at once; sr.py and detect.py load on first use of one of their names,
so that viva_sitl.config can build an SRConfig without the upscalers and the camera renderer.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from viva_sitl.perception.config import SRConfig, SRMethod
from viva_sitl.perception.errors import INSTALL_HINT, INSTALL_HINT_YOLO, PerceptionError

if TYPE_CHECKING:
    from viva_sitl.perception.detect import Detection, Detector, train_detector
    from viva_sitl.perception.sr import (
        BicubicUpscaler,
        MagnifiedRender,
        OpenCVSR,
        Upscaler,
        load_upscaler,
        magnified_render_from_config,
    )

_DETECT = {"Detection", "Detector", "train_detector"}
_SR = {
    "BicubicUpscaler",
    "MagnifiedRender",
    "OpenCVSR",
    "Upscaler",
    "load_upscaler",
    "magnified_render_from_config",
}


def __getattr__(name: str) -> Any:
    if name in _SR:
        from viva_sitl.perception import sr

        return getattr(sr, name)
    if name in _DETECT:
        from viva_sitl.perception import detect

        return getattr(detect, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "INSTALL_HINT",
    "INSTALL_HINT_YOLO",
    "Detection",
    "Detector",
    "train_detector",
    "BicubicUpscaler",
    "MagnifiedRender",
    "OpenCVSR",
    "PerceptionError",
    "SRConfig",
    "SRMethod",
    "Upscaler",
    "load_upscaler",
    "magnified_render_from_config",
]
