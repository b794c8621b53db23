"""Tiled multi-resolution footage cache: decode cost scales with the VAC's output, not the footage's resolution.

Every footage frame is stored as its full mip-map pyramid (level 0 = the decoded frame, each level the 2x2 box
halving of the previous one, exactly as `viva_sitl.camera.LazyPyramid` builds it), each level cut into
`tile_px` x `tile_px` tiles (level 0 may have a size of its own: format 3, below), each tile intra-coded on its own
(as map tile servers and cloud-optimised GeoTIFFs do).
A render decodes only the tiles under the VAC's footprint at the level(s) it samples; decoded tiles are kept in an
LRU with a byte cap (256 MiB; `TileSettings`, an argument or the process's; `$VIVA_SITL_TILE_CACHE_MB` is read by
the top floor, not here, see `settings.py`).
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
than jpeg, coarser levels as jpeg 4:4:4; ~0.7-1.0 byte per footage pixel, see `_encode`), "yuv420zg" (the
automatic cache's with `--cache-compact`: yuv420z with level 0's planes gradient-coded, the same pixels, ~30 % smaller
and its level-0 tiles ~1.7x slower to decode, see YUVG_LEVEL).
Every tile read checks its length and checksum and the decoded shape; any mismatch, a missing pack or level, or a bad
index raises a one-line `FootageError` naming the cache and the command that rebuilds it: never a wrong image.

Format 3 is format 2 with level 0 cut into tiles of their own size (meta.json's `tile_px_level0`; the automatic
yuv420z cache of footage up to 4K uses 128 px there, 256 px above: a view near the ground reads a small footprint of
level 0, and smaller tiles decode fewer pixels around it). A uniform cache keeps format 2, so older readers still
open it; they refuse a format-3 cache in one line instead of misreading its level 0.

The checksum (format 2) is `tile_checksum`: the tile's bytes summed as little-endian 64-bit words, modulo 2^64,
plus its length. It catches truncation, any changed byte or run of bytes, zeroed or overwritten ranges; what it
cannot see is 8-byte words swapped with each other inside one tile, which no storage fault produces. Why not CRC-32
(format 1, still read): a raw 256 px tile is 192 KiB, and zlib.crc32 over it took 47 us against 3.8 us for the sum,
~0.27 ms of a ~1.5 ms step at 50 m (5.8 tiles per step; bench/results_tiles.md, session 8).

Modules: `format` (folder layout, tile grid, index records, checksums, codecs), `read` (TileCache, TileSource),
`build` (build_tiles), `settings` (TileSettings, the process's settings); this package re-exports their names.
"""

from viva_sitl.footage.tiles.build import TileBuildResult, build_tiles
from viva_sitl.footage.tiles.format import (
    AUTO_CODEC,
    CODECS,
    COMMIT_FRAMES,
    COMPACT_CODEC,
    DEFAULT_CODEC,
    DEFAULT_JPEG_QUALITY,
    DEFAULT_TILE_PX,
    FORMAT_VERSION,
    FORMATS,
    INDEX_DTYPE,
    INDEX_DTYPE_V1,
    JPEG_FALLBACK_QUALITIES,
    PACK_BYTES,
    TILES_SUBDIR,
    YUVG_LEVEL,
    YUVZ_COARSE_MIN_PSNR_DB,
    YUVZ_CODECS,
    YUVZ_LEVEL,
    YUVZ_MAX_LEVEL,
    TileLayout,
    _decode,
    _encode,
    encode_frame,
    frame_pyramid,
    is_tile_cache,
    read_progress,
    tile_checksum,
)
from viva_sitl.footage.tiles.read import TileCache, TileSource
from viva_sitl.footage.tiles.settings import (
    CACHE_ENV,
    DECODE_THREADS_ENV,
    DEFAULT_CACHE_BYTES,
    DEFAULT_DECODE_THREADS,
    READ_AHEAD_ENV,
    TileSettings,
    process_settings,
    set_process_settings,
)

__all__ = [
    "AUTO_CODEC",
    "CACHE_ENV",
    "CODECS",
    "COMMIT_FRAMES",
    "COMPACT_CODEC",
    "DECODE_THREADS_ENV",
    "READ_AHEAD_ENV",
    "DEFAULT_CACHE_BYTES",
    "DEFAULT_CODEC",
    "DEFAULT_DECODE_THREADS",
    "DEFAULT_JPEG_QUALITY",
    "DEFAULT_TILE_PX",
    "FORMATS",
    "FORMAT_VERSION",
    "INDEX_DTYPE",
    "INDEX_DTYPE_V1",
    "JPEG_FALLBACK_QUALITIES",
    "PACK_BYTES",
    "TILES_SUBDIR",
    "YUVG_LEVEL",
    "YUVZ_CODECS",
    "YUVZ_COARSE_MIN_PSNR_DB",
    "YUVZ_LEVEL",
    "YUVZ_MAX_LEVEL",
    "TileBuildResult",
    "TileCache",
    "TileLayout",
    "TileSettings",
    "TileSource",
    "_decode",
    "_encode",
    "build_tiles",
    "encode_frame",
    "frame_pyramid",
    "is_tile_cache",
    "process_settings",
    "read_progress",
    "set_process_settings",
    "tile_checksum",
]
