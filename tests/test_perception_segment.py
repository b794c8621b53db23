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
    "torch",
    reason="the U-Net needs the perception extra: pip install torch==2.13.0 && pip install 'viva-sitl[perception]'",
)
from viva_sitl.perception.segment import (  # noqa: E402
    GroundRisk,
    Segmenter,
    UNet,
    _to_tensor,
    augment,
    budget_lr,
    class_weights,
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


def test_class_weights_lift_rare_levels() -> None:
    m = np.zeros((10, 100), np.uint8)  # 0 = unseen: ignored
    m[:, 10:] = 1  # 900 px
    m[:, :10] = 5  # 100 px (9x rarer)
    w = class_weights([m])
    assert w[0] == 0 and w[2] == w[3] == w[4] == 0  # ignored and absent levels
    assert w[5] / w[1] == pytest.approx(3.0)  # inverse square root of the frequency ratio 9
    assert (900 * w[1] + 100 * w[5]) / 1000 == pytest.approx(1.0)  # mean weight over labelled pixels is 1
    m2 = np.ones((10, 1000), np.uint8)
    m2[0, 0] = 4  # one pixel in 10^4: capped at max_ratio x the commonest level's weight
    w2 = class_weights([m2], max_ratio=10.0)
    assert w2[4] / w2[1] == pytest.approx(10.0)
    assert not class_weights([np.zeros((4, 4), np.uint8)]).any()


def test_augment_keeps_image_and_mask_aligned() -> None:
    rng = np.random.default_rng(0)
    # the mask is a function of the (un-jittered) image: level = 1 + red channel // 64 ... only if they move together
    red = rng.integers(0, 4, (6, 1, 24, 32)).repeat(8, axis=2).repeat(8, axis=3)[:, :, :24, :32]
    x = torch.from_numpy(np.concatenate([red / 4.0, np.zeros_like(red), np.zeros_like(red)], axis=1)).float()
    y = torch.from_numpy(red[:, 0] + 1).long()
    seen_flip = set()
    for _ in range(8):
        xa, ya = augment(x, y, rng)
        assert xa.shape == x.shape and ya.shape == y.shape and xa.min() >= 0 and xa.max() <= 1
        # photometric jitter is monotonic per image: the level order of the red channel survives; geometry matches
        for i in range(x.shape[0]):
            r = xa[i, 0]
            for lv in range(1, 5):
                sel = ya[i] == lv
                if sel.any():
                    assert float(r[sel].max() - r[sel].min()) < 1e-6  # one red value per level: aligned
            seen_flip.add(tuple(int(v) for v in ya[i, 0, :2]) != tuple(int(v) for v in y[i, 0, :2]))
        assert sorted(np.unique(ya.numpy())) == sorted(np.unique(y.numpy()))
    assert True in seen_flip  # it does move things
    xs, ys = augment(x[:, :, :24, :24], y[:, :24, :24], np.random.default_rng(1))  # square: transposes too
    assert xs.shape == (6, 3, 24, 24) and ys.shape == (6, 24, 24)


def test_budget_lr_warms_up_then_decays() -> None:
    lrs = [budget_lr(f, 1e-2) for f in np.linspace(0.0, 1.0, 101)]
    assert lrs[0] == pytest.approx(1e-3) and max(lrs) == pytest.approx(1e-2, rel=1e-3)
    peak = int(np.argmax(lrs))
    assert peak == 5 and all(a >= b for a, b in zip(lrs[peak:], lrs[peak + 1 :], strict=False))
    assert lrs[-1] == pytest.approx(1e-4) and budget_lr(3.0, 1e-2) == pytest.approx(1e-4)


def _rect_dataset(root: Path, n: int, seed: int) -> None:
    import cv2

    rng = np.random.default_rng(seed)
    for split, count in (("train", n), ("val", max(2, n // 3))):
        (root / "images" / split).mkdir(parents=True)
        (root / "masks" / split).mkdir(parents=True)
        for i in range(count):
            img = np.full((48, 64, 3), 120, np.uint8)
            mask = np.ones((48, 64), np.uint8)
            y, x = int(rng.integers(0, 32)), int(rng.integers(0, 44))
            img[y : y + 12, x : x + 16] = (0, 0, 200)
            mask[y : y + 12, x : x + 16] = 5
            cv2.imwrite(str(root / "images" / split / f"{i}.jpg"), img)
            cv2.imwrite(str(root / "masks" / split / f"{i}.png"), mask)


def test_training_keeps_the_best_epoch_and_reports_it(tmp_path: Path) -> None:
    from viva_sitl.perception.segment import evaluate, load_split, train_segmenter

    _rect_dataset(tmp_path, 12, 0)
    saved: list[float] = []
    lines: list[str] = []
    model, hist = train_segmenter(
        tmp_path, epochs=4, size=(64, 48), width=4, batch=4, lr=1e-2,
        on_best=lambda m, met: saved.append(met["val_miou"]), log=lines.append,
    )  # fmt: skip
    curve = [row["val_miou"] for row in hist["curve"]]
    assert len(curve) == hist["epochs_run"] == 4 and len(lines) == 4 and "val_miou=" in lines[0]
    assert hist["val_miou"] == max(curve) and saved[-1] == max(curve)  # on_best at every improvement
    assert saved == sorted(saved) and len(saved) == len(set(saved))
    again = evaluate(Segmenter(model, (64, 48), None), load_split(tmp_path, "val", (64, 48)))
    assert again["val_miou"] == pytest.approx(hist["val_miou"])  # the returned model is the best epoch's
    assert hist["class_weights"][5] > hist["class_weights"][1] > 0  # the rare level 5 weighs more
    # a time budget stops early (after the first evaluation) whatever the epoch cap
    _, h2 = train_segmenter(tmp_path, epochs=1000, size=(64, 48), width=4, batch=4, time_limit_s=1e-3)
    assert h2["epochs_run"] == 1 and len(h2["loss"]) >= 1


def test_evaluate_counts_missed_and_false_hazards() -> None:
    from viva_sitl.perception.segment import SegData, evaluate

    truth = np.ones((4, 10), np.uint8)
    truth[:, :2] = 5  # 8 hazard pixels, 32 safe
    truth[0, 9] = 0  # unseen: ignored

    class _Pred:
        def predict(self, img: np.ndarray) -> np.ndarray:
            p = np.ones((4, 10), np.uint8)
            p[:, 0] = 5  # half the hazard found
            p[:, 2] = 4  # 4 safe pixels called hazardous
            return p

    r = evaluate(_Pred(), SegData([np.zeros((4, 10, 3), np.uint8)], [truth]))  # type: ignore[arg-type]
    assert r["val_missed_hazard"] == pytest.approx(4 / 8) and r["val_false_hazard"] == pytest.approx(4 / 31)
    assert r["val_iou_by_level"][5] == pytest.approx(4 / 8) and set(r["val_iou_by_level"]) == {1, 5}


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


@pytest.mark.slow  # trains a U-Net from the CLI
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
