"""The `[tracks]` and `[risk]` tables of a footage metadata file (ground truth for viva_sitl.world), validated.

    [tracks]                               # objects over time (besides [annotations], which also count)
    path = "footage/sdd/nexus_video5/annotations.txt"   # resolved like `path` (../shared, then this file's folder)
    format = "sdd"                         # sdd | motchallenge | visdrone | coco | viva
    fps = 30.0                             # the annotations' clock (needed over a still; default: the footage's)
    max_gap_frames = 30                    # interpolate between annotated frames up to this gap
    class_map = { Cart = "car" }           # label -> world class overrides (world/classes.py has the table)

    [risk]                                 # SORA-style ground risk, levels 1 (open ground) .. 5 (people, busy road)
    polygons = "nexus.risk.json"           # relative to this file: polygons in footage pixels (or NED metres)
    raster = "x.png"                       # ... or a label raster: pixel value = level (0 = default_level)
    default_level = 3                      # ground no polygon covers
    accuracy_m = 2.0                       # how far a polygon edge may be off on the ground (planners keep this
                                           # margin; missing: 2 m assumed for a map, 0 for the synthetic field)
    levels = { lawn = 1, road = 4 }        # class -> level overrides of the default table (world/risk.py)
    [risk.objects]                         # moving objects raise the level around them
    person = { level = 5, buffer_m = 5.0 } # within buffer_m (+ half the object's size) of its centre

Besides, `<metadata stem>.tracks.csv` beside the metadata file (written by `viva-sitl footage annotate`) is read as
`viva` tracks of derived objects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from viva_sitl.footage.boxfiles import TrackFormat
from viva_sitl.footage.errors import FootageError

DERIVED_SUFFIX = ".tracks.csv"


def derived_tracks_path(config_file: str | Path) -> Path | None:
    """Where a footage's derived tracks live (`footage annotate` writes them, the world model reads them):
    `<metadata stem>.tracks.csv` beside its metadata file; None when the footage has no .toml metadata file."""
    cfg = Path(config_file)
    return cfg.with_name(cfg.stem + DERIVED_SUFFIX) if cfg.suffix == ".toml" else None


OBJECT_CLASS_LABELS = ("person", "bicycle", "car", "bus", "truck", "other", "moving object")
_TRACK_KEYS = {"path", "format", "fps", "max_gap_frames", "class_map"}
_RISK_KEYS = {"polygons", "raster", "default_level", "levels", "objects", "notes", "accuracy_m"}


@dataclass(frozen=True)
class TracksSpec:
    path: str  # absolute
    format: TrackFormat
    fps: float | None = None
    max_gap_frames: int = 30
    class_map: tuple[tuple[str, str], ...] = ()


@dataclass(frozen=True)
class RiskSpec:
    polygons: str = ""  # absolute path of the polygon json
    raster: str = ""  # absolute path of a label raster
    default_level: int = 3
    levels: tuple[tuple[str, int], ...] = ()
    objects: tuple[tuple[str, int, float], ...] = ()  # (class, level, buffer_m)
    notes: str = field(default="")
    accuracy_m: float | None = None  # stated accuracy of the map on the ground (None: not stated)


def _level(v: Any, where: str, what: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or not 1 <= v <= 5:
        raise FootageError(f"{where}: {what} must be a risk level 1..5, got {v!r}")
    return int(v)


def parse_tracks(table: Any, where: str, resolve: Any) -> TracksSpec:
    if not isinstance(table, dict) or "path" not in table:
        raise FootageError(f"{where}: [tracks] needs a path")
    unknown = set(table) - _TRACK_KEYS
    if unknown:
        raise FootageError(f"{where}: unknown [tracks] key(s) {', '.join(sorted(unknown))}")
    fmt_text = str(table.get("format", "")).lower()
    allowed = [f.value for f in TrackFormat if f not in (TrackFormat.YOLO, TrackFormat.MOT)]
    if fmt_text not in allowed:
        raise FootageError(f"{where}: [tracks] format must be one of {', '.join(allowed)}, got {fmt_text!r}")
    fps = table.get("fps")
    if fps is not None and (isinstance(fps, bool) or not isinstance(fps, int | float) or not fps > 0
                            or not math.isfinite(fps)):  # fmt: skip
        raise FootageError(f"{where}: [tracks] fps must be a positive number, got {fps!r}")
    gap = table.get("max_gap_frames", 30)
    if isinstance(gap, bool) or not isinstance(gap, int) or gap < 1:
        raise FootageError(f"{where}: [tracks] max_gap_frames must be an integer >= 1, got {gap!r}")
    cmap = table.get("class_map", {})
    if not isinstance(cmap, dict):
        raise FootageError(f'{where}: [tracks] class_map must be a table of label = "class"')
    for k, v in cmap.items():
        if str(v).lower() not in OBJECT_CLASS_LABELS:
            raise FootageError(
                f"{where}: [tracks] class_map {k} = {v!r}: class must be one of {', '.join(OBJECT_CLASS_LABELS)}"
            )
    return TracksSpec(resolve(str(table["path"])), TrackFormat(fmt_text), None if fps is None else float(fps),
                      gap, tuple(sorted((str(k), str(v).lower()) for k, v in cmap.items())))  # fmt: skip


def parse_risk(table: Any, where: str, own_dir: Path) -> RiskSpec:
    if not isinstance(table, dict):
        raise FootageError(f"{where}: [risk] must be a table")
    unknown = set(table) - _RISK_KEYS
    if unknown:
        raise FootageError(f"{where}: unknown [risk] key(s) {', '.join(sorted(unknown))}")
    if "polygons" in table and "raster" in table:
        raise FootageError(f"{where}: [risk] takes polygons or raster, not both")
    levels = table.get("levels", {})
    if not isinstance(levels, dict):
        raise FootageError(f"{where}: [risk] levels must be a table of class = level")
    lv = tuple(sorted((str(k), _level(v, where, f"[risk] levels.{k}")) for k, v in levels.items()))
    objs = table.get("objects", {})
    if not isinstance(objs, dict):
        raise FootageError(f"{where}: [risk.objects] must be a table")
    ob: list[tuple[str, int, float]] = []
    for k, v in objs.items():
        if str(k).lower() not in OBJECT_CLASS_LABELS:
            raise FootageError(
                f"{where}: [risk.objects] {k}: not an object class ({', '.join(OBJECT_CLASS_LABELS)})"
            )
        if not isinstance(v, dict) or set(v) - {"level", "buffer_m"}:
            raise FootageError(f"{where}: [risk.objects] {k} must be {{ level = 1..5, buffer_m = metres }}")
        b = v.get("buffer_m", 0.0)
        if isinstance(b, bool) or not isinstance(b, int | float) or not 0 <= b < math.inf:
            raise FootageError(f"{where}: [risk.objects] {k}.buffer_m must be a number >= 0, got {b!r}")
        ob.append((str(k).lower(), _level(v.get("level", 5), where, f"[risk.objects] {k}.level"), float(b)))

    def rel(key: str) -> str:
        v = table.get(key)
        if v is None:
            return ""
        p = Path(str(v)).expanduser()
        return str(p if p.is_absolute() else (own_dir / p).resolve())

    acc = table.get("accuracy_m")
    if acc is not None and (
        isinstance(acc, bool) or not isinstance(acc, int | float) or not 0 <= acc < math.inf
    ):
        raise FootageError(f"{where}: [risk] accuracy_m must be a number of metres >= 0, got {acc!r}")
    return RiskSpec(rel("polygons"), rel("raster"), _level(table.get("default_level", 3), where, "[risk] default_level"),
                    lv, tuple(sorted(ob)), str(table.get("notes", "")),
                    None if acc is None else float(acc))  # fmt: skip
