"""Building a tile cache: `build_tiles` (resumable, size-bounded) writes the packs, the index and the progress
record of the format in `format.py`."""

from __future__ import annotations

import contextlib
import json
import os
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.tiles.format import (
    CODECS,
    COMMIT_FRAMES,
    DEFAULT_CODEC,
    DEFAULT_JPEG_QUALITY,
    DEFAULT_TILE_PX,
    FORMAT_VERSION,
    FORMAT_VERSION_LEVEL0,
    INDEX_DTYPE,
    JPEG_FALLBACK_QUALITIES,
    PACK_BYTES,
    TILES_SUBDIR,
    U8,
    YUVZ_CODECS,
    TileLayout,
    encode_frame,
    read_progress,
    tile_checksum,
)


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
    level0_tile_px: int | None = None,
    max_bytes: int | None = None,
    source_id: str = "",
    progress_file: TextIO | None = None,
    show_progress: bool = True,
    desc: str = "tiles",
    threads: int = 2,
) -> TileBuildResult:
    """Write (or resume) the tiles of `frames` (an iterator of BGR frames, in order) under `folder`/tiles.
    `level0_tile_px`: level 0's own tile size (None: `tile_px`; a different one writes format 3).

    Resumable: the packs and index are written in frame order and progress.json records, every COMMIT_FRAMES
    frames, how many frames are complete and how long each pack was then; a rerun with the same source and options
    truncates the packs to those lengths and continues after that frame (it skips the frames already done from
    `frames`). A rerun with other options or another source starts over.
    """
    from tqdm import tqdm

    if codec not in CODECS:
        raise FootageError(f"tile codec must be one of {', '.join(CODECS)}, got {codec!r}")
    if codec in ("jpeg", *YUVZ_CODECS) and not 1 <= quality <= 100:
        raise FootageError(f"tile quality must be 1..100, got {quality}")
    if frame_count <= 0:
        raise FootageError("no frames to tile")
    l0 = tile_px if level0_tile_px is None else level0_tile_px
    if not (16 <= tile_px <= 4096 and 16 <= l0 <= 4096):
        raise FootageError(
            f"tile size must be 16..4096 px, got {tile_px}" + (f" (level 0: {l0})" if l0 != tile_px else "")
        )
    layout = TileLayout.of(width_px, height_px, tile_px, l0)
    tdir = Path(folder) / TILES_SUBDIR
    tdir.mkdir(parents=True, exist_ok=True)
    want = {
        "version": FORMAT_VERSION, "width_px": width_px, "height_px": height_px, "frames": frame_count,
        "fps": fps, "tile_px": tile_px, "codec": codec, "source": source_id,
        "levels": [list(s) for s in layout.levels], "asked_quality": quality,
        "max_bytes": max_bytes,
    }  # fmt: skip
    if l0 != tile_px:  # format 3: level 0's own tile size (a uniform cache keeps format 2's meta.json)
        want.update(version=FORMAT_VERSION_LEVEL0, tile_px_level0=l0)
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
