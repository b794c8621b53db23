"""Ingest: transcode heavy footage (4K/8K, long GOPs, high bit rates) into a fast-decoding, multi-resolution cache.

Output folder (default `<cache>/ingest/<name>/`):
    full.mp4      H.264 at full resolution, x264 `ultrafast` + `tune=fastdecode` (no CABAC, no deblocking: cheapest
                  decode), a keyframe every second (cheap seeks), no B-frames, same frame count and rate
    half.mp4      the same at half resolution (and quarter.mp4 with `levels=3`), read by `VideoSource.frame(i, level)`
    footage.toml  the source's metadata with the geometry written out explicitly (GSD, altitude, heading, origin),
                  so `open_footage(folder)` or `open_footage("<name>")` (name lookup in the cache) use the copy.
The folder is built under a temporary name and renamed when complete: an interrupted ingest leaves no cache entry.

`ingest_tiles` (`viva-sitl footage ingest --tiles`) builds instead a tiled multi-resolution cache
(`viva_sitl.footage.tiles`, default folder `<cache>/ingest/<name>-tiles/`): a render then decodes only the tiles
under the VAC's footprint, so its cost follows the VAC's output size, not the footage's resolution. It is built in
place and resumable (an interrupted run continues where it stopped); footage.toml is written last.
Why not the default: the tile cache is ~3-10x bigger on disk than the H.264 copies and slower to build; it pays for
4K/8K footage and training loops, not for a quick look at 1080p footage.
"""

from __future__ import annotations

import json
import math
import shutil
import sys
from fractions import Fraction
from pathlib import Path
from typing import Any, TextIO

import av
from tqdm import tqdm

from viva_sitl.footage import tiles
from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.footage.loader import (
    INGEST_METADATA,
    INGEST_SUBDIR,
    geometry_for,
    open_footage,
    resolve_metadata,
    with_scale_sources,
)
from viva_sitl.footage.metadata import FootageKind, FootageMetadata
from viva_sitl.footage.paths import default_cache_dir
from viva_sitl.footage.source import RegionRead
from viva_sitl.footage.srt import find_srt_sidecar
from viva_sitl.footage.worldmeta import derived_tracks_path

LEVEL_FILES = ("full.mp4", "half.mp4", "quarter.mp4")


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    return json.dumps(str(v))  # a JSON string is a valid TOML basic string


def _even(x: float) -> int:
    return max(2, int(round(x / 2.0)) * 2)


def ingest(
    spec: str | Path,
    *,
    out_dir: Path | None = None,
    cache_dir: Path | None = None,
    config_dir: Path | None = None,
    shared_dir: Path | None = None,
    levels: int = 2,
    crf: int = 18,
    name: str | None = None,
    progress_file: TextIO | None = None,
    show_progress: bool = True,
    max_frames: int | None = None,
) -> Path:
    """Transcode a video footage into the ingest cache; returns the folder (holding footage.toml)."""
    if not 1 <= levels <= len(LEVEL_FILES):
        raise FootageError(f"levels must be 1..{len(LEVEL_FILES)}, got {levels}")
    meta = resolve_metadata(spec, shared_dir=shared_dir, config_dir=config_dir, cache_dir=cache_dir)
    if meta.kind is not FootageKind.VIDEO:
        raise FootageError(f"ingest takes videos; {meta.name!r} is a {meta.kind.value}")
    src_path = Path(meta.path)
    entry = name or f"{meta.name}-ingest"
    if not entry or "/" in entry or entry.startswith("."):
        raise FootageError(f"bad ingest name {entry!r}")
    dest = out_dir if out_dir is not None else (cache_dir or default_cache_dir()) / INGEST_SUBDIR / entry
    tmp = dest.with_name(dest.name + ".tmp-ingest")
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir(parents=True)
    try:
        try:
            inp = av.open(str(src_path))
        except (av.FFmpegError, OSError) as exc:
            raise FootageError(
                f"cannot open video {src_path}: {getattr(exc, 'strerror', None) or exc}"
            ) from None
        with inp:
            if not inp.streams.video:
                raise FootageError(f"{src_path} has no video stream")
            ist = inp.streams.video[0]
            ist.thread_type = "AUTO"
            rate = Fraction(ist.average_rate or ist.guessed_rate or 30)
            w, h = ist.codec_context.width, ist.codec_context.height
            total = int(ist.frames or 0) or None
            if max_frames is not None:
                total = min(total or max_frames, max_frames)
            geometry = geometry_for(with_scale_sources(meta), w, h)
            outs = []
            for k in range(levels):
                ow, oh = (w, h) if k == 0 else (_even(w / 2**k), _even(h / 2**k))
                oc = av.open(str(tmp / LEVEL_FILES[k]), mode="w")
                st = oc.add_stream("libx264", rate=rate)
                st.width, st.height, st.pix_fmt = ow, oh, "yuv420p"
                st.codec_context.time_base = 1 / rate
                st.options = {
                    "preset": "ultrafast", "tune": "fastdecode", "crf": str(crf), "g": str(max(1, round(float(rate)))),
                    "bf": "0",
                }  # fmt: skip
                outs.append((oc, st, ow, oh))
            count = 0
            with tqdm(total=total, unit="frame", desc=f"ingest {meta.name}", file=progress_file or sys.stderr,
                      disable=not show_progress) as bar:  # fmt: skip
                for frame in inp.decode(ist):
                    if max_frames is not None and count >= max_frames:
                        break
                    yuv = frame if frame.format.name == "yuv420p" else frame.reformat(format="yuv420p")
                    for oc, st, ow, oh in outs:
                        f = (
                            yuv
                            if (ow, oh) == (w, h)
                            else yuv.reformat(width=ow, height=oh, interpolation="AREA")
                        )
                        f.pts, f.time_base = count, 1 / rate
                        for pkt in st.encode(f):
                            oc.mux(pkt)
                    count += 1
                    bar.update(1)
            for oc, st, _, _ in outs:
                for pkt in st.encode(None):
                    oc.mux(pkt)
                oc.close()
        if count == 0:
            raise FootageError(f"{src_path}: no frame could be decoded")
        _write_metadata(
            tmp / INGEST_METADATA, meta, geometry, entry, float(rate), levels, src_path, count, LEVEL_FILES[0]
        )
        if dest.exists():
            shutil.rmtree(dest)
        tmp.rename(dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return dest


def _write_metadata(
    path: Path,
    meta: FootageMetadata,
    geometry: FootageGeometry,
    name: str,
    fps: float,
    levels: int,
    src: Path,
    frames: int,
    video: str,
) -> None:
    lines = [
        f"# written by `viva-sitl footage ingest` from {src} ({frames} frames)",
        f"name = {_toml_value(name)}",
        f"title = {_toml_value((meta.title or meta.name) + (' (tile cache)' if video == str(src) else ' (ingest cache)'))}",
        'kind = "video"',
        f"path = {_toml_value(video)}",
        f"levels = {_toml_value(list(LEVEL_FILES[1:levels]))}",
        f"fps = {_toml_value(meta.fps or fps)}",
        f"gsd_m_per_px = {_toml_value(geometry.gsd_m_per_px)}",
        f"recording_altitude_m = {_toml_value(geometry.recording_altitude_m)}",
        f"heading_deg = {_toml_value(geometry.heading_deg)}",
        f"ground_alt_amsl_m = {_toml_value(meta.ground_alt_amsl_m)}",
    ]
    if geometry.geo_origin is not None:
        lines += [
            f"home_lat_deg = {_toml_value(geometry.geo_origin.lat_deg)}",
            f"home_lon_deg = {_toml_value(geometry.geo_origin.lon_deg)}",
        ]
    for key in ("licence", "attribution", "source_url"):
        if getattr(meta, key):
            lines.append(f"{key} = {_toml_value(getattr(meta, key))}")
    lines.append(f"notes = {_toml_value(f'ingested from {src}; geometry of {meta.name!r} written out')}")
    srt = meta.srt or (str(find_srt_sidecar(src) or ""))
    if srt:
        lines.append(f"srt = {_toml_value(srt)}")
    if meta.annotated is not None:  # what the ground truth looked for travels with it
        lines.append(f"annotated = {_toml_value(list(meta.annotated))}")
    if meta.annotations_path and meta.annotations_format is not None:
        lines += [
            "",
            "[annotations]",
            f"path = {_toml_value(meta.annotations_path)}",
            f"format = {_toml_value(meta.annotations_format.value)}",
            f"class_names = {_toml_value(list(meta.class_names))}",
        ]
    lines += _ground_truth_lines(meta)
    if not all(math.isfinite(v) for v in (geometry.gsd_m_per_px, geometry.recording_altitude_m)):
        raise FootageError("ingest: non-finite geometry")
    # the source's derived tracks (`footage annotate`, `<metadata stem>.tracks.csv`) as of now, beside the copy's
    # metadata where the world model looks for them; before the metadata file, which marks the cache complete
    derived = derived_tracks_path(meta.config_file)
    copy = derived_tracks_path(path)
    if derived is not None and copy is not None and derived.is_file():
        shutil.copyfile(derived, copy)
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def _ground_truth_lines(meta: FootageMetadata) -> list[str]:
    """The source's [tracks] and [risk] tables (paths made absolute): a cache of the footage keeps its ground
    truth, so trials over it are scored as over the footage itself."""
    out: list[str] = []
    t = meta.tracks
    if t is not None:
        out += ["", "[tracks]", f"path = {_toml_value(t.path)}", f"format = {_toml_value(t.format.value)}",
                f"max_gap_frames = {_toml_value(t.max_gap_frames)}"]  # fmt: skip
        if t.fps is not None:
            out.append(f"fps = {_toml_value(t.fps)}")
        if t.class_map:
            out.append("class_map = { " + ", ".join(f"{json.dumps(k)} = {_toml_value(v)}" for k, v in t.class_map)
                       + " }")  # fmt: skip
    r = meta.risk
    if r is not None:
        out += ["", "[risk]", f"default_level = {_toml_value(r.default_level)}"]
        if r.polygons:
            out.append(f"polygons = {_toml_value(r.polygons)}")
        if r.raster:
            out.append(f"raster = {_toml_value(r.raster)}")
        if r.notes:
            out.append(f"notes = {_toml_value(r.notes)}")
        if r.accuracy_m is not None:
            out.append(f"accuracy_m = {_toml_value(r.accuracy_m)}")
        if r.levels:
            out.append("levels = { " + ", ".join(f"{json.dumps(k)} = {v}" for k, v in r.levels) + " }")
        if r.objects:
            out += ["", "[risk.objects]"]
            out += [
                f"{json.dumps(c)} = {{ level = {lv}, buffer_m = {_toml_value(b)} }}" for c, lv, b in r.objects
            ]
    return out


def ingest_tiles(
    spec: str | Path,
    *,
    out_dir: Path | None = None,
    cache_dir: Path | None = None,
    config_dir: Path | None = None,
    shared_dir: Path | None = None,
    name: str | None = None,
    codec: str = tiles.DEFAULT_CODEC,
    quality: int = tiles.DEFAULT_JPEG_QUALITY,
    tile_px: int = tiles.DEFAULT_TILE_PX,
    max_bytes: int | None = None,
    progress_file: TextIO | None = None,
    show_progress: bool = True,
    max_frames: int | None = None,
) -> tiles.TileBuildResult:
    """Build (or resume) the tile cache of a video or still; returns where it is, its size and codec."""
    meta = resolve_metadata(spec, shared_dir=shared_dir, config_dir=config_dir, cache_dir=cache_dir)
    if meta.kind is FootageKind.SYNTHETIC:
        raise FootageError("the synthetic field needs no tile cache (it is drawn per view)")
    entry = name or f"{meta.name}-tiles"
    if not entry or "/" in entry or entry.startswith("."):
        raise FootageError(f"bad cache name {entry!r}")
    dest = out_dir if out_dir is not None else (cache_dir or default_cache_dir()) / INGEST_SUBDIR / entry
    src = open_footage(spec, shared_dir=shared_dir, config_dir=config_dir, cache_dir=cache_dir)
    if src.capabilities.region is RegionRead.TILES:
        src.close()
        raise FootageError(f"{spec} is already a tile cache")
    with src:
        n = src.frame_count if max_frames is None else max(1, min(src.frame_count, max_frames))
        w, h = src.geometry.width_px, src.geometry.height_px
        src_path = Path(meta.path)
        st = src_path.stat()
        (dest / INGEST_METADATA).unlink(missing_ok=True)  # not openable until complete
        result = tiles.build_tiles(
            (src.frame(i) for i in range(n)), n, w, h, src.fps, dest, codec=codec, quality=quality,
            tile_px=tile_px, max_bytes=max_bytes, source_id=f"{src_path.resolve()}:{st.st_size}:{st.st_mtime_ns}",
            progress_file=progress_file, show_progress=show_progress, desc=f"tiles {meta.name}",
        )  # fmt: skip
        _write_metadata(
            dest / INGEST_METADATA,
            meta,
            src.geometry,
            entry,
            src.fps,
            1,
            src_path,
            n,
            str(src_path.resolve()),
        )
    return result
