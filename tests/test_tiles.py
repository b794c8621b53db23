"""The tiled footage cache: same images as the video (lossless codecs) or within a stated PSNR (jpeg), resumable
builds, a bounded size and LRU, and corruption that gives one clear error, never a wrong image. Also the trilinear
anti-aliasing's PSNR ordering against the plain warp. Real generated H.264 clips and real files; no mocks."""

from __future__ import annotations

import json
import math
import os
import shutil
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from viva_sitl.camera import CameraParams, LazyPyramid, Renderer
from viva_sitl.cli_footage import footage_main
from viva_sitl.config import SimConfig
from viva_sitl.footage import FootageError, open_footage
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.footage.ingest import ingest_tiles
from viva_sitl.footage.testclip import write_coded_clip
from viva_sitl.footage.tiles import (
    COMMIT_FRAMES,
    INDEX_DTYPE,
    INDEX_DTYPE_V1,
    YUVZ_COARSE_MIN_PSNR_DB,
    TileCache,
    TileSettings,
    TileSource,
    _decode,
    _encode,
    build_tiles,
    process_settings,
    set_process_settings,
    tile_checksum,
)
from viva_sitl.sim import Simulator

W, H = 1280, 720
ALT_M, HFOV = 100.0, 82.1
FRAMES = 6
# jpeg quality 95 (4:4:4) tiles vs the decoded video: asserted bound on the VAC render's PSNR (measured 49.3 dB here,
# bench/results_tiles.md gives the bench clip's figure)
JPEG_MIN_PSNR_DB = 45.0


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("tiles")
    path = write_coded_clip(d / "coded.mp4", frames=FRAMES, width_px=W, height_px=H, fps=25, gop=4, bframes=2)
    path.with_suffix(".toml").write_text(
        f'name = "coded"\nkind = "video"\npath = "{path.name}"\nrecording_altitude_m = {ALT_M}\n'
        f"hfov_deg = {HFOV}\n",
        encoding="utf-8",
    )
    return path


@pytest.fixture(scope="module")
def caches(clip: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("caches")
    out = {}
    for codec in ("png", "raw", "jpeg", "yuv420z", "yuv420zg"):
        res = ingest_tiles(
            str(clip.with_suffix(".toml")), out_dir=d / codec, codec=codec, show_progress=False
        )
        assert res.frames == FRAMES and res.disk_bytes > 0 and res.resumed_from == 0
        out[codec] = res.folder
    return out


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0**2 / mse)


def _poses() -> list[tuple[tuple[float, float, float], tuple[float, float, float]]]:
    rng = np.random.default_rng(3)
    out = []
    for _ in range(14):
        z = float(rng.uniform(8.0, 140.0))
        pos = (float(rng.uniform(-60, 60)), float(rng.uniform(-90, 90)), -z)
        att = (float(rng.uniform(-0.4, 0.4)), float(rng.uniform(-0.4, 0.4)), float(rng.uniform(-3.1, 3.1)))
        out.append((pos, att))
    for z in (10.0, 40.0, 90.0, 200.0, 900.0):  # levels 0..6, straight down
        out.append(((0.0, 0.0, -z), (0.0, 0.0, 0.3)))
    out.append(((0.0, 0.0, -30.0), (0.0, 1.3, 0.0)))  # horizon in view: whole-frame fallback
    out.append(((400.0, 0.0, -20.0), (0.0, 0.0, 0.0)))  # off the footage
    return out


def _compare(clip: Path, folder: Path, camera: CameraParams) -> tuple[float, set[int], Simulator]:
    """Worst PSNR of tile-cache renders vs whole-frame renders of the video, over the poses and frames."""
    tiled = Simulator(SimConfig(camera=camera), footage=str(folder))
    plain = Simulator(
        SimConfig(camera=camera),
        footage=open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV),
        region_render=False,
    )
    assert isinstance(tiled.footage, TileSource)
    worst, levels = math.inf, set()
    try:
        for k, (pos, att) in enumerate(_poses()):
            for sim in (tiled, plain):
                sim.reset(seed=k, pos_ned_m=pos, yaw_rad=att[2])
            s = replace(tiled.state, att_rpy_rad=np.array(att), time_s=0.04 * (k % FRAMES))
            a, b = tiled.render(s, wall_time_s=1.0), plain.render(s, wall_time_s=1.0)
            assert a.meta == replace(b.meta, frame_counter=a.meta.frame_counter)
            worst = min(worst, _psnr(a.image_bgr, b.image_bgr))
            if tiled._region is not None and tiled._region.filled_level >= 0:
                levels |= tiled._region.filled_levels
        return worst, levels, tiled
    finally:
        tiled.close()
        plain.close()


@pytest.mark.parametrize("codec", ["png", "raw"])
def test_lossless_tiles_render_bit_identical_to_the_video(
    clip: Path, caches: dict[str, Path], codec: str
) -> None:
    cam = CameraParams(width_px=200, height_px=150, hfov_deg=HFOV)
    worst, levels, sim = _compare(clip, caches[codec], cam)
    assert worst == math.inf  # every pixel equal
    assert {0, 1, 2, 3} <= levels  # region renders from several levels (and blended pairs)
    assert sim.region_renders >= 15 and sim.full_renders >= 1


def test_jpeg_tiles_render_within_the_stated_psnr(clip: Path, caches: dict[str, Path]) -> None:
    cam = CameraParams(width_px=200, height_px=150, hfov_deg=HFOV)
    worst, _, _ = _compare(clip, caches["jpeg"], cam)
    print(f"jpeg q95 tiles: worst render PSNR {worst:.1f} dB vs the video")
    assert worst >= JPEG_MIN_PSNR_DB


def test_yuv420z_tiles_render_within_the_stated_psnr_and_decode_each_level(
    clip: Path, caches: dict[str, Path]
) -> None:
    """The automatic cache's codec: level 0 as zstd YUV 4:2:0, coarser levels as jpeg 4:4:4; every level's tiles
    decode to the right size and the renders (levels 0..3 and blends) stay within the jpeg bound."""
    cam = CameraParams(width_px=200, height_px=150, hfov_deg=HFOV)
    worst, levels, _ = _compare(clip, caches["yuv420z"], cam)
    print(f"yuv420z tiles: worst render PSNR {worst:.1f} dB vs the video")
    assert worst >= JPEG_MIN_PSNR_DB
    assert {0, 1, 2, 3} <= levels
    video = open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV)
    tiled = open_footage(str(caches["yuv420z"]))
    try:
        assert isinstance(tiled, TileSource) and tiled.cache.codec == "yuv420z"
        # level 0 alone (the 4:2:0 part) against the decoded video frame: the frame came from 4:2:0 H.264
        for i in (0, FRAMES - 1):
            assert _psnr(tiled.frame(i), video.frame(i)) >= JPEG_MIN_PSNR_DB
        # odd level sizes (1280x720 -> ... 5x3 -> 3x2 -> 2x1 -> 1x1) round-trip through the padding
        for level in range(tiled.level_count):
            w, h = tiled.level_size_px(level) or (0, 0)
            assert tiled.frame(1, level).shape == (h, w, 3)
    finally:
        video.close()
        tiled.close()


def test_yuv420zg_holds_yuv420z_pixels_in_fewer_bytes(clip: Path, caches: dict[str, Path]) -> None:
    """--cache-compact's codec: level 0's tiles gradient-coded (their own magic), every level's pixels (BGR and the
    renderer's BGRA) and the renders bit-identical to yuv420z's, level 0 in fewer bytes; levels >= 1 the same bytes.
    A plane buffer whose int32 prefix sums could overflow is stored as yuv420z's, with the same pixels."""
    from viva_sitl.footage.tiles.format import YUVG_MAX_PLANE_BYTES

    z, zg = open_footage(str(caches["yuv420z"])), open_footage(str(caches["yuv420zg"]))
    assert isinstance(z, TileSource) and isinstance(zg, TileSource) and zg.cache.codec == "yuv420zg"
    try:
        lay = zg.cache.layout
        sizes = {0: [0, 0], 1: [0, 0]}
        for f in range(FRAMES):  # the stored bytes (read before any decode: the LRU holds no tile yet)
            for lv in (0, 1):
                for ty in range(lay.grid[lv][1]):
                    for tx in range(lay.grid[lv][0]):
                        a, b = z.cache._read(f, lv, tx, ty), zg.cache._read(f, lv, tx, ty)
                        assert isinstance(a, bytes) and isinstance(b, bytes)
                        assert b[:4] == (b"Y4G1" if lv == 0 else a[:4]) and (lv == 0 or a == b)
                        sizes[lv][0] += len(a)
                        sizes[lv][1] += len(b)
        for f in range(FRAMES):
            for lv in range(zg.level_count):
                lw, lh = lay.levels[lv]
                assert np.array_equal(zg.region(f, lv, 0, 0, lw, lh), z.region(f, lv, 0, 0, lw, lh)), (f, lv)
        out = np.zeros((301 - 50, 400 - 16, 4), np.uint8)
        assert np.array_equal(
            zg.region(2, 0, 16, 50, 400, 301, out=out), z.region(2, 0, 16, 50, 400, 301, out=out.copy())
        )
        print(f"level 0: yuv420z {sizes[0][0]} bytes, yuv420zg {sizes[0][1]}")
        assert sizes[0][1] < 0.9 * sizes[0][0] and sizes[1][1] == sizes[1][0]
    finally:
        z.close()
        zg.close()
    cam = CameraParams(width_px=200, height_px=150, hfov_deg=HFOV)
    sims = [Simulator(SimConfig(camera=cam), footage=str(caches[c])) for c in ("yuv420z", "yuv420zg")]
    try:
        for k, (pos, att) in enumerate(_poses()):
            imgs = []
            for sim in sims:
                sim.reset(seed=k, pos_ned_m=pos, yaw_rad=att[2])
                s = replace(sim.state, att_rpy_rad=np.array(att), time_s=0.04 * (k % FRAMES))
                imgs.append(sim.render(s, wall_time_s=1.0).image_bgr)
            assert np.array_equal(*imgs), k
    finally:
        for sim in sims:
            sim.close()
    side = 2400  # 2400 x 3600 plane bytes > YUVG_MAX_PLANE_BYTES
    assert side * side * 3 // 2 > YUVG_MAX_PLANE_BYTES
    (frame0,) = _frames(clip, 1)
    big = np.ascontiguousarray(cv2.resize(frame0, (side, side)))
    data = _encode(big, "yuv420zg", 95, 0)
    assert data[:4] == b"Y4Z1"
    assert np.array_equal(
        _decode(data, "yuv420zg", bgra=True), _decode(_encode(big, "yuv420z", 95, 0), "yuv420z", bgra=True)
    )


def test_yuv420z_regions_into_bgra_equal_the_bgr_pixels_whichever_the_lru_holds(
    caches: dict[str, Path],
) -> None:
    """The renderer's paste asks for BGRA: yuv420z's zstd tiles are then decoded straight to BGRA (one YUV -> BGRA
    pass). The pixels equal the BGR decode's exactly, alpha 255, whether the tile was decoded for this request
    (LRU of 1 byte), or is served from the LRU decoded for the other channel count (BGR first, then BGRA, and the
    reverse); `tile()` gives BGR either way."""
    box = (1, 0, 16, 50, 400, 301)  # frame, level, x0, y0, x1, y1: level 0 (zstd 4:2:0), several tiles
    outputs: dict[str, list[np.ndarray]] = {}
    for name, cap, order in (("fresh", 1, ("bgr", "bgra")), ("bgr first", 1 << 28, ("bgr", "bgra")),
                             ("bgra first", 1 << 28, ("bgra", "bgr"))):  # fmt: skip
        src = open_footage(str(caches["yuv420z"]))
        assert isinstance(src, TileSource)
        src.cache.cache_bytes = cap
        try:
            got = {}
            for kind in order:
                f, lv, x0, y0, x1, y1 = box
                out = np.zeros((y1 - y0, x1 - x0, 4 if kind == "bgra" else 3), np.uint8)
                got[kind] = src.region(f, lv, x0, y0, x1, y1, out=out).copy()
            assert np.all(got["bgra"][..., 3] == 255), name
            assert np.array_equal(got["bgra"][..., :3], got["bgr"]), name
            assert src.cache.tile(1, 0, 0, 0).shape[2] == 3
            outputs[name] = [got["bgr"], got["bgra"]]
        finally:
            src.close()
    assert all(np.array_equal(a, b) for a, b in zip(outputs["fresh"], outputs["bgra first"], strict=True))
    # the zstd path was the one taken (level 0 of yuv420z is always zstd 4:2:0)
    assert _decode(_encode(np.zeros((16, 16, 3), np.uint8), "yuv420z", 95, 0), "yuv420z", bgra=True).shape == (
        16, 16, 4)  # fmt: skip


# a view's footprint in level-0 pixels (yawed: its bounding box holds tiles the quad filter leaves out)
_QUAD = np.array([[300.0, 120.0], [760.0, 250.0], [640.0, 610.0], [180.0, 480.0]])
_BOX = (150, 100, 790, 630)  # level 0: x0, y0, x1, y1 around it


def _ahead_region(cache: TileCache, frame: int) -> np.ndarray:
    x0, y0, x1, y1 = _BOX
    out = np.zeros((y1 - y0, x1 - x0, 4), np.uint8)
    return cache.region(frame, 0, x0, y0, x1, y1, out, _QUAD, 4.0).copy()


def _worker_done(cache: TileCache) -> None:
    """Wait for the read-ahead the last region started (if any) to finish."""
    if cache._worker_job is not None:
        cache._worker_job.result(timeout=60)


@pytest.mark.parametrize("codec", ["yuv420z", "yuv420zg"])
def test_read_ahead_decodes_the_next_frame_while_the_caller_works_and_changes_no_pixel(
    caches: dict[str, Path], codec: str
) -> None:
    """Regions read frame after frame (a flight over a clip) have the next frame's tiles decoded on the decode
    worker in between: once the sequence is steady (two equal steps), every tile of the next region comes from it,
    and the pixels are those of a cache read without read-ahead, frame by frame, through the clip's wrap to frame 0,
    and after a seek backwards (the job for the frame that did not come is dropped)."""
    ahead = TileCache(caches[codec], TileSettings(cache_bytes=1, decode_threads=2))
    plain = TileCache(caches[codec], TileSettings(cache_bytes=1, decode_threads=2, read_ahead=False))
    try:
        n_tiles = len(ahead.tiles_under(0, *_BOX, _QUAD, 4.0))
        assert 0 < n_tiles < len(ahead.tiles_under(0, *_BOX))
        frames = [*range(FRAMES), 0, 1, 4, 5]  # in sequence through the wrap, then a seek (1 -> 4), then on
        for k, frame in enumerate(frames):
            before = ahead.tiles_ahead
            got = _ahead_region(ahead, frame)
            assert np.array_equal(got, _ahead_region(plain, frame)), (codec, k, frame)
            # from the 4th read of a steady sequence on (and not right after the seek): all from the read-ahead
            from_ahead = ahead.tiles_ahead - before
            if 3 <= k <= 7:
                assert from_ahead == n_tiles, (k, frame, from_ahead)
            elif k in (0, 1, 2, 8):
                assert from_ahead == 0, (k, frame, from_ahead)
            _worker_done(ahead)  # the caller's "rest of the step" outlasts the worker's decode here
        assert plain.ahead_jobs == 0 and plain.tiles_ahead == 0
        assert ahead.ahead_jobs >= 6
        # a seek drops the job: 4 came after 1 (the job was for 2); the step 3 then planned nothing
        assert ahead._seq[0] == (5, 1)
    finally:
        ahead.close()
        plain.close()


def test_read_ahead_that_runs_late_pauses_and_a_bad_tile_still_fails_its_own_region(
    caches: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A worker that has not decoded half the tiles by the time the region comes (no core for it) ran late; a window
    of AHEAD_WINDOW jobs mostly late (after the first, the warm-up) pauses read-ahead for AHEAD_PAUSE_FRAMES regions,
    the next pause with no good window before it twice as long. The region decodes the rest itself, never wrong pixels. A tile whose bytes are damaged fails the region of its frame with the cache's one-line error,
    whether or not a worker read it ahead."""
    from viva_sitl.footage.tiles import read as tile_read

    real = tile_read.TileCache._work_ahead

    def idle_worker(self: TileCache, job: tile_read._ReadAhead) -> None:
        if threading.current_thread() is threading.main_thread():
            real(self, job)  # the region's own share
            return
        while job.todo:  # the worker gets no core: it waits until the region has taken its queue
            time.sleep(0.001)

    monkeypatch.setattr(tile_read.TileCache, "_work_ahead", idle_worker)
    monkeypatch.setattr(tile_read, "AHEAD_WINDOW", 4)
    monkeypatch.setattr(tile_read, "AHEAD_PAUSE_FRAMES", 4)
    cache = TileCache(caches["yuv420z"], TileSettings(cache_bytes=1, decode_threads=2))
    plain = TileCache(caches["yuv420z"], TileSettings(cache_bytes=1, decode_threads=1))
    try:
        jobs = []
        for k in range(19):
            frame = k % FRAMES
            assert np.array_equal(_ahead_region(cache, frame), _ahead_region(plain, frame)), k
            jobs.append(cache.ahead_jobs)  # (no wait for the worker: it waits for the next region)
        # a job after each read from the 3rd on; the first window of 4 (warm-up) is not judged, the second, all
        # late, pauses them for 4 reads; then 4 more late ones, and a pause of 8
        assert jobs == [0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 8, 8, 8, 8, 9, 10, 11, 12, 12], jobs
        assert cache._ahead_paused[0] == 8 - 1 and cache._ahead_backoff[0] == 2
        # a worker with a core again: after the pause, jobs in time, and the next pause would be the first's length
        monkeypatch.setattr(tile_read.TileCache, "_work_ahead", real)
        for k in range(19, 33):
            frame = k % FRAMES
            assert np.array_equal(_ahead_region(cache, frame), _ahead_region(plain, frame)), k
            _worker_done(cache)
        assert cache.ahead_jobs > 12 and cache._ahead_backoff[0] == 0 and cache._ahead_paused[0] == 0
    finally:
        cache.close()
        plain.close()
    monkeypatch.undo()
    # a damaged tile of frame 3, read ahead by a working worker: frame 3's region fails, in one line
    bad = _copy(caches["yuv420z"], tmp_path / "bad")
    victim = TileCache(bad)
    t = victim.layout.tile_index(0, *victim.tiles_under(0, *_BOX, _QUAD, 4.0)[0])
    pack, _length, offset, _check = victim.index[3 * victim.layout.tiles_per_frame + t].item()[:4]
    victim.close()
    with open(bad / "tiles" / f"pack-{pack:03d}.bin", "r+b") as f:
        f.seek(offset + 9)
        byte = f.read(1)
        f.seek(offset + 9)
        f.write(bytes([byte[0] ^ 0xFF]))
    cache = TileCache(bad, TileSettings(cache_bytes=1, decode_threads=2))
    try:
        for frame in range(3):
            _ahead_region(cache, frame)
            _worker_done(cache)
        assert cache.ahead_jobs == 1  # frame 3's tiles were read ahead
        with pytest.raises(FootageError, match=r"frame 3 level 0 tile .*checksum mismatch") as err:
            _ahead_region(cache, 3)
        assert "\n" not in str(err.value)
    finally:
        cache.close()


def test_yuv420z_level_1_tiles_are_4_2_0_only_where_that_keeps_the_bound() -> None:
    """Level 0 is always zstd 4:2:0; a level-1 tile is zstd 4:2:0 when its round trip keeps the bound (smooth
    chroma, as in video), jpeg 4:4:4 when 4:2:0 would blur sharp colour edges; level 2 is jpeg; all decode back."""
    yy, xx = np.mgrid[0:256, 0:256]
    smooth = np.dstack([(xx + yy) // 2, 128 + (xx - yy) // 4, 255 - yy]).astype(np.uint8)
    sharp = np.zeros((256, 256, 3), np.uint8)
    sharp[(xx + yy) % 2 == 0] = (0, 0, 255)  # one-pixel red/blue checkerboard: 4:2:0 averages it to purple
    sharp[(xx + yy) % 2 == 1] = (255, 0, 0)
    kinds = {}
    for name, tile, level in (("l0 sharp", sharp, 0), ("l1 smooth", smooth, 1), ("l1 sharp", sharp, 1),
                              ("l2 smooth", smooth, 2)):  # fmt: skip
        data = _encode(tile, "yuv420z", 95, level)
        kinds[name] = "zstd" if data[:4] == b"Y4Z1" else "jpeg" if data[:2] == b"\xff\xd8" else "?"
        back = _decode(data, "yuv420z")
        assert back is not None and back.shape == tile.shape
        if name != "l0 sharp":
            assert _psnr(back, tile) >= YUVZ_COARSE_MIN_PSNR_DB - 1.0, name
    assert kinds == {"l0 sharp": "zstd", "l1 smooth": "zstd", "l1 sharp": "jpeg", "l2 smooth": "jpeg"}


def test_tile_source_frames_equal_the_video_and_the_lru_is_capped(
    clip: Path, caches: dict[str, Path]
) -> None:
    video = open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV)
    src = open_footage(str(caches["raw"]))
    try:
        assert isinstance(src, TileSource)
        assert src.frame_count == video.frame_count == FRAMES and src.fps == video.fps
        assert src.geometry == video.geometry
        for i in range(FRAMES):
            assert np.array_equal(src.frame(i), video.frame(i))
            lazy = LazyPyramid(np.ascontiguousarray(video.frame(i)))
            assert np.array_equal(src.frame(i, level=3), lazy.level(3))
            assert np.array_equal(src.region(i, 1, 100, 50, 333, 301), lazy.level(1)[50:301, 100:333])
            # into a BGRA buffer (what the simulator's region render asks for): the same pixels, alpha 255
            bgra = np.zeros((301 - 50, 333 - 100, 4), np.uint8)
            assert src.region(i, 1, 100, 50, 333, 301, out=bgra) is bgra
            assert np.array_equal(bgra[..., :3], lazy.level(1)[50:301, 100:333]) and np.all(
                bgra[..., 3] == 255
            )
        with pytest.raises(ValueError, match="BGR or BGRA"):
            src.region(0, 1, 100, 50, 333, 301, out=np.zeros((10, 10, 4), np.uint8))
        assert src.cache.lru_bytes <= src.cache.cache_bytes
    finally:
        src.close()
        video.close()
    small = TileSource(src.metadata, caches["raw"], lambda w, h: video.geometry, cache_bytes=1 << 20)
    try:
        for i in range(FRAMES):
            small.frame(i)
            assert small.cache.lru_bytes <= 1 << 20
        assert small.cache.tiles_decoded > 0
    finally:
        small.close()


def _refused_in_one_line(
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    var: str,
    bad: tuple[str, ...],
    folder: Path,
) -> None:
    """`viva-sitl footage info` (the top floor, which reads the variables) with each bad value of $var is one error
    line naming the variable, exit status 2."""
    capsys.readouterr()
    for value in bad:
        monkeypatch.setenv(var, value)
        assert footage_main(["info", str(folder)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"${var}={value!r}: give " in err[0], err
    monkeypatch.delenv(var)


@pytest.fixture
def process_tiles() -> Iterator[None]:
    """The process's tile settings as they were after the test (the top floor sets them)."""
    before = process_settings()
    yield
    set_process_settings(before)


def _top_floor() -> None:
    """What an entry point does: the documented variables, read once, are the process's tile settings."""
    set_process_settings(TileSettings.from_environ(os.environ))


def test_tile_cache_size_from_the_environment(
    caches: dict[str, Path],
    monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
    process_tiles: None,
) -> None:
    """$VIVA_SITL_TILE_CACHE_MB, read by the top floor, caps the decoded-tile LRU of every source opened after it
    (trial workers get it as an argument), $VIVA_SITL_TILE_DECODE_THREADS sets its decode threads; a bad value is
    one error line naming the variable. `open_footage` itself reads no environment."""
    monkeypatch.setenv("VIVA_SITL_TILE_CACHE_MB", "0.5")
    src = open_footage(str(caches["raw"]))
    try:  # not read by the footage layer
        assert isinstance(src, TileSource) and src.cache.cache_bytes == process_settings().cache_bytes
    finally:
        src.close()
    _top_floor()
    src = open_footage(str(caches["raw"]))
    try:
        assert isinstance(src, TileSource)
        assert src.cache.cache_bytes == 1 << 19
        for i in range(FRAMES):
            src.frame(i)  # whole frames: far more than 0.5 MiB of tiles
            assert src.cache.lru_bytes <= 1 << 19 or len(src.cache._lru) == 1
        decoded = src.cache.tiles_decoded
        src.frame(0)  # evicted long ago: decoded again
        assert src.cache.tiles_decoded > decoded
    finally:
        src.close()
    _refused_in_one_line(
        monkeypatch, capsys, "VIVA_SITL_TILE_CACHE_MB", ("0", "-3", "lots", "nan"), caches["raw"]
    )
    # decode threads (the trials' pool sets 1 per worker when the workers fill the cores): same frames either way
    _top_floor()
    pooled = open_footage(str(caches["jpeg"]))
    try:
        assert isinstance(pooled, TileSource) and pooled.cache._pool is not None  # default: 2 threads
        monkeypatch.setenv("VIVA_SITL_TILE_DECODE_THREADS", "1")
        _top_floor()
        one = open_footage(str(caches["jpeg"]))
        try:
            assert isinstance(one, TileSource) and one.cache._pool is None
            for i in range(FRAMES):
                assert np.array_equal(one.frame(i), pooled.frame(i))
        finally:
            one.close()
    finally:
        pooled.close()
    _refused_in_one_line(
        monkeypatch, capsys, "VIVA_SITL_TILE_DECODE_THREADS", ("0", "two", "-1", "1.5"), caches["jpeg"]
    )


def _frames(clip: Path, n: int, fail_after: int | None = None) -> Iterator[np.ndarray]:
    with open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV) as v:
        for i in range(n):
            if fail_after is not None and i == fail_after:
                raise KeyboardInterrupt  # as a Ctrl-C / kill between frames
            yield np.ascontiguousarray(v.frame(i))


def test_an_interrupted_build_resumes_and_ends_byte_identical(clip: Path, tmp_path: Path) -> None:
    args = dict(frame_count=FRAMES, width_px=W, height_px=H, fps=25.0, codec="jpeg", show_progress=False)
    fresh = build_tiles(_frames(clip, FRAMES), folder=tmp_path / "fresh", **args)  # type: ignore[arg-type]
    with pytest.raises(KeyboardInterrupt):
        build_tiles(_frames(clip, FRAMES, fail_after=5), folder=tmp_path / "cut", **args)  # type: ignore[arg-type]
    tdir = tmp_path / "cut" / "tiles"
    assert json.loads((tdir / "progress.json").read_text())["frames_done"] == COMMIT_FRAMES
    with open(tdir / "pack-000.bin", "ab") as f:
        f.write(b"half a tile written when the process died")
    with pytest.raises(FootageError, match="unfinished build"):
        TileSource(
            fresh_meta(clip), tmp_path / "cut", lambda w, h: FootageGeometry.from_fov(w, h, ALT_M, HFOV)
        )
    res = build_tiles(_frames(clip, FRAMES), folder=tmp_path / "cut", **args)  # type: ignore[arg-type]
    assert res.resumed_from == COMMIT_FRAMES and res.disk_bytes == fresh.disk_bytes
    for name in ("index.bin", "pack-000.bin"):
        assert (tdir / name).read_bytes() == (tmp_path / "fresh" / "tiles" / name).read_bytes()


def test_a_level_0_tile_size_of_its_own_reads_the_same_pixels(
    clip: Path, caches: dict[str, Path], tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """128 px tiles at level 0 and 256 px above (the automatic yuv420z cache's layout): format 3, the level-0 grid
    of 128 px tiles, and every level's pixels equal the uniform 256 px cache's (raw: both lossless; yuv420z: the
    4:2:0 blocks do not straddle a tile edge either way). A reader that knows only formats 1 and 2 refuses it in
    one line instead of misreading level 0."""
    from viva_sitl.footage.tiles import FORMATS
    from viva_sitl.footage.tiles import format as tile_format

    for codec in ("raw", "yuv420z"):
        folder = tmp_path / codec
        args = dict(frame_count=FRAMES, width_px=W, height_px=H, fps=25.0, codec=codec, show_progress=False)
        build_tiles(_frames(clip, FRAMES), folder=folder, tile_px=256, level0_tile_px=128, **args)  # type: ignore[arg-type]
        meta = json.loads((folder / "tiles" / "meta.json").read_text())
        assert meta["version"] == 3 and meta["tile_px"] == 256 and meta["tile_px_level0"] == 128
        mixed = TileSource(fresh_meta(clip), folder, lambda w, h: FootageGeometry.from_fov(w, h, ALT_M, HFOV))
        uniform = open_footage(str(caches[codec]))
        assert isinstance(uniform, TileSource)
        try:
            lay = mixed.cache.layout
            assert lay.grid[0] == (10, 6) and lay.grid[1] == uniform.cache.layout.grid[1] == (3, 2)
            assert (lay.tile_size(0), lay.tile_size(1)) == (128, 256)
            assert uniform.cache.layout.grid[0] == (5, 3)
            assert "(128 px at level 0)" in mixed.describe()["tile_cache"]
            for f in range(FRAMES):
                for lv in (0, 1, 2):
                    lw, lh = lay.levels[lv]
                    a = mixed.region(f, lv, 0, 0, lw, lh)
                    b = uniform.region(f, lv, 0, 0, lw, lh)
                    assert np.array_equal(a, b), (codec, f, lv)
            # a footprint's box at level 0 reads the 128 px tiles under it, into BGRA as the renderer asks
            out = np.zeros((301 - 50, 400 - 16, 4), np.uint8)
            got = mixed.region(1, 0, 16, 50, 400, 301, out=out)
            assert np.array_equal(got[..., :3], uniform.region(1, 0, 16, 50, 400, 301))
            assert mixed.cache.tiles_under(0, 16, 50, 400, 301) == [
                (x, y) for y in (0, 1, 2) for x in (0, 1, 2, 3)
            ]
        finally:
            mixed.close()
            uniform.close()
        monkeypatch.setattr(tile_format, "FORMATS", {k: v for k, v in FORMATS.items() if k <= 2})
        monkeypatch.setattr(sys.modules["viva_sitl.footage.tiles.read"], "FORMATS", tile_format.FORMATS)
        with pytest.raises(FootageError, match="unknown format") as exc:
            TileSource(fresh_meta(clip), folder, lambda w, h: FootageGeometry.from_fov(w, h, ALT_M, HFOV))
        assert "\n" not in str(exc.value)
        monkeypatch.undo()


def fresh_meta(clip: Path):  # type: ignore[no-untyped-def]
    from viva_sitl.footage import resolve_metadata

    return resolve_metadata(str(clip.with_suffix(".toml")))


def test_cli_builds_reports_size_and_refuses_beyond_the_bound(
    clip: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    toml = str(clip.with_suffix(".toml"))
    out = tmp_path / "t"
    rc = footage_main(["ingest", toml, "--tiles", "-o", str(out), "--max-frames", "2", "--no-progress"])
    assert rc == 0 and "tiled 2 frames into" in capsys.readouterr().out
    with open_footage(str(out)) as src:
        assert isinstance(src, TileSource) and src.frame_count == 2
    rc = footage_main(
        ["ingest", toml, "--tiles", "--out", str(tmp_path / "p"), "--tile-codec", "png", "--max-size", "0.5",
         "--no-progress"]
    )  # fmt: skip
    err = capsys.readouterr().err.strip()
    assert rc == 2 and len(err.splitlines()) == 1 and "--max-size" in err
    # jpeg: a bound below q95's size but above q50's picks a lower quality
    q95 = ingest_tiles(toml, out_dir=tmp_path / "q", max_frames=2, show_progress=False)
    res = ingest_tiles(
        toml, out_dir=tmp_path / "b", max_frames=2, show_progress=False, max_bytes=int(q95.disk_bytes * 0.7)
    )
    assert res.quality < 95 and res.disk_bytes <= q95.disk_bytes * 0.7


def _copy(src: Path, dst: Path) -> Path:
    shutil.copytree(src, dst)
    return dst


def test_corrupt_caches_give_one_clear_error_never_a_wrong_image(
    caches: dict[str, Path], tmp_path: Path
) -> None:
    base = caches["jpeg"]

    def fails(folder: Path, match: str, render: bool = False) -> None:
        with pytest.raises(FootageError, match=match) as e:
            sim = Simulator(SimConfig(camera=CameraParams(width_px=160, height_px=120)), footage=str(folder))
            try:
                for z in (15.0, 40.0, 90.0, 300.0):
                    for t in range(FRAMES):
                        sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -z))
                        sim.render(replace(sim.state, time_s=0.04 * t))
                sim.footage.frame(0)
            finally:
                sim.close()
        msg = str(e.value)
        assert "\n" not in msg and "footage ingest --tiles" in msg

    # truncated pack file
    d = _copy(base, tmp_path / "trunc")
    pack = d / "tiles" / "pack-000.bin"
    pack.write_bytes(pack.read_bytes()[: pack.stat().st_size // 2])
    fails(d, "truncated")
    # missing pack
    d = _copy(base, tmp_path / "nopack")
    (d / "tiles" / "pack-000.bin").unlink()
    fails(d, "missing")
    # one tile's bytes changed (same length): its checksum
    d = _copy(base, tmp_path / "flip")
    data = bytearray(pack.read_bytes() if False else (d / "tiles" / "pack-000.bin").read_bytes())
    for off in range(1000, len(data), 997):
        data[off] ^= 0x55
    (d / "tiles" / "pack-000.bin").write_bytes(bytes(data))
    fails(d, "checksum")
    # the same in a raw cache (192 KiB tiles, no decoder to notice): one byte changed, or a 4 KiB page zeroed
    for name, change in (("rawflip", "flip"), ("rawzero", "zero")):
        d = _copy(caches["raw"], tmp_path / name)
        data = bytearray((d / "tiles" / "pack-000.bin").read_bytes())
        rec = np.fromfile(d / "tiles" / "index.bin", INDEX_DTYPE)[3]  # a level-0 tile of frame 0
        start = int(rec["offset"]) + int(rec["length"]) // 3
        if change == "flip":
            data[start] ^= 0x01
        else:
            data[start : start + 4096] = bytes(4096)
        (d / "tiles" / "pack-000.bin").write_bytes(bytes(data))
        fails(d, "checksum")
    # a level missing: meta.json lists one level fewer
    d = _copy(base, tmp_path / "level")
    meta = json.loads((d / "tiles" / "meta.json").read_text())
    meta["levels"] = meta["levels"][:-1]
    (d / "tiles" / "meta.json").write_text(json.dumps(meta))
    fails(d, "levels")
    # a level's tiles missing from the index
    d = _copy(base, tmp_path / "holes")
    idx = np.fromfile(d / "tiles" / "index.bin", np.uint8)
    idx[24 * 40 : 24 * 60] = 0
    idx.tofile(d / "tiles" / "index.bin")
    fails(d, "missing tiles")
    # index of the wrong size
    d = _copy(base, tmp_path / "index")
    (d / "tiles" / "index.bin").write_bytes((d / "tiles" / "index.bin").read_bytes()[:-7])
    fails(d, "index.bin")
    # meta.json garbage
    d = _copy(base, tmp_path / "meta")
    (d / "tiles" / "meta.json").write_text("{not json")
    fails(d, "meta.json")


# --- trilinear anti-aliasing -------------------------------------------------------------------------------------


def _texture(h: int, w: int, seed: int) -> np.ndarray:
    """Detail at every scale: sums of random-phase gratings plus noise."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.zeros((h, w, 3), np.float32)
    for period in (3.0, 5.0, 9.0, 17.0, 40.0, 110.0):
        for c in range(3):
            a = rng.uniform(0, math.pi)
            img[..., c] += np.sin(
                (x * math.cos(a) + y * math.sin(a)) * 2 * math.pi / period + rng.uniform(0, 6)
            )
    img = 128 + 18 * img + rng.normal(0, 10, img.shape)
    return np.clip(img, 0, 255).astype(np.uint8)


def test_trilinear_beats_the_plain_warp_at_every_footprint_ratio() -> None:
    img = _texture(1080, 1920, seed=4)
    geom = FootageGeometry.from_fov(1920, 1080, 200.0, HFOV)
    cam = CameraParams(width_px=160, height_px=120, hfov_deg=HFOV)
    tri, mip, plain = (
        Renderer(cam, geom),
        Renderer(replace(cam, trilinear=False), geom),
        Renderer(replace(cam, antialias=False), geom),
    )
    pyr = LazyPyramid(img)
    rows = []
    for z in np.geomspace(25.0, 190.0, 12):  # 1.5 to 11 footage px per VAC px
        pos, att = (3.0, -4.0, -float(z)), (0.02, -0.03, 0.4)
        a = tri.render(pyr, pos, att)
        k = 8  # reference: 8x8 supersampled warp, area-averaged
        t = np.array([[k, 0, (k - 1) / 2], [0, k, (k - 1) / 2], [0, 0, 1]], np.float64)
        big = cv2.warpPerspective(
            img, t @ a.homography, (cam.width_px * k, cam.height_px * k), flags=cv2.INTER_LINEAR
        )
        ref = cv2.resize(big, (cam.width_px, cam.height_px), interpolation=cv2.INTER_AREA)
        p_tri = _psnr(a.image_bgr, ref)
        p_mip = _psnr(mip.render(pyr, pos, att).image_bgr, ref)
        p_plain = _psnr(plain.render(img, pos, att).image_bgr, ref)
        rows.append((a.footage_px_per_vac_px, p_tri, p_mip, p_plain))
    for rho, p_tri, _, p_plain in rows:
        assert p_tri >= p_plain, (rho, p_tri, p_plain)
    assert float(np.mean([r[1] - r[2] for r in rows])) > 0.5  # and better than one mip level on average


@pytest.mark.slow  # kills and reruns an ingest process
def test_a_killed_ingest_process_resumes_on_rerun(tmp_path: Path) -> None:
    """`viva-sitl footage ingest --tiles` SIGKILLed mid-way: the rerun continues after the last committed frame and
    ends with the same cache as an uninterrupted build."""
    import os
    import signal
    import subprocess
    import sys
    import time

    frames = 24
    clip = write_coded_clip(
        tmp_path / "k.mp4", frames=frames, width_px=W, height_px=H, fps=25, gop=4, bframes=0
    )
    toml = clip.with_suffix(".toml")
    toml.write_text(
        f'name = "k"\nkind = "video"\npath = "{clip.name}"\nrecording_altitude_m = {ALT_M}\nhfov_deg = {HFOV}\n',
        encoding="utf-8",
    )
    repo = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": str(repo)}

    def cmd(out: Path) -> list[str]:
        return [sys.executable, "-m", "viva_sitl", "footage", "ingest", str(toml), "--tiles", "--tile-codec", "png",
                "--out", str(out), "--no-progress"]  # fmt: skip

    out = tmp_path / "killed"
    proc = subprocess.Popen(cmd(out), env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    progress = out / "tiles" / "progress.json"
    deadline = time.monotonic() + 120.0
    done = 0
    while time.monotonic() < deadline and proc.poll() is None:
        try:
            done = int(json.loads(progress.read_text())["frames_done"])
        except (OSError, ValueError, KeyError):
            done = 0
        if done >= 2 * COMMIT_FRAMES:
            break
        time.sleep(0.01)  # polling a file the other process writes (the condition is checked above)
    assert proc.poll() is None, "the build ended before it could be killed"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    assert 0 < done < frames and not (out / "footage.toml").exists()
    with pytest.raises(FootageError, match="folder without footage.toml|not an ingest cache"):
        open_footage(str(out))
    r = subprocess.run(cmd(out), env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    assert f"tiled {frames} frames" in r.stdout and "resumed after frame" in r.stdout
    fresh = subprocess.run(cmd(tmp_path / "fresh"), env=env, capture_output=True, text=True, timeout=300)
    assert fresh.returncode == 0, fresh.stderr
    for name in ("index.bin", "pack-000.bin"):
        assert (out / "tiles" / name).read_bytes() == (tmp_path / "fresh" / "tiles" / name).read_bytes()
    with open_footage(str(out)) as src, open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV) as video:
        assert isinstance(src, TileSource)
        for i in (0, done, frames - 1):
            assert np.array_equal(src.frame(i), video.frame(i))


def _tiles_under_numpy(ts: int, x0: int, y0: int, x1: int, y1: int, quad: np.ndarray, margin: float) -> list:
    """The general (vectorised) separating-axis selection, as tiles_under computed it before its per-tile loop."""
    mx, my = np.meshgrid(np.arange(x0 // ts, (x1 - 1) // ts + 1), np.arange(y0 // ts, (y1 - 1) // ts + 1))
    gx, gy = mx.ravel().astype(np.int64), my.ravel().astype(np.int64)
    rx0, ry0 = gx * ts - margin, gy * ts - margin
    rx1, ry1 = (gx + 1) * ts - 1 + margin, (gy + 1) * ts - 1 + margin
    keep = np.ones(gx.shape, bool)
    centre = quad.mean(axis=0)
    for i in range(len(quad)):
        e = quad[(i + 1) % len(quad)] - quad[i]
        n = np.array([e[1], -e[0]])
        if np.dot(n, centre - quad[i]) > 0:
            n = -n
        lo = np.where(n[0] > 0, rx0, rx1) * n[0] + np.where(n[1] > 0, ry0, ry1) * n[1]
        keep &= lo <= float(np.max(quad @ n)) + 1e-9
    return [(int(x), int(y)) for x, y in zip(gx[keep], gy[keep], strict=True)]


def test_tiles_under_equals_the_vectorised_selection() -> None:
    """tiles_under tests each tile in plain floats (few tiles per call): the same tiles, in the same order, as the
    vectorised separating-axis test, over random footprints (rotated, sheared, touching tile edges)."""
    from types import SimpleNamespace

    from viva_sitl.footage.tiles import TileCache, TileLayout

    rng = np.random.default_rng(5)
    ts = 256
    cache = SimpleNamespace(layout=TileLayout.of(4096, 4096, ts))
    dropped = 0
    for k in range(300):
        c = rng.uniform(0, 3000, 2)
        quad = (
            c + rng.uniform(-400, 400, (4, 2))
            if k % 3
            else c + np.array([[0, 0], [512, 0], [512, 256], [0, 256]])
        )
        hull = cv2.convexHull(quad.astype(np.float32)).reshape(-1, 2).astype(np.float64)
        if k % 3 == 0:
            hull = quad.astype(np.float64)  # axis-aligned, edges on tile boundaries
        x0, y0 = (max(0, int(v) - 40) for v in hull.min(axis=0))
        x1, y1 = (int(v) + 41 for v in hull.max(axis=0))
        margin = float(rng.choice([0.0, 1.5, 9.0]))
        got = TileCache.tiles_under(cache, 0, x0, y0, x1, y1, hull, margin)  # type: ignore[arg-type]
        assert got == _tiles_under_numpy(ts, x0, y0, x1, y1, hull, margin)
        dropped += len(got) < len(TileCache.tiles_under(cache, 0, x0, y0, x1, y1))  # type: ignore[arg-type]
    assert dropped > 100  # the footprint test did exclude tiles of the bounding box
    assert TileCache.tiles_under(cache, 0, 0, 0, 600, 300) == [(x, y) for y in (0, 1) for x in (0, 1, 2)]  # type: ignore[arg-type]


def test_tile_checksum_sees_every_single_byte_change_and_truncation() -> None:
    rng = np.random.default_rng(5)
    for n in (0, 1, 7, 8, 9, 8 + 4 + 256 * 256 * 3, 1003):
        data = bytearray(rng.integers(0, 256, n, dtype=np.uint8).tobytes())
        base = tile_checksum(bytes(data))
        assert base == tile_checksum(memoryview(bytes(data)))
        if n:
            assert tile_checksum(bytes(data[:-1])) != base
        for pos in rng.integers(0, max(n, 1), min(n, 40)):
            for flip in (0x01, 0x80, 0xFF):
                data[pos] ^= flip
                assert tile_checksum(bytes(data)) != base, (n, pos, flip)
                data[pos] ^= flip


def test_format_1_caches_with_crc32_stay_readable_and_checked(
    caches: dict[str, Path], tmp_path: Path
) -> None:
    """A cache written before the 64-bit sum (format 1: CRC-32 in a 4-byte field) renders the same pixels, and a
    changed byte in it is still a checksum error."""
    import zlib

    def to_v1(folder: Path) -> None:
        tdir = folder / "tiles"
        idx = np.fromfile(tdir / "index.bin", INDEX_DTYPE)
        packs = {int(k): (tdir / f"pack-{int(k):03d}.bin").read_bytes() for k in np.unique(idx["pack"])}
        v1 = np.zeros(len(idx), INDEX_DTYPE_V1)
        for name in ("pack", "length", "offset"):
            v1[name] = idx[name]
        for i, r in enumerate(idx):
            blob = packs[int(r["pack"])][int(r["offset"]) : int(r["offset"]) + int(r["length"])]
            v1["check"][i] = zlib.crc32(blob)
        v1.tofile(tdir / "index.bin")
        meta = json.loads((tdir / "meta.json").read_text())
        meta["version"] = 1
        (tdir / "meta.json").write_text(json.dumps(meta))

    old = _copy(caches["raw"], tmp_path / "v1")
    to_v1(old)
    cam = CameraParams(width_px=160, height_px=120)
    sims = [Simulator(SimConfig(camera=cam), footage=str(f)) for f in (caches["raw"], old)]
    try:
        for sim in sims:
            sim.reset(seed=0, pos_ned_m=(3.0, -2.0, -40.0))
        for t in range(FRAMES):
            a, b = (sim.render(replace(sim.state, time_s=0.04 * t)).image_bgr for sim in sims)
            assert np.array_equal(a, b)
    finally:
        for sim in sims:
            sim.close()
    pack = old / "tiles" / "pack-000.bin"
    data = bytearray(pack.read_bytes())
    rec = np.fromfile(old / "tiles" / "index.bin", INDEX_DTYPE_V1)[3]  # a level-0 tile of frame 0
    data[int(rec["offset"]) + int(rec["length"]) // 3] ^= 0x10
    pack.write_bytes(bytes(data))
    src = open_footage(str(old))
    try:
        with pytest.raises(FootageError, match="checksum"):
            for k in range(FRAMES):
                src.frame(k)
    finally:
        src.close()


ODD_FOOTAGE = {
    # name: (file, width, height, codec, pixel format, frames): coded clips (testclip); the still is random pixels
    "odd-size-444": ("odd.mp4", 333, 221, "libx264", "yuv444p", 5),
    "10-bit": ("ten.mp4", 320, 240, "libx264", "yuv420p10le", 5),
    "vp9": ("vp9.webm", 320, 240, "libvpx-vp9", "yuv420p", 5),
    "portrait": ("tall.mp4", 240, 320, "libx264", "yuv420p", 5),
    "one-frame": ("one.mp4", 320, 240, "libx264", "yuv420p", 1),
    "still": ("still.png", 401, 299, "", "", 1),
}


@pytest.mark.parametrize("kind", list(ODD_FOOTAGE))
def test_footage_of_other_formats_gives_the_same_gym_images_over_its_raw_tile_cache(
    kind: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Footage a user brings (odd sizes, 4:4:4, 10-bit, VP9, portrait, one frame, a still) flies in the gym env and
    ingests into a tile cache; a seeded episode over the raw cache shows exactly the video's images."""
    from viva_sitl.gym import LandingEnv

    name, w, h, codec, pix_fmt, frames = ODD_FOOTAGE[kind]
    if kind == "still":
        path = tmp_path / name
        cv2.imwrite(str(path), np.random.default_rng(7).integers(0, 256, (h, w, 3), dtype=np.uint8))
    else:
        import av

        try:
            path = write_coded_clip(tmp_path / name, frames, w, h, fps=25, codec=codec, pix_fmt=pix_fmt)
        except (av.FFmpegError, ValueError) as exc:
            pytest.skip(f"PyAV here cannot write {codec}/{pix_fmt}: {exc}")
    assert footage_main(["ingest", str(path), "--tiles", "--tile-codec", "raw", "-o", str(tmp_path / "t"),
                         "--no-progress"]) == 0  # fmt: skip
    assert "tiled" in capsys.readouterr().out
    runs = []
    for footage in (str(path), str(tmp_path / "t")):
        env = LandingEnv(footage, image_size=(64, 48), max_episode_s=5.0)
        try:
            obs, _ = env.reset(seed=5)
            images = [obs["image"]]
            for _ in range(12):
                obs, *_ = env.step(np.array([0.3, -0.2, 0.4, -0.5], np.float32))
                images.append(obs["image"])
        finally:
            env.close()
        runs.append(np.stack(images))
    video, tiles = runs
    assert video.std() > 10.0  # the footage's pattern, not a blank fill
    assert np.array_equal(video, tiles)
