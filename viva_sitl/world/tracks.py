"""Object tracks in world metres over sim time, stored per footage frame for cheap queries at the physics rate.

Clock: the objects at sim time t are those of frame i = floor(t * fps + 1e-9) mod frame_count, exactly the frame the
camera shows (FootageSource.frame_index_at). Over a still with tracks (SDD), the tracks keep their own clock (fps of
the annotations, frame_count = the annotated span) and loop the same way.

Storage: every presence (object k in frame i) is one row of flat arrays sorted by frame; `_start[i]:_start[i+1]`
is frame i's slice (CSR). A query slices one frame and does a few vectorised numpy operations: no Python loop over
objects, no per-query allocation beyond the result.

Building: annotated rows are turned into NED through the footage geometry (box centre on the ground: the camera
is nadir), grouped by track, and frames between two annotated frames of the same track are filled by linear
interpolation when both are present and the gap is at most `max_gap_frames`. `lost` rows (out of view) are not
present and are never interpolated across; `occluded` rows are present (flag kept).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from viva_sitl.footage.boxfiles import BoxRow
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.world.classes import ALL, ObjectClass, class_of


@dataclass(frozen=True)
class TrackInfo:
    index: int  # row in TrackTable.tracks
    source: str  # e.g. "sdd", "synthetic", "motion"
    source_id: int | None  # the id in the source file (None: an untracked detection)
    object_class: ObjectClass
    label: str  # the source's own label
    derived: bool  # made by a program (motion/detector), not annotated by a person


@dataclass(frozen=True)
class Objects:
    """Objects present at one instant (arrays of equal length; views into the table where possible)."""

    track: NDArray[np.int32]  # index into TrackTable.tracks
    ne_m: NDArray[np.float64]  # (k, 2) ground position (north, east), m
    size_m: NDArray[np.float64]  # (k, 2) ground extent of the box (along footage u, along footage v), m
    object_class: NDArray[np.uint8]  # ObjectClass values
    occluded: NDArray[np.bool_]
    frame: int

    def __len__(self) -> int:
        return int(self.track.size)


@dataclass(frozen=True)
class Nearest:
    track: int
    object_class: ObjectClass
    distance_m: float
    ne_m: tuple[float, float]


@dataclass
class TrackSource:
    """Rows of one source before they become world tracks."""

    name: str
    rows: Sequence[BoxRow]
    class_map: dict[str, str] | None = None
    derived: bool = False


def _class_table(classes: Iterable[ObjectClass] | None) -> NDArray[np.bool_]:
    table = np.zeros(len(ObjectClass), bool)
    table[[int(c) for c in (ALL if classes is None else classes)]] = True
    return table


class TrackTable:
    """All objects of one footage over its clock; queries are pure and never do I/O."""

    def __init__(
        self,
        fps: float,
        frame_count: int,
        tracks: Sequence[TrackInfo],
        frame: NDArray[np.int64],
        track: NDArray[np.int32],
        ne_m: NDArray[np.float64],
        size_m: NDArray[np.float64],
        occluded: NDArray[np.bool_],
    ) -> None:
        if not (fps > 0 and math.isfinite(fps)) or frame_count < 1:
            raise ValueError(f"track clock needs fps > 0 and frame_count >= 1, got {fps}, {frame_count}")
        order = np.lexsort((track, frame))
        self.fps = float(fps)
        self.frame_count = int(frame_count)
        self.tracks: tuple[TrackInfo, ...] = tuple(tracks)
        self._frame = np.ascontiguousarray(frame[order])
        self._track = np.ascontiguousarray(track[order].astype(np.int32))
        self._ne = np.ascontiguousarray(ne_m[order], dtype=np.float64)
        self._size = np.ascontiguousarray(size_m[order], dtype=np.float64)
        self._occluded = np.ascontiguousarray(occluded[order])
        track_class = np.array([int(t.object_class) for t in self.tracks], np.uint8)
        self._class = track_class[self._track] if self._track.size else np.zeros(0, np.uint8)
        self._start = np.searchsorted(self._frame, np.arange(self.frame_count + 1)).astype(np.int64)
        self._tables: dict[frozenset[ObjectClass] | None, NDArray[np.bool_]] = {}

    # --- clock ------------------------------------------------------------------------------------------------------
    def frame_at(self, t_s: float) -> int:
        """floor(t * fps + 1e-9) mod frame_count: the footage frame the camera shows at sim time t."""
        if not math.isfinite(t_s):
            raise ValueError(f"time must be finite, got {t_s!r}")
        if self.frame_count <= 1:
            return 0
        return int(math.floor(t_s * self.fps + 1e-9)) % self.frame_count

    @property
    def duration_s(self) -> float:
        return self.frame_count / self.fps

    @property
    def presence_count(self) -> int:
        return int(self._frame.size)

    def count_by_class(self) -> dict[str, int]:
        out: dict[str, int] = {}
        for t in self.tracks:
            out[t.object_class.label] = out.get(t.object_class.label, 0) + 1
        return out

    # --- queries ----------------------------------------------------------------------------------------------------
    def _table(self, classes: Iterable[ObjectClass] | None) -> NDArray[np.bool_]:
        key = None if classes is None else frozenset(classes)
        tab = self._tables.get(key)
        if tab is None:
            tab = self._tables[key] = _class_table(key)
        return tab

    def frame_slice(self, t_s: float) -> slice:
        """The rows of the frame shown at time t (index `row_*` arrays with it): for callers' own vector maths."""
        return self._slice(self.frame_at(t_s))

    @property
    def row_ne_m(self) -> NDArray[np.float64]:
        return self._ne

    @property
    def row_size_m(self) -> NDArray[np.float64]:
        return self._size

    @property
    def row_class(self) -> NDArray[np.uint8]:
        return self._class

    def _slice(self, frame: int) -> slice:
        return slice(int(self._start[frame]), int(self._start[frame + 1]))

    def _objects(self, frame: int, sl: slice, mask: NDArray[np.bool_] | None) -> Objects:
        tr, ne, sz = self._track[sl], self._ne[sl], self._size[sl]
        cl, oc = self._class[sl], self._occluded[sl]
        if mask is not None:
            tr, ne, sz, cl, oc = tr[mask], ne[mask], sz[mask], cl[mask], oc[mask]
        return Objects(tr, ne, sz, cl, oc, frame)

    def objects_at(self, t_s: float, classes: Iterable[ObjectClass] | None = None) -> Objects:
        """Every object present at sim time t (of the given classes; None = all)."""
        f = self.frame_at(t_s)
        sl = self._slice(f)
        mask = None if classes is None else self._table(classes)[self._class[sl]]
        return self._objects(f, sl, mask)

    def within(
        self,
        north_m: float,
        east_m: float,
        radius_m: float,
        t_s: float,
        classes: Iterable[ObjectClass] | None = None,
    ) -> Objects:
        """Objects whose centre lies within radius_m of (north, east) at time t."""
        f = self.frame_at(t_s)
        sl = self._slice(f)
        ne = self._ne[sl]
        d2 = (ne[:, 0] - north_m) ** 2 + (ne[:, 1] - east_m) ** 2
        mask = d2 <= radius_m * radius_m
        if classes is not None:
            mask &= self._table(classes)[self._class[sl]]
        return self._objects(f, sl, mask)

    def nearest(
        self, north_m: float, east_m: float, t_s: float, classes: Iterable[ObjectClass] | None = None
    ) -> Nearest | None:
        """The closest object (centre distance) at time t, or None when there is none of those classes."""
        f = self.frame_at(t_s)
        sl = self._slice(f)
        ne = self._ne[sl]
        d2 = (ne[:, 0] - north_m) ** 2 + (ne[:, 1] - east_m) ** 2
        if classes is not None:
            d2 = np.where(self._table(classes)[self._class[sl]], d2, np.inf)
        if d2.size == 0:
            return None
        k = int(np.argmin(d2))
        if not math.isfinite(d2[k]):
            return None
        row = sl.start + k
        return Nearest(int(self._track[row]), ObjectClass(int(self._class[row])), math.sqrt(float(d2[k])),
                       (float(self._ne[row, 0]), float(self._ne[row, 1])))  # fmt: skip

    def distance_m(
        self, north_m: float, east_m: float, t_s: float, classes: Iterable[ObjectClass] | None = None
    ) -> float:
        """Distance to the nearest object of those classes at time t (inf when there is none)."""
        n = self.nearest(north_m, east_m, t_s, classes)
        return math.inf if n is None else n.distance_m

    def distances_along(
        self,
        north_m: NDArray[np.float64],
        east_m: NDArray[np.float64],
        t_s: NDArray[np.float64],
        classes: Iterable[ObjectClass] | None = None,
    ) -> NDArray[np.float64]:
        """Nearest-object distance for each sample of a trajectory (inf where there is none): for scores."""
        n_arr, e_arr, t_arr = (np.asarray(a, np.float64).ravel() for a in (north_m, east_m, t_s))
        if not (n_arr.shape == e_arr.shape == t_arr.shape):
            raise ValueError("north_m, east_m and t_s must have the same length")
        if not np.all(np.isfinite(t_arr)):
            raise ValueError("times must be finite")
        frames = (
            np.zeros(t_arr.size, np.int64)
            if self.frame_count <= 1
            else np.floor(t_arr * self.fps + 1e-9).astype(np.int64) % self.frame_count
        )
        table = self._table(classes)
        out = np.full(t_arr.size, np.inf)
        order = np.argsort(frames, kind="stable")
        uniq, first, counts = np.unique(frames[order], return_index=True, return_counts=True)
        for f, a, c in zip(
            uniq.tolist(), first.tolist(), counts.tolist(), strict=True
        ):  # one block per frame
            sl = self._slice(f)
            ne = self._ne[sl][table[self._class[sl]]]
            if ne.shape[0] == 0:
                continue
            idx = order[a : a + c]
            d2 = (n_arr[idx, None] - ne[None, :, 0]) ** 2 + (e_arr[idx, None] - ne[None, :, 1]) ** 2
            out[idx] = np.sqrt(d2.min(axis=1))
        return out

    def track_path(self, track: int) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
        """(frames, (k, 2) NED positions) of one track, in frame order."""
        m = self._track == track
        return self._frame[m], self._ne[m]


def build_tracks(
    sources: Sequence[TrackSource],
    geometry: FootageGeometry,
    fps: float,
    frame_count: int | None = None,
    max_gap_frames: int = 30,
) -> TrackTable:
    """Rows from one or more sources -> a TrackTable (frame_count None: the annotated span, for tracks over a still)."""
    infos: list[TrackInfo] = []
    frames: list[NDArray[np.int64]] = []
    tracks: list[NDArray[np.int32]] = []
    centres: list[NDArray[np.float64]] = []
    sizes: list[NDArray[np.float64]] = []
    occl: list[NDArray[np.bool_]] = []
    g = geometry.gsd_m_per_px
    for src in sources:
        by_track: dict[int | None, list[BoxRow]] = {}
        for r in src.rows:
            by_track.setdefault(r.track_id, []).append(r)
        groups: list[tuple[int | None, list[BoxRow]]] = []
        for tid, rows in by_track.items():
            if tid is None:  # untracked detections: one object per row
                groups.extend((None, [r]) for r in rows)
            else:
                groups.append((tid, sorted(rows, key=lambda r: r.frame)))
        for tid, rows in groups:
            cls = class_of(rows[0].label, src.class_map)
            if cls is None:
                continue
            arr = np.array(
                [(r.frame, r.x0_px, r.y0_px, r.x1_px, r.y1_px, r.lost, r.occluded) for r in rows], np.float64
            )
            f = arr[:, 0].astype(np.int64)
            present = arr[:, 5] == 0
            cu = (arr[:, 1] + arr[:, 3]) / 2.0 - 0.5  # pixel-area edges -> pixel-centre coordinates
            cv = (arr[:, 2] + arr[:, 4]) / 2.0 - 0.5
            sz = np.stack([(arr[:, 3] - arr[:, 1]) * g, (arr[:, 4] - arr[:, 2]) * g], axis=1)
            occ = arr[:, 6] != 0
            # interpolation: consecutive annotated frames, both present, 1 < gap <= max_gap
            fi: list[NDArray[np.float64]] = [f[present].astype(np.float64)]
            ui, vi, si, oi = [cu[present]], [cv[present]], [sz[present]], [occ[present]]
            if f.size > 1:
                gap = np.diff(f)
                ks = np.nonzero(present[:-1] & present[1:] & (gap > 1) & (gap <= max_gap_frames))[0]
                for k in ks:
                    steps = np.arange(1, gap[k], dtype=np.float64)
                    w = steps / gap[k]
                    fi.append(f[k] + steps)
                    ui.append(cu[k] + w * (cu[k + 1] - cu[k]))
                    vi.append(cv[k] + w * (cv[k + 1] - cv[k]))
                    si.append(sz[k] + w[:, None] * (sz[k + 1] - sz[k]))
                    oi.append(np.full(steps.size, bool(occ[k] or occ[k + 1])))
            ff = np.concatenate(fi).astype(np.int64)
            if ff.size == 0:
                continue
            _, first = np.unique(ff, return_index=True)  # duplicate rows for one frame: keep the first
            uu, vv = np.concatenate(ui)[first], np.concatenate(vi)[first]
            idx = len(infos)
            infos.append(TrackInfo(idx, src.name, tid, cls, rows[0].label, src.derived or rows[0].derived))
            frames.append(ff[first])
            tracks.append(np.full(first.size, idx, np.int32))
            centres.append(np.stack([uu, vv], axis=1))
            sizes.append(np.concatenate(si)[first])
            occl.append(np.concatenate(oi)[first])
    if infos:
        frame = np.concatenate(frames)
        uv = np.concatenate(centres)
        m = geometry.px_to_ground
        hom = np.column_stack([uv, np.ones(len(uv))]) @ m.T
        ne = hom[:, :2] / hom[:, 2:3]
        track, size, occluded = np.concatenate(tracks), np.concatenate(sizes), np.concatenate(occl)
    else:
        frame, track = np.zeros(0, np.int64), np.zeros(0, np.int32)
        ne, size, occluded = np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, bool)
    if frame_count is None:
        frame_count = int(frame.max()) + 1 if frame.size else 1
    keep = (frame >= 0) & (frame < frame_count)
    return TrackTable(fps, frame_count, infos, frame[keep], track[keep], ne[keep], size[keep], occluded[keep])


def analytic_tracks(
    tracks: Sequence[TrackInfo],
    positions_ne_m: NDArray[np.float64],
    sizes_m: NDArray[np.float64],
    fps: float,
) -> TrackTable:
    """Tracks known at every frame: positions (frame_count, n_tracks, 2), sizes (n_tracks, 2) (synthetic field)."""
    fc, nt = positions_ne_m.shape[:2]
    frame = np.repeat(np.arange(fc, dtype=np.int64), nt)
    track = np.tile(np.arange(nt, dtype=np.int32), fc)
    size = np.tile(sizes_m, (fc, 1))
    return TrackTable(
        fps, fc, tracks, frame, track, positions_ne_m.reshape(-1, 2), size, np.zeros(fc * nt, bool)
    )
