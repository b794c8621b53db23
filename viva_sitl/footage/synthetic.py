"""The built-in SYNTHETIC CALIBRATION FIELD: footage that needs no download and doubles as the geometric test target.

A procedurally drawn ground seen from straight above (north up): a faint seeded texture, a metric grid (a line every
10 m, thicker every 50 m, labelled in metres north/east of the centre), a north arrow, the label "SYNTHETIC
CALIBRATION FIELD", and a few markers moving on analytic trajectories (circle, back-and-forth line, static pad). The
frame is a deterministic function of the frame index (t = index / fps, looping every `loop_s`), and `annotations()`
gives each marker's exact position: the ground truth for tests of the camera and of perception.

The static background is drawn once; a frame costs one copy plus a few filled shapes.
"""

from __future__ import annotations

import enum
import math
import threading
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.footage.annotations import Annotation, make_annotation
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.footage.metadata import FootageKind, FootageMetadata
from viva_sitl.footage.source import FootageSource, _readonly
from viva_sitl.footage.synthetic_actors import draw_actors, draw_scene_ground

LABEL = "SYNTHETIC CALIBRATION FIELD"
GROUND_BGR = (78, 104, 92)  # olive-grey ground
GRID_BGR = (200, 200, 200)
GRID_MAJOR_BGR = (240, 240, 240)
TEXT_BGR = (255, 255, 255)


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


class SyntheticField(FootageSource):
    """The synthetic calibration field as a FootageSource (north up, NED origin at the field centre)."""

    def __init__(
        self, params: SyntheticFieldParams | None = None, metadata: FootageMetadata | None = None
    ) -> None:
        self.params = params or SyntheticFieldParams()
        self.metadata = metadata or synthetic_metadata(self.params)
        p = self.params
        self.geometry = FootageGeometry(
            p.width_px, p.height_px, p.gsd_m_per_px, p.recording_altitude_m, 0.0, None
        )
        self._frame_count = int(round(p.loop_s * p.fps))
        self._background: NDArray[np.uint8] | None = None
        self._last_index = -1
        self._last: NDArray[np.uint8] | None = None
        self._lock = threading.Lock()

    @property
    def fps(self) -> float:
        return self.params.fps

    @property
    def frame_count(self) -> int:
        return self._frame_count

    @property
    def markers(self) -> tuple[MarkerSpec, ...]:
        return self.params.markers

    def time_of(self, index: int) -> float:
        return (int(index) % self._frame_count) / self.params.fps

    def marker_positions_ne_m(self, index: int) -> dict[str, tuple[float, float]]:
        t = self.time_of(index)
        return {m.name: m.position_ne_m(t) for m in self.params.markers}

    # --- drawing ---------------------------------------------------------------------------------------------------
    @property
    def background(self) -> NDArray[np.uint8]:
        if self._background is None:
            self._background = _readonly(self._draw_background())
        return self._background

    def _px(self, north_m: float, east_m: float) -> tuple[float, float]:
        return self.geometry.ned_to_px(north_m, east_m)

    def _draw_background(self) -> NDArray[np.uint8]:
        p, g = self.params, self.geometry
        w, h = p.width_px, p.height_px
        img = np.empty((h, w, 3), np.uint8)
        img[:] = GROUND_BGR
        if p.texture_amplitude > 0:  # seeded low-frequency texture: same picture on every machine
            rng = np.random.default_rng(p.texture_seed)
            small = rng.normal(0.0, 1.0, ((h + 7) // 8, (w + 7) // 8)).astype(np.float32)
            tex = cv2.resize(small, (w, h), interpolation=cv2.INTER_CUBIC)
            tex = cv2.GaussianBlur(tex, (0, 0), 2.0) * (p.texture_amplitude / max(float(tex.std()), 1e-6))
            img = np.clip(img.astype(np.float32) + tex[:, :, None], 0, 255).astype(np.uint8)
        draw_scene_ground(img, self._px)  # ring road + plaza of the moving people/cars (synthetic_actors.py)
        half_n, half_e = g.ground_height_m / 2.0, g.ground_width_m / 2.0
        font = cv2.FONT_HERSHEY_SIMPLEX
        px_per_m = 1.0 / g.gsd_m_per_px
        # grid: a line every 10 m, thicker every 50 m (north lines are horizontal, east lines vertical)
        for k in range(-int(half_e // 10), int(half_e // 10) + 1):
            u, _ = self._px(0.0, 10.0 * k)
            major = k % 5 == 0
            cv2.line(
                img,
                (round(u), 0),
                (round(u), h - 1),
                GRID_MAJOR_BGR if major else GRID_BGR,
                3 if major else 1,
                cv2.LINE_AA,
            )
        for k in range(-int(half_n // 10), int(half_n // 10) + 1):
            _, v = self._px(10.0 * k, 0.0)
            major = k % 5 == 0
            cv2.line(img, (0, round(v)), (w - 1, round(v)), GRID_MAJOR_BGR if major else GRID_BGR, 3 if major else 1, cv2.LINE_AA)  # fmt: skip
        scale = max(0.5, 2.0 * px_per_m / 10.0 * 0.6)
        for kn in range(-int(half_n // 50), int(half_n // 50) + 1):
            for ke in range(-int(half_e // 50), int(half_e // 50) + 1):
                u, v = self._px(50.0 * kn, 50.0 * ke)
                text = f"N{50 * kn:+d} E{50 * ke:+d} m"
                dx = 8 + (round(6.0 * px_per_m) if kn == ke == 0 else 0)  # clear of the centre ring
                cv2.putText(img, text, (round(u) + dx, round(v) - 10), font, scale, TEXT_BGR, 2, cv2.LINE_AA)
                cv2.putText(img, "SYNTHETIC", (round(u) + dx, round(v) + int(40 * scale)), font, scale * 0.8, TEXT_BGR, 1, cv2.LINE_AA)  # fmt: skip
        # centre cross
        cu, cv_ = self._px(0.0, 0.0)
        cv2.circle(img, (round(cu), round(cv_)), round(5.0 * px_per_m), TEXT_BGR, 4, cv2.LINE_AA)
        # north arrow (top left), 15 m long
        base = self._px(half_n - 25.0, -half_e + 12.0)
        tip = self._px(half_n - 10.0, -half_e + 12.0)
        cv2.arrowedLine(img, (round(base[0]), round(base[1])), (round(tip[0]), round(tip[1])), TEXT_BGR, 8, cv2.LINE_AA, 0, 0.3)  # fmt: skip
        cv2.putText(img, "N", (round(base[0]) - int(12 * scale), round(base[1]) + int(45 * scale)), font, scale * 1.6, TEXT_BGR, 3, cv2.LINE_AA)  # fmt: skip
        # the label, in a black box at the top and bottom
        for frac in (0.04, 0.96):
            size, _ = cv2.getTextSize(LABEL, font, scale * 1.4, 3)
            x0 = (w - size[0]) // 2
            y0 = int(h * frac) + size[1] // 2
            cv2.rectangle(img, (x0 - 12, y0 - size[1] - 12), (x0 + size[0] + 12, y0 + 12), (0, 0, 0), -1)
            cv2.putText(img, LABEL, (x0, y0), font, scale * 1.4, TEXT_BGR, 3, cv2.LINE_AA)
        return img

    def _draw_marker(self, img: NDArray[np.uint8], m: MarkerSpec, t_s: float) -> None:
        shift = 4  # 1/16 px sub-pixel precision for the drawn centre
        u, v = self._px(*m.position_ne_m(t_s))
        half = m.size_m / 2.0 / self.geometry.gsd_m_per_px
        s = 1 << shift
        c = (round(u * s), round(v * s))
        if m.shape is MarkerShape.BOX:
            pts = np.array(
                [[u - half, v - half], [u + half, v - half], [u + half, v + half], [u - half, v + half]]
            )
            cv2.fillPoly(img, [np.round(pts * s).astype(np.int32)], m.color_bgr, cv2.LINE_AA, shift)
            return
        cv2.circle(img, c, round(half * s), m.color_bgr, -1, cv2.LINE_AA, shift)
        if (
            m.shape is MarkerShape.PAD
        ):  # black "H": symmetric about the centre, so the colour centroid stays put
            a, b, t = 0.5 * half, 0.55 * half, max(1.0, 0.14 * half)
            for x0, y0, x1, y1 in ((-a - t, -b, -a + t, b), (a - t, -b, a + t, b), (-a, -t, a, t)):
                rect = np.array([[u + x0, v + y0], [u + x1, v + y0], [u + x1, v + y1], [u + x0, v + y1]])
                cv2.fillPoly(img, [np.round(rect * s).astype(np.int32)], (0, 0, 0), cv2.LINE_AA, shift)

    def frame(self, index: int) -> NDArray[np.uint8]:
        index = int(index) % self._frame_count
        with self._lock:
            if index == self._last_index and self._last is not None:
                return self._last
            img = self.background.copy()
            t = self.time_of(index)
            for m in self.params.markers:
                self._draw_marker(img, m, t)
            draw_actors(img, t, self._px, self.geometry.gsd_m_per_px)  # people and cars (synthetic_actors.py)
            self._last, self._last_index = _readonly(img), index
            return self._last

    def annotations(self, index: int) -> list[Annotation]:
        """Exact marker positions at frame `index` (t = index / fps); box_px edges in pixel-area coordinates."""
        t = self.time_of(index)
        names = tuple(m.name for m in self.params.markers)
        out = []
        for k, m in enumerate(self.params.markers):
            u, v = self._px(*m.position_ne_m(t))
            half = m.size_m / 2.0 / self.geometry.gsd_m_per_px
            box = (u + 0.5 - half, v + 0.5 - half, u + 0.5 + half, v + 0.5 + half)
            out.append(make_annotation(self.geometry, k, box, names, track_id=k))
        return out
