"""Perception on the virtual camera (optional extra `perception`): super-resolution, datasets, segmentation, detection.

Light parts import without torch (sr's OpenCV models, dataset export); torch parts (EDSR, U-Net) import it lazily and
raise `PerceptionError` naming the extra to install when it is absent.

    from viva_sitl.perception import SRConfig, SRMethod, load_upscaler, MagnifiedRender   # sr.py
    from viva_sitl.perception import Detector, train_detector                          # detect.py (perception-yolo)
    from viva_sitl.perception.dataset import ExportSpec, export_dataset                # dataset.py
    from viva_sitl.perception.segment import Segmenter, train_segmenter                # segment.py (torch)
    from viva_sitl.perception.landing_spot import Eyes, PlanConfig, choose_spot         # landing_spot.py (no torch)
"""

from viva_sitl.perception.detect import Detection, Detector, train_detector
from viva_sitl.perception.errors import INSTALL_HINT, INSTALL_HINT_YOLO, PerceptionError
from viva_sitl.perception.sr import (
    BicubicUpscaler,
    MagnifiedRender,
    OpenCVSR,
    SRConfig,
    SRMethod,
    Upscaler,
    load_upscaler,
    magnified_render_from_config,
)

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
