"""Overview images from 8K footage: the server crops and scales, the browser never gets an 8K picture."""

from __future__ import annotations

import asyncio
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from viva_sitl.camera.projection import footprint_px
from viva_sitl.dashboard.overview import CropRequest, OverviewImages
from viva_sitl.footage import open_footage

W8K, H8K = 7680, 4320


@pytest.fixture(scope="module")
def video_8k(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Two 8K H.264 frames of a pattern with fine detail everywhere (a crop's content is checkable)."""
    path = tmp_path_factory.mktemp("8k") / "field_8k.mp4"
    yy, xx = np.mgrid[0:H8K, 0:W8K]
    img = np.empty((H8K, W8K, 3), np.uint8)
    img[..., 0] = ((xx // 64 + yy // 64) % 2 * 160 + 40).astype(np.uint8)
    img[..., 1] = (yy * 255 // H8K).astype(np.uint8)
    img[..., 2] = (xx * 255 // W8K).astype(np.uint8)
    with av.open(str(path), "w") as out:
        st = out.add_stream("libx264", rate=Fraction(10, 1))
        st.width, st.height, st.pix_fmt = W8K, H8K, "yuv420p"
        st.options = {"preset": "ultrafast", "crf": "12"}
        for i in range(2):
            frame = av.VideoFrame.from_ndarray(img, format="bgr24")
            frame.pts = i
            for pkt in st.encode(frame):
                out.mux(pkt)
        for pkt in st.encode():
            out.mux(pkt)
    return path


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    """PSNR of the luma (JPEG keeps luma; its 4:2:0 chroma blurs this saturated test pattern)."""
    a = cv2.cvtColor(a, cv2.COLOR_BGR2GRAY)
    b = cv2.cvtColor(b, cv2.COLOR_BGR2GRAY)
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return 99.0 if mse == 0 else 10 * np.log10(255.0**2 / mse)


def test_8k_full_view_and_zoomed_crop_are_small_and_right(video_8k: Path) -> None:
    src = open_footage(str(video_8k), altitude_m=100.0, hfov_deg=80.0)
    try:
        own = open_footage(str(video_8k), altitude_m=100.0, hfov_deg=80.0)  # its own decoder, as in the app
        images = OverviewImages(own, src.geometry)
        full_req = CropRequest.parse({"w": "1024", "h": "1024"}, W8K, H8K, 2048)
        zoom_req = CropRequest.parse(
            {"x0": "3000", "y0": "2000", "x1": "3400", "y1": "2225", "w": "800", "h": "450"}, W8K, H8K, 2048
        )

        async def get() -> tuple[bytes, bytes]:
            return await images.crop(0, full_req), await images.crop(0, zoom_req)

        full_jpg, zoom_jpg = asyncio.run(get())
        images.close()
        own.close()
        full = cv2.imdecode(np.frombuffer(full_jpg, np.uint8), cv2.IMREAD_COLOR)
        zoom = cv2.imdecode(np.frombuffer(zoom_jpg, np.uint8), cv2.IMREAD_COLOR)
        assert full.shape == (576, 1024, 3)  # the 16:9 frame inside the 1024x1024 box asked for
        assert zoom.shape == (450, 800, 3)  # 2x magnified: 400x225 footage px
        assert len(full_jpg) < 1_000_000 and len(zoom_jpg) < 1_000_000
        ref = src.frame(0)
        ref_full = cv2.resize(ref, (1024, 576), interpolation=cv2.INTER_AREA)
        ref_zoom = cv2.resize(np.ascontiguousarray(ref[2000:2225, 3000:3400]), (800, 450))
        p_full, p_zoom = _psnr(full, ref_full), _psnr(zoom, ref_zoom)
        assert p_full > 30.0 and p_zoom > 30.0, (p_full, p_zoom)
        shifted = cv2.resize(np.ascontiguousarray(ref[2000:2225, 3064:3464]), (800, 450))
        assert _psnr(zoom, shifted) < p_zoom - 6.0  # the check can fail: a crop 64 px off is far worse
        with pytest.raises(ValueError, match="w and h"):
            CropRequest.parse({"w": "7680", "h": "4320"}, W8K, H8K, 2048)  # never an 8K picture
    finally:
        src.close()


def test_footprint_is_a_trapezoid_under_tilt_and_follows_the_vehicle() -> None:
    src = open_footage("synthetic")
    try:
        from viva_sitl.config import SimConfig

        cam = SimConfig().camera
        level = footprint_px(src.geometry, cam, (0.0, 0.0, -50.0), (0.0, 0.0, 0.0))
        tilted = footprint_px(src.geometry, cam, (0.0, 0.0, -50.0), (0.0, 0.3, 0.0))
        moved = footprint_px(src.geometry, cam, (20.0, 0.0, -50.0), (0.0, 0.0, 0.0))
        assert level is not None and tilted is not None and moved is not None

        def edges(p: list[list[float]]) -> list[float]:
            return [
                float(np.hypot(p[i][0] - p[(i + 1) % 4][0], p[i][1] - p[(i + 1) % 4][1])) for i in range(4)
            ]

        e_level, e_tilt = edges(level), edges(tilted)
        assert abs(e_level[0] - e_level[2]) < 1e-6  # a rectangle when level
        assert abs(e_tilt[0] - e_tilt[2]) > 0.05 * e_tilt[0]  # opposite edges differ under pitch: a trapezoid
        gsd = src.geometry.gsd_m_per_px
        dv = np.mean([p[1] for p in moved]) - np.mean([p[1] for p in level])
        assert abs(dv + 20.0 / gsd) < 1e-6  # 20 m north = 20/gsd pixels up (north-up footage)
        # pitched up past the horizon: unbounded, no polygon
        assert footprint_px(src.geometry, cam, (0.0, 0.0, -50.0), (0.0, 1.5, 0.0)) is None
    finally:
        src.close()


class _RiskLayer:
    name = "risk map"

    def features(self, time_s: float, footage_frame_index: int) -> list[dict[str, object]]:
        return [
            {
                "kind": "polygon",
                "points": [[0, 0], [100, 0], [100, 100]],
                "label": "high",
                "fill": "rgba(255,0,0,.3)",
            }
        ]


class _BrokenLayer:
    name = "broken"

    def features(self, time_s: float, footage_frame_index: int) -> list[dict[str, object]]:
        raise RuntimeError("provider bug")


def test_layer_providers_are_served_and_a_broken_one_does_not_break_the_hud() -> None:
    aiohttp = pytest.importorskip("aiohttp")
    from viva_sitl.app import SitlApp
    from viva_sitl.config import SimConfig
    from viva_sitl.dashboard import DashboardConfig

    app = SitlApp(SimConfig(), video=False, dashboard=DashboardConfig(port=0))
    assert app.dashboard is not None
    app.dashboard.add_layer(_RiskLayer())
    app.dashboard.add_layer(_BrokenLayer())

    async def run() -> tuple[dict[str, object], dict[str, object]]:
        await app.dashboard.start()
        try:
            async with aiohttp.ClientSession() as s:
                async with s.get(app.dashboard.url + "api/info") as r:
                    info = await r.json()
                async with s.get(app.dashboard.url + "api/state") as r:
                    state = await r.json()
            return info, state
        finally:
            await app.dashboard.stop()

    try:
        info, state = asyncio.run(run())
    finally:
        app.sim.close()
    assert info["layers"] == ["ground truth", "risk map", "broken"]
    layers = state["layers"]
    assert isinstance(layers, dict)
    assert layers["risk map"][0]["fill"] == "rgba(255,0,0,.3)"
    assert layers["broken"] == []
    assert len(layers["ground truth"]) > 0  # the synthetic field's markers, from the footage annotations
