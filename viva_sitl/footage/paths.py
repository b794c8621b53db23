"""Default directories: the footage configs, the shared footage folder and the download/ingest cache.

Every function takes the caller's explicit choice first; the defaults are only where nothing was given.
"""

from __future__ import annotations

import os
from importlib import resources
from pathlib import Path

_REPO_ROOT = Path(__file__).resolve().parents[2]
SHARED_DIR_ENV = "VIVA_SITL_SHARED_DIR"


def default_config_dir() -> Path:
    """The footage catalog shipped inside the package (viva_sitl/data/footage): the same in a source checkout and a
    wheel install."""
    return Path(str(resources.files("viva_sitl").joinpath("data", "footage")))


def default_shared_dir() -> Path:
    """$VIVA_SITL_SHARED_DIR, else the `shared` folder beside the repository (../shared), else ../shared of the
    working directory: where the sample footage lives."""
    env = os.environ.get(SHARED_DIR_ENV)
    if env:
        return Path(env).expanduser()
    beside = _REPO_ROOT.parent / "shared"
    return beside if beside.is_dir() else Path.cwd().parent / "shared"


def default_cache_dir() -> Path:
    """$XDG_CACHE_HOME/viva-sitl, else ~/.cache/viva-sitl (XDG base-directory convention; `--dest`/`cache_dir` override)."""
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg and Path(xdg).is_absolute() else Path.home() / ".cache"
    return base / "viva-sitl"
