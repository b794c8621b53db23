"""Risk U-Net: shapes, one-batch overfit, checkpoints and bad input, ground mapping, export + token training (e2e)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from viva_sitl.camera import CameraParams, frame_camera_fields, ground_to_image_homography, pixel_to_ground
from viva_sitl.perception import PerceptionError

torch = pytest.importorskip(
    "torch", reason="the U-Net needs the perception extra: pip install 'viva-sitl[perception]'"
)
from viva_sitl.perception.segment import (  # noqa: E402
    GroundRisk,
    Segmenter,
    UNet,
    _to_tensor,
    save_segmenter,
)

REPO = Path(__file__).resolve().parents[1]


def test_unet_shapes() -> None:
    m = UNet(width=4, depth=3).eval()
    with torch.inference_mode():
        assert m(torch.zeros(2, 3, 48, 64)).shape == (2, 6, 48, 64)


def test_one_batch_overfit() -> None:
    torch.manual_seed(0)
    rng = np.random.default_rng(0)
    imgs, masks = [], []
    for _ in range(2):  # coloured rectangles on grey: the level is the colour
        img = np.full((48, 64, 3), 120, np.uint8)
        mask = np.full((48, 64), 1, np.uint8)
        for level, bgr in ((3, (0, 0, 200)), (5, (200, 0, 0))):
            y, x = int(rng.integers(0, 30)), int(rng.integers(0, 40))
            img[y : y + 16, x : x + 20] = bgr
            mask[y : y + 16, x : x + 20] = level
        imgs.append(img)
        masks.append(mask)
    m = UNet(width=8, depth=3)
    opt = torch.optim.Adam(m.parameters(), lr=1e-2)
    x, y = _to_tensor(imgs), torch.from_numpy(np.stack(masks).astype(np.int64))
    for _ in range(80):
        loss = torch.nn.functional.cross_entropy(m(x), y, ignore_index=0)
        opt.zero_grad()
        loss.backward()
        opt.step()
    seg = Segmenter(m, (64, 48), None)
    for img, mask in zip(imgs, masks, strict=True):
        assert np.mean(seg.predict(img) == mask) > 0.98


def test_checkpoint_roundtrip_and_bad_input(tmp_path: Path) -> None:
    m = UNet(width=4, depth=3)
    m.input_size = (64, 48)  # type: ignore[assignment]
    save_segmenter(m, tmp_path / "u.pt", frame_size=(128, 96))
    seg = Segmenter.load(tmp_path / "u.pt")
    out = seg.predict(np.zeros((96, 128, 3), np.uint8))
    assert out.shape == (96, 128) and out.dtype == np.uint8 and out.min() >= 1 and out.max() <= 5
    with pytest.raises(PerceptionError, match=r"frame is 640x480, but this segmenter was trained on 128x96"):
        seg.predict(np.zeros((480, 640, 3), np.uint8))
    with pytest.raises(PerceptionError, match="HxWx3 uint8"):
        seg.predict(np.zeros((96, 128), np.float32))  # type: ignore[arg-type]
    with pytest.raises(PerceptionError, match="segmenter weights not found"):
        Segmenter.load(tmp_path / "missing.pt")
    from viva_sitl.perception.edsr import EDSR, save_edsr

    save_edsr(EDSR(2, 4, 1), tmp_path / "edsr.pt")
    with pytest.raises(PerceptionError, match="is a viva-sitl-edsr checkpoint, not a risk segmenter"):
        Segmenter.load(tmp_path / "edsr.pt")
    (tmp_path / "junk.pt").write_text("junk")
    with pytest.raises(PerceptionError, match="is not a torch checkpoint"):
        Segmenter.load(tmp_path / "junk.pt")


def test_on_ground_follows_the_pose() -> None:
    params = CameraParams()
    pos, att = np.array([5.0, -3.0, -30.0]), np.array([0.05, -0.08, 0.7])
    levels = np.ones((480, 640), np.uint8)
    levels[100:200, 300:420] = 5  # a level-5 patch in the image
    g = Segmenter.on_ground(levels, pos, att, params, cell_m=0.2)
    assert isinstance(g, GroundRisk)
    # the patch centre's ground point reads 5; a ground point seen elsewhere reads 1; outside the view 0
    ne = pixel_to_ground(np.array([[360.0, 150.0], [100.0, 400.0]]), pos, att, params)
    assert g.level_at(ne[0, 0], ne[0, 1]) == 5 and g.level_at(ne[1, 0], ne[1, 1]) == 1
    assert g.level_at(pos[0] + 500.0, pos[1]) == 0
    # every level-5 cell projects into the patch (1 px slack for the nearest-pixel sampling)
    rows, cols = np.nonzero(g.levels == 5)
    pts = np.stack([g.north0_m + rows * g.cell_m, g.east0_m + cols * g.cell_m, np.ones(rows.size)], axis=1)
    q = pts @ ground_to_image_homography(pos, att, params).T
    u, v = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
    assert u.min() >= 299.5 - 1 and u.max() <= 419.5 + 1 and v.min() >= 99.5 - 1 and v.max() <= 199.5 + 1
    # the same through the fields the frame-and-pose socket sends
    meta = {"pos_ned_m": list(pos), "att_rpy_rad": list(att), **frame_camera_fields(params, att)}
    g2 = Segmenter.on_ground(levels, meta=meta, cell_m=0.2)
    assert np.array_equal(g2.levels, g.levels) and (g2.north0_m, g2.east0_m) == pytest.approx(
        (g.north0_m, g.east0_m)
    )


@pytest.mark.e2e
def test_export_then_token_training_from_the_cli(tmp_path: Path) -> None:
    def run(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "viva_sitl", *args], cwd=REPO, capture_output=True, text=True,
                              timeout=600)  # fmt: skip

    data = tmp_path / "data"
    r = run("dataset", "export", "--footage", "synthetic", "--n", "6", "--seed", "2", "--poses", "alt=15:30", "-o",
            str(data))  # fmt: skip
    assert r.returncode == 0, r.stderr
    r = run("perception", "train-segmenter", "--data", str(data), "--epochs", "1", "--size", "64x48", "--width",
            "4", "-o", str(tmp_path / "unet.pt"))  # fmt: skip
    assert r.returncode == 0, r.stderr
    assert "val mIoU" in r.stdout
    seg = Segmenter.load(tmp_path / "unet.pt")
    assert seg.frame_size == (640, 480) and seg.input_size == (64, 48)
    bad = run("perception", "train-segmenter", "--data", str(tmp_path / "nope"), "-o", str(tmp_path / "x.pt"))
    assert (
        bad.returncode == 2
        and "has no images/train" in bad.stderr
        and len(bad.stderr.strip().splitlines()) == 1
    )
