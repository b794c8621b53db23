"""Tiled multi-resolution footage cache: decode cost scales with the VAC's output, not the footage's resolution.

Every footage frame is stored as its full mip-map pyramid (level 0 = the decoded frame, each level the 2x2 box
halving of the previous one, exactly as `viva_sitl.camera.LazyPyramid` builds it), each level cut into
`tile_px` x `tile_px` tiles, each tile intra-coded on its own (as map tile servers and cloud-optimised GeoTIFFs do).
A render decodes only the tiles under the VAC's footprint at the level(s) it samples; decoded tiles are kept in an
LRU with a byte cap (256 MiB; `$VIVA_SITL_TILE_CACHE_MB` sets it for a process and the trial workers it starts).
Across frames the LRU only pays off when frames repeat (a still, or a short clip that loops inside a trial); over a
clip longer than the cap every frame's tiles are decoded afresh.

Layout of a cache folder (built by `viva-sitl footage ingest --tiles`, see `build_tile_cache`):

    footage.toml        metadata with the geometry written out (as the video ingest); written last, so a folder
                        without it is an unfinished build (rerun the same command: it resumes)
    tiles/meta.json     size, frame count, fps, tile size, codec, quality, the level sizes
    tiles/index.bin     one 24-byte record per (frame, level, tile): pack number, length, offset, checksum
    tiles/pack-NNN.bin  the encoded tiles, appended in order (a new pack every PACK_BYTES)
    tiles/progress.json frames done and the pack sizes at that point (rewritten atomically after each batch)

Codecs: "jpeg" (cv2.imencode, quality 95 by default: ~46 dB PSNR per tile on the interchange clip, ~19 KiB per
256 px tile), "png" (lossless: renders bit-identical to those from the decoded video, ~4x bigger, ~3x slower to
decode), "raw" (uncompressed BGR: bit-identical and the cheapest decode, a memory copy; ~10x bigger than jpeg) and
"yuv420z" (the automatic cache's: level 0 as zstd-compressed planar YUV 4:2:0, ~47 dB and ~4x faster to decode
than jpeg, coarser levels as jpeg 4:4:4; ~0.7-1.0 byte per footage pixel, see `_encode`).
Every tile read checks its length and checksum and the decoded shape; any mismatch, a missing pack or level, or a bad
index raises a one-line `FootageError` naming the cache and the command that rebuilds it: never a wrong image.

The checksum (format 2) is `tile_checksum`: the tile's bytes summed as little-endian 64-bit words, modulo 2^64,
plus its length. It catches truncation, any changed byte or run of bytes, zeroed or overwritten ranges; what it
cannot see is 8-byte words swapped with each other inside one tile, which no storage fault produces. Why not CRC-32
(format 1, still read): a raw 256 px tile is 192 KiB, and zlib.crc32 over it took 47 us against 3.8 us for the sum,
~0.27 ms of a ~1.5 ms step at 50 m (5.8 tiles per step; bench/results_tiles.md, session 8).
"""

from __future__ import annotations

import contextlib
import json
import math
import os
import sys
import threading
import zlib
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.footage.metadata import FootageMetadata
from viva_sitl.footage.source import FootageSource
from viva_sitl.imaging import half_size, max_pyramid_level

U8 = NDArray[np.uint8]

TILES_SUBDIR = "tiles"
FORMAT_VERSION = 2
DEFAULT_TILE_PX = 256
DEFAULT_CODEC = "jpeg"
CODECS = ("jpeg", "png", "raw", "yuv420z")
AUTO_CODEC = "yuv420z"  # the automatic cache's codec (viva_sitl.footage.autocache)
DEFAULT_JPEG_QUALITY = 95
# qualities tried, best first, when the size bound would be exceeded at the asked one
JPEG_FALLBACK_QUALITIES = (95, 92, 90, 85, 80, 75, 70, 60, 50)
DEFAULT_CACHE_BYTES = 256 << 20  # decoded-tile LRU cap
PACK_BYTES = 1 << 30  # start a new pack file beyond this size
COMMIT_FRAMES = 4  # progress.json is rewritten (and packs flushed) every this many frames
INDEX_DTYPE = np.dtype([("pack", "<u4"), ("length", "<u4"), ("offset", "<u8"), ("check", "<u8")])
INDEX_DTYPE_V1 = np.dtype(
    [("pack", "<u4"), ("length", "<u4"), ("offset", "<u8"), ("check", "<u4"), ("pad", "<u4")]
)
_MASK64 = (1 << 64) - 1
_RAW_MAGIC = b"RAWT"
_YUVZ_MAGIC = b"Y4Z1"
YUVZ_LEVEL = 3  # zstd level of the yuv420z codec's zstd tiles (decode speed does not depend on it)
# the yuv420z codec's levels stored as zstd YUV 4:2:0 (the rest as jpeg 4:4:4): levels 0 and 1, the levels a view
# reads up to ~4 footage px per VAC px (~300 m over the 4K bench clip), decoded ~3.3x faster than jpeg. A level >= 1
# tile has the chroma resolution 4:2:0 halves again: it is stored so only where its round trip keeps
# YUVZ_COARSE_MIN_PSNR_DB (jpeg q95's own level-1 figure; 93-100 % of the 4K bench clip's level-1 tiles, ~0.8 MiB
# more per 4K frame), as jpeg 4:4:4 elsewhere (sharp chroma edges: 31 dB as 4:2:0 in the tests' synthetic clip)
YUVZ_MAX_LEVEL = 1
YUVZ_COARSE_MIN_PSNR_DB = 44.0
# full-resolution chroma: 4:2:0 costs 4-7 dB on sharp coarse levels (bench/results_tiles.md) for ~30 % less size
_JPEG_444 = (cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444)

# Environment overrides for every tile source of a process and its children (the trials' pool sets the decode
# threads per worker: 1 when the workers fill the cores, where handing ~2 misses per frame to a pool costs more than
# it overlaps). A bad value is one FootageError, raised before any file is opened.
CACHE_ENV = "VIVA_SITL_TILE_CACHE_MB"
DECODE_THREADS_ENV = "VIVA_SITL_TILE_DECODE_THREADS"
DEFAULT_DECODE_THREADS = 2


def _from_env(
    name: str, parse: Callable[[str], float], valid: Callable[[float], bool], what: str
) -> float | None:
    """$name parsed, None when unset or blank; a value that does not parse or is not `valid` is one error line."""
    raw = os.environ.get(name, "").strip()
    if not raw:
        return None
    try:
        value = parse(raw)
    except ValueError:
        value = math.nan
    if not valid(value):
        raise FootageError(f"${name}={raw!r}: give {what}")
    return value


def default_cache_bytes() -> int:
    """The decoded-tile LRU cap: $VIVA_SITL_TILE_CACHE_MB (MiB, > 0) or DEFAULT_CACHE_BYTES."""
    mb = _from_env(
        CACHE_ENV, float, lambda v: math.isfinite(v) and v > 0, "the decoded-tile cache size in MiB (> 0)"
    )
    return DEFAULT_CACHE_BYTES if mb is None else max(1, int(mb * (1 << 20)))


def default_decode_threads() -> int:
    """Threads that decode one region's missing tiles: $VIVA_SITL_TILE_DECODE_THREADS (>= 1) or 2."""
    n = _from_env(DECODE_THREADS_ENV, int, lambda v: v >= 1, "a whole number of threads >= 1")
    return DEFAULT_DECODE_THREADS if n is None else int(n)


def check_tile_environment() -> None:
    """Raise the one-line FootageError of a bad $VIVA_SITL_TILE_CACHE_MB / $VIVA_SITL_TILE_DECODE_THREADS now (for a
    parent whose children will open tile caches: it fails once, up front, rather than in every child)."""
    default_cache_bytes()
    default_decode_threads()


@dataclass(frozen=True)
class TileLayout:
    """Level sizes and tile grid of one footage size."""

    width_px: int
    height_px: int
    tile_px: int
    levels: tuple[tuple[int, int], ...]  # (w, h) per level
    grid: tuple[tuple[int, int], ...]  # (tiles across, tiles down) per level
    first: tuple[int, ...]  # index of each level's first tile within a frame

    @staticmethod
    def of(width_px: int, height_px: int, tile_px: int) -> TileLayout:
        if width_px <= 0 or height_px <= 0 or tile_px < 16:
            raise FootageError(f"bad tile layout {width_px}x{height_px}, tile {tile_px} px")
        sizes = [(width_px, height_px)]
        for _ in range(max_pyramid_level(width_px, height_px)):
            w, h = sizes[-1]
            sizes.append(((w + 1) // 2, (h + 1) // 2))
        grid = [(-(-w // tile_px), -(-h // tile_px)) for w, h in sizes]
        first, n = [], 0
        for nx, ny in grid:
            first.append(n)
            n += nx * ny
        return TileLayout(width_px, height_px, tile_px, tuple(sizes), tuple(grid), tuple(first))

    @property
    def tiles_per_frame(self) -> int:
        nx, ny = self.grid[-1]
        return self.first[-1] + nx * ny

    def tile_index(self, level: int, tx: int, ty: int) -> int:
        return self.first[level] + ty * self.grid[level][0] + tx


def tile_checksum(data: bytes | memoryview) -> int:
    """The format-2 tile checksum: the bytes as little-endian uint64 words summed modulo 2^64 (the last < 8 bytes
    as one more word), plus the length. ~12x cheaper than CRC-32 on a raw tile (see the module docstring)."""
    n = len(data)
    whole = n - n % 8
    total = int(np.frombuffer(data, "<u8", count=whole // 8).sum(dtype=np.uint64)) if whole else 0
    return (total + int.from_bytes(bytes(data[whole:]), "little") + n) & _MASK64


# format -> its index record and the checksum the record holds (format 1: CRC-32 in 4 bytes; caches written by
# earlier versions stay readable)
FORMATS: dict[int, tuple[np.dtype[Any], Callable[[bytes], int]]] = {
    1: (INDEX_DTYPE_V1, zlib.crc32),
    2: (INDEX_DTYPE, tile_checksum),
}


def _encode_yuvz(tile: U8, min_psnr_db: float | None = None) -> bytes | None:
    """A BGR tile as planar YUV 4:2:0 (I420, OpenCV's BT.601 conversion) compressed with zstd; an odd width or
    height is padded by repeating the last column/row (the header keeps the true size). With `min_psnr_db`: None
    when the round trip through 4:2:0 is below it."""
    import zstandard

    h, w = tile.shape[:2]
    even = tile
    if w % 2 or h % 2:
        even = np.asarray(cv2.copyMakeBorder(tile, 0, h % 2, 0, w % 2, cv2.BORDER_REPLICATE), np.uint8)
    yuv = cv2.cvtColor(even, cv2.COLOR_BGR2YUV_I420)
    if min_psnr_db is not None:
        back = cv2.cvtColor(yuv, cv2.COLOR_YUV2BGR_I420)
        if cv2.PSNR(np.ascontiguousarray(back[:h, :w]), tile) < min_psnr_db:
            return None
    body = zstandard.ZstdCompressor(level=YUVZ_LEVEL).compress(yuv.tobytes())
    return _YUVZ_MAGIC + int(w).to_bytes(2, "little") + int(h).to_bytes(2, "little") + body


_zstd_local = threading.local()


def _decode_yuvz(data: bytes | memoryview) -> U8 | None:
    import zstandard

    if len(data) < 8 or bytes(data[:4]) != _YUVZ_MAGIC:
        return None
    w = int.from_bytes(data[4:6], "little")
    h = int.from_bytes(data[6:8], "little")
    ew, eh = w + w % 2, h + h % 2
    dec = getattr(_zstd_local, "dec", None)
    if dec is None:  # a decompression context is not thread-safe: one per decode thread
        dec = _zstd_local.dec = zstandard.ZstdDecompressor()
    try:
        raw = dec.decompress(data[8:], max_output_size=ew * eh * 3 // 2)
    except zstandard.ZstdError:
        return None
    if len(raw) != ew * eh * 3 // 2:
        return None
    bgr = cv2.cvtColor(np.frombuffer(raw, np.uint8).reshape(eh * 3 // 2, ew), cv2.COLOR_YUV2BGR_I420)
    return np.asarray(bgr if (ew, eh) == (w, h) else bgr[:h, :w], dtype=np.uint8)


def _encode(tile: U8, codec: str, quality: int, level: int = 0) -> bytes:
    """One tile's bytes. "yuv420z" is two codecs by level: level 0 as zstd-compressed YUV 4:2:0 (the video's own
    chroma resolution: ~47 dB, decoded ~4x faster than a JPEG), coarser levels as JPEG 4:4:4 (4:2:0 there costs
    5-10 dB on sharp images: a box-halved level has full-resolution chroma again; bench/results_tiles.md, session
    10) except level-1 tiles whose 4:2:0 round trip keeps YUVZ_COARSE_MIN_PSNR_DB (YUVZ_MAX_LEVEL; the reader
    tells the two by the tile's magic)."""
    if codec == "raw":
        h, w = tile.shape[:2]
        return _RAW_MAGIC + int(w).to_bytes(2, "little") + int(h).to_bytes(2, "little") + tile.tobytes()
    if codec == "yuv420z":
        data = (
            _encode_yuvz(tile, None if level == 0 else YUVZ_COARSE_MIN_PSNR_DB)
            if level <= YUVZ_MAX_LEVEL
            else None
        )
        if data is not None:
            return data
        codec = "jpeg"
    if codec == "jpeg":
        ok, buf = cv2.imencode(".jpg", tile, [cv2.IMWRITE_JPEG_QUALITY, quality, *_JPEG_444])
    else:
        ok, buf = cv2.imencode(".png", tile, [cv2.IMWRITE_PNG_COMPRESSION, 1])
    if not ok:
        raise FootageError(f"cannot encode a tile as {codec}")
    return bytes(buf)


def _decode(data: bytes | memoryview, codec: str) -> U8 | None:
    if codec == "raw":
        if len(data) < 8 or bytes(data[:4]) != _RAW_MAGIC:
            return None
        w = int.from_bytes(data[4:6], "little")
        h = int.from_bytes(data[6:8], "little")
        if len(data) != 8 + w * h * 3:
            return None
        return np.frombuffer(data, np.uint8, offset=8).reshape(h, w, 3)
    if codec == "yuv420z" and bytes(data[:4]) == _YUVZ_MAGIC:
        return _decode_yuvz(data)
    img = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)
    return None if img is None else np.asarray(img, dtype=np.uint8)


def frame_pyramid(frame_bgr: U8) -> list[U8]:
    """Every level of the frame, as LazyPyramid builds them (level 0 is the frame)."""
    levels = [frame_bgr]
    for _ in range(max_pyramid_level(frame_bgr.shape[1], frame_bgr.shape[0])):
        levels.append(half_size(levels[-1]))
    return levels


def encode_frame(
    frame_bgr: U8, layout: TileLayout, codec: str, quality: int, pool: ThreadPoolExecutor | None = None
) -> list[bytes]:
    """The encoded tiles of one frame, in index order (level by level, row by row)."""
    jobs: list[tuple[U8, int]] = []
    t = layout.tile_px
    for level, img in enumerate(frame_pyramid(frame_bgr)):
        nx, ny = layout.grid[level]
        for ty in range(ny):
            for tx in range(nx):
                jobs.append((np.ascontiguousarray(img[ty * t : (ty + 1) * t, tx * t : (tx + 1) * t]), level))
    if pool is None:
        return [_encode(j, codec, quality, lv) for j, lv in jobs]
    return list(pool.map(lambda j: _encode(j[0], codec, quality, j[1]), jobs))


# ------------------------------------------------------------------------------------------------ reading


class TileCache:
    """Read access to one tile cache folder (`<folder>/tiles`), with an LRU of decoded tiles."""

    def __init__(
        self, folder: Path, cache_bytes: int | None = None, decode_threads: int | None = None
    ) -> None:
        # environment defaults first: a bad value fails before any file is opened
        cap = default_cache_bytes() if cache_bytes is None else int(cache_bytes)
        threads = default_decode_threads() if decode_threads is None else int(decode_threads)
        self.folder = Path(folder)
        self.dir = self.folder / TILES_SUBDIR
        self._rebuild = f"rebuild it with `viva-sitl footage ingest --tiles` (or delete {self.folder})"
        meta = self._read_meta()
        index_dtype, self._checksum = FORMATS[int(meta["version"])]
        try:
            self.layout = TileLayout.of(int(meta["width_px"]), int(meta["height_px"]), int(meta["tile_px"]))
            self.frame_count = int(meta["frames"])
            self.fps = float(meta["fps"])
            self.codec = str(meta["codec"])
            self.quality = int(meta["quality"])
            levels = [tuple(int(v) for v in s) for s in meta["levels"]]
        except (KeyError, TypeError, ValueError) as exc:
            raise self._error(f"bad tiles/meta.json ({exc})") from None
        if self.codec not in CODECS or self.frame_count <= 0 or not self.fps > 0:
            raise self._error("bad tiles/meta.json (codec, frames or fps)")
        if tuple(levels) != self.layout.levels:
            raise self._error(
                f"tiles/meta.json lists {len(levels)} levels, the frame size needs {len(self.layout.levels)}"
            )
        progress = read_progress(self.dir)
        if progress.get("frames_done") != self.frame_count:
            raise self._error(
                f"unfinished build ({progress.get('frames_done', 0)}/{self.frame_count} frames): rerun the ingest"
            )
        n = self.frame_count * self.layout.tiles_per_frame
        index_path = self.dir / "index.bin"
        if not index_path.is_file() or index_path.stat().st_size != n * index_dtype.itemsize:
            raise self._error("tiles/index.bin is missing or has the wrong size")
        self.index = np.fromfile(index_path, index_dtype)
        if np.any(self.index["length"] == 0):
            first = int(np.argmax(self.index["length"] == 0))
            frame, rest = divmod(first, self.layout.tiles_per_frame)
            level = int(np.searchsorted(self.layout.first, rest, side="right")) - 1
            raise self._error(f"frame {frame} level {level} has missing tiles in tiles/index.bin")
        self._packs: list[Any] = []
        ends = self.index["offset"] + self.index["length"]
        for k in range(int(self.index["pack"].max()) + 1):
            path = self.dir / f"pack-{k:03d}.bin"
            if not path.is_file():
                raise self._error(f"{path.name} is missing")
            need = int(ends[self.index["pack"] == k].max(initial=0))
            if path.stat().st_size < need:
                raise self._error(f"{path.name} is truncated ({path.stat().st_size} of {need} bytes)")
            self._packs.append(open(path, "rb"))  # noqa: SIM115 - kept open for the cache's life
        self.cache_bytes = cap
        self._lru: OrderedDict[tuple[int, int], U8] = OrderedDict()
        self._lru_bytes = 0
        self._lock = threading.Lock()
        self.tiles_decoded = 0  # statistics
        self.tile_hits = 0
        # cv2.imdecode releases the GIL: misses of one region are decoded in parallel
        self._pool = (
            ThreadPoolExecutor(threads, thread_name_prefix="viva-sitl-tile-decode")
            if threads > 1 and self.codec != "raw"
            else None
        )

    def _error(self, what: str) -> FootageError:
        return FootageError(f"tile cache {self.folder}: {what}; {self._rebuild}")

    def _read_meta(self) -> dict[str, Any]:
        path = self.dir / "meta.json"
        try:
            meta = json.loads(path.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise self._error("tiles/meta.json is missing") from None
        except (OSError, ValueError) as exc:
            raise self._error(f"tiles/meta.json is unreadable ({exc})") from None
        version = meta.get("version") if isinstance(meta, dict) else None
        if type(version) is not int or version not in FORMATS:
            raise self._error("tiles/meta.json has an unknown format")
        return meta

    @property
    def disk_bytes(self) -> int:
        return sum(p.stat().st_size for p in self.dir.glob("*") if p.is_file())

    @property
    def lru_bytes(self) -> int:
        return self._lru_bytes

    def _read(self, frame: int, level: int, tx: int, ty: int) -> U8 | bytes:
        """The cached decoded tile, or its checked encoded bytes."""
        t = self.layout.tile_index(level, tx, ty)
        with self._lock:
            hit = self._lru.get((frame, t))
            if hit is not None:
                self._lru.move_to_end((frame, t))
                self.tile_hits += 1
                return hit
            if not self._packs:
                raise FootageError(f"tile cache {self.folder} is closed")
            rec = self.index[frame * self.layout.tiles_per_frame + t]
            length = int(rec["length"])
            f = self._packs[int(rec["pack"])]
            f.seek(int(rec["offset"]))
            data = f.read(length)
        where = f"frame {frame} level {level} tile ({tx}, {ty})"
        if len(data) != length:
            raise self._error(f"{where}: pack truncated")
        if self._checksum(data) != int(rec["check"]):
            raise self._error(f"{where}: checksum mismatch")
        return data

    def _decoded(self, frame: int, level: int, tx: int, ty: int, data: bytes) -> U8:
        """Decode checked bytes, check the size, keep the tile in the LRU."""
        img = _decode(data, self.codec)
        lw, lh = self.layout.levels[level]
        ts = self.layout.tile_px
        want = (min(ts, lh - ty * ts), min(ts, lw - tx * ts), 3)
        if img is None or img.shape != want:
            raise self._error(f"frame {frame} level {level} tile ({tx}, {ty}): does not decode to a "
                              f"{want[1]}x{want[0]} image")  # fmt: skip
        img.setflags(write=False)
        key = (frame, self.layout.tile_index(level, tx, ty))
        with self._lock:
            self.tiles_decoded += 1
            if key not in self._lru:
                self._lru[key] = img
                self._lru_bytes += img.nbytes
            while self._lru_bytes > self.cache_bytes and len(self._lru) > 1:
                _, old = self._lru.popitem(last=False)
                self._lru_bytes -= old.nbytes
        return img

    def tile(self, frame: int, level: int, tx: int, ty: int) -> U8:
        """The decoded tile (read-only), checked against its length, checksum and expected size."""
        got = self._read(frame, level, tx, ty)
        return got if isinstance(got, np.ndarray) else self._decoded(frame, level, tx, ty, got)

    def tiles_under(
        self,
        level: int,
        x0: int,
        y0: int,
        x1: int,
        y1: int,
        quad: NDArray[np.float64] | None = None,
        margin_px: float = 0.0,
    ) -> list[tuple[int, int]]:
        """(tx, ty) of the tiles of level `level` meeting [x0, x1) x [y0, y1); with `quad` (a convex polygon in
        level pixel coordinates, e.g. the VAC footprint) only those within `margin_px` of it (separating axes)."""
        ts = self.layout.tile_px
        txs = range(x0 // ts, (x1 - 1) // ts + 1)
        grid = [(x, y) for y in range(y0 // ts, (y1 - 1) // ts + 1) for x in txs]  # row-major
        if quad is None or len(quad) < 3:
            return grid
        # the footprint's edges as outward normals n and extents h: a tile is kept unless, along some n, its
        # rectangle lies beyond h (separating axis)
        q = np.asarray(quad, np.float64)
        centre = q.mean(axis=0)
        axes: list[tuple[float, float, float]] = []
        for i in range(len(q)):
            e = q[(i + 1) % len(q)] - q[i]
            n = np.array([e[1], -e[0]])
            if np.dot(n, centre - q[i]) > 0:
                n = -n  # outward
            axes.append((float(n[0]), float(n[1]), float(np.max(q @ n)) + 1e-9))
        keep = []
        for tx, ty in grid:
            # tile pixel centres span [t * ts, (t + 1) * ts - 1]; grown by the margin (per tile in plain floats:
            # a few tiles, where numpy's per-call cost dominated)
            rx0, ry0 = tx * ts - margin_px, ty * ts - margin_px
            rx1, ry1 = (tx + 1) * ts - 1 + margin_px, (ty + 1) * ts - 1 + margin_px
            if all((rx0 if nx > 0 else rx1) * nx + (ry0 if ny > 0 else ry1) * ny <= h for nx, ny, h in axes):
                keep.append((tx, ty))
        return keep

    def region(
        self,
        frame: int,
        level: int,
        x0: int,
        y0: int,
        x1: int,
        y1: int,
        out: U8 | None = None,
        quad: NDArray[np.float64] | None = None,
        margin_px: float = 0.0,
    ) -> U8:
        """Level `level` pixels [y0:y1, x0:x1] of frame `frame`, assembled from the tiles under them (with `quad`:
        only the tiles within `margin_px` of that polygon; the rest of `out` is left as it was). Tiles missing
        from the LRU are decoded on `decode_threads` threads. A 4-channel `out` receives BGRA (alpha 255): each
        tile is converted as it is pasted, one pass instead of a copy and a conversion."""
        lw, lh = self.layout.levels[level]
        if not (0 <= x0 < x1 <= lw and 0 <= y0 < y1 <= lh):
            raise ValueError(f"region ({x0}, {y0})-({x1}, {y1}) outside level {level} ({lw}x{lh})")
        if out is None:
            out = np.empty((y1 - y0, x1 - x0, 3), np.uint8)
        if out.shape[:2] != (y1 - y0, x1 - x0) or out.ndim != 3 or out.shape[2] not in (3, 4):
            raise ValueError(f"out must be a {x1 - x0}x{y1 - y0} BGR or BGRA array, got shape {out.shape}")
        bgra = out.shape[2] == 4
        ts = self.layout.tile_px
        todo = self.tiles_under(level, x0, y0, x1, y1, quad, margin_px)
        got = [self._read(frame, level, tx, ty) for tx, ty in todo]
        misses = [i for i, g in enumerate(got) if not isinstance(g, np.ndarray)]
        if len(misses) > 1 and self._pool is not None:
            decoded = list(
                self._pool.map(lambda i: self._decoded(frame, level, *todo[i], got[i]), misses)  # type: ignore[arg-type]
            )
        else:
            decoded = [self._decoded(frame, level, *todo[i], got[i]) for i in misses]  # type: ignore[arg-type]
        for i, img in zip(misses, decoded, strict=True):
            got[i] = img
        for (tx, ty), tile in zip(todo, got, strict=True):
            assert isinstance(tile, np.ndarray)
            ax0, ay0 = tx * ts, ty * ts
            sx0, sy0 = max(x0, ax0), max(y0, ay0)
            sx1, sy1 = min(x1, ax0 + tile.shape[1]), min(y1, ay0 + tile.shape[0])
            part = tile[sy0 - ay0 : sy1 - ay0, sx0 - ax0 : sx1 - ax0]
            if bgra:
                cv2.cvtColor(part, cv2.COLOR_BGR2BGRA, dst=out[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0])
            else:
                out[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0] = part
        return out

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True)
            self._pool = None
        with self._lock:
            for f in self._packs:
                f.close()
            self._packs.clear()
            self._lru.clear()
            self._lru_bytes = 0


class TileSource(FootageSource):
    """A footage served from a tile cache (the same interface as `VideoSource`, plus `region`)."""

    def __init__(
        self,
        metadata: FootageMetadata,
        folder: Path,
        geometry_factory: Callable[[int, int], FootageGeometry],
        cache_bytes: int | None = None,
    ) -> None:
        self.metadata = metadata
        self.cache = TileCache(folder, cache_bytes)
        try:
            self.geometry = geometry_factory(self.cache.layout.width_px, self.cache.layout.height_px)
        except BaseException:
            self.cache.close()
            raise
        self._fps = metadata.fps or self.cache.fps
        self._frame: tuple[int, U8] | None = None
        self._closed = False

    @property
    def fps(self) -> float:
        return self._fps

    @property
    def frame_count(self) -> int:
        return self.cache.frame_count

    @property
    def frame_size_px(self) -> tuple[int, int]:
        return (self.cache.layout.width_px, self.cache.layout.height_px)

    @property
    def level_count(self) -> int:
        return len(self.cache.layout.levels)

    def level_size_px(self, level: int) -> tuple[int, int] | None:
        levels = self.cache.layout.levels
        return levels[level] if 0 <= level < len(levels) else None

    def _check_open(self) -> None:
        if self._closed:
            raise FootageError(f"footage {self.metadata.name!r} is closed")

    def frame(self, index: int, level: int = 0) -> U8:
        """Frame `index` at pyramid level `level` (0: full resolution), assembled from all its tiles."""
        self._check_open()
        index = int(index) % self.frame_count
        if level == 0 and self._frame is not None and self._frame[0] == index:
            return self._frame[1]
        w, h = self.cache.layout.levels[level]
        img = self.cache.region(index, level, 0, 0, w, h)
        img.setflags(write=False)
        if level == 0:
            self._frame = (index, img)
        return img

    def region(
        self,
        index: int,
        level: int,
        x0: int,
        y0: int,
        x1: int,
        y1: int,
        out: U8 | None = None,
        quad: NDArray[np.float64] | None = None,
        margin_px: float = 0.0,
    ) -> U8:
        """Pixels [y0:y1, x0:x1] of pyramid level `level` of frame `index` (only the tiles under them decoded;
        with `quad`, only those within `margin_px` of it: see `TileCache.region`)."""
        self._check_open()
        return self.cache.region(int(index) % self.frame_count, level, x0, y0, x1, y1, out, quad, margin_px)

    def prefetch(self, index: int, level: int = 0, only_next: bool = False) -> None:
        """Nothing to do ahead: tiles are decoded on demand (kept for the VideoSource interface)."""

    def describe(self) -> dict[str, Any]:
        out = super().describe()
        c = self.cache
        out["tile_cache"] = (
            f"{c.codec}" + (f" q{c.quality}" if c.codec == "jpeg" else "")
            + f", {c.layout.tile_px} px tiles, {len(c.layout.levels)} levels, {c.disk_bytes / 2**20:.1f} MiB"
        )  # fmt: skip
        return out

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._frame = None
            self.cache.close()


def is_tile_cache(folder: Path) -> bool:
    return (Path(folder) / TILES_SUBDIR / "meta.json").is_file()


# ------------------------------------------------------------------------------------------------ building


def read_progress(tiles_dir: Path) -> dict[str, Any]:
    try:
        p = json.loads((tiles_dir / "progress.json").read_text(encoding="utf-8"))
        return p if isinstance(p, dict) else {}
    except (OSError, ValueError):
        return {}


def _write_json_atomic(path: Path, obj: dict[str, Any]) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        json.dump(obj, f, indent=1)
        f.flush()
        os.fsync(f.fileno())
    tmp.replace(path)


@dataclass(frozen=True)
class TileBuildResult:
    folder: Path
    frames: int
    disk_bytes: int
    codec: str
    quality: int
    resumed_from: int  # frames found done when the build started (0: a fresh build)


def _estimate_quality(
    frame_bgr: U8,
    layout: TileLayout,
    frames: int,
    codec: str,
    quality: int,
    max_bytes: int | None,
    pool: ThreadPoolExecutor,
) -> tuple[int, int]:
    """(quality, estimated total bytes) honouring `max_bytes` from the first frame's size (+10 % margin)."""
    tried = [quality] + [q for q in JPEG_FALLBACK_QUALITIES if q < quality] if codec == "jpeg" else [quality]
    est = 0
    for q in tried:
        est = int(sum(len(b) for b in encode_frame(frame_bgr, layout, codec, q, pool)) * frames * 1.1)
        if max_bytes is None or est <= max_bytes:
            return q, est
    hint = "a lower --tile-quality or a larger --max-size" if codec == "jpeg" else "--tile-codec jpeg"
    raise FootageError(
        f"the tile cache would take ~{est / 2**20:.0f} MiB ({frames} frames, {codec}"
        + (f" even at quality {tried[-1]}" if codec == "jpeg" else "")
        + f") > --max-size {(max_bytes or 0) / 2**20:.0f} MiB: use {hint}"
    )


def build_tiles(
    frames: Any,
    frame_count: int,
    width_px: int,
    height_px: int,
    fps: float,
    folder: Path,
    *,
    codec: str = DEFAULT_CODEC,
    quality: int = DEFAULT_JPEG_QUALITY,
    tile_px: int = DEFAULT_TILE_PX,
    max_bytes: int | None = None,
    source_id: str = "",
    progress_file: TextIO | None = None,
    show_progress: bool = True,
    desc: str = "tiles",
    threads: int = 2,
) -> TileBuildResult:
    """Write (or resume) the tiles of `frames` (an iterator of BGR frames, in order) under `folder`/tiles.

    Resumable: the packs and index are written in frame order and progress.json records, every COMMIT_FRAMES
    frames, how many frames are complete and how long each pack was then; a rerun with the same source and options
    truncates the packs to those lengths and continues after that frame (it skips the frames already done from
    `frames`). A rerun with other options or another source starts over.
    """
    from tqdm import tqdm

    if codec not in CODECS:
        raise FootageError(f"tile codec must be one of {', '.join(CODECS)}, got {codec!r}")
    if codec in ("jpeg", "yuv420z") and not 1 <= quality <= 100:
        raise FootageError(f"tile quality must be 1..100, got {quality}")
    if frame_count <= 0:
        raise FootageError("no frames to tile")
    if tile_px < 16 or tile_px > 4096:
        raise FootageError(f"tile size must be 16..4096 px, got {tile_px}")
    layout = TileLayout.of(width_px, height_px, tile_px)
    tdir = Path(folder) / TILES_SUBDIR
    tdir.mkdir(parents=True, exist_ok=True)
    want = {
        "version": FORMAT_VERSION, "width_px": width_px, "height_px": height_px, "frames": frame_count,
        "fps": fps, "tile_px": tile_px, "codec": codec, "source": source_id,
        "levels": [list(s) for s in layout.levels], "asked_quality": quality,
        "max_bytes": max_bytes,
    }  # fmt: skip
    old: dict[str, Any] = {}
    with contextlib.suppress(OSError, ValueError):
        old = json.loads((tdir / "meta.json").read_text(encoding="utf-8"))
    progress = read_progress(tdir)
    done = 0
    pack_sizes: list[int] = []
    same = isinstance(old, dict) and {k: old.get(k) for k in want} == want
    if same and isinstance(progress.get("frames_done"), int) and isinstance(progress.get("pack_sizes"), list):
        done = int(progress["frames_done"])
        pack_sizes = [int(v) for v in progress["pack_sizes"]]
        paths = [tdir / f"pack-{k:03d}.bin" for k in range(len(pack_sizes))]
        idx_ok = (tdir / "index.bin").is_file()
        if not idx_ok or any(
            not p.is_file() or p.stat().st_size < n for p, n in zip(paths, pack_sizes, strict=True)
        ):
            done, pack_sizes = 0, []  # the packs are shorter than recorded: start over
    if done == 0:
        for p in tdir.glob("*"):
            p.unlink()
        pack_sizes = []
    resumed_from = done
    with ThreadPoolExecutor(max_workers=max(1, threads), thread_name_prefix="viva-sitl-tiles") as pool:
        it = iter(frames)
        for _ in range(done):  # the frames already stored
            if next(it, None) is None:
                raise FootageError(f"the source has fewer frames than the {done} already tiled")
        first: U8 | None = None
        if done < frame_count:
            first = next(it, None)
            if first is None:
                raise FootageError("the source has no frame to tile")
        q = int(old.get("quality", quality)) if resumed_from else quality
        if done == 0:
            assert first is not None
            q, est = _estimate_quality(first, layout, frame_count, codec, quality, max_bytes, pool)
            if q != quality:
                print(f"tiles: jpeg quality {quality} -> {q} to stay under --max-size (~{est / 2**20:.0f} MiB)",
                      file=progress_file or sys.stderr)  # fmt: skip
            _write_json_atomic(tdir / "meta.json", {**want, "quality": q})
            np.zeros(frame_count * layout.tiles_per_frame, INDEX_DTYPE).tofile(tdir / "index.bin")
            _write_json_atomic(tdir / "progress.json", {"frames_done": 0, "pack_sizes": []})
        for k, n in enumerate(pack_sizes):  # drop what was written after the last commit
            os.truncate(tdir / f"pack-{k:03d}.bin", n)
        index = np.memmap(tdir / "index.bin", INDEX_DTYPE, mode="r+")
        packs = [open(tdir / f"pack-{k:03d}.bin", "ab") for k in range(len(pack_sizes))]  # noqa: SIM115
        if not packs:
            packs.append(open(tdir / "pack-000.bin", "ab"))  # noqa: SIM115
            pack_sizes.append(0)
        total = sum(pack_sizes)
        try:
            with tqdm(total=frame_count, initial=done, unit="frame", desc=desc, file=progress_file or sys.stderr,
                      disable=not show_progress) as bar:  # fmt: skip
                frame = first
                while done < frame_count:
                    if frame is None:
                        frame = next(it, None)
                        if frame is None:
                            raise FootageError(f"the source ended after {done} of {frame_count} frames")
                    if frame.shape != (height_px, width_px, 3):
                        raise FootageError(
                            f"frame {done} is {frame.shape}, expected {(height_px, width_px, 3)}"
                        )
                    blobs = encode_frame(frame, layout, codec, q, pool)
                    frame = None
                    size = sum(len(b) for b in blobs)
                    if max_bytes is not None and total + size > max_bytes:
                        raise FootageError(
                            f"the tile cache reached --max-size {max_bytes / 2**20:.0f} MiB at frame {done} of "
                            f"{frame_count} (the first frame's estimate was low): rerun with a larger bound"
                        )
                    if pack_sizes[-1] + size > PACK_BYTES and pack_sizes[-1] > 0:
                        packs.append(open(tdir / f"pack-{len(packs):03d}.bin", "ab"))  # noqa: SIM115
                        pack_sizes.append(0)
                    pk = len(packs) - 1
                    recs = index[done * layout.tiles_per_frame : (done + 1) * layout.tiles_per_frame]
                    off = pack_sizes[pk]
                    for i, b in enumerate(blobs):
                        recs[i] = (pk, len(b), off, tile_checksum(b))
                        off += len(b)
                    packs[pk].write(b"".join(blobs))
                    pack_sizes[pk] = off
                    total += size
                    done += 1
                    bar.update(1)
                    if done % COMMIT_FRAMES == 0 or done == frame_count:
                        for f in packs:
                            f.flush()
                            os.fsync(f.fileno())
                        index.flush()
                        _write_json_atomic(
                            tdir / "progress.json", {"frames_done": done, "pack_sizes": pack_sizes}
                        )
        finally:
            for f in packs:
                f.close()
            del index
    disk = sum(p.stat().st_size for p in tdir.glob("*") if p.is_file())
    return TileBuildResult(Path(folder), frame_count, disk, codec, q, resumed_from)
