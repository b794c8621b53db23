"""How a process reads tile caches: `TileSettings` (decoded-tile LRU cap, decode threads, read-ahead), passed to `TileCache` /
`TileSource` / `open_footage` as an argument.

Nothing in the footage layer reads the environment. The documented environment variables
($VIVA_SITL_TILE_CACHE_MB, $VIVA_SITL_TILE_DECODE_THREADS, $VIVA_SITL_TILE_READ_AHEAD: a process and the trial
workers it starts; the trials' pool sets the decode threads per worker, 1 when the workers fill the cores, where
handing ~2 misses per frame to a pool costs more than it overlaps, unless the user chose them) are read on the top floor: the `viva-sitl` commands,
the gym environments and the benches call `TileSettings.from_environ(os.environ)` once and make the result the
process's settings (`set_process_settings`, what `open_footage` uses when it is given none, as
`autocache.set_policy`) or pass it as an argument; the campaign hands it to its workers as an argument, and an
external trial's `viva-sitl run` gets it back as those variables (`to_environ`). A bad value is one FootageError
naming the variable, raised by `from_environ` before any file is opened. A Python caller that wants the variables
honoured does the same: `set_process_settings(TileSettings.from_environ(os.environ))`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace

from viva_sitl.footage.errors import FootageError

DEFAULT_CACHE_BYTES = 256 << 20  # decoded-tile LRU cap
DEFAULT_DECODE_THREADS = 2
CACHE_ENV = "VIVA_SITL_TILE_CACHE_MB"
DECODE_THREADS_ENV = "VIVA_SITL_TILE_DECODE_THREADS"
READ_AHEAD_ENV = "VIVA_SITL_TILE_READ_AHEAD"


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
    region's missing tiles (the caller's thread and decode_threads - 1 workers; 1: the caller's alone; None: not
    chosen, DEFAULT_DECODE_THREADS, or the cores a trial worker is left: `or_threads`), `read_ahead`: with a
    decode worker (decode_threads >= 2), regions read frame after frame have the next frame's tiles decoded on the
    worker while the caller does the rest of its step (TileCache; the same pixels either way)."""

    cache_bytes: int = DEFAULT_CACHE_BYTES
    decode_threads: int | None = None
    read_ahead: bool = True

    @property
    def threads(self) -> int:
        """The decode threads a reader uses."""
        return DEFAULT_DECODE_THREADS if self.decode_threads is None else self.decode_threads

    def or_threads(self, threads: int) -> TileSettings:
        """These settings with `threads` decode threads where none were chosen (the chosen ones win)."""
        return self if self.decode_threads is not None else replace(self, decode_threads=max(1, int(threads)))

    def to_environ(self) -> dict[str, str]:
        """The documented variables that give a child process these settings (`from_environ` reads them back
        exactly; decode threads not chosen: not set)."""
        env = {CACHE_ENV: repr(self.cache_bytes / (1 << 20))}
        if self.decode_threads is not None:
            env[DECODE_THREADS_ENV] = str(self.decode_threads)
        if not self.read_ahead:
            env[READ_AHEAD_ENV] = "0"
        return env

    @staticmethod
    def from_environ(environ: Mapping[str, str]) -> TileSettings:
        """The settings `environ` gives ($VIVA_SITL_TILE_CACHE_MB in MiB > 0, $VIVA_SITL_TILE_DECODE_THREADS >= 1,
        $VIVA_SITL_TILE_READ_AHEAD 0 or 1; the defaults where unset or blank); FootageError (one line naming the
        variable) for a bad value."""
        mb = _parse(
            environ, CACHE_ENV, float, lambda v: math.isfinite(v) and v > 0,
            "the decoded-tile cache size in MiB (> 0)",
        )  # fmt: skip
        n = _parse(environ, DECODE_THREADS_ENV, int, lambda v: v >= 1, "a whole number of threads >= 1")
        ahead = _parse(environ, READ_AHEAD_ENV, int, lambda v: v in (0, 1), "0 (off) or 1 (on)")
        return TileSettings(
            cache_bytes=DEFAULT_CACHE_BYTES if mb is None else max(1, int(mb * (1 << 20))),
            decode_threads=None if n is None else int(n),
            read_ahead=ahead != 0,
        )


_process = TileSettings()


def set_process_settings(settings: TileSettings) -> None:
    """The process's settings: what `open_footage` uses when it is given none (set by the top floor: the
    `viva-sitl` commands from the environment, a campaign's worker from its argument)."""
    global _process
    if not isinstance(settings, TileSettings):
        raise TypeError(f"tile settings must be a TileSettings, got {type(settings).__name__}")
    _process = settings


def process_settings() -> TileSettings:
    return _process
