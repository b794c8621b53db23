"""Tile cache format: the layout of a cache folder, the tile grid, the index records and their checksums, and the
tile codecs (see the package docstring for the whole format)."""

from __future__ import annotations

import json
import threading
import zlib
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.footage.errors import FootageError
from viva_sitl.imaging import half_size, max_pyramid_level

U8 = NDArray[np.uint8]

TILES_SUBDIR = "tiles"
FORMAT_VERSION = 2
# format 3: format 2 whose level 0 has a tile size of its own (meta.json's "tile_px_level0"); written only for such a
# cache, so that a viva-sitl that does not know it refuses it (unknown format) instead of misreading level 0
FORMAT_VERSION_LEVEL0 = 3
DEFAULT_TILE_PX = 256
DEFAULT_CODEC = "jpeg"
CODECS = ("jpeg", "png", "raw", "yuv420z", "yuv420zg")
AUTO_CODEC = "yuv420z"  # the automatic cache's codec (viva_sitl.footage.autocache)
COMPACT_CODEC = "yuv420zg"  # the automatic cache's with --cache-compact: yuv420z with level 0 gradient-coded
YUVZ_CODECS = ("yuv420z", "yuv420zg")
DEFAULT_JPEG_QUALITY = 95
# qualities tried, best first, when the size bound would be exceeded at the asked one
JPEG_FALLBACK_QUALITIES = (95, 92, 90, 85, 80, 75, 70, 60, 50)
PACK_BYTES = 1 << 30  # start a new pack file beyond this size
COMMIT_FRAMES = 4  # progress.json is rewritten (and packs flushed) every this many frames
INDEX_DTYPE = np.dtype([("pack", "<u4"), ("length", "<u4"), ("offset", "<u8"), ("check", "<u8")])
INDEX_DTYPE_V1 = np.dtype(
    [("pack", "<u4"), ("length", "<u4"), ("offset", "<u8"), ("check", "<u4"), ("pad", "<u4")]
)
_MASK64 = (1 << 64) - 1
_RAW_MAGIC = b"RAWT"
_YUVZ_MAGIC = b"Y4Z1"
_YUVG_MAGIC = b"Y4G1"  # a yuv420zg gradient-coded tile (the reader tells the kinds of tile by their magic)
_YUVZ_MAGICS = (_YUVZ_MAGIC, _YUVG_MAGIC)  # the tiles _decode_yuvz reads
# zstd level of the yuv420z codec's zstd tiles: -1, zstd's first fast mode (literals not Huffman-coded), decodes a
# 256 px tile in ~49 us where levels 1-3 take ~69-72 us, for ~9 % more bytes (4K bench clip: 9.37 MiB per frame vs
# 8.60 at level 3; bench/results_tiles.md, session 16); readers decode any level
YUVZ_LEVEL = -1
# the yuv420z codec's levels stored as zstd YUV 4:2:0 (the rest as jpeg 4:4:4): levels 0 and 1, the levels a view
# reads up to ~4 footage px per VAC px (~300 m over the 4K bench clip), decoded ~3.3x faster than jpeg. A level >= 1
# tile has the chroma resolution 4:2:0 halves again: it is stored so only where its round trip keeps
# YUVZ_COARSE_MIN_PSNR_DB (jpeg q95's own level-1 figure; 93-100 % of the 4K bench clip's level-1 tiles, ~0.8 MiB
# more per 4K frame), as jpeg 4:4:4 elsewhere (sharp chroma edges: 31 dB as 4:2:0 in the tests' synthetic clip)
YUVZ_MAX_LEVEL = 1
YUVZ_COARSE_MIN_PSNR_DB = 44.0
# yuv420zg: yuv420z whose level-0 tiles store each YUV plane byte's difference to its gradient prediction (left + up
# - up-left, modulo 256), zstd-compressed at YUVG_LEVEL (literals Huffman-coded: the residuals are small numbers, which
# zstd's fast modes store a byte each) with matches of at least YUVG_MIN_MATCH bytes (residuals repeat little: fewer
# short matches, ~1 % fewer bytes and ~8 % faster to decompress than level 1's default 6, as fast to compress).
# Lossless against yuv420z's planes; undone by one cv2.integral (sums modulo 256 in int32). 4K bench clip: the cache
# 6.52 MiB per frame instead of 9.48 (level 0 ~3.7 instead of 6.5), 8K 20.1 instead of 31.8; a 128 px tile decodes
# in ~31 us instead of ~19, a 50 m region ~1.3x slower (bench/results_tiles.md, session 18). Level 1 keeps
# yuv420z's tiles: the ~0.7 MiB more it would save costs the 300 m view's reads. A plane buffer whose int32 sums
# could overflow (tiles over 2048 px) is stored as yuv420z's.
YUVG_LEVEL = 1
YUVG_MIN_MATCH = 7
YUVG_MAX_PLANE_BYTES = (1 << 31) // 255
# full-resolution chroma: 4:2:0 costs 4-7 dB on sharp coarse levels (bench/results_tiles.md) for ~30 % less size
_JPEG_444 = (cv2.IMWRITE_JPEG_SAMPLING_FACTOR, cv2.IMWRITE_JPEG_SAMPLING_FACTOR_444)

# Environment overrides for every tile source of a process and its children (the trials' pool sets the decode
# threads per worker: 1 when the workers fill the cores, where handing ~2 misses per frame to a pool costs more than


@dataclass(frozen=True)
class TileLayout:
    """Level sizes and tile grid of one footage size: `tile_px` square tiles, level 0's `level0_px` (0: `tile_px`)."""

    width_px: int
    height_px: int
    tile_px: int
    levels: tuple[tuple[int, int], ...]  # (w, h) per level
    grid: tuple[tuple[int, int], ...]  # (tiles across, tiles down) per level
    first: tuple[int, ...]  # index of each level's first tile within a frame
    level0_px: int = 0

    @staticmethod
    def of(width_px: int, height_px: int, tile_px: int, level0_px: int | None = None) -> TileLayout:
        l0 = tile_px if level0_px is None else level0_px
        if width_px <= 0 or height_px <= 0 or min(tile_px, l0) < 16:
            raise FootageError(
                f"bad tile layout {width_px}x{height_px}, tile {tile_px} px (level 0: {l0} px)"
            )
        sizes = [(width_px, height_px)]
        for _ in range(max_pyramid_level(width_px, height_px)):
            w, h = sizes[-1]
            sizes.append(((w + 1) // 2, (h + 1) // 2))
        sides = [l0] + [tile_px] * (len(sizes) - 1)
        grid = [(-(-w // t), -(-h // t)) for (w, h), t in zip(sizes, sides, strict=True)]
        first, n = [], 0
        for nx, ny in grid:
            first.append(n)
            n += nx * ny
        return TileLayout(width_px, height_px, tile_px, tuple(sizes), tuple(grid), tuple(first), l0)

    def tile_size(self, level: int) -> int:
        """The side of level `level`'s tiles, px."""
        return (self.level0_px or self.tile_px) if level == 0 else self.tile_px

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
    FORMAT_VERSION_LEVEL0: (INDEX_DTYPE, tile_checksum),
}


def _encode_yuvz(tile: U8, min_psnr_db: float | None = None, gradient: bool = False) -> bytes | None:
    """A BGR tile as planar YUV 4:2:0 (I420, OpenCV's BT.601 conversion) compressed with zstd; an odd width or
    height is padded by repeating the last column/row (the header keeps the true size). With `min_psnr_db`: None
    when the round trip through 4:2:0 is below it. With `gradient`: the planes' gradient residuals (YUVG_LEVEL)."""
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
    size = int(w).to_bytes(2, "little") + int(h).to_bytes(2, "little")
    if gradient and yuv.size <= YUVG_MAX_PLANE_BYTES:
        params = zstandard.ZstdCompressionParameters.from_level(YUVG_LEVEL, min_match=YUVG_MIN_MATCH)
        body = zstandard.ZstdCompressor(compression_params=params).compress(_gradient_residuals(yuv))
        return _YUVG_MAGIC + size + body
    return _YUVZ_MAGIC + size + zstandard.ZstdCompressor(level=YUVZ_LEVEL).compress(yuv.tobytes())


def _gradient_residuals(planes: NDArray[Any]) -> bytes:
    """Each byte minus its gradient prediction (left + up - up-left; 0 outside the buffer), modulo 256: the second
    difference whose 2-D prefix sum (cv2.integral) gives the bytes back."""
    a = planes.astype(np.int16)
    rows = np.diff(a, axis=0, prepend=np.zeros((1, a.shape[1]), np.int16))
    return np.diff(rows, axis=1, prepend=np.zeros((a.shape[0], 1), np.int16)).astype(np.uint8).tobytes()


_zstd_local = threading.local()


def _decode_yuvz(data: bytes | memoryview, bgra: bool = False) -> U8 | None:
    """A yuv420z tile's BGR pixels (with `bgra`: BGRA, alpha 255, converted from YUV in the same pass); None when
    the bytes are not one."""
    import zstandard

    magic = bytes(data[:4])
    if len(data) < 8 or magic not in _YUVZ_MAGICS:
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
    code = cv2.COLOR_YUV2BGRA_I420 if bgra else cv2.COLOR_YUV2BGR_I420
    planes = np.frombuffer(raw, np.uint8).reshape(eh * 3 // 2, ew)
    if magic == _YUVG_MAGIC:  # the residuals' 2-D prefix sums, modulo 256 (int32 -> uint8 keeps the low byte)
        planes = cv2.integral(planes, sdepth=cv2.CV_32S)[1:, 1:].astype(np.uint8)
    img = cv2.cvtColor(planes, code)
    return np.asarray(img if (ew, eh) == (w, h) else img[:h, :w], dtype=np.uint8)


def _encode(tile: U8, codec: str, quality: int, level: int = 0) -> bytes:
    """One tile's bytes. "yuv420z" is two codecs by level: level 0 as zstd-compressed YUV 4:2:0 (the video's own
    chroma resolution: ~47 dB, decoded ~4x faster than a JPEG), coarser levels as JPEG 4:4:4 (4:2:0 there costs
    5-10 dB on sharp images: a box-halved level has full-resolution chroma again; bench/results_tiles.md, session
    10) except level-1 tiles whose 4:2:0 round trip keeps YUVZ_COARSE_MIN_PSNR_DB (YUVZ_MAX_LEVEL; the reader
    tells the two by the tile's magic). "yuv420zg" is yuv420z with level 0 gradient-coded (YUVG_LEVEL)."""
    if codec == "raw":
        h, w = tile.shape[:2]
        return _RAW_MAGIC + int(w).to_bytes(2, "little") + int(h).to_bytes(2, "little") + tile.tobytes()
    if codec in YUVZ_CODECS:
        if level == 0:
            data = _encode_yuvz(tile, None, gradient=codec == "yuv420zg")
        elif level <= YUVZ_MAX_LEVEL:
            data = _encode_yuvz(tile, YUVZ_COARSE_MIN_PSNR_DB)
        else:
            data = None
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


def _decode(data: bytes | memoryview, codec: str, bgra: bool = False) -> U8 | None:
    """A tile's pixels: BGR, or with `bgra` BGRA where the codec converts to it in the same pass (yuv420z's zstd
    tiles: a BGR -> BGRA pass of the renderer's paste saved); the caller checks the channels it got."""
    if codec == "raw":
        if len(data) < 8 or bytes(data[:4]) != _RAW_MAGIC:
            return None
        w = int.from_bytes(data[4:6], "little")
        h = int.from_bytes(data[6:8], "little")
        if len(data) != 8 + w * h * 3:
            return None
        return np.frombuffer(data, np.uint8, offset=8).reshape(h, w, 3)
    if codec in YUVZ_CODECS and bytes(data[:4]) in _YUVZ_MAGICS:
        return _decode_yuvz(data, bgra)
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
    for level, img in enumerate(frame_pyramid(frame_bgr)):
        nx, ny = layout.grid[level]
        t = layout.tile_size(level)
        for ty in range(ny):
            for tx in range(nx):
                jobs.append((np.ascontiguousarray(img[ty * t : (ty + 1) * t, tx * t : (tx + 1) * t]), level))
    if pool is None:
        return [_encode(j, codec, quality, lv) for j, lv in jobs]
    return list(pool.map(lambda j: _encode(j[0], codec, quality, j[1]), jobs))


def read_progress(tiles_dir: Path) -> dict[str, Any]:
    try:
        p = json.loads((tiles_dir / "progress.json").read_text(encoding="utf-8"))
        return p if isinstance(p, dict) else {}
    except (OSError, ValueError):
        return {}


def is_tile_cache(folder: Path) -> bool:
    return (Path(folder) / TILES_SUBDIR / "meta.json").is_file()
