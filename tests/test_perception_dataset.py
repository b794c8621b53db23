"""Dataset export: boxes land on the synthetic field's people and cars to the pixel, masks align, splits, CLI."""

from __future__ import annotations

import dataclasses
import json
import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from viva_sitl.camera import CameraParams, ground_footprint, ground_to_image_homography, pixel_to_ground
from viva_sitl.dynamics import EavState
from viva_sitl.footage import open_footage
from viva_sitl.footage.synthetic_actors import (
    CAR_BGR,
    DEFAULT_ACTORS,
    PERSON_BGR,
    ROAD_BGR,
    actor_position_ne_m,
)
from viva_sitl.perception import PerceptionError
from viva_sitl.perception.dataset import (
    ExportSpec,
    PoseRanges,
    export_dataset,
    ground_rectangles,
    project_boxes,
    risk_mask,
)
from viva_sitl.sim import Simulator
from viva_sitl.world import ObjectClass, world_from_source

REPO = Path(__file__).resolve().parents[1]
PARAMS = CameraParams()


def _render(sim: Simulator, pos: np.ndarray, att: np.ndarray, t: float) -> np.ndarray:
    s = EavState.at_rest(pos, yaw_rad=att[2], roll_rad=att[0], pitch_rad=att[1])
    return sim.render(dataclasses.replace(s, time_s=t), wall_time_s=0.0).image_bgr


def _colour_pixels(
    img: np.ndarray, bgr: tuple[int, int, int], near: tuple[float, float, float, float]
) -> tuple:
    """(extent (x0, y0, x1, y1) in pixel edges, weighted centroid) of the pixels of colour `bgr` near box `near`."""
    diff = np.abs(img.astype(int) - np.array(bgr)).max(axis=2)
    ys, xs = np.nonzero(diff < 60)  # mostly covered by the object (its anti-aliased rim excluded)
    x0, y0, x1, y1 = near
    keep = (xs >= x0 - 6) & (xs < x1 + 6) & (ys >= y0 - 6) & (ys < y1 + 6)
    xs, ys = xs[keep], ys[keep]
    assert xs.size > 10, "the object is not in the image"
    return (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1), (xs.mean() + 0.5, ys.mean() + 0.5)


@pytest.mark.parametrize(("actor", "yaw_deg", "tilt"), [("walker-1", 30.0, 0.0), ("car-1", -70.0, 0.12)])
def test_box_lands_on_the_object_to_the_pixel(actor: str, yaw_deg: float, tilt: float) -> None:
    a = next(x for x in DEFAULT_ACTORS if x.name == actor)
    t = 7.3
    n, e = actor_position_ne_m(a, t)
    pos = np.array([n + 1.3, e - 0.8, -14.0])
    att = np.array([tilt, -tilt / 2, math.radians(yaw_deg)])
    src = open_footage("synthetic")
    world = world_from_source(src)
    with Simulator(footage=src, camera=PARAMS) as sim:
        img = _render(sim, pos, att, t)
    boxes = project_boxes(
        ground_rectangles(world, t), ground_to_image_homography(pos, att, PARAMS), PARAMS, 0.5
    )
    want_cls = ObjectClass.CAR if a.object_class == "car" else ObjectClass.PERSON
    centre = (PARAMS.width_px / 2, PARAMS.height_px / 2)
    box = min(
        (b for b in boxes if b.object_class == want_cls),
        key=lambda b: math.hypot((b.x0 + b.x1) / 2 - centre[0], (b.y0 + b.y1) / 2 - centre[1]),
    )
    colour = CAR_BGR if a.object_class == "car" else PERSON_BGR
    extent, centroid = _colour_pixels(img, colour, (box.x0, box.y0, box.x1, box.y1))
    # the box centre is the drawn object's centroid to half a pixel; its edges are the object's outermost pixels
    # within 2 px (the field paints with OpenCV's anti-aliased fill, about one source pixel fatter than the shape)
    np.testing.assert_allclose(((box.x0 + box.x1) / 2, (box.y0 + box.y1) / 2), centroid, atol=0.5)
    np.testing.assert_allclose((box.x0, box.y0, box.x1, box.y1), extent, atol=2.0)
    assert (box.x1 - box.x0) > 0.8 * (extent[2] - extent[0]) and (box.y1 - box.y0) > 0.8 * (
        extent[3] - extent[1]
    )
    assert box.visible == pytest.approx(1.0)


def test_mask_aligns_with_the_painted_ground() -> None:
    src = open_footage("synthetic")
    world = world_from_source(src)
    pos = np.array([0.0, 50.0, -25.0])  # over the east side of the ring road
    att = np.array([0.05, 0.02, 0.6])
    t = 3.0
    with Simulator(footage=src, camera=PARAMS) as sim:
        img = _render(sim, pos, att, t)
    mask = risk_mask(world, pos, att, t, PARAMS)
    assert mask.shape == img.shape[:2] and mask.dtype == np.uint8
    road = np.abs(img.astype(int) - np.array(ROAD_BGR)).max(axis=2) <= 6
    assert road.sum() > 20000
    assert np.mean(mask[road] == 5) > 0.99  # busy_road
    car = np.abs(img.astype(int) - np.array(CAR_BGR)).max(axis=2) < 60
    b, g, r = (img[..., k].astype(int) for k in range(3))
    grass = (g > r + 6) & (g > b + 6) & ~car  # greenish; the road and its painted lines and text are grey
    near_road_edge = cv2.dilate(road.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    # objects raise the level around them (people 5 within 5 m, cars 4 within 3 m): leave out their surroundings
    uu, vv = np.meshgrid(np.arange(PARAMS.width_px, dtype=float), np.arange(PARAMS.height_px, dtype=float))
    ground = pixel_to_ground(np.column_stack([uu.ravel(), vv.ravel()]), pos, att, PARAMS)[:, :2]
    objs = world.tracks.objects_at(t)
    d = np.min(np.hypot(*(ground[:, None, :] - objs.ne_m[None, :, :]).transpose(2, 0, 1)), axis=1)
    near_object = (d < 8.0).reshape(mask.shape)
    quiet_grass = grass & ~near_road_edge & ~near_object
    inside_buffer = grass & (d < 5.0).reshape(mask.shape)  # every object's buffer reaches >= 5.25 m
    assert quiet_grass.sum() > 20000 and inside_buffer.sum() > 1000  # both cases are in view
    assert np.mean(mask[quiet_grass] == 1) > 0.995  # lawn / open ground
    assert np.all(mask[inside_buffer] >= 4)


def test_export_is_reproducible_split_by_region_and_readable(tmp_path: Path) -> None:
    spec = ExportSpec(n=5, seed=3, poses=PoseRanges.parse("alt=12:30,tilt=0:10"), val_fraction=0.4)
    counts = export_dataset(spec, tmp_path / "a")
    export_dataset(spec, tmp_path / "b")
    export_dataset(dataclasses.replace(spec, seed=4), tmp_path / "c")
    assert counts["train_images"] >= 1 and counts["val_images"] >= 1
    for sub in ("labels", "poses"):
        for f in sorted((tmp_path / "a" / sub).rglob("*.*")):
            assert f.read_bytes() == (tmp_path / "b" / f.relative_to(tmp_path / "a")).read_bytes()
    pa = sorted((tmp_path / "a" / "poses").rglob("*.json"))
    pc = sorted((tmp_path / "c" / "poses").rglob("*.json"))
    assert [json.loads(p.read_text())["pos_ned_m"] for p in pa] != [
        json.loads(p.read_text())["pos_ned_m"] for p in pc
    ]
    # region split: every val footprint is east of every train footprint
    east = {"train": [], "val": []}  # type: dict[str, list[float]]
    for p in pa:
        meta = json.loads(p.read_text())
        fp = ground_footprint(meta["pos_ned_m"], meta["att_rpy_rad"], PARAMS)
        assert fp is not None
        east[meta["split"]] += list(fp[:, 1])
        img = cv2.imread(str(p.parent.parent.parent / "images" / meta["split"] / (p.stem + ".jpg")))
        mask = cv2.imread(str(p.parent.parent.parent / "masks" / meta["split"] / (p.stem + ".png")), 0)
        assert img.shape == (480, 640, 3) and mask.shape == (480, 640) and mask.min() >= 1 and mask.max() <= 5
    assert max(east["train"]) <= min(east["val"])
    # data.yaml: plain YAML (ultralytics reads it in the detector e2e test); no `path`, so the folder can move
    lines = (tmp_path / "a" / "data.yaml").read_text().splitlines()
    assert "train: images/train" in lines and "val: images/val" in lines and "names:" in lines
    assert (
        "  0: 'person'" in lines and "  2: 'car'" in lines and not any(x.startswith("path:") for x in lines)
    )


def test_export_cli_and_bad_input(tmp_path: Path) -> None:
    def cli(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            [sys.executable, "-m", "viva_sitl", "dataset", "export", *args],
            cwd=REPO, capture_output=True, text=True, timeout=240,
        )  # fmt: skip

    ok = cli("--footage", "synthetic", "--n", "2", "--seed", "1", "-o", str(tmp_path / "d"))
    assert ok.returncode == 0, ok.stderr
    assert "2 images (train" in ok.stdout and (tmp_path / "d" / "data.yaml").is_file()
    again = cli("--footage", "synthetic", "--n", "2", "-o", str(tmp_path / "d"))
    assert (
        again.returncode == 2
        and "is not empty" in again.stderr
        and len(again.stderr.strip().splitlines()) == 1
    )
    bad = cli("--footage", "synthetic", "--n", "2", "--poses", "alt=banana", "-o", str(tmp_path / "e"))
    assert bad.returncode == 2 and "bad --poses item 'alt=banana'" in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1
    nope = cli("--footage", "no-such-footage", "--n", "2", "-o", str(tmp_path / "f"))
    assert (
        nope.returncode == 2
        and "no-such-footage" in nope.stderr
        and len(nope.stderr.strip().splitlines()) == 1
    )
    with pytest.raises(PerceptionError, match="--val-footage"):
        ExportSpec(footages=("synthetic", "interchange"), split="footage").check()
    with pytest.raises(PerceptionError, match="tilt range"):
        PoseRanges.parse("tilt=0:80")


@pytest.mark.parametrize("cmd", ["train-segmenter", "train-sr"])
def test_training_without_torch_names_the_extra(tmp_path: Path, cmd: str) -> None:
    args = ["--data", str(tmp_path)] if cmd == "train-segmenter" else ["--footage", "synthetic"]
    code = (
        "import sys; sys.modules['torch'] = None\n"
        "from viva_sitl.perception.cli import perception_main\n"
        f"raise SystemExit(perception_main({[cmd, *args, '-o', str(tmp_path / 'x.pt')]!r}))\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert r.stderr.strip() == (
        f"viva-sitl perception {cmd}: this needs PyTorch, which is not installed: pip install torch==2.13.0 && "
        "pip install 'viva-sitl[perception]' (the CPU torch CI pins; an unpinned torch may pull GBs of CUDA wheels)"
    )
