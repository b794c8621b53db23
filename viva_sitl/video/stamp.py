"""A frame counter painted into the picture, readable after lossy coding (H.264, JPEG).

Layout (top-left corner, `cell_px` x `cell_px` cells in one row, black = 0, white = 1):
    cells 0-1: guard (white, black), cells 2-25: the 24-bit counter (MSB first), cells 26-33: an 8-bit check.
With the default 8 px cells the strip is 272 x 8 px and aligned to the 16 px macroblock grid of H.264/JPEG,
so it survives compression; `read_counter` returns None for a picture without a (readable) stamp.
Counters wrap at 2**24 (6.5 days at 30 fps).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

COUNTER_BITS = 24
CHECK_BITS = 8
GUARD = (1, 0)
N_CELLS = len(GUARD) + COUNTER_BITS + CHECK_BITS
DEFAULT_CELL_PX = 8


def _check(counter: int) -> int:
    b0, b1, b2 = (counter >> 16) & 0xFF, (counter >> 8) & 0xFF, counter & 0xFF
    return (b0 * 1 + b1 * 3 + b2 * 7 + 0x5A) & 0xFF


def _bits(counter: int) -> list[int]:
    c = counter % (1 << COUNTER_BITS)
    chk = _check(c)
    return (
        list(GUARD)
        + [(c >> (COUNTER_BITS - 1 - i)) & 1 for i in range(COUNTER_BITS)]
        + [(chk >> (CHECK_BITS - 1 - i)) & 1 for i in range(CHECK_BITS)]
    )


def strip_size_px(cell_px: int = DEFAULT_CELL_PX) -> tuple[int, int]:
    """(width, height) of the stamp in pixels."""
    return N_CELLS * cell_px, cell_px


def stamp_counter(image_bgr: NDArray[np.uint8], counter: int, cell_px: int = DEFAULT_CELL_PX) -> None:
    """Paint `counter` (mod 2**24) into the top-left corner of `image_bgr` in place."""
    if image_bgr.ndim != 3 or image_bgr.dtype != np.uint8:
        raise ValueError(
            f"stamp_counter needs an (H, W, C) uint8 image, got {image_bgr.shape} {image_bgr.dtype}"
        )
    if cell_px < 2:
        raise ValueError(f"cell_px must be >= 2, got {cell_px}")
    w, h = strip_size_px(cell_px)
    if image_bgr.shape[0] < h or image_bgr.shape[1] < w:
        raise ValueError(
            f"image {image_bgr.shape[1]}x{image_bgr.shape[0]} too small for a {w}x{h} counter stamp"
        )
    if counter < 0:
        raise ValueError(f"counter must be >= 0, got {counter}")
    row = np.repeat(np.array(_bits(counter), dtype=np.uint8) * 255, cell_px)
    image_bgr[:h, :w, :] = row[None, :, None]


def read_counter(image_bgr: NDArray[Any], cell_px: int = DEFAULT_CELL_PX) -> int | None:
    """The counter stamped by `stamp_counter`, or None when there is no valid stamp (guard or check mismatch)."""
    w, h = strip_size_px(cell_px)
    if image_bgr.ndim not in (2, 3) or image_bgr.shape[0] < h or image_bgr.shape[1] < w:
        return None
    strip = image_bgr[:h, :w].astype(np.float32)
    if strip.ndim == 3:
        strip = strip.mean(axis=2)
    m = cell_px // 4  # sample the centre of each cell: edges blur under compression
    cells = strip.reshape(h, N_CELLS, cell_px)[m : h - m, :, m : cell_px - m].mean(axis=(0, 2))
    bits = [int(v > 127.5) for v in cells]
    if tuple(bits[: len(GUARD)]) != GUARD:
        return None
    counter = 0
    for b in bits[len(GUARD) : len(GUARD) + COUNTER_BITS]:
        counter = (counter << 1) | b
    chk = 0
    for b in bits[len(GUARD) + COUNTER_BITS :]:
        chk = (chk << 1) | b
    return counter if chk == _check(counter) else None
