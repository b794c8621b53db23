"""Errors of the perception extra: one line naming what is missing and how to fix it."""

from __future__ import annotations

from types import ModuleType

# torch pinned to the CPU wheel CI installs (0.9 GB): an unpinned torch may resolve to a CUDA build with GBs of
# nvidia wheels (README, Perception)
INSTALL_HINT = (
    "pip install torch==2.13.0 && pip install 'viva-sitl[perception]' "
    "(the CPU torch CI pins; an unpinned torch may pull GBs of CUDA wheels)"
)
INSTALL_HINT_YOLO = "pip install 'viva-sitl[perception-yolo]'"
INSTALL_HINT_ONNX = "pip install 'viva-sitl[perception-onnx]'"


class PerceptionError(ValueError):
    """Bad input to the perception code (missing weights, wrong model type, wrong frame size, missing extra)."""


def require_torch() -> ModuleType:
    """The torch module, or PerceptionError naming the extra to install."""
    try:
        import torch
    except ImportError:
        raise PerceptionError(f"this needs PyTorch, which is not installed: {INSTALL_HINT}") from None
    return torch
