"""The remote catalog: a Zenodo record's file list, and downloads with progress, resume and size/md5 checks.

The record JSON is Zenodo's REST API shape (`GET {base}/api/records/{id}`):

    {"id": 13942934, "metadata": {"title": ...},
     "files": [{"key": "clip.MP4", "size": 123, "checksum": "md5:0123...", "links": {"self": "https://.../content"}}]}

Downloads use urllib from the standard library, not requests: one GET with a `Range` header is all resume needs,
and it keeps the package's dependency list short (requests is not one of them).
A file is written to `NAME.part`, resumed from the .part's size with `Range: bytes=N-` (a server that answers 200
instead of 206 restarts it), checked for size and md5, then renamed atomically to `NAME`; on a mismatch the .part is
deleted and nothing named `NAME` appears.
"""

from __future__ import annotations

import contextlib
import fnmatch
import hashlib
import http.client
import json
import logging
import os
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

from tqdm import tqdm

from viva_sitl import __version__
from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.metadata import CatalogSpec

log = logging.getLogger(__name__)

RECORD_FILE = "record.json"
CHUNK_BYTES = 1 << 20
USER_AGENT = f"viva-sitl/{__version__} (+urllib)"


@dataclass(frozen=True)
class RemoteFile:
    key: str  # file name in the record
    size_bytes: int
    md5_hex: str | None  # lower-case hex, when the record gives an md5 checksum
    url: str


def _check_key(key: str) -> str:
    """A record's file key becomes a local file name: refuse anything that could escape the download folder."""
    if not key or key in (".", "..") or "/" in key or "\\" in key or "\x00" in key:
        raise FootageError(f"refusing unsafe file name in the record: {key!r}")
    return key


def parse_record(record: dict[str, Any], base_url: str, record_id: int) -> list[RemoteFile]:
    """The files of a Zenodo record JSON (new `files: [...]` list; the legacy `{"entries": {...}}` form too)."""
    files = record.get("files")
    if isinstance(files, dict):  # InvenioRDM's /files endpoint shape
        files = files.get("entries", [])
        if isinstance(files, dict):
            files = list(files.values())
    if not isinstance(files, list):
        raise FootageError(f"record {record_id}: no file list in the record JSON")
    out: list[RemoteFile] = []
    for f in files:
        try:
            key, size = str(f["key"]), int(f["size"])
        except (KeyError, TypeError, ValueError):
            raise FootageError(f"record {record_id}: a file entry lacks key/size: {f!r}") from None
        _check_key(key)
        checksum = str(f.get("checksum") or "")
        algo, _, digest = checksum.partition(":")
        md5 = digest.lower() if algo.lower() == "md5" and digest else None
        links = f.get("links") or {}
        url = str(links.get("content") or links.get("self") or "")
        if not url:
            url = f"{base_url.rstrip('/')}/api/records/{record_id}/files/{urllib.parse.quote(key)}/content"
        elif url.startswith("/"):
            url = base_url.rstrip("/") + url
        out.append(RemoteFile(key, size, md5, url))
    return out


def _open(url: str, timeout_s: float, headers: dict[str, str] | None = None) -> http.client.HTTPResponse:
    req = urllib.request.Request(url, headers={"User-Agent": USER_AGENT, **(headers or {})})
    try:
        resp: http.client.HTTPResponse = urllib.request.urlopen(req, timeout=timeout_s)  # noqa: S310 - http(s) URLs from config
        return resp
    except urllib.error.HTTPError as exc:
        raise FootageError(f"GET {url}: HTTP {exc.code} {exc.reason}") from None
    except (urllib.error.URLError, OSError) as exc:
        reason = getattr(exc, "reason", exc)
        raise FootageError(f"GET {url}: cannot connect ({reason})") from None


def fetch_record(
    catalog: CatalogSpec, *, base_url: str | None = None, timeout_s: float = 30.0
) -> dict[str, Any]:
    """GET {base}/api/records/{id} -> the record JSON."""
    base = (base_url or catalog.base_url).rstrip("/")
    url = f"{base}/api/records/{catalog.record_id}"
    with _open(url, timeout_s, {"Accept": "application/json"}) as resp:
        body = resp.read()
    try:
        record = json.loads(body)
    except json.JSONDecodeError:
        raise FootageError(f"GET {url}: the answer is not JSON") from None
    if not isinstance(record, dict):
        raise FootageError(f"GET {url}: the answer is not a record object")
    return record


def select_files(files: list[RemoteFile], patterns: tuple[str, ...]) -> list[RemoteFile]:
    return [f for f in files if any(fnmatch.fnmatchcase(f.key, p) for p in patterns)]


def _md5_hex(path: Path) -> str:
    h = hashlib.md5(usedforsecurity=False)
    with path.open("rb") as f:
        for chunk in iter(lambda: f.read(CHUNK_BYTES), b""):
            h.update(chunk)
    return h.hexdigest()


def _verify(path: Path, rf: RemoteFile) -> str | None:
    """None when the local file has the record's size and md5, else why not."""
    size = path.stat().st_size
    if size != rf.size_bytes:
        return f"size {size} bytes, the record says {rf.size_bytes}"
    if rf.md5_hex is not None:
        digest = _md5_hex(path)
        if digest != rf.md5_hex:
            return f"md5 {digest}, the record says {rf.md5_hex}"
    return None


def download_file(
    rf: RemoteFile,
    dest_dir: Path,
    *,
    retries: int = 3,
    timeout_s: float = 30.0,
    progress_file: TextIO | None = None,
    show_progress: bool = True,
    retry_wait_s: float = 0.5,
) -> Path:
    """Download one file into dest_dir (resuming a .part), verify size and md5, rename atomically; return the path.

    A file already present and verified is not downloaded again. A connection cut mid-file is resumed up to
    `retries` times; after that the .part stays for the next call to resume. Raises FootageError on failure.
    """
    dest_dir.mkdir(parents=True, exist_ok=True)
    final = dest_dir / _check_key(rf.key)
    part = final.with_name(final.name + ".part")
    if final.exists():
        why = _verify(final, rf)
        if why is None:
            return final
        log.warning("%s exists but does not match the record (%s); downloading again", final, why)
        final.unlink()
    attempt = 0
    while True:
        have = part.stat().st_size if part.exists() else 0
        if have > rf.size_bytes:
            part.unlink()
            have = 0
        bar = tqdm(
            total=rf.size_bytes, initial=have, unit="B", unit_scale=True, unit_divisor=1024, desc=rf.key,
            file=progress_file or sys.stderr, disable=not show_progress, leave=True, mininterval=0.2,
        )  # fmt: skip
        try:
            if have < rf.size_bytes:
                _fetch_into(rf, part, have, timeout_s, bar)
            break
        except (OSError, http.client.HTTPException, FootageError) as exc:
            attempt += 1
            got = part.stat().st_size if part.exists() else 0
            if isinstance(exc, FootageError) and "HTTP 4" in str(exc):
                raise
            if attempt > retries:
                raise FootageError(
                    f"download of {rf.key} interrupted at {got}/{rf.size_bytes} bytes after {attempt} attempt(s) "
                    f"({exc}); run the command again to resume from {part}"
                ) from None
            log.warning("download of %s interrupted at %d bytes (%s); resuming", rf.key, got, exc)
            time.sleep(retry_wait_s)
        finally:
            bar.close()
    why = _verify(part, rf)
    if why is not None:
        part.unlink(missing_ok=True)
        raise FootageError(f"download of {rf.key} rejected: {why}; the partial file was deleted")
    os.replace(part, final)  # atomic on one file system: the final name only ever holds a verified file
    return final


def _fetch_into(rf: RemoteFile, part: Path, have: int, timeout_s: float, bar: tqdm[Any]) -> None:
    headers = {"Range": f"bytes={have}-"} if have > 0 else {}
    with _open(rf.url, timeout_s, headers) as resp:
        status = resp.status
        mode = "ab"
        if have > 0 and status != 206:  # the server ignored the range: start over
            log.info("%s: server does not resume (HTTP %d); restarting", rf.key, status)
            bar.reset(total=rf.size_bytes)
            mode = "wb"
        elif status not in (200, 206):
            raise FootageError(f"GET {rf.url}: HTTP {status}")
        elif status == 206 and not str(resp.headers.get("Content-Range", "")).startswith(f"bytes {have}-"):
            part.unlink(missing_ok=True)  # a range we did not ask for: drop the .part, the retry starts over
            raise ConnectionError(
                f"unexpected Content-Range {resp.headers.get('Content-Range')!r} for bytes={have}-"
            )
        with part.open(mode) as out:
            while True:
                chunk = resp.read(CHUNK_BYTES)
                if not chunk:
                    break
                out.write(chunk)
                bar.update(len(chunk))
    got = part.stat().st_size
    if got < rf.size_bytes:
        raise ConnectionError(f"connection closed after {got} of {rf.size_bytes} bytes")


def download_catalog(
    catalog: CatalogSpec,
    dest_dir: Path,
    *,
    base_url: str | None = None,
    only: tuple[str, ...] = (),
    retries: int = 3,
    timeout_s: float = 30.0,
    progress_file: TextIO | None = None,
    show_progress: bool = True,
) -> list[Path]:
    """Fetch the record, save its JSON beside the files, download the selected files; return their paths."""
    record = fetch_record(catalog, base_url=base_url, timeout_s=timeout_s)
    files = parse_record(record, base_url or catalog.base_url, catalog.record_id)
    chosen = select_files(files, only or catalog.include)
    if not chosen:
        keys = ", ".join(f.key for f in files[:10]) or "none"
        raise FootageError(
            f"record {catalog.record_id}: no file matches {list(only or catalog.include)} (files: {keys})"
        )
    dest_dir.mkdir(parents=True, exist_ok=True)
    tmp = dest_dir / (RECORD_FILE + ".tmp")
    tmp.write_text(json.dumps(record, indent=1))
    os.replace(tmp, dest_dir / RECORD_FILE)
    return [
        download_file(
            rf,
            dest_dir,
            retries=retries,
            timeout_s=timeout_s,
            progress_file=progress_file,
            show_progress=show_progress,
        )
        for rf in chosen
    ]


def cached_record_files(catalog: CatalogSpec, dest_dir: Path) -> list[RemoteFile]:
    """The file list saved by the last `get` (empty when never fetched)."""
    path = dest_dir / RECORD_FILE
    if not path.is_file():
        return []
    with contextlib.suppress(OSError, json.JSONDecodeError, FootageError):
        return parse_record(json.loads(path.read_text()), catalog.base_url, catalog.record_id)
    return []
