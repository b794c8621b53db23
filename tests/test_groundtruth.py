"""World model: loaders, track clock/interpolation/lost handling, queries vs brute force, risk map, synthetic actors,
`footage show` and `footage annotate` (motion) with its Ctrl-C safety."""

from __future__ import annotations

import json
import math
import os
import re
import signal
import subprocess
import sys
import threading
from fractions import Fraction
from pathlib import Path

import av
import cv2
import numpy as np
import pytest

from viva_sitl.cli_footage import footage_main
from viva_sitl.footage import FootageError, FootageGeometry, open_footage
from viva_sitl.footage.boxfiles import (
    BoxRow,
    TrackFormat,
    parse_coco,
    parse_motchallenge,
    parse_sdd,
    parse_visdrone,
    parse_viva,
    read_boxes,
    write_viva,
)
from viva_sitl.footage.synthetic import SyntheticField
from viva_sitl.footage.synthetic_actors import DEFAULT_ACTORS, actor_position_ne_m
from viva_sitl.footage.worldmeta import OBJECT_CLASS_LABELS
from viva_sitl.world import PEOPLE, VEHICLES, ObjectClass, TrackSource, build_tracks, load_world
from viva_sitl.world.annotate import motion_tracks
from viva_sitl.world.risk import RiskPolygon, read_polygons, risk_map_from_polygons

REPO = Path(__file__).resolve().parents[1]
SHARED = REPO.parent / "shared"
CONFIGS = REPO / "viva_sitl" / "data" / "footage"
needs_sdd = pytest.mark.skipif(
    not (SHARED / "footage" / "sdd").is_dir(), reason=f"{SHARED / 'footage' / 'sdd'} is absent"
)
GEOM = FootageGeometry(400, 300, 0.1, 50.0)  # 40 m x 30 m, north up


# --- loaders ----------------------------------------------------------------------------------------------------------
def test_sdd_parser_lost_and_occluded(tmp_path: Path) -> None:
    f = tmp_path / "annotations.txt"
    f.write_text(
        '3 10 20 30 60 0 0 0 0 "Pedestrian"\n3 12 20 32 60 1 1 0 1 "Pedestrian"\n4 0 0 40 20 0 0 1 0 "Biker"\n'
    )
    rows = parse_sdd(f)
    assert rows[0] == BoxRow(0, 3, "Pedestrian", 10, 20, 30, 60, False, False, None, False)
    assert rows[1].lost and not rows[1].occluded
    assert rows[2].occluded and not rows[2].lost and rows[2].label == "Biker"
    f.write_text("3 10 20 oops\n")
    with pytest.raises(FootageError, match=r"annotations.txt:1: expected"):
        parse_sdd(f)


def test_motchallenge_visdrone_coco_parsers(tmp_path: Path) -> None:
    mot = tmp_path / "gt.txt"
    mot.write_text(
        "1,7,10,20,4,8,1,1,1.0\n2,7,12,20,4,8,1,1,0.2\n1,8,0,0,5,5,0,1,1\n1,9,0,0,5,5,1,3,1\n1,10,0,0,5,5,1,9,1\n"
    )
    rows = parse_motchallenge(mot)
    assert [(r.frame, r.track_id, r.label, r.occluded) for r in rows] == [
        (0, 7, "pedestrian", False), (1, 7, "pedestrian", True), (0, 9, "car", False), (0, 10, "occluder", False)
    ]  # fmt: skip
    assert rows[0][3:7] == (10, 20, 14, 28)
    vd = tmp_path / "vd.txt"
    vd.write_text(
        "1,1,10,10,4,4,1,1,0,0\n1,2,10,10,4,4,0,4,0,0\n2,3,10,10,4,4,1,0,0,0\n3,4,1,1,2,2,1,5,0,2\n"
    )
    rows = parse_visdrone(vd)
    assert [(r.frame, r.track_id, r.label, r.occluded) for r in rows] == [
        (0, 1, "pedestrian", False),
        (2, 4, "van", True),
    ]
    coco = tmp_path / "c.json"
    coco.write_text(json.dumps({
        "images": [{"id": 5, "file_name": "f_000012.jpg"}, {"id": 6, "file_name": "f_000013.jpg"}],
        "categories": [{"id": 1, "name": "person"}, {"id": 3, "name": "car"}],
        "annotations": [{"image_id": 5, "bbox": [1, 2, 3, 4], "category_id": 1, "track_id": 4},
                        {"image_id": 6, "bbox": [2, 2, 3, 4], "category_id": 3}],
    }))  # fmt: skip
    rows = parse_coco(coco)
    assert [(r.frame, r.track_id, r.label) for r in rows] == [(12, 4, "person"), (13, None, "car")]
    assert rows[0][3:7] == (1, 2, 4, 6)
    mot.write_text("0,1,1,1,1,1\n")
    with pytest.raises(FootageError, match="1-based"):
        parse_motchallenge(mot)
    with pytest.raises(FootageError, match="not valid COCO"):
        (tmp_path / "bad.json").write_text("{")
        parse_coco(tmp_path / "bad.json")
    with pytest.raises(FootageError, match="tracks not found"):
        read_boxes(tmp_path / "nope.txt", TrackFormat.SDD)


def test_viva_roundtrip_is_atomic(tmp_path: Path) -> None:
    rows = [
        BoxRow(0, 1, "moving object", 1.5, 2.0, 3.0, 4.0, False, True, 0.5, True),
        BoxRow(3, None, "car", 0, 0, 1, 1),
    ]
    out = write_viva(tmp_path / "t.tracks.csv", rows, "a comment\nsecond line")
    assert parse_viva(out) == rows
    assert [p.name for p in tmp_path.iterdir()] == ["t.tracks.csv"]
    umask = os.umask(0)
    os.umask(umask)
    assert out.stat().st_mode & 0o777 == 0o666 & ~umask

    def boom():  # an interrupted writer leaves neither the file nor its temp file
        yield rows[0]
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        write_viva(tmp_path / "u.tracks.csv", boom())
    assert [p.name for p in tmp_path.iterdir()] == ["t.tracks.csv"]


def test_class_tables_agree() -> None:
    assert tuple(c.label for c in ObjectClass) == OBJECT_CLASS_LABELS


# --- tracks: clock, interpolation, lost -----------------------------------------------------------------------------
def _px_centre_to_ne(u: float, v: float) -> tuple[float, float]:
    return GEOM.px_to_ned(u, v)


def test_interpolation_lost_occluded_and_gap() -> None:
    rows = [
        BoxRow(0, 1, "Pedestrian", 100, 100, 110, 110),
        BoxRow(10, 1, "Pedestrian", 200, 100, 210, 110, occluded=True),
        BoxRow(20, 1, "Pedestrian", 300, 100, 310, 110, lost=True),
        BoxRow(30, 1, "Pedestrian", 300, 150, 310, 160),
        BoxRow(80, 1, "Pedestrian", 100, 150, 110, 160),  # gap 50 > max_gap 30: not interpolated
        BoxRow(5, 2, "Car", 0, 0, 40, 20),
        BoxRow(5, 3, "distractor", 0, 0, 4, 4),  # not an object
    ]
    tt = build_tracks([TrackSource("t", rows)], GEOM, fps=10.0, frame_count=100, max_gap_frames=30)
    assert len(tt.tracks) == 2 and {t.object_class for t in tt.tracks} == {
        ObjectClass.PERSON,
        ObjectClass.CAR,
    }
    person = next(t.index for t in tt.tracks if t.object_class is ObjectClass.PERSON)
    frames, ne = tt.track_path(person)
    assert list(frames) == list(range(0, 11)) + [30, 80]
    for k in range(11):  # linear between frames 0 and 10: u = 104.5 + 10 k
        assert tuple(ne[k]) == pytest.approx(_px_centre_to_ne(104.5 + 10 * k, 104.5), abs=1e-9)
    at = tt.objects_at(1.0)  # frame 10: present and occluded
    assert len(at) == 1 and bool(at.occluded[at.track == person][0])
    assert tt.objects_at(0.5).frame == 5 and len(tt.objects_at(0.5)) == 2
    assert len(tt.objects_at(2.0)) == 0  # frame 20: lost
    assert len(tt.objects_at(2.5)) == 0  # between a lost and a present row: not interpolated
    assert len(tt.objects_at(5.0)) == 0  # inside the too-long gap
    assert tt.objects_at(10.0 + 3.0).frame == 30  # the clock loops: 13 s = frame 130 -> 30
    assert len(tt.objects_at(13.0)) == 1


def test_clock_matches_the_camera() -> None:
    field = SyntheticField()
    world = load_world("synthetic", config_dir=CONFIGS)
    rng = np.random.default_rng(3)
    times = np.concatenate(
        [rng.uniform(-100, 500, 2000), np.arange(0, 70, 1 / 30.0), [1 / 30 * 7, 59.99999, 60.0]]
    )
    for t in times:
        assert world.tracks.frame_at(float(t)) == field.frame_index_at(float(t))


# --- queries vs brute force -----------------------------------------------------------------------------------------
def _random_rows(rng: np.random.Generator, n_tracks: int, frames: int) -> list[BoxRow]:
    labels = ["Pedestrian", "Biker", "Car", "Bus", "Cart", "Skater"]
    rows = []
    for tid in range(n_tracks):
        f0 = int(rng.integers(0, frames - 5))
        f1 = int(rng.integers(f0 + 1, frames))
        x, y = rng.uniform(0, 380), rng.uniform(0, 280)
        label = labels[tid % len(labels)]
        for f in range(f0, f1 + 1, int(rng.integers(1, 4))):
            x, y = x + rng.normal(0, 2), y + rng.normal(0, 2)
            rows.append(BoxRow(f, tid, label, x, y, x + 8, y + 8, lost=bool(rng.random() < 0.1)))
    return rows


def _brute(rows: list[BoxRow], frames: int) -> dict[int, dict[int, tuple[float, float, str]]]:
    """frame -> {track: (north, east, label)} with explicit loops (interpolation over present neighbours, gap <= 30)."""
    out: dict[int, dict[int, tuple[float, float, str]]] = {f: {} for f in range(frames)}
    by: dict[int, list[BoxRow]] = {}
    for r in rows:
        by.setdefault(r.track_id or 0, []).append(r)
    for tid, rs in by.items():
        rs.sort(key=lambda r: r.frame)
        for a, b in zip(rs, rs[1:] + [None], strict=True):
            if a.lost:
                continue
            ua, va = (a.x0_px + a.x1_px) / 2 - 0.5, (a.y0_px + a.y1_px) / 2 - 0.5
            out[a.frame][tid] = (*GEOM.px_to_ned(ua, va), a.label)
            if b is not None and not b.lost and 1 < b.frame - a.frame <= 30:
                ub, vb = (b.x0_px + b.x1_px) / 2 - 0.5, (b.y0_px + b.y1_px) / 2 - 0.5
                for f in range(a.frame + 1, b.frame):
                    w = (f - a.frame) / (b.frame - a.frame)
                    out[f][tid] = (*GEOM.px_to_ned(ua + w * (ub - ua), va + w * (vb - va)), a.label)
    return out


def test_queries_equal_brute_force() -> None:
    rng = np.random.default_rng(11)
    frames = 120
    rows = _random_rows(rng, 60, frames)
    tt = build_tracks([TrackSource("r", rows)], GEOM, fps=30.0, frame_count=frames)
    brute = _brute(rows, frames)
    people = {"Pedestrian", "Biker", "Skater"}
    for _ in range(400):
        t = float(rng.uniform(0, 2 * frames / 30.0))
        n, e = rng.uniform(-20, 20), rng.uniform(-25, 25)
        f = int(math.floor(t * 30.0 + 1e-9)) % frames
        present = brute[f]
        got = tt.objects_at(t)
        assert sorted(tt.tracks[int(k)].source_id for k in got.track) == sorted(present)
        for k, ne in zip(got.track, got.ne_m, strict=True):
            assert tuple(ne) == pytest.approx(present[tt.tracks[int(k)].source_id][:2], abs=1e-9)
        d_people = {tid: math.hypot(p[0] - n, p[1] - e) for tid, p in present.items() if p[2] in people}
        near = tt.nearest(n, e, t, PEOPLE)
        if d_people:
            assert near is not None and near.distance_m == pytest.approx(min(d_people.values()), abs=1e-9)
            assert tt.tracks[near.track].source_id in {
                k for k, v in d_people.items() if v <= near.distance_m + 1e-9
            }
        else:
            assert near is None
        r = float(rng.uniform(1, 15))
        inside = {
            tid for tid, p in present.items() if math.hypot(p[0] - n, p[1] - e) <= r and p[2] not in people
        }
        got_in = tt.within(n, e, r, t, VEHICLES)
        assert {tt.tracks[int(k)].source_id for k in got_in.track} == inside
    # batched distances equal one-by-one queries
    ts = rng.uniform(0, 8, 300)
    ns, es = rng.uniform(-20, 20, 300), rng.uniform(-25, 25, 300)
    batch = tt.distances_along(ns, es, ts, PEOPLE)
    single = [tt.distance_m(float(a), float(b), float(c), PEOPLE) for a, b, c in zip(ns, es, ts, strict=True)]
    assert np.array_equal(batch, np.array(single))


# --- synthetic field: drawn where ground truth says -----------------------------------------------------------------
@pytest.mark.parametrize("t_s", [0.0, 3.3, 17.0, 31.5, 59.9])
def test_synthetic_people_and_cars_drawn_at_ground_truth(t_s: float) -> None:
    field = SyntheticField()
    world = load_world("synthetic", config_dir=CONFIGS)
    idx = field.frame_index_at(t_s)
    img = field.frame(idx)
    objs = world.tracks.objects_at(t_s)
    assert len(objs) == len(DEFAULT_ACTORS)
    checked = 0
    for k, a in enumerate(DEFAULT_ACTORS):
        if not a.name.startswith(("walker", "car")):
            continue
        n, e = world.tracks.track_path(k)[1][idx]
        assert (n, e) == pytest.approx(actor_position_ne_m(a, field.time_of(idx)), abs=1e-12)
        u, v = field.geometry.ned_to_px(n, e)
        r = 40
        win = img[round(v) - r : round(v) + r, round(u) - r : round(u) + r].astype(int)
        b, g, rr = win[:, :, 0], win[:, :, 1], win[:, :, 2]
        if a.object_class == "car":
            mask = (rr > 200) & (g > 100) & (g < 180) & (b < 60)
        else:
            mask = (rr > 200) & (b > 200) & (g < 60)
        ys, xs = np.nonzero(mask)
        assert xs.size > 10, f"{a.name} not drawn near its ground truth"
        du, dv = xs.mean() + round(u) - r - u, ys.mean() + round(v) - r - v
        assert math.hypot(du, dv) < 1.0, f"{a.name}: drawn {du:.2f}, {dv:.2f} px off its ground truth"
        checked += 1
    assert checked == 7


def test_synthetic_risk_is_exact_by_construction() -> None:
    world = load_world("synthetic", config_dir=CONFIGS)
    assert world.has_risk_map and world.has_objects
    assert world.static_risk_at(0.0, 50.0) == 5  # ring road (46..54 m)
    assert world.static_risk_at(0.0, 45.5) == 1 and world.static_risk_at(0.0, 54.6) == 1
    assert world.static_risk_at(-25.0, -9.0) == 4  # plaza (7 m half side around N-25 E-15)
    assert world.static_risk_at(10.0, 10.0) == 1
    # a walker raises the level to 5 within 5 m (+ half its size), not beyond
    t = 12.0
    n, e = actor_position_ne_m(DEFAULT_ACTORS[0], t)
    assert world.risk_at(n + 5.2, e, t) == 5 and world.risk_at(n + 5.6, e, t) == 1
    near = world.tracks.nearest(n + 3.0, e, t, PEOPLE)
    assert near is not None and near.distance_m == pytest.approx(3.0, abs=1e-9)


# --- risk maps ------------------------------------------------------------------------------------------------------
def test_risk_at_on_known_polygons(tmp_path: Path) -> None:
    levels = {"lawn": 1, "road": 4, "busy_road": 5}
    f = tmp_path / "r.json"
    # footage 400 x 300 px at 0.1 m/px; a road band v in [100, 140) px, a lawn over its right part, a thick line
    f.write_text(json.dumps({"units": "px", "polygons": [
        {"class": "road", "points": [[0, 100], [400, 100], [400, 140], [0, 140]]},
        {"class": "lawn", "points": [[300, 0], [400, 0], [400, 300], [300, 300]]},
        {"class": "busy_road", "points": [[50, 250], [250, 250]], "width": 10},
    ]}))  # fmt: skip
    polys, units, _, _, size = read_polygons(f, levels)
    rm = risk_map_from_polygons(polys, GEOM, 2, units, image_size=size)
    at = lambda u, v: rm.level_at(*GEOM.px_to_ned(u, v))  # noqa: E731
    assert at(10, 120) == 4 and at(10, 98) == 2 and at(10, 141) == 2 and at(350, 120) == 1
    assert at(150, 250) == 5 and at(150, 243) == 2 and at(150, 256) == 2
    assert rm.level_at(1000.0, 0.0) == 2  # beyond the footage: default
    n = np.array([GEOM.px_to_ned(10, 120)[0], GEOM.px_to_ned(350, 120)[0]])
    e = np.array([GEOM.px_to_ned(10, 120)[1], GEOM.px_to_ned(350, 120)[1]])
    assert list(rm.levels_at(n, e)) == [4, 1]
    ned = risk_map_from_polygons(
        [RiskPolygon("road", 4, np.array([[0.0, 0], [0, 10], [-5, 10], [-5, 0]]))], GEOM, 1, "ned_m"
    )
    assert ned.level_at(-2.5, 5.0) == 4 and ned.level_at(1.0, 5.0) == 1 and ned.level_at(-2.5, 10.5) == 1
    f.write_text(
        json.dumps({"units": "px", "polygons": [{"class": "swamp", "points": [[0, 0], [1, 0], [1, 1]]}]})
    )
    with pytest.raises(FootageError, match="polygon #0 class 'swamp' has no risk level"):
        read_polygons(f, levels)


def test_risk_and_tracks_metadata_errors(tmp_path: Path) -> None:
    base = 'name = "x"\nkind = "still"\npath = "a.jpg"\ngsd_m_per_px = 0.1\nrecording_altitude_m = 50\n'
    cases = {
        "[risk]\ndefault_level = 7\n": "default_level must be a risk level 1..5",
        "[risk]\npolygon = 'a.json'\n": "unknown \\[risk\\] key",
        "[risk.objects]\nperson = { level = 5, buffer_m = -1 }\n": "buffer_m must be a number >= 0",
        "[risk.objects]\ndog = { level = 5 }\n": "dog: not an object class",
        "[tracks]\npath = 'a.txt'\nformat = 'kitti'\n": "format must be one of sdd",
        "[tracks]\npath = 'a.txt'\nformat = 'sdd'\nclass_map = { Cart = 'golfcart' }\n": "class must be one of",
    }
    for extra, msg in cases.items():
        (tmp_path / "x.toml").write_text(base + extra)
        with pytest.raises(FootageError, match=msg):
            open_footage(tmp_path / "x.toml")


def test_world_from_a_user_still_with_tracks_and_risk(tmp_path: Path) -> None:
    cv2.imwrite(str(tmp_path / "a.png"), np.full((300, 400, 3), 90, np.uint8))
    (tmp_path / "a.txt").write_text(
        "".join(f'1 {10 + f} 10 {20 + f} 20 {f} 0 0 0 "Pedestrian"\n' for f in range(0, 50, 5))
    )
    (tmp_path / "r.json").write_text(json.dumps({"units": "px", "polygons": [
        {"class": "lawn", "points": [[0, 0], [400, 0], [400, 300], [0, 300]]}]}))  # fmt: skip
    (tmp_path / "a.toml").write_text(
        'name = "a"\nkind = "still"\npath = "a.png"\ngsd_m_per_px = 0.1\nrecording_altitude_m = 50\n'
        '[tracks]\npath = "a.txt"\nformat = "sdd"\nfps = 10\n[risk]\npolygons = "r.json"\n'
        "[risk.objects]\nperson = { level = 4, buffer_m = 2.0 }\n"
    )
    world = load_world(tmp_path / "a.toml")
    assert world.tracks.frame_count == 46 and world.tracks.fps == 10.0
    objs = world.tracks.objects_at(0.7)  # frame 7: interpolated between frames 5 and 10
    assert len(objs) == 1
    assert tuple(objs.ne_m[0]) == pytest.approx(GEOM.px_to_ned(10 + 7 + 4.5, 14.5), abs=1e-9)
    n, e = objs.ne_m[0]
    assert world.risk_at(n, e + 2.4, 0.7) == 4 and world.risk_at(n, e + 2.6, 0.7) == 1


def test_annotated_classes_say_what_the_truth_can_answer(tmp_path: Path) -> None:
    """`annotated` tells "nobody of that class here" from "nobody looked": undeclared answers nothing (older
    metadata stays readable, conservatively), a declared class answers for itself, "object" needs people and
    vehicles (or "all"); a bad value is one line; every shipped footage declares it."""
    from viva_sitl.footage.metadata import load_config_dir

    cv2.imwrite(str(tmp_path / "a.png"), np.full((300, 400, 3), 90, np.uint8))
    (tmp_path / "a.txt").write_text('1 10 10 20 20 0 0 0 0 "Car"\n1 10 10 20 20 5 0 0 0 "Car"\n')
    base = 'name = "a"\nkind = "still"\npath = "a.png"\ngsd_m_per_px = 0.1\nrecording_altitude_m = 50\n'
    tracks = '[tracks]\npath = "a.txt"\nformat = "sdd"\nfps = 10\n'
    answers = {}
    for decl in (
        "",
        'annotated = ["vehicle"]\n',
        'annotated = ["Person", "vehicle"]\n',
        'annotated = ["all"]\n',
    ):
        (tmp_path / "a.toml").write_text(base + decl + tracks)
        w = load_world(tmp_path / "a.toml")
        assert w.has_objects
        answers[decl.split("=")[-1].strip()] = tuple(w.answers(g) for g in ("person", "vehicle", "object"))
    assert answers == {"": (False, False, False), '["vehicle"]': (False, True, False),
                       '["Person", "vehicle"]': (True, True, True), '["all"]': (True, True, True)}  # fmt: skip
    for bad, msg in (('annotated = ["dogs"]\n', "annotated: unknown class 'dogs'"),
                     ('annotated = "vehicle"\n', "annotated must be a list")):  # fmt: skip
        (tmp_path / "a.toml").write_text(base + bad + tracks)
        with pytest.raises(FootageError, match=msg):
            load_world(tmp_path / "a.toml")
    assert load_world("synthetic").answers("object")  # exact by construction
    shipped = {k: m for k, m in load_config_dir(CONFIGS).items() if not hasattr(m, "record_id")}
    assert shipped and all(getattr(m, "annotated", None) for m in shipped.values()), "declare `annotated`"
    assert shipped["interchange"].annotated == (
        "moving object",
    )  # motion only: no people or vehicles as such
    assert shipped["songdo-00003"].annotated == ("vehicle",)


@needs_sdd
@pytest.mark.parametrize(
    ("name", "frames", "pedestrians"), [("sdd-deathcircle-4", 452, 10), ("sdd-nexus-5", 1062, 16)]
)
def test_sdd_scenes_load_in_metres(name: str, frames: int, pedestrians: int) -> None:
    world = load_world(name, shared_dir=SHARED, config_dir=CONFIGS)
    assert world.tracks.frame_count == frames and world.tracks.fps == 30.0
    assert sum(t.label == "Pedestrian" for t in world.tracks.tracks) == pedestrians
    assert world.has_risk_map and world.risk_map.hand_made
    src_dir = SHARED / "footage" / "sdd" / ("deathCircle_video4" if "death" in name else "nexus_video5")
    rows = parse_sdd(src_dir / "annotations.txt")
    gsd = world.geometry.gsd_m_per_px
    for r in rows[:: max(1, len(rows) // 50)]:
        objs = world.tracks.objects_at(r.frame / 30.0)
        ids = [world.tracks.tracks[int(k)].source_id for k in objs.track]
        if r.lost:
            assert r.track_id not in ids
            continue
        k = ids.index(r.track_id)
        u, v = (r.x0_px + r.x1_px) / 2 - 0.5, (r.y0_px + r.y1_px) / 2 - 0.5
        assert tuple(objs.ne_m[k]) == pytest.approx(world.geometry.px_to_ned(u, v), abs=1e-6)
        assert objs.size_m[k, 0] == pytest.approx((r.x1_px - r.x0_px) * gsd)
        assert bool(objs.occluded[k]) == r.occluded


@pytest.mark.skipif(not (SHARED / "footage" / "songdo").is_dir(), reason="shared songdo stills are absent")
def test_songdo_world_has_vehicles_and_roads() -> None:
    world = load_world("songdo-00003", shared_dir=SHARED, config_dir=CONFIGS)
    objs = world.tracks.objects_at(123.0)  # a still: the same objects at every time
    assert len(objs) == len(world.tracks.objects_at(0.0)) > 50
    cars = [k for k in range(len(objs)) if objs.object_class[k] == ObjectClass.CAR]
    # most cars stand on the hand-made roads (levels >= 4)
    on_road = [world.static_risk_at(*objs.ne_m[k]) >= 4 for k in cars]
    assert sum(on_road) / len(on_road) > 0.8


# --- CLI: show and annotate -----------------------------------------------------------------------------------------
def test_footage_show_writes_an_overview(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "o.png"
    assert footage_main(["show", "synthetic", "--time", "12", "-o", str(out), "--max-size", "1024",
                         "--config-dir", str(CONFIGS)]) == 0  # fmt: skip
    assert "23 objects" in capsys.readouterr().out
    img = cv2.imread(str(out))
    assert img is not None and img.shape == (1024, 1024, 3)
    # walker-1 at t = 12 s is drawn and boxed where the ground truth says (scale 0.5)
    field = SyntheticField()
    u, v = field.geometry.ned_to_px(*actor_position_ne_m(DEFAULT_ACTORS[0], 12.0))
    x, y = round((u + 0.5) * 0.5 - 0.5), round((v + 0.5) * 0.5 - 0.5)
    win = img[y - 4 : y + 5, x - 4 : x + 5].astype(int)
    assert np.any((win[:, :, 2] > 200) & (win[:, :, 0] > 200) & (win[:, :, 1] < 80))
    # the ring road is tinted red (risk 5), the lawn green (risk 1)
    ru, rv = field.geometry.ned_to_px(0.0, 50.0)
    road = img[round(rv * 0.5), round(ru * 0.5)].astype(int)
    lu, lv = field.geometry.ned_to_px(0.0, 30.0)
    lawn = img[round(lv * 0.5), round(lu * 0.5)].astype(int)
    assert road[2] > road[1] and lawn[1] > lawn[2]
    assert (
        footage_main(["show", "synthetic", "-o", str(tmp_path / "o.txt"), "--config-dir", str(CONFIGS)]) == 2
    )


def _moving_boxes_clip(path: Path, frames: int = 120) -> list[list[tuple[float, float]]]:
    """A hovering-camera clip: textured still ground, two 12x12 px boxes moving in straight lines; their centres."""
    rng = np.random.default_rng(1)
    ground = cv2.GaussianBlur(rng.integers(60, 120, (240, 320, 3)).astype(np.uint8), (0, 0), 2)
    truth: list[list[tuple[float, float]]] = [[], []]
    with av.open(str(path), mode="w") as out:
        st = out.add_stream("libx264", rate=25)
        st.width, st.height, st.pix_fmt = 320, 240, "yuv420p"
        st.codec_context.time_base = Fraction(1, 25)
        st.options = {"preset": "ultrafast", "crf": "18"}
        for i in range(frames):
            img = ground.copy()
            for k, (x, y) in enumerate(((20 + 2 * i, 60), (280 - 1.5 * i, 180 - 0.5 * i))):
                cv2.rectangle(img, (round(x), round(y)), (round(x) + 11, round(y) + 11), (230, 230, 240), -1)
                truth[k].append(
                    (round(x) + 5.5, round(y) + 5.5)
                )  # pixel-centre coordinates of the box centre
            f = av.VideoFrame.from_ndarray(img, format="bgr24")
            f.pts = i
            for pkt in st.encode(f):
                out.mux(pkt)
        for pkt in st.encode(None):
            out.mux(pkt)
    (path.with_suffix(".toml")).write_text(
        'gsd_m_per_px = 0.2\nrecording_altitude_m = 50.0\nlicence = "test"\n'
    )
    return truth


def test_annotate_motion_finds_the_moving_boxes(tmp_path: Path) -> None:
    clip = tmp_path / "boxes.mp4"
    truth = _moving_boxes_clip(clip)
    assert footage_main(["annotate", str(clip), "--no-progress"]) == 0
    out = tmp_path / "boxes.tracks.csv"  # beside the clip's metadata
    rows = parse_viva(out)
    assert all(r.derived and r.label == "moving object" for r in rows)
    by: dict[int | None, list[BoxRow]] = {}
    for r in rows:
        by.setdefault(r.track_id, []).append(r)
    long = [rs for rs in by.values() if len(rs) > 60]
    assert len(long) == 2, f"expected the 2 boxes as 2 long tracks, got {[len(v) for v in by.values()]}"
    for rs in long:
        errs = []
        for r in rs:
            c = ((r.x0_px + r.x1_px) / 2 - 0.5, (r.y0_px + r.y1_px) / 2 - 0.5)
            errs.append(
                min(math.hypot(c[0] - t[0], c[1] - t[1]) for t in (truth[0][r.frame], truth[1][r.frame]))
            )
        assert float(np.median(errs)) < 2.0
    # the world model reads it back as derived moving objects
    world = load_world(clip)
    assert world.tracks.count_by_class().get("moving object", 0) >= 2
    assert all(t.derived for t in world.tracks.tracks)


def test_annotate_motion_sees_the_objects_from_the_first_frame_of_the_loop(tmp_path: Path) -> None:
    """The camera loops the clip, so frame 0 comes right after the last frame: the derivation must count the boxes
    there like anywhere else (it primed the background with frame 0 itself, cars included, and found 0-2 of ~65
    objects for the first ~0.5 s of every loop of the interchange clip)."""
    clip = tmp_path / "boxes.mp4"
    _moving_boxes_clip(clip, frames=60)
    with open_footage(clip) as src:
        rows = motion_tracks(src)
    per_frame = [sum(r.frame == f for r in rows) for f in range(60)]
    assert min(per_frame[:12]) == 2, per_frame  # both boxes from frame 0 on
    assert max(per_frame) == 2


def test_the_shipped_interchange_tracks_keep_their_count_across_the_loop_seam() -> None:
    """The committed interchange.tracks.csv (derived by `footage annotate interchange`): over the first 0.5 s after
    the loop seam the object count stays near the clip's typical count (it was 0-2 of a median 67)."""
    rows = parse_viva(CONFIGS / "interchange.tracks.csv")
    frames = max(r.frame for r in rows) + 1
    count = np.bincount([r.frame for r in rows if not r.lost], minlength=frames)
    typical = float(np.median(count))
    assert typical > 40
    head = count[: round(0.5 * 25)]  # 25 fps
    assert head.min() >= 0.6 * typical, (head.tolist(), typical)
    assert head[:3].min() >= 0.8 * typical, (head.tolist(), typical)  # the seam itself


def test_annotate_detector_without_ultralytics_is_one_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    try:
        import ultralytics  # noqa: F401

        pytest.skip("ultralytics is installed")
    except ImportError:
        pass
    clip = tmp_path / "boxes.mp4"
    _moving_boxes_clip(clip, frames=5)
    assert (
        footage_main(["annotate", str(clip), "--method", "detector", "--detector", "w.pt", "--no-progress"])
        == 2
    )
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "needs ultralytics" in err and "perception" in err


def test_annotate_ctrl_c_leaves_no_file(tmp_path: Path) -> None:
    out = tmp_path / "synthetic.tracks.csv"
    env = dict(os.environ, PYTHONPATH=str(REPO), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "viva_sitl", "footage", "annotate", "synthetic", "-o", str(out),
         "--config-dir", str(CONFIGS)],  # fmt: skip
        stderr=subprocess.PIPE, env=env, cwd=tmp_path,
    )  # fmt: skip
    assert proc.stderr is not None
    started = threading.Event()
    seen: list[bytes] = []

    def watch() -> None:  # the progress bar counts processed frames: wait until a few are done
        assert proc.stderr is not None
        buf = b""
        while chunk := proc.stderr.read1(4096):  # type: ignore[attr-defined]
            seen.append(chunk)
            buf += chunk
            # tqdm redraws every ~0.1 s, so the counts it shows depend on the machine's speed: any 3..1500
            counts = [int(m) for m in re.findall(rb"(\d+)/1800", buf[-4096:])]
            if any(3 <= c <= 1500 for c in counts):
                started.set()

    th = threading.Thread(target=watch, daemon=True)
    th.start()
    try:
        assert started.wait(120), f"annotate never progressed: {b''.join(seen)[-500:]!r}"
        proc.send_signal(signal.SIGINT)
        rc = proc.wait(60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    th.join(5)
    assert rc == 130, b"".join(seen)[-500:]
    assert b"interrupted; nothing was written" in b"".join(seen)
    assert list(tmp_path.iterdir()) == [], "a half-written or temp file was left behind"


def test_risk_at_equals_a_loop_over_objects() -> None:
    world = load_world("synthetic", config_dir=CONFIGS)
    rng = np.random.default_rng(5)
    for _ in range(300):
        t = float(rng.uniform(0, 120))
        n, e = float(rng.uniform(-60, 60)), float(rng.uniform(-60, 60))
        objs = world.tracks.objects_at(t)
        level = world.static_risk_at(n, e)
        for k in range(len(objs)):
            risk = world.object_risk[ObjectClass(int(objs.object_class[k]))]
            if math.dist(objs.ne_m[k], (n, e)) <= risk.buffer_m + 0.5 * max(objs.size_m[k]):
                level = max(level, risk.level)
        assert world.risk_at(n, e, t) == level
        assert int(world.risk_levels_at(np.array([n]), np.array([e]), t)[0]) == level


def test_bad_input_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    cv2.imwrite(str(tmp_path / "s.png"), np.full((100, 120, 3), 80, np.uint8))
    (tmp_path / "s.toml").write_text("gsd_m_per_px = 0.1\nrecording_altitude_m = 50.0\n")
    cases = [
        (["annotate", str(tmp_path / "s.png"), "--no-progress"], "motion needs a video"),
        (["annotate", str(tmp_path / "s.png"), "--method", "detector"], "needs --detector WEIGHTS"),
        (["show", "no-such-footage", "-o", str(tmp_path / "o.png")], "unknown footage 'no-such-footage'"),
        (
            ["show", "synthetic", "--time", "nan", "-o", str(tmp_path / "o.png")],
            "--time must be a finite number",
        ),
    ]
    for argv, msg in cases:
        assert footage_main([*argv, "--config-dir", str(CONFIGS)]) == 2
        err = capsys.readouterr().err.strip()
        assert msg in err and "\n" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["s.png", "s.toml"]


def test_existing_mot_annotations_become_interpolated_tracks(tmp_path: Path) -> None:
    from viva_sitl.footage.testclip import write_coded_clip

    clip = write_coded_clip(tmp_path / "c.mp4", 40, gop=10)  # 320x240 at 30 fps
    (tmp_path / "c.txt").write_text("1,5,100,100,10,10,1,1\n11,5,120,100,10,10,1,1\n3,6,10,10,4,4,1,0\n")
    (tmp_path / "c.toml").write_text(
        "gsd_m_per_px = 0.1\nrecording_altitude_m = 50.0\n"
        '[annotations]\npath = "c.txt"\nformat = "mot"\nclass_names = ["person", "car"]\n'
    )
    world = load_world(clip)
    assert world.tracks.frame_count == 40 and world.tracks.fps == pytest.approx(30.0)
    g = world.geometry
    objs = world.tracks.objects_at(
        5 / 30.0
    )  # frame 5: halfway between the MOT frames 1 and 11 (0-based 0, 10)
    assert len(objs) == 1 and ObjectClass(int(objs.object_class[0])) is ObjectClass.CAR
    assert tuple(objs.ne_m[0]) == pytest.approx(g.px_to_ned(114.5, 104.5), abs=1e-9)
    at2 = world.tracks.objects_at(2 / 30.0)
    assert sorted(ObjectClass(int(c)).label for c in at2.object_class) == ["car", "person"]
    assert len(world.tracks.objects_at(12 / 30.0)) == 0 and len(world.tracks.objects_at((40 + 2) / 30.0)) == 2


@pytest.mark.parametrize("name", ["interchange", "sdd-nexus-5"])
def test_a_tile_cache_keeps_the_footage_ground_truth(name: str, tmp_path: Path) -> None:
    """`footage ingest --tiles` carries [tracks], [risk] and the derived tracks into the cache's footage.toml, so
    trials flown over the cache are scored against the same objects and risk as over the footage itself."""
    from viva_sitl.footage.ingest import ingest_tiles

    if not (SHARED / "footage").is_dir():
        pytest.skip(f"{SHARED / 'footage'} is absent")
    src = load_world(name, shared_dir=SHARED, config_dir=CONFIGS)
    res = ingest_tiles(name, out_dir=tmp_path / "t", shared_dir=SHARED, config_dir=CONFIGS, max_frames=8,
                       show_progress=False)  # fmt: skip
    cache = load_world(str(res.folder), shared_dir=SHARED, config_dir=CONFIGS)
    assert cache.has_risk_map and src.has_risk_map and cache.has_objects == src.has_objects
    assert cache.annotated == src.annotated and src.annotated  # what was looked for travels with the truth
    assert cache.has_objects, "the shipped footage has objects: the comparison below must compare some"
    # the video's first 8 frames (the cache holds those); the still's tracks over two minutes
    times = np.arange(0.0, 8 / 25.0, 0.02) if name == "interchange" else np.arange(0.0, 120.0, 2.1)
    seen = 0
    for t in times:
        a, b = src.tracks.objects_at(float(t)), cache.tracks.objects_at(float(t))
        assert np.array_equal(a.ne_m, b.ne_m) and np.array_equal(a.object_class, b.object_class)
        seen += len(a)
    assert seen > 0
    rng = np.random.default_rng(1)
    half_n, half_e = src.geometry.ground_height_m / 2, src.geometry.ground_width_m / 2
    for n, e in rng.uniform(-1.0, 1.0, (300, 2)) * (half_n, half_e):
        assert src.risk_at(float(n), float(e), 0.1) == cache.risk_at(float(n), float(e), 0.1)
