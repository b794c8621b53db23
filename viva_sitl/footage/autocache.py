"""The automatic tile cache: heavy footage is served from a tile cache without the user asking for one.

`open_footage` (and so `viva-sitl run`, the trials' workers, the gym environments and the headless `Simulator`)
calls `open_video` for every video footage. A video of at least ~4K (`CachePolicy.min_pixels`) gets a tile cache
(`viva_sitl.footage.tiles`, codec "yuv420z": ~9.5 MiB per 4K frame; with `--cache-compact` "yuv420zg", the same
pixels in ~6.5 MiB, its level-0 reads ~1.3x slower) in the user cache directory
(`$XDG_CACHE_HOME/viva-sitl/tiles-auto/<key>/`, else `~/.cache/viva-sitl/...`), built the first time with a
progress bar and then reused. Smaller videos (the README's examples, the embedded default footage: the synthetic
field) are opened as before.

- Key: SHA-256 of the file's size and 8 blocks of 1 MiB read at evenly spaced offsets (first and last included), the
  tile format version, codec and tile sizes (yuv420z/zg up to 4K: 128 px tiles at level 0, `level0_tile_px`). A changed
  file gets a new key (its old cache ages out of the LRU); the key does not depend on the file's path, so a renamed
  or copied file reuses its cache.
- Built once, concurrency-safe: a builder holds an exclusive `flock` on `<key>.lock` and writes `<key>.partial/`;
  only a complete build is renamed to `<key>/`. A second process (another campaign, a trial worker) blocks on the
  same lock, logs one line that it waits, then opens the finished cache: nothing reads a half-written cache.
  An interrupted build resumes from `<key>.partial/` (`tiles.build_tiles` is resumable).
- Checked on open: the tile cache's own structure checks (meta, index size, pack lengths) plus the checksums of the
  first and last frames' tiles. A corrupt or truncated cache is rebuilt with one warning line.
- Size-bounded: after a build, whole caches are evicted least recently used first (each open touches
  `<key>/last_used`) until the total is under `CachePolicy.max_bytes` (`--cache-max-gb`); a cache whose own
  estimated size exceeds the bound is not built (one warning line; the video is used).
- `CachePolicy(enabled=False)` (`viva-sitl run --no-cache`) opens the video itself. Configure a process with
  `set_policy`, or pass `cache=` to `open_footage`; `viva-sitl footage cache list|clear` shows and removes caches.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import logging
import shutil
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO

from viva_sitl.footage import tiles
from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.paths import default_cache_dir
from viva_sitl.footage.tiles import format as tile_format  # the codec's constants live (and are set) there

log = logging.getLogger("viva_sitl.footage.autocache")

AUTO_SUBDIR = "tiles-auto"
HEAVY_PIXELS = 3840 * 2160 * 9 // 10  # "~4K": a 4096x2160 or 3840x2160 video, not 2.7K
DEFAULT_MAX_BYTES = 32 << 30
SAMPLE_BLOCKS = 8
SAMPLE_BYTES = 1 << 20
LAST_USED = "last_used"
SOURCE_INFO = "source.json"
# level 0's tiles in a yuv420z cache of footage up to AUTO_LEVEL0_MAX_SIDE_PX (levels >= 1 keep tiles.DEFAULT_TILE_PX):
# a view below ~100 m reads level 0, where a 256 px tile decodes up to ~3x the pixels under a small footprint, and a
# yuv420z tile's fixed cost (a read, a checksum, a zstd frame) is small against a JPEG's. 4K bench clip
# (bench/results_tiles.md, session 17): a trial worker -9 % CPU, the full step at 50 m -10 % CPU on 2 decode threads,
# -13 % on one; 128 px at level 1 too would cost 300 m (which reads level 1) ~20 %. Larger footage (8K) keeps 256 px:
# there a 256 px tile covers the ground a 128 px tile of 4K does, and its cache stays within 32 MiB per frame (128 px
# tiles compress ~1.3 % worse: 32.2 MiB per 8K frame).
AUTO_LEVEL0_TILE_PX = 128
AUTO_LEVEL0_MAX_SIDE_PX = 4096


@dataclass(frozen=True)
class CachePolicy:
    """How `open_footage` treats heavy videos. `root` None: `<user cache dir>/tiles-auto`."""

    enabled: bool = True
    max_bytes: int | None = DEFAULT_MAX_BYTES
    root: Path | None = None
    min_pixels: int = HEAVY_PIXELS
    codec: str = tiles.AUTO_CODEC
    show_progress: bool = True

    def directory(self) -> Path:
        return Path(self.root) if self.root is not None else default_cache_dir() / AUTO_SUBDIR


_policy = CachePolicy()


def set_policy(policy: CachePolicy) -> None:
    """The process's default (the CLI sets it from `--no-cache` / `--cache-max-gb`)."""
    global _policy
    if policy.codec not in tiles.CODECS:
        raise FootageError(f"cache codec must be one of {', '.join(tiles.CODECS)}, got {policy.codec!r}")
    if policy.max_bytes is not None and policy.max_bytes <= 0:
        raise FootageError(f"the cache size bound must be > 0, got {policy.max_bytes} bytes")
    _policy = policy


def policy() -> CachePolicy:
    return _policy


def from_flags(
    no_cache: bool, max_gb: float, root: Path | None, base: CachePolicy | None = None, compact: bool = False
) -> CachePolicy:
    """`base` (default: this process's policy) changed by `--no-cache` / `--cache-max-gb` / `--tile-cache-dir` /
    `--cache-compact` (root None keeps base's folder, compact False its codec)."""
    base = _policy if base is None else base
    return replace(
        base, enabled=base.enabled and not no_cache, max_bytes=int(max_gb * 2**30), root=root or base.root,
        codec=tiles.COMPACT_CODEC if compact else base.codec,
    )  # fmt: skip


@contextlib.contextmanager
def using_policy(p: CachePolicy) -> Iterator[None]:
    """This process's policy is `p` inside the block, the previous one again after."""
    before = _policy
    set_policy(p)
    try:
        yield
    finally:
        set_policy(before)


def policy_cli_args(p: CachePolicy | None = None) -> list[str]:
    """`viva-sitl run` flags that give a child process policy `p` (default: this process's): what differs from a
    fresh process's defaults (`--no-cache`, `--cache-max-gb`, `--tile-cache-dir`, `--cache-compact`; `[]` for the
    defaults). A codec other than the two the flags name (set through the API) is not passed on."""
    p = _policy if p is None else p
    if not p.enabled:
        return ["--no-cache"]
    out = []
    if p.max_bytes != DEFAULT_MAX_BYTES and p.max_bytes is not None:
        out += ["--cache-max-gb", repr(p.max_bytes / 2**30)]
    if p.root is not None:
        out += ["--tile-cache-dir", str(p.root)]
    if p.codec == tiles.COMPACT_CODEC:
        out += ["--cache-compact"]
    return out


def _codec_layout(codec: str) -> str:
    """What else than the codec's name decides its bytes: the yuv420z levels stored as zstd and the zstd level
    (caches built when it was level 0 alone, or at zstd level 3, get a new key, so that a cache is rebuilt with the
    faster layout, not kept); yuv420zg's gradient tiles' zstd level."""
    if codec not in tiles.YUVZ_CODECS:
        return ""
    layout = ""
    if tile_format.YUVZ_MAX_LEVEL != 0:
        layout = f" zstd<={tile_format.YUVZ_MAX_LEVEL}@{tile_format.YUVZ_COARSE_MIN_PSNR_DB:g}dB"
    if tile_format.YUVZ_LEVEL != 3:
        layout += f" zstd-level {tile_format.YUVZ_LEVEL}"
    if codec == "yuv420zg":
        layout += f" gradient zstd-level {tile_format.YUVG_LEVEL} min-match {tile_format.YUVG_MIN_MATCH}"
    return layout


def _level0_key(codec: str, size_px: tuple[int, int]) -> str:
    """The level-0 tile size in the key where it differs (caches built with uniform tiles get a new key)."""
    l0 = level0_tile_px(codec, size_px)
    return "" if l0 == tiles.DEFAULT_TILE_PX else f" level0 {l0}"


def level0_tile_px(codec: str, size_px: tuple[int, int]) -> int:
    """The automatic cache's level-0 tile size for `codec` and footage of `size_px` (w, h)."""
    if codec in tiles.YUVZ_CODECS and max(size_px) <= AUTO_LEVEL0_MAX_SIDE_PX:
        return AUTO_LEVEL0_TILE_PX
    return tiles.DEFAULT_TILE_PX


def content_key(path: Path, policy: CachePolicy, size_px: tuple[int, int]) -> str:
    """The cache key of a video file of frame size `size_px` (w, h) (see the module docstring)."""
    size = path.stat().st_size
    h = hashlib.sha256(
        f"viva-sitl tiles v{tiles.FORMAT_VERSION} {policy.codec}{_codec_layout(policy.codec)} "
        f"{tiles.DEFAULT_TILE_PX}{_level0_key(policy.codec, size_px)} {size}".encode()
    )
    with open(path, "rb") as f:
        span = max(0, size - SAMPLE_BYTES)
        for k in range(SAMPLE_BLOCKS):
            f.seek(span * k // (SAMPLE_BLOCKS - 1))
            h.update(f.read(SAMPLE_BYTES))
    return h.hexdigest()


@contextlib.contextmanager
def _locked(lock_path: Path, what: str) -> Iterator[None]:
    """Hold the exclusive lock of one cache key (blocking, with one log line when another process holds it)."""
    lock_path.parent.mkdir(parents=True, exist_ok=True)
    f: IO[str] = open(lock_path, "a")  # noqa: SIM115 - released in finally
    try:
        try:
            fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            log.warning("tile cache of %s: another process is building it; waiting for it to finish", what)
            fcntl.flock(f.fileno(), fcntl.LOCK_EX)
        yield
    finally:
        f.close()  # releases the lock


def _is_locked(lock_path: Path) -> bool:
    """True while another process builds that key (a non-blocking try fails)."""
    try:
        f = open(lock_path, "a")  # noqa: SIM115
    except OSError:
        return False
    try:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        f.close()
    return False


def verify(folder: Path) -> tiles.TileCache:
    """Open a cache and check the checksums and sizes of its first and last frames' tiles; FootageError if not.
    (Read with the default settings: a check reads each tile once, the caller's LRU and threads do not matter.)"""
    cache = tiles.TileCache(folder, tiles.TileSettings())
    try:
        lay = cache.layout
        for frame in sorted({0, cache.frame_count - 1}):
            for level, (nx, ny) in enumerate(lay.grid):
                for ty in range(ny):
                    for tx in range(nx):
                        cache.tile(frame, level, tx, ty)
    except BaseException:
        cache.close()
        raise
    return cache


def _dir_bytes(folder: Path) -> int:
    return sum(p.stat().st_size for p in folder.rglob("*") if p.is_file())


@dataclass(frozen=True)
class CacheEntry:
    key: str
    folder: Path
    bytes: int
    last_used: float
    source: str
    frames: int
    codec: str  # yuv420z, yuv420zg (--cache-compact); "?" where source.json is unreadable


def list_caches(root: Path) -> list[CacheEntry]:
    """The complete caches under `root`, least recently used first."""
    out: list[CacheEntry] = []
    if not root.is_dir():
        return out
    for d in root.iterdir():
        if not d.is_dir() or "." in d.name:
            continue  # <key>.partial: a build in progress or interrupted
        try:
            info = json.loads((d / SOURCE_INFO).read_text(encoding="utf-8"))
        except (OSError, ValueError):
            info = {}
        out.append(
            CacheEntry(
                d.name, d, _dir_bytes(d), _last_used(d),
                str(info.get("source", "?")), int(info.get("frames", 0)), str(info.get("codec", "?")),
            )
        )  # fmt: skip
    return sorted(out, key=lambda e: e.last_used)


def remove(root: Path, entry: CacheEntry) -> bool:
    """Delete one cache unless a process is building it now (True when removed)."""
    lock = root / f"{entry.key}.lock"
    if _is_locked(lock):
        return False
    shutil.rmtree(entry.folder, ignore_errors=True)
    lock.unlink(missing_ok=True)
    return True


def evict(root: Path, max_bytes: int, keep: Path | None = None) -> list[CacheEntry]:
    """Remove whole caches, least recently used first, until the total is <= max_bytes (`keep` stays)."""
    entries = list_caches(root)
    total = sum(e.bytes for e in entries)
    gone = []
    for e in entries:
        if total <= max_bytes:
            break
        if keep is not None and e.folder == keep:
            continue
        if remove(root, e):
            total -= e.bytes
            gone.append(e)
            log.info(
                "tile cache %s (%s, %.1f GiB) evicted: least recently used",
                e.key[:12],
                e.source,
                e.bytes / 2**30,
            )
    return gone


def _last_used(folder: Path) -> float:
    """When the cache was last used (s since the epoch): the time _touch wrote, else the folder's mtime."""
    try:
        return int((folder / LAST_USED).read_text(encoding="ascii").strip()) / 1e9
    except (OSError, ValueError):
        try:
            return folder.stat().st_mtime
        except OSError:
            return 0.0


def _touch(folder: Path) -> None:
    # the time in the file, in ns: file mtimes are coarse (kernel ticks), two uses a few ms apart would tie
    with contextlib.suppress(OSError):
        (folder / LAST_USED).write_text(str(time.time_ns()), encoding="ascii")


def ensure_cache(path: Path, frames: object, frame_count: int, size_px: tuple[int, int], fps: float,
                 policy: CachePolicy, what: str) -> Path | None:  # fmt: skip
    """The folder of the complete, checked cache of video `path` (built now when missing or corrupt), or None when
    it is not cached (over the size bound: one warning line). `frames` is a callable returning the frames in
    order (called only when a build is needed)."""
    root = policy.directory()
    key = content_key(path, policy, size_px)
    folder = root / key
    if folder.is_dir():
        try:
            verify(folder).close()
            _touch(folder)
            return folder
        except FootageError:
            pass  # checked again under the lock (another process may be replacing it)
    with _locked(root / f"{key}.lock", what):
        rebuilding = False
        if folder.is_dir():
            try:
                verify(folder).close()
                _touch(folder)
                return folder
            except FootageError as exc:
                log.warning("tile cache of %s is corrupt (%s): rebuilding it", what, str(exc).split("; ")[0])
                shutil.rmtree(folder, ignore_errors=True)
                rebuilding = True
        partial = root / f"{key}.partial"
        w, h = size_px
        (log.info if rebuilding else log.warning)(
            "footage %s is %dx%d: building its tile cache once (%d frames, about %.1f GiB at ~1 byte per pixel) in "
            "%s; later runs reuse it (--no-cache: read the video instead)", what, w, h, frame_count,
            frame_count * w * h / 2**30, root,
        )  # fmt: skip
        t0 = time.monotonic()
        try:
            assert callable(frames)
            tiles.build_tiles(
                frames(), frame_count, w, h, fps, partial, codec=policy.codec,
                level0_tile_px=level0_tile_px(policy.codec, size_px), max_bytes=policy.max_bytes,
                source_id=key, show_progress=policy.show_progress, desc=f"tile cache {what}",
            )  # fmt: skip
        except KeyboardInterrupt:  # Ctrl-C: say what is kept (build_tiles committed whole batches of frames)
            done = tiles.read_progress(partial / tiles.TILES_SUBDIR).get("frames_done", 0)
            log.warning("tile cache of %s: build interrupted after %s of %d frames; the next run resumes it",
                        what, done, frame_count)  # fmt: skip
            raise
        except FootageError as exc:
            if "would take" not in str(exc) and "reached --max-size" not in str(exc):
                raise
            shutil.rmtree(partial, ignore_errors=True)
            est = str(exc).split(" > ")[0].removeprefix("the tile cache would take ")
            log.warning(
                "tile cache of %s not built: it would take %s, over the cache bound (--cache-max-gb %.1f); "
                "reading the video", what, est, (policy.max_bytes or 0) / 2**30,
            )  # fmt: skip
            return None
        (partial / SOURCE_INFO).write_text(
            json.dumps({"source": str(path), "frames": frame_count, "width_px": w, "height_px": h,
                        "codec": policy.codec, "build_s": round(time.monotonic() - t0, 1)}),
            encoding="utf-8",
        )  # fmt: skip
        _touch(partial)
        partial.rename(folder)
    log.info("tile cache of %s built in %.0f s: %s", what, time.monotonic() - t0, folder)
    if policy.max_bytes is not None:
        evict(root, policy.max_bytes, keep=folder)
    return folder
