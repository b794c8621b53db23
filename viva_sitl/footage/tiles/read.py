"""Reading a tile cache: `TileCache` (checked tile reads, an LRU of decoded tiles, region assembly) and `TileSource`
(a FootageSource served from it). Their settings (`TileSettings`) are arguments: nothing here reads the
environment."""

from __future__ import annotations

import json
import os
import threading
from collections import OrderedDict, deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.footage.metadata import FootageMetadata
from viva_sitl.footage.source import FootageCapabilities, FootageSource, RegionRead
from viva_sitl.footage.tiles.format import (
    CODECS,
    FORMATS,
    TILES_SUBDIR,
    U8,
    TileLayout,
    _decode,
    read_progress,
)
from viva_sitl.footage.tiles.settings import TileSettings

_TILE_CAPABILITIES = FootageCapabilities(region=RegionRead.TILES)  # raw tiles: copied, not decoded
_DECODED_TILE_CAPABILITIES = FootageCapabilities(region=RegionRead.TILES, region_decodes=True)


# read-ahead: the jobs of a level are judged by windows of AHEAD_WINDOW (the first one is not: a flight's first
# frames run late in bursts while threads, decoders and buffers warm up): when more than half of a window's jobs ran
# late (the worker had not done half the tiles when the region came), read-ahead of that level pauses for
# AHEAD_PAUSE_FRAMES regions, then it is tried again; each pause that follows another with no good window between
# them is twice as long, up to AHEAD_PAUSE_MAX_FRAMES. Why: a worker that gets no core between two regions (2 cores,
# the compact cache's decode or 300 m's level-1 tiles beside OpenCV's 2-thread warp: 75-95 % of jobs late) only
# delays the warp's threads and the region that waits for it; where it helps (the default cache at 50 m: ~95 % in
# time, the late ones in bursts) it is never paused
AHEAD_WINDOW = 16
AHEAD_PAUSE_FRAMES = 240
AHEAD_PAUSE_MAX_FRAMES = 240 * 16


class _ReadAhead:
    """The tiles of one (frame, level) decoded on the pool's worker before a region asks for them; the region that
    comes takes the rest of the queue (`todo`) itself. Each decoded tile lands in `done` (out of the LRU until the
    region uses it: a small LRU would evict them first)."""

    def __init__(self, frame: int, level: int, tiles: list[tuple[int, int]], bgra: bool) -> None:
        self.frame, self.level, self.bgra = frame, level, bgra
        self.total = len(tiles)
        self.todo: deque[tuple[int, int]] = deque(tiles)
        self.done: dict[tuple[int, int], U8] = {}
        self.future: Future[None] | None = None


class TileCache:
    """Read access to one tile cache folder (`<folder>/tiles`), with an LRU of decoded tiles."""

    def __init__(
        self,
        folder: Path,
        settings: TileSettings | None = None,
        *,
        cache_bytes: int | None = None,
        decode_threads: int | None = None,
    ) -> None:
        """`settings`: the LRU cap and decode threads (None: TileSettings() defaults; nothing here reads the
        environment); `cache_bytes`, `decode_threads` override one of them."""
        base = settings if settings is not None else TileSettings()
        cap = base.cache_bytes if cache_bytes is None else int(cache_bytes)
        threads = base.threads if decode_threads is None else int(decode_threads)
        self.folder = Path(folder)
        self.dir = self.folder / TILES_SUBDIR
        self._rebuild = f"rebuild it with `viva-sitl footage ingest --tiles` (or delete {self.folder})"
        meta = self._read_meta()
        index_dtype, self._checksum = FORMATS[int(meta["version"])]
        try:
            self.layout = TileLayout.of(
                int(meta["width_px"]),
                int(meta["height_px"]),
                int(meta["tile_px"]),
                int(meta["tile_px_level0"]) if "tile_px_level0" in meta else None,
            )
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
        self.tiles_ahead = 0  # tiles a region found decoded ahead (read-ahead)
        self.ahead_jobs = 0
        # read-ahead (with a decode pool): per level, the last frame a region read and the step to it; two equal
        # steps in a row (frames read in sequence, as a flight over a clip does) start decoding the same tiles of
        # the next frame on the pool's worker while the caller warps, simulates, encodes
        self._read_ahead = base.read_ahead
        self._seq: dict[int, tuple[int, int]] = {}
        self._ahead: dict[int, _ReadAhead] = {}
        self._ahead_window: dict[int, list[bool]] = {}  # late or not, the jobs since the last judgement
        self._ahead_paused: dict[int, int] = {}
        self._ahead_backoff: dict[int, int] = {}  # pauses in a row with no good window between them
        self._worker_job: Future[None] | None = None
        self._ahead_lock = threading.Lock()
        # the decoders release the GIL: misses of one region are decoded in parallel, by the caller's thread and
        # threads - 1 workers, each every n-th of them (one hand-off per worker and region, not per tile)
        self._threads = threads
        self._pool = (
            ThreadPoolExecutor(threads - 1, thread_name_prefix="viva-sitl-tile-decode")
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
            # the record as Python ints in one call (pack, length, offset, check[, pad]); one positional read
            pack, length, offset, check = self.index[frame * self.layout.tiles_per_frame + t].item()[:4]
            data = os.pread(self._packs[pack].fileno(), length, offset)
        if len(data) != length:
            raise self._error(f"frame {frame} level {level} tile ({tx}, {ty}): pack truncated")
        if self._checksum(data) != check:
            raise self._error(f"frame {frame} level {level} tile ({tx}, {ty}): checksum mismatch")
        return data

    def _decoded(
        self, frame: int, level: int, tx: int, ty: int, data: bytes, bgra: bool = False, keep: bool = True
    ) -> U8:
        """Decode checked bytes (BGR, or BGRA where the codec converts to it in the same pass and `bgra` asks),
        check the size, keep the tile in the LRU (unless `keep` is False: a read-ahead's tile, kept by the region
        that uses it)."""
        img = _decode(data, self.codec, bgra)
        lw, lh = self.layout.levels[level]
        ts = self.layout.tile_size(level)
        want = (min(ts, lh - ty * ts), min(ts, lw - tx * ts))
        if img is None or img.ndim != 3 or img.shape[:2] != want or img.shape[2] not in (3, 4):
            raise self._error(f"frame {frame} level {level} tile ({tx}, {ty}): does not decode to a "
                              f"{want[1]}x{want[0]} image")  # fmt: skip
        img.setflags(write=False)
        with self._lock:
            self.tiles_decoded += 1
        if keep:
            self._keep(frame, level, tx, ty, img)
        return img

    def _keep(self, frame: int, level: int, tx: int, ty: int, img: U8) -> None:
        """Put a decoded tile in the LRU (evicting the least recently used beyond the cap)."""
        key = (frame, self.layout.tile_index(level, tx, ty))
        with self._lock:
            if key not in self._lru:
                self._lru[key] = img
                self._lru_bytes += img.nbytes
            while self._lru_bytes > self.cache_bytes and len(self._lru) > 1:
                _, old = self._lru.popitem(last=False)
                self._lru_bytes -= old.nbytes

    def _work_ahead(self, job: _ReadAhead) -> None:
        """Decode the job's tiles until its queue is empty (the worker, then the region that came). A tile that
        fails is left out: the region that asks for it reads it again and raises there, with its message."""
        while True:
            try:
                tx, ty = job.todo.popleft()
            except IndexError:
                return
            try:
                got = self._read(job.frame, job.level, tx, ty)
                img = got if isinstance(got, np.ndarray) else self._decoded(
                    job.frame, job.level, tx, ty, got, job.bgra, keep=False
                )  # fmt: skip
            except Exception:  # noqa: BLE001, S112 - reported by the region that reads the tile
                continue
            job.done[(tx, ty)] = img

    def _take_ahead(self, frame: int, level: int, bgra: bool) -> dict[tuple[int, int], U8]:
        """The tiles of (frame, level) decoded ahead, or {}: the caller decodes the job's tiles no worker has
        started, then waits for the one in progress. A job for another frame is dropped, unless this read repeats
        the level's last frame (two renders of one footage frame: the next one is still to come)."""
        if not self._ahead:  # nothing planned (or no read-ahead at all): no lock on the region's path
            return {}
        with self._ahead_lock:
            job = self._ahead.get(level)
            if job is None:
                return {}
            if job.frame != frame or job.bgra != bgra:
                if self._seq.get(level, (None, 0))[0] != frame:
                    del self._ahead[level]
                    job.todo.clear()  # the worker stops after its tile
                return {}
            del self._ahead[level]
            window = self._ahead_window.setdefault(level, [])
            window.append(2 * len(job.done) < job.total)  # late
            if len(window) >= AHEAD_WINDOW:
                backoff = self._ahead_backoff.get(level, 0)
                if level not in self._ahead_backoff:  # the first window: warm-up, not judged
                    self._ahead_backoff[level] = 0
                elif 2 * sum(window) > len(window):
                    self._ahead_paused[level] = min(AHEAD_PAUSE_FRAMES << backoff, AHEAD_PAUSE_MAX_FRAMES)
                    self._ahead_backoff[level] = backoff + 1
                else:
                    self._ahead_backoff[level] = 0
                window.clear()
        self._work_ahead(job)
        if job.future is not None:
            job.future.result()
        return job.done

    def _plan_ahead(self, frame: int, level: int, tiles: list[tuple[int, int]], bgra: bool) -> None:
        """After a region of `frame`: when the level's frames come in steady steps, start decoding `tiles` of the
        next frame of the sequence on the pool's worker, while the caller warps, simulates, encodes."""
        if self._pool is None or not self._read_ahead or not tiles:
            return
        with self._ahead_lock:
            last, stride = self._seq.get(level, (None, 0))
            if last == frame:
                return  # the same frame again: its successor is planned (or the sequence is not steady)
            step = 0 if last is None else (frame - last) % self.frame_count
            self._seq[level] = (frame, step)
            paused = self._ahead_paused.get(level, 0)
            if paused:
                self._ahead_paused[level] = paused - 1
                return
            if step == 0 or step != stride or level in self._ahead or not self._packs:
                return
            job = _ReadAhead((frame + step) % self.frame_count, level, tiles, bgra)
            self._ahead[level] = job
            job.future = self._pool.submit(self._work_ahead, job)
            self._worker_job = job.future
            self.ahead_jobs += 1

    def _worker_busy(self) -> bool:
        """The pool's worker is on a read-ahead (one that was taken may still be on its last tile)."""
        return self._worker_job is not None and not self._worker_job.done()

    def tile(self, frame: int, level: int, tx: int, ty: int) -> U8:
        """The decoded tile as BGR (read-only), checked against its length, checksum and expected size."""
        got = self._read(frame, level, tx, ty)
        img = got if isinstance(got, np.ndarray) else self._decoded(frame, level, tx, ty, got)
        if img.shape[2] == 4:  # kept as BGRA for the renderer's paste
            img = np.asarray(cv2.cvtColor(img, cv2.COLOR_BGRA2BGR), np.uint8)
            img.setflags(write=False)
        return img

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
        ts = self.layout.tile_size(level)
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
        from the LRU are decoded on `decode_threads` threads. A 4-channel `out` receives BGRA (alpha 255): a
        yuv420z tile is decoded straight to BGRA (YUV -> BGRA in one pass, then copied), any other tile converted as
        it is pasted; a tile the LRU holds in the other channel count is converted as it is pasted."""
        lw, lh = self.layout.levels[level]
        if not (0 <= x0 < x1 <= lw and 0 <= y0 < y1 <= lh):
            raise ValueError(f"region ({x0}, {y0})-({x1}, {y1}) outside level {level} ({lw}x{lh})")
        if out is None:
            out = np.empty((y1 - y0, x1 - x0, 3), np.uint8)
        if out.shape[:2] != (y1 - y0, x1 - x0) or out.ndim != 3 or out.shape[2] not in (3, 4):
            raise ValueError(f"out must be a {x1 - x0}x{y1 - y0} BGR or BGRA array, got shape {out.shape}")
        bgra = out.shape[2] == 4
        ts = self.layout.tile_size(level)
        todo = self.tiles_under(level, x0, y0, x1, y1, quad, margin_px)
        ahead = self._take_ahead(frame, level, bgra)
        got: list[U8 | bytes] = []
        for tx, ty in todo:
            early = ahead.get((tx, ty))
            if early is None:
                got.append(self._read(frame, level, tx, ty))
            else:
                self._keep(frame, level, tx, ty, early)
                self.tiles_ahead += 1
                got.append(early)
        misses = [i for i, g in enumerate(got) if not isinstance(g, np.ndarray)]

        def decode(share: list[int]) -> None:
            for i in share:
                got[i] = self._decoded(frame, level, *todo[i], got[i], bgra)  # type: ignore[arg-type]

        # misses shared with the pool's worker, unless it is still on a read-ahead's tile (then the caller's alone)
        if len(misses) > 1 and self._pool is not None and not self._worker_busy():
            n = min(self._threads, len(misses))
            shares = [misses[k::n] for k in range(n)]  # interleaved: a region may mix zstd and jpeg tiles
            futures = [self._pool.submit(decode, share) for share in shares[1:]]
            decode(shares[0])
            for fut in futures:
                fut.result()
        else:
            decode(misses)
        for (tx, ty), tile in zip(todo, got, strict=True):
            assert isinstance(tile, np.ndarray)
            ax0, ay0 = tx * ts, ty * ts
            sx0, sy0 = max(x0, ax0), max(y0, ay0)
            sx1, sy1 = min(x1, ax0 + tile.shape[1]), min(y1, ay0 + tile.shape[0])
            part = tile[sy0 - ay0 : sy1 - ay0, sx0 - ax0 : sx1 - ax0]
            dst = out[sy0 - y0 : sy1 - y0, sx0 - x0 : sx1 - x0]
            if part.shape[2] == dst.shape[2]:
                dst[...] = part
            else:
                cv2.cvtColor(part, cv2.COLOR_BGR2BGRA if bgra else cv2.COLOR_BGRA2BGR, dst=dst)
        self._plan_ahead(frame, level, todo, bgra)
        return out

    def close(self) -> None:
        with self._ahead_lock:
            for job in self._ahead.values():
                job.todo.clear()
            self._ahead.clear()
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
        *,
        settings: TileSettings | None = None,
    ) -> None:
        """`settings`: see TileCache (`cache_bytes` overrides its LRU cap)."""
        self.metadata = metadata
        self.cache = TileCache(folder, settings, cache_bytes=cache_bytes)
        try:
            self.geometry = geometry_factory(self.cache.layout.width_px, self.cache.layout.height_px)
        except BaseException:
            self.cache.close()
            raise
        self._fps = metadata.fps or self.cache.fps
        self._frame: tuple[int, U8] | None = None
        self._closed = False

    @property
    def capabilities(self) -> FootageCapabilities:
        """Regions of the stored pyramid levels (only the tiles under them decoded; raw tiles need no decoding)."""
        return _TILE_CAPABILITIES if self.cache.codec == "raw" else _DECODED_TILE_CAPABILITIES

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
            + f", {c.layout.tile_px} px tiles"
            + (f" ({c.layout.tile_size(0)} px at level 0)" if c.layout.tile_size(0) != c.layout.tile_px else "")
            + f", {len(c.layout.levels)} levels, {c.disk_bytes / 2**20:.1f} MiB"
        )  # fmt: skip
        return out

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._frame = None
            self.cache.close()
