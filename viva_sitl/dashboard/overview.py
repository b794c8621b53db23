"""The overview: where the vehicle, its camera footprint, home and the mission lie on the footage, and the footage
image itself, cropped and scaled on the server so an 8K frame never travels whole to the browser.

Coordinates sent to the page are footage pixels (u right, v down, pixel centres at integers, as FootageGeometry).

`OverviewImages` owns its OWN footage source (the render thread's decoder is not shared: a source belongs to one
thread) and one worker thread; a request names the footage-pixel rectangle and the output size, and gets a JPEG of
the current footage frame's crop at that size, read from the smallest ingest-cache copy that still has the pixels
needed. Results are cached per (frame, rect, size); at most one crop is made at a time.
"""

from __future__ import annotations

import asyncio
import math
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, Protocol

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.footage import FootageGeometry, FootageSource, VideoSource, open_footage


class LayerProvider(Protocol):
    """A toggleable overview layer (ground-truth objects, risk map; viva_sitl/world provides them).

    `features(time_s, footage_frame_index)` returns drawable features in footage pixels, each a dict:
    {"kind": "box"|"polygon"|"point", "points": [[u, v], ...], "label": str, "color": "#rrggbb" (optional),
    "fill": CSS colour with alpha, e.g. "rgba(255,0,0,0.3)" (polygons, optional: a risk map's cells)}.
    A polygon may carry "holes": [[[u, v], ...], ...] (drawn even-odd). A provider with a true `static` attribute
    (features independent of time) is asked once per page, in /api/info, instead of in every telemetry message.
    Register one with `Dashboard.add_layer(provider)` (before or after start); the page shows a toggle per layer.
    Called on the asyncio loop at the telemetry rate: it must be cheap (precompute; never block).
    """

    name: str

    def features(self, time_s: float, footage_frame_index: int) -> list[dict[str, Any]]: ...


class AnnotationLayer:
    """Ground truth from the footage's own annotations (the synthetic field's markers, MOT/YOLO boxes)."""

    name = "ground truth"

    def __init__(self, footage: FootageSource) -> None:
        self.footage = footage
        self._cache: tuple[int, list[dict[str, Any]]] | None = None

    def features(self, time_s: float, footage_frame_index: int) -> list[dict[str, Any]]:
        if self._cache is not None and self._cache[0] == footage_frame_index:
            return self._cache[1]
        out: list[dict[str, Any]] = []
        for a in self.footage.annotations(footage_frame_index)[:500]:
            x0, y0, x1, y1 = a.box_px
            out.append(
                {"kind": "box", "points": [[x0 - 0.5, y0 - 0.5], [x1 - 0.5, y1 - 0.5]], "label": a.label}
            )
        self._cache = (footage_frame_index, out)
        return out


def _finite_or_none(v: float) -> float | None:
    return v if math.isfinite(v) else None


@dataclass(frozen=True)
class CropRequest:
    x0: float
    y0: float
    x1: float
    y1: float
    width_px: int
    height_px: int

    @classmethod
    def parse(cls, query: dict[str, str], frame_w: int, frame_h: int, max_px: int) -> CropRequest:
        """From the query string; raises ValueError with a one-line reason. The rectangle is clipped to the frame."""
        try:
            x0, y0, x1, y1 = (float(query.get(k, d)) for k, d in
                              (("x0", "0"), ("y0", "0"), ("x1", str(frame_w)), ("y1", str(frame_h))))  # fmt: skip
            w, h = int(query.get("w", "640")), int(query.get("h", "360"))
        except ValueError:
            raise ValueError("x0, y0, x1, y1 must be numbers and w, h integers") from None
        if not all(math.isfinite(v) for v in (x0, y0, x1, y1)):
            raise ValueError("crop rectangle must be finite")
        if not (1 <= w <= max_px and 1 <= h <= max_px):
            raise ValueError(f"w and h must be in 1..{max_px}")
        x0, x1 = max(0.0, min(x0, x1)), min(float(frame_w), max(x0, x1))
        y0, y1 = max(0.0, min(y0, y1)), min(float(frame_h), max(y0, y1))
        if x1 - x0 < 1 or y1 - y0 < 1:
            raise ValueError("crop rectangle is outside the footage")
        return cls(x0, y0, x1, y1, w, h)


class OverviewImages:
    """Footage crops for the overview, made on one worker thread from a separate footage source."""

    def __init__(self, footage_spec: Any, geometry: FootageGeometry, quality: int = 80) -> None:
        self.footage_spec = footage_spec
        self.geometry = geometry
        self.quality = quality
        self._source: FootageSource | None = None
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="viva-dashboard-overview")
        self._lock = asyncio.Lock()
        self._cache: dict[tuple[Any, ...], bytes] = {}
        self._closed = threading.Event()
        self.crops_made = 0
        self.cache_hits = 0
        self.errors = 0

    def _open(self) -> FootageSource:
        if self._source is None:
            if isinstance(self.footage_spec, FootageSource):
                self._source = self.footage_spec
            else:
                self._source = open_footage(self.footage_spec)
        return self._source

    def _make(self, index: int, req: CropRequest) -> bytes:
        src = self._open()
        geom = self.geometry
        x0, y0 = int(math.floor(req.x0)), int(math.floor(req.y0))
        x1, y1 = int(math.ceil(req.x1)), int(math.ceil(req.y1))
        # scale: footage pixels per output pixel; use the deepest ingest copy that still has >= 1 px per output px
        scale = max((x1 - x0) / req.width_px, (y1 - y0) / req.height_px)
        img: NDArray[np.uint8]
        if isinstance(src, VideoSource):
            level = 0
            while level + 1 < src.level_count and (1 << (level + 1)) <= scale:
                level += 1
            if level > 0:
                full = src.frame(index, level=level)
                fh, fw = full.shape[:2]
                sx, sy = fw / geom.width_px, fh / geom.height_px
                img = full[int(y0 * sy) : max(int(y0 * sy) + 1, int(y1 * sy)),
                           int(x0 * sx) : max(int(x0 * sx) + 1, int(x1 * sx))]  # fmt: skip
            else:
                ex0, ey0 = x0 // 2 * 2, y0 // 2 * 2
                ex1 = min(geom.width_px, -(-x1 // 2) * 2)
                ey1 = min(geom.height_px, -(-y1 // 2) * 2)
                region = src.frame_region(index, ex0, ey0, ex1, ey1)
                if region is None:
                    region = src.frame(index)[ey0:ey1, ex0:ex1]
                img = region[y0 - ey0 : y1 - ey0, x0 - ex0 : x1 - ex0]
        else:
            img = src.frame(index)[y0:y1, x0:x1]
        # keep the aspect of the rectangle inside the requested box
        aspect = (x1 - x0) / max(1, y1 - y0)
        w = min(req.width_px, max(1, round(req.height_px * aspect)))
        h = min(req.height_px, max(1, round(w / aspect)))
        interp = cv2.INTER_AREA if img.shape[1] > w else cv2.INTER_LINEAR
        out = cv2.resize(np.ascontiguousarray(img), (w, h), interpolation=interp)
        ok, buf = cv2.imencode(".jpg", out, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        if not ok:
            raise ValueError("JPEG encoding failed")
        self.crops_made += 1
        return bytes(buf.tobytes())

    async def crop(self, index: int, req: CropRequest) -> bytes:
        key = (index, req)
        hit = self._cache.get(key)
        if hit is not None:
            self.cache_hits += 1
            return hit
        async with self._lock:  # one crop at a time: pages wait, the worker never queues up work
            hit = self._cache.get(key)
            if hit is not None:
                return hit
            loop = asyncio.get_running_loop()
            try:
                data = await loop.run_in_executor(self._pool, self._make, index, req)
            except Exception:
                self.errors += 1
                raise
            if len(self._cache) >= 16:
                self._cache.pop(next(iter(self._cache)))
            self._cache[key] = data
            return data

    def close(self) -> None:
        self._pool.shutdown(wait=True, cancel_futures=True)
        if self._source is not None and self._source is not self.footage_spec:
            self._source.close()
        self._source = None
