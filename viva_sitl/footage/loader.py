"""`open_footage`: a catalog name, a path or nothing (the synthetic field) -> an open FootageSource.

Resolution of `spec`:
  None or "synthetic"            the built-in synthetic calibration field (data/footage/synthetic.toml may tune it)
  an existing path               a video/image (metadata from `clip.toml`/`clip.mp4.toml` beside it, a catalog entry
                                 with that path, a DJI `clip.SRT` sidecar and the keyword overrides), a metadata .toml,
                                 or an ingest-cache folder (its footage.toml)
  a NAME                         the catalog (viva_sitl/data/footage/*.toml), then the ingest cache (<cache>/ingest/*/footage.toml), then
                                 downloaded catalog files "CATALOG/FILE" (e.g. viva-safeland/clip01)
Explicit keyword overrides (altitude_m, hfov_deg, gsd_m_per_px, heading_deg, fps) beat every file.
"""

from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

from viva_sitl.footage import autocache
from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.exif import read_photo_scale
from viva_sitl.footage.geometry import FootageGeometry, corners_fit
from viva_sitl.footage.metadata import (
    IMAGE_EXTENSIONS,
    VIDEO_EXTENSIONS,
    CatalogSpec,
    FootageKind,
    FootageMetadata,
    kind_from_path,
    load_config_dir,
    load_metadata_file,
    metadata_from_table,
    read_toml,
)
from viva_sitl.footage.paths import default_cache_dir, default_config_dir, default_shared_dir
from viva_sitl.footage.source import FootageSource, StillSource, VideoSource
from viva_sitl.footage.srt import find_srt_sidecar, parse_srt
from viva_sitl.footage.synthetic import SyntheticField, SyntheticFieldParams, synthetic_metadata
from viva_sitl.footage.tiles import TileSettings, TileSource, is_tile_cache, process_settings
from viva_sitl.geo import GeoOrigin

log = logging.getLogger(__name__)

# The last resort for footage nobody describes: the paper's DJI Mini 4 Pro FoV taken as horizontal, and a stated
# altitude (a typical survey hover height).
DEFAULT_HFOV_DEG = 82.1
DEFAULT_ALTITUDE_M = 100.0

INGEST_SUBDIR = "ingest"
DOWNLOAD_SUBDIR = "downloads"
INGEST_METADATA = "footage.toml"


def geometry_for(meta: FootageMetadata, width_px: int, height_px: int) -> FootageGeometry:
    """The ground geometry a metadata record implies for a width x height picture (explicit values beat derived)."""
    gsd = meta.gsd_m_per_px
    heading = meta.heading_deg
    origin: GeoOrigin | None = None
    if meta.home_lat_deg is not None and meta.home_lon_deg is not None:
        origin = GeoOrigin(meta.home_lat_deg, meta.home_lon_deg, meta.ground_alt_amsl_m)
    if meta.corners_lonlat is not None:
        try:
            c_gsd, c_heading, c_origin, residual = corners_fit(
                width_px, height_px, meta.corners_lonlat, meta.ground_alt_amsl_m
            )
        except ValueError as exc:
            raise FootageError(f"footage {meta.name!r}: {exc}") from None
        if residual > 0.05 * c_gsd * max(width_px, height_px):
            log.warning(
                "footage %s: corners are not a rectangle of the picture's shape (misfit %.1f m)",
                meta.name,
                residual,
            )
        gsd = gsd if gsd is not None else c_gsd
        heading = heading if heading is not None else c_heading
        origin = origin or c_origin
    alt = meta.recording_altitude_m
    if gsd is None:
        if alt is None or meta.hfov_deg is None:
            raise FootageError(
                f"footage {meta.name!r}: the ground scale is unknown; give gsd_m_per_px, corners_lonlat, or "
                "recording_altitude_m with hfov_deg (a DJI .SRT sidecar gives the altitude)"
            )
        return FootageGeometry.from_fov(width_px, height_px, alt, meta.hfov_deg, heading or 0.0, origin)
    if alt is None:
        if meta.hfov_deg is None:
            raise FootageError(
                f"footage {meta.name!r}: the recording altitude is unknown; give recording_altitude_m or hfov_deg "
                "(or a DJI .SRT sidecar with rel_alt)"
            )
        alt = width_px * gsd / (2.0 * math.tan(math.radians(meta.hfov_deg) / 2.0))
    try:
        return FootageGeometry(width_px, height_px, gsd, alt, heading or 0.0, origin)
    except ValueError as exc:
        raise FootageError(f"footage {meta.name!r}: {exc}") from None


def with_srt_sidecar(meta: FootageMetadata) -> FootageMetadata:
    """Fill the altitude (and the geo origin) from a DJI .SRT sidecar when the metadata lacks them."""
    srt = Path(meta.srt) if meta.srt else (find_srt_sidecar(Path(meta.path)) if meta.path else None)
    if srt is None or (meta.recording_altitude_m is not None and meta.home_lat_deg is not None):
        return meta
    track = parse_srt(srt)
    updates: dict[str, Any] = {"srt": str(srt)}
    if meta.recording_altitude_m is None:
        if track.rel_alt_m is None or track.rel_alt_m <= 0:
            log.info("%s: no positive rel_alt: altitude in the SRT sidecar", srt)
        else:
            updates["recording_altitude_m"] = track.rel_alt_m
    pos = track.lat_lon_deg
    if meta.home_lat_deg is None and meta.corners_lonlat is None and pos is not None:
        updates["home_lat_deg"], updates["home_lon_deg"] = pos
    return meta.with_overrides(**updates)


def _scale_missing(meta: FootageMetadata) -> bool:
    has_gsd = meta.gsd_m_per_px is not None or meta.corners_lonlat is not None
    if has_gsd:
        return meta.recording_altitude_m is None and meta.hfov_deg is None
    return meta.recording_altitude_m is None or meta.hfov_deg is None


def with_photo_metadata(meta: FootageMetadata) -> FootageMetadata:
    """Fill what a still's own DJI XMP / EXIF say (altitude, FoV, GPS position, gimbal heading) where the metadata
    file and the SRT are silent."""
    if meta.kind is not FootageKind.STILL or not meta.path:
        return meta
    need_place = meta.home_lat_deg is None and meta.corners_lonlat is None
    if not (_scale_missing(meta) or need_place or meta.heading_deg is None):
        return meta
    photo = read_photo_scale(Path(meta.path))
    updates: dict[str, Any] = {}
    rel_alt = photo.relative_altitude_m
    if meta.recording_altitude_m is None and rel_alt is not None and rel_alt > 0:
        updates["recording_altitude_m"] = rel_alt
    if meta.hfov_deg is None and photo.hfov_deg is not None:
        updates["hfov_deg"] = photo.hfov_deg
    if need_place and photo.lat_deg is not None and photo.lon_deg is not None:
        updates["home_lat_deg"], updates["home_lon_deg"] = photo.lat_deg, photo.lon_deg
    if meta.heading_deg is None and meta.corners_lonlat is None and photo.heading_deg is not None:
        updates["heading_deg"] = photo.heading_deg
    if photo.gimbal_pitch_deg is not None and abs(photo.gimbal_pitch_deg + 90.0) > 10.0:
        log.warning(
            "footage %s: the gimbal pitch was %.0f deg, not nadir (-90): the ground scale will be off",
            meta.name, photo.gimbal_pitch_deg,
        )  # fmt: skip
    if updates and photo.source:
        log.info("footage %s: from the photo's metadata: %s", meta.name, photo.source)
    return meta.with_overrides(**updates)


def with_default_scale(meta: FootageMetadata) -> FootageMetadata:
    """The paper's defaults for what no source gave (82.1 deg horizontal FoV, DEFAULT_ALTITUDE_M), with ONE
    warning line saying what was assumed and how to set it."""
    if meta.kind is FootageKind.SYNTHETIC or not _scale_missing(meta):
        return meta
    has_gsd = meta.gsd_m_per_px is not None or meta.corners_lonlat is not None
    updates: dict[str, Any] = {}
    if meta.hfov_deg is None:
        updates["hfov_deg"] = DEFAULT_HFOV_DEG
    if meta.recording_altitude_m is None and not has_gsd:
        updates["recording_altitude_m"] = DEFAULT_ALTITUDE_M
    assumed = ", ".join(
        f"{'altitude' if k == 'recording_altitude_m' else 'horizontal FoV'} {v:g} {'m' if k == 'recording_altitude_m' else 'deg'}"
        for k, v in updates.items()
    )
    log.warning(
        "footage %s: no recording scale in a metadata file, DJI .SRT or photo XMP/EXIF; assuming the paper's "
        "defaults (%s); set --footage-alt and --footage-hfov or --footage-gsd to fix the scale",
        meta.name, assumed,
    )  # fmt: skip
    return meta.with_overrides(**updates)


def with_scale_sources(meta: FootageMetadata) -> FootageMetadata:
    """Metadata file (given) -> DJI .SRT sidecar -> photo XMP/EXIF -> the paper's defaults (one warning)."""
    return with_default_scale(with_photo_metadata(with_srt_sidecar(meta)))


def _build(meta: FootageMetadata, tile_settings: TileSettings) -> FootageSource:
    if meta.kind is FootageKind.SYNTHETIC:
        try:
            params = SyntheticFieldParams(**dict(meta.synthetic))
        except (TypeError, ValueError) as exc:
            raise FootageError(f"{meta.config_file or 'synthetic'}: bad [synthetic] table: {exc}") from None
        base = synthetic_metadata(params)
        return SyntheticField(params, base.with_overrides(title=meta.title or None, notes=meta.notes or None))
    if meta.config_file and is_tile_cache(Path(meta.config_file).parent):
        # a tile cache (`footage ingest --tiles`): served from its tiles, the source video is not needed
        return TileSource(
            meta, Path(meta.config_file).parent, lambda w, h: geometry_for(meta, w, h),
            settings=tile_settings,
        )  # fmt: skip
    path = Path(meta.path)
    if not path.exists():
        raise FootageError(f"footage {meta.name!r}: file not found: {path}")
    if not path.is_file():
        raise FootageError(f"footage {meta.name!r}: not a file: {path}")
    meta = with_scale_sources(meta)
    if meta.kind is FootageKind.STILL:
        image = StillSource.read(path)
        h, w = image.shape[:2]
        return StillSource(meta, geometry_for(meta, w, h), image)
    return VideoSource(meta, lambda w, h: geometry_for(meta, w, h))


def _sibling_metadata(media: Path, shared_dir: Path) -> FootageMetadata | None:
    for cand in (media.with_name(media.name + ".toml"), media.with_suffix(".toml")):
        if cand.is_file():
            table = read_toml(cand)
            table.setdefault("path", str(media.resolve()))
            table.setdefault("kind", kind_from_path(media).value)
            return metadata_from_table(
                table, where=str(cand), base_dirs=(cand.parent, shared_dir), name=media.stem
            )
    return None


def _downloaded(
    name: str, entries: dict[str, FootageMetadata | CatalogSpec], cache_dir: Path
) -> FootageMetadata | None:
    """'CATALOG/FILE' -> metadata for a file fetched by `footage get` (catalog defaults; altitude from its SRT)."""
    cat_name, _, file_part = name.partition("/")
    cat = entries.get(cat_name)
    if not isinstance(cat, CatalogSpec) or not file_part:
        return None
    folder = cache_dir / DOWNLOAD_SUBDIR / cat.name
    media_ext = VIDEO_EXTENSIONS | IMAGE_EXTENSIONS
    cands = [folder / file_part] + sorted(
        p for p in folder.glob(file_part + ".*") if p.suffix.lower() in media_ext
    )
    media = next((p for p in cands if p.is_file()), None)
    if media is None:
        raise FootageError(
            f"footage {name!r} is not downloaded (looked in {folder}); run: viva-sitl footage get {cat.name} --only '{file_part}*'"
        )
    table: dict[str, Any] = dict(cat.defaults)
    table.update(
        name=name,
        path=str(media),
        kind=kind_from_path(media).value,
        licence=table.get("licence", cat.licence),
        attribution=table.get("attribution", cat.attribution),
        source_url=table.get("source_url", cat.source_url),
    )
    return metadata_from_table(table, where=cat.config_file, base_dirs=(folder,), name=name)


def known_names(config_dir: Path, shared_dir: Path, cache_dir: Path) -> list[str]:
    names = ["synthetic"] + [
        n for n in load_config_dir(config_dir, shared_dir=shared_dir) if n != "synthetic"
    ]
    for f in sorted((cache_dir / INGEST_SUBDIR).glob(f"*/{INGEST_METADATA}")):
        names.append(f.parent.name)
    return names


def resolve_metadata(
    spec: str | Path | None,
    *,
    shared_dir: Path | None = None,
    config_dir: Path | None = None,
    cache_dir: Path | None = None,
) -> FootageMetadata:
    """The metadata `open_footage(spec)` would use (no video is opened)."""
    shared = Path(shared_dir) if shared_dir is not None else default_shared_dir()
    configs = Path(config_dir) if config_dir is not None else default_config_dir()
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    entries = load_config_dir(configs, shared_dir=shared)
    if spec is None or (isinstance(spec, str) and spec == "synthetic"):
        meta = entries.get("synthetic")
        return meta if isinstance(meta, FootageMetadata) else synthetic_metadata()
    p = Path(spec).expanduser()
    if p.exists():
        if p.is_dir():
            if (p / INGEST_METADATA).is_file():
                p = p / INGEST_METADATA
            else:
                raise FootageError(f"{p} is a folder without {INGEST_METADATA} (not an ingest cache)")
        if p.suffix.lower() == ".toml":
            meta_or_cat = load_metadata_file(p, shared_dir=shared)
            if isinstance(meta_or_cat, CatalogSpec):
                raise FootageError(
                    f"{p} describes the remote catalog {meta_or_cat.name!r}; run: viva-sitl footage get {meta_or_cat.name}"
                )
            return meta_or_cat
        found = _sibling_metadata(p, shared)
        if found is not None:
            return found
        rp = p.resolve()
        for meta in entries.values():
            if isinstance(meta, FootageMetadata) and meta.path and Path(meta.path) == rp:
                return meta
        return FootageMetadata(name=p.stem, kind=kind_from_path(p), path=str(rp))
    name = str(spec)
    entry = entries.get(name)
    if isinstance(entry, FootageMetadata):
        return entry
    if isinstance(entry, CatalogSpec):
        raise FootageError(
            f"{name!r} is a remote catalog ({entry.record_url}); download it with `viva-sitl footage get {name}` "
            f"and open one file as {name}/FILE (see `viva-sitl footage list`)"
        )
    ingest = cache / INGEST_SUBDIR / name / INGEST_METADATA
    if ingest.is_file():
        meta_or_cat = load_metadata_file(ingest, shared_dir=shared)
        if isinstance(meta_or_cat, FootageMetadata):
            return meta_or_cat
    downloaded = _downloaded(name, entries, cache)
    if downloaded is not None:
        return downloaded
    if "/" in name or "\\" in name or Path(name).suffix:
        raise FootageError(f"footage not found: {name}")
    raise FootageError(
        f"unknown footage {name!r}: not a file and not a catalog name "
        f"(known: {', '.join(known_names(configs, shared, cache))})"
    )


def open_footage(
    spec: str | Path | None,
    *,
    shared_dir: str | Path | None = None,
    config_dir: str | Path | None = None,
    cache_dir: str | Path | None = None,
    altitude_m: float | None = None,
    hfov_deg: float | None = None,
    gsd_m_per_px: float | None = None,
    heading_deg: float | None = None,
    fps: float | None = None,
    cache: autocache.CachePolicy | None = None,
    tiles: TileSettings | None = None,
) -> FootageSource:
    """Open footage by catalog name or path (None/"synthetic": the built-in synthetic calibration field).

    A heavy video (>= ~4K) is served from its automatic tile cache, built the first time (`cache`: the policy,
    None = the process's, `autocache.set_policy`; see viva_sitl.footage.autocache). `tiles`: how a tile cache is
    read (None: the process's, `tiles.set_process_settings`; nothing here reads the environment: the top floor
    parses $VIVA_SITL_TILE_CACHE_MB / $VIVA_SITL_TILE_DECODE_THREADS / $VIVA_SITL_TILE_READ_AHEAD, see
    viva_sitl.footage.tiles.settings).

    Raises FootageError (a ValueError) with one clear message for anything unusable; nothing is left open then.
    """
    meta = resolve_metadata(
        spec,
        shared_dir=Path(shared_dir) if shared_dir is not None else None,
        config_dir=Path(config_dir) if config_dir is not None else None,
        cache_dir=Path(cache_dir) if cache_dir is not None else None,
    )
    meta = meta.with_overrides(
        recording_altitude_m=altitude_m,
        hfov_deg=hfov_deg,
        gsd_m_per_px=gsd_m_per_px,
        heading_deg=heading_deg,
        fps=fps,
    )
    if gsd_m_per_px is not None and meta.corners_lonlat is not None:
        log.info(
            "footage %s: explicit gsd_m_per_px %.4f overrides the corners' scale", meta.name, gsd_m_per_px
        )

    tile_settings = tiles if tiles is not None else process_settings()
    src = _build(meta, tile_settings)
    if isinstance(src, VideoSource):  # the factory's own product: a video may be served from its tile cache
        return _auto_cached(src, meta, cache or autocache.policy(), tile_settings)
    return src


def _auto_cached(
    src: VideoSource,
    meta: FootageMetadata,
    policy: autocache.CachePolicy,
    settings: TileSettings,
) -> FootageSource:
    """`src` itself, or (heavy footage, cache enabled) the same footage from its automatic tile cache."""
    w, h = src.frame_size_px
    if not policy.enabled or w * h < policy.min_pixels:
        return src
    n = src.frame_count
    try:
        folder = autocache.ensure_cache(
            Path(meta.path), lambda: (src.frame(i) for i in range(n)), n, (w, h), src.fps, policy, meta.name
        )
    except BaseException:
        src.close()
        raise
    if folder is None:
        return src
    geometry, metadata = src.geometry, src.metadata
    src.close()
    return TileSource(metadata, folder, lambda w, h: geometry, settings=settings)
