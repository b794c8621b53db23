"""The built-in SYNTHETIC CALIBRATION FIELD: footage that needs no download and doubles as the geometric test target.

A procedurally drawn ground seen from straight above (north up): a faint seeded texture, a metric grid (a line every
10 m, thicker every 50 m, coarser lines every 250 m and 1250 m, labelled in metres north/east of the centre), a north
arrow, the label "SYNTHETIC CALIBRATION FIELD", and a few markers moving on analytic trajectories (circle,
back-and-forth line, static pad). The frame is a deterministic function of the frame index (t = index / fps, looping
every `loop_s`), and `annotations()` gives each object's exact position: the ground truth for tests of the camera and
of perception.

No edge (`unbounded`, the default): like PX4's empty world, the ground goes on forever. Every ground pixel is a pure
function of its world position (the texture is hashed from the world lattice cell, grid lines and labels sit at fixed
metres), so the field can be drawn anywhere: `ground_view()` draws a window around the camera's footprint at a ground
sample distance 0.1 m x 2^L chosen from the camera height, at most `window_max_px` a side, so a frame costs the same
2 km away or 300 m up. The window's background is kept while the footprint stays inside it (a 25 % margin each side);
a frame costs one copy plus the moving objects. Once the footprint has used half of that margin, the next window
(shifted the same way) is drawn on a background thread (`draw_ahead`), so a flight does not stall the renderer;
which window is used depends only on the poses, never on timing (an unfinished one is waited for). `frame(index)` is the nominal `width_px` x `height_px` window at the
centre (what `footage info`, `render` and the annotations' pixel boxes refer to); its geometry reports every ground
point as covered. `[synthetic] unbounded = false` restores a finite field of that size (outside it: the camera fill).

Moving objects: `SyntheticField.objects` is a list of `GroundObject`s (anything with `name`, `size_m`,
`position_ne_m(t)` and `draw(img, to_px, px_per_m, t)`); the markers are the first ones, `add_object()` adds more.
"""

from __future__ import annotations

import enum
import math
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from viva_sitl.footage.annotations import Annotation, make_annotation
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.footage.metadata import FootageKind, FootageMetadata
from viva_sitl.footage.source import FootageCapabilities, FootageSource, _readonly
from viva_sitl.footage.synthetic_actors import draw_actors, draw_scene_ground

LABEL = "SYNTHETIC CALIBRATION FIELD"
GROUND_BGR = (78, 104, 92)  # olive-grey ground
GRID_BGR = (200, 200, 200)
GRID_MAJOR_BGR = (240, 240, 240)
TEXT_BGR = (255, 255, 255)


# grid line spacings (m); a class is drawn where its lines are at least MIN_GRID_SPACING_PX apart
GRID_SPACINGS_M = (10.0, 50.0, 250.0, 1250.0, 6250.0)
MIN_GRID_SPACING_PX = 10.0
LABEL_SPACING_MIN_PX = 160.0  # labels at the finest 50/250/1250.. m crossings at least this far apart
TEXTURE_CELLS_PER_BASE_PX = 8  # texture lattice cell = 8 base pixels (0.8 m at 0.1 m/px)
WINDOW_MARGIN = 0.25  # a drawn window extends this fraction of the footprint size beyond it on each side
# Pixels along a window's edge whose values depend on where the window lies (the texture blur's border handling, the
# renderer's pyramid and interpolation): they never come into view, so a view is a pure function of the pose,
# whichever window the flight's history left (at 1 m height a window is only a few dozen pixels across).
WINDOW_EDGE_PX = 16

ToPx = Callable[[float, float], tuple[float, float]]


@runtime_checkable
class GroundObject(Protocol):
    """Something drawn on the synthetic ground that moves on a known trajectory (markers; later people, cars)."""

    @property
    def name(self) -> str: ...

    @property
    def size_m(self) -> float:
        """Side of its square annotation box (m)."""

    def position_ne_m(self, t_s: float) -> tuple[float, float]: ...

    def draw(self, img: NDArray[np.uint8], to_px: ToPx, px_per_m: float, t_s: float) -> None:
        """Draw at time t into `img`, whose pixel of ground (north, east) is `to_px(north, east)`."""


class MarkerShape(enum.Enum):
    DISC = "disc"
    BOX = "box"
    PAD = "pad"  # disc with a black "H" (a landing pad)


class Trajectory(enum.Enum):
    STATIC = "static"
    CIRCLE = "circle"  # centre + radius (cos, sin) of 2 pi t / period + phase: clockwise seen from above
    LINE = "line"  # start -> end -> start, constant speed, one round trip per period


@dataclass(frozen=True)
class MarkerSpec:
    name: str
    shape: MarkerShape
    color_bgr: tuple[int, int, int]
    size_m: float  # diameter (disc, pad) or side (box)
    trajectory: Trajectory
    center_ne_m: tuple[float, float]  # circle centre, line start, static position (north, east)
    radius_m: float = 0.0  # circle
    end_ne_m: tuple[float, float] = (0.0, 0.0)  # line end
    period_s: float = 60.0
    phase_rad: float = 0.0

    def position_ne_m(self, t_s: float) -> tuple[float, float]:
        """Exact ground position (north, east) in metres at time t."""
        n0, e0 = self.center_ne_m
        if self.trajectory is Trajectory.CIRCLE:
            a = 2.0 * math.pi * t_s / self.period_s + self.phase_rad
            return n0 + self.radius_m * math.cos(a), e0 + self.radius_m * math.sin(a)
        if self.trajectory is Trajectory.LINE:
            s = (t_s / self.period_s) % 1.0
            f = 2.0 * s if s < 0.5 else 2.0 - 2.0 * s
            n1, e1 = self.end_ne_m
            return n0 + f * (n1 - n0), e0 + f * (e1 - e0)
        return n0, e0

    def velocity_ne_m_s(self, t_s: float) -> tuple[float, float]:
        if self.trajectory is Trajectory.CIRCLE:
            w = 2.0 * math.pi / self.period_s
            a = w * t_s + self.phase_rad
            return -self.radius_m * w * math.sin(a), self.radius_m * w * math.cos(a)
        if self.trajectory is Trajectory.LINE:
            s = (t_s / self.period_s) % 1.0
            sign = 1.0 if s < 0.5 else -1.0
            n0, e0 = self.center_ne_m
            n1, e1 = self.end_ne_m
            return sign * 2.0 * (n1 - n0) / self.period_s, sign * 2.0 * (e1 - e0) / self.period_s
        return 0.0, 0.0

    def draw(self, img: NDArray[np.uint8], to_px: ToPx, px_per_m: float, t_s: float) -> None:
        shift = 4  # 1/16 px sub-pixel precision for the drawn centre
        u, v = to_px(*self.position_ne_m(t_s))
        half = self.size_m / 2.0 * px_per_m
        h, w = img.shape[:2]
        if not (-half - 2 <= u <= w + half + 2 and -half - 2 <= v <= h + half + 2):
            return
        s = 1 << shift
        c = (round(u * s), round(v * s))
        if self.shape is MarkerShape.BOX:
            pts = np.array(
                [[u - half, v - half], [u + half, v - half], [u + half, v + half], [u - half, v + half]]
            )
            cv2.fillPoly(img, [np.round(pts * s).astype(np.int32)], self.color_bgr, cv2.LINE_AA, shift)
            return
        cv2.circle(img, c, round(half * s), self.color_bgr, -1, cv2.LINE_AA, shift)
        if (
            self.shape is MarkerShape.PAD
        ):  # black "H": symmetric about the centre, so the colour centroid stays put
            a, b, t = 0.5 * half, 0.55 * half, max(1.0, 0.14 * half)
            for x0, y0, x1, y1 in ((-a - t, -b, -a + t, b), (a - t, -b, a + t, b), (-a, -t, a, t)):
                rect = np.array([[u + x0, v + y0], [u + x1, v + y0], [u + x1, v + y1], [u + x0, v + y1]])
                cv2.fillPoly(img, [np.round(rect * s).astype(np.int32)], (0, 0, 0), cv2.LINE_AA, shift)


DEFAULT_MARKERS: tuple[MarkerSpec, ...] = (
    MarkerSpec("red-disc", MarkerShape.DISC, (0, 0, 255), 4.0, Trajectory.CIRCLE, (0.0, 0.0), radius_m=40.0, period_s=60.0),
    MarkerSpec("blue-box", MarkerShape.BOX, (255, 0, 0), 4.0, Trajectory.LINE, (-70.0, -60.0), end_ne_m=(-70.0, 60.0), period_s=30.0),
    MarkerSpec("green-disc", MarkerShape.DISC, (0, 255, 0), 3.0, Trajectory.CIRCLE, (55.0, -55.0), radius_m=15.0, period_s=20.0, phase_rad=math.pi / 2),
    MarkerSpec("landing-pad", MarkerShape.PAD, (0, 255, 255), 6.0, Trajectory.STATIC, (30.0, 70.0)),
)  # fmt: skip


@dataclass(frozen=True)
class SyntheticFieldParams:
    width_px: int = 2048
    height_px: int = 2048
    gsd_m_per_px: float = 0.1  # 204.8 m x 204.8 m of ground
    recording_altitude_m: float = 120.0  # -> recording hfov 80.9 deg
    fps: float = 30.0
    loop_s: float = 60.0  # frames repeat every loop_s (every marker period divides it)
    texture_seed: int = 7
    texture_amplitude: float = 10.0  # grey levels of the ground texture (features for optical flow)
    markers: tuple[MarkerSpec, ...] = field(default=DEFAULT_MARKERS)
    unbounded: bool = True  # no edge: the ground goes on forever (False: a finite width x height field)
    window_max_px: int = 2048  # largest side of a window drawn around the camera footprint (bounds the cost)
    view_range_m: float = 3000.0  # ground farther from the camera is not drawn (oblique views: fill)
    draw_ahead: bool = True  # draw the next window on a background thread before this one runs out

    def __post_init__(self) -> None:
        if self.width_px < 64 or self.height_px < 64:
            raise ValueError(
                f"synthetic field must be at least 64x64 px, got {self.width_px}x{self.height_px}"
            )
        if not (self.gsd_m_per_px > 0 and self.recording_altitude_m > 0 and self.fps > 0 and self.loop_s > 0):
            raise ValueError(
                "synthetic field: gsd_m_per_px, recording_altitude_m, fps and loop_s must be > 0"
            )
        n = self.loop_s * self.fps
        if abs(n - round(n)) > 1e-6:
            raise ValueError(f"synthetic field: loop_s * fps must be a whole number of frames, got {n}")
        for m in self.markers:
            k = self.loop_s / m.period_s if m.period_s > 0 else 0.0
            if m.trajectory is not Trajectory.STATIC and (m.period_s <= 0 or abs(k - round(k)) > 1e-9):
                raise ValueError(
                    f"synthetic marker {m.name!r}: period {m.period_s} s must divide loop_s {self.loop_s}"
                )
        if self.texture_amplitude < 0:
            raise ValueError("texture_amplitude must be >= 0")
        if self.window_max_px < 256 or not self.view_range_m > 0:
            raise ValueError("synthetic field: window_max_px must be >= 256 and view_range_m > 0")


def synthetic_metadata(params: SyntheticFieldParams | None = None) -> FootageMetadata:
    p = params or SyntheticFieldParams()
    return FootageMetadata(
        name="synthetic",
        kind=FootageKind.SYNTHETIC,
        title=f"{LABEL} (built-in, {p.width_px}x{p.height_px} px at {p.gsd_m_per_px} m/px)",
        fps=p.fps,
        recording_altitude_m=p.recording_altitude_m,
        gsd_m_per_px=p.gsd_m_per_px,
        heading_deg=0.0,
        licence="generated by viva-sitl (MIT)",
        class_names=tuple(m.name for m in p.markers),
    )


def _rnd(x: float) -> int:
    """Nearest integer, halves up (not to even): a window shifted by whole pixels draws the same pixels."""
    return math.floor(x + 0.5 + 1e-6)


def _hash_unit(i: NDArray[np.int64], j: NDArray[np.int64], seed: int) -> NDArray[np.float32]:
    """A value in [-sqrt 3, sqrt 3) (zero mean, unit variance) per integer lattice point: splitmix64 of (i, j, seed)."""
    with np.errstate(over="ignore"):
        x = i.astype(np.uint64) * np.uint64(0x9E3779B97F4A7C15)
        x ^= j.astype(np.uint64) * np.uint64(0xC2B2AE3D27D4EB4F)
        x ^= np.uint64((seed * 0x165667B19E3779F9) & 0xFFFFFFFFFFFFFFFF)
        x ^= x >> np.uint64(33)
        x *= np.uint64(0xFF51AFD7ED558CCD)
        x ^= x >> np.uint64(33)
        x *= np.uint64(0xC4CEB9FE1A85EC53)
        x ^= x >> np.uint64(33)
    unit = (x >> np.uint64(40)).astype(np.float32) / np.float32(1 << 24)
    return ((unit - 0.5) * np.float32(math.sqrt(12.0))).astype(np.float32)


@dataclass(frozen=True)
class _Window:
    """A drawn piece of the ground: level L (GSD = base * 2^L), centre, size; its background image."""

    level: int
    geometry: FootageGeometry
    background: NDArray[np.uint8]

    def margin_left(self, n_lo: float, n_hi: float, e_lo: float, e_hi: float) -> float:
        """Ground (m) between the footprint and the window's edge band (WINDOW_EDGE_PX wide; negative: in or past it)."""
        g = self.geometry
        n0, e0 = g.center_ne_m
        hn, he = g.ground_height_m / 2.0, g.ground_width_m / 2.0
        edge_m = WINDOW_EDGE_PX * g.gsd_m_per_px
        return min(n_lo - (n0 - hn), n0 + hn - n_hi, e_lo - (e0 - he), e0 + he - e_hi) - edge_m

    def holds(self, level: int, n_lo: float, n_hi: float, e_lo: float, e_hi: float) -> bool:
        return level == self.level and self.margin_left(n_lo, n_hi, e_lo, e_hi) >= 0.0


class SyntheticField(FootageSource):
    """The synthetic calibration field as a FootageSource (north up, NED origin at the field centre)."""

    def __init__(
        self, params: SyntheticFieldParams | None = None, metadata: FootageMetadata | None = None
    ) -> None:
        self.params = params or SyntheticFieldParams()
        self.metadata = metadata or synthetic_metadata(self.params)
        p = self.params
        self.geometry = FootageGeometry(
            p.width_px, p.height_px, p.gsd_m_per_px, p.recording_altitude_m, 0.0, None,
            unbounded=p.unbounded,
        )  # fmt: skip
        self._capabilities = FootageCapabilities(ground_view=p.unbounded, per_view=True)
        self.objects: list[GroundObject] = list(p.markers)
        self._frame_count = int(round(p.loop_s * p.fps))
        self._background: NDArray[np.uint8] | None = None
        self._last_index = -1
        self._last: NDArray[np.uint8] | None = None
        self._lock = threading.Lock()
        self._tex_norm: float | None = None
        self._window: _Window | None = None
        self._view_key: tuple[int, int] = (-1, -1)
        self._view: NDArray[np.uint8] | None = None
        self.windows_drawn = 0  # statistics: windows ground_view moved to (tests, bench) ...
        self.windows_ahead = 0  # ... of which drawn ahead on the background thread
        self._pool: ThreadPoolExecutor | None = None
        self._ahead: tuple[int, FootageGeometry, Future[NDArray[np.uint8]]] | None = None

    @property
    def capabilities(self) -> FootageCapabilities:
        """No edge (`unbounded`): rendered through `ground_view`; its window follows one view (`per_view`)."""
        return self._capabilities

    @property
    def fps(self) -> float:
        return self.params.fps

    @property
    def frame_count(self) -> int:
        return self._frame_count

    @property
    def markers(self) -> tuple[MarkerSpec, ...]:
        return self.params.markers

    def add_object(self, obj: GroundObject) -> None:
        """Draw `obj` in every later frame (and report it in `annotations`)."""
        with self._lock:
            self.objects.append(obj)
            self._last, self._last_index = None, -1
            self._view, self._view_key = None, (-1, -1)

    def time_of(self, index: int) -> float:
        return (int(index) % self._frame_count) / self.params.fps

    def marker_positions_ne_m(self, index: int) -> dict[str, tuple[float, float]]:
        t = self.time_of(index)
        return {m.name: m.position_ne_m(t) for m in self.objects}

    # --- drawing ---------------------------------------------------------------------------------------------------
    @property
    def background(self) -> NDArray[np.uint8]:
        """The nominal window's background (width_px x height_px at gsd_m_per_px around the centre)."""
        if self._background is None:
            self._background = _readonly(self._draw_ground(self.geometry))
        return self._background

    def _px(self, north_m: float, east_m: float) -> tuple[float, float]:
        return self.geometry.ned_to_px(north_m, east_m)

    def _texture_norm(self) -> float:
        """Standard deviation of the raw texture at the base GSD (measured once on a fixed patch: deterministic)."""
        if self._tex_norm is None:
            p = self.params
            ref = FootageGeometry(256, 256, p.gsd_m_per_px, p.recording_altitude_m)
            raw = self._texture(ref, 1.0)
            self._tex_norm = max(float(raw.std()), 1e-6) if raw is not None else 1.0
        return self._tex_norm

    def _texture(self, g: FootageGeometry, norm: float) -> NDArray[np.float32] | None:
        """Seeded value noise on a world lattice (cell 8 base px), cubic-interpolated, blurred 2 base px; None when
        the cells are too small to see at this GSD."""
        p = self.params
        cell_m = TEXTURE_CELLS_PER_BASE_PX * p.gsd_m_per_px
        gsd = g.gsd_m_per_px
        if cell_m / gsd < 1.5:
            return None
        w, h = g.width_px, g.height_px
        cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
        n0, e0 = g.center_ne_m
        n_hi, n_lo = n0 + (cy + 0.5) * gsd, n0 - (cy + 0.5) * gsd
        e_lo, e_hi = e0 - (cx + 0.5) * gsd, e0 + (cx + 0.5) * gsd
        i_max, i_min = math.ceil(n_hi / cell_m) + 3, math.floor(n_lo / cell_m) - 3
        j_min, j_max = math.floor(e_lo / cell_m) - 3, math.ceil(e_hi / cell_m) + 3
        ii = np.arange(i_max, i_min - 1, -1, dtype=np.int64)[:, None]  # rows: north decreasing downwards
        jj = np.arange(j_min, j_max + 1, dtype=np.int64)[None, :]
        lattice = _hash_unit(
            np.broadcast_to(ii, (ii.size, jj.size)), np.broadcast_to(jj, (ii.size, jj.size)), p.texture_seed
        )
        k = gsd / cell_m  # window px -> lattice cells
        m = np.array([[k, 0.0, (e0 - cx * gsd) / cell_m - j_min], [0.0, k, i_max - (n0 + cy * gsd) / cell_m]])
        tex = cv2.warpAffine(
            lattice, m, (w, h), flags=cv2.INTER_CUBIC | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REFLECT
        )
        sigma_px = 2.0 * p.gsd_m_per_px / gsd
        if sigma_px >= 0.5:
            tex = cv2.GaussianBlur(tex, (0, 0), sigma_px)
        return np.asarray(tex, dtype=np.float32) * np.float32(p.texture_amplitude / norm)

    def _draw_ground(self, g: FootageGeometry) -> NDArray[np.uint8]:
        """The static ground (texture, grid, labels, centre ring, north arrow, banner) in the window `g`."""
        p = self.params
        w, h = g.width_px, g.height_px
        gsd = g.gsd_m_per_px
        px_per_m = 1.0 / gsd
        n0, e0 = g.center_ne_m
        cx, cy = (w - 1) / 2.0, (h - 1) / 2.0

        def to_px(n: float, e: float) -> tuple[float, float]:
            return cx + (e - e0) * px_per_m, cy - (n - n0) * px_per_m

        tex = self._texture(g, self._texture_norm()) if p.texture_amplitude > 0 else None
        if tex is not None:  # same picture on every machine, a pure function of the world position
            # ground + texture, rounded and saturated to uint8 (all values are >= 0 before the saturation)
            chans = [
                cv2.convertScaleAbs(np.maximum(tex + np.float32(c), np.float32(0.0))) for c in GROUND_BGR
            ]
            img = np.asarray(cv2.merge(chans), dtype=np.uint8)
        else:
            img = np.empty((h, w, 3), np.uint8)
            img[:] = GROUND_BGR
        draw_scene_ground(img, to_px)  # ring road + plaza of the moving people/cars (synthetic_actors.py)
        half_n, half_e = (cy + 0.5) * gsd, (cx + 0.5) * gsd
        n_lo, n_hi, e_lo, e_hi = n0 - half_n, n0 + half_n, e0 - half_e, e0 + half_e
        font = cv2.FONT_HERSHEY_SIMPLEX
        # grid: every visible spacing class; the finest drawn thin, the coarser ones thick
        drawn = [s for s in GRID_SPACINGS_M if s * px_per_m >= MIN_GRID_SPACING_PX]
        for rank, spacing in enumerate(drawn):
            major = rank > 0
            color = GRID_MAJOR_BGR if major else GRID_BGR
            thick = 1 if not major else min(1 + 2 * rank, 7)
            for k in range(math.ceil(e_lo / spacing), math.floor(e_hi / spacing) + 1):
                u = _rnd(to_px(0.0, spacing * k)[0])
                cv2.line(img, (u, 0), (u, h - 1), color, thick, cv2.LINE_AA)
            for k in range(math.ceil(n_lo / spacing), math.floor(n_hi / spacing) + 1):
                v = _rnd(to_px(spacing * k, 0.0)[1])
                cv2.line(img, (0, v), (w - 1, v), color, thick, cv2.LINE_AA)
        scale = max(0.5, 2.0 * px_per_m / 10.0 * 0.6)
        label_spacing = next((s for s in GRID_SPACINGS_M[1:] if s * px_per_m >= LABEL_SPACING_MIN_PX), None)
        if label_spacing is not None:
            reach_m = 500.0 * scale * gsd  # a label's extent right of / below its crossing
            for kn in range(
                math.ceil((n_lo - 10 * gsd) / label_spacing), math.floor((n_hi + reach_m) / label_spacing) + 1
            ):
                for ke in range(
                    math.ceil((e_lo - reach_m) / label_spacing), math.floor(e_hi / label_spacing) + 1
                ):
                    nm, em = round(label_spacing * kn), round(label_spacing * ke)
                    lu, lv = to_px(nm, em)
                    text = f"N{nm:+d} E{em:+d} m"
                    dx = 8 + (_rnd(6.0 * px_per_m) if kn == ke == 0 else 0)  # clear of the centre ring
                    cv2.putText(
                        img, text, (_rnd(lu) + dx, _rnd(lv) - 10), font, scale, TEXT_BGR, 2, cv2.LINE_AA
                    )
                    cv2.putText(img, "SYNTHETIC", (_rnd(lu) + dx, _rnd(lv) + int(40 * scale)), font, scale * 0.8, TEXT_BGR, 1, cv2.LINE_AA)  # fmt: skip
        # centre ring (5 m radius)
        cu, cv_ = to_px(0.0, 0.0)
        if -10 * px_per_m <= cu <= w + 10 * px_per_m and -10 * px_per_m <= cv_ <= h + 10 * px_per_m:
            ring = max(1, _rnd(4 * p.gsd_m_per_px * px_per_m))
            cv2.circle(img, (_rnd(cu), _rnd(cv_)), _rnd(5.0 * px_per_m), TEXT_BGR, ring, cv2.LINE_AA)
        # north arrow (15 m) and the label banners: placed on the nominal field, drawn at ground scale
        base_scale = max(0.5, 2.0 / p.gsd_m_per_px / 10.0 * 0.6)  # the label scale of the nominal field
        zoom = p.gsd_m_per_px * px_per_m  # window px per nominal px
        fn, fe = p.height_px * p.gsd_m_per_px / 2.0, p.width_px * p.gsd_m_per_px / 2.0
        if zoom * base_scale >= 0.25:
            base = to_px(fn - 25.0, -fe + 12.0)
            tip = to_px(fn - 10.0, -fe + 12.0)
            cv2.arrowedLine(img, (_rnd(base[0]), _rnd(base[1])), (_rnd(tip[0]), _rnd(tip[1])), TEXT_BGR, max(1, _rnd(8 * zoom)), cv2.LINE_AA, 0, 0.3)  # fmt: skip
            cv2.putText(img, "N", (_rnd(base[0]) - int(12 * base_scale * zoom), _rnd(base[1]) + int(45 * base_scale * zoom)), font, base_scale * 1.6 * zoom, TEXT_BGR, max(1, _rnd(3 * zoom)), cv2.LINE_AA)  # fmt: skip
            bs = base_scale * 1.4 * zoom
            bt = max(1, _rnd(3 * zoom))
            size, _ = cv2.getTextSize(LABEL, font, bs, bt)
            pad = max(1, _rnd(12 * zoom))
            for frac in (0.04, 0.96):
                # the banner's centre line on the nominal field, in metres
                n_line = fn - (p.height_px * frac) * p.gsd_m_per_px
                uc, vc = to_px(n_line, 0.0)
                x0 = _rnd(uc - size[0] / 2.0)
                y0 = _rnd(vc) + size[1] // 2
                cv2.rectangle(
                    img, (x0 - pad, y0 - size[1] - pad), (x0 + size[0] + pad, y0 + pad), (0, 0, 0), -1
                )
                cv2.putText(img, LABEL, (x0, y0), font, bs, TEXT_BGR, bt, cv2.LINE_AA)
        return img

    def _draw_objects(self, img: NDArray[np.uint8], g: FootageGeometry, t_s: float) -> None:
        for obj in self.objects:
            obj.draw(img, g.ned_to_px, 1.0 / g.gsd_m_per_px, t_s)
        draw_actors(img, t_s, g.ned_to_px, g.gsd_m_per_px)  # people and cars (synthetic_actors.py)

    def frame(self, index: int) -> NDArray[np.uint8]:
        index = int(index) % self._frame_count
        with self._lock:
            if index == self._last_index and self._last is not None:
                return self._last
            img = self.background.copy()
            self._draw_objects(img, self.geometry, self.time_of(index))
            self._last, self._last_index = _readonly(img), index
            return self._last

    def ground_view(
        self,
        index: int,
        camera_ned_m: ArrayLike,
        rays_ned: NDArray[np.float64],
        ground_px_m: float,
    ) -> tuple[NDArray[np.uint8], FootageGeometry]:
        """A window of the ground holding everything the camera sees (rays clipped at `view_range_m`), drawn at the
        coarsest GSD 0.1 m x 2^L not coarser than `ground_px_m` (the ground size of one camera pixel) that keeps the
        window within `window_max_px` a side. Returns the frame-`index` image of that window and its geometry (read-only;
        the same objects again for the same index and window)."""
        p = self.params
        cam = np.asarray(camera_ned_m, dtype=np.float64).reshape(3)
        height = max(-float(cam[2]), 0.01)
        d = np.asarray(rays_ned, dtype=np.float64).reshape(-1, 3)
        horiz = np.hypot(d[:, 0], d[:, 1])
        with np.errstate(divide="ignore", invalid="ignore"):
            dist = np.where(d[:, 2] > 1e-9, height * horiz / np.maximum(d[:, 2], 1e-300), np.inf)
            dist = np.minimum(dist, p.view_range_m)
            unit = np.where(horiz[:, None] > 1e-12, d[:, :2] / np.maximum(horiz[:, None], 1e-300), 0.0)
        pts = cam[None, :2] + unit * dist[:, None]
        n_lo, n_hi = float(min(pts[:, 0].min(), cam[0])), float(max(pts[:, 0].max(), cam[0]))
        e_lo, e_hi = float(min(pts[:, 1].min(), cam[1])), float(max(pts[:, 1].max(), cam[1]))
        base = p.gsd_m_per_px
        span = max(n_hi - n_lo, e_hi - e_lo, base)
        lvl_res = math.floor(math.log2(ground_px_m / base)) if ground_px_m > base else 0
        usable_px = p.window_max_px - 2 * WINDOW_EDGE_PX - 2  # the edge bands and the even-size rounding
        lvl_cap = max(0, math.ceil(math.log2(span * (1.0 + 2.0 * WINDOW_MARGIN) / (usable_px * base))))
        level = max(lvl_res, lvl_cap)
        bbox = (n_lo, n_hi, e_lo, e_hi)
        with self._lock:
            win = self._window
            if win is None or not win.holds(level, *bbox):
                win = self._take_ahead(level, bbox)
                if win is None:
                    geom = self._window_geometry(level, bbox, span, (0.0, 0.0))
                    win = _Window(level, geom, _readonly(self._draw_ground(geom)))
                self._window = win
                self.windows_drawn += 1
                self._view_key = (-1, -1)
            elif p.draw_ahead and win.margin_left(*bbox) < 0.5 * WINDOW_MARGIN * span:
                # the footprint has used half of the margin: draw the next window (shifted the same way) meanwhile
                n0, e0 = win.geometry.center_ne_m
                shift = ((n_lo + n_hi) / 2.0 - n0, (e_lo + e_hi) / 2.0 - e0)
                self._start_ahead(level, self._window_geometry(level, bbox, span, shift))
            index = int(index) % self._frame_count
            key = (index, id(win))
            if self._view is None or self._view_key != key:
                img = win.background.copy()
                self._draw_objects(img, win.geometry, self.time_of(index))
                self._view, self._view_key = _readonly(img), key
            return self._view, win.geometry

    def _window_geometry(
        self, level: int, bbox: tuple[float, float, float, float], span: float, shift_ne: tuple[float, float]
    ) -> FootageGeometry:
        """The window for footprint `bbox` (n_lo, n_hi, e_lo, e_hi) at `level`: the footprint plus WINDOW_MARGIN of
        its size each side plus the edge band, centred on it (moved by `shift_ne`), on the level's pixel grid, at most
        window_max_px."""
        p = self.params
        n_lo, n_hi, e_lo, e_hi = bbox
        gsd = p.gsd_m_per_px * (1 << level)
        grow = WINDOW_MARGIN * span + WINDOW_EDGE_PX * gsd
        w = min(p.window_max_px, 2 * math.ceil((e_hi - e_lo + 2 * grow) / gsd / 2.0) + 2)
        h = min(p.window_max_px, 2 * math.ceil((n_hi - n_lo + 2 * grow) / gsd / 2.0) + 2)
        cn = round(((n_lo + n_hi) / 2.0 + shift_ne[0]) / gsd) * gsd
        ce = round(((e_lo + e_hi) / 2.0 + shift_ne[1]) / gsd) * gsd
        return FootageGeometry(
            w, h, gsd, p.recording_altitude_m * (1 << level), 0.0, None, (cn, ce), unbounded=True
        )

    def _start_ahead(self, level: int, geom: FootageGeometry) -> None:
        """Draw window `geom` on the background thread (one at a time), for `_take_ahead` to pick up."""
        if self._ahead is not None and not self._ahead[2].done():
            return
        if self._ahead is not None and self._ahead[1] == geom:
            return  # already drawn
        self._texture_norm()  # computed here, so the worker only reads it
        if self._pool is None:
            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="viva-sitl-ground")
        self._ahead = (level, geom, self._pool.submit(self._draw_ground, geom))

    def _take_ahead(self, level: int, bbox: tuple[float, float, float, float]) -> _Window | None:
        """The window drawn ahead, if it holds this footprint (waits for it to finish: it is already under way)."""
        ahead, self._ahead = self._ahead, None
        if ahead is None:
            return None
        win = _Window(ahead[0], ahead[1], np.empty((0, 0, 3), np.uint8))
        if not win.holds(level, *bbox):
            ahead[2].cancel()
            return None
        self.windows_ahead += 1
        return _Window(ahead[0], ahead[1], _readonly(ahead[2].result()))

    def forget_windows(self) -> None:
        """Drop the ground window kept from earlier views (and one being drawn ahead): the next view draws afresh,
        so what a new episode sees depends on its own poses only (viva_sitl.gym calls this on reset: a window left by
        another flight can differ in grid/level and shift pixels by a grey level)."""
        with self._lock:
            self._window, self._ahead = None, None
            self._view, self._view_key = None, (-1, -1)

    def close(self) -> None:
        """Stop the background window drawing (idempotent)."""
        pool, self._pool = self._pool, None
        if pool is not None:
            pool.shutdown(wait=True, cancel_futures=True)
        self._ahead = None

    def annotations(self, index: int) -> list[Annotation]:
        """Exact object positions at frame `index` (t = index / fps) in the nominal window; box_px edges in
        pixel-area coordinates."""
        t = self.time_of(index)
        names = tuple(m.name for m in self.objects)
        out = []
        for k, m in enumerate(self.objects):
            u, v = self._px(*m.position_ne_m(t))
            half = m.size_m / 2.0 / self.geometry.gsd_m_per_px
            box = (u + 0.5 - half, v + 0.5 - half, u + 0.5 + half, v + 0.5 + half)
            out.append(make_annotation(self.geometry, k, box, names, track_id=k))
        return out
