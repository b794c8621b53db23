"""Mip-map pyramids of a footage frame, full or built lazily down to the needed level.

Each level halves the previous one with cv2.resize(INTER_AREA) (a 2x2 box average; size ((w + 1) // 2, (h + 1) // 2)).
Why box and not cv2.pyrDown's Gaussian: against an area-averaged reference (what a real sensor integrates), over a
sweep of 2-7 footage px per VAC px, the box mip-map is as good or better on average and clearly better in the worst
case, and it builds about 2x faster (bench/bench_render.py, "Sweep" in bench/results_render.md).
Levels are edge-aligned with level 0: u_l + 0.5 = (u_0 + 0.5) * w_l / w_0 (see `level_from_source`).
"""

from __future__ import annotations

import threading
import time
from collections.abc import Sequence
from typing import overload

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.imaging import half_size, max_pyramid_level

U8 = NDArray[np.uint8]


def check_image(image_bgr: NDArray[np.generic]) -> None:
    if not isinstance(image_bgr, np.ndarray) or image_bgr.ndim not in (2, 3) or image_bgr.size == 0:
        raise ValueError("pyramid source must be a non-empty (h, w) or (h, w, c) array")
    if image_bgr.dtype != np.uint8:
        raise ValueError(f"pyramid source must be uint8, got {image_bgr.dtype}")


def level_from_source(src_w: int, src_h: int, level_w: int, level_h: int) -> NDArray[np.float64]:
    """3x3 mapping level-0 pixel coordinates to those of a level of size level_w x level_h (pixel edges aligned)."""
    sx, sy = level_w / src_w, level_h / src_h
    return np.array([[sx, 0.0, 0.5 * (sx - 1.0)], [0.0, sy, 0.5 * (sy - 1.0)], [0.0, 0.0, 1.0]])


def build_pyramid(image_bgr: U8, levels: int) -> list[U8]:
    """[level 0 (the image itself), level 1, ..., level `levels`] by repeated halving (clamped to the deepest)."""
    check_image(image_bgr)
    if levels < 0:
        raise ValueError(f"levels must be >= 0, got {levels}")
    levels = min(levels, max_pyramid_level(image_bgr.shape[1], image_bgr.shape[0]))
    out = [image_bgr]
    for _ in range(levels):
        out.append(half_size(out[-1]))
    return out


class LazyPyramid:
    """A pyramid that builds levels on first use and keeps them (one per footage frame, cached by the caller).

    `level(l)` is thread-safe; the level-0 array is the caller's image (not copied: do not modify it afterwards).
    """

    def __init__(self, image_bgr: U8) -> None:
        check_image(image_bgr)
        self._levels: list[U8] = [image_bgr]
        self._lock = threading.Lock()
        self.max_level = max_pyramid_level(image_bgr.shape[1], image_bgr.shape[0])
        self.build_s = 0.0  # time spent building levels so far (s), for benchmarks

    @property
    def width_px(self) -> int:
        return int(self._levels[0].shape[1])

    @property
    def height_px(self) -> int:
        return int(self._levels[0].shape[0])

    @property
    def built_levels(self) -> int:
        """Number of levels built so far (1 = only the source)."""
        return len(self._levels)

    def level(self, index: int) -> U8:
        """Image of level `index` (clamped to max_level), building the missing levels."""
        if index < 0:
            raise ValueError(f"pyramid level must be >= 0, got {index}")
        index = min(index, self.max_level)
        if index < len(self._levels):
            return self._levels[index]
        with self._lock:
            t0 = time.perf_counter()
            while len(self._levels) <= index:
                self._levels.append(half_size(self._levels[-1]))
            self.build_s += time.perf_counter() - t0
            return self._levels[index]

    def __len__(self) -> int:
        return self.max_level + 1


# a level buffer is replaced (its pages given back) once what was written into it spans more than this many times
# the region being written, and more than RESET_MIN_PX pixels (see RegionPyramid._buffer)
RESET_REGIONS = 6
RESET_MIN_PX = 1 << 22


class RegionPyramid(Sequence[U8]):
    """Full-size pyramid levels of one footage frame of which only one region of one level is filled in.

    For a renderer that is known to read only that region of that level (`viva_sitl.sim.Simulator` plans it from
    the VAC footprint): the level-0 frame then never has to be converted, nor its lower levels built, in full.
    It is a sequence of levels (`len`, `[l]`) as `Renderer.render` accepts. Level `filled_level` is a reused
    full-size buffer whose region holds exactly what `LazyPyramid(frame).level(filled_level)` holds there (the
    region is aligned to 2^level level-0 pixels and every halving is exact, so box averages of the region equal those
    of the whole frame); outside it, and at every other level, the content is unspecified (zero or stale): read
    `filled_level` and `region_px` before trusting a pixel.

    With trilinear anti-aliasing the renderer also reads level `filled_level + 1`: `fill(..., next_level=True)`
    fills its matching region too (`filled_levels` lists every level holding data). `fill_level` pastes pixels of
    one level directly (from a tile cache that stores every level, see `viva_sitl.footage.tiles`), with no
    exact-halving constraint.
    """

    def __init__(self, width_px: int, height_px: int, channels: int = 3) -> None:
        if width_px <= 0 or height_px <= 0 or channels <= 0:
            raise ValueError(f"region pyramid size must be positive, got {width_px}x{height_px}x{channels}")
        self.max_level = max_pyramid_level(width_px, height_px)
        self.channels = channels
        self.sizes_px: list[tuple[int, int]] = [(width_px, height_px)]
        for _ in range(self.max_level):
            w, h = self.sizes_px[-1]
            self.sizes_px.append(((w + 1) // 2, (h + 1) // 2))
        zero = np.zeros((1, 1, channels), np.uint8)
        # levels nobody filled: zero-strided stand-ins of the right shape (no memory; the renderer reads level 0's
        # shape even when it warps from another level)
        self._stubs: list[U8] = [np.broadcast_to(zero, (h, w, channels)) for w, h in self.sizes_px]
        self._buffers: dict[int, U8] = {}
        self._written: dict[int, tuple[int, int, int, int]] = {}  # level -> box written since allocated
        self.filled_level = -1
        self.filled_levels: set[int] = set()
        # level-0 x0, y0, x1, y1 of the filled region
        self.region_px: tuple[int, int, int, int] = (0, 0, 0, 0)
        self.key: object = None  # the caller's tag of what is filled (e.g. (frame index, level, region))

    @property
    def width_px(self) -> int:
        return self.sizes_px[0][0]

    @property
    def height_px(self) -> int:
        return self.sizes_px[0][1]

    def exact_level(self, level: int) -> bool:
        """True when `level` can be filled from a region (the frame's size is a multiple of 2^level)."""
        step = 1 << max(level, 0)
        return 0 <= level <= self.max_level and self.width_px % step == 0 and self.height_px % step == 0

    def clear(self) -> None:
        """Forget the filled region (every level reads as unspecified)."""
        self.filled_level, self.region_px, self.key = -1, (0, 0, 0, 0), None
        self.filled_levels = set()

    def _buffer(self, level: int, box: tuple[int, int, int, int]) -> U8:
        """Level `level`'s full-size buffer, about to be written over `box` (x0, y0, x1, y1 in level pixels).

        Allocated lazily (np.zeros: only the pages written become resident), and replaced by a fresh one once the
        bounding box of everything written into it since it was allocated would exceed RESET_REGIONS times this
        region (and RESET_MIN_PX): a long flight over a large frame would otherwise make all of it resident
        (133 MB for a BGRA 8K level 0). What lies outside the filled region is unspecified anyway."""
        x0, y0, x1, y1 = box
        buf = self._buffers.get(level)
        wx0, wy0, wx1, wy1 = self._written.get(level, box)
        ux0, uy0, ux1, uy1 = min(wx0, x0), min(wy0, y0), max(wx1, x1), max(wy1, y1)
        union = max(0, ux1 - ux0) * max(0, uy1 - uy0)
        if buf is None or union > max(RESET_REGIONS * max(0, x1 - x0) * max(0, y1 - y0), RESET_MIN_PX):
            lw, lh = self.sizes_px[level]
            buf = self._buffers[level] = np.zeros((lh, lw, self.channels), np.uint8)
            ux0, uy0, ux1, uy1 = box
        self._written[level] = (ux0, uy0, ux1, uy1)
        return buf

    def level_buffer(self, level: int, lx0: int, ly0: int, lx1: int, ly1: int) -> U8:
        """A writable view of level `level` pixels [ly0:ly1, lx0:lx1] to fill in place; `mark_filled` it after."""
        lw, lh = self.sizes_px[level]
        if not (0 <= lx0 < lx1 <= lw and 0 <= ly0 < ly1 <= lh):
            raise ValueError(f"({lx0}, {ly0})-({lx1}, {ly1}) is outside level {level} ({lw}x{lh})")
        return self._buffer(level, (lx0, ly0, lx1, ly1))[ly0:ly1, lx0:lx1]

    def mark_filled(self, level: int) -> None:
        """Level `level` now holds data (filled through `level_buffer`)."""
        if self.filled_level < 0 or level < self.filled_level:
            self.filled_level = level
        self.filled_levels.add(level)

    def fill_level(self, level: int, lx0: int, ly0: int, pixels_bgr: U8) -> None:
        """Paste `pixels_bgr`, pixels of level `level` itself (e.g. from tiles), at level pixel (lx0, ly0)."""
        check_image(pixels_bgr)
        if not 0 <= level <= self.max_level:
            raise ValueError(f"pyramid level {level} out of 0..{self.max_level}")
        lw, lh = self.sizes_px[level]
        h, w = pixels_bgr.shape[:2]
        if lx0 < 0 or ly0 < 0 or lx0 + w > lw or ly0 + h > lh or pixels_bgr.shape[2:] != (self.channels,):
            raise ValueError(f"{w}x{h} pixels at ({lx0}, {ly0}) do not fit level {level} ({lw}x{lh})")
        self._buffer(level, (lx0, ly0, lx0 + w, ly0 + h))[ly0 : ly0 + h, lx0 : lx0 + w] = pixels_bgr
        if self.filled_level < 0 or level < self.filled_level:
            self.filled_level = level
        self.filled_levels.add(level)

    def fill(
        self, level: int, x0: int, y0: int, region_bgr: U8, source_level: int = 0, next_level: bool = False
    ) -> None:
        """Fill level `level` from `region_bgr`: pixels of level `source_level` (<= level) covering level-0 pixels
        [y0:y1, x0:x1] (x1 = x0 + w * 2^source_level, or the frame's edge; likewise y1).

        x0, y0, x1 and y1 must be multiples of 2^level (x1, y1 may instead end at the frame's edge), and the frame's
        size a multiple of 2^level (`exact_level`), so that each halving of the region is exact. `source_level` > 0:
        the region comes from a reduced copy of the frame (e.g. the ingest cache's half-resolution video) of the
        size of that level. `next_level`: also fill level + 1 (one more halving; the same constraints at level + 1).
        A BGR region fills a BGRA pyramid (`channels=4`) converted as it is pasted (alpha 255; halving each channel
        alone, so B, G, R equal those of a BGR pyramid).
        """
        check_image(region_bgr)
        if not 0 <= source_level <= level:
            raise ValueError(f"source level {source_level} must be in 0..{level}")
        h, w = region_bgr.shape[:2]
        h, w = h << source_level, w << source_level
        step = 1 << level
        if not self.exact_level(level):
            raise ValueError(
                f"level {level} of a {self.width_px}x{self.height_px} frame is not an exact halving"
            )
        to_bgra = self.channels == 4 and region_bgr.shape[2:] == (3,)
        if region_bgr.shape[2:] != (self.channels,) and not to_bgra:
            raise ValueError(f"region must have {self.channels} channels, got shape {region_bgr.shape}")
        x1, y1 = x0 + w, y0 + h
        slack = (1 << source_level) - 1  # a reduced copy's last pixel may stand for fewer level-0 pixels
        x1 = self.width_px if x1 - slack <= self.width_px < x1 else x1
        y1 = self.height_px if y1 - slack <= self.height_px < y1 else y1
        if x0 < 0 or y0 < 0 or x1 > self.width_px or y1 > self.height_px or x0 % step or y0 % step:
            raise ValueError(f"region ({x0}, {y0})-({x1}, {y1}) is not aligned to {step} px inside the frame")
        if (x1 % step and x1 != self.width_px) or (y1 % step and y1 != self.height_px):
            raise ValueError(f"region ({x0}, {y0})-({x1}, {y1}) does not end on a {step} px boundary")
        if next_level:
            nstep = step << 1
            if not self.exact_level(level + 1):
                raise ValueError(
                    f"level {level + 1} of a {self.width_px}x{self.height_px} frame is not an exact halving"
                )
            if (
                x0 % nstep
                or y0 % nstep
                or (x1 % nstep and x1 != self.width_px)
                or (y1 % nstep and y1 != self.height_px)
            ):
                raise ValueError(f"region ({x0}, {y0})-({x1}, {y1}) is not aligned to {nstep} px")
        img = region_bgr
        for _ in range(level - source_level):
            img = half_size(img)
        lx, ly = x0 >> level, y0 >> level
        box = (lx, ly, lx + img.shape[1], ly + img.shape[0])
        self._paste(self._buffer(level, box)[box[1] : box[3], box[0] : box[2]], img, to_bgra)
        self.filled_level = level
        self.filled_levels = {level}
        if next_level:
            img = half_size(img)
            box = (lx >> 1, ly >> 1, (lx >> 1) + img.shape[1], (ly >> 1) + img.shape[0])
            self._paste(self._buffer(level + 1, box)[box[1] : box[3], box[0] : box[2]], img, to_bgra)
            self.filled_levels.add(level + 1)
        self.region_px = (x0, y0, x1, y1)

    def halve_into_next(self, level: int, lx0: int, ly0: int, lx1: int, ly1: int) -> None:
        """Fill level `level + 1` over the level-`level` box [ly0:ly1, lx0:lx1] by halving level `level`'s pixels
        there (2x2 box averages, as the pyramid itself is built): for a tile cache whose coarse levels cost a
        decode each (jpeg), the trilinear blend's second level then costs one resize instead of its own tiles.

        Level `level` must hold data over the box, `exact_level(level + 1)` must hold and the box must start on
        even pixels (its end is even anyway: the level's size is even), so that each output pixel is exactly the
        box average of the four level pixels under it."""
        if level not in self.filled_levels:
            raise ValueError(f"level {level} is not filled: nothing to halve")
        if not self.exact_level(level + 1):
            raise ValueError(
                f"level {level + 1} of a {self.width_px}x{self.height_px} frame is not an exact halving"
            )
        lw, lh = self.sizes_px[level]
        if not (0 <= lx0 < lx1 <= lw and 0 <= ly0 < ly1 <= lh) or (lx0 | ly0 | lx1 | ly1) & 1:
            raise ValueError(
                f"({lx0}, {ly0})-({lx1}, {ly1}) is not an even box inside level {level} ({lw}x{lh})"
            )
        src = self._buffers[level][ly0:ly1, lx0:lx1]
        box = (lx0 >> 1, ly0 >> 1, lx1 >> 1, ly1 >> 1)
        dst = self._buffer(level + 1, box)[box[1] : box[3], box[0] : box[2]]
        cv2.resize(src, (box[2] - box[0], box[3] - box[1]), dst=dst, interpolation=cv2.INTER_AREA)
        self.filled_levels.add(level + 1)

    @staticmethod
    def _paste(dst: U8, img: U8, to_bgra: bool) -> None:
        """Copy `img` into `dst`; `to_bgra`: a BGR image into a BGRA buffer, converted in the same pass."""
        if to_bgra:
            cv2.cvtColor(img, cv2.COLOR_BGR2BGRA, dst=dst)
        else:
            dst[...] = img

    def __len__(self) -> int:
        return self.max_level + 1

    @overload
    def __getitem__(self, level: int) -> U8: ...

    @overload
    def __getitem__(self, level: slice) -> list[U8]: ...

    def __getitem__(self, level: int | slice) -> U8 | list[U8]:
        if isinstance(level, slice):
            return [self[i] for i in range(*level.indices(len(self)))]
        if not 0 <= level <= self.max_level:
            raise IndexError(f"pyramid level {level} out of 0..{self.max_level}")
        if level in self.filled_levels:
            return self._buffers[level]
        return self._stubs[level]
