"""The headless Python API, the config loader and `viva-sitl render`: real footage sources, no mocks."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from viva_sitl.config import ConfigError, SimConfig
from viva_sitl.dynamics import EavCommand, EavParams
from viva_sitl.sim import Simulator

REPO = Path(__file__).resolve().parents[1]


def _psnr(a: np.ndarray, b: np.ndarray) -> float:
    mse = float(np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2))
    return math.inf if mse == 0 else 10 * math.log10(255.0**2 / mse)


def test_reset_step_render_roundtrip() -> None:
    with Simulator(SimConfig()) as sim:
        s0 = sim.reset(seed=3, pos_ned_m=(5.0, -4.0, -40.0), yaw_rad=0.5)
        assert s0.pos_ned_m.tolist() == [5.0, -4.0, -40.0] and not s0.landed
        hover = EavCommand(0.0, 0.0, 0.5, sim.params.hover_thrust_n)
        s1 = sim.step(hover, n=250)
        assert s1.time_s == pytest.approx(1.0)
        assert np.allclose(s1.pos_ned_m, s0.pos_ned_m, atol=1e-9)
        frame = sim.render()
        assert frame.image_bgr.shape == (480, 640, 3) and frame.image_bgr.dtype == np.uint8
        m = frame.meta
        assert m.frame_counter == 0 and m.sim_time_s == pytest.approx(1.0)
        assert m.pos_ned_m == pytest.approx((5.0, -4.0, -40.0))
        assert m.att_rpy_rad[2] == pytest.approx(0.5)
        assert m.coverage == pytest.approx(1.0)
        assert m.intrinsics_k[0][0] == pytest.approx(320 / math.tan(math.radians(82.1 / 2)))
        assert sim.render().meta.frame_counter == 1


def test_frames_change_as_the_vehicle_moves_and_repeat_for_same_pose() -> None:
    with Simulator(SimConfig()) as sim:
        sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -30.0))
        a = sim.render().image_bgr
        a2 = sim.render(sim.state).image_bgr
        assert np.array_equal(a, a2)  # same pose, same footage frame: same picture
        sim.reset(seed=0, pos_ned_m=(10.0, 0.0, -30.0))
        b = sim.render().image_bgr
        assert _psnr(a, b) < 20  # moved 10 m north: a different view


def test_seeded_runs_with_wind_and_noise_are_bit_identical() -> None:
    cfg = SimConfig.from_dict(
        {
            "physics": {"wind": {"gust_std_m_s": 1.0, "force_noise_std_n": 0.05}},
            "camera": {"noise_std": 4.0},
        }
    )

    def rollout(seed: int) -> tuple[np.ndarray, np.ndarray]:
        with Simulator(cfg) as sim:
            sim.reset(seed=seed, pos_ned_m=(0.0, 0.0, -20.0))
            for _ in range(50):
                sim.step(EavCommand(0.02, -0.01, 0.0, sim.params.hover_thrust_n), n=5)
            return sim.state.pos_ned_m.copy(), sim.render().image_bgr

    p1, i1 = rollout(11)
    p2, i2 = rollout(11)
    p3, i3 = rollout(12)
    assert p1.tobytes() == p2.tobytes() and np.array_equal(i1, i2)
    assert p1.tobytes() != p3.tobytes() and not np.array_equal(i1, i3)


def test_footage_frame_follows_sim_time_not_steps() -> None:
    with Simulator(SimConfig()) as sim:
        fps = sim.footage.fps
        sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -30.0))
        sim.step(EavCommand(0, 0, 0, sim.params.hover_thrust_n), n=int(round(2.0 / sim.params.dt_s)))
        assert sim.render().meta.footage_frame_index == sim.footage.frame_index_at(2.0)
        assert sim.footage.frame_index_at(2.0) == int(2.0 * fps) % sim.footage.frame_count


def test_config_file_round_trip_and_errors(tmp_path: Path) -> None:
    good = tmp_path / "good.toml"
    good.write_text(
        '[sim]\nfootage = "synthetic"\nspeed = 2.0\n[physics]\nrate_hz = 500\n[physics.wind]\n'
        'mean_wind_ned_m_s = [1.0, 0.0, 0.0]\n[camera]\nwidth_px = 320\nheight_px = 240\nmount = "gimbal"\n'
        "[params]\nMIS_TAKEOFF_ALT = 10.0\n"
    )
    cfg = SimConfig.load(good)
    assert cfg.speed == 2.0 and cfg.physics.dt_s == pytest.approx(1 / 500)
    assert cfg.physics.wind.mean_wind_ned_m_s == (1.0, 0.0, 0.0)
    assert cfg.camera.width_px == 320 and cfg.camera.mount.name == "GIMBAL"
    assert cfg.params == (("MIS_TAKEOFF_ALT", 10.0),)
    assert SimConfig.load(REPO / "configs" / "default.toml") == SimConfig()
    assert SimConfig.load(REPO / "configs" / "paper.toml") == SimConfig(physics=EavParams.paper())

    cases = {
        "[physics]\nmass = 1.0\n": "unknown key 'mass'",
        "[physcs]\n": "unknown table",
        "[physics]\nmass_kg = -1.0\n": "mass_kg",
        '[camera]\nmount = "sideways"\n': "not one of",
        '[sim]\nspeed = "fast"\n': "expected a number",
        "[physics\n": "not valid TOML",
    }
    for text, message in cases.items():
        bad = tmp_path / "bad.toml"
        bad.write_text(text)
        with pytest.raises(ConfigError, match=message):
            SimConfig.load(bad)
    with pytest.raises(ConfigError, match="not found"):
        SimConfig.load(tmp_path / "missing.toml")


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "viva_sitl", *args], capture_output=True, text=True, timeout=120, cwd=REPO
    )


def test_cli_render_writes_the_view(tmp_path: Path) -> None:
    out = tmp_path / "view.png"
    r = _cli("render", "--pose", "0,0,50,0,0,0", "-o", str(out))
    assert r.returncode == 0, r.stderr
    img = cv2.imread(str(out))
    assert img is not None and img.shape == (480, 640, 3)
    with Simulator(SimConfig()) as sim:
        sim.reset(seed=0, pos_ned_m=(0.0, 0.0, -50.0))
        expected = sim.render().image_bgr
    assert _psnr(img, expected) > 60  # the same view as the API renders (PNG is lossless)


def test_cli_errors_are_one_clear_line(tmp_path: Path) -> None:
    r = _cli(
        "render",
        "--footage",
        str(tmp_path / "nope.mp4"),
        "--pose",
        "0,0,50,0,0,0",
        "-o",
        str(tmp_path / "x.png"),
    )
    assert r.returncode == 2 and "viva-sitl:" in r.stderr and "Traceback" not in r.stderr
    r = _cli("render", "--pose", "0,0,nan,0,0,0", "-o", str(tmp_path / "x.png"))
    assert r.returncode == 2 and "--pose" in r.stderr
    r = _cli("render", "--pose", "0,0,50,0,0,0", "-o", str(tmp_path / "view"))  # no extension: no format
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        f"viva-sitl render: cannot write {tmp_path / 'view'}: no image format for a name without an extension "
        "(use .png or .jpg)"
    ], r.stderr
    bad = tmp_path / "bad.toml"
    bad.write_text("[camera]\nwidth_px = -5\n")
    r = _cli("run", "--config", str(bad), "--no-video", "--duration", "1")
    assert r.returncode == 2 and "width_px" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("camera", [{}, {"noise_std": 4.0}, {"width_px": 96, "height_px": 72}])
def test_render_rgb_is_the_bgr_render_reversed(camera: dict[str, float]) -> None:
    """Simulator.render_rgb (the gym's observation: one conversion, no frame metadata, optionally into a given
    array) gives the pixels of render().image_bgr in RGB order, noise included, as the poses change."""
    cfg = SimConfig.from_dict({"camera": camera})
    with Simulator(cfg) as a, Simulator(cfg) as b:
        for sim in (a, b):
            sim.reset(seed=3, pos_ned_m=(5.0, -8.0, -30.0), yaw_rad=0.4)
        for k in range(4):
            for sim in (a, b):
                sim.step(EavCommand(0.1, -0.05, 0.2, sim.params.hover_thrust_n * 0.9), n=25)
            bgr = a.render().image_bgr
            out = np.zeros_like(bgr) if k % 2 else None
            rgb = b.render_rgb(out=out)
            assert out is None or rgb is out
            assert np.array_equal(rgb, bgr[:, :, ::-1]), k
