"""How a process reads tile caches: `TileSettings` (decoded-tile LRU cap, decode threads), passed to `TileCache` /
`TileSource` / `open_footage` as an argument.

The documented environment variables ($VIVA_SITL_TILE_CACHE_MB, $VIVA_SITL_TILE_DECODE_THREADS: a process and the
trial workers it starts; the trials' pool sets the decode threads per worker, 1 when the workers fill the cores,
where handing ~2 misses per frame to a pool costs more than it overlaps) are parsed by `TileSettings.from_environ`
from a mapping its caller passes; `environment_settings()` is the one place that hands it the process's
environment (called by `open_footage` when it is given no settings, and by the campaign's up-front check). A bad
value is one FootageError naming the variable, raised before any file is opened.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from viva_sitl.footage.errors import FootageError

DEFAULT_CACHE_BYTES = 256 << 20  # decoded-tile LRU cap
DEFAULT_DECODE_THREADS = 2
CACHE_ENV = "VIVA_SITL_TILE_CACHE_MB"
DECODE_THREADS_ENV = "VIVA_SITL_TILE_DECODE_THREADS"


def _parse(
    environ: Mapping[str, str],
    name: str,
    parse: Callable[[str], float],
    valid: Callable[[float], bool],
    what: str,
) -> float | None:
    """environ[name] parsed, None when unset or blank; a value that does not parse or is not `valid` is one error
    line."""
    raw = environ.get(name, "").strip()
    if not raw:
        return None
    try:
        value = parse(raw)
    except ValueError:
        value = math.nan
    if not valid(value):
        raise FootageError(f"${name}={raw!r}: give {what}")
    return value


@dataclass(frozen=True)
class TileSettings:
    """Settings of a tile cache reader: `cache_bytes` caps the LRU of decoded tiles, `decode_threads` decode one
    region's missing tiles (1: in the caller's thread)."""

    cache_bytes: int = DEFAULT_CACHE_BYTES
    decode_threads: int = DEFAULT_DECODE_THREADS

    @staticmethod
    def from_environ(environ: Mapping[str, str]) -> TileSettings:
        """The settings `environ` gives ($VIVA_SITL_TILE_CACHE_MB in MiB > 0, $VIVA_SITL_TILE_DECODE_THREADS >= 1;
        the defaults where unset or blank); FootageError (one line naming the variable) for a bad value."""
        mb = _parse(
            environ, CACHE_ENV, float, lambda v: math.isfinite(v) and v > 0,
            "the decoded-tile cache size in MiB (> 0)",
        )  # fmt: skip
        n = _parse(environ, DECODE_THREADS_ENV, int, lambda v: v >= 1, "a whole number of threads >= 1")
        return TileSettings(
            cache_bytes=DEFAULT_CACHE_BYTES if mb is None else max(1, int(mb * (1 << 20))),
            decode_threads=DEFAULT_DECODE_THREADS if n is None else int(n),
        )


def environment_settings() -> TileSettings:
    """The process's settings from its environment (see the module docstring): the ONE read of os.environ for
    tile caches."""
    return TileSettings.from_environ(os.environ)


def check_tile_environment() -> None:
    """Raise the one-line FootageError of a bad $VIVA_SITL_TILE_CACHE_MB / $VIVA_SITL_TILE_DECODE_THREADS now (for a
    parent whose children will open tile caches: it fails once, up front, rather than in every child)."""
    environment_settings()
