"""The world without an edge: the synthetic field drawn anywhere, at a bounded cost, and the same ground wherever it is
drawn from; a finite field on request."""

from __future__ import annotations

import math

import numpy as np
import pytest

from viva_sitl.camera import CameraParams, camera_intrinsics
from viva_sitl.config import SimConfig
from viva_sitl.footage import SyntheticField, SyntheticFieldParams
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.sim import Simulator

FILL = np.array(CameraParams().fill_bgr, dtype=np.uint8)


def fill_fraction(img: np.ndarray) -> float:
    return float(np.all(img == FILL, axis=2).mean())


def nadir_px(
    sim: Simulator, north_m: float, east_m: float, pos: tuple[float, float, float]
) -> tuple[float, float]:
    """Where a ground point appears in a level, yaw-0 nadir view (x right = east, y down = south)."""
    k = camera_intrinsics(sim.camera)
    h = -pos[2]
    return k[0, 2] + k[0, 0] * (east_m - pos[1]) / h, k[1, 2] - k[1, 1] * (north_m - pos[0]) / h


@pytest.mark.parametrize("pos", [(2000.0, -1500.0, -50.0), (-7321.0, 12004.0, -40.0)])
def test_far_beyond_the_old_edge_the_camera_sees_the_grid(pos: tuple[float, float, float]) -> None:
    with Simulator(footage="synthetic") as sim:
        assert sim.inside_footage(pos[0], pos[1])  # the geometry covers every ground point
        sim.reset(pos_ned_m=pos)
        frame = sim.render()
        img = frame.image_bgr
        assert frame.meta.coverage == 1.0 and fill_fraction(img) == 0.0
        # the 50 m grid lines nearest the vehicle are bright lines exactly where the ground geometry puts them
        e50 = round(pos[1] / 50.0) * 50.0
        n50 = round(pos[0] / 50.0) * 50.0
        u, _ = nadir_px(sim, 0.0, e50, pos)
        _, v = nadir_px(sim, n50, 0.0, pos)
        column = img[:, round(u)].astype(int).sum(axis=1)
        row = img[round(v), :].astype(int).sum(axis=1)
        assert np.mean(column > 600) > 0.8, f"no grid line at u={u:.1f}"
        assert np.mean(row > 600) > 0.8, f"no grid line at v={v:.1f}"
        # between lines: textured ground, not a flat colour
        u5, _ = nadir_px(sim, 0.0, e50 + 5.0, pos)
        between = img[:, round(u5)].astype(int)
        assert np.mean(between.sum(axis=1) > 600) < 0.3
        assert between[:, 1].std() > 1.0


def test_the_landing_pad_is_seen_where_it_lies() -> None:
    pos = (30.0, 70.0, -30.0)  # straight above the static pad
    with Simulator(footage="synthetic") as sim:
        sim.reset(pos_ned_m=pos)
        img = sim.render().image_bgr
        yellow = (img[:, :, 1] > 200) & (img[:, :, 2] > 200) & (img[:, :, 0] < 60)
        ys, xs = np.nonzero(yellow)
        assert xs.size > 200
        u, v = nadir_px(sim, 30.0, 70.0, pos)
        assert math.hypot(xs.mean() - u, ys.mean() - v) < 1.5


def test_the_ground_is_the_same_wherever_it_is_drawn_from() -> None:
    """Two windows cut around different centres agree on the ground they share (pure function of position)."""
    field = SyntheticField()
    a = FootageGeometry(600, 500, 0.1, 120.0, center_ne_m=(1000.0, -2000.0), unbounded=True)
    b = FootageGeometry(600, 500, 0.1, 120.0, center_ne_m=(1012.3, -1985.1), unbounded=True)
    img_a, img_b = field._draw_ground(a), field._draw_ground(b)
    # ground (1006, -1993) and its neighbourhood, 150 x 150 px, in both windows
    ua, va = a.ned_to_px(1006.0, -1993.0)
    ub, vb = b.ned_to_px(1006.0, -1993.0)
    assert ua - ub == pytest.approx(round(ua - ub)) and va - vb == pytest.approx(
        round(va - vb)
    )  # whole pixels
    ia, ja, ib, jb = math.floor(va), math.floor(ua), math.floor(vb), math.floor(ub)
    pa = img_a[ia - 75 : ia + 75, ja - 75 : ja + 75].astype(int)
    pb = img_b[ib - 75 : ib + 75, jb - 75 : jb + 75].astype(int)
    diff = np.abs(pa - pb)
    assert diff.mean() < 0.2 and diff.max() <= 3
    assert pa.std() > 1.0  # and there is something to compare


def test_rendering_cost_is_bounded_wherever_the_vehicle_flies() -> None:
    """The window drawn around the footprint never exceeds window_max_px a side: low, high, near or far."""
    with Simulator(footage="synthetic") as sim:
        field = sim.footage
        assert isinstance(field, SyntheticField)
        cap = field.params.window_max_px
        sizes = {}
        for pos in [(0.0, 0.0, -10.0), (0.0, 0.0, -300.0), (2000.0, 0.0, -300.0), (0.0, 0.0, -2500.0)]:
            sim.reset(pos_ned_m=pos)
            frame = sim.render()
            g = sim.renderer.geometry
            assert max(g.width_px, g.height_px) <= cap
            assert frame.meta.coverage == 1.0
            sizes[pos] = (g.width_px * g.height_px, g.gsd_m_per_px)
        # higher up: a coarser ground sample distance, not a bigger picture
        assert sizes[(0.0, 0.0, -300.0)][1] > sizes[(0.0, 0.0, -10.0)][1]
        assert sizes[(0.0, 0.0, -300.0)][0] == sizes[(2000.0, 0.0, -300.0)][0]
        # an oblique view sees up to view_range_m of ground; beyond that, the fill (coverage says how much)
        sim.reset(pos_ned_m=(0.0, 0.0, -50.0))
        s = sim.state
        tilted = type(s)(
            time_s=s.time_s, step=s.step, pos_ned_m=s.pos_ned_m, prev_pos_ned_m=s.prev_pos_ned_m,
            att_rpy_rad=np.array([0.0, math.radians(70.0), 0.0]), thrust_n=s.thrust_n, gust_ned_m_s=s.gust_ned_m_s,
            landed=s.landed, touchdown_speed_m_s=s.touchdown_speed_m_s, dt_s=s.dt_s,
        )  # fmt: skip
        frame = sim.render(tilted)
        g = sim.renderer.geometry
        assert max(g.width_px, g.height_px) <= cap
        assert 0.0 < frame.meta.coverage < 1.0
        assert fill_fraction(frame.image_bgr) == pytest.approx(1.0 - frame.meta.coverage, abs=0.02)


def test_the_window_is_kept_while_the_footprint_stays_inside() -> None:
    with Simulator(footage="synthetic") as sim:
        field = sim.footage
        assert isinstance(field, SyntheticField)
        sim.reset(pos_ned_m=(0.0, 0.0, -50.0))
        sim.render()
        drawn = field.windows_drawn
        for k in range(1, 6):  # 1 m steps: the same background
            sim.reset(pos_ned_m=(float(k), 0.0, -50.0))
            sim.render()
        assert field.windows_drawn == drawn
        sim.reset(pos_ned_m=(500.0, 0.0, -50.0))
        sim.render()
        assert field.windows_drawn == drawn + 1


def test_a_finite_field_on_request() -> None:
    cfg = SimConfig()
    field = SyntheticField(SyntheticFieldParams(unbounded=False))
    with Simulator(cfg, footage=field) as sim:
        assert sim.inside_footage(0.0, 0.0) and not sim.inside_footage(150.0, 0.0)
        sim.reset(pos_ned_m=(300.0, 0.0, -50.0))
        frame = sim.render()
        assert frame.meta.coverage == 0.0 and fill_fraction(frame.image_bgr) == 1.0


def test_a_steady_flight_gets_its_next_windows_drawn_ahead() -> None:
    """Flying north, the next windows come from the background thread and show the same ground as a fresh draw."""
    with Simulator(footage="synthetic") as sim, Simulator(footage="synthetic") as fresh:
        field = sim.footage
        assert isinstance(field, SyntheticField)
        for k in range(60):  # 2 m steps, 120 m
            pos = (2.0 * k, 0.0, -50.0)
            sim.reset(pos_ned_m=pos)
            frame = sim.render()
        assert field.windows_drawn >= 3 and field.windows_ahead == field.windows_drawn - 1
        fresh.reset(pos_ned_m=pos)
        ref = fresh.render()
        assert (
            sim.renderer.geometry != fresh.renderer.geometry
        )  # drawn ahead: another window than a fresh one
        diff = np.abs(frame.image_bgr.astype(int) - ref.image_bgr.astype(int))
        assert diff.mean() < 0.5 and np.percentile(diff, 99.9) <= 4


@pytest.mark.parametrize("height_m", [0.8, 1.2, 3.0, 10.0])
def test_a_view_does_not_depend_on_the_windows_the_flight_left(height_m: float) -> None:
    """Climbing out from the ground reuses small windows; the view at a height equals a fresh render there. (Before the
    window edge band, at 0.8 m 88,000 values differed by up to 109 grey levels: the texture blur's window border.)"""
    with Simulator(footage="synthetic") as climbed, Simulator(footage="synthetic") as fresh:
        for z in np.linspace(-0.05, -height_m, 40):
            climbed.reset(pos_ned_m=(0.3, -0.2, float(z)))
            climbed.render()
        fresh.reset(pos_ned_m=(0.3, -0.2, -height_m))
        a, b = climbed.render().image_bgr.astype(int), fresh.render().image_bgr.astype(int)
    diff = np.abs(a - b)
    assert diff.max() <= 2 and diff.mean() < 0.01, (int(np.count_nonzero(diff > 2)), diff.max(), diff.mean())
