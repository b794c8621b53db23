"""RegionPyramid.halve_into_next: the trilinear blend's second level from the first, as the pyramid builds it."""

from __future__ import annotations

import numpy as np
import pytest

from viva_sitl.camera.pyramid import LazyPyramid, RegionPyramid


def test_halving_a_filled_box_equals_the_next_pyramid_level_there() -> None:
    rng = np.random.default_rng(3)
    frame = rng.integers(0, 256, (96, 128, 3), dtype=np.uint8)
    lazy = LazyPyramid(frame)
    region = RegionPyramid(128, 96, channels=4)
    lx0, ly0, lx1, ly1 = 10, 4, 64, 48  # level 1 is 64x48: the box ends on its edge
    region.fill_level(
        1, lx0, ly0, np.dstack([lazy.level(1)[ly0:ly1, lx0:lx1], np.full((44, 54, 1), 255, np.uint8)])
    )
    region.halve_into_next(1, lx0, ly0, lx1, ly1)
    assert region.filled_levels == {1, 2}
    got = region[2][ly0 // 2 : ly1 // 2, lx0 // 2 : lx1 // 2]
    assert np.array_equal(got[..., :3], lazy.level(2)[ly0 // 2 : ly1 // 2, lx0 // 2 : lx1 // 2])
    assert np.all(got[..., 3] == 255)


def test_halving_refuses_what_would_not_be_an_exact_box_average() -> None:
    region = RegionPyramid(128, 96)
    with pytest.raises(ValueError, match="not filled"):
        region.halve_into_next(1, 0, 0, 8, 8)
    region.fill_level(1, 0, 0, np.zeros((48, 64, 3), np.uint8))
    with pytest.raises(ValueError, match="even box"):
        region.halve_into_next(1, 1, 0, 8, 8)
    with pytest.raises(ValueError, match="even box"):
        region.halve_into_next(1, 0, 0, 66, 8)
    odd = RegionPyramid(100, 60)  # level 2 is 25x15: level 3 is no exact halving of it
    odd.fill_level(2, 0, 0, np.zeros((15, 25, 3), np.uint8))
    with pytest.raises(ValueError, match="not an exact halving"):
        odd.halve_into_next(2, 0, 0, 24, 14)
