"""Footage sources declare what they can do (`FootageSource.capabilities`), and the Simulator picks its render path
from that declaration, not from the source's type. Real generated H.264 clips, real decoders, no mocks."""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.typing import NDArray

from viva_sitl.camera import CameraParams
from viva_sitl.config import SimConfig
from viva_sitl.footage import (
    FootageCapabilities,
    FootageSource,
    RegionRead,
    SyntheticField,
    SyntheticFieldParams,
    VideoSource,
    open_footage,
)
from viva_sitl.footage.testclip import write_coded_clip
from viva_sitl.sim import Simulator

W, H = 640, 368
ALT_M, HFOV = 100.0, 82.1


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return write_coded_clip(
        tmp_path_factory.mktemp("caps") / "c.mp4", frames=4, width_px=W, height_px=H, fps=25
    )


class Delegate(FootageSource):
    """Not a VideoSource: a source of its own type that serves a video's frames and declares `caps`. With the
    video's capabilities it must be rendered exactly as the video is; with none, through whole frames only."""

    def __init__(self, video: VideoSource, caps: FootageCapabilities) -> None:
        self.video, self.caps = video, caps
        self.geometry, self.metadata = video.geometry, video.metadata
        self.region_reads = 0

    @property
    def capabilities(self) -> FootageCapabilities:
        return self.caps

    @property
    def fps(self) -> float:
        return self.video.fps

    @property
    def frame_count(self) -> int:
        return self.video.frame_count

    def frame(self, index: int) -> NDArray[np.uint8]:
        return self.video.frame(index)

    def frame_region(
        self, index: int, x0: int, y0: int, x1: int, y1: int, level: int = 0
    ) -> NDArray[np.uint8] | None:
        self.region_reads += 1
        return self.video.frame_region(index, x0, y0, x1, y1, level)

    def prefetch(self, index: int, level: int = 0, only_next: bool = False) -> None:
        self.video.prefetch(index, level, only_next)

    def close(self) -> None:
        self.video.close()


def _renders(sim: Simulator, poses: list[tuple[float, float, float, float]]) -> list[NDArray[np.uint8]]:
    out = []
    for k, (n, e, z, yaw) in enumerate(poses):
        sim.reset(seed=3, pos_ned_m=(n, e, z), yaw_rad=yaw)
        out.append(sim.render(dataclasses.replace(sim.state, time_s=k / 25.0)).image_bgr)  # frame k
    return out


POSES = [(0.0, 0.0, -40.0, 0.0), (5.0, -3.0, -60.0, 0.5), (-4.0, 6.0, -30.0, 1.2), (0.0, 0.0, -80.0, -0.7)]
CAMERA = CameraParams(width_px=160, height_px=120)


def _open(clip: Path) -> FootageSource:
    return open_footage(str(clip), altitude_m=ALT_M, hfov_deg=HFOV)


def test_each_source_declares_its_capabilities(clip: Path, tmp_path: Path) -> None:
    with _open(clip) as video:
        assert isinstance(video, VideoSource)
        assert video.capabilities == FootageCapabilities(RegionRead.CROP, reduced_copies=True, prefetch=True)
    edgeless = SyntheticField()
    assert edgeless.capabilities == FootageCapabilities(ground_view=True, per_view=True)
    bounded = SyntheticField(SyntheticFieldParams(unbounded=False))
    assert bounded.capabilities == FootageCapabilities(per_view=True)  # a finite field: whole frames
    from viva_sitl.footage.ingest import ingest_tiles

    toml = tmp_path / "c.toml"
    toml.write_text(f'path = "{clip}"\nrecording_altitude_m = {ALT_M}\nhfov_deg = {HFOV}\n')
    ingest_tiles(str(toml), out_dir=tmp_path / "t", codec="raw", show_progress=False)
    with open_footage(str(tmp_path / "t")) as tiled:
        assert tiled.capabilities == FootageCapabilities(region=RegionRead.TILES)
        from viva_sitl.footage.errors import FootageError

        with pytest.raises(FootageError, match="already a tile cache"):  # ingest asks the capabilities too
            ingest_tiles(str(tmp_path / "t"), out_dir=tmp_path / "t2", show_progress=False)


def test_a_source_without_abilities_has_safe_defaults(clip: Path) -> None:
    """The base class answers the optional calls harmlessly (or says which capability is missing)."""
    with _open(clip) as video:
        assert isinstance(video, VideoSource)
        plain = Delegate(video, FootageCapabilities())
        base: Any = FootageSource
        assert base.frame_region(plain, 0, 0, 0, 2, 2) is None
        assert base.level_count.fget(plain) == 1
        assert base.frame_size_px.fget(plain) == (W, H)
        assert base.level_size_px(plain, 0) == (W, H) and base.level_size_px(plain, 1) is None
        assert base.prefetch(plain, 1) is None
        with pytest.raises(NotImplementedError, match="capabilities.region"):
            base.region(plain, 0, 0, 0, 0, 2, 2)
        with pytest.raises(NotImplementedError, match="capabilities.ground_view"):
            base.ground_view(plain, 0, np.zeros(3), np.zeros((1, 3)), 0.1)


def test_the_simulator_asks_the_capabilities_not_the_type(clip: Path) -> None:
    """A source of an unknown type declaring the video's capabilities gets the region path and the prefetch thread
    (bit-identical to the video's own render); declaring none, it gets whole frames (the same image, no region
    reads, no thread)."""
    with Simulator(SimConfig(camera=CAMERA), footage=_open(clip), prefetch=True) as ref_sim:
        assert ref_sim._prefetcher is not None
        want = _renders(ref_sim, POSES)
        assert ref_sim.region_renders == len(POSES)
    video = _open(clip)
    assert isinstance(video, VideoSource)
    declared = Delegate(video, video.capabilities)
    with Simulator(SimConfig(camera=CAMERA), footage=declared, prefetch=True) as sim:
        assert sim._region is not None and sim._prefetcher is not None
        got = _renders(sim, POSES)
        assert sim.region_renders == len(POSES) and sim.full_renders == 0
        assert declared.region_reads >= 1
    for a, b in zip(want, got, strict=True):
        assert np.array_equal(a, b)
    plain = Delegate(_open(clip), FootageCapabilities())  # type: ignore[arg-type]
    with Simulator(SimConfig(camera=CAMERA), footage=plain, prefetch=True) as sim:
        assert sim._region is None and sim._prefetcher is None
        got = _renders(sim, POSES)
        assert sim.region_renders == 0 and sim.full_renders == len(POSES) and plain.region_reads == 0
    for a, b in zip(want, got, strict=True):
        assert np.array_equal(a, b)


def test_an_edgeless_ground_is_rendered_through_its_ground_view() -> None:
    """capabilities.ground_view (the unbounded synthetic field) routes renders through `ground_view`, far beyond
    the nominal frame; a bounded field renders whole frames."""
    with Simulator(SimConfig(camera=CAMERA), footage=SyntheticField()) as sim:
        sim.reset(seed=0, pos_ned_m=(3000.0, -2000.0, -50.0), yaw_rad=0.0)
        frame = sim.render()
        assert frame.meta.coverage == 1.0 and sim.full_renders == 1
        assert isinstance(sim.footage, SyntheticField) and sim.footage.windows_drawn >= 1
    bounded = SyntheticField(SyntheticFieldParams(unbounded=False))
    with Simulator(SimConfig(camera=CAMERA), footage=bounded) as sim:
        sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -50.0), yaw_rad=0.0)
        sim.render()
        assert bounded.windows_drawn == 0 and sim.full_renders == 1
