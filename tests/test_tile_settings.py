"""Tile cache settings are arguments (`TileSettings`): the tile library never reads the environment itself; the
documented $VIVA_SITL_TILE_* variables are parsed from a mapping, and read from the process only where no settings
are given (`open_footage`). Real generated clips, real tile caches, real automatic cache; no mocks."""

from __future__ import annotations

from pathlib import Path

import pytest

from viva_sitl.footage import FootageError, autocache, open_footage
from viva_sitl.footage.autocache import CachePolicy
from viva_sitl.footage.ingest import ingest_tiles
from viva_sitl.footage.testclip import write_coded_clip
from viva_sitl.footage.tiles import (
    CACHE_ENV,
    DECODE_THREADS_ENV,
    DEFAULT_CACHE_BYTES,
    DEFAULT_DECODE_THREADS,
    TileCache,
    TileSettings,
    TileSource,
)

W, H = 320, 240


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    d = tmp_path_factory.mktemp("settings")
    path = write_coded_clip(d / "s.mp4", frames=3, width_px=W, height_px=H, fps=25, gop=4)
    path.with_suffix(".toml").write_text(
        f'name = "s"\nkind = "video"\npath = "{path.name}"\nrecording_altitude_m = 100.0\nhfov_deg = 80.0\n',
        encoding="utf-8",
    )
    return path


@pytest.fixture(scope="module")
def jpeg_cache(clip: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("jpeg") / "c"
    ingest_tiles(str(clip.with_suffix(".toml")), out_dir=out, codec="jpeg", show_progress=False)
    return out


def test_settings_from_a_mapping() -> None:
    assert TileSettings.from_environ({}) == TileSettings(DEFAULT_CACHE_BYTES, DEFAULT_DECODE_THREADS)
    assert TileSettings.from_environ({CACHE_ENV: " ", DECODE_THREADS_ENV: ""}) == TileSettings()
    got = TileSettings.from_environ({CACHE_ENV: "0.5", DECODE_THREADS_ENV: "1", "UNRELATED": "x"})
    assert got == TileSettings(cache_bytes=1 << 19, decode_threads=1)
    for var, bad in [(CACHE_ENV, "0"), (CACHE_ENV, "nan"), (CACHE_ENV, "lots"), (DECODE_THREADS_ENV, "1.5")]:
        with pytest.raises(FootageError, match=f"\\${var}={bad!r}: give ") as err:
            TileSettings.from_environ({var: bad})
        assert "\n" not in str(err.value)


def test_the_library_takes_its_settings_as_arguments(
    jpeg_cache: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A bad (or any) environment does not reach a TileCache / TileSource / open_footage given settings."""
    monkeypatch.setenv(CACHE_ENV, "lots")
    monkeypatch.setenv(DECODE_THREADS_ENV, "0")
    cache = TileCache(jpeg_cache)  # no settings: the defaults, not the environment
    try:
        assert cache.cache_bytes == DEFAULT_CACHE_BYTES and cache._pool is not None
    finally:
        cache.close()
    cache = TileCache(jpeg_cache, TileSettings(cache_bytes=1 << 20, decode_threads=1))
    try:
        assert cache.cache_bytes == 1 << 20 and cache._pool is None
    finally:
        cache.close()
    src = open_footage(str(jpeg_cache), tiles=TileSettings(cache_bytes=3 << 20, decode_threads=1))
    try:
        assert isinstance(src, TileSource)
        assert src.cache.cache_bytes == 3 << 20 and src.cache._pool is None
        assert src.frame(1).shape == (H, W, 3)
    finally:
        src.close()
    with pytest.raises(FootageError, match=CACHE_ENV):  # no settings given: the process's environment is read
        open_footage(str(jpeg_cache))


def test_a_bad_environment_fails_before_the_automatic_cache_is_checked(
    clip: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A bad $VIVA_SITL_TILE_CACHE_MB is one error raised before the automatic cache is looked at: the valid cache
    is neither reported corrupt nor rebuilt (its checks read it with their own settings)."""
    pol = CachePolicy(root=tmp_path / "auto", min_pixels=1, show_progress=False)
    open_footage(str(clip), cache=pol).close()  # built
    (entry,) = autocache.list_caches(pol.directory())
    packs = sorted((entry.folder / "tiles").glob("pack-*.bin"))
    stamp = [p.stat().st_mtime_ns for p in packs]
    monkeypatch.setenv(CACHE_ENV, "lots")
    with pytest.raises(FootageError, match=CACHE_ENV) as err:
        open_footage(str(clip), cache=pol)
    assert "\n" not in str(err.value)
    assert "corrupt" not in caplog.text
    assert [p.stat().st_mtime_ns for p in packs] == stamp  # not rebuilt
    with open_footage(str(clip), cache=pol, tiles=TileSettings(decode_threads=1)) as src:
        assert isinstance(src, TileSource) and src.cache._pool is None
    assert [p.stat().st_mtime_ns for p in packs] == stamp
