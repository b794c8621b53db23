"""Footage metadata: one TOML file per footage (viva_sitl/data/footage/<name>.toml), read with tomllib.

A footage file (top-level keys; only `name`, `kind` and, except for synthetic, `path` are required):

    name = "interchange"                 # catalog name (what `--footage NAME` takes)
    title = "Highway interchange, Kharkiv"
    kind = "video"                       # video | still | synthetic
    path = "footage/interchange/interchange_1080p.mp4"   # relative to ../shared (or to this file), or absolute
    fps = 25.0                           # playback rate (optional for video: default = the stream's rate)
    recording_altitude_m = 470.1         # m above ground of the recording camera
    hfov_deg = 82.1                      # recording horizontal FoV ... or:
    gsd_m_per_px = 0.43                  # ground metres per footage pixel
    heading_deg = 0.0                    # bearing of footage "up" (clockwise from north)
    ground_alt_amsl_m = 0.0              # ground altitude of the geo origin (AMSL)
    home_lat_deg = 49.97                 # geo-reference: WGS84 of the footage centre ... or:
    home_lon_deg = 36.31
    corners_lonlat = [[lon, lat], ...]   # (lon, lat) of the corners TL, TR, BR, BL -> GSD, heading, centre
    srt = "clip.SRT"                     # DJI sidecar (altitude from `rel_alt:`), relative like `path`
    licence = "CC-BY-4.0"
    attribution = "..."
    source_url = "https://..."
    notes = "..."                        # how the numbers were chosen
    annotated = ["vehicle"]              # which object classes the ground truth looked for (ANNOTATED_GROUPS)

    [annotations]
    path = "footage/songdo/00003.txt"    # YOLO .txt (stills), a folder of per-frame YOLO .txt, or a MOT .txt/.csv
    format = "yolo"                      # yolo | mot
    class_names = ["vehicle"]

    [synthetic]                          # kind = "synthetic" only: SyntheticFieldParams fields

`annotated` says which classes the footage's object ground truth ([annotations], [tracks], the derived
`<stem>.tracks.csv`) looked for everywhere in the frame, so that "none there" can be told from "not looked for":
"person" (people on foot and on bikes), "vehicle" (cars, buses, trucks), "moving object" (whatever moved: the
motion-derived tracks), "all" (every object on the ground, as the synthetic field's actors). A score or a criterion
about a class that is not listed is unavailable (null), never "nobody there". Missing (older files): nothing is
declared, so nothing is assumed annotated (the synthetic field, exact by construction, counts as "all").

A catalog file (`[catalog]` table) describes a remote record (Zenodo); its files are listed at `get` time:

    [catalog]
    name = "viva-safeland"
    record_id = 13942934
    base_url = "https://zenodo.org"
    include = ["*.mp4", "*.MP4", "*.SRT", "*.srt"]
    [defaults]                           # metadata applied to each downloaded video (altitude from its .SRT)
    hfov_deg = 82.1
"""

from __future__ import annotations

import enum
import math
import tomllib
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.worldmeta import RiskSpec, TracksSpec, parse_risk, parse_tracks

VIDEO_EXTENSIONS = frozenset(
    {".mp4", ".mov", ".mkv", ".avi", ".m4v", ".webm", ".ts", ".mts", ".h264", ".hevc", ".y4m"}
)
IMAGE_EXTENSIONS = frozenset({".jpg", ".jpeg", ".png", ".tif", ".tiff", ".bmp", ".webp", ".jp2"})
ANNOTATED_GROUPS = ("person", "vehicle", "moving object", "all")  # values of `annotated`


class FootageKind(enum.Enum):
    VIDEO = "video"
    STILL = "still"
    SYNTHETIC = "synthetic"


class AnnotationFormat(enum.Enum):
    YOLO = "yolo"  # class cx cy w h (normalised), one .txt per still / per frame
    MOT = "mot"  # frame,id,x,y,w,h,conf,class,... (MOTChallenge, 1-based frames, pixels)


def kind_from_path(path: Path) -> FootageKind:
    return FootageKind.STILL if path.suffix.lower() in IMAGE_EXTENSIONS else FootageKind.VIDEO


@dataclass(frozen=True)
class FootageMetadata:
    """What a footage's metadata file says (paths resolved to absolute where they were given)."""

    name: str
    kind: FootageKind
    path: str = ""  # absolute path of the video/image (empty for synthetic)
    title: str = ""
    fps: float | None = None  # playback rate; None = the video's own rate
    recording_altitude_m: float | None = None
    hfov_deg: float | None = None
    gsd_m_per_px: float | None = None
    heading_deg: float | None = None
    ground_alt_amsl_m: float = 0.0
    home_lat_deg: float | None = None
    home_lon_deg: float | None = None
    corners_lonlat: tuple[tuple[float, float], ...] | None = None
    srt: str = ""  # absolute path of a DJI .SRT sidecar, if any
    licence: str = ""
    attribution: str = ""
    source_url: str = ""
    notes: str = ""
    annotations_path: str = ""
    annotations_format: AnnotationFormat | None = None
    class_names: tuple[str, ...] = ()
    levels: tuple[str, ...] = ()  # ingest cache: absolute paths of half-, quarter-... resolution copies
    synthetic: tuple[tuple[str, Any], ...] = ()  # kind synthetic: SyntheticFieldParams overrides
    tracks: TracksSpec | None = None  # [tracks]: objects over time (worldmeta.py)
    risk: RiskSpec | None = None  # [risk]: ground risk map (worldmeta.py)
    config_file: str = ""  # where this came from
    annotated: tuple[str, ...] | None = (
        None  # classes the object ground truth looked for (None: not declared)
    )

    def __post_init__(self) -> None:
        if not self.name:
            raise FootageError("footage metadata needs a name")
        for key in ("fps", "recording_altitude_m", "hfov_deg", "gsd_m_per_px"):
            v = getattr(self, key)
            if v is not None and not (math.isfinite(v) and v > 0.0):
                raise FootageError(f"footage {self.name!r}: {key} must be a positive number, got {v!r}")
        if self.hfov_deg is not None and self.hfov_deg >= 180.0:
            raise FootageError(f"footage {self.name!r}: hfov_deg must be < 180, got {self.hfov_deg}")
        if (self.home_lat_deg is None) != (self.home_lon_deg is None):
            raise FootageError(f"footage {self.name!r}: give both home_lat_deg and home_lon_deg, or neither")
        if self.home_lat_deg is not None and not -90.0 <= self.home_lat_deg <= 90.0:
            raise FootageError(f"footage {self.name!r}: home_lat_deg out of range: {self.home_lat_deg}")
        if self.kind is not FootageKind.SYNTHETIC and not self.path:
            raise FootageError(f"footage {self.name!r}: no path")

    def with_overrides(self, **overrides: Any) -> FootageMetadata:
        """A copy with the non-None overrides applied (explicit arguments beat the file)."""
        known = {f.name for f in fields(self)}
        updates = {k: v for k, v in overrides.items() if v is not None}
        unknown = set(updates) - known
        if unknown:
            raise FootageError(f"unknown footage metadata override(s): {', '.join(sorted(unknown))}")
        if not updates:
            return self
        values = {f.name: getattr(self, f.name) for f in fields(self)}
        values.update(updates)
        return FootageMetadata(**values)


@dataclass(frozen=True)
class CatalogSpec:
    """A remote record whose files can be downloaded with `viva-sitl footage get NAME`."""

    name: str
    record_id: int
    base_url: str = "https://zenodo.org"
    title: str = ""
    include: tuple[str, ...] = ("*.mp4", "*.MP4", "*.mov", "*.MOV", "*.SRT", "*.srt")
    licence: str = ""
    attribution: str = ""
    source_url: str = ""
    notes: str = ""
    defaults: tuple[tuple[str, Any], ...] = field(default=())  # metadata applied to each downloaded video
    config_file: str = ""

    @property
    def record_url(self) -> str:
        return f"{self.base_url.rstrip('/')}/api/records/{self.record_id}"


_META_KEYS = {f.name for f in fields(FootageMetadata)} - {
    "annotations_path",
    "annotations_format",
    "class_names",
    "synthetic",
    "tracks",
    "risk",
    "config_file",
}
_CATALOG_KEYS = {f.name for f in fields(CatalogSpec)} - {"defaults", "config_file"}


def _num(table: dict[str, Any], key: str, where: str) -> float | None:
    v = table.get(key)
    if v is None:
        return None
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise FootageError(f"{where}: {key} must be a number, got {v!r}")
    return float(v)


def _resolve(rel: str, base_dirs: tuple[Path, ...]) -> str:
    """Absolute path: as given if absolute, else the first base dir under which it exists (else the first base)."""
    p = Path(rel).expanduser()
    if p.is_absolute():
        return str(p)
    for base in base_dirs:
        if (base / p).exists():
            return str((base / p).resolve())
    return str((base_dirs[0] / p).resolve())


def _annotated(v: Any, where: str) -> tuple[str, ...]:
    if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
        raise FootageError(
            f"{where}: annotated must be a list of class names ({', '.join(ANNOTATED_GROUPS)})"
        )
    bad = [x for x in v if x.strip().lower() not in ANNOTATED_GROUPS]
    if bad:
        raise FootageError(
            f"{where}: annotated: unknown class {bad[0]!r} (one of {', '.join(ANNOTATED_GROUPS)})"
        )
    return tuple(sorted({x.strip().lower() for x in v}))


def read_toml(path: Path) -> dict[str, Any]:
    try:
        with path.open("rb") as f:
            return tomllib.load(f)
    except OSError as exc:
        raise FootageError(f"cannot read footage metadata {path}: {exc.strerror or exc}") from None
    except tomllib.TOMLDecodeError as exc:
        raise FootageError(f"footage metadata {path} is not valid TOML: {exc}") from None


def metadata_from_table(
    table: dict[str, Any], *, where: str, base_dirs: tuple[Path, ...], name: str | None = None
) -> FootageMetadata:
    """Build FootageMetadata from a parsed TOML table; relative paths resolve against `base_dirs` in order."""
    table = dict(table)
    ann = table.pop("annotations", None)
    synth = table.pop("synthetic", None)
    tracks = table.pop("tracks", None)
    risk = table.pop("risk", None)
    unknown = set(table) - _META_KEYS
    if unknown:
        raise FootageError(f"{where}: unknown key(s) {', '.join(sorted(unknown))}")
    kind_text = str(table.get("kind", "video")).lower()
    try:
        kind = FootageKind(kind_text)
    except ValueError:
        raise FootageError(f"{where}: kind must be video, still or synthetic, got {kind_text!r}") from None
    corners = table.get("corners_lonlat")
    corners_t: tuple[tuple[float, float], ...] | None = None
    if corners is not None:
        try:
            corners_t = tuple((float(c[0]), float(c[1])) for c in corners)
        except (TypeError, ValueError, IndexError):
            raise FootageError(f"{where}: corners_lonlat must be 4 [lon, lat] pairs") from None
        if len(corners_t) != 4:
            raise FootageError(f"{where}: corners_lonlat must be 4 [lon, lat] pairs (TL, TR, BR, BL)")
    path = table.get("path", "")
    srt = table.get("srt", "")
    values: dict[str, Any] = {
        "name": str(table.get("name") or name or ""),
        "kind": kind,
        "path": _resolve(str(path), base_dirs) if path else "",
        "title": str(table.get("title", "")),
        "srt": _resolve(str(srt), base_dirs) if srt else "",
        "corners_lonlat": corners_t,
        "levels": tuple(_resolve(str(p), base_dirs) for p in table.get("levels", ())),
        "config_file": where,
    }
    for key in (
        "fps",
        "recording_altitude_m",
        "hfov_deg",
        "gsd_m_per_px",
        "heading_deg",
        "home_lat_deg",
        "home_lon_deg",
    ):
        values[key] = _num(table, key, where)
    values["ground_alt_amsl_m"] = _num(table, "ground_alt_amsl_m", where) or 0.0
    for key in ("licence", "attribution", "source_url", "notes"):
        values[key] = str(table.get(key, ""))
    if "annotated" in table:
        values["annotated"] = _annotated(table["annotated"], where)
    if ann is not None:
        if not isinstance(ann, dict) or "path" not in ann:
            raise FootageError(f"{where}: [annotations] needs a path")
        fmt = str(ann.get("format", "yolo")).lower()
        try:
            values["annotations_format"] = AnnotationFormat(fmt)
        except ValueError:
            raise FootageError(f"{where}: annotations format must be yolo or mot, got {fmt!r}") from None
        values["annotations_path"] = _resolve(str(ann["path"]), base_dirs)
        values["class_names"] = tuple(str(c) for c in ann.get("class_names", ()))
    if synth is not None:
        if not isinstance(synth, dict):
            raise FootageError(f"{where}: [synthetic] must be a table")
        values["synthetic"] = tuple(sorted(synth.items()))
    if tracks is not None:
        values["tracks"] = parse_tracks(tracks, where, lambda rel: _resolve(rel, base_dirs))
    if risk is not None:
        values["risk"] = parse_risk(
            risk, where, Path(where).parent if where.endswith(".toml") else base_dirs[-1]
        )
    return FootageMetadata(**values)


def catalog_from_table(table: dict[str, Any], *, where: str) -> CatalogSpec:
    cat = dict(table["catalog"])
    unknown = set(cat) - _CATALOG_KEYS
    if unknown:
        raise FootageError(f"{where}: unknown [catalog] key(s) {', '.join(sorted(unknown))}")
    try:
        record_id = int(cat.pop("record_id"))
        name = str(cat.pop("name"))
    except (KeyError, TypeError, ValueError):
        raise FootageError(f"{where}: [catalog] needs name and an integer record_id") from None
    if "include" in cat:
        cat["include"] = tuple(str(p) for p in cat["include"])
    defaults = table.get("defaults", {})
    if not isinstance(defaults, dict):
        raise FootageError(f"{where}: [defaults] must be a table")
    return CatalogSpec(
        name=name, record_id=record_id, defaults=tuple(sorted(defaults.items())), config_file=where, **cat
    )


def load_metadata_file(path: Path, *, shared_dir: Path | None = None) -> FootageMetadata | CatalogSpec:
    """Parse one footage .toml: relative paths resolve against `shared_dir`, then the file's own folder."""
    table = read_toml(path)
    if "catalog" in table:
        return catalog_from_table(table, where=str(path))
    bases = (shared_dir, path.parent) if shared_dir is not None else (path.parent,)
    return metadata_from_table(table, where=str(path), base_dirs=bases, name=path.stem)


def load_config_dir(
    config_dir: Path, *, shared_dir: Path | None = None
) -> dict[str, FootageMetadata | CatalogSpec]:
    """Every metadata/catalog file in a folder, by name (a bad file raises FootageError naming it)."""
    entries: dict[str, FootageMetadata | CatalogSpec] = {}
    if not config_dir.is_dir():
        return entries
    for f in sorted(config_dir.glob("*.toml")):
        meta = load_metadata_file(f, shared_dir=shared_dir)
        if meta.name in entries:
            raise FootageError(
                f"duplicate footage name {meta.name!r} in {f} and {entries[meta.name].config_file}"
            )
        entries[meta.name] = meta
    return entries
