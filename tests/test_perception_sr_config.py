"""`[perception.sr]` (issue 9 §4): config -> SRConfig -> super_resolution_from_config -> the vehicle's simulator (built
once per vehicle, kept across resets); a bad model is one line at start-up."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from viva_sitl.config import ConfigError, SimConfig
from viva_sitl.perception import MagnifiedRender, OpenCVSR, SRMethod
from viva_sitl.perception.from_config import super_resolution_from_config
from viva_sitl.vehicle import Vehicle

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def fsrcnn(shared_dir: Path) -> Path:
    path = shared_dir / "models" / "sr" / "FSRCNN_x2.pb"
    if not path.is_file():
        pytest.skip(f"super-resolution model {path} is absent")
    return path


def _write(tmp_path: Path, body: str) -> Path:
    p = tmp_path / "cfg.toml"
    p.write_text(body)
    return p


def test_sr_table_reaches_the_simulator_and_upscales_low_frames(
    tmp_path: Path, fsrcnn: Path, interchange_video: Path
) -> None:
    cfg = SimConfig.load(_write(tmp_path, f"""
[sim]
footage = "interchange"
[perception.sr]
method = "fsrcnn"
model_path = "{fsrcnn}"
min_magnification = 1.5
"""))  # fmt: skip
    assert cfg.perception.sr.method is SRMethod.FSRCNN and cfg.perception.sr.min_magnification == 1.5
    with Vehicle(cfg, super_resolution=super_resolution_from_config(cfg)) as v:
        sr = v.sim.super_resolution
        assert isinstance(sr, MagnifiedRender) and isinstance(sr.upscaler, OpenCVSR)
        v.reset()
        assert v.sim.super_resolution is sr  # loaded once per vehicle: a reset keeps the model
        assert sr.upscaler.scale == 2 and sr.min_magnification == 1.5
        v.sim.reset(pos_ned_m=(0.0, 0.0, -400.0))
        v.render()
        assert sr.renders == 0  # high: the footage is not magnified, no SR
        v.sim.reset(pos_ned_m=(0.0, 0.0, -30.0))
        with_sr = v.render().image_bgr
        assert sr.renders == 1  # low: rendered from the upscaled crop
        v.sim.super_resolution = None
        plain = v.render().image_bgr
    assert with_sr.shape == plain.shape and not np.array_equal(with_sr, plain)


def test_default_config_has_no_sr() -> None:
    assert SimConfig().perception.sr.method is SRMethod.NONE
    assert SimConfig.load(REPO / "configs" / "default.toml").perception.sr.method is SRMethod.NONE
    assert super_resolution_from_config(SimConfig()) is None
    with Vehicle(SimConfig()) as v:
        assert v.sim.super_resolution is None


@pytest.mark.parametrize(
    ("body", "needle"),
    [
        ('[perception.sr]\nmethod = "magic"', "perception.sr.method: 'magic' is not one of none"),
        (
            '[perception.sr]\nmethod = "bicubic"\nmin_magnification = 0',
            "min_magnification must be a positive",
        ),
        ("[perception.sr]\nthreshold = 2.0", "perception.sr: unknown key 'threshold'"),
        ('[perception.sr]\nmethod = "espcn"', "espcn needs model_path"),
        ('[perception.sr]\nmethod = "fsrcnn"\nmodel_path = "/no/such/FSRCNN_x2.pb"', "model not found"),
    ],
)
def test_bad_sr_config_is_one_line(tmp_path: Path, body: str, needle: str) -> None:
    path = _write(tmp_path, body)
    with pytest.raises(ConfigError, match="perception"):
        super_resolution_from_config(SimConfig.load(path))
    # the same at start-up of `viva-sitl run`: one line, exit status 2, no traceback, nothing bound
    proc = subprocess.run(
        [sys.executable, "-m", "viva_sitl", "run", "--config", str(path), "--no-video", "--duration", "1",
         "--no-dashboard", "--run-dir", str(tmp_path / "run")],
        capture_output=True, text=True, timeout=60, cwd=REPO,
    )  # fmt: skip
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2, proc.stderr
    assert len(err) == 1 and needle in err[0] and "Traceback" not in proc.stderr, proc.stderr
