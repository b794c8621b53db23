"""Footage: metadata, geometry from corners, timing, decode (sequential vs seek), stills, annotations, the synthetic
calibration field's ground truth, DJI SRT sidecars and clear errors for unusable footage."""

from __future__ import annotations

import math
import statistics
from pathlib import Path

import cv2
import numpy as np
import pytest

from viva_sitl.footage import (
    AnnotationFormat,
    CatalogSpec,
    FootageError,
    FootageKind,
    FootageMetadata,
    SyntheticField,
    VideoSource,
    open_footage,
    parse_srt,
    parse_srt_text,
)
from viva_sitl.footage.annotations import AnnotationStore, parse_mot
from viva_sitl.footage.geometry import FootageGeometry, corners_fit
from viva_sitl.footage.metadata import load_config_dir
from viva_sitl.footage.testclip import read_code, write_coded_clip

REPO = Path(__file__).resolve().parents[1]
SHARED = Path(__file__).resolve().parents[2] / "shared"
CONFIGS = REPO / "viva_sitl" / "data" / "footage"
needs_shared = pytest.mark.skipif(
    not (SHARED / "footage").is_dir(), reason=f"shared footage folder {SHARED / 'footage'} is absent"
)
INTERCHANGE_CORNERS = [
    (36.3034739, 49.9671879),
    (36.3063206, 49.9743221),
    (36.3125578, 49.9732927),
    (36.3097064, 49.9661625),
]


@pytest.fixture(scope="module")
def clip(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """95 frames at 30 fps, keyframe every 10 frames, B-frames; each frame carries its index as a bar code."""
    return write_coded_clip(tmp_path_factory.mktemp("clip") / "coded.mp4", 95, gop=10)


# --- metadata -------------------------------------------------------------------------------------------------------
def test_every_config_entry_parses() -> None:
    entries = load_config_dir(CONFIGS, shared_dir=SHARED)
    assert {
        "interchange",
        "songdo-00003",
        "songdo-00972",
        "songdo-03936",
        "synthetic",
        "viva-safeland",
    } <= set(entries)
    cat = entries["viva-safeland"]
    assert isinstance(cat, CatalogSpec) and cat.record_id == 13942934
    assert cat.record_url == "https://zenodo.org/api/records/13942934"
    for name, e in entries.items():
        if isinstance(e, FootageMetadata):
            assert e.licence, f"{name} has no licence"
            if e.kind is not FootageKind.SYNTHETIC:
                assert Path(e.path).is_absolute()
    songdo = entries["songdo-00972"]
    assert isinstance(songdo, FootageMetadata)
    assert "CC-BY-4.0" in songdo.attribution and "Fonod" in songdo.attribution
    assert songdo.annotations_format is AnnotationFormat.YOLO


@needs_shared
@pytest.mark.parametrize("name", ["interchange", "songdo-00003", "songdo-00972", "songdo-03936", "synthetic"])
def test_every_shared_entry_opens(name: str) -> None:
    with open_footage(name, shared_dir=SHARED, config_dir=CONFIGS) as src:
        img = src.frame(0)
        assert img.dtype == np.uint8 and img.shape == (src.geometry.height_px, src.geometry.width_px, 3)
        assert src.metadata.name == name


def test_unknown_name_lists_the_catalog() -> None:
    with pytest.raises(FootageError, match="unknown footage 'no-such-footage'.*interchange"):
        open_footage("no-such-footage", config_dir=CONFIGS, shared_dir=SHARED)


def test_remote_catalog_name_says_how_to_get_it(tmp_path: Path) -> None:
    with pytest.raises(FootageError, match="footage get viva-safeland"):
        open_footage("viva-safeland", config_dir=CONFIGS, cache_dir=tmp_path)
    with pytest.raises(FootageError, match="not downloaded.*footage get viva-safeland"):
        open_footage("viva-safeland/DJI_0001", config_dir=CONFIGS, cache_dir=tmp_path)


def test_bad_metadata_is_one_clear_error(tmp_path: Path) -> None:
    (tmp_path / "x.toml").write_text('name = "x"\nkind = "video"\npath = "a.mp4"\naltitud_m = 3\n')
    with pytest.raises(FootageError, match="unknown key.*altitud_m"):
        open_footage(tmp_path / "x.toml")
    (tmp_path / "y.toml").write_text('name = "y"\nkind = "movie"\npath = "a.mp4"\n')
    with pytest.raises(FootageError, match="kind must be"):
        open_footage(tmp_path / "y.toml")
    (tmp_path / "z.toml").write_text("name = \n")
    with pytest.raises(FootageError, match="not valid TOML"):
        open_footage(tmp_path / "z.toml")


# --- geometry from corners --------------------------------------------------------------------------------------------
def test_interchange_geometry_from_corners() -> None:
    gsd, heading, origin, residual = corners_fit(1920, 1080, INTERCHANGE_CORNERS)
    assert gsd == pytest.approx(0.43, abs=0.01)  # README: 820 m x 461 m, about 0.43 m/px
    assert residual < 1.0  # the corners are a 16:9 rectangle to within a metre
    # The corners' top edge (TL -> TR) runs NNE: footage right is NNE, footage up is 90 deg left of it (WNW).
    right_bearing = (heading + 90.0) % 360.0
    assert 5.0 < right_bearing < 30.0
    assert heading == pytest.approx(284.4, abs=0.5)
    g = FootageGeometry.from_corners(1920, 1080, INTERCHANGE_CORNERS, hfov_deg=82.1)
    assert g.recording_altitude_m == pytest.approx(g.ground_width_m / (2 * math.tan(math.radians(41.05))))
    assert g.recording_altitude_m == pytest.approx(470.1, abs=1.0)
    assert g.geo_origin is not None
    for (u, v), (lon, lat) in zip(
        [(-0.5, -0.5), (1919.5, -0.5), (1919.5, 1079.5), (-0.5, 1079.5)], INTERCHANGE_CORNERS, strict=True
    ):
        n, e = g.px_to_ned(u, v)
        n_true, e_true, _ = g.geo_origin.global_to_ned(lat, lon, 0.0)
        assert math.hypot(n - n_true, e - e_true) < 1.0


def test_corners_fit_recovers_a_known_similarity() -> None:
    truth = FootageGeometry(640, 360, 0.25, 100.0, heading_deg=33.0)
    from viva_sitl.geo import GeoOrigin

    home = GeoOrigin(19.43, -99.13, 2240.0)
    corners = []
    for u, v in [(-0.5, -0.5), (639.5, -0.5), (639.5, 359.5), (-0.5, 359.5)]:
        n, e = truth.px_to_ned(u, v)
        lat, lon, _ = home.ned_to_global(n, e, 0.0)
        corners.append((lon, lat))
    gsd, heading, origin, residual = corners_fit(640, 360, corners, 2240.0)
    assert gsd == pytest.approx(0.25, rel=1e-4)
    assert heading == pytest.approx(33.0, abs=1e-3)
    assert origin.global_to_ned(home.lat_deg, home.lon_deg, 2240.0)[:2] == pytest.approx((0.0, 0.0), abs=0.01)
    assert residual < 0.01


@needs_shared
def test_interchange_metadata_geometry() -> None:
    with open_footage("interchange", shared_dir=SHARED, config_dir=CONFIGS) as src:
        g = src.geometry
        assert (g.width_px, g.height_px) == (1920, 1080)
        assert g.gsd_m_per_px == pytest.approx(0.4264, abs=0.002)
        assert g.recording_hfov_deg == pytest.approx(82.1)
        assert g.heading_deg == pytest.approx(284.4, abs=0.5)
        assert g.geo_origin is not None and g.geo_origin.lat_deg == pytest.approx(49.9702, abs=1e-3)
        assert src.fps == 25.0 and src.frame_count == 177


# --- timing ------------------------------------------------------------------------------------------------------------
def test_frame_index_follows_fps_and_loops(clip: Path) -> None:
    with open_footage(clip, altitude_m=50.0, hfov_deg=80.0) as src:
        assert src.fps == 30.0 and src.frame_count == 95
        assert src.duration_s == pytest.approx(95 / 30)
        for k in range(0, 300, 7):
            assert (
                src.frame_index_at(k / 30.0) == k % 95
            )  # exactly on frame boundaries despite float rounding
        assert src.frame_index_at(0.0) == 0
        assert src.frame_index_at(1.0 / 30.0 - 1e-6) == 0
        assert src.frame_index_at(10.0) == 300 % 95
        assert src.frame_index_at(-1.0 / 30.0) == 94  # deterministic for negative times too
        assert [src.frame_index_at(t) for t in np.arange(0, 5, 0.01)] == [
            src.frame_index_at(t) for t in np.arange(0, 5, 0.01)
        ]
        with pytest.raises(ValueError):
            src.frame_index_at(float("nan"))
    with open_footage(
        clip, altitude_m=50.0, hfov_deg=80.0, fps=10.0
    ) as slow:  # metadata fps overrides the stream's
        assert slow.frame_index_at(1.0) == 10


def test_synthetic_timing_and_determinism() -> None:
    a, b = SyntheticField(), SyntheticField()
    assert a.fps == 30.0 and a.frame_count == 1800
    assert a.frame_index_at(61.0) == 30
    assert np.array_equal(a.frame(123), b.frame(123))
    assert np.array_equal(a.frame(5), a.frame(5 + 1800))  # loops
    assert not np.array_equal(a.frame(5), a.frame(6))  # the markers move
    assert not a.frame(5).flags.writeable


# --- decoding ------------------------------------------------------------------------------------------------------------
def test_sequential_and_seek_decode_agree_exactly(clip: Path) -> None:
    with open_footage(clip, altitude_m=50.0, hfov_deg=80.0) as seq:
        assert isinstance(seq, VideoSource)
        frames = [seq.frame(i).copy() for i in range(seq.frame_count)]
        assert seq.decoder_stats["seeks"] == 1  # one open, then the sequential fast path only
    assert [read_code(f) for f in frames] == list(range(95))
    with open_footage(clip, altitude_m=50.0, hfov_deg=80.0) as rnd:
        assert isinstance(rnd, VideoSource)
        order = [57, 3, 94, 12, 11, 60, 0, 95 + 7, 33, 70, 69, 25]
        for i in order:
            img = rnd.frame(i)
            assert np.array_equal(img, frames[i % 95]), (
                f"frame {i}: seek decode differs from sequential decode"
            )
        assert rnd.decoder_stats["seeks"] > 3
        assert rnd.frame(25) is rnd.frame(25)  # the last frame is cached


@needs_shared
def test_shared_clip_seek_matches_sequential() -> None:
    with open_footage("interchange", shared_dir=SHARED, config_dir=CONFIGS) as seq:
        wanted: dict[int, np.ndarray] = {}
        for i in range(42):
            img = seq.frame(i)
            if i in (3, 40, 41):
                wanted[i] = img.copy()
    with open_footage("interchange", shared_dir=SHARED, config_dir=CONFIGS) as rnd:
        for i in (41, 3, 40):
            assert np.array_equal(rnd.frame(i), wanted[i])


# --- stills and annotations ------------------------------------------------------------------------------------------
@needs_shared
def test_songdo_still_and_annotations_in_metres() -> None:
    with open_footage("songdo-00003", shared_dir=SHARED, config_dir=CONFIGS) as src:
        assert src.frame_count == 1
        assert src.frame_index_at(123.4) == 0
        img = src.frame(0)
        assert img.shape == (2160, 3840, 3)
        assert src.frame(7) is img
        ann = src.annotations(0)
        assert len(ann) == 69
        cars = [a for a in ann if a.class_id == 0]
        long_m = statistics.median(max(a.size_m) for a in cars)
        short_m = statistics.median(min(a.size_m) for a in cars)
        assert 3.5 < long_m < 6.0 and 1.5 < short_m < 2.6  # cars are a few metres long
        g = src.geometry
        for a in ann:
            assert g.contains_ned(*a.center_ned_m, margin_m=-1.0)
            u, v = g.ned_to_px(*a.center_ned_m)
            assert (u, v) == pytest.approx(a.center_px, abs=1e-6)
            assert a.label in ("vehicle", "bus", "truck", "motorcycle")


def test_still_from_a_generated_image_and_yolo(tmp_path: Path) -> None:
    img = np.zeros((200, 400, 3), np.uint8)
    img[90:110, 190:230] = (0, 0, 255)
    cv2.imwrite(str(tmp_path / "s.png"), img)
    (tmp_path / "s.txt").write_text("0 0.525 0.5 0.1 0.1\n")
    (tmp_path / "s.png.toml").write_text(
        'gsd_m_per_px = 0.5\nrecording_altitude_m = 80.0\n[annotations]\npath = "s.txt"\nclass_names = ["red"]\n'
    )
    with open_footage(tmp_path / "s.png") as src:
        assert src.metadata.kind is FootageKind.STILL
        assert np.array_equal(src.frame(0), img)
        (a,) = src.annotations(0)
        assert a.label == "red" and a.box_px == pytest.approx((190.0, 90.0, 230.0, 110.0))
        assert a.size_m == pytest.approx((20.0, 10.0))
        # centre pixel (209.5, 99.5): 10 px right of the image centre (199.5, 99.5) -> 5 m east
        assert a.center_ned_m == pytest.approx((0.0, 5.0))


def test_yolo_per_frame_folder_and_mot_tracks(tmp_path: Path, clip: Path) -> None:
    g = FootageGeometry(320, 240, 0.2, 50.0)
    folder = tmp_path / "yolo"
    folder.mkdir()
    (folder / "frame_000004.txt").write_text("2 0.5 0.5 0.25 0.25\n")
    store = AnnotationStore(str(folder), AnnotationFormat.YOLO, g, ("a", "b", "c"))
    assert store.get(3) == []
    (a,) = store.get(4)
    assert (
        a.label == "c"
        and a.size_m == pytest.approx((16.0, 12.0))
        and a.center_ned_m == pytest.approx((0.0, 0.0))
    )
    mot = tmp_path / "gt.txt"
    mot.write_text("1,7,150,110,20,20,1,0,1\n2,7,160,110,20,20,1,0,1\n2,8,0,0,10,10,1,1,1\n")
    tracks = parse_mot(mot, g, ("car", "bus"))
    assert sorted(tracks) == [0, 1] and len(tracks[1]) == 2
    first, second = tracks[0][0], tracks[1][0]
    assert first.track_id == second.track_id == 7
    # 10 px to the right in one frame = 2 m east at 0.2 m/px
    assert second.center_ned_m[1] - first.center_ned_m[1] == pytest.approx(2.0)
    assert tracks[1][1].label == "bus"
    (tmp_path / "coded.mp4").symlink_to(clip)
    (tmp_path / "coded.toml").write_text(
        'recording_altitude_m = 50.0\nhfov_deg = 80.0\n[annotations]\npath = "gt.txt"\nformat = "mot"\n'
    )
    with open_footage(tmp_path / "coded.mp4") as src:
        assert [x.track_id for x in src.annotations(1)] == [7, 8]
        assert [x.track_id for x in src.annotations(95)] == [7]  # frame 95 loops to 0
    bad = tmp_path / "bad.txt"
    bad.write_text("0 0.5 zero 0.1 0.1\n")
    with pytest.raises(FootageError, match="bad.txt:1"):
        AnnotationStore(str(bad), AnnotationFormat.YOLO, g).get(0)


# --- the synthetic calibration field ---------------------------------------------------------------------------------
MARKER_MASKS = {
    "red-disc": lambda f: (f[:, :, 2] > 200) & (f[:, :, 1] < 60) & (f[:, :, 0] < 60),
    "blue-box": lambda f: (f[:, :, 0] > 200) & (f[:, :, 1] < 60) & (f[:, :, 2] < 60),
    "green-disc": lambda f: (f[:, :, 1] > 200) & (f[:, :, 0] < 60) & (f[:, :, 2] < 60),
    "landing-pad": lambda f: (f[:, :, 1] > 200) & (f[:, :, 2] > 200) & (f[:, :, 0] < 60),
}


@pytest.mark.parametrize("index", [0, 1, 137, 450, 899, 1799])
def test_synthetic_markers_are_drawn_where_the_ground_truth_says(index: int) -> None:
    field = SyntheticField()
    img = field.frame(index)
    truth = {a.label: a for a in field.annotations(index)}
    assert set(truth) == set(MARKER_MASKS)
    for label, mask_of in MARKER_MASKS.items():
        ys, xs = np.nonzero(mask_of(img))
        assert xs.size > 100, f"{label} not visible"
        u, v = truth[label].center_px
        assert math.hypot(xs.mean() - u, ys.mean() - v) < 1.0, (
            f"{label}: drawn at ({xs.mean()}, {ys.mean()}), truth ({u}, {v})"
        )
        # metres: the ground truth equals the analytic trajectory at t = index / fps
        spec = next(m for m in field.markers if m.name == label)
        assert truth[label].center_ned_m == pytest.approx(spec.position_ne_m(index / 30.0), abs=1e-9)
        assert truth[label].size_m == pytest.approx((spec.size_m, spec.size_m))


def test_synthetic_trajectories_are_analytic() -> None:
    field = SyntheticField()
    red = next(m for m in field.markers if m.name == "red-disc")
    for t in (0.0, 7.5, 15.0, 33.3):
        n, e = red.position_ne_m(t)
        assert math.hypot(n, e) == pytest.approx(40.0)
        vn, ve = red.velocity_ne_m_s(t)
        assert math.hypot(vn, ve) == pytest.approx(2 * math.pi * 40.0 / 60.0)
    assert red.position_ne_m(15.0) == pytest.approx(
        (0.0, 40.0), abs=1e-9
    )  # clockwise from north, seen from above
    blue = next(m for m in field.markers if m.name == "blue-box")
    assert blue.position_ne_m(0.0) == pytest.approx((-70.0, -60.0))
    assert blue.position_ne_m(15.0) == pytest.approx((-70.0, 60.0))
    assert blue.position_ne_m(7.5) == pytest.approx((-70.0, 0.0))


def test_synthetic_field_is_labelled_and_metric() -> None:
    field = SyntheticField()
    assert "SYNTHETIC CALIBRATION FIELD" in field.metadata.title
    bg = field.background
    g = field.geometry
    # the major grid lines (every 50 m) are bright lines across the whole picture
    u50, _ = g.ned_to_px(0.0, 50.0)
    column = bg[:, round(u50)].astype(int).sum(axis=1)
    assert np.mean(column > 600) > 0.9
    u55, _ = g.ned_to_px(0.0, 55.0)  # between grid lines: ground
    assert np.mean(bg[:, round(u55)].astype(int).sum(axis=1) > 600) < 0.2
    # the label banner: a black box with white text near the top
    top = bg[: int(0.08 * g.height_px)]
    assert (top.sum(axis=2) == 0).sum() > 10_000 and (top.min(axis=2) > 250).sum() > 1_000


def test_synthetic_config_overrides(tmp_path: Path) -> None:
    (tmp_path / "synthetic.toml").write_text(
        'name = "synthetic"\nkind = "synthetic"\n[synthetic]\nwidth_px = 512\nheight_px = 256\ngsd_m_per_px = 0.5\n'
    )
    with open_footage(None, config_dir=tmp_path) as src:
        assert src.frame(0).shape == (256, 512, 3) and src.geometry.gsd_m_per_px == 0.5
    (tmp_path / "synthetic.toml").write_text(
        'name = "synthetic"\nkind = "synthetic"\n[synthetic]\nfps = 7.0\nloop_s = 0.1\n'
    )
    with pytest.raises(FootageError, match="whole number of frames"):
        open_footage("synthetic", config_dir=tmp_path)


# --- DJI SRT ------------------------------------------------------------------------------------------------------------
SRT_MINI4 = """1
00:00:00,000 --> 00:00:00,033
<font size="28">FrameCnt: 1, DiffTime: 33ms
2024-05-14 10:21:34.123
[iso: 100] [shutter: 1/1000.0] [fnum: 1.7] [ev: 0] [color_md: default] [focal_len: 24.00] [latitude: 19.432608] [longitude: -99.133209] [rel_alt: 87.300 abs_alt: 2327.512] [ct: 5500] </font>

2
00:00:00,033 --> 00:00:00,066
<font size="28">FrameCnt: 2, DiffTime: 33ms
2024-05-14 10:21:34.156
[iso: 100] [latitude: 19.432610] [longitude: -99.133211] [rel_alt: 87.400 abs_alt: 2327.612] </font>

3
00:00:00,066 --> 00:00:00,100
<font size="28">FrameCnt: 3, DiffTime: 34ms
[iso: 100] [latitude: 19.432612] [longitude: -99.133213] [rel_alt: 87.500 abs_alt: 2327.712] </font>
"""

SRT_OLD = """1
00:00:01,000 --> 00:00:02,000
HOME(-99.1332,19.4326) 2019.05.14 10:21:34
GPS(-99.1333,19.4327,18) BAROMETER:52.3
ISO:100 Shutter:1000 EV:0 F-NUM:2.8 H 52.3m
"""


def test_srt_parsing() -> None:
    track = parse_srt_text(SRT_MINI4)
    assert len(track.samples) == 3
    s0 = track.samples[0]
    assert (s0.index, s0.start_s, s0.end_s) == (1, 0.0, pytest.approx(0.033))
    assert s0.rel_alt_m == 87.3 and s0.abs_alt_m == 2327.512
    assert (s0.lat_deg, s0.lon_deg) == (19.432608, -99.133209)
    assert track.rel_alt_m == pytest.approx(87.4) and track.first_rel_alt_m == 87.3
    assert track.lat_lon_deg == pytest.approx((19.432610, -99.133211))
    old = parse_srt_text(SRT_OLD)
    assert old.samples[0].rel_alt_m == 52.3
    assert old.lat_lon_deg == pytest.approx((19.4327, -99.1333))
    assert parse_srt_text("not a subtitle file").samples == ()


def test_srt_sidecar_gives_altitude_and_home(
    tmp_path: Path, clip: Path, caplog: pytest.LogCaptureFixture
) -> None:
    video = tmp_path / "DJI_0042.MP4"
    video.write_bytes(clip.read_bytes())
    with (
        caplog.at_level("WARNING"),
        open_footage(video) as src,
    ):  # no metadata, no sidecar: the paper's defaults
        assert src.geometry.recording_altitude_m == 100.0
        assert src.geometry.recording_hfov_deg == pytest.approx(82.1)
    warnings = [r for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1 and "--footage-alt" in warnings[0].getMessage()
    (tmp_path / "DJI_0042.SRT").write_text(SRT_MINI4)
    with open_footage(video, hfov_deg=82.1) as src:
        assert src.geometry.recording_altitude_m == pytest.approx(87.4)
        assert src.geometry.recording_hfov_deg == pytest.approx(82.1)
        origin = src.geometry.geo_origin
        assert origin is not None and origin.lat_deg == pytest.approx(19.43261)
    with open_footage(video, hfov_deg=82.1, altitude_m=100.0) as src:  # explicit beats the sidecar
        assert src.geometry.recording_altitude_m == 100.0
    assert parse_srt(tmp_path / "DJI_0042.SRT").rel_alt_m == pytest.approx(87.4)
    with pytest.raises(FootageError, match="no SRT subtitle blocks"):
        (tmp_path / "empty.SRT").write_text("nothing here")
        parse_srt(tmp_path / "empty.SRT")


# --- unusable footage ---------------------------------------------------------------------------------------------------
def test_unreadable_footage_is_a_footage_error(tmp_path: Path) -> None:
    fake = tmp_path / "fake.mp4"
    fake.write_text("this is not a video\n")
    with pytest.raises(FootageError, match="cannot open video .*fake.mp4"):
        open_footage(fake, altitude_m=50.0, hfov_deg=80.0)
    with pytest.raises(FootageError, match="footage not found: .*missing.mp4"):
        open_footage(tmp_path / "missing.mp4", altitude_m=50.0, hfov_deg=80.0)
    with pytest.raises(FootageError, match="footage not found"):
        open_footage(str(tmp_path / "missing.jpg"))
    img = tmp_path / "fake.jpg"
    img.write_text("not an image")
    with pytest.raises(FootageError, match="cannot read image"):
        open_footage(img, gsd_m_per_px=0.1, altitude_m=50.0)
    with pytest.raises(FootageError, match="without footage.toml"):
        open_footage(tmp_path)
    truncated = tmp_path / "truncated.mp4"  # an interrupted copy: the mp4 index (moov) is missing
    data = write_coded_clip(tmp_path / "whole.mp4", 20).read_bytes()
    truncated.write_bytes(data[: len(data) // 2])
    with pytest.raises(FootageError, match="truncated.mp4"):
        open_footage(truncated, altitude_m=50.0, hfov_deg=80.0)
    assert issubclass(FootageError, ValueError)


def test_closed_source_refuses_frames(clip: Path) -> None:
    src = open_footage(clip, altitude_m=50.0, hfov_deg=80.0)
    src.frame(0)
    src.close()
    src.close()  # idempotent
    with pytest.raises(FootageError, match="closed"):
        src.frame(1)


def test_frames_from_two_threads_are_serialised_not_corrupted(clip: Path) -> None:
    import threading

    errors: list[str] = []
    with open_footage(clip, altitude_m=50.0, hfov_deg=80.0) as src:

        def worker(indices: list[int]) -> None:
            for i in indices:
                code = read_code(src.frame(i))
                if code != i % 95:
                    errors.append(f"asked {i}, got {code}")

        threads = [
            threading.Thread(target=worker, args=(list(range(0, 95, 3)),)),
            threading.Thread(target=worker, args=(list(range(94, 0, -7)),)),
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert errors == []
