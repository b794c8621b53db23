"""The ONNX branch of `Detector` (issue 9 §2): a YOLO exported to ONNX detects as its .pt does; without onnxruntime
the .onnx weights are one line at load naming the extra (ultralytics alone fails only at the first frame)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from viva_sitl.perception import PerceptionError
from viva_sitl.perception.detect import Detector

REPO = Path(__file__).resolve().parents[1]


def test_onnx_without_onnxruntime_names_the_extra(tmp_path: Path) -> None:
    (tmp_path / "best.onnx").write_bytes(b"x")
    code = (
        "import sys; sys.modules['onnxruntime'] = None\n"
        "from viva_sitl.perception.detect import Detector\n"
        "from viva_sitl.perception import PerceptionError\n"
        f"try:\n    Detector({str(tmp_path / 'best.onnx')!r})\nexcept PerceptionError as e:\n    print(e)\n"
    )
    r = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=120)
    line = r.stdout.strip()
    assert r.returncode == 0 and "\n" not in line, r.stdout + r.stderr
    assert "best.onnx need onnxruntime" in line and "pip install 'viva-sitl[perception-onnx]'" in line


@pytest.mark.slow  # trains and exports a detector
@pytest.mark.e2e
def test_onnx_export_detects_as_the_pt(tmp_path: Path) -> None:
    ultralytics = pytest.importorskip("ultralytics", reason="needs the perception-yolo extra")
    pytest.importorskip("onnx", reason="ONNX export needs onnx: pip install 'viva-sitl[perception-onnx]'")
    pytest.importorskip("onnxruntime", reason="ONNX inference needs onnxruntime: extra perception-onnx")
    from viva_sitl.sim import Simulator

    net = ultralytics.YOLO("yolov8n.yaml", task="detect")  # random weights: no download; 80 classes
    pt = tmp_path / "tiny.pt"
    net.save(str(pt))
    onnx_path = Path(
        ultralytics.YOLO(str(pt), task="detect").export(format="onnx", imgsz=160, simplify=False)
    )
    assert onnx_path.suffix == ".onnx" and onnx_path.is_file()
    with Simulator(footage="synthetic") as sim:
        sim.reset(pos_ned_m=(-25.0, -15.0, -15.0))  # over the crowd
        frame = sim.render().image_bgr
    a = Detector(pt, conf=1e-7, imgsz=160).detect(frame)
    det_onnx = Detector(onnx_path, conf=1e-7, imgsz=160)
    b = det_onnx.detect(frame)
    assert det_onnx.names == Detector(pt).names and len(det_onnx.names) == 80
    assert len(a) > 5 and len(b) > 5  # an untrained net still proposes boxes at this threshold
    # the strongest proposals agree (near the threshold the two runtimes' rounding keeps a few boxes apart)
    top_a = sorted(a, key=lambda d: -d.confidence)[:5]
    top_b = sorted(b, key=lambda d: -d.confidence)[:10]
    for da in top_a:
        assert any(
            db.class_id == da.class_id
            and np.allclose(db.box_px, da.box_px, atol=1.0)
            and abs(db.confidence - da.confidence) <= 0.01 * da.confidence
            for db in top_b
        ), (da, top_b)
    with pytest.raises(PerceptionError, match="HxWx3 uint8"):
        det_onnx.detect(np.zeros((480, 640), np.uint8))
