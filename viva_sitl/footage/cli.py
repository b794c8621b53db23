"""`viva-sitl footage list | info | get | ingest` (the lead's CLI passes everything after `footage` to footage_main)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from viva_sitl.cliargs import positive_float
from viva_sitl.footage import tiles
from viva_sitl.footage.catalog import cached_record_files, download_catalog
from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.ingest import ingest, ingest_tiles
from viva_sitl.footage.loader import DOWNLOAD_SUBDIR, INGEST_METADATA, INGEST_SUBDIR, open_footage
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
    common.add_argument("--config-dir", type=Path, help="footage metadata folder (default: configs/footage)")
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
    ing.add_argument("--out", type=Path, help="output folder (default: <cache>/ingest/<name>-ingest)")
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
    ing.add_argument("--tile-codec", choices=tiles.CODECS, default=tiles.DEFAULT_CODEC, help="with --tiles")
    ing.add_argument(
        "--tile-quality", type=int, default=tiles.DEFAULT_JPEG_QUALITY, help="jpeg quality 1-100"
    )
    ing.add_argument("--tile-px", type=int, default=tiles.DEFAULT_TILE_PX, help="tile size, px")
    ing.add_argument(
        "--max-size", type=positive_float, metavar="MIB",
        help="with --tiles: size bound on disk (jpeg: lower quality to fit, else refuse)",
    )  # fmt: skip
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


def footage_main(argv: list[str]) -> int:
    """Entry point of `viva-sitl footage ...`; returns the exit status (2 with one message on FootageError)."""
    args = build_parser().parse_args(argv)
    config_dir = args.config_dir or default_config_dir()
    shared_dir = args.shared_dir or default_shared_dir()
    cache_dir = args.cache_dir or default_cache_dir()
    try:
        if args.cmd == "list":
            return _cmd_list(config_dir, shared_dir, cache_dir)
        if args.cmd == "info":
            return _cmd_info(args, config_dir, shared_dir, cache_dir)
        if args.cmd == "get":
            return _cmd_get(args, config_dir, shared_dir, cache_dir)
        if args.cmd == "ingest":
            return _cmd_ingest(args, config_dir, shared_dir, cache_dir)
    except FootageError as exc:
        print(f"viva-sitl footage {args.cmd}: {exc}", file=sys.stderr)
        return 2
    return 2
