"""The Simulator's fast footage paths render exactly what the plain path renders (bit-identical, tolerance 0).

Plain path: the whole footage frame converted to BGR (`to_bgr`), its pyramid built by `LazyPyramid`, warped by the
renderer. Fast paths: `region_render` (convert only the region the VAC reads, build the pyramid level from it) and
`prefetch` (decode the next footage frame on a background thread). Real generated H.264 clips, no mocks.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import av
import numpy as np
import pytest

from viva_sitl.camera import CameraParams, LazyPyramid
from viva_sitl.camera.pyramid import RegionPyramid
from viva_sitl.config import SimConfig
from viva_sitl.dynamics import EavCommand, EavParams
from viva_sitl.footage import open_footage
from viva_sitl.footage.source import (
    SCRATCH_FRAME_AREAS,
    SCRATCH_FRAMES,
    SWSCALE_MAX_WIDTH_PX,
    VideoSource,
    crop_to_bgr,
    to_bgr,
)
from viva_sitl.footage.testclip import write_coded_clip
from viva_sitl.sim import Simulator

CLIP_W, CLIP_H = 1280, 720  # multiples of 16: levels 0-4 are exact halvings, level 5 (720 / 32) is not
ALT_M = 100.0
HFOV = 82.1


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("speed") / "coded.mp4"
    return write_coded_clip(path, frames=8, width_px=CLIP_W, height_px=CLIP_H, fps=25, gop=4, bframes=2)


def _sim(clip: Path, camera: CameraParams, region_render: bool = True) -> Simulator:
    footage = open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV)
    return Simulator(SimConfig(camera=camera), footage=footage, region_render=region_render)


def _random_i420(rng: np.random.Generator, w: int, h: int) -> av.VideoFrame:
    frame = av.VideoFrame(w, h, "yuv420p")
    for p in frame.planes:
        view = np.frombuffer(memoryview(p), np.uint8).reshape(p.height, p.line_size)[:, : p.width]
        view[...] = rng.integers(0, 256, view.shape, dtype=np.uint8)
    return frame


@pytest.mark.parametrize("width", [640, 1288, SWSCALE_MAX_WIDTH_PX + 64])  # swscale, odd /16 width, OpenCV
def test_crop_conversion_equals_crop_of_full_conversion(width: int) -> None:
    rng = np.random.default_rng(width)
    h = 36
    frame = _random_i420(rng, width, h)
    full = to_bgr(frame)
    scratch: list[av.VideoFrame] = []
    crops = [(0, 0, width, h), (2, 2, width - 2, h - 2), (width - 6, h - 4, width, h)]
    for _ in range(12):
        x0, x1 = sorted(2 * rng.choice(width // 2 + 1, 2, replace=False))
        y0, y1 = sorted(2 * rng.choice(h // 2 + 1, 2, replace=False))
        crops.append((int(x0), int(y0), int(x1), int(y1)))
    for x0, y0, x1, y1 in crops:
        got = crop_to_bgr(frame, x0, y0, x1, y1, scratch)
        assert got is not None
        assert np.array_equal(got, full[y0:y1, x0:x1]), (x0, y0, x1, y1)
    if width > SWSCALE_MAX_WIDTH_PX:
        assert scratch == []  # OpenCV path: no reusable frame
    else:  # swscale: reusable frames, one per crop size, bounded by one source frame's pixels (+ the newest)
        assert 1 <= len(scratch) <= SCRATCH_FRAMES
        assert sum(f.width * f.height for f in scratch[:-1]) <= SCRATCH_FRAME_AREAS * width * h
        n = len(scratch)
        again = crop_to_bgr(frame, *crops[-1], scratch)  # the same size again: reused, nothing added
        assert again is not None and np.array_equal(
            again, full[crops[-1][1] : crops[-1][3], crops[-1][0] : crops[-1][2]]
        )
        assert len(scratch) == n


def test_crop_conversion_refuses_odd_or_outside_crops_and_other_formats() -> None:
    frame = _random_i420(np.random.default_rng(0), 64, 32)
    for bad in [(1, 0, 10, 10), (0, 3, 10, 10), (0, 0, 11, 10), (0, 0, 66, 10), (10, 10, 10, 20)]:
        with pytest.raises(ValueError, match="crop"):
            crop_to_bgr(frame, *bad)
    yuv444 = av.VideoFrame(64, 32, "yuv444p")
    assert crop_to_bgr(yuv444, 0, 0, 8, 8) is None


def test_frame_region_equals_the_frame_and_keeps_decoding_sequential(clip: Path) -> None:
    src = open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV)
    assert isinstance(src, VideoSource)
    ref = open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV)
    try:
        assert src.frame_size_px == (CLIP_W, CLIP_H)
        for i in range(src.frame_count):
            region = src.frame_region(i, 100, 50, 422, 300)
            if i % 2 and i + 1 < src.frame_count:
                src.prefetch(i + 1)  # decoded ahead; a second request for frame i must not seek back
                again = src.frame_region(i, 0, 0, 64, 64)
                assert again is not None and np.array_equal(again, ref.frame(i)[:64, :64])
            assert region is not None and np.array_equal(region, ref.frame(i)[50:300, 100:422])
            big = src.frame_region(i, 0, 16, CLIP_W, CLIP_H)  # most of the frame: converted whole, then cut
            assert big is not None and np.array_equal(big, ref.frame(i)[16:])
            assert np.array_equal(src.frame(i), ref.frame(i))
        assert src.decoder_stats["seeks"] == 1  # the opening one only
    finally:
        src.close()
        ref.close()


def test_a_late_read_ahead_is_skipped_not_seeked(clip: Path) -> None:
    """The simulator's read-ahead (prefetch with only_next) decodes only the frame after the decoder's position or
    the loop's wrap to frame 0: a job that ran late, after the loop moved on, neither seeks back nor decodes past
    the frames the loop reads next. A plain prefetch(index) still decodes any frame."""
    src = open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV)
    assert isinstance(src, VideoSource)
    try:
        for i in range(5):
            src.frame(i)
        stats = dict(src.decoder_stats)
        src.prefetch(0, only_next=True)  # behind: a late job from the previous loop
        src.prefetch(7, only_next=True)  # ahead of the next frame: a late job as well
        assert src.decoder_stats == stats
        src.prefetch(5, only_next=True)  # the next frame: decoded ahead, no seek
        assert (
            src.decoder_stats["decoded"] == stats["decoded"] + 1
            and src.decoder_stats["seeks"] == stats["seeks"]
        )
        src.frame(5)
        src.frame(6)
        src.frame(7)
        seeks = src.decoder_stats["seeks"]
        src.prefetch(0, only_next=True)  # the wrap from the clip's last frame: seeks to the start
        assert src.decoder_stats["seeks"] == seeks + 1
        src.frame(7)  # still kept: no seek back
        src.frame(0)
        assert src.decoder_stats["seeks"] == seeks + 1
        decoded = src.decoder_stats["decoded"]
        src.prefetch(4)  # an explicit prefetch of any frame decodes it (here forward, 1..4)
        assert src.decoder_stats["decoded"] == decoded + 4
    finally:
        src.close()


@pytest.mark.parametrize("channels", [3, 4])
def test_region_pyramid_level_equals_lazy_pyramid_in_its_region(channels: int) -> None:
    """channels=4 (what the simulator keeps): a BGR region is converted to BGRA as it is pasted, at the level and
    at the next one, with the same B, G, R as the 3-channel pyramid and alpha 255."""
    rng = np.random.default_rng(5)
    img = rng.integers(0, 256, (72, 96, 3), dtype=np.uint8)
    lazy = LazyPyramid(img)
    rp = RegionPyramid(96, 72, channels=channels)
    assert len(rp) == len(lazy) and rp[0].shape == (72, 96, channels)
    for level, (x0, y0, x1, y1), blend in [
        (0, (2, 4, 40, 30), False),
        (1, (4, 8, 96, 72), False),
        (2, (8, 0, 48, 36), False),
        (3, (0, 0, 96, 72), False),
        (0, (4, 4, 40, 32), True),
        (1, (8, 8, 96, 72), True),
    ]:
        rp.fill(level, x0, y0, img[y0:y1, x0:x1], next_level=blend)
        for lv in (level, level + 1) if blend else (level,):
            s = 1 << lv
            got = rp[lv][y0 // s : (y1 + s - 1) // s, x0 // s : (x1 + s - 1) // s]
            want = lazy.level(lv)[y0 // s : (y1 + s - 1) // s, x0 // s : (x1 + s - 1) // s]
            assert np.array_equal(got[..., :3], want), (level, lv)
            if channels == 4:
                assert (got[..., 3] == 255).all()
        assert rp.filled_level == level and rp.region_px == (x0, y0, x1, y1)
    with pytest.raises(ValueError, match="channels"):
        RegionPyramid(96, 72, channels=channels).fill(0, 0, 0, img[:8, :8, :2])
    with pytest.raises(ValueError, match="aligned"):
        rp.fill(2, 2, 0, img[0:8, 2:10])
    with pytest.raises(ValueError, match="exact halving"):
        RegionPyramid(90, 72).fill(2, 0, 0, img[:8, :8])  # 90 is not a multiple of 4


def test_region_pyramid_gives_pages_back_on_a_long_flight(monkeypatch: pytest.MonkeyPatch) -> None:
    """Regions written far apart (a flight across a large frame) do not accumulate resident pages: once what was
    written spans RESET_REGIONS times the region, the level buffer is replaced; the region just written is right."""
    import viva_sitl.camera.pyramid as pyramid

    monkeypatch.setattr(pyramid, "RESET_MIN_PX", 0)  # the rule alone, at a test-sized frame
    rng = np.random.default_rng(2)
    img = rng.integers(0, 256, (512, 1024, 4), dtype=np.uint8)
    rp = RegionPyramid(1024, 512, channels=4)
    buffers: list[np.ndarray] = []  # kept alive, so distinct buffers have distinct ids
    spans = []
    for x0 in range(0, 1024 - 64, 32):  # a 64 x 64 region sliding right, 32 px per frame
        out = rp.level_buffer(0, x0, 200, x0 + 64, 264)
        out[...] = img[200:264, x0 : x0 + 64]
        rp.mark_filled(0)
        assert np.array_equal(rp[0][200:264, x0 : x0 + 64], img[200:264, x0 : x0 + 64])
        buffers.append(rp[0])
        x_lo, _, x_hi, _ = rp._written[0]
        spans.append(x_hi - x_lo)
    assert max(spans) * 64 <= pyramid.RESET_REGIONS * 64 * 64  # never more than the rule allows written
    assert len({id(b) for b in buffers}) > 1  # replaced along the way (30 frames over 16 region widths)


def _poses(
    rng: np.random.Generator, n: int
) -> list[tuple[tuple[float, float, float], tuple[float, float, float]]]:
    out = []
    for _ in range(n):
        z = float(rng.uniform(8.0, 140.0))
        pos = (float(rng.uniform(-70, 70)), float(rng.uniform(-100, 100)), -z)
        att = (
            float(rng.uniform(-0.5, 0.5)),
            float(rng.uniform(-0.5, 0.5)),
            float(rng.uniform(-math.pi, math.pi)),
        )
        out.append((pos, att))
    # fixed cases: straight down (levels 0..2, and 5: not exact, whole frame), horizon in view, off the footage
    for z in (10.0, 30.0, 60.0, 110.0, 450.0, 900.0):
        out.append(((0.0, 0.0, -z), (0.0, 0.0, 0.3)))
    out.append(((0.0, 0.0, -30.0), (0.0, 1.3, 0.0)))  # pitched 75 deg: sky in view, unbounded footprint
    out.append(((400.0, 0.0, -20.0), (0.0, 0.0, 0.0)))  # nothing below but fill
    return out


@pytest.mark.parametrize(
    "camera",
    [
        CameraParams(width_px=160, height_px=120, hfov_deg=HFOV),
        CameraParams(
            width_px=200, height_px=150, hfov_deg=70.0, noise_std=3.0, motion_blur=True, exposure_s=0.05
        ),
    ],
    ids=["plain_camera", "noise_and_blur"],
)
def test_region_render_is_bit_identical_to_the_whole_frame_render(clip: Path, camera: CameraParams) -> None:
    fast, plain = _sim(clip, camera), _sim(clip, camera, region_render=False)
    try:
        levels = set()
        rng = np.random.default_rng(11)
        for k, (pos, att) in enumerate(_poses(rng, 40)):
            for sim in (fast, plain):
                sim.reset(seed=k, pos_ned_m=pos, yaw_rad=att[2], vel_ned_m_s=(3.0, -2.0, 0.5))
            s = replace(fast.state, att_rpy_rad=np.array(att), time_s=0.04 * (k % 9))  # frames 0..8 (loops)
            a, b = fast.render(s, wall_time_s=1.0), plain.render(s, wall_time_s=1.0)
            assert np.array_equal(a.image_bgr, b.image_bgr), (k, pos, att)
            assert a.meta == replace(b.meta, frame_counter=a.meta.frame_counter)
            levels.add(fast._region.filled_level if fast._region is not None else None)
        assert {0, 1, 2} <= levels  # the region path served levels 0, 1 and 2
        assert fast.region_renders > 30 and fast.full_renders >= 2  # and fell back where it must
        assert plain.region_renders == 0
    finally:
        fast.close()
        plain.close()


def test_footage_frame_still_returns_the_whole_frame_after_region_renders(clip: Path) -> None:
    cam = CameraParams(width_px=160, height_px=120, hfov_deg=HFOV)
    with _sim(clip, cam) as sim, open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV) as ref:
        sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -20.0), yaw_rad=0.0)
        sim.render()
        index, pyramid = sim.footage_frame(sim.state.time_s)
        assert index == 0 and np.array_equal(pyramid.level(0), ref.frame(0))
        again = sim.render(wall_time_s=0.0)  # now served from the converted whole frame
        assert sim.full_renders == 1 and again.meta.footage_frame_index == 0


@pytest.mark.parametrize("region", [True, False])
def test_prefetch_gives_the_same_frames_in_a_stepped_run(clip: Path, region: bool) -> None:
    cam = CameraParams(width_px=160, height_px=120, hfov_deg=HFOV)
    params = EavParams.paper()  # 30 Hz steps over 25 fps footage: frames repeat and advance, then loop
    cfg = SimConfig(camera=cam, physics=params)

    def run(prefetch: bool) -> tuple[list[np.ndarray], list[int]]:
        footage = open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV)
        sim = Simulator(cfg, footage=footage, region_render=region, prefetch=prefetch)
        try:
            sim.reset(seed=1, pos_ned_m=(2.0, -3.0, -40.0), yaw_rad=0.4)
            cmd = EavCommand(0.05, -0.03, 0.4, params.hover_thrust_n * 1.01)
            images, indices = [], []
            for _ in range(24):
                sim.step(cmd)
                f = sim.render(wall_time_s=0.0)
                images.append(f.image_bgr)
                indices.append(f.meta.footage_frame_index)
            assert isinstance(sim.footage, VideoSource)
            assert sim.footage.decoder_stats["seeks"] <= 3  # opening + one per loop of the 8-frame clip
            return images, indices
        finally:
            sim.close()
            if prefetch:
                assert sim._prefetcher is None  # the thread was joined

    (im_a, idx_a), (im_b, idx_b) = run(True), run(False)
    assert idx_a == idx_b and len(set(idx_a)) == 8
    for a, b in zip(im_a, im_b, strict=True):
        assert np.array_equal(a, b)


def test_footage_levels_reads_the_half_resolution_copy_close_to_the_plain_render(
    clip: Path, tmp_path: Path
) -> None:
    """Opt-in and NOT bit-exact: the ingest cache's half-resolution video is a separate lossy encode."""
    from viva_sitl.footage.ingest import ingest

    meta = clip.with_name("coded_levels.toml")
    meta.write_text(
        f'name = "coded"\nkind = "video"\npath = "{clip.name}"\nrecording_altitude_m = {ALT_M}\n'
        f"hfov_deg = {HFOV}\n",
        encoding="utf-8",
    )
    folder = ingest(str(meta), out_dir=tmp_path / "ingest", levels=2, show_progress=False)
    cam = CameraParams(width_px=160, height_px=120, hfov_deg=HFOV, trilinear=False)  # one level per render
    cfg = SimConfig(camera=cam)
    fast = Simulator(cfg, footage=str(folder), footage_levels=True)
    plain = Simulator(cfg, footage=str(folder), region_render=False)
    try:
        assert isinstance(fast.footage, VideoSource) and fast.footage.level_count == 2
        for k, (z, want_level) in enumerate([(15.0, 0), (30.0, 1), (60.0, 2), (90.0, 2)]):
            for sim in (fast, plain):
                sim.reset(seed=0, pos_ned_m=(3.0, -5.0, -z), yaw_rad=0.3)
            s = replace(fast.state, time_s=0.04 * k)
            a, b = fast.render(s, wall_time_s=0.0), plain.render(s, wall_time_s=0.0)
            assert fast._region is not None and fast._region.filled_level == want_level
            if want_level == 0:
                assert np.array_equal(a.image_bgr, b.image_bgr) and fast._source_level_used == 0
            else:
                assert fast._source_level_used == 1  # decoded half.mp4, not the 4x larger full.mp4
                diff = a.image_bgr.astype(np.float64) - b.image_bgr
                psnr = 10 * math.log10(255.0**2 / max(float(np.mean(diff**2)), 1e-12))
                assert psnr > 30.0, (z, psnr)
                print(f"footage_levels z={z} level={want_level}: PSNR {psnr:.1f} dB vs the plain render")
    finally:
        fast.close()
        plain.close()
