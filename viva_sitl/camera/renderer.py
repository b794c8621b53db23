"""The VAC renderer: footage frame (as a pyramid) + full pose -> anti-aliased camera image, coverage, homography.

Anti-aliasing: the pyramid level is chosen from the footprint, i.e. the number of footage pixels one VAC pixel spans
at the image centre (the longer axis of the local Jacobian of the VAC -> footage map, as in mip-mapping). The frame is
then warped from that level with bilinear interpolation, so each VAC pixel reads about one source pixel and the cost
per frame depends on the output size, not on the footage resolution.

Trilinear (`CameraParams.trilinear`, the default): the level of detail is lod = log2(scale) + lod_bias - 0.5; the
image is warped from levels floor(lod) and floor(lod) + 1 and blended by the fraction of lod (two warps instead of
one). Plain mip-mapping (floor(log2 scale)) over-blurs just above a power of two (a bilinear read of a box-filtered
level spans ~3 level pixels where the footprint spans ~1): on the interchange clip at 4.2 footage px per VAC px it
scored 32.4 dB against an area-averaged reference, below the plain full-resolution warp; the -0.5 offset with the blend
is at or above the plain warp at every ratio measured (bench/bench_tiles.py --aa, bench/results_tiles.md). The pyramid is built once per footage frame by
the caller (`LazyPyramid` builds only the levels actually used).

Pixels whose ray misses the footage (outside it, or at/above the horizon) get `CameraParams.fill_bgr`; the fraction of
pixels that see footage is `RenderResult.coverage` (exact, from the clipped footprint polygon).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from viva_sitl.camera.effects import add_sensor_noise, apply_motion_blur, distortion_source_map
from viva_sitl.camera.params import CameraParams
from viva_sitl.camera.projection import (
    _vec3,
    camera_extrinsics,
    camera_intrinsics,
    clip_convex_polygon,
    footage_to_image_homography,
    ground_to_image_homography,
    image_corners_px,
    pixel_to_ground,
    polygon_area,
)
from viva_sitl.camera.pyramid import U8, LazyPyramid, check_image, level_from_source
from viva_sitl.footage.geometry import FootageGeometry

F64 = NDArray[np.float64]
PyramidLike = LazyPyramid | Sequence[U8] | U8

_W_EPS = 1e-9  # homogeneous w at or below this is treated as a ray at/above the horizon
# Trilinear: added to log2(scale). 0 (textbook trilinear) scored below the plain warp between levels on the
# interchange sweep; -0.5 is above it at every ratio (bench/results_tiles.md, section 4)
TRILINEAR_LOD_OFFSET = -0.5
# the 4-channel warp (Renderer._bgra_source): used when the region it reads is at most this many views' pixels;
# its buffer is replaced once the bounding box of the regions written into it exceeds this many views' pixels
# (bounds its resident memory to ~4 bytes x that; a hovering view rewrites one region and never resets)
BGRA_MAX_READ_VIEWS = 4
BGRA_RESET_VIEWS = 6


@dataclass(frozen=True)
class RenderResult:
    image_bgr: U8  # (height, width, 3) uint8 BGR
    coverage: float  # fraction (0..1) of VAC pixels that see footage; the rest is fill_bgr
    homography: F64  # 3x3: FootageGeometry pixels -> VAC px (ideal pinhole, before lens distortion)
    pyramid_level: int  # pyramid level warped from (0 = full resolution)
    footage_px_per_vac_px: float  # footprint scale at the image centre that chose the level (nan: none)
    cam_rot_body: F64  # R^b_v actually used (differs from the mount's for a gimbal at non-level attitude)
    lod_blend: float = 0.0  # trilinear weight of level pyramid_level + 1 (0: that level alone)


def _level_image(pyramid: PyramidLike, level: int) -> tuple[U8, int]:
    if isinstance(pyramid, LazyPyramid):
        level = min(level, pyramid.max_level)
        return pyramid.level(level), level
    if isinstance(pyramid, np.ndarray):
        if level > 0:
            pyr = LazyPyramid(pyramid)  # not cached: pass a LazyPyramid to reuse levels between frames
            level = min(level, pyr.max_level)
            return pyr.level(level), level
        return pyramid, 0
    level = min(level, len(pyramid) - 1)
    return pyramid[level], level


def _level0_image(pyramid: PyramidLike) -> U8:
    if isinstance(pyramid, LazyPyramid):
        return pyramid.level(0)
    if isinstance(pyramid, np.ndarray):
        return pyramid
    if len(pyramid) == 0:
        raise ValueError("empty pyramid")
    return pyramid[0]


def _footprint_scale(m: F64, u: float, v: float) -> float:
    """Longer axis of the Jacobian of p -> (m p)_xy / (m p)_z at (u, v): source pixels per output pixel."""
    q = m @ np.array([u, v, 1.0])
    if q[2] <= _W_EPS:
        return math.nan
    j = (m[:2, :2] * q[2] - np.outer(q[:2], m[2, :2])) / (q[2] * q[2])
    return float(max(np.hypot(j[0, 0], j[1, 0]), np.hypot(j[0, 1], j[1, 1])))


class Renderer:
    """Renders the VAC view of one footage geometry. Stateless per frame (safe to call from one render thread)."""

    def __init__(self, params: CameraParams, geometry: FootageGeometry) -> None:
        self.params = params
        self.geometry = geometry
        self.k = camera_intrinsics(params)
        self._fill = tuple(float(c) for c in params.fill_bgr)
        self._fill_u8 = np.array(params.fill_bgr, dtype=np.uint8)
        # ideal-pinhole pixel seen by each distorted pixel (precomputed once; None without distortion)
        self._und_map = distortion_source_map(params, self.k) if params.has_distortion else None
        # the last view's maps (see `view_maps`): the simulator plans its footage region with the same pose just
        # before rendering, so each is computed once per frame
        self._view_key: tuple[object, ...] | None = None
        self._view: tuple[F64, F64] = (np.eye(3), np.eye(3))
        self._lod_key: tuple[object, ...] | None = None
        self._lod: tuple[int, float, float] = (0, 0.0, math.nan)
        corners = image_corners_px(params)
        self._corners_h = np.column_stack([corners, np.ones(4)])  # homogeneous image corners (pixel edges)
        self._corners_abs = np.abs(self._corners_h)
        self._full_coverage = min(1.0, polygon_area(corners) / float(params.width_px * params.height_px))
        # the corner pixels' centres (what the warp maps)
        wp, hp = params.width_px - 1.0, params.height_px - 1.0
        self._pixel_corners_h = np.array([[0.0, 0.0, 1.0], [wp, 0.0, 1.0], [wp, hp, 1.0], [0.0, hp, 1.0]])
        # level size -> (its BGRA copy for the 4-channel warp, bounding box x0, y0, x1, y1 of the pixels written
        # into it), see `_bgra_source`
        self._bgra: dict[tuple[int, int], tuple[U8, tuple[int, int, int, int]]] = {}
        self._bgra_used: set[tuple[int, int]] = set()  # the level sizes the current frame warped from

    def view_maps(
        self, pos_ned_m: ArrayLike, att_rpy_rad: ArrayLike, src_w: int, src_h: int
    ) -> tuple[F64, F64]:
        """(H geometry px -> VAC px, VAC px -> source px of a src_w x src_h level-0 image, scaled to max |m| = 1)
        at a pose. The last result is kept (keyed by the pose's values, the size, the geometry and the params
        objects, by identity): the arrays are read-only."""
        pos = _vec3("pos_ned_m", pos_ned_m)
        att = _vec3("att_rpy_rad", att_rpy_rad)
        # the geometry and params objects themselves, compared by identity (an id() could be reused)
        key = (pos.tobytes(), att.tobytes(), src_w, src_h, self.geometry, self.params)
        old = self._view_key
        if old is not None and old[:4] == key[:4] and old[4] is key[4] and old[5] is key[5]:
            return self._view
        gw, gh = self.geometry.width_px, self.geometry.height_px
        geom_to_src = np.eye(3) if (src_w, src_h) == (gw, gh) else level_from_source(gw, gh, src_w, src_h)
        h_f2i = footage_to_image_homography(self.geometry, pos, att, self.params)  # geometry px -> VAC
        h_src2i = h_f2i @ np.linalg.inv(geom_to_src)
        vac_to_src = np.linalg.inv(h_src2i)
        vac_to_src /= np.max(np.abs(vac_to_src))
        h_f2i.setflags(write=False)
        vac_to_src.setflags(write=False)
        self._view_key, self._view = key, (h_f2i, vac_to_src)
        return self._view

    def _image_scale(self, image: U8) -> F64:
        """Geometry pixels -> pixels of the given level-0 image (the frame may be decoded at another resolution)."""
        gw, gh = self.geometry.width_px, self.geometry.height_px
        iw, ih = image.shape[1], image.shape[0]
        if (iw, ih) == (gw, gh):
            return np.eye(3)
        if abs((iw / gw) / (ih / gh) - 1.0) > 0.01:
            raise ValueError(f"footage frame {iw}x{ih} does not have the aspect of its geometry {gw}x{gh}")
        return level_from_source(gw, gh, iw, ih)  # pixel edges stay aligned

    def choose_level(self, vac_to_src: F64, max_level: int) -> tuple[int, float]:
        """(finer pyramid level the render reads, scale); see `choose_lod`."""
        level, _, rho = self.choose_lod(vac_to_src, max_level)
        return level, rho

    def choose_lod(self, vac_to_src: F64, max_level: int) -> tuple[int, float, float]:
        """(level, blend, scale) for the VAC -> level-0 source map, scale = footage px per VAC px at the centre.

        Without trilinear: level = floor(log2(scale) + lod_bias), clamped, blend 0. With it: lod = log2(scale) +
        lod_bias + TRILINEAR_LOD_OFFSET, level = floor(lod) clamped to 0..max_level, blend = the weight of level + 1
        (lod - level, 0 below level 0 and at the deepest level). When the centre ray misses the ground (steep tilt),
        the scale is the smallest over a 5x5 grid of valid pixels.
        """
        p = self.params
        key = (vac_to_src.tobytes(), max_level, p)
        old = self._lod_key
        if old is not None and old[:2] == key[:2] and old[2] is p:
            return self._lod
        self._lod = self._choose_lod(vac_to_src, max_level)
        self._lod_key = key
        return self._lod

    def _choose_lod(self, vac_to_src: F64, max_level: int) -> tuple[int, float, float]:
        p = self.params
        cu, cv = (p.width_px - 1) / 2.0, (p.height_px - 1) / 2.0
        rho = _footprint_scale(vac_to_src, cu, cv)
        if not math.isfinite(rho):
            scales = [
                _footprint_scale(vac_to_src, u, v)
                for u in np.linspace(0, p.width_px - 1, 5)
                for v in np.linspace(0, p.height_px - 1, 5)
            ]
            finite = [s for s in scales if math.isfinite(s)]
            rho = min(finite) if finite else math.nan
        if not p.antialias or not math.isfinite(rho) or rho <= 0.0:
            return 0, 0.0, rho
        if not p.trilinear:
            level = math.floor(math.log2(rho) + p.lod_bias)
            return max(0, min(level, max_level)), 0.0, rho
        lod = math.log2(rho) + p.lod_bias + TRILINEAR_LOD_OFFSET
        if lod <= 0.0:
            return 0, 0.0, rho
        level = math.floor(lod)
        if level >= max_level:
            return max_level, 0.0, rho
        blend = lod - level
        # a blend this small changes no pixel by a level: one warp
        return level, (blend if blend >= 1.0 / 512.0 else 0.0), rho

    def _halfplanes(self, vac_to_src: F64, src_w: int, src_h: int) -> list[F64]:
        m = vac_to_src
        return [
            m[2] - np.array([0.0, 0.0, _W_EPS]),
            m[0] + 0.5 * m[2],  # u >= -0.5
            (src_w - 0.5) * m[2] - m[0],  # u <= w - 0.5
            m[1] + 0.5 * m[2],
            (src_h - 0.5) * m[2] - m[1],
        ]

    def _sees_only_footage(self, halfplanes: list[F64]) -> bool:
        """True when all four image corners are strictly inside every half-plane, by a margin (1e-9 of the terms'
        magnitude) far above the rounding of the two-term dot products: then `clip_convex_polygon` keeps the whole
        image rectangle (every plane's `d >= 0` holds exactly as computed there) and no ray is at or above the
        horizon. One 4x3 @ 3x5 product instead of the clipping loop (the common case: the view inside the frame)."""
        a = np.empty((3, len(halfplanes)))
        for j, plane in enumerate(halfplanes):
            a[:, j] = plane  # np.column_stack's result without its per-call overhead
        d = self._corners_h @ a
        return bool(np.all(d > 1e-9 * (self._corners_abs @ np.abs(a))))

    def coverage(self, vac_to_src: F64, src_w: int, src_h: int) -> float:
        """Exact fraction of the (undistorted) VAC image whose rays hit the footage rectangle in front of the camera.

        With w = m2 . p > 0, `lo <= (mi . p) / w <= hi` is linear in p, so the region is the image rectangle clipped
        by five half-planes.
        """
        halfplanes = self._halfplanes(vac_to_src, src_w, src_h)
        if self._sees_only_footage(halfplanes):
            return self._full_coverage  # what the clipping below returns for the unclipped rectangle
        poly = clip_convex_polygon(image_corners_px(self.params), halfplanes)
        return min(1.0, polygon_area(poly) / float(self.params.width_px * self.params.height_px))

    def render(
        self,
        pyramid: PyramidLike,
        pos_ned_m: ArrayLike,
        att_rpy_rad: ArrayLike,
        vel_ned_m_s: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
        rgb: bool = False,
        out: U8 | None = None,
    ) -> RenderResult:
        """Render the VAC at the vehicle pose. `pyramid`: a LazyPyramid (preferred), a list of levels or an image.
        `rgb`: return the image in RGB order (`image_bgr` then holds RGB), for callers that want RGB (the gym):
        the 4-channel warp's output is converted once, straight to RGB. `out`: an array of the image's shape to
        write the image into (returned as `image_bgr`)."""
        p = self.params
        pos = _vec3("pos_ned_m", pos_ned_m)
        att = _vec3("att_rpy_rad", att_rpy_rad)
        vel = None if vel_ned_m_s is None else _vec3("vel_ned_m_s", vel_ned_m_s)
        if p.noise_std > 0.0 and rng is None:
            raise ValueError("camera noise_std > 0 needs a numpy Generator (rng)")
        src0 = _level0_image(pyramid)
        check_image(src0)
        self._image_scale(src0)  # checks the frame's aspect
        src_w, src_h = int(src0.shape[1]), int(src0.shape[0])
        h_f2i, vac_to_src = self.view_maps(pos, att, src_w, src_h)
        h_f2i = h_f2i.copy()  # the result's own (the cached one stays read-only)
        cam_rot_body, _ = camera_extrinsics(p, att)
        # a BGRA source (tile regions) renders BGR like a BGR one
        shape = (p.height_px, p.width_px) + (src0.shape[2:] if src0.shape[2:] != (4,) else (3,))

        # exact polygon coverage for the pinhole; with lens distortion it is counted per pixel below
        # (the common case, the view inside the frame, is one product: no clipping, nothing behind to paint)
        inside = self._sees_only_footage(self._halfplanes(vac_to_src, src_w, src_h))
        if self._und_map is not None:
            coverage = -1.0
        else:
            coverage = self._full_coverage if inside else self.coverage(vac_to_src, src_w, src_h)
        if coverage == 0.0:
            image = np.empty(shape, np.uint8)
            image[...] = self._fill_u8[: image.shape[2]] if image.ndim == 3 else self._fill_u8[0]
            return RenderResult(self._to_order(image, rgb, out), 0.0, h_f2i, 0, math.nan, cam_rot_body)

        max_level = self._max_level(pyramid)
        level, blend, rho = self.choose_lod(vac_to_src, max_level)
        src, level = _level_image(pyramid, level)
        # the 4-channel warp's BGRA output is kept to the end (blend and fill work per channel): one conversion
        self._bgra_used.clear()
        image, cov = self._warp_level(src, src_w, src_h, vac_to_src, keep_bgra=True)
        if blend > 0.0:
            src1, level1 = _level_image(pyramid, level + 1)
            if level1 == level + 1:
                coarse, _ = self._warp_level(src1, src_w, src_h, vac_to_src, keep_bgra=True)
                if coarse.shape != image.shape:
                    image, coarse = self._to_order(image, False), self._to_order(coarse, False)
                image = np.asarray(cv2.addWeighted(image, 1.0 - blend, coarse, blend, 0.0), dtype=np.uint8)
            else:
                blend = 0.0
        if self._und_map is None:
            if not inside:
                self._fill_behind(image, vac_to_src)
        else:
            coverage = cov

        for size in [k for k in self._bgra if k not in self._bgra_used]:
            del self._bgra[size]  # a level this frame did not read: its buffer's pages go back
        if p.motion_blur and vel is not None and p.exposure_s > 0.0:
            image = apply_motion_blur(self._to_order(image, False), self._blur_shift_px(pos, att, vel))
        if p.noise_std > 0.0 and rng is not None:
            image = add_sensor_noise(self._to_order(image, False), p.noise_std, rng)
        image = self._to_order(image, rgb, out)
        return RenderResult(
            np.asarray(image, dtype=np.uint8), coverage, h_f2i, level, rho, cam_rot_body, float(blend)
        )

    @staticmethod
    def _to_order(image: U8, rgb: bool, out: U8 | None = None) -> U8:
        """A rendered image (BGR, BGRA from the 4-channel warp, or one channel) as BGR, or RGB with `rgb`; into
        `out` when given."""
        code = None
        if image.ndim == 3 and image.shape[2] == 4:
            code = cv2.COLOR_BGRA2RGB if rgb else cv2.COLOR_BGRA2BGR
        elif rgb and image.ndim == 3 and image.shape[2] == 3:
            code = cv2.COLOR_BGR2RGB
        if code is None:
            if out is None:
                return image
            out[...] = image
            return out
        if out is None:
            return np.asarray(cv2.cvtColor(image, code), np.uint8)
        cv2.cvtColor(image, code, dst=out)
        return out

    def _warp_level(
        self, src: U8, src_w: int, src_h: int, vac_to_src: F64, keep_bgra: bool = False
    ) -> tuple[U8, float]:
        """The VAC image warped (bilinear) from one pyramid level, and its coverage with lens distortion (else -1).
        `keep_bgra`: a 4-channel warp's output is returned as BGRA (else converted to BGR)."""
        p = self.params
        vac_to_level = level_from_source(src_w, src_h, int(src.shape[1]), int(src.shape[0])) @ vac_to_src
        if self._und_map is not None:
            return self._remap_distorted(src, vac_to_level)
        quad = self._bgra_source(src, vac_to_level) if src.ndim == 3 and src.shape[2] == 3 else None
        if quad is not None:
            warped4 = cv2.warpPerspective(
                quad, vac_to_level, (p.width_px, p.height_px),
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_CONSTANT, borderValue=(*self._fill[:3], 0.0),
            )  # fmt: skip
            bgra = np.asarray(warped4, dtype=np.uint8)
            return (bgra if keep_bgra else self._to_order(bgra, False)), -1.0
        warped = cv2.warpPerspective(
            src, vac_to_level, (p.width_px, p.height_px),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT, borderValue=self._fill,
        )  # fmt: skip
        return np.asarray(warped, dtype=np.uint8), -1.0

    def _bgra_source(self, src: U8, vac_to_level: F64) -> U8 | None:
        """`src` as 4-channel BGRA, of the same size, valid over the pixels the warp reads (the bounding box of the
        VAC's corner pixels mapped to `src`, + 2 px); None to warp the 3-channel image itself (a footprint that is
        unbounded or large against the view).

        Why: OpenCV's bilinear warpPerspective of 8-bit 4-channel images is ~1.5-2x faster than of 3-channel ones
        (vectorised; measured 0.7-1.2 vs 1.7-1.8 ms for 640x480 on one core here), and each channel is interpolated
        alone, so the first three channels equal the 3-channel warp bit for bit (tests/test_camera.py). The
        conversion covers only the read region (~0.05 ms for a 640x480 view at 1 footage px per VAC px). The buffer
        keeps the level's size (the warp's coordinates stay those of `src`) and is allocated lazily (np.empty: only
        the pages written are resident); it is replaced once the bounding box of the regions written into it
        exceeds BGRA_RESET_VIEWS views (a long flight over a large frame would otherwise make all of it resident)."""
        p = self.params
        c = self._pixel_corners_h @ vac_to_level.T
        # the four corners' tests and bounds on Python floats (the same IEEE divisions and comparisons as the
        # numpy reductions, without their ~3 us call overhead each, 6 per warp)
        eps = _W_EPS * max(abs(x) for x in vac_to_level[2].tolist())
        corners = c.tolist()
        if not all(w > eps for _, _, w in corners):
            return None
        u = [x / w for x, _, w in corners]
        v = [y / w for _, y, w in corners]
        if not all(map(math.isfinite, u + v)):
            return None
        lh, lw = int(src.shape[0]), int(src.shape[1])
        x0 = min(lw, max(0, math.floor(min(u)) - 2))
        x1 = min(lw, max(0, math.floor(max(u)) + 3))
        y0 = min(lh, max(0, math.floor(min(v)) - 2))
        y1 = min(lh, max(0, math.floor(max(v)) + 3))
        area = (x1 - x0) * (y1 - y0)
        view_area = p.width_px * p.height_px
        if area > BGRA_MAX_READ_VIEWS * view_area:
            return None
        if area <= 0:
            x0, y0, x1, y1 = lw, lh, 0, 0  # nothing to write (no pixel of src is read)
        buf, (ux0, uy0, ux1, uy1) = self._bgra.get((lh, lw), (None, (lw, lh, 0, 0)))
        ux0, uy0, ux1, uy1 = min(ux0, x0), min(uy0, y0), max(ux1, x1), max(uy1, y1)  # written since allocated
        if buf is None or max(0, ux1 - ux0) * max(0, uy1 - uy0) > BGRA_RESET_VIEWS * view_area:
            buf, (ux0, uy0, ux1, uy1) = np.empty((lh, lw, 4), np.uint8), (x0, y0, x1, y1)
        if area > 0:
            cv2.cvtColor(src[y0:y1, x0:x1], cv2.COLOR_BGR2BGRA, dst=buf[y0:y1, x0:x1])
        self._bgra[(lh, lw)] = (buf, (ux0, uy0, ux1, uy1))
        self._bgra_used.add((lh, lw))
        return buf

    @staticmethod
    def _max_level(pyramid: PyramidLike) -> int:
        if isinstance(pyramid, LazyPyramid):
            return pyramid.max_level
        if isinstance(pyramid, np.ndarray):
            return LazyPyramid(pyramid).max_level
        return len(pyramid) - 1

    def _fill_behind(self, image: U8, vac_to_src: F64) -> None:
        """Paint the pixels whose ray is at or above the horizon (homogeneous w <= 0), which the warp would mirror."""
        poly = clip_convex_polygon(image_corners_px(self.params), [-vac_to_src[2]])
        if polygon_area(poly) <= 0.0:
            return
        pts = np.round(poly * 16.0).astype(np.int32)  # 4 fractional bits
        cv2.fillConvexPoly(image, pts, self._fill, lineType=cv2.LINE_8, shift=4)

    def _remap_distorted(self, src: U8, vac_to_level: F64) -> tuple[U8, float]:
        assert self._und_map is not None
        m = vac_to_level
        x, y = self._und_map[..., 0], self._und_map[..., 1]
        w = m[2, 0] * x + m[2, 1] * y + m[2, 2]
        valid = w > _W_EPS * np.max(np.abs(m[2]))
        w_safe = np.where(valid, w, 1.0)
        mx = (m[0, 0] * x + m[0, 1] * y + m[0, 2]) / w_safe
        my = (m[1, 0] * x + m[1, 1] * y + m[1, 2]) / w_safe
        mx[~valid] = -1e6
        my[~valid] = -1e6
        lw, lh = src.shape[1], src.shape[0]
        inside = valid & (mx >= -0.5) & (mx <= lw - 0.5) & (my >= -0.5) & (my <= lh - 0.5)
        coverage = float(np.count_nonzero(inside)) / inside.size
        image = cv2.remap(
            src, mx.astype(np.float32), my.astype(np.float32), cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT, borderValue=self._fill,
        )  # fmt: skip
        return np.asarray(image, dtype=np.uint8), coverage

    def _blur_shift_px(self, pos: F64, att: F64, vel: F64) -> tuple[float, float]:
        """Image displacement of the ground point at the image centre over the exposure (translation only)."""
        p = self.params
        centre = np.array([[(p.width_px - 1) / 2.0, (p.height_px - 1) / 2.0]])
        g = pixel_to_ground(centre, pos, att, p)[0]
        if not np.all(np.isfinite(g)):
            return (0.0, 0.0)
        half = 0.5 * p.exposure_s * vel
        gh = np.array([g[0], g[1], 1.0])
        a = ground_to_image_homography(pos - half, att, p) @ gh
        b = ground_to_image_homography(pos + half, att, p) @ gh
        if a[2] <= 0.0 or b[2] <= 0.0:
            return (0.0, 0.0)
        return (float(b[0] / b[2] - a[0] / a[2]), float(b[1] / b[2] - a[1] / a[2]))


def render_view(
    source_image_bgr: U8,
    geometry: FootageGeometry,
    params: CameraParams,
    pos_ned_m: ArrayLike,
    att_rpy_rad: ArrayLike,
) -> U8:
    """One VAC frame of a footage image at a pose (builds a throw-away pyramid; for the CLI and quick looks)."""
    return Renderer(params, geometry).render(LazyPyramid(source_image_bgr), pos_ned_m, att_rpy_rad).image_bgr
