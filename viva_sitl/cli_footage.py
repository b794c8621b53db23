"""`viva-sitl footage list | info | get | ingest | cache | show | annotate` (viva_sitl.cli passes everything after `footage`
to `footage_main`).

On the top floor with the other CLIs: `show` and `annotate` build a world (viva_sitl.world) over the footage, and the
footage package itself must not import the world that stands on it. The footage package does not import this
module either, so trial workers that only fly over footage never load the catalog, download and ingest code.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

from viva_sitl.cliargs import positive_float
from viva_sitl.footage import tiles
from viva_sitl.footage.catalog import cached_record_files, download_catalog
from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.ingest import ingest, ingest_tiles
from viva_sitl.footage.loader import (
    DOWNLOAD_SUBDIR,
    INGEST_METADATA,
    INGEST_SUBDIR,
    open_footage,
    resolve_metadata,
)
from viva_sitl.footage.metadata import (
    IMAGE_EXTENSIONS,
    VIDEO_EXTENSIONS,
    CatalogSpec,
    FootageMetadata,
    load_config_dir,
    load_metadata_file,
)
from viva_sitl.footage.paths import default_cache_dir, default_config_dir, default_shared_dir


def _human(n: int | None) -> str:
    if n is None:
        return "?"
    size = float(n)
    for unit in ("B", "KiB", "MiB", "GiB"):
        if size < 1024 or unit == "GiB":
            return f"{size:.0f} {unit}" if unit == "B" else f"{size:.1f} {unit}"
        size /= 1024
    return f"{n} B"


def build_parser() -> argparse.ArgumentParser:
    common = argparse.ArgumentParser(add_help=False)
    common.add_argument(
        "--config-dir",
        type=Path,
        help="footage metadata folder (default: the catalog shipped in viva_sitl/data/footage)",
    )
    common.add_argument("--shared-dir", type=Path, help="base of relative footage paths (default: ../shared)")
    common.add_argument(
        "--cache-dir", type=Path, help="download/ingest cache (default: $XDG_CACHE_HOME/viva-sitl)"
    )
    p = argparse.ArgumentParser(
        prog="viva-sitl footage", description="Footage catalog: list, inspect, download, ingest."
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    sub.add_parser("list", parents=[common], help="catalog entries: name, kind, size, available locally?")
    info = sub.add_parser("info", parents=[common], help="metadata and geometry of a footage (name or path)")
    info.add_argument("footage", help="catalog name or path")
    info.add_argument("--altitude", type=positive_float, help="override the recording altitude (m)")
    info.add_argument("--hfov", type=positive_float, help="override the recording horizontal FoV (deg)")
    info.add_argument("--gsd", type=positive_float, help="override the ground sample distance (m/px)")
    get = sub.add_parser(
        "get", parents=[common], help="download a remote catalog (ViVa-SAFELAND from Zenodo)"
    )
    get.add_argument("name", help="catalog name (viva-safeland), or NAME/FILE for one file")
    get.add_argument(
        "--base-url", help="Zenodo (or mirror) base URL (default: the catalog's, https://zenodo.org)"
    )
    get.add_argument("--dest", type=Path, help="download folder (default: <cache>/downloads/<name>)")
    get.add_argument(
        "--only", action="append", default=[], metavar="GLOB", help="file name pattern (repeatable)"
    )
    get.add_argument("--retries", type=int, default=3, help="resume attempts per file after a cut connection")
    get.add_argument("--timeout", type=positive_float, default=30.0, help="socket timeout, s")
    get.add_argument("--no-progress", action="store_true", help="no progress bar")
    ing = sub.add_parser(
        "ingest", parents=[common], help="transcode a heavy video into a fast-decoding cache"
    )
    ing.add_argument("footage", help="video path or catalog name")
    ing.add_argument("-o", "--out", type=Path, help="output folder (default: <cache>/ingest/<name>-ingest)")
    ing.add_argument("--name", help="cache entry name (default: <name>-ingest)")
    ing.add_argument("--levels", type=int, default=2, help="resolution levels: 1 full, 2 +half, 3 +quarter")
    ing.add_argument("--crf", type=int, default=18, help="x264 quality (lower = better, bigger)")
    ing.add_argument("--max-frames", type=int, help="ingest only the first N frames")
    ing.add_argument("--no-progress", action="store_true", help="no progress bar")
    ing.add_argument(
        "--tiles", action="store_true",
        help="build a tiled multi-resolution cache instead (render cost follows the view, not the footage size; "
        "resumable: rerun after an interruption)",
    )  # fmt: skip
    ing.add_argument(
        "--tile-codec", choices=tiles.CODECS, default=tiles.DEFAULT_CODEC,
        help="with --tiles: jpeg (default, q95, ~46 dB, the smallest), png (lossless, slowest to read) or raw "
        "(lossless and the fastest: ~2x jpeg's full steps/s at 50 m over 4K, for ~7x its size on disk: ~32 MiB "
        "per 4K frame) or yuv420z (the automatic cache's: zstd YUV 4:2:0 level 0, ~3x faster to decode than jpeg, "
        "jpeg coarse levels; ~9.5 MiB per 4K frame) or yuv420zg (yuv420z with level 0 gradient-coded: the same "
        "pixels, ~6.5 MiB per 4K frame, level-0 reads ~1.3x slower)",
    )  # fmt: skip
    ing.add_argument(
        "--tile-quality", type=int, default=tiles.DEFAULT_JPEG_QUALITY, help="jpeg quality 1-100"
    )
    ing.add_argument("--tile-px", type=int, default=tiles.DEFAULT_TILE_PX, help="tile size, px")
    ing.add_argument(
        "--max-size", type=positive_float, metavar="MIB",
        help="with --tiles: size bound on disk (jpeg: lower quality to fit, else refuse)",
    )  # fmt: skip
    cache = sub.add_parser(
        "cache", parents=[common], help="the automatic tile caches of heavy footage: list or clear"
    )
    cache.add_argument("action", choices=("list", "clear"))
    cache.add_argument("--tile-cache-dir", type=Path, help="where they are (default: <cache-dir>/tiles-auto)")
    show = sub.add_parser(
        "show", parents=[common], help="overview PNG: the frame at --time with the risk map and the objects"
    )
    show.add_argument("footage", help="catalog name or path")
    show.add_argument(
        "--time", type=float, default=0.0, help="simulation time in s (selects frame and objects)"
    )
    show.add_argument("-o", "--out", type=Path, default=Path("overview.png"), help="output image (.png/.jpg)")
    show.add_argument("--max-size", type=int, default=1600, help="longest side of the image, px")
    show.add_argument("--no-risk", action="store_true", help="objects only, no risk layer")
    ann = sub.add_parser("annotate", parents=[common], help="derive object tracks for footage that has none")
    ann.add_argument("footage", help="catalog name or video path")
    ann.add_argument("--method", choices=("motion", "detector"), default="motion",
                     help="motion: background subtraction + tracker (no model); detector: ultralytics weights")  # fmt: skip
    ann.add_argument(
        "--detector", metavar="WEIGHTS", help="ultralytics weights for --method detector (e.g. yolo11n.pt)"
    )
    ann.add_argument("-o", "--out", type=Path,
                     help="tracks file (default: <metadata stem>.tracks.csv beside the footage metadata)")  # fmt: skip
    ann.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def _cmd_list(config_dir: Path, shared_dir: Path, cache_dir: Path) -> int:
    entries = load_config_dir(config_dir, shared_dir=shared_dir)
    rows: list[tuple[str, str, str, str, str]] = []
    if "synthetic" not in entries:
        rows.append(("synthetic", "synthetic", "-", "built-in", "SYNTHETIC CALIBRATION FIELD"))
    for name, e in entries.items():
        if isinstance(e, FootageMetadata):
            if e.path:
                p = Path(e.path)
                rows.append((name, e.kind.value, _human(p.stat().st_size) if p.is_file() else "-",
                             "yes" if p.is_file() else f"no ({p})", e.title))  # fmt: skip
            else:
                rows.append((name, e.kind.value, "-", "built-in", e.title))
            continue
        folder = cache_dir / DOWNLOAD_SUBDIR / e.name
        files = cached_record_files(e, folder)
        media = [f for f in files if Path(f.key).suffix.lower() in VIDEO_EXTENSIONS | IMAGE_EXTENSIONS]
        have = [f for f in media if (folder / f.key).is_file()]
        size = _human(sum(f.size_bytes for f in media)) if files else "?"
        status = f"{len(have)}/{len(media)} files" if files else "not fetched (footage get " + e.name + ")"
        rows.append((name, "catalog", size, status, f"{e.title} [{e.record_url}]"))
        for f in media:
            local = (folder / f.key).is_file()
            rows.append(
                (
                    f"{e.name}/{Path(f.key).stem}",
                    "video",
                    _human(f.size_bytes),
                    "yes" if local else "no",
                    f.key,
                )
            )
    for meta_file in sorted((cache_dir / INGEST_SUBDIR).glob(f"*/{INGEST_METADATA}")):
        try:
            m = load_metadata_file(meta_file, shared_dir=shared_dir)
        except FootageError as exc:
            rows.append((meta_file.parent.name, "ingest", "?", "broken", str(exc)))
            continue
        if isinstance(m, FootageMetadata):
            n_bytes = sum(f.stat().st_size for f in meta_file.parent.glob("*.mp4"))
            rows.append((meta_file.parent.name, "ingest", _human(n_bytes), "yes", m.title))
    widths = [max(len(r[i]) for r in rows + [("NAME", "KIND", "SIZE", "LOCAL", "TITLE")]) for i in range(4)]
    for r in [("NAME", "KIND", "SIZE", "LOCAL", "TITLE"), *rows]:
        print("  ".join(c.ljust(w) for c, w in zip(r[:4], widths, strict=True)) + "  " + r[4])
    return 0


def _cmd_info(args: argparse.Namespace, config_dir: Path, shared_dir: Path, cache_dir: Path) -> int:
    with open_footage(
        args.footage, shared_dir=shared_dir, config_dir=config_dir, cache_dir=cache_dir,
        altitude_m=args.altitude, hfov_deg=args.hfov, gsd_m_per_px=args.gsd,
    ) as src:  # fmt: skip
        info = src.describe()
        ann = src.annotations(0)
        if ann:
            info["annotations_frame0"] = (
                f"{len(ann)} objects, e.g. {ann[0].label} {ann[0].size_m[0]:.1f} x {ann[0].size_m[1]:.1f} m"
            )
        width = max(len(k) for k in info)
        for k, v in info.items():
            print(f"{k.ljust(width)}  {v}")
    return 0


def _cmd_get(args: argparse.Namespace, config_dir: Path, shared_dir: Path, cache_dir: Path) -> int:
    entries = load_config_dir(config_dir, shared_dir=shared_dir)
    cat_name, _, file_part = str(args.name).partition("/")
    cat = entries.get(cat_name)
    if not isinstance(cat, CatalogSpec):
        remote = [n for n, e in entries.items() if isinstance(e, CatalogSpec)]
        raise FootageError(
            f"{cat_name!r} is not a remote catalog (remote catalogs: {', '.join(remote) or 'none'})"
        )
    only = tuple(args.only) + ((f"{file_part}*",) if file_part else ())
    dest = args.dest or cache_dir / DOWNLOAD_SUBDIR / cat.name
    paths = download_catalog(
        cat, dest, base_url=args.base_url, only=only, retries=args.retries, timeout_s=args.timeout,
        show_progress=not args.no_progress,
    )  # fmt: skip
    for p in paths:
        print(f"ok  {p}  ({_human(p.stat().st_size)}, size and checksum verified)")
    return 0


def _cmd_ingest(args: argparse.Namespace, config_dir: Path, shared_dir: Path, cache_dir: Path) -> int:
    if args.tiles:
        res = ingest_tiles(
            args.footage, out_dir=args.out, cache_dir=cache_dir, config_dir=config_dir, shared_dir=shared_dir,
            name=args.name, codec=args.tile_codec, quality=args.tile_quality, tile_px=args.tile_px,
            max_bytes=None if args.max_size is None else int(args.max_size * 2**20),
            show_progress=not args.no_progress, max_frames=args.max_frames,
        )  # fmt: skip
        q = f" quality {res.quality}" if res.codec == "jpeg" else ""
        again = f", resumed after frame {res.resumed_from}" if res.resumed_from else ""
        print(
            f"tiled {res.frames} frames into {res.folder} ({_human(res.disk_bytes)}, {res.codec}{q}{again}); "
            f"open it with --footage {res.folder}"
        )
        return 0
    out = ingest(
        args.footage, out_dir=args.out, cache_dir=cache_dir, config_dir=config_dir, shared_dir=shared_dir,
        levels=args.levels, crf=args.crf, name=args.name, show_progress=not args.no_progress,
        max_frames=args.max_frames,
    )  # fmt: skip
    print(f"ingested into {out}; open it with --footage {out} (or by name {out.name!r} when in the cache)")
    return 0


def _cmd_cache(args: argparse.Namespace, cache_dir: Path) -> int:
    from viva_sitl.footage import autocache

    root = args.tile_cache_dir or cache_dir / autocache.AUTO_SUBDIR
    entries = autocache.list_caches(root)
    if args.action == "list":
        if not entries:
            print(f"no automatic tile cache in {root}")
            return 0
        print("KEY           SIZE       FRAMES  CODEC     LAST USED         SOURCE")
        for e in reversed(entries):  # most recently used first
            used = time.strftime("%Y-%m-%d %H:%M", time.localtime(e.last_used))
            print(f"{e.key[:12]}  {_human(e.bytes):>9}  {e.frames:>6}  {e.codec:<8}  {used}  {e.source}")
        print(f"{len(entries)} caches, {_human(sum(e.bytes for e in entries))} in {root}")
        return 0
    removed = [e for e in entries if autocache.remove(root, e)]
    busy = len(entries) - len(removed)
    print(
        f"removed {len(removed)} tile caches ({_human(sum(e.bytes for e in removed))}) from {root}"
        + (f"; {busy} in use by a build, kept" if busy else "")
    )
    return 0


def _cmd_show(args: argparse.Namespace, config_dir: Path, shared_dir: Path, cache_dir: Path) -> int:
    import cv2

    from viva_sitl.world.model import world_from_source
    from viva_sitl.world.overlay import render_overview

    if args.out.suffix.lower() not in (".png", ".jpg", ".jpeg"):
        raise FootageError(f"-o {args.out}: the overview is a .png or .jpg image")
    if args.max_size < 16:
        raise FootageError(f"--max-size must be >= 16, got {args.max_size}")
    if not math.isfinite(args.time):
        raise FootageError(f"--time must be a finite number, got {args.time}")
    meta = resolve_metadata(args.footage, shared_dir=shared_dir, config_dir=config_dir, cache_dir=cache_dir)
    with open_footage(args.footage, shared_dir=shared_dir, config_dir=config_dir, cache_dir=cache_dir) as src:
        world = world_from_source(src, meta)
        img = render_overview(world, src, args.time, args.max_size, show_risk=not args.no_risk)
    if not cv2.imwrite(str(args.out), img):
        raise FootageError(f"cannot write {args.out}")
    objs = world.tracks.objects_at(args.time)
    print(f"wrote {args.out} ({img.shape[1]}x{img.shape[0]}, t = {args.time:g} s, {len(objs)} objects)")
    return 0


def default_tracks_path(meta: FootageMetadata) -> Path:
    """Where derived tracks go: beside the metadata file (<stem>.tracks.csv), else beside the media file."""
    from viva_sitl.footage.worldmeta import DERIVED_SUFFIX, derived_tracks_path

    beside_metadata = derived_tracks_path(meta.config_file)
    if beside_metadata is not None:
        return beside_metadata
    if meta.path:
        media = Path(meta.path)
        return media.with_name(media.stem + DERIVED_SUFFIX)
    raise FootageError(f"footage {meta.name!r} has no metadata file or media path: give -o")


def _cmd_annotate(args: argparse.Namespace, config_dir: Path, shared_dir: Path, cache_dir: Path) -> int:
    from tqdm import tqdm

    from viva_sitl.footage.boxfiles import write_viva
    from viva_sitl.world.annotate import detector_tracks, motion_tracks

    if args.method == "detector" and not args.detector:
        raise FootageError("--method detector needs --detector WEIGHTS (an ultralytics .pt file)")
    meta = resolve_metadata(args.footage, shared_dir=shared_dir, config_dir=config_dir, cache_dir=cache_dir)
    out = Path(args.out) if args.out else default_tracks_path(meta)
    if not out.parent.is_dir():
        raise FootageError(f"output folder {out.parent} does not exist")
    with (
        open_footage(args.footage, shared_dir=shared_dir, config_dir=config_dir, cache_dir=cache_dir) as src,
        tqdm(
            total=src.frame_count, unit="frame", desc=f"annotate {meta.name}", disable=args.no_progress
        ) as bar,
    ):
        if args.method == "motion":
            rows = motion_tracks(src, progress=bar.update)
        else:
            rows = detector_tracks(src, args.detector, progress=bar.update)
    comment = (
        f"derived by viva-sitl footage annotate --method {args.method}"
        + (f" --detector {args.detector}" if args.detector else "")
        + f"\nfootage: {meta.name}; frames are 0-based footage frame indices; boxes in footage pixels"
    )
    try:
        write_viva(out, rows, comment)
    except OSError as exc:
        raise FootageError(f"cannot write {out}: {exc.strerror or exc}") from None
    n_tracks = len({r.track_id for r in rows})
    print(f"wrote {out}: {n_tracks} tracks, {len(rows)} boxes ({args.method})")
    return 0


def footage_main(argv: list[str]) -> int:
    """Entry point of `viva-sitl footage ...`; returns the exit status (2 with one message on FootageError)."""
    args = build_parser().parse_args(argv)
    config_dir = args.config_dir or default_config_dir()
    shared_dir = args.shared_dir or default_shared_dir()
    cache_dir = args.cache_dir or default_cache_dir()
    try:
        if args.cmd in ("info", "ingest", "show", "annotate"):  # the commands that open footage
            # the top floor reads the documented $VIVA_SITL_TILE_* (the footage layer reads no environment)
            tiles.set_process_settings(tiles.TileSettings.from_environ(os.environ))
        if args.cmd == "list":
            return _cmd_list(config_dir, shared_dir, cache_dir)
        if args.cmd == "info":
            return _cmd_info(args, config_dir, shared_dir, cache_dir)
        if args.cmd == "get":
            return _cmd_get(args, config_dir, shared_dir, cache_dir)
        if args.cmd == "ingest":
            return _cmd_ingest(args, config_dir, shared_dir, cache_dir)
        if args.cmd == "cache":
            return _cmd_cache(args, cache_dir)
        if args.cmd == "show":
            return _cmd_show(args, config_dir, shared_dir, cache_dir)
        if args.cmd == "annotate":
            return _cmd_annotate(args, config_dir, shared_dir, cache_dir)
    except KeyboardInterrupt:
        print(f"viva-sitl footage {args.cmd}: interrupted; nothing was written", file=sys.stderr)
        return 130
    except FootageError as exc:
        print(f"viva-sitl footage {args.cmd}: {exc}", file=sys.stderr)
        return 2
    return 2
