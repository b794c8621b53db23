"""Default directories: the footage configs, the shared footage folder and the download/ingest cache.

Every function takes the caller's explicit choice first; the defaults are only where nothing was given.
"""

from __future__ import annotations

import os
from pathlib import Path

_REPO_ROOT = Path(__file__).resolve().parents[2]


def default_config_dir() -> Path:
    """configs/footage of the source checkout, else ./configs/footage (an installed package runs from a checkout)."""
    repo = _REPO_ROOT / "configs" / "footage"
    return repo if repo.is_dir() else Path.cwd() / "configs" / "footage"


def default_shared_dir() -> Path:
    """The `shared` folder beside the repository (../shared), where the sample footage lives."""
    beside = _REPO_ROOT.parent / "shared"
    return beside if beside.is_dir() else Path.cwd().parent / "shared"


def default_cache_dir() -> Path:
    """$XDG_CACHE_HOME/viva-sitl, else ~/.cache/viva-sitl (XDG base-directory convention; `--dest`/`cache_dir` override)."""
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "viva-sitl"
