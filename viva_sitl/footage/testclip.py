"""Generated clips whose frames carry their own index (a 16-bit bar code): for tests, benchmarks and demos."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
from numpy.typing import NDArray

CODE_BITS = 16


def coded_frame(index: int, width_px: int, height_px: int) -> NDArray[np.uint8]:
    """BGR frame: a moving gradient with a 16-bit bar code of `index` across the top eighth."""
    yy, xx = np.mgrid[0:height_px, 0:width_px]
    base = ((xx + 3 * index) % 256).astype(np.uint8)
    img = cv2.merge([base, ((yy + index) % 256).astype(np.uint8), np.full_like(base, 96)])
    bar_h = max(8, height_px // 8)
    for b in range(CODE_BITS):
        x0, x1 = b * width_px // CODE_BITS, (b + 1) * width_px // CODE_BITS
        img[:bar_h, x0:x1] = 255 if (index >> b) & 1 else 0
    return img


def read_code(img: NDArray[np.uint8]) -> int:
    """The index coded in a (decoded, possibly lossy) frame made by `coded_frame`."""
    h, w = img.shape[:2]
    bar_h = max(8, h // 8)
    value = 0
    for b in range(CODE_BITS):
        x0, x1 = b * w // CODE_BITS, (b + 1) * w // CODE_BITS
        block = img[bar_h // 4 : 3 * bar_h // 4, x0 + (x1 - x0) // 4 : x1 - (x1 - x0) // 4]
        if float(block.mean()) > 128.0:
            value |= 1 << b
    return value


def write_coded_clip(
    path: Path,
    frames: int,
    width_px: int = 320,
    height_px: int = 240,
    fps: int = 30,
    gop: int = 10,
    bframes: int = 2,
    codec: str = "libx264",
    pix_fmt: str = "yuv420p",
) -> Path:
    """H.264 clip of `frames` coded frames (keyframe every `gop`, with B-frames to exercise reordering).

    `codec`, `pix_fmt`: another of PyAV's encoders or pixel formats (e.g. "libvpx-vp9", "yuv444p", "yuv420p10le"):
    the footage formats a user may bring; `gop` and `bframes` apply to libx264 only."""
    with av.open(str(path), mode="w") as out:
        st = out.add_stream(codec, rate=fps)
        if not isinstance(st, av.video.stream.VideoStream):
            raise ValueError(f"{codec!r} is not a video encoder")
        st.width, st.height, st.pix_fmt = width_px, height_px, pix_fmt
        st.codec_context.time_base = Fraction(1, fps)
        if codec == "libx264":
            st.options = {"preset": "ultrafast", "g": str(gop), "bf": str(bframes), "crf": "20"}
        for i in range(frames):
            f = av.VideoFrame.from_ndarray(coded_frame(i, width_px, height_px), format="bgr24")
            f.pts = i
            for pkt in st.encode(f):
                out.mux(pkt)
        for pkt in st.encode(None):
            out.mux(pkt)
    return path
