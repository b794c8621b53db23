"""YOLO detector wrapper: bad input without the extra, then (with ultralytics) a token training on an export."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from viva_sitl.camera import CameraParams, pixel_to_ground
from viva_sitl.perception import PerceptionError
from viva_sitl.perception.detect import Detection, Detector

REPO = Path(__file__).resolve().parents[1]


def test_bad_weights_are_one_line_errors(tmp_path: Path) -> None:
    with pytest.raises(PerceptionError, match="detector weights not found: .*nope.pt"):
        Detector(tmp_path / "nope.pt")
    (tmp_path / "model.pb").write_bytes(b"x")
    with pytest.raises(PerceptionError, match=r"must be a \.pt or \.onnx file, got \.pb"):
        Detector(tmp_path / "model.pb")


def test_without_ultralytics_names_the_extra(tmp_path: Path) -> None:
    (tmp_path / "w.pt").write_bytes(b"x")
    code = (
        "import sys; sys.modules['ultralytics'] = None\n"
        "from viva_sitl.perception.detect import Detector\n"
        "from viva_sitl.perception import PerceptionError\n"
        f"try:\n    Detector({str(tmp_path / 'w.pt')!r})\nexcept PerceptionError as e:\n    print(e)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=60)
    line = r.stdout.strip()
    assert "ultralytics" in line and "pip install 'viva-sitl[perception-yolo]'" in line and "\n" not in line


def test_on_ground_uses_the_box_centre() -> None:
    params = CameraParams()
    pos, att = np.array([3.0, 4.0, -20.0]), np.array([0.0, 0.1, 0.5])
    d = Detection(2, "car", 0.9, (100.0, 200.0, 140.0, 220.0))
    g = Detector.on_ground([d], pos, att, params)
    np.testing.assert_allclose(g[0], pixel_to_ground(np.array([[119.5, 209.5]]), pos, att, params)[0, :2])
    assert Detector.on_ground([], pos, att, params).shape == (0, 2)


@pytest.mark.slow  # trains a detector
@pytest.mark.e2e
def test_export_token_training_and_detection(tmp_path: Path) -> None:
    pytest.importorskip(
        "ultralytics", reason="needs the perception-yolo extra: pip install 'viva-sitl[perception-yolo]'"
    )
    pytest.importorskip(
        "torchvision", reason="ultralytics needs torchvision: pip install 'viva-sitl[perception-yolo]'"
    )
    import cv2

    data = tmp_path / "data"
    r = subprocess.run(
        [sys.executable, "-m", "viva_sitl", "dataset", "export", "--footage", "synthetic", "--n", "4", "--seed", "5",
         "--poses", "alt=12:25", "-o", str(data)],
        cwd=REPO, capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr
    r = subprocess.run(
        [sys.executable, "-m", "viva_sitl", "perception", "train-detector", "--data", str(data), "--epochs", "1",
         "--imgsz", "160", "--batch", "4", "--nbs", "4", "--width", "0.125", "--recipe", "--classes", "0,2",
         "--copy-best", str(tmp_path / "copy.pt"), "-o", str(tmp_path / "det")],
        cwd=REPO, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert r.returncode == 0, r.stderr[-2000:]
    best = tmp_path / "det" / "train" / "weights" / "best.pt"
    assert best.is_file() and "mAP50" in r.stdout
    assert (tmp_path / "copy.pt").read_bytes() == best.read_bytes()  # the final best, copied where asked
    det = Detector(best, conf=1e-4, imgsz=160)
    assert det.names[0] == "person" and det.names[2] == "car"
    frame = cv2.imread(str(next((data / "images").rglob("*.jpg"))))
    dets = det.detect(frame)
    for d in dets:  # an untrained net still returns well-formed, in-image boxes
        x0, y0, x1, y1 = d.box_px
        assert (
            0 <= x0 <= x1 <= 640
            and 0 <= y0 <= y1 <= 480
            and 0 < d.confidence <= 1
            and d.name in det.names.values()
        )
    with pytest.raises(PerceptionError, match="HxWx3 uint8"):
        det.detect(np.zeros((480, 640), np.uint8))
    (tmp_path / "junk.pt").write_bytes(b"not a model")
    with pytest.raises(PerceptionError, match="is not an ultralytics YOLO model"):
        Detector(tmp_path / "junk.pt")


def test_scaled_architecture_is_thinner(tmp_path: Path) -> None:
    pytest.importorskip(
        "ultralytics", reason="needs the perception-yolo extra: pip install 'viva-sitl[perception-yolo]'"
    )
    pytest.importorskip(
        "torchvision", reason="ultralytics needs torchvision: pip install 'viva-sitl[perception-yolo]'"
    )
    from viva_sitl.perception.detect import require_ultralytics, scaled_model_yaml

    yolo = require_ultralytics()
    path = scaled_model_yaml("yolov8n.yaml", 0.125, tmp_path)
    assert Path(path).name == "yolov8n-w0.125.yaml"

    def n_params(m: str) -> int:
        return sum(p.numel() for p in yolo(m, task="detect").model.parameters())

    base, thin = n_params("yolov8n.yaml"), n_params(path)
    assert thin < base / 2.5  # channels halved: ~1/4 of the weights (the head keeps a floor)
    with pytest.raises(PerceptionError, match="width/depth multiples"):
        scaled_model_yaml("yolov8n.yaml", 0.0, tmp_path)
    with pytest.raises(PerceptionError, match="cannot read the architecture"):
        scaled_model_yaml("no-such-net.yaml", 0.125, tmp_path)
