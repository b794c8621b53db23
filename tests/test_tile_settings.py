"""Tile cache settings are arguments (`TileSettings`): the footage layer never reads the environment; the
documented $VIVA_SITL_TILE_* variables are parsed from a mapping by the top floor (the commands, the gym, the
benches), which makes them the process's settings; a campaign hands them to its workers as an argument. Real
generated clips, real tile caches, real automatic cache, real worker processes; no mocks."""

from __future__ import annotations

import ast
import os
from pathlib import Path

import pytest

from viva_sitl.evaluation.campaign import run_campaign
from viva_sitl.evaluation.spec import spec_from_dict
from viva_sitl.footage import FootageError, autocache, open_footage
from viva_sitl.footage.autocache import CachePolicy
from viva_sitl.footage.ingest import ingest_tiles
from viva_sitl.footage.testclip import write_coded_clip
from viva_sitl.footage.tiles import (
    CACHE_ENV,
    DECODE_THREADS_ENV,
    DEFAULT_CACHE_BYTES,
    DEFAULT_DECODE_THREADS,
    READ_AHEAD_ENV,
    TileCache,
    TileSettings,
    TileSource,
    process_settings,
    set_process_settings,
)

W, H = 320, 240
CORES = os.cpu_count() or 1


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
    assert TileSettings.from_environ({}) == TileSettings(DEFAULT_CACHE_BYTES, None)
    assert TileSettings.from_environ({}).threads == DEFAULT_DECODE_THREADS  # not chosen: the default
    assert TileSettings.from_environ({CACHE_ENV: " ", DECODE_THREADS_ENV: ""}) == TileSettings()
    got = TileSettings.from_environ({CACHE_ENV: "0.5", DECODE_THREADS_ENV: "1", "UNRELATED": "x"})
    assert got == TileSettings(cache_bytes=1 << 19, decode_threads=1)
    assert TileSettings.from_environ({READ_AHEAD_ENV: "0"}) == TileSettings(read_ahead=False)
    assert TileSettings.from_environ({READ_AHEAD_ENV: "1"}) == TileSettings() == TileSettings(read_ahead=True)
    for var, bad in [(CACHE_ENV, "0"), (CACHE_ENV, "nan"), (CACHE_ENV, "lots"), (DECODE_THREADS_ENV, "1.5"),
                     (READ_AHEAD_ENV, "2"), (READ_AHEAD_ENV, "yes")]:  # fmt: skip
        with pytest.raises(FootageError, match=f"\\${var}={bad!r}: give ") as err:
            TileSettings.from_environ({var: bad})
        assert "\n" not in str(err.value)
    # handed to a child process as the documented variables, read back exactly; the chosen threads win over a share
    for s in (
        TileSettings(),
        TileSettings(cache_bytes=3 << 20, decode_threads=1),
        TileSettings(cache_bytes=12345),
        TileSettings(decode_threads=2, read_ahead=False),
    ):
        assert TileSettings.from_environ(s.to_environ()) == s
    assert (
        TileSettings().or_threads(3).threads == 3
        and TileSettings(decode_threads=2).or_threads(3).threads == 2
    )


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
    before = process_settings()
    try:  # no settings given: the process's (set by the top floor), never the environment
        src = open_footage(str(jpeg_cache))
        try:
            assert isinstance(src, TileSource) and src.cache.cache_bytes == DEFAULT_CACHE_BYTES
        finally:
            src.close()
        set_process_settings(TileSettings(cache_bytes=5 << 20, decode_threads=1))
        src = open_footage(str(jpeg_cache))
        try:
            assert (
                isinstance(src, TileSource) and src.cache.cache_bytes == 5 << 20 and src.cache._pool is None
            )
        finally:
            src.close()
    finally:
        set_process_settings(before)


def test_a_bad_environment_does_not_reach_the_automatic_cache(
    clip: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """A bad $VIVA_SITL_TILE_CACHE_MB is refused by the top floor (one line, before anything is opened: see
    tests/test_tiles.py and tests/test_trials.py); `open_footage` does not read it: the valid automatic cache opens
    with the process's settings, neither reported corrupt nor rebuilt."""
    pol = CachePolicy(root=tmp_path / "auto", min_pixels=1, show_progress=False)
    open_footage(str(clip), cache=pol).close()  # built
    (entry,) = autocache.list_caches(pol.directory())
    packs = sorted((entry.folder / "tiles").glob("pack-*.bin"))
    stamp = [p.stat().st_mtime_ns for p in packs]
    monkeypatch.setenv(CACHE_ENV, "lots")
    with open_footage(str(clip), cache=pol) as src:
        assert isinstance(src, TileSource) and src.cache.cache_bytes == process_settings().cache_bytes
    assert "corrupt" not in caplog.text
    assert [p.stat().st_mtime_ns for p in packs] == stamp  # not rebuilt
    with open_footage(str(clip), cache=pol, tiles=TileSettings(decode_threads=1)) as src:
        assert isinstance(src, TileSource) and src.cache._pool is None
    assert [p.stat().st_mtime_ns for p in packs] == stamp


# the process's own environment may be read (a documented path lookup, not a tile setting) only here
ENVIRON_READERS = {
    "paths.py"
}  # $VIVA_SITL_SHARED_DIR and $XDG_CACHE_HOME: where footage lives, not how it is read


def _reads_environment(tree: ast.AST) -> list[int]:
    """Lines of `os.environ` / `os.getenv` / `environ` / `getenv` (imported from os) uses in a module."""
    names = ("environ", "getenv", "environb", "getenvb")
    attrs = [n.lineno for n in ast.walk(tree) if isinstance(n, ast.Attribute) and n.attr in names]
    imports = [
        n.lineno
        for n in ast.walk(tree)
        if isinstance(n, ast.ImportFrom) and n.module == "os" and any(a.name in names for a in n.names)
    ]
    return attrs + imports


def test_the_footage_layer_reads_no_environment_for_tiles() -> None:
    """No module under viva_sitl/footage reads the process's environment (paths.py's documented shared-dir and
    XDG cache-dir lookups aside): the tile settings come from arguments or the process's settings, which the
    top floor sets."""
    root = Path(__file__).resolve().parents[1] / "viva_sitl" / "footage"
    files = sorted(root.rglob("*.py"))
    assert len(files) > 10
    found = {
        str(f.relative_to(root)): lines
        for f in files
        if f.name not in ENVIRON_READERS
        and (lines := _reads_environment(ast.parse(f.read_text(encoding="utf-8"))))
    }
    assert found == {}, f"os.environ read in the footage layer: {found}"
    for name in ENVIRON_READERS:  # the exception reads no tile variable either
        text = (root / name).read_text(encoding="utf-8")
        assert CACHE_ENV not in text and DECODE_THREADS_ENV not in text and "VIVA_SITL_TILE" not in text


class SettingsProbe:
    """An in-process pilot that ends its trial at its first step with the tile settings its worker reads with."""

    name, control_hz, frame_hz, uses_ground_truth = "settings-probe", 5.0, 0.0, False

    def reset(self, scenario: object, truth: object) -> None:
        pass

    def act(self, obs, ctl):  # type: ignore[no-untyped-def]
        raise RuntimeError(f"worker tiles {process_settings()!r}; env {os.environ.get(DECODE_THREADS_ENV)!r}")


@pytest.mark.parametrize(
    ("given", "expected"),
    [
        (
            TileSettings(cache_bytes=3 << 20, decode_threads=3),
            TileSettings(cache_bytes=3 << 20, decode_threads=3),
        ),
        # threads not chosen: the worker's share of the cores (2 jobs)
        (
            TileSettings(cache_bytes=5 << 20),
            TileSettings(cache_bytes=5 << 20, decode_threads=max(1, CORES // 2)),
        ),
    ],
)
def test_campaign_workers_get_the_tile_settings_as_an_argument(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, given: TileSettings, expected: TileSettings
) -> None:
    """A campaign hands its TileSettings to its (spawned) workers as an argument: they read with them although
    neither variable is set, in the parent or the worker."""
    monkeypatch.delenv(CACHE_ENV, raising=False)
    monkeypatch.delenv(DECODE_THREADS_ENV, raising=False)
    spec = spec_from_dict(
        {
            "trials": {"n": 2, "seed": 1, "timeout_s": 5.0},
            "scenario": {"footage": "synthetic", "start": "air"},
        },
        "probe",
    )
    camp = run_campaign(
        spec, "tests.test_tile_settings:SettingsProbe", tmp_path, jobs=2, progress=False, tiles=given
    )
    rows = camp.ordered_rows()
    assert len(rows) == 2
    for row in rows:
        assert row["end"] == "pilot_error", row
        assert f"worker tiles {expected!r}; env None" in str(row["end_detail"]), row["end_detail"]
