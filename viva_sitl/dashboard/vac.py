"""The VAC panel's feed: a video output of the app's VideoPipeline that JPEG-encodes frames for the pages.

`VacOutput.write` runs on its own pipeline worker thread (bounded queue, oldest frame dropped and counted by the
pipeline, as every video output), never on the asyncio loop. It encodes only while a page watches; the JPEG is then
handed to the loop, where each page has a one-frame slot (latest frame wins: a frame replaced before it was sent to a
slow page is counted in `page_drops`).

Wire format (one binary WebSocket message per frame): 4-byte little-endian header length N, N bytes of JSON
({"frame_counter", "sim_time_s", "wall_time_s", "footage_frame_index", "encoded_wall_s"}), then the JPEG.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import struct
import threading
import time
from collections.abc import Callable

import cv2

from viva_sitl.frame import RenderedFrame

Publish = Callable[[bytes, int], None]  # (message, frame_counter) on the asyncio loop


def pack_vac_message(jpeg: bytes, header: dict[str, object]) -> bytes:
    head = json.dumps(header, separators=(",", ":")).encode()
    return struct.pack("<I", len(head)) + head + jpeg


def unpack_vac_message(data: bytes) -> tuple[dict[str, object], bytes]:
    """The inverse of pack_vac_message (tests, bench). Raises ValueError on a short or corrupt message."""
    if len(data) < 4:
        raise ValueError("VAC message shorter than its header length")
    (n,) = struct.unpack_from("<I", data)
    if 4 + n > len(data):
        raise ValueError("VAC message header longer than the message")
    return dict(json.loads(data[4 : 4 + n])), data[4 + n :]


class VacOutput:
    """A `viva_sitl.video.VideoOutput` for the dashboard (name "dashboard")."""

    name = "dashboard"

    def __init__(self, quality: int = 80) -> None:
        self.quality = int(quality)
        self._loop: asyncio.AbstractEventLoop | None = None
        self._publish: Publish | None = None
        self._lock = threading.Lock()
        self.watchers = 0  # pages with an open VAC socket (set on the loop, read on the worker thread)
        self.encoded = 0
        self.skipped_unwatched = 0
        self.encode_errors = 0
        self.encode_ms_last = 0.0
        self.last_meta: dict[str, object] | None = None

    def attach(self, loop: asyncio.AbstractEventLoop, publish: Publish) -> None:
        with self._lock:
            self._loop, self._publish = loop, publish

    def detach(self) -> None:
        with self._lock:
            self._loop, self._publish = None, None

    # --- VideoOutput --------------------------------------------------------------------------
    def open(self) -> None:
        pass

    def close(self) -> None:
        self.detach()

    def write(self, frame: RenderedFrame) -> None:
        if self.watchers <= 0:
            self.skipped_unwatched += 1
            return
        t0 = time.perf_counter()
        ok, buf = cv2.imencode(".jpg", frame.image_bgr, [cv2.IMWRITE_JPEG_QUALITY, self.quality])
        if not ok:
            self.encode_errors += 1
            return
        self.encode_ms_last = (time.perf_counter() - t0) * 1e3
        m = frame.meta
        header: dict[str, object] = {
            "frame_counter": m.frame_counter,
            "sim_time_s": m.sim_time_s,
            "wall_time_s": m.wall_time_s,
            "footage_frame_index": m.footage_frame_index,
            "encoded_wall_s": time.time(),
            "width_px": m.width_px,
            "height_px": m.height_px,
        }
        msg = pack_vac_message(buf.tobytes(), header)
        self.encoded += 1
        self.last_meta = header
        with self._lock:
            loop, publish = self._loop, self._publish
        if loop is None or publish is None:
            return
        with contextlib.suppress(RuntimeError):  # the loop closed under us (shutdown): nobody to deliver to
            loop.call_soon_threadsafe(publish, msg, m.frame_counter)
