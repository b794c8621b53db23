"""The Ray backend gives the same results as the local pool (issue 8 §4), on a local Ray started by the test."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from viva_sitl.evaluation.campaign import rows_equal, run_campaign
from viva_sitl.evaluation.spec import spec_from_dict

ray = pytest.importorskip("ray", reason="the ray backend needs the trials-ray extra")


@pytest.fixture
def local_ray() -> Iterator[None]:
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        yield
    finally:
        ray.shutdown()


@pytest.mark.slow  # starts a Ray cluster
def test_ray_backend_matches_local_pool(tmp_path: Path, local_ray: None) -> None:
    spec = spec_from_dict(
        {"trials": {"name": "ray", "n": 3, "seed": 11, "timeout_s": 40.0},
         "scenario": {"footage": "synthetic", "north_m": [-30.0, 30.0], "east_m": [-30.0, 30.0],
                      "altitude_m": [8.0, 10.0], "land_at_s": 0.5, "wind_speed_m_s": [0.0, 2.0]}},
        "ray",
    )  # fmt: skip
    r = run_campaign(spec, "descend", tmp_path / "ray", backend="ray", jobs=2, progress=False)
    loc = run_campaign(spec, "descend", tmp_path / "local", backend="local", jobs=1, progress=False)
    assert [x["end"] for x in r.ordered_rows()] == ["landed"] * 3
    assert rows_equal(r.ordered_rows(), loc.ordered_rows())
    assert ray.is_initialized()  # the campaign used the test's Ray and left it running
