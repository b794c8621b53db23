"""YOLO detection on VAC frames (extra `perception-yolo`: ultralytics + a torchvision matching torch).

    det = Detector("runs/det/train/weights/best.pt")          # any ultralytics detection weights: .pt or .onnx
                                                               # (.onnx: extra perception-onnx, onnxruntime)
    for d in det.detect(frame_bgr): print(d.name, d.confidence, d.box_px)
    ground = det.on_ground(dets, meta=frame_meta)               # (k, 2) north/east of each box centre
    best, metrics = train_detector("data/songdo/data.yaml", epochs=30, imgsz=640)   # ultralytics' own trainer

Weights cannot be downloaded on machines without internet: `train_detector` starts from an architecture file
(`yolov8n.yaml` by default, randomly initialised) unless given weights. YOLO_OFFLINE=1 is set before ultralytics is
imported so it never tries to reach the network.
"""

from __future__ import annotations

import importlib.util
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from viva_sitl.camera import CameraParams
from viva_sitl.camera.projection import ground_to_image_homography
from viva_sitl.perception.errors import INSTALL_HINT_ONNX, INSTALL_HINT_YOLO, PerceptionError
from viva_sitl.perception.geometry import ground_homography_from_meta, image_to_ground

U8 = NDArray[np.uint8]
WEIGHT_SUFFIXES = (".pt", ".onnx")


def require_ultralytics() -> Any:
    """The ultralytics YOLO class, or PerceptionError naming the extra."""
    os.environ.setdefault("YOLO_OFFLINE", "1")
    os.environ.setdefault("YOLO_VERBOSE", "False")
    try:
        from ultralytics import YOLO
    except ImportError as exc:
        raise PerceptionError(
            f"the detector needs ultralytics with a matching torchvision ({exc.name or exc} is missing): "
            f"{INSTALL_HINT_YOLO}"
        ) from None
    return YOLO


@dataclass(frozen=True)
class Detection:
    class_id: int
    name: str
    confidence: float
    box_px: tuple[float, float, float, float]  # x0, y0, x1, y1 (pixel edges)

    @property
    def centre_px(self) -> tuple[float, float]:
        x0, y0, x1, y1 = self.box_px
        return (x0 + x1) / 2.0, (y0 + y1) / 2.0


class Detector:
    """An ultralytics YOLO detection model run on BGR frames (CPU unless `device` says otherwise)."""

    def __init__(
        self,
        weights: str | Path,
        conf: float = 0.25,
        iou: float = 0.45,
        imgsz: int = 640,
        device: str = "cpu",
    ) -> None:
        path = Path(weights)
        if not path.is_file():
            raise PerceptionError(
                f"detector weights not found: {path} (train them with `viva-sitl perception train-detector`)"
            )
        if path.suffix.lower() not in WEIGHT_SUFFIXES:
            raise PerceptionError(
                f"detector weights {path} must be a .pt or .onnx file, got {path.suffix or 'none'}"
            )
        if path.suffix.lower() == ".onnx" and importlib.util.find_spec("onnxruntime") is None:
            # ultralytics would only fail at the first frame (after trying to pip-install it)
            raise PerceptionError(
                f"ONNX weights {path.name} need onnxruntime, which is not installed: {INSTALL_HINT_ONNX}"
            )
        yolo = require_ultralytics()
        try:
            self.model = yolo(str(path), task="detect")
        except Exception as exc:  # ultralytics raises many types for a foreign file
            msg = str(exc).strip().splitlines()[0][:160] if str(exc).strip() else type(exc).__name__
            raise PerceptionError(f"{path} is not an ultralytics YOLO model: {msg}") from None
        task = getattr(self.model, "task", "detect")
        if task != "detect":
            raise PerceptionError(f"{path} is a YOLO {task} model, not a detection model")
        self.path, self.conf, self.iou, self.imgsz, self.device = path, conf, iou, imgsz, device

    @property
    def names(self) -> dict[int, str]:
        return dict(getattr(self.model, "names", {}) or {})

    def detect(self, image_bgr: U8) -> list[Detection]:
        img = np.asarray(image_bgr)
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise PerceptionError(f"frame must be an HxWx3 uint8 BGR image, got {img.dtype} {img.shape}")
        res = self.model.predict(img, imgsz=self.imgsz, conf=self.conf, iou=self.iou, device=self.device,
                                 verbose=False)[0]  # fmt: skip
        names = res.names or {}
        boxes = res.boxes
        xyxy = boxes.xyxy.cpu().numpy() if boxes is not None else np.zeros((0, 4))
        cls = boxes.cls.cpu().numpy().astype(int) if boxes is not None else np.zeros(0, int)
        confs = boxes.conf.cpu().numpy() if boxes is not None else np.zeros(0)
        return [
            Detection(
                int(c),
                str(names.get(int(c), c)),
                float(p),
                (float(b[0]), float(b[1]), float(b[2]), float(b[3])),
            )
            for b, c, p in zip(xyxy, cls, confs, strict=True)
        ]

    @staticmethod
    def on_ground(
        detections: list[Detection],
        pos_ned_m: ArrayLike | None = None,
        att_rpy_rad: ArrayLike | None = None,
        params: CameraParams | None = None,
        meta: Any = None,
    ) -> NDArray[np.float64]:
        """(k, 2) north/east of each detection's box centre on the ground (NaN above the horizon), through the
        frame's pose: (pos_ned_m, att_rpy_rad, params) or `meta` (a FrameMeta from the frame-and-pose socket)."""
        if meta is not None:
            h = ground_homography_from_meta(meta)
        elif pos_ned_m is not None and att_rpy_rad is not None and params is not None:
            h = ground_to_image_homography(pos_ned_m, att_rpy_rad, params)
        else:
            raise PerceptionError(
                "on_ground needs the frame's pose: meta=FrameMeta, or pos_ned_m, att_rpy_rad, params"
            )
        if not detections:
            return np.zeros((0, 2))
        px = np.array([d.centre_px for d in detections]) - 0.5  # box edges -> pixel-centre coordinates
        return image_to_ground(h, px)


def scaled_model_yaml(model: str, width: float, out_dir: Path, depth: float = 0.33) -> str:
    """An ultralytics architecture file (e.g. `yolov8n.yaml`) rescaled to `width` x the channels (and `depth` x the
    repeats), written to out_dir; the returned path keeps the name's scale letter so ultralytics picks our scale.
    Thinner than `n` (0.25) trains several times faster on a CPU, which matters more than capacity for a from-scratch
    detector of a few object classes."""
    import yaml
    from ultralytics.nn.tasks import yaml_model_load

    if not 0.0 < width <= 1.5 or not 0.0 < depth <= 1.5:
        raise PerceptionError(f"detector width/depth multiples must be in (0, 1.5], got {width}/{depth}")
    try:
        cfg = yaml_model_load(model)
    except Exception as exc:
        raise PerceptionError(
            f"cannot read the architecture {model}: {str(exc).splitlines()[0][:160]}"
        ) from None
    scale = cfg.get("scale") or "n"
    cfg["scales"] = {scale: [depth, width, 1024]}
    for key in ("scale", "yaml_file"):
        cfg.pop(key, None)
    stem = Path(model).stem
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"{stem}-w{width:g}.yaml"
    path.write_text(yaml.safe_dump(cfg, sort_keys=False))
    return str(path)


# Recipe for a from-scratch detector of small objects on a CPU (overrides of ultralytics' defaults; see train_detector)
FROM_SCRATCH_RECIPE: dict[str, Any] = {
    "flipud": 0.5,  # a nadir view has no up: vertical flips are as free as horizontal ones
    "degrees": 180.0,  # ... and no preferred heading
    "scale": 0.3,  # less zoom-out than 0.5: the objects are already a few pixels
    "mosaic": 1.0,
    "close_mosaic": 2,
    "warmup_epochs": 1.0,
}


def train_detector(
    data_yaml: str | Path,
    epochs: int = 30,
    imgsz: int = 640,
    model: str = "yolov8n.yaml",
    batch: int = 8,
    out_dir: str | Path = "runs/detector",
    seed: int = 0,
    fraction: float = 1.0,
    *,
    width: float = 0.0,
    nbs: int = 0,
    time_h: float = 0.0,
    patience: int = 100,
    classes: list[int] | None = None,
    recipe: bool = False,
    on_best: Any = None,
) -> tuple[Path, dict[str, float]]:
    """ultralytics' trainer on an exported dataset; returns (best weights, {map50, map50_95, precision, recall}).

    width > 0 rescales an architecture .yaml (`scaled_model_yaml`); nbs > 0 sets ultralytics' nominal batch (it
    accumulates gradients over nbs/batch batches, 64 by default: a small CPU run then makes few optimizer steps; nbs =
    batch steps every batch); time_h > 0 trains for that many hours (ultralytics re-plans the epochs and schedule);
    classes keeps only those class ids; recipe applies FROM_SCRATCH_RECIPE; on_best(path, metrics) is called each
    time a better best.pt is written."""
    data = Path(data_yaml)
    if data.is_dir():
        data = data / "data.yaml"
    if not data.is_file():
        raise PerceptionError(
            f"dataset description not found: {data} (export one with `viva-sitl dataset export`)"
        )
    yolo = require_ultralytics()
    if model.endswith(".pt") and not Path(model).is_file():
        raise PerceptionError(
            f"starting weights not found: {model} (offline: start from an architecture .yaml)"
        )
    out = Path(out_dir).resolve()
    if width > 0.0:
        if not model.endswith((".yaml", ".yml")):
            raise PerceptionError(f"--width rescales an architecture .yaml, not {model}")
        model = scaled_model_yaml(model, width, out)
    try:
        net = yolo(model, task="detect")
    except Exception as exc:
        raise PerceptionError(
            f"cannot build the detector from {model}: {str(exc).splitlines()[0][:160]}"
        ) from None
    extra: dict[str, Any] = dict(FROM_SCRATCH_RECIPE) if recipe else {}
    if nbs > 0:
        extra["nbs"] = nbs
    if time_h > 0.0:
        extra["time"] = time_h
    if classes:
        extra["classes"] = list(classes)
    if on_best is not None:

        def _saved(trainer: Any) -> None:
            if trainer.best_fitness is not None and trainer.best_fitness == trainer.fitness:
                on_best(Path(trainer.best), _metrics(trainer.metrics))

        net.add_callback("on_model_save", _saved)
    net.train(
        data=str(data.resolve()), epochs=epochs, imgsz=imgsz, batch=batch, device="cpu", workers=0, seed=seed,
        project=str(out), name="train", exist_ok=True, plots=False, amp=False, verbose=False, fraction=fraction,
        pretrained=False, patience=patience, **extra,
    )  # fmt: skip
    best = out / "train" / "weights" / "best.pt"
    if not best.is_file():
        best = out / "train" / "weights" / "last.pt"
    return best, _metrics(getattr(getattr(net, "trainer", None), "metrics", {}) or {})


def _metrics(m: Any) -> dict[str, float]:
    m = m or {}
    return {
        "map50": float(m.get("metrics/mAP50(B)", float("nan"))),
        "map50_95": float(m.get("metrics/mAP50-95(B)", float("nan"))),
        "precision": float(m.get("metrics/precision(B)", float("nan"))),
        "recall": float(m.get("metrics/recall(B)", float("nan"))),
    }


def export_onnx(weights: str | Path, imgsz: int) -> Path:
    """ONNX export of trained weights (ultralytics' exporter; needs the onnx package), next to them."""
    yolo = require_ultralytics()
    try:
        import onnx  # noqa: F401
    except ImportError:
        raise PerceptionError(
            "ONNX export needs the onnx package: pip install 'viva-sitl[perception-onnx]'"
        ) from None
    try:
        return Path(yolo(str(weights), task="detect").export(format="onnx", imgsz=imgsz, simplify=False))
    except Exception as exc:
        raise PerceptionError(f"ONNX export of {weights} failed: {str(exc).splitlines()[0][:160]}") from None
