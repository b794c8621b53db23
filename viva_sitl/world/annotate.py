"""`viva-sitl footage annotate`: derive object tracks for footage that has none.

(b) method "motion" (no model): the camera hovers, so whatever moves against the background is an object. OpenCV's
    MOG2 background subtractor (primed with the per-pixel median of frames spread over the whole clip, so the first
    frames already have a clean background) -> morphology -> connected components (area limits in m^2) -> a small tracker -> tracks labelled
    derived, class "moving object". Tracks that never travel `min_travel_m` are dropped (flicker, swaying trees).
    Across the loop seam: the camera plays the clip in a loop, so the derivation does too: it first runs over the
    clip's last `preroll_frames` frames (their rows discarded, they are derived again in order), so that at frame 0
    the background model and the tracker are warm and the objects there are counted like anywhere else (without
    it the count dropped from ~65 to 0-2 objects for the first ~0.5 s at every loop of the interchange clip).
    Tracker: greedy nearest-centroid association with constant-velocity prediction, written here because the
    light PyPI trackers do not fit: norfair pins numpy < 2 (the project runs numpy 2 with opencv 5), `trackers`
    pulls supervision + full opencv-python (clashes with opencv-python-headless), motpy/sort-track are
    unmaintained since 2021-2022.
(a) method "detector": an ultralytics model (`--detector WEIGHTS`) with its own tracker (ByteTrack); the class names
    of the model are mapped to world classes (world/classes.py). Needs the `perception` extra.

Rows are in footage pixels (full resolution) with 0-based frame indices; `write_viva` writes them atomically.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.footage.boxfiles import BoxRow
from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.source import FootageSource

MOVING_LABEL = "moving object"
Progress = Callable[[int], None]


@dataclass(frozen=True)
class MotionParams:
    max_side_px: int = 960  # frames are processed downscaled to at most this size
    var_threshold: float = 25.0  # MOG2 variance threshold
    prime_frames: int = 40  # frames spread over the clip that build the background first
    prime_median: bool = True  # then as many copies of their per-pixel median (else the frames only)
    min_area_m2: float = 1.5
    max_area_m2: float = 400.0
    close_m: float = 1.5  # morphological closing size: joins the parts of one vehicle
    gate_m: float = 4.0  # max distance between a predicted and a detected centre (plus the box half-diagonal)
    max_misses: int = 10  # frames a track may go undetected before it ends
    min_hits: int = 5  # detections a track needs to be kept
    min_travel_m: float = 4.0  # net displacement a track needs to be kept (drops flicker)
    preroll_frames: int = 50  # the clip's last frames run first (the loop seam), their rows dropped; 0: none


@dataclass
class _Track:
    tid: int
    box: NDArray[np.float64]  # x0, y0, x1, y1 (work pixels)
    vel: NDArray[np.float64] = field(default_factory=lambda: np.zeros(2))
    misses: int = 0
    rows: list[tuple[int, NDArray[np.float64]]] = field(default_factory=list)

    @property
    def centre(self) -> NDArray[np.float64]:
        return np.array([(self.box[0] + self.box[2]) / 2, (self.box[1] + self.box[3]) / 2])


class CentroidTracker:
    """Greedy nearest-centroid association with constant-velocity prediction (boxes in any pixel unit)."""

    def __init__(self, gate_px: float, max_misses: int) -> None:
        self.gate_px = gate_px
        self.max_misses = max_misses
        self.active: list[_Track] = []
        self.finished: list[_Track] = []
        self._next = 1

    def update(self, frame: int, boxes: NDArray[np.float64]) -> None:
        dets = [np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2]) for b in boxes]
        pairs: list[tuple[float, int, int]] = []
        if self.active and len(boxes):
            pred = np.array([t.centre + t.vel for t in self.active])
            half = np.array([0.5 * math.hypot(t.box[2] - t.box[0], t.box[3] - t.box[1]) for t in self.active])
            dist = np.hypot(
                pred[:, None, 0] - np.array(dets)[None, :, 0], pred[:, None, 1] - np.array(dets)[None, :, 1]
            )
            ii, jj = np.nonzero(dist <= self.gate_px + half[:, None])
            pairs = [(float(dist[i, j]), int(i), int(j)) for i, j in zip(ii, jj, strict=True)]
        used_t: set[int] = set()
        used_d: set[int] = set()
        for _, i, j in sorted(pairs):
            if i in used_t or j in used_d:
                continue
            used_t.add(i)
            used_d.add(j)
            t = self.active[i]
            t.vel = 0.5 * t.vel + 0.5 * (dets[j] - t.centre)
            t.box = boxes[j].astype(np.float64)
            t.misses = 0
            t.rows.append((frame, t.box.copy()))
        keep: list[_Track] = []
        for i, t in enumerate(self.active):
            if i not in used_t:
                t.misses += 1
                t.box = t.box + np.concatenate([t.vel, t.vel])
            (keep if t.misses <= self.max_misses else self.finished).append(t)
        for j, b in enumerate(boxes):
            if j not in used_d:
                t = _Track(self._next, b.astype(np.float64))
                t.rows.append((frame, t.box.copy()))
                self._next += 1
                keep.append(t)
        self.active = keep

    def close(self) -> list[_Track]:
        self.finished.extend(self.active)
        self.active = []
        return sorted(self.finished, key=lambda t: t.tid)


def motion_boxes(
    mask: NDArray[np.uint8], min_area_px: float, max_area_px: float, close_px: int
) -> NDArray[np.float64]:
    """Foreground mask -> boxes (x0, y0, x1, y1, pixel-area edges) of blobs within the area limits."""
    m = cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
    if close_px > 1:
        m = cv2.morphologyEx(
            m, cv2.MORPH_CLOSE, cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (close_px, close_px))
        )
    n, _, stats, _ = cv2.connectedComponentsWithStats(m, connectivity=8)
    out = []
    for k in range(1, n):
        x, y, w, h, area = stats[k]
        if min_area_px <= area <= max_area_px:
            out.append((x, y, x + w, y + h))
    return np.array(out, np.float64).reshape(-1, 4)


def motion_tracks(src: FootageSource, params: MotionParams | None = None, progress: Progress | None = None) -> list[BoxRow]:  # fmt: skip
    """Tracks of moving things in a hovering clip (see the module doc)."""
    p = params or MotionParams()
    n_frames = src.frame_count
    if n_frames < 3:
        raise FootageError(f"footage {src.metadata.name!r} has {n_frames} frame(s): motion needs a video")
    g = src.geometry
    s = min(1.0, p.max_side_px / max(g.width_px, g.height_px))
    size = (max(1, round(g.width_px * s)), max(1, round(g.height_px * s)))
    m_per_px = g.gsd_m_per_px / s

    def work(i: int) -> NDArray[np.uint8]:
        img = np.asarray(src.frame(i))
        return img if s == 1.0 else cv2.resize(img, size, interpolation=cv2.INTER_AREA).astype(np.uint8)

    mog = cv2.createBackgroundSubtractorMOG2(history=max(50, n_frames), varThreshold=p.var_threshold, detectShadows=False)  # fmt: skip
    # prime: the per-pixel median of frames spread over the clip is the background without the movers
    sample = [work(int(i)) for i in np.linspace(0, n_frames - 1, min(p.prime_frames, n_frames)).astype(int)]
    if p.prime_median:  # the frames teach the per-pixel spread (jitter), their median the clean background
        median = np.median(np.stack(sample), axis=0).astype(np.uint8)
        # the median goes first too: MOG2 takes its first image as the initial background at full weight, and
        # when that was frame 0 (cars included) the cars of the first frames read as background (0-2 objects
        # at frame 0 of every loop, ~0.5 s to recover)
        sample = [median] + sample + [median] * len(sample)
    for img in sample:
        mog.apply(img, learningRate=-1)
    tracker = CentroidTracker(p.gate_m / m_per_px, p.max_misses)
    area = m_per_px * m_per_px
    close_px = max(1, round(p.close_m / m_per_px)) | 1
    pre = min(max(0, p.preroll_frames), n_frames - 1)
    for i in range(-pre, n_frames):  # frame -k is frame n_frames - k played before frame 0 (the loop)
        fg = np.asarray(mog.apply(work(i % n_frames)) > 127, np.uint8) * np.uint8(255)
        tracker.update(i, motion_boxes(fg, p.min_area_m2 / area, p.max_area_m2 / area, close_px))
        if progress is not None and i >= 0:
            progress(1)
    rows: list[BoxRow] = []
    kept = 0
    for t in tracker.close():
        if len(t.rows) < p.min_hits:
            continue
        c0 = (t.rows[0][1][:2] + t.rows[0][1][2:]) / 2
        c1 = (t.rows[-1][1][:2] + t.rows[-1][1][2:]) / 2
        if float(np.hypot(*(c1 - c0))) * m_per_px < p.min_travel_m:
            continue
        if t.rows[-1][0] < 0:
            continue  # seen in the pre-roll only: those frames come again (and are tracked) at the clip's end
        kept += 1
        for f, b in t.rows:
            if f < 0:
                continue
            x0, y0, x1, y1 = (float(v) / s for v in b)
            rows.append(BoxRow(f, kept, MOVING_LABEL, x0, y0, x1, y1, False, False, None, True))
    return rows


def detector_tracks(
    src: FootageSource,
    weights: str | Path,
    tracker: str = "bytetrack.yaml",
    conf: float = 0.25,
    progress: Progress | None = None,
) -> list[BoxRow]:
    """(a) an ultralytics detector + its tracker over every frame; labels are the model's class names."""
    try:
        from ultralytics import YOLO  # type: ignore[import-not-found,unused-ignore]
    except ImportError:
        raise FootageError(
            "--method detector needs ultralytics: pip install 'viva-sitl[perception-yolo]' (or use --method motion)"
        ) from None
    if not Path(weights).is_file():
        raise FootageError(f"detector weights not found: {weights}")
    model = YOLO(str(weights))
    names = model.names
    rows: list[BoxRow] = []
    for i in range(src.frame_count):
        res = model.track(np.asarray(src.frame(i)), persist=True, tracker=tracker, conf=conf, verbose=False)[
            0
        ]
        b = res.boxes
        if b is not None and len(b):
            ids = b.id.int().tolist() if b.id is not None else [None] * len(b)
            for xyxy, c, tid, score in zip(
                b.xyxy.tolist(), b.cls.int().tolist(), ids, b.conf.tolist(), strict=True
            ):
                x0, y0, x1, y1 = (float(v) for v in xyxy)
                rows.append(BoxRow(i, tid, str(names[c]), x0, y0, x1, y1, False, False, float(score), True))
        if progress is not None:
            progress(1)
    return rows
