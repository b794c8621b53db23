"""The footage catalog: Zenodo-shaped record, downloads with progress, resume, size/md5 checks (against a local HTTP
server on 127.0.0.1), the `footage` CLI, and ingest into the fast-decoding cache."""

from __future__ import annotations

import hashlib
import io
import json
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np
import pytest

from viva_sitl.cli_footage import footage_main
from viva_sitl.footage import CatalogSpec, FootageError, VideoSource, open_footage
from viva_sitl.footage.catalog import RemoteFile, download_catalog, download_file, parse_record
from viva_sitl.footage.ingest import ingest
from viva_sitl.footage.testclip import read_code, write_coded_clip

RECORD_ID = 13942934
SRT = """1
00:00:00,000 --> 00:00:00,033
<font size="28">FrameCnt: 1 [latitude: 19.4326] [longitude: -99.1332] [rel_alt: 64.200 abs_alt: 2300.0] </font>
"""


@dataclass
class FakeZenodo:
    """Files by key; `cut_first[key]` = bytes to send before dropping the connection on the first GET of that key."""

    files: dict[str, bytes]
    cut_first: dict[str, int] = field(default_factory=dict)
    honour_range: bool = True
    wrong_md5: set[str] = field(default_factory=set)
    requests: list[tuple[str, str | None]] = field(default_factory=list)  # (path, Range header)
    base_url: str = ""

    def record(self) -> dict[str, object]:
        files = []
        for key, data in self.files.items():
            md5 = hashlib.md5(data, usedforsecurity=False).hexdigest()
            if key in self.wrong_md5:
                md5 = "0" * 32
            files.append(
                {
                    "id": f"id-{key}",
                    "key": key,
                    "size": len(data),
                    "checksum": f"md5:{md5}",
                    "links": {"self": f"{self.base_url}/api/records/{RECORD_ID}/files/{key}/content"},
                }
            )
        return {"id": RECORD_ID, "metadata": {"title": "fake ViVa-SAFELAND"}, "files": files}


def _handler(state: FakeZenodo) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        def log_message(self, *args: object) -> None:  # keep pytest output clean
            pass

        def do_GET(self) -> None:  # noqa: N802 - http.server's naming
            state.requests.append((self.path, self.headers.get("Range")))
            if self.path == f"/api/records/{RECORD_ID}":
                body = json.dumps(state.record()).encode()
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)
                return
            prefix = f"/api/records/{RECORD_ID}/files/"
            key = self.path[len(prefix) : -len("/content")] if self.path.startswith(prefix) else ""
            if key not in state.files:
                self.send_error(404)
                return
            data = state.files[key]
            start = 0
            rng = self.headers.get("Range")
            if rng and state.honour_range:
                start = int(rng.split("=")[1].split("-")[0])
                self.send_response(206)
                self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
            else:
                self.send_response(200)
            self.send_header("Content-Length", str(len(data) - start))
            self.end_headers()
            cut = state.cut_first.pop(key, None)
            if cut is not None:  # send part of the body, then drop the connection
                self.wfile.write(data[start : start + cut])
                self.wfile.flush()
                self.close_connection = True
                return
            self.wfile.write(data[start:])

    return Handler


@pytest.fixture
def zenodo(tmp_path: Path) -> Iterator[FakeZenodo]:
    clip = write_coded_clip(tmp_path / "src.mp4", 40, width_px=256, height_px=144)
    rng = np.random.default_rng(0)
    state = FakeZenodo(
        files={
            "DJI_0001.MP4": clip.read_bytes(),
            "DJI_0001.SRT": SRT.encode(),
            "big.bin": rng.integers(0, 256, 600_000, dtype=np.uint8).tobytes(),
            "README.txt": b"not a video",
        }
    )
    server = ThreadingHTTPServer(("127.0.0.1", 0), _handler(state))
    state.base_url = f"http://127.0.0.1:{server.server_address[1]}"
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield state
    finally:
        server.shutdown()
        server.server_close()
        thread.join()


def _catalog(base_url: str) -> CatalogSpec:
    return CatalogSpec(
        name="viva-safeland", record_id=RECORD_ID, base_url=base_url, defaults=(("hfov_deg", 82.1),)
    )


def _remote(zenodo: FakeZenodo, key: str) -> RemoteFile:
    files = parse_record(zenodo.record(), zenodo.base_url, RECORD_ID)
    return next(f for f in files if f.key == key)


def test_parse_record_shape() -> None:
    record = {
        "files": [
            {
                "key": "a.MP4",
                "size": 10,
                "checksum": "md5:ABCDEF",
                "links": {"self": "https://x/api/records/1/files/a.MP4/content"},
            },
            {"key": "b.SRT", "size": 3, "checksum": "sha256:00", "links": {}},
        ]
    }
    a, b = parse_record(record, "https://zenodo.org/", 1)
    assert (a.key, a.size_bytes, a.md5_hex, a.url) == (
        "a.MP4",
        10,
        "abcdef",
        "https://x/api/records/1/files/a.MP4/content",
    )
    assert b.md5_hex is None and b.url == "https://zenodo.org/api/records/1/files/b.SRT/content"
    with pytest.raises(FootageError, match="unsafe file name"):
        parse_record({"files": [{"key": "../evil", "size": 1}]}, "https://zenodo.org", 1)
    with pytest.raises(FootageError, match="no file list"):
        parse_record({"hits": []}, "https://zenodo.org", 1)


def test_download_with_progress_and_checks(zenodo: FakeZenodo, tmp_path: Path) -> None:
    out = io.StringIO()
    path = download_file(_remote(zenodo, "big.bin"), tmp_path / "dl", progress_file=out)
    assert path.read_bytes() == zenodo.files["big.bin"]
    assert not (tmp_path / "dl" / "big.bin.part").exists()
    bar = out.getvalue()
    assert "100%" in bar and "big.bin" in bar  # tqdm progress bar went to the given stream
    n = len(zenodo.requests)
    assert download_file(_remote(zenodo, "big.bin"), tmp_path / "dl", show_progress=False) == path
    assert len(zenodo.requests) == n  # verified local copy: nothing downloaded again


def test_resume_after_a_cut_connection_within_one_call(zenodo: FakeZenodo, tmp_path: Path) -> None:
    zenodo.cut_first["big.bin"] = 250_000
    path = download_file(_remote(zenodo, "big.bin"), tmp_path, show_progress=False, retry_wait_s=0.0)
    assert path.read_bytes() == zenodo.files["big.bin"]
    ranges = [r for p, r in zenodo.requests if p.endswith("big.bin/content")]
    assert ranges[0] is None and ranges[1] == "bytes=250000-"  # second request resumed at the cut


def test_resume_a_part_file_left_by_an_interrupted_run(zenodo: FakeZenodo, tmp_path: Path) -> None:
    zenodo.cut_first["big.bin"] = 100_000
    rf = _remote(zenodo, "big.bin")
    with pytest.raises(FootageError, match="interrupted at 100000/600000 bytes.*resume"):
        download_file(rf, tmp_path, retries=0, show_progress=False)
    part = tmp_path / "big.bin.part"
    assert part.stat().st_size == 100_000 and not (tmp_path / "big.bin").exists()
    out = io.StringIO()
    path = download_file(rf, tmp_path, retries=0, progress_file=out)
    assert path.read_bytes() == zenodo.files["big.bin"] and not part.exists()
    assert zenodo.requests[-1][1] == "bytes=100000-"
    assert "100%" in out.getvalue()


def test_server_without_range_support_restarts_cleanly(zenodo: FakeZenodo, tmp_path: Path) -> None:
    zenodo.honour_range = False
    (tmp_path / "big.bin.part").write_bytes(b"garbage" * 1000)  # a stale .part that must not be kept
    path = download_file(_remote(zenodo, "big.bin"), tmp_path, show_progress=False)
    assert path.read_bytes() == zenodo.files["big.bin"]


def test_checksum_mismatch_is_rejected_and_leaves_nothing(zenodo: FakeZenodo, tmp_path: Path) -> None:
    zenodo.wrong_md5.add("big.bin")
    with pytest.raises(FootageError, match="rejected: md5 .* the record says 0{32}"):
        download_file(_remote(zenodo, "big.bin"), tmp_path / "dl", show_progress=False)
    assert list((tmp_path / "dl").iterdir()) == []


def test_size_mismatch_is_rejected(zenodo: FakeZenodo, tmp_path: Path) -> None:
    rf = _remote(zenodo, "README.txt")
    short = RemoteFile(rf.key, rf.size_bytes - 3, None, rf.url)  # the server sends more than the record says
    with pytest.raises(FootageError, match="size"):
        download_file(short, tmp_path, retries=0, show_progress=False)
    assert not (tmp_path / "README.txt").exists()


def test_http_errors_are_footage_errors(zenodo: FakeZenodo, tmp_path: Path) -> None:
    missing = RemoteFile(
        "nope.mp4", 10, None, f"{zenodo.base_url}/api/records/{RECORD_ID}/files/nope.mp4/content"
    )
    with pytest.raises(FootageError, match="HTTP 404"):
        download_file(missing, tmp_path, show_progress=False)
    with pytest.raises(FootageError, match="cannot connect"):
        download_catalog(_catalog("http://127.0.0.1:9"), tmp_path, timeout_s=2.0, show_progress=False)


def test_get_catalog_then_open_the_downloaded_video(zenodo: FakeZenodo, tmp_path: Path) -> None:
    cfg = tmp_path / "configs"
    cfg.mkdir()
    (cfg / "viva-safeland.toml").write_text(
        '[catalog]\nname = "viva-safeland"\nrecord_id = 13942934\nbase_url = "https://zenodo.org"\n'
        "[defaults]\nhfov_deg = 82.1\n"
    )
    cache = tmp_path / "cache"
    common = ["--config-dir", str(cfg), "--cache-dir", str(cache)]
    assert (
        footage_main(["get", "viva-safeland", "--base-url", zenodo.base_url, "--no-progress", *common]) == 0
    )
    folder = cache / "downloads" / "viva-safeland"
    assert sorted(p.name for p in folder.iterdir()) == ["DJI_0001.MP4", "DJI_0001.SRT", "record.json"]
    with open_footage("viva-safeland/DJI_0001", config_dir=cfg, cache_dir=cache) as src:
        assert isinstance(src, VideoSource) and src.frame_count == 40
        assert src.geometry.recording_altitude_m == pytest.approx(64.2)  # from the downloaded .SRT
        assert src.geometry.recording_hfov_deg == pytest.approx(82.1)  # the catalog default
        assert read_code(src.frame(17)) == 17
    assert footage_main(["list", *common]) == 0
    assert footage_main(["info", "viva-safeland/DJI_0001", *common]) == 0
    dest = tmp_path / "elsewhere"
    rc = footage_main(["get", "viva-safeland", "--only", "*.bin", "--dest", str(dest), "--no-progress", "--base-url", zenodo.base_url, *common])  # fmt: skip
    assert rc == 0 and (dest / "big.bin").read_bytes() == zenodo.files["big.bin"]
    assert footage_main(["get", "interchange", *common]) == 2  # not a remote catalog: exit 2, one message


def test_list_shows_downloaded_files(
    zenodo: FakeZenodo, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    cat = _catalog(zenodo.base_url)
    cfg = tmp_path / "configs"
    cfg.mkdir()
    (cfg / "viva-safeland.toml").write_text('[catalog]\nname = "viva-safeland"\nrecord_id = 13942934\n')
    cache = tmp_path / "cache"
    assert footage_main(["list", "--config-dir", str(cfg), "--cache-dir", str(cache)]) == 0
    assert "not fetched" in capsys.readouterr().out
    download_catalog(cat, cache / "downloads" / "viva-safeland", only=("*.SRT",), show_progress=False)
    assert footage_main(["list", "--config-dir", str(cfg), "--cache-dir", str(cache)]) == 0
    out = capsys.readouterr().out
    assert "viva-safeland/DJI_0001" in out and "0/1 files" in out  # the video is known but not local yet


def test_ingest_a_small_clip(tmp_path: Path) -> None:
    clip = write_coded_clip(tmp_path / "heavy.mp4", 36, width_px=320, height_px=240, gop=250)
    (tmp_path / "heavy.toml").write_text("recording_altitude_m = 60.0\nhfov_deg = 80.0\nheading_deg = 10.0\n")
    cache = tmp_path / "cache"
    out = io.StringIO()
    dest = ingest(clip, cache_dir=cache, progress_file=out)
    assert dest == cache / "ingest" / "heavy-ingest"
    assert "36/36" in out.getvalue()  # progress bar
    assert sorted(p.name for p in dest.iterdir()) == ["footage.toml", "full.mp4", "half.mp4"]
    with open_footage(clip) as src, open_footage("heavy-ingest", cache_dir=cache) as cached:
        assert isinstance(cached, VideoSource)
        assert cached.frame_count == src.frame_count == 36 and cached.fps == src.fps
        assert cached.geometry == src.geometry
        for i in (0, 17, 35, 5):
            a, b = src.frame(i).astype(float), cached.frame(i).astype(float)
            psnr = 10 * np.log10(255.0**2 / max(np.mean((a - b) ** 2), 1e-9))
            assert psnr > 30.0 and read_code(cached.frame(i)) == i
        half = cached.frame(17, level=1)
        assert half.shape == (120, 160, 3) and read_code(half) == 17
    with open_footage(dest) as by_folder:
        assert by_folder.frame_count == 36
    assert (
        footage_main(["ingest", str(tmp_path / "missing.mp4"), "--cache-dir", str(cache), "--no-progress"])
        == 2
    )
    assert not list((cache / "ingest").glob("*.tmp-ingest"))


def test_default_cache_dir_follows_xdg(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    from viva_sitl.footage.paths import default_cache_dir

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert default_cache_dir() == tmp_path / "viva-sitl"
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert default_cache_dir() == Path.home() / ".cache" / "viva-sitl"
