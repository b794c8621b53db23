"""Ground-truth layers of the overview: what they draw is what the world model answers at that sim time."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from viva_sitl.dashboard.layers import ObjectsLayer, RiskMapLayer, world_layers
from viva_sitl.world import ObjectClass, load_world


@pytest.fixture(scope="module")
def world():  # type: ignore[no-untyped-def]
    return load_world("synthetic")


@pytest.mark.parametrize("t_s", [0.0, 3.3, 11.7])
def test_object_boxes_are_the_world_objects_at_that_time(world, t_s: float) -> None:  # type: ignore[no-untyped-def]
    layer = ObjectsLayer(world)
    feats = layer.features(t_s, 0)
    objs = world.tracks.objects_at(t_s)
    assert len(objs) > 0 and len(feats) == len(objs)
    g = world.geometry
    for k, ft in enumerate(feats):
        (x0, y0), (x1, y1) = ft["points"]
        n, e = g.px_to_ned((x0 + x1) / 2, (y0 + y1) / 2)
        assert abs(n - objs.ne_m[k, 0]) < 0.05 and abs(e - objs.ne_m[k, 1]) < 0.05
        assert abs((x1 - x0) * g.gsd_m_per_px - max(objs.size_m[k, 0], 2 * g.gsd_m_per_px)) < 0.05
        assert ft["label"].startswith(ObjectClass(int(objs.object_class[k])).label)
    # the actors move: a later time gives other boxes
    later = layer.features(t_s + 2.0, 0)
    assert later != feats


def _level_image(feats: list[dict], w: int, h: int, default: int) -> np.ndarray:  # type: ignore[type-arg]
    """Re-rasterise the drawn polygons (holes cut out, later levels over earlier) at footage resolution."""
    img = np.full((h, w), default, np.uint8)
    for ft in feats:
        mask = np.zeros((h, w), np.uint8)
        cv2.fillPoly(mask, [np.round(np.array(ft["points"])).astype(np.int32)], 1)
        for hole in ft["holes"]:
            cv2.fillPoly(mask, [np.round(np.array(hole)).astype(np.int32)], 0)
        img[mask > 0] = ft["level"]
    return img


@pytest.mark.parametrize("name", ["synthetic", "songdo-00003", "interchange"])
def test_risk_polygons_are_the_risk_map(name: str) -> None:
    try:
        world = load_world(name)
    except Exception as exc:  # catalog footage lives in ../shared
        pytest.skip(f"{name}: {exc}")
    assert world.has_risk_map
    feats = RiskMapLayer(world).features(0.0, 0)
    assert feats and {f["level"] for f in feats} <= {1, 2, 3, 4, 5}
    g = world.geometry
    drawn = _level_image(feats, g.width_px, g.height_px, world.risk_map.default_level)
    # compare at a grid of footage pixels (pixel centres) with the world's own answer there
    us, vs = np.meshgrid(np.arange(2, g.width_px, 7), np.arange(2, g.height_px, 7))
    m = g.px_to_ground
    den = m[2, 0] * us + m[2, 1] * vs + m[2, 2]
    n = (m[0, 0] * us + m[0, 1] * vs + m[0, 2]) / den
    e = (m[1, 0] * us + m[1, 1] * vs + m[1, 2]) / den
    truth = world.risk_map.levels_at(n, e)
    agree = float(np.mean(drawn[vs, us] == truth))
    assert agree > 0.98, f"{name}: drawn levels agree with world.static_risk_at at only {agree:.3f} of points"
    assert len(np.unique(truth)) > 1  # a check that could fail: the map is not uniform


def test_layers_only_for_what_the_world_has(world) -> None:  # type: ignore[no-untyped-def]
    names = [layer.name for layer in world_layers(world)]
    assert names == ["objects", "risk map"]
    assert getattr(world_layers(world)[1], "static", False)
