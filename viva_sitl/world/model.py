"""One world model per footage: object tracks over sim time + the static risk map; `load_world(NAME)` builds it.

    world = load_world("synthetic")                     # or a catalog name / path, like open_footage
    world.tracks.nearest(n, e, t, PEOPLE)               # Nearest(track, object_class, distance_m, ne_m) | None
    world.tracks.within(n, e, 10.0, t, VEHICLES)        # Objects (arrays) within 10 m
    world.tracks.objects_at(t)                          # everything present at t
    world.tracks.distances_along(n_arr, e_arr, t_arr, PEOPLE)   # per-sample nearest distance (scores)
    world.risk_at(n, e, t)                              # level 1..5: static map, raised near moving objects
    world.has_objects / world.has_risk_map              # False: scores that need them are "unavailable"
    world.answers("person")                             # the object ground truth looked for people (see below)

What the object ground truth can answer: the footage metadata's `annotated` list (footage/metadata.py) names the
classes that were looked for everywhere; "nobody of class X here" is only known for those. answers(group) for the
score groups "person", "vehicle" and "object" (any object: needs "all", or "person" and "vehicle"). The synthetic
field is "all" (its actors are exact); a footage that declares nothing answers nothing (conservative: older
metadata files make person / vehicle / object scores unavailable until they say what was annotated).

Sources of objects, all merged: the synthetic field's actors (exact), `[annotations]` (yolo/mot, via the footage
source), `[tracks]` (sdd/motchallenge/visdrone/coco/viva), and `<metadata stem>.tracks.csv` beside the metadata
file (derived by `viva-sitl footage annotate`). Building reads files; every query afterwards is pure.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from viva_sitl.footage.boxfiles import BoxRow, TrackFormat, read_boxes
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.footage.loader import open_footage, resolve_metadata
from viva_sitl.footage.metadata import FootageKind, FootageMetadata
from viva_sitl.footage.source import FootageSource
from viva_sitl.footage.synthetic import SyntheticField
from viva_sitl.footage.synthetic_actors import DEFAULT_ACTORS, actor_position_ne_m, scene_risk_polygons_ne_m
from viva_sitl.footage.worldmeta import derived_tracks_path
from viva_sitl.world.classes import ObjectClass
from viva_sitl.world.risk import (
    DEFAULT_CLASS_LEVELS,
    RiskMap,
    RiskPolygon,
    read_polygons,
    risk_map_from_polygons,
    risk_map_from_raster,
)
from viva_sitl.world.tracks import TrackInfo, TrackSource, TrackTable, analytic_tracks, build_tracks

DEFAULT_RISK_ACCURACY_M = 2.0  # a risk map whose metadata states no accuracy_m


@dataclass(frozen=True)
class ObjectRisk:
    level: int  # 1..5 inside the buffer
    buffer_m: float  # metres beyond half the object's larger ground size


DEFAULT_OBJECT_RISK: dict[ObjectClass, ObjectRisk] = {
    ObjectClass.PERSON: ObjectRisk(5, 5.0),
    ObjectClass.BICYCLE: ObjectRisk(5, 5.0),
    ObjectClass.CAR: ObjectRisk(4, 3.0),
    ObjectClass.BUS: ObjectRisk(4, 3.0),
    ObjectClass.TRUCK: ObjectRisk(4, 3.0),
    ObjectClass.OTHER: ObjectRisk(3, 2.0),
    ObjectClass.MOVING: ObjectRisk(4, 3.0),
}


class WorldModel:
    """Ground truth of one footage; all methods are pure (no I/O) and cheap enough for the physics rate."""

    def __init__(
        self,
        name: str,
        geometry: FootageGeometry,
        tracks: TrackTable,
        risk_map: RiskMap,
        object_risk: dict[ObjectClass, ObjectRisk] | None = None,
        has_objects: bool = True,
        has_risk_map: bool = True,
        class_levels: dict[str, int] | None = None,
        annotated: frozenset[str] | None = None,
        risk_accuracy_m: float = 0.0,
    ) -> None:
        self.name = name
        self.geometry = geometry
        self.tracks = tracks
        self.risk_map = risk_map
        self.object_risk = dict(DEFAULT_OBJECT_RISK)
        self.object_risk.update(object_risk or {})
        self.has_objects = has_objects
        self.has_risk_map = has_risk_map
        self.class_levels = dict(class_levels or DEFAULT_CLASS_LEVELS)
        # the classes the object ground truth looked for (metadata `annotated`); empty: unknown, answers nothing
        self.annotated = frozenset(annotated or ()) if has_objects else frozenset()
        # how far the risk map's edges may be off on the ground (metadata [risk] accuracy_m; planners keep it)
        self.risk_accuracy_m = float(risk_accuracy_m)
        self._obj_level = np.array([self.object_risk[c].level for c in ObjectClass], np.uint8)
        self._obj_buffer = np.array([self.object_risk[c].buffer_m for c in ObjectClass], np.float64)
        # per presence row: the level it imposes and the squared reach (buffer + half its larger ground size)
        reach = self._obj_buffer[tracks.row_class] + 0.5 * (
            tracks.row_size_m.max(axis=1) if len(tracks.row_size_m) else np.zeros(0)
        )
        self._row_reach2 = reach * reach
        self._row_level = self._obj_level[tracks.row_class]

    def answers(self, group: str) -> bool:
        """Whether the object ground truth can answer questions about `group` ("person", "vehicle", "object"):
        the class was annotated, so no track of it means nobody there (not: nobody looked)."""
        a = self.annotated
        if "all" in a:
            return True
        if group == "object":
            return {"person", "vehicle"} <= a
        if group in ("person", "vehicle"):
            return group in a
        raise ValueError(f"unknown object group {group!r} (person, vehicle, object)")

    def static_risk_at(self, north_m: float, east_m: float) -> int:
        return self.risk_map.level_at(north_m, east_m)

    def risk_at(self, north_m: float, east_m: float, t_s: float) -> int:
        """Risk level 1..5 at (north, east) at sim time t: the ground's, raised near moving objects."""
        level = self.risk_map.level_at(north_m, east_m)
        if level >= 5:
            return level
        sl = self.tracks.frame_slice(t_s)
        if sl.start == sl.stop:
            return level
        ne = self.tracks.row_ne_m[sl]
        d2 = (ne[:, 0] - north_m) ** 2 + (ne[:, 1] - east_m) ** 2
        hit = d2 <= self._row_reach2[sl]
        if hit.any():
            level = max(level, int(self._row_level[sl][hit].max()))
        return level

    def risk_levels_at(
        self, north_m: NDArray[np.float64], east_m: NDArray[np.float64], t_s: float
    ) -> NDArray[np.uint8]:
        """risk_at for arrays of points at one time (a grid for overlays or for choosing a landing spot)."""
        n = np.asarray(north_m, np.float64)
        e = np.asarray(east_m, np.float64)
        out = self.risk_map.levels_at(n, e)
        objs = self.tracks.objects_at(t_s)
        for k in range(len(objs)):  # objects are few per frame; points can be many
            c = int(objs.object_class[k])
            reach = self._obj_buffer[c] + 0.5 * float(objs.size_m[k].max())
            d2 = (n - objs.ne_m[k, 0]) ** 2 + (e - objs.ne_m[k, 1]) ** 2
            np.maximum(out, np.where(d2 <= reach * reach, self._obj_level[c], 0).astype(np.uint8), out=out)
        return out

    def describe(self) -> dict[str, str]:
        t = self.tracks
        return {
            "world": self.name,
            "objects": ", ".join(f"{n} {k}" for k, n in sorted(t.count_by_class().items())) or "none",
            "track_clock": f"{t.frame_count} frames at {t.fps:g} fps ({t.duration_s:.1f} s, loops)",
            "risk_map": ("hand-made " if self.risk_map.hand_made else "")
            + (
                f"{len(self.risk_map.polygons)} polygons ({self.risk_map.units})"
                if self.has_risk_map
                else "none"
            )
            + f", default level {self.risk_map.default_level}",
            "risk_accuracy_m": f"{self.risk_accuracy_m:g}",
            "annotated": ", ".join(sorted(self.annotated))
            or "not declared (person/vehicle/object scores unavailable)",
        }


def annotation_rows(src: FootageSource, frames: range) -> list[BoxRow]:
    """The footage's [annotations] (yolo/mot via the source) as rows."""
    out: list[BoxRow] = []
    for i in frames:
        for a in src.annotations(i):
            x0, y0, x1, y1 = a.box_px
            out.append(BoxRow(i, a.track_id, a.label, x0, y0, x1, y1, False, False, a.confidence, False))
    return out


def synthetic_tracks(field: SyntheticField) -> TrackTable:
    """The synthetic field's actors sampled at every frame time index / fps: exact, as drawn."""
    actors = DEFAULT_ACTORS
    fc = field.frame_count
    pos = np.array(
        [[actor_position_ne_m(a, field.time_of(i)) for a in actors] for i in range(fc)], np.float64
    )
    infos = [TrackInfo(k, "synthetic", k, ObjectClass.parse(a.object_class), a.name, False)
             for k, a in enumerate(actors)]  # fmt: skip
    sizes = np.array([a.size_m for a in actors], np.float64)
    return analytic_tracks(infos, pos, sizes, field.fps)


def _risk_for(meta: FootageMetadata, geometry: FootageGeometry, synthetic: bool) -> tuple[RiskMap, bool, dict[str, int]]:  # fmt: skip
    spec = meta.risk
    levels = dict(DEFAULT_CLASS_LEVELS)
    if spec is not None:
        levels.update(dict(spec.levels))
    default = spec.default_level if spec is not None else (1 if synthetic else 3)
    if spec is not None and spec.polygons:
        polys, units, hand, notes, size = read_polygons(Path(spec.polygons), levels)
        return (
            risk_map_from_polygons(polys, geometry, default, units, hand, notes or spec.notes, size),
            True,
            levels,
        )
    if spec is not None and spec.raster:
        return risk_map_from_raster(Path(spec.raster), geometry, default), True, levels
    if synthetic:
        polys = [RiskPolygon(c, levels[c], np.array(p, np.float64)) for c, p in scene_risk_polygons_ne_m()]
        notes = "exact by construction: the polygons the field is drawn with (synthetic_actors.py)"
        return risk_map_from_polygons(polys, geometry, default, "ned_m", False, notes), True, levels
    return RiskMap.uniform(default), False, levels


def world_from_source(src: FootageSource, meta: FootageMetadata | None = None) -> WorldModel:
    """Build the world of an open footage (`meta`: the metadata file's record, for [tracks]/[risk])."""
    meta = meta or src.metadata
    synthetic = isinstance(src, SyntheticField)
    sources: list[TrackSource] = []
    still = meta.kind is FootageKind.STILL or src.frame_count <= 1
    fps, frame_count = src.fps, src.frame_count
    if meta.tracks is not None:
        t = meta.tracks
        rows = read_boxes(Path(t.path), t.format)
        sources.append(
            TrackSource(t.format.value, rows, dict(t.class_map) or None, t.format is TrackFormat.VIVA)
        )
        if t.fps is not None:
            fps = t.fps
        if still:
            frame_count = max((r.frame for r in rows), default=0) + 1
    derived = derived_tracks_path(meta.config_file)
    if derived is not None and derived.is_file():
        sources.append(TrackSource("motion", read_boxes(derived, TrackFormat.VIVA), None, True))
    if meta.annotations_path and not synthetic:
        rows = annotation_rows(src, range(1 if still else src.frame_count))
        if still and frame_count > 1:  # static boxes over a still with tracks: present at every track frame
            rows = [
                r._replace(frame=f, track_id=-1 - k) for f in range(frame_count) for k, r in enumerate(rows)
            ]
        sources.append(TrackSource("annotations", rows, None, False))
    if synthetic:
        assert isinstance(src, SyntheticField)
        tracks = synthetic_tracks(src)  # the actors are the exact truth; other sources are not merged here
    else:
        max_gap = meta.tracks.max_gap_frames if meta.tracks is not None else 30
        tracks = build_tracks(sources, src.geometry, fps, frame_count, max_gap)
    risk, has_risk, levels = _risk_for(meta, src.geometry, synthetic)
    object_risk: dict[ObjectClass, ObjectRisk] = {}
    if meta.risk is not None:
        for cls_name, level, buffer_m in meta.risk.objects:
            object_risk[ObjectClass.parse(cls_name)] = ObjectRisk(level, buffer_m)
    annotated = frozenset({"all"}) if synthetic else frozenset(meta.annotated or ())
    stated = meta.risk.accuracy_m if meta.risk is not None else None
    # unstated: the synthetic field's map is exact (drawn from the same polygons); any other map is taken as
    # good to DEFAULT_RISK_ACCURACY_M (a hand-drawn edge at a few px of GSD)
    accuracy = stated if stated is not None else (0.0 if synthetic else DEFAULT_RISK_ACCURACY_M)
    return WorldModel(meta.name, src.geometry, tracks, risk, object_risk, synthetic or bool(sources), has_risk,
                      levels, annotated, accuracy)  # fmt: skip


def load_world(
    spec: str | Path | None,
    *,
    shared_dir: str | Path | None = None,
    config_dir: str | Path | None = None,
    cache_dir: str | Path | None = None,
) -> WorldModel:
    """The world model of a footage (catalog name, path, or None/"synthetic"); FootageError on bad input."""
    shared = Path(shared_dir) if shared_dir is not None else None
    configs = Path(config_dir) if config_dir is not None else None
    cache = Path(cache_dir) if cache_dir is not None else None
    meta = resolve_metadata(spec, shared_dir=shared, config_dir=configs, cache_dir=cache)
    with open_footage(spec, shared_dir=shared, config_dir=configs, cache_dir=cache) as src:
        return world_from_source(src, meta)
