"""The automatic tile cache (viva_sitl.footage.autocache): heavy video is served from a cache built once in the user
cache directory, within the codec's PSNR of the video; a second process waits for a build in progress instead of
reading it; a corrupt cache is rebuilt with one line; the size bound evicts the least recently used cache;
`--no-cache` reads the video. Real generated H.264 clips, real files, real processes and locks; no mocks."""

from __future__ import annotations

import json
import logging
import math
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from viva_sitl.cli import main as cli_main
from viva_sitl.cli_footage import footage_main
from viva_sitl.footage import autocache, open_footage
from viva_sitl.footage.autocache import CachePolicy
from viva_sitl.footage.source import VideoSource
from viva_sitl.footage.testclip import write_coded_clip
from viva_sitl.footage.tiles import TileLayout, TileSource
from viva_sitl.sim import Simulator

REPO = Path(__file__).resolve().parents[1]
MIN_PSNR_DB = 45.0  # the yuv420z codec's bound, as tests/test_tiles.py states it for the render


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b) ** 2))
    return math.inf if mse == 0.0 else 10.0 * math.log10(255.0**2 / mse)


def _clip(d: Path, name: str, frames: int = 4, w: int = 320, h: int = 240) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    path = write_coded_clip(d / f"{name}.mp4", frames=frames, width_px=w, height_px=h, fps=25, gop=4)
    path.with_suffix(".toml").write_text(
        f'name = "{name}"\nkind = "video"\npath = "{path.name}"\nrecording_altitude_m = 100.0\nhfov_deg = 80.0\n',
        encoding="utf-8",
    )
    return path


def _policy(root: Path, **kw: object) -> CachePolicy:
    # min_pixels=1: the small test clips count as heavy (the real threshold is tested with a 4K clip below)
    return CachePolicy(root=root, min_pixels=1, show_progress=False, **kw)  # type: ignore[arg-type]


def test_heavy_video_is_cached_once_and_renders_within_the_bound(tmp_path: Path) -> None:
    clip = _clip(tmp_path / "v", "a")
    pol = _policy(tmp_path / "auto")
    src = open_footage(str(clip), cache=pol)
    video = open_footage(str(clip), cache=CachePolicy(enabled=False))
    try:
        assert isinstance(src, TileSource) and src.cache.codec == "yuv420z"
        assert isinstance(video, VideoSource)
        assert src.frame_count == video.frame_count == 4
        assert src.geometry == video.geometry and src.fps == video.fps
        for i in range(4):
            assert _psnr(src.frame(i), video.frame(i)) >= MIN_PSNR_DB
    finally:
        src.close()
        video.close()
    (entry,) = autocache.list_caches(pol.directory())
    assert entry.frames == 4 and entry.source == str(clip.resolve())
    packs = sorted((entry.folder / "tiles").glob("pack-*.bin"))
    stamp = [p.stat().st_mtime_ns for p in packs]
    again = open_footage(str(clip), cache=pol)  # reused, not rebuilt
    again.close()
    assert [p.stat().st_mtime_ns for p in packs] == stamp
    assert [e.key for e in autocache.list_caches(pol.directory())] == [entry.key]
    # the key is the content, not the path: a copy elsewhere opens the same cache
    copy = tmp_path / "elsewhere" / "b.mp4"
    copy.parent.mkdir()
    copy.write_bytes(clip.read_bytes())
    c = open_footage(str(copy), altitude_m=100.0, hfov_deg=80.0, cache=pol)
    c.close()
    assert len(autocache.list_caches(pol.directory())) == 1


def test_the_embedded_default_and_small_videos_build_nothing(tmp_path: Path) -> None:
    clip = _clip(tmp_path / "v", "small")
    pol = CachePolicy(root=tmp_path / "auto", show_progress=False)  # the real threshold: ~4K
    with open_footage(None, cache=pol) as s:  # the synthetic field (README's first command)
        assert not isinstance(s, TileSource | VideoSource)
    with open_footage(str(clip), cache=pol) as v:
        assert isinstance(v, VideoSource)
    assert not pol.directory().exists()


def test_no_cache_renders_from_the_video_and_the_cli_flag_reaches_the_simulator(tmp_path: Path) -> None:
    clip = _clip(tmp_path / "v", "a")
    before = autocache.policy()
    try:
        autocache.set_policy(_policy(tmp_path / "auto", enabled=False))
        sim = Simulator(footage=str(clip))
        assert isinstance(sim.footage, VideoSource)
        plain = sim.render().image_bgr
        sim.close()
        assert not (tmp_path / "auto").exists()
        autocache.set_policy(_policy(tmp_path / "auto"))
        sim = Simulator(footage=str(clip))
        assert isinstance(sim.footage, TileSource)
        assert _psnr(sim.render().image_bgr, plain) >= MIN_PSNR_DB
        sim.close()
    finally:
        autocache.set_policy(before)


def test_render_cli_caches_4k_footage_unless_no_cache(tmp_path: Path) -> None:
    """`render` over 4K footage builds the automatic cache (none with --no-cache); with --cache-compact a yuv420zg
    cache beside it, smaller, rendering the same pixels."""
    clip = _clip(tmp_path / "v", "uhd", frames=2, w=3840, h=2160)
    root = tmp_path / "auto"
    before = autocache.policy()
    try:
        common = ["--footage", str(clip), "--pose", "0,0,50,0,0,0", "--tile-cache-dir", str(root)]
        assert cli_main(["render", *common, "--no-cache", "-o", str(tmp_path / "plain.png")]) == 0
        assert not root.exists()
        assert cli_main(["render", *common, "-o", str(tmp_path / "cached.png")]) == 0
        (entry,) = autocache.list_caches(root)
        assert entry.frames == 2
        mib_per_frame = entry.bytes / 2 / 2**20
        assert mib_per_frame <= 8.0  # the bound (this synthetic clip is smooth: far below it)
        a, b = cv2.imread(str(tmp_path / "plain.png")), cv2.imread(str(tmp_path / "cached.png"))
        assert _psnr(a, b) >= MIN_PSNR_DB
        assert cli_main(["render", *common, "--cache-compact", "-o", str(tmp_path / "compact.png")]) == 0
        caches = {e.codec: e for e in autocache.list_caches(root)}
        assert set(caches) == {"yuv420z", "yuv420zg"} and caches["yuv420z"].key == entry.key
        assert caches["yuv420zg"].bytes < caches["yuv420z"].bytes
        assert np.array_equal(cv2.imread(str(tmp_path / "compact.png")), b)
    finally:
        autocache.set_policy(before)


CHILD_BUILDER = """
import sys, time
from pathlib import Path
from typing import Any
from viva_sitl.footage import open_footage, autocache
clip, root, started, go = (Path(a) for a in sys.argv[1:5])
pol = autocache.CachePolicy(root=root, min_pixels=1, show_progress=False)
src = open_footage(str(clip), cache=autocache.CachePolicy(enabled=False))  # the frames, from the video
n, size, fps = src.frame_count, src.frame_size_px, src.fps
frames = [src.frame(i) for i in range(n)]
src.close()
def slow():
    started.touch()
    while not go.exists():  # the test lets the build finish once the other process is seen waiting
        time.sleep(0.02)
    yield from frames
print(autocache.ensure_cache(clip, slow, n, size, fps, pol, "a"), flush=True)
"""

CHILD_READER = """
import logging, sys
from pathlib import Path
from typing import Any
from viva_sitl.footage import open_footage, autocache
logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")
clip, root = Path(sys.argv[1]), Path(sys.argv[2])
src = open_footage(str(clip), cache=autocache.CachePolicy(root=root, min_pixels=1, show_progress=False))
print(type(src).__name__, src.cache.folder, src.frame_count, flush=True)
"""


def test_a_second_process_waits_for_the_build_in_progress(tmp_path: Path) -> None:
    clip = _clip(tmp_path / "v", "a")
    root = tmp_path / "auto"
    started, go = tmp_path / "started", tmp_path / "go"
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    builder = subprocess.Popen(
        [sys.executable, "-c", CHILD_BUILDER, str(clip), str(root), str(started), str(go)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
    )  # fmt: skip
    reader = None
    try:
        deadline = time.monotonic() + 60
        while not started.exists():
            assert builder.poll() is None, builder.communicate()
            assert time.monotonic() < deadline, "the builder never started"
            time.sleep(0.02)
        key = autocache.content_key(clip, CachePolicy(root=root), (320, 240))
        reader = subprocess.Popen(
            [sys.executable, "-c", CHILD_READER, str(clip), str(root)],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        )  # fmt: skip
        assert reader.stderr is not None
        line = reader.stderr.readline()  # blocks until the reader logs something
        assert "another process is building it; waiting" in line, line
        assert reader.poll() is None  # still waiting: the build is not finished
        assert (root / f"{key}.partial").is_dir() and not (root / key).exists()
        go.touch()
        out_b, err_b = builder.communicate(timeout=60)
        assert builder.returncode == 0, err_b
        out_r, err_r = reader.communicate(timeout=60)
        assert reader.returncode == 0, err_r
        assert out_r.split() == ["TileSource", str(root / key), "4"]
        assert "built" not in err_r and "rebuilding" not in err_r  # the reader built nothing
        assert out_b.strip() == str(root / key)
    finally:
        go.touch()
        for p in (builder, reader):
            if p is not None and p.poll() is None:
                p.kill()
                p.wait()


def test_a_corrupt_or_truncated_cache_is_rebuilt_with_one_line(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    clip = _clip(tmp_path / "v", "a")
    pol = _policy(tmp_path / "auto")
    open_footage(str(clip), cache=pol).close()
    (entry,) = autocache.list_caches(pol.directory())
    pack = entry.folder / "tiles" / "pack-000.bin"
    good = pack.read_bytes()
    for damage in ("truncate", "flip"):
        if damage == "truncate":
            pack.write_bytes(good[: len(good) // 2])
        else:
            pack.write_bytes(good[:100] + bytes([good[100] ^ 0xFF]) + good[101:])  # frame 0: checksum
        caplog.clear()
        with caplog.at_level(logging.INFO, logger="viva_sitl.footage.autocache"):
            src = open_footage(str(clip), cache=pol)
        try:
            assert isinstance(src, TileSource)
            video = open_footage(str(clip), cache=CachePolicy(enabled=False))
            assert all(_psnr(src.frame(i), video.frame(i)) >= MIN_PSNR_DB for i in range(4))
            video.close()
        finally:
            src.close()
        warnings = [r for r in caplog.records if r.levelno >= logging.WARNING]
        assert (
            len(warnings) == 1
            and "is corrupt" in warnings[0].getMessage()
            and "rebuilding" in warnings[0].getMessage()
        )
        assert pack.read_bytes() == good  # rebuilt identically


def test_a_build_stopped_by_ctrl_c_says_so_in_one_line_and_the_next_open_resumes_it(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    """Ctrl-C during the automatic build (here: KeyboardInterrupt from the frame source after 6 of 10 frames): one
    warning line with the frames kept, the interrupt goes on to the caller, only `<key>.partial/` is on disk (nothing
    reads it), and the next open resumes from the committed frames and finishes."""
    clip = _clip(tmp_path / "v", "stopped", frames=10)
    pol = _policy(tmp_path / "auto", codec="yuv420zg")
    with open_footage(str(clip), cache=CachePolicy(enabled=False)) as video:
        n, size, fps = video.frame_count, video.frame_size_px, video.fps
        frames = [video.frame(i) for i in range(n)]

    def stopped() -> Any:
        yield from frames[:6]
        raise KeyboardInterrupt

    caplog.clear()
    with (
        caplog.at_level(logging.WARNING, logger="viva_sitl.footage.autocache"),
        pytest.raises(KeyboardInterrupt),
    ):
        autocache.ensure_cache(clip, stopped, n, size, fps, pol, "stopped")
    lines = [r.getMessage() for r in caplog.records if "interrupted" in r.getMessage()]
    assert lines == ["tile cache of stopped: build interrupted after 4 of 10 frames; the next run resumes it"]
    assert autocache.list_caches(pol.directory()) == []
    assert [p.suffix for p in pol.directory().iterdir() if p.is_dir()] == [".partial"]
    with (
        open_footage(str(clip), cache=pol) as src,
        open_footage(str(clip), cache=_policy(tmp_path / "b")) as fresh,
    ):
        assert isinstance(src, TileSource) and src.frame_count == 10 and src.cache.codec == "yuv420zg"
        assert all(np.array_equal(src.frame(i), fresh.frame(i)) for i in range(10))  # the same pixels
    assert [p.suffix for p in pol.directory().iterdir() if p.is_dir()] == [""]


def test_the_size_bound_evicts_the_least_recently_used_cache(tmp_path: Path) -> None:
    # three videos of different content (3, 4 and 5 frames)
    clips = [_clip(tmp_path / n, n, frames=k) for n, k in (("a", 3), ("b", 4), ("c", 5))]
    root = tmp_path / "auto"
    unbounded = _policy(root, max_bytes=None)
    open_footage(str(clips[0]), cache=unbounded).close()
    open_footage(str(clips[1]), cache=unbounded).close()
    open_footage(str(clips[0]), cache=unbounded).close()  # a used after b: b is the least recently used
    sizes = {e.source: e.bytes for e in autocache.list_caches(root)}
    assert len(sizes) == 2
    biggest_c = sizes[str(clips[1].resolve())] * 2  # c has 5 frames, b 4: c < 2 b
    bound = sizes[str(clips[0].resolve())] + biggest_c
    open_footage(str(clips[2]), cache=_policy(root, max_bytes=bound)).close()
    left = {e.source for e in autocache.list_caches(root)}
    assert left == {str(clips[0].resolve()), str(clips[2].resolve())}
    assert sum(e.bytes for e in autocache.list_caches(root)) <= bound


def test_footage_cache_list_and_clear(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    clip = _clip(tmp_path / "v", "a")
    root = tmp_path / "auto"
    open_footage(str(clip), cache=_policy(root)).close()
    assert footage_main(["cache", "list", "--tile-cache-dir", str(root)]) == 0
    out = capsys.readouterr().out
    assert str(clip.resolve()) in out and "1 caches" in out
    assert footage_main(["cache", "clear", "--tile-cache-dir", str(root)]) == 0
    assert "removed 1 tile caches" in capsys.readouterr().out
    assert autocache.list_caches(root) == []
    assert footage_main(["cache", "list", "--tile-cache-dir", str(root)]) == 0
    assert "no automatic tile cache" in capsys.readouterr().out


def test_trials_run_hands_the_cache_flags_to_its_spawned_workers(tmp_path: Path) -> None:
    """`trials run --tile-cache-dir D` builds the footage's cache in D from inside the trial's (spawned) worker;
    `--no-cache` builds none and the trial still flies over the video; this process's policy is restored after."""
    import json

    from viva_sitl.evaluation.cli import trials_main

    clip = _clip(tmp_path / "clip", "trialclip", frames=6)
    spec = tmp_path / "spec.toml"
    spec.write_text(
        '[trials]\nname = "cached"\nn = 1\nseed = 2\ntimeout_s = 30.0\n[scenario]\n'
        f'footage = "{clip}"\nstart = "air"\nnorth_m = [-5.0, 5.0]\neast_m = [-5.0, 5.0]\naltitude_m = [6.0, 8.0]\n'
        "land_at_s = 0.5\n",
        encoding="utf-8",
    )
    mine = _policy(
        tmp_path / "mine"
    )  # min_pixels=1: handed to the workers, so the small clip counts as heavy
    with autocache.using_policy(mine):
        for flags, root in (
            ([], tmp_path / "flagged"), (["--no-cache"], tmp_path / "off"), (["--cache-compact"], tmp_path / "small")
        ):  # fmt: skip
            out = tmp_path / f"out-{root.name}"
            argv = ["run", str(spec), "--pilot", "descend", "--jobs", "1", "-o", str(out), "--no-progress"]
            assert trials_main([*argv, "--tile-cache-dir", str(root), *flags]) == 0
            (row,) = json.loads((out / "results.json").read_text())["rows"]
            assert row["end"] == "landed", row
            built = autocache.list_caches(root) if root.exists() else []
            assert [(e.source, e.codec) for e in built] == (
                [] if flags == ["--no-cache"] else [(str(clip.resolve()), "yuv420zg" if flags else "yuv420z")]
            )
        assert autocache.policy() == mine
    assert not (tmp_path / "mine").exists()
    assert autocache.policy_cli_args(mine) == ["--tile-cache-dir", str(tmp_path / "mine")]
    assert autocache.policy_cli_args(autocache.from_flags(True, 32.0, None, mine)) == ["--no-cache"]
    compact = autocache.from_flags(False, 32.0, None, mine, compact=True)
    assert compact.codec == "yuv420zg" and autocache.policy_cli_args(compact)[-1] == "--cache-compact"
    assert autocache.from_flags(False, 2.0, None, mine).max_bytes == 2 << 30


def test_a_spawned_trial_worker_opens_footage_under_the_policy_it_is_handed(tmp_path: Path) -> None:
    """The worker process (spawn: none of the parent's state) builds the cache where the handed policy says; the
    parent here opens nothing under a cache (its scenarios are drawn with the cache off)."""
    import multiprocessing as mp

    from viva_sitl.evaluation import campaign
    from viva_sitl.evaluation.spec import draw_scenarios, load_spec

    clip = _clip(tmp_path / "clip", "workerclip", frames=6)
    spec_path = tmp_path / "spec.toml"
    spec_path.write_text(
        '[trials]\nname = "w"\nn = 1\nseed = 2\ntimeout_s = 30.0\n[scenario]\n'
        f'footage = "{clip}"\nstart = "air"\nnorth_m = [-5.0, 5.0]\neast_m = [-5.0, 5.0]\naltitude_m = [6.0, 8.0]\n'
        "land_at_s = 0.5\n",
        encoding="utf-8",
    )
    spec = load_spec(spec_path)
    with autocache.using_policy(CachePolicy(enabled=False)):
        (scenario,) = draw_scenarios(spec)
    ctx = mp.get_context("spawn")
    results = ctx.Queue()
    parent, child = ctx.Pipe()
    root = tmp_path / "handed"
    p = ctx.Process(target=campaign._worker,
                    args=(0, child, results, spec, "descend", str(tmp_path / "out"), False, 1, _policy(root)))  # fmt: skip
    p.start()
    try:
        parent.send(scenario)
        _, index, row = results.get(timeout=120)
        parent.send(None)
        p.join(30)
    finally:
        if p.is_alive():
            p.kill()
    assert index == scenario.index and row["end"] == "landed", row
    assert [e.source for e in autocache.list_caches(root)] == [str(clip.resolve())]


@pytest.mark.slow
def test_trials_search_hands_the_cache_flags_to_its_pool_workers(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """`trials search --jobs 2` flies in a spawned pool whose workers open the (4K: heavy) footage under the
    search's policy, as `trials run`'s do: `--tile-cache-dir D` builds the cache in D and the workers read it there;
    `--no-cache` builds none; no worker falls back to the user cache directory (a worker without the policy builds
    its own cache there); this process's policy is restored after."""
    from viva_sitl.evaluation.cli import trials_main

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))  # spawned workers inherit it
    clip = _clip(tmp_path / "clip", "searchuhd", frames=2, w=3840, h=2160)
    spec = tmp_path / "spec.toml"
    spec.write_text(
        '[trials]\nname = "searched"\nn = 1\nseed = 2\ntimeout_s = 30.0\n[scenario]\n'
        f'footage = "{clip}"\nstart = "air"\nnorth_m = [-5.0, 5.0]\neast_m = [-5.0, 5.0]\naltitude_m = [6.0, 8.0]\n'
        "land_at_s = 0.5\n",
        encoding="utf-8",
    )
    mine = CachePolicy(root=tmp_path / "mine", show_progress=False)
    with autocache.using_policy(mine):
        for flags, root in (([], tmp_path / "flagged"), (["--no-cache"], tmp_path / "off")):
            out = tmp_path / f"out{len(flags)}"
            argv = ["search", str(spec), "--pilot", "descend", "--budget", "2", "--batch", "2", "--jobs", "2",
                    "--max-failures", "0", "-o", str(out)]  # fmt: skip
            assert trials_main([*argv, "--tile-cache-dir", str(root), *flags]) == 0
            rows = [t["result"] for t in json.loads((out / "search.json").read_text())["trials"]]
            assert len(rows) == 2 and all(r["end"] == "landed" for r in rows), rows
            built = autocache.list_caches(root) if root.exists() else []
            assert [e.source for e in built] == ([] if flags else [str(clip.resolve())])
            assert not (tmp_path / "xdg").exists()
        assert autocache.policy() == mine
    assert not (tmp_path / "mine").exists()


def _older_layout_then_today(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, target: object, attr: str, value: object
) -> tuple[dict[str, Any], dict[str, Any]]:
    """The automatic cache of a fresh clip built under an older layout (`target.attr` = `value`), then under today's:
    the two keys differ, today's cache is built anew beside the older one (both listed), and both give the same
    pixels (frame 1, levels 0 and 1). Returns what each held: bytes on disk, layout, meta.json."""
    clip = _clip(tmp_path, attr.lower())
    policy = _policy(tmp_path / "cache")
    now = autocache.content_key(clip, policy, (320, 240))
    monkeypatch.setattr(target, attr, value)
    old = autocache.content_key(clip, policy, (320, 240))
    assert old != now
    held: list[dict[str, Any]] = []
    for key in (old, now):
        with open_footage(str(clip.with_suffix(".toml")), cache=policy) as src:
            assert isinstance(src, TileSource) and src.cache.folder.name == key
            held.append({"pixels": [src.frame(1), src.frame(1, level=1)], "bytes": src.cache.disk_bytes,
                         "layout": src.cache.layout,
                         "meta": json.loads((src.cache.folder / "tiles" / "meta.json").read_text())})  # fmt: skip
        monkeypatch.undo()
    for a, b in zip(held[0]["pixels"], held[1]["pixels"], strict=True):
        assert np.array_equal(a, b)
    assert {e.folder.name for e in autocache.list_caches(policy.directory())} == {old, now}
    return held[0], held[1]


def test_a_cache_of_another_zstd_level_is_not_reused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The zstd level is part of the key: a cache built at level 3 (before level -1 decoded faster) is rebuilt,
    not kept (as a change of the levels stored as zstd); both decode to the same pixels (zstd is lossless)."""
    from viva_sitl.footage.tiles import format as tile_format

    level3, fast = _older_layout_then_today(tmp_path, monkeypatch, tile_format, "YUVZ_LEVEL", 3)
    assert fast["bytes"] != level3["bytes"]
    # the default codec's key text is the one its caches were built under (--cache-compact's codec added no word
    # to it, so no existing cache is rebuilt); the compact codec's differs
    assert autocache._codec_layout("yuv420z") == " zstd<=1@44dB zstd-level -1"
    assert (
        autocache._codec_layout("yuv420zg") == " zstd<=1@44dB zstd-level -1 gradient zstd-level 1 min-match 7"
    )


def test_the_automatic_cache_has_128_px_tiles_at_level_0_and_rebuilds_a_uniform_one(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A yuv420z automatic cache of footage up to 4K stores level 0 as 128 px tiles and the levels above as 256 px
    ones (format 3); above 4K (8K) level 0 keeps 256 px tiles (the same key and cache as before). The level-0 tile
    size is part of the key, so a cache built with 256 px tiles everywhere (before) is rebuilt beside it, not kept;
    both give the same pixels."""
    assert (
        autocache.level0_tile_px("yuv420z", (3840, 2160))
        == autocache.level0_tile_px("yuv420z", (4096, 2160))
        == 128
    )
    assert (
        autocache.level0_tile_px("yuv420z", (7680, 4320))
        == autocache.level0_tile_px("jpeg", (3840, 2160))
        == 256
    )
    uniform, mixed = _older_layout_then_today(tmp_path, monkeypatch, autocache, "AUTO_LEVEL0_TILE_PX", 256)
    u, m = uniform["layout"], mixed["layout"]
    assert isinstance(u, TileLayout) and isinstance(m, TileLayout)
    assert (u.tile_size(0), u.tile_size(1)) == (256, 256) and (m.tile_size(0), m.tile_size(1)) == (128, 256)
    assert uniform["meta"]["version"] == 2 and "tile_px_level0" not in uniform["meta"]
    assert mixed["meta"]["version"] == 3 and mixed["meta"]["tile_px_level0"] == 128
