"""Super-resolution: OpenCV zoo models through cv2.dnn (graph surgery), EDSR in torch, the magnified render path."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import numpy as np
import pytest

from viva_sitl.camera import CameraParams, Renderer
from viva_sitl.footage import open_footage
from viva_sitl.perception import (
    BicubicUpscaler,
    MagnifiedRender,
    OpenCVSR,
    PerceptionError,
    SRConfig,
    SRMethod,
    load_upscaler,
    magnified_render_from_config,
)
from viva_sitl.perception.quality import degrade_area, psnr_db, ssim
from viva_sitl.perception.sr import _pixel_shuffle
from viva_sitl.sim import Simulator

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def sr_dir(shared_dir: Path) -> Path:
    d = shared_dir / "models" / "sr"
    if not (d / "FSRCNN_x2.pb").is_file():
        pytest.skip(f"SR models absent in {d}")
    return d


@pytest.fixture
def songdo_crop(shared_dir: Path) -> np.ndarray:
    path = shared_dir / "footage" / "songdo" / "03936.jpg"
    if not path.is_file():
        pytest.skip(f"{path} absent")
    img = cv2.imread(str(path))
    assert img is not None
    return np.ascontiguousarray(img[800:1040, 1200:1520])  # 320x240 of cars and road


def test_pixel_shuffle_follows_tensorflow_depth_to_space() -> None:
    s, h, w = 3, 2, 4
    x = np.arange(s * s * h * w, dtype=np.float32).reshape(s * s, h, w)
    y = _pixel_shuffle(x, s)
    assert y.shape == (h * s, w * s)
    for i in range(s):
        for j in range(s):
            np.testing.assert_array_equal(y[i::s, j::s], x[i * s + j])


@pytest.mark.parametrize(
    ("name", "method"),
    [("FSRCNN_x2", "fsrcnn"), ("FSRCNN-small_x2", "fsrcnn"), ("ESPCN_x2", "espcn"), ("ESPCN_x3", "espcn")],
)
def test_zoo_models_load_upscale_and_beat_bicubic(
    sr_dir: Path, songdo_crop: np.ndarray, name: str, method: str
) -> None:
    up = load_upscaler(SRConfig(method=method, model_path=str(sr_dir / f"{name}.pb")))
    assert up is not None and up.scale == int(name[-1])
    lr = degrade_area(songdo_crop, up.scale)
    hr = songdo_crop[: lr.shape[0] * up.scale, : lr.shape[1] * up.scale]
    out = up.upscale(lr)
    assert out.shape == hr.shape and out.dtype == np.uint8
    bicubic = BicubicUpscaler(up.scale).upscale(lr)
    # a model run with a wrong pixel shuffle or colour handling falls far below bicubic
    assert psnr_db(out, hr, up.scale) > psnr_db(bicubic, hr, up.scale) + 0.1
    assert ssim(out, hr, up.scale) > ssim(bicubic, hr, up.scale)


def test_bad_models_are_one_line_errors(sr_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(PerceptionError, match="not found: .*nope.pb"):
        load_upscaler(SRConfig(method="fsrcnn", model_path=str(tmp_path / "nope.pb")))
    with pytest.raises(PerceptionError, match="is an espcn model, but the method asks for fsrcnn"):
        load_upscaler(SRConfig(method="fsrcnn", model_path=str(sr_dir / "ESPCN_x2.pb")))
    junk = tmp_path / "junk.pb"
    junk.write_bytes(b"\x00\x01not a graph at all" * 10)
    with pytest.raises(PerceptionError, match="not an FSRCNN/ESPCN TensorFlow graph"):
        OpenCVSR(junk)
    with pytest.raises(PerceptionError, match="needs model_path"):
        load_upscaler(SRConfig(method="espcn"))
    with pytest.raises(PerceptionError, match="unknown super-resolution method 'lanczos'"):
        SRConfig(method="lanczos")  # type: ignore[arg-type]
    up = OpenCVSR(sr_dir / "FSRCNN_x2.pb")
    with pytest.raises(PerceptionError, match="HxWx3 uint8 BGR"):
        up.upscale(np.zeros((10, 10), np.float32))  # type: ignore[arg-type]
    assert load_upscaler(SRConfig(method=SRMethod.NONE)) is None
    assert magnified_render_from_config(SRConfig()) is None
    mr = magnified_render_from_config(SRConfig("espcn", str(sr_dir / "ESPCN_x2.pb"), min_magnification=1.5))
    assert isinstance(mr, MagnifiedRender) and mr.min_magnification == 1.5 and mr.upscaler.scale == 2


def test_edsr_without_torch_names_the_extra(tmp_path: Path) -> None:
    code = (
        "import sys; sys.modules['torch'] = None\n"
        "from viva_sitl.perception import load_upscaler, SRConfig, PerceptionError\n"
        "try:\n"
        f"    load_upscaler(SRConfig(method='edsr', model_path={str(tmp_path / 'x.pt')!r}))\n"
        "except PerceptionError as e:\n"
        "    print('ERR', e)\n"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60, check=True
    )
    line = out.stdout.strip()
    assert line.startswith("ERR ") and "PyTorch" in line and "pip install 'viva-sitl[perception]'" in line
    assert "\n" not in line


def _interchange_renderer() -> tuple[Renderer, np.ndarray]:
    src = open_footage("interchange")
    try:
        frame = src.frame(0)
        return Renderer(CameraParams(), src.geometry), frame
    finally:
        src.close()


def test_magnified_render_keeps_the_geometry(interchange_video: Path) -> None:
    renderer, frame = _interchange_renderer()
    mr = MagnifiedRender(BicubicUpscaler(2), min_magnification=1.0)
    high = np.array([0.0, 0.0, -300.0])
    low = np.array([10.0, -20.0, -40.0])
    att = np.array([0.02, -0.03, 0.4])
    assert not mr.magnified(renderer, high, att)  # 300 m: about 0.5 VAC px per footage px
    assert mr.magnified(renderer, low, att)
    assert mr.magnification(renderer, low, att) == pytest.approx(3.97, rel=0.05)  # 40 m over 0.43 m/px
    plain = renderer.render(frame, low, att)
    sr = mr.render(renderer, frame, low, att)
    assert sr.coverage == pytest.approx(plain.coverage)
    np.testing.assert_allclose(sr.homography, plain.homography)
    # same picture, same place: bicubic-then-bilinear vs bilinear differ only in texture, never by a shift
    assert psnr_db(sr.image_bgr, plain.image_bgr) > 30.0
    shift, _ = cv2.phaseCorrelate(
        cv2.cvtColor(sr.image_bgr, cv2.COLOR_BGR2GRAY).astype(np.float64),
        cv2.cvtColor(plain.image_bgr, cv2.COLOR_BGR2GRAY).astype(np.float64),
    )
    assert abs(shift[0]) < 0.1 and abs(shift[1]) < 0.1


def test_simulator_hook_upscales_only_when_low(interchange_video: Path, sr_dir: Path) -> None:
    with Simulator(footage="interchange") as sim:
        mr = MagnifiedRender(OpenCVSR(sr_dir / "FSRCNN_x2.pb"), min_magnification=1.5)
        sim.reset(pos_ned_m=(0.0, 0.0, -400.0))
        before = sim.render().image_bgr
        sim.super_resolution = mr
        high = sim.render().image_bgr
        assert mr.renders == 0
        np.testing.assert_array_equal(high, before)  # high up: the hook does not touch the image
        sim.reset(pos_ned_m=(0.0, 0.0, -30.0))
        low_sr = sim.render().image_bgr
        assert mr.renders == 1
        sim.super_resolution = None
        low_plain = sim.render().image_bgr
    assert 25.0 < psnr_db(low_sr, low_plain) < 60.0  # the same view, sharper texture
    sharp = cv2.Laplacian(cv2.cvtColor(low_sr, cv2.COLOR_BGR2GRAY), cv2.CV_64F).var()
    soft = cv2.Laplacian(cv2.cvtColor(low_plain, cv2.COLOR_BGR2GRAY), cv2.CV_64F).var()
    assert sharp > soft


def test_edsr_shapes_roundtrip_and_training_lowers_the_loss(tmp_path: Path) -> None:
    pytest.importorskip(
        "torch",
        reason="EDSR needs the perception extra: pip install torch==2.13.0 && pip install 'viva-sitl[perception]'",
    )
    from viva_sitl.perception.edsr import EDSR, load_edsr, save_edsr, train_edsr

    rng = np.random.default_rng(1)
    img = cv2.GaussianBlur(rng.integers(0, 256, (96, 128, 3), dtype=np.uint8), (0, 0), 1.2)
    for s in (2, 3, 4):
        import torch

        with torch.inference_mode():
            assert EDSR(s, n_feats=8, n_resblocks=1)(torch.zeros(1, 3, 10, 12)).shape == (
                1,
                3,
                10 * s,
                12 * s,
            )
    model, losses = train_edsr([img], scale=2, steps=40, patch_px=16, batch=4, n_feats=16, n_resblocks=2)
    assert np.mean(losses[-10:]) < np.mean(losses[:5])
    path = tmp_path / "edsr_x2.pt"
    save_edsr(model, path)
    up = load_upscaler(SRConfig(method="edsr", model_path=str(path)))
    assert up is not None and up.scale == 2
    out = up.upscale(img[:24, :32])
    assert out.shape == (48, 64, 3) and out.dtype == np.uint8
    with pytest.raises(PerceptionError, match="EDSR weights not found"):
        load_edsr(tmp_path / "missing.pt")
    (tmp_path / "bad.pt").write_bytes(b"garbage")
    with pytest.raises(PerceptionError, match="is not a torch checkpoint"):
        load_edsr(tmp_path / "bad.pt")
    torch.save({"weights": torch.zeros(3)}, tmp_path / "other.pt")
    with pytest.raises(PerceptionError, match="not a viva-sitl EDSR checkpoint"):
        load_edsr(tmp_path / "other.pt")


def test_train_sr_cli_writes_a_loadable_checkpoint(tmp_path: Path) -> None:
    pytest.importorskip(
        "torch",
        reason="EDSR needs the perception extra: pip install torch==2.13.0 && pip install 'viva-sitl[perception]'",
    )
    out = tmp_path / "edsr.pt"
    r = subprocess.run(
        [sys.executable, "-m", "viva_sitl", "perception", "train-sr", "--footage", "synthetic", "--frames", "1",
         "--steps", "3", "--feats", "4", "--blocks", "1", "-o", str(out)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout and "EDSR x2" in r.stdout
    up = load_upscaler(SRConfig(method="edsr", model_path=str(out)))
    assert up is not None and up.upscale(np.zeros((8, 8, 3), np.uint8)).shape == (16, 16, 3)
