"""Perception evaluation the way the paper does it: a detector or a risk segmenter scored on the virtual camera
against the footage's ground truth, per altitude x tilt x speed x super-resolution cell.

    viva-sitl perception eval --detector best.onnx --footage synthetic --altitudes 10:120:10 --tilt-deg 0,15 \\
        --speed-m-s 0,5 --sr none,bicubic --effects blur,noise --n-per-cell 8 --seed 0 -o out/eval
    viva-sitl perception eval --segmenter mypkg.models:make_segmenter --footage synthetic -o out/seg
    viva-sitl perception eval --compare out/eval_a out/eval_b -o out/a_vs_b

Views: for every footage, altitude and tilt, `n_per_cell` poses are drawn (seeded) exactly as `dataset export` draws
them (`sample_poses`: random position with the whole footprint on the footage, random yaw, tilt in a random
direction, random footage time), and the same poses are rendered in every speed x SR cell, so cells differ only by
what they name (paired). The vehicle moves at the cell's speed in a seeded random horizontal direction (motion blur
uses it); sensor noise is drawn per frame from a seeded generator. Ground truth goes through the label geometry of
`dataset export` (`ground_rectangles` + `project_boxes`, `risk_mask`), through the lens when --effects names
distortion (effects.py).

Models (--detector / --segmenter W):
- a file: `.pt` is ultralytics weights for a detector (extra perception-yolo) or a U-Net saved by
  `perception train-segmenter` for a segmenter (extra perception); `.onnx` runs in onnxruntime (extra perception-onnx,
  no torch): input 1x3xHxW float RGB 0..1 (resized to the model's static H, W, else the frame rounded up to 32;
  a detector's frame is letterboxed as ultralytics does: aspect kept, centred, grey 114 bars);
  detector output either (1, 4 + classes, N) raw YOLOv8 (cx, cy, w, h, class scores; NMS here at IoU 0.7) or
  (1, N, 6) [x1, y1, x2, y2, score, class] (ultralytics' nms/end2end export); segmenter output (1, 5 or 6, H, W)
  logits over levels 1..5 (6: channel 0 = no ground, ignored) or (1, H, W) levels.
- `module:factory` (importable from the current directory or the environment): factory() returns a callable
  f(image_bgr) or f(image_bgr, meta); meta is a dict with the frame's footage, pos_ned_m, att_rpy_rad, vel_ned_m_s,
  time_s, width_px, height_px, intrinsics_k (what the frame-and-pose socket sends) and lens_k1_k2 (the lens's
  radial distortion, 0 without --effects distortion). A detector returns rows
  [x1, y1, x2, y2, class, score] (pixel edges, class = viva_sitl.world.ObjectClass ids, as `dataset export` labels;
  --class-map SRC=DST,... renames a model's ids) or a list of `Detection`; a segmenter returns an (H, W) array of
  levels 1..5 (0: no prediction).

Scores. Detection (COCO-style, implemented here in ~40 lines since no COCO package is a dependency): per class, the
predictions of each frame (top 100 by score) are matched greedily in score order to the unmatched ground-truth box of
highest IoU >= t; AP is the 101-point interpolated area under the precision/recall curve over all frames of the cell;
mAP50 at t = 0.5, mAP50-95 the mean over t = 0.50:0.05:0.95, each the mean over the classes with ground truth in the
cell. precision / recall: at score >= --conf and IoU 0.5, over all scored classes. recall_near_people /
recall_near_vehicles: the share of the people (person, bicycle) / vehicles (car, bus, truck) whose ground centre is
within --radius-m of the ground point at the image centre that are detected (IoU 0.5, score >= conf, right class):
what a landing decision depends on; size_px_people / size_px_vehicles: their median box size sqrt(w h) in pixels.
Segmentation: mIoU over the levels present in the truth, per-level IoU, missed_danger (share of level-4/5 ground
predicted 1-2), lost_landing (share of level-1/2 ground predicted 4-5), pixel accuracy; pixels that see no footage
ground (truth 0) are ignored.

Unavailable is null, never 0 or 1: a class the footage's ground truth does not annotate (metadata `annotated`) has
null scores and its predictions are ignored; a class / level / group with no ground truth in a cell has null AP /
IoU / recall; precision is null without predictions. A footage with no object ground truth (detection) or no risk map
(segmentation) is an error, not a row of nulls.

CIs: a percentile bootstrap over the frames of a cell (--bootstrap resamples, seeded by --seed and the cell), 95 %.

results.json (schema "viva-sitl/perception-eval", version 1):
    schema, version, task ("detection" | "segmentation"), command (the exact argv), model {spec, kind},
    settings {footages, altitudes_m, tilts_deg, speeds_m_s, sr, effects {names, exposure_s, noise_std, k1, k2},
              n_per_cell, seed, width_px, height_px, conf, radius_m, min_visible, bootstrap, class_map, imgsz},
    footages {name: {classes_available: [labels], risk_map: bool}},
    metrics: [names of the headline metrics, in cells[].metrics],
    cells: [{index, footage, altitude_m, tilt_deg, speed_m_s, sr, frames, sr_applied_frames,
             metrics {name: {value, lo, hi}} (null value: unavailable; lo/hi null without a CI),
             per_class {label: {available, n_gt, n_pred, ap50, ap50_95, precision, recall}}      (detection)
             per_level {"1".."5": {n_px, iou}}                                                   (segmentation)}],
    frames: [{id, cell, k, pos_ned_m, att_rpy_rad, vel_ned_m_s, time_s, sr_applied, score, ...}] (score: the
             frame's recall at conf (detection; null without ground truth) or its mIoU (segmentation); lower = worse)
Nothing in it depends on the clock: the same inputs and seed give a byte-identical file. cells.csv has one row per
cell (value, lo, hi of each headline metric, then per-class AP50 / recall or per-level IoU); report.html is
self-contained (eval_report.py).
"""

from __future__ import annotations

import dataclasses
import importlib
import inspect
import json
import math
import os
import re
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.camera import CameraParams
from viva_sitl.camera.effects import distortion_source_map
from viva_sitl.camera.projection import camera_intrinsics, ground_to_image_homography, pixel_to_ground
from viva_sitl.perception.dataset import (
    ExportSpec,
    PoseRanges,
    ground_rectangles,
    project_boxes,
    risk_mask,
    sample_poses,
)
from viva_sitl.perception.effects import EffectSpec, distort_px
from viva_sitl.perception.errors import INSTALL_HINT_ONNX, PerceptionError

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]
SCHEMA = "viva-sitl/perception-eval"
VERSION = 1
IOU_THRESHOLDS = np.round(np.arange(0.5, 0.951, 0.05), 2)
MAX_DETS = 100  # COCO's maxDets per image
DET_METRICS = ("map50", "map50_95", "precision", "recall", "recall_near_people", "recall_near_vehicles",
               "size_px_people", "size_px_vehicles")  # fmt: skip
SEG_METRICS = ("miou", "missed_danger", "lost_landing", "pixel_acc")
N_LEVELS = 6  # 0 (no ground) + 1..5


# --- spec -------------------------------------------------------------------------------------------------------


def parse_values(text: str, what: str, lo: float = -math.inf, hi: float = math.inf) -> tuple[float, ...]:
    """'10:120:10' (start:stop:step, stop included) or '0,15,30' -> floats; each in [lo, hi]."""
    text = text.strip()
    try:
        if ":" in text:
            parts = [float(p) for p in text.split(":")]
            if len(parts) != 3 or parts[2] <= 0 or parts[1] < parts[0]:
                raise ValueError
            n = int(math.floor((parts[1] - parts[0]) / parts[2] + 1e-9)) + 1
            vals = tuple(round(parts[0] + i * parts[2], 9) for i in range(n))
        else:
            vals = tuple(float(p) for p in text.split(",") if p.strip())
    except ValueError:
        raise PerceptionError(
            f"{what} must be START:STOP:STEP or a comma-separated list, got {text!r}"
        ) from None
    if not vals or len(vals) > 1000:
        raise PerceptionError(f"{what} must name 1..1000 values, got {text!r}")
    for v in vals:
        if not (math.isfinite(v) and lo <= v <= hi):
            raise PerceptionError(f"{what} values must be in [{lo:g}, {hi:g}], got {v:g}")
    return vals


@dataclass(frozen=True)
class EvalSpec:
    task: str  # detection | segmentation
    model: str
    footages: tuple[str, ...] = ("synthetic",)
    altitudes_m: tuple[float, ...] = tuple(float(a) for a in range(10, 121, 10))
    tilts_deg: tuple[float, ...] = (0.0,)
    speeds_m_s: tuple[float, ...] = (0.0,)
    sr: tuple[str, ...] = ("none",)
    sr_models: tuple[tuple[str, str], ...] = ()  # (method, model path) for fsrcnn / espcn / edsr
    effects: EffectSpec = field(default_factory=EffectSpec)
    n_per_cell: int = 8
    seed: int = 0
    width_px: int = 640
    height_px: int = 480
    conf: float = 0.25
    radius_m: float = 10.0
    min_visible: float = 0.5
    bootstrap: int = 200
    class_map: tuple[tuple[int, int], ...] = ()
    worst: int = 8
    imgsz: int = 640  # inference size of an ultralytics .pt detector (ONNX: the export's own input)

    def check(self) -> None:
        from viva_sitl.perception.config import SRMethod

        if self.task not in ("detection", "segmentation"):
            raise PerceptionError(f"task must be detection or segmentation, got {self.task!r}")
        if not self.footages:
            raise PerceptionError("perception eval needs at least one --footage")
        if self.n_per_cell < 1:
            raise PerceptionError(f"--n-per-cell must be >= 1, got {self.n_per_cell}")
        if not 0.0 <= self.conf <= 1.0:
            raise PerceptionError(f"--conf must be in [0, 1], got {self.conf}")
        if not (math.isfinite(self.radius_m) and self.radius_m > 0.0):
            raise PerceptionError(f"--radius-m must be > 0, got {self.radius_m}")
        if not 0 <= self.bootstrap <= 100_000:
            raise PerceptionError(f"--bootstrap must be in [0, 100000], got {self.bootstrap}")
        if not 32 <= self.imgsz <= 4096:
            raise PerceptionError(f"--imgsz must be in [32, 4096] px, got {self.imgsz}")
        for a in self.altitudes_m:
            if not 0.5 <= a <= 2000.0:
                raise PerceptionError(f"--altitudes must be in [0.5, 2000] m, got {a:g}")
        for t in self.tilts_deg:
            if not 0.0 <= t < 60.0:
                raise PerceptionError(f"--tilt-deg must be in [0, 60), got {t:g}")
        for s in self.speeds_m_s:
            if not 0.0 <= s <= 100.0:
                raise PerceptionError(f"--speed-m-s must be in [0, 100], got {s:g}")
        known = [m.value for m in SRMethod]
        for m in self.sr:
            if m not in known:
                raise PerceptionError(f"unknown --sr method {m!r} (known: {', '.join(known)})")
        self.effects.check()


# --- models -----------------------------------------------------------------------------------------------------


@dataclass
class Model:
    kind: str  # callable | onnx | ultralytics | unet
    fn: Callable[[U8, dict[str, Any]], Any]


def _wants_meta(fn: Callable[..., Any]) -> bool:
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return False
    params = [p for p in sig.parameters.values() if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    return len(params) >= 2 or any(p.kind is p.VAR_POSITIONAL for p in sig.parameters.values())


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return (text.splitlines()[0][:160] if text else type(exc).__name__).strip()


def load_model(spec: str, task: str, imgsz: int = 640) -> Model:
    """A model from a file (.pt, .onnx) or `module:factory`; PerceptionError (one line) on anything wrong."""
    what = "detector" if task == "detection" else "segmenter"
    path = Path(spec)
    if path.is_file():
        suffix = path.suffix.lower()
        if suffix == ".onnx":
            onnx = OnnxModel(path, task)
            return Model("onnx", lambda img, meta: onnx(img))
        if suffix == ".pt":
            if task == "detection":
                from viva_sitl.perception.detect import Detector

                # conf 0.001: mAP needs the low-score tail; --conf applies in the scores
                det = Detector(path, conf=0.001, imgsz=imgsz)
                return Model("ultralytics", lambda img, meta: det.detect(img))
            from viva_sitl.perception.errors import require_torch

            try:
                require_torch()
            except PerceptionError as exc:
                raise PerceptionError(f"segmenter {path.name} (a U-Net .pt): {exc}") from None
            from viva_sitl.perception.segment import Segmenter

            seg = Segmenter.load(path)
            return Model("unet", lambda img, meta: seg.predict(img))
        raise PerceptionError(
            f"{what} {path} must be a .pt or .onnx file or module:factory, got {suffix or 'none'}"
        )
    if re.fullmatch(r"[A-Za-z_][\w.]*:[A-Za-z_]\w*", spec):
        mod_name, _, fac_name = spec.partition(":")
        if os.getcwd() not in sys.path:
            sys.path.insert(0, os.getcwd())
        try:
            mod = importlib.import_module(mod_name)
        except Exception as exc:
            raise PerceptionError(
                f"cannot import {mod_name} for the {what} {spec}: {_first_line(exc)}"
            ) from None
        factory = getattr(mod, fac_name, None)
        if not callable(factory):
            raise PerceptionError(f"{mod_name} has no callable {fac_name} (the {what} factory {spec})")
        try:
            fn = factory()
        except Exception as exc:
            raise PerceptionError(f"the {what} factory {spec} failed: {_first_line(exc)}") from None
        if not callable(fn):
            raise PerceptionError(f"the {what} factory {spec} returned {type(fn).__name__}, not a callable")
        if _wants_meta(fn):
            return Model("callable", fn)
        return Model("callable", lambda img, meta: fn(img))
    raise PerceptionError(f"{what} weights not found: {spec} (a .pt or .onnx file, or module:factory)")


def _nms(boxes: F64, scores: F64, iou: float) -> list[int]:
    order = list(np.argsort(-scores, kind="stable"))
    keep: list[int] = []
    while order:
        i = order.pop(0)
        keep.append(i)
        if order:
            rest = np.array(order)
            ious = box_iou(boxes[i : i + 1], boxes[rest])[0]
            order = [int(j) for j, v in zip(rest, ious, strict=True) if v <= iou]
    return keep


class OnnxModel:
    """An ONNX detector or segmenter in onnxruntime (formats in the module docstring)."""

    def __init__(self, path: Path, task: str) -> None:
        try:
            import onnxruntime as ort
        except ImportError:
            raise PerceptionError(f"ONNX model {path.name} needs onnxruntime, which is not installed: "
                                  f"{INSTALL_HINT_ONNX}") from None  # fmt: skip
        try:
            self.sess = ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])
        except Exception as exc:
            raise PerceptionError(f"{path} is not a loadable ONNX model: {_first_line(exc)}") from None
        inp = self.sess.get_inputs()[0]
        if len(inp.shape) != 4:
            raise PerceptionError(f"{path}: input {inp.name} has shape {inp.shape}, expected 1x3xHxW")
        h, w = inp.shape[2], inp.shape[3]
        self.in_hw = (h, w) if isinstance(h, int) and isinstance(w, int) else None
        self.name, self.path, self.task = inp.name, path, task

    def __call__(self, img: U8) -> Any:
        h, w = img.shape[:2]
        th, tw = self.in_hw or (32 * math.ceil(h / 32), 32 * math.ceil(w / 32))
        # a detector sees the frame letterboxed as ultralytics trains and predicts (aspect kept, grey 114 bars,
        # centred): stretching a 640x480 frame to a 480x480 export squashed every object by 3/4 and scored a
        # different model than its .pt; a segmenter's mask keeps the input's aspect, so it is resized as trained
        r, px, py = 1.0, 0, 0
        if self.task == "detection" and (th, tw) != (h, w):
            r = min(tw / w, th / h) if self.in_hw else 1.0  # a dynamic input: padded up to 32, not scaled
            nw, nh = max(1, round(w * r)), max(1, round(h * r))
            px, py = (tw - nw) // 2, (th - nh) // 2
            x = np.full((th, tw, 3), 114, np.uint8)
            x[py : py + nh, px : px + nw] = cv2.resize(img, (nw, nh), interpolation=cv2.INTER_LINEAR)
        else:
            x = cv2.resize(img, (tw, th), interpolation=cv2.INTER_LINEAR) if (th, tw) != (h, w) else img
        x = np.ascontiguousarray(x[..., ::-1].transpose(2, 0, 1)[None], np.float32) / np.float32(255.0)
        try:
            out = np.asarray(self.sess.run(None, {self.name: x})[0], np.float64)
        except Exception as exc:
            raise PerceptionError(f"{self.path.name} failed on a {w}x{h} frame: {_first_line(exc)}") from None
        if self.task == "segmentation":
            oh, ow = (out.shape[-2], out.shape[-1]) if out.ndim >= 2 else (0, 0)
            if min(oh, ow) < 8 or abs(oh / ow - th / tw) > 0.05 * th / tw:  # a mask keeps the input's aspect
                raise PerceptionError(f"{self.path.name} outputs {out.shape}: not a segmenter (expected a "
                                      f"1x5xHxW, 1x6xHxW or 1xHxW mask for its {tw}x{th} input)")  # fmt: skip
            if out.ndim == 4 and out.shape[1] in (5, 6):
                lv = out[0, -5:].argmax(0) + 1
            elif out.ndim == 3 and out.shape[0] == 1:
                lv = np.rint(out[0])
            else:
                raise PerceptionError(f"{self.path.name} outputs {out.shape}: not a segmenter (expected 1x5xHxW, "
                                      "1x6xHxW or 1xHxW)")  # fmt: skip
            lv = np.clip(lv, 0, 5).astype(np.uint8)
            return np.asarray(cv2.resize(lv, (w, h), interpolation=cv2.INTER_NEAREST), np.uint8)
        o = out[0] if out.ndim == 3 else out
        if o.ndim != 2:
            raise PerceptionError(f"{self.path.name} outputs {out.shape}: not a detector")
        if o.shape[1] == 6 and o.shape[0] != 6:  # [x1, y1, x2, y2, score, class]
            rows = o[o[:, 4] >= 0.001][:, [0, 1, 2, 3, 5, 4]]  # drops the export's zero padding rows
        elif o.shape[0] > 4 and o.shape[0] < o.shape[1]:  # raw YOLOv8 (4 + nc, N)
            o = o.T
            cls, score = o[:, 4:].argmax(1), o[:, 4:].max(1)
            ok = score >= 0.001
            cx, cy, bw, bh = o[ok, 0], o[ok, 1], o[ok, 2], o[ok, 3]
            boxes = np.column_stack([cx - bw / 2, cy - bh / 2, cx + bw / 2, cy + bh / 2])
            cls, score = cls[ok], score[ok]
            keep: list[int] = []
            for c in np.unique(cls):
                idx = np.flatnonzero(cls == c)
                top = idx[np.argsort(-score[idx], kind="stable")[:3000]]
                keep += [int(top[i]) for i in _nms(boxes[top], score[top], 0.7)]
            keep = sorted(keep, key=lambda i: -score[i])[:300]
            rows = np.column_stack([boxes[keep], cls[keep], score[keep]]) if keep else np.zeros((0, 6))
        else:
            raise PerceptionError(f"{self.path.name} outputs {out.shape}: not a detector (expected 1x(4+C)xN "
                                  "or 1xNx6)")  # fmt: skip
        rows[:, [0, 2]] = np.clip((rows[:, [0, 2]] - px) / r, 0.0, w)
        rows[:, [1, 3]] = np.clip((rows[:, [1, 3]] - py) / r, 0.0, h)
        return rows


def as_detections(out: Any, class_map: dict[int, int]) -> F64:
    """A detector's answer -> (k, 6) [x1, y1, x2, y2, class, score]; PerceptionError when it is not one."""
    from viva_sitl.perception.detect import Detection

    if isinstance(out, list | tuple) and out and all(isinstance(d, Detection) for d in out):
        a = np.array([[*d.box_px, d.class_id, d.confidence] for d in out], np.float64)
    else:
        try:
            a = np.asarray(
                out if not (isinstance(out, list | tuple) and not out) else np.zeros((0, 6)), np.float64
            )
        except (TypeError, ValueError):
            raise PerceptionError(f"the detector returned {type(out).__name__}, not rows [x1, y1, x2, y2, class, "
                                  "score]") from None  # fmt: skip
        if a.size == 0:
            a = np.zeros((0, 6))
    if a.ndim != 2 or a.shape[1] != 6:
        raise PerceptionError(f"the detector returned an array of shape {a.shape}, expected (k, 6) rows [x1, y1, "
                              "x2, y2, class, score] (is it a segmenter?)")  # fmt: skip
    if not np.all(np.isfinite(a)):
        raise PerceptionError("the detector returned a non-finite box or score")
    if np.any(a[:, 2] < a[:, 0]) or np.any(a[:, 3] < a[:, 1]):
        raise PerceptionError("the detector returned a box with x2 < x1 or y2 < y1 (rows are [x1, y1, x2, y2, "
                              "class, score], corners, not centre and size)")  # fmt: skip
    if class_map:
        a = a.copy()
        a[:, 4] = [class_map.get(int(c), int(c)) for c in a[:, 4]]
    return a


def as_levels(out: Any, shape: tuple[int, int]) -> U8:
    try:
        a = np.asarray(out)
    except (TypeError, ValueError):
        raise PerceptionError(f"the segmenter returned {type(out).__name__}, not an HxW level mask") from None
    if a.shape != shape:
        raise PerceptionError(f"the segmenter returned shape {a.shape}, expected the frame's {shape} of levels "
                              "1..5 (is it a detector?)")  # fmt: skip
    if a.dtype.kind not in "iub" or (a.size and (a.min() < 0 or a.max() > 5)):
        raise PerceptionError("the segmenter must return integer levels 0..5 (0: no prediction)")
    return np.asarray(a, np.uint8)


# --- geometry of the ground truth -------------------------------------------------------------------------------


@dataclass(frozen=True)
class GtObjects:
    cls: NDArray[np.int64]
    boxes: F64  # (g, 4) x0, y0, x1, y1 pixel edges
    dist_m: F64  # ground distance of the object's centre from the ground point at the image centre
    size_px: F64  # sqrt(w h) of the box


def _densify(outline: F64, per_edge: int = 8) -> F64:
    nxt = np.roll(outline, -1, axis=0)
    t = np.linspace(0.0, 1.0, per_edge, endpoint=False)[:, None, None]
    return np.asarray(
        (outline[None] + t * (nxt - outline)[None]).transpose(1, 0, 2).reshape(-1, 2), np.float64
    )


def gt_objects(
    world: Any, t_s: float, pos: F64, att: F64, params: CameraParams, min_visible: float
) -> GtObjects:
    """Boxes of the objects present at t (dataset export's geometry; through the lens when params distort)."""
    h_gi = ground_to_image_homography(pos, att, params)
    centre = pixel_to_ground(np.array([[(params.width_px - 1) / 2.0, (params.height_px - 1) / 2.0]]), pos, att,
                             params)[0, :2]  # fmt: skip
    cls, boxes, dist = [], [], []
    for c, outline in ground_rectangles(world, t_s):
        if params.has_distortion:
            q = np.column_stack([_densify(outline), np.ones(len(outline) * 8)]) @ h_gi.T
            if np.any(q[:, 2] <= 1e-9):
                continue
            px = distort_px(q[:, :2] / q[:, 2:3], params).astype(np.float32)
            hull = np.asarray(cv2.convexHull(px), np.float64).reshape(-1, 2)
            got = project_boxes([(c, hull)], np.eye(3), params, min_visible)
        else:
            got = project_boxes([(c, outline)], h_gi, params, min_visible)
        for b in got:
            cls.append(b.object_class)
            boxes.append((b.x0, b.y0, b.x1, b.y1))
            dist.append(
                float(np.hypot(*(outline.mean(axis=0) - centre))) if np.all(np.isfinite(centre)) else math.nan
            )
    bx = np.array(boxes, np.float64).reshape(-1, 4)
    size = np.sqrt(np.maximum(bx[:, 2] - bx[:, 0], 0) * np.maximum(bx[:, 3] - bx[:, 1], 0))
    return GtObjects(np.array(cls, np.int64), bx, np.array(dist, np.float64), size)


def box_iou(a: F64, b: F64) -> F64:
    """(n, m) IoU of boxes x0, y0, x1, y1."""
    if len(a) == 0 or len(b) == 0:
        return np.zeros((len(a), len(b)))
    x0 = np.maximum(a[:, None, 0], b[None, :, 0])
    y0 = np.maximum(a[:, None, 1], b[None, :, 1])
    x1 = np.minimum(a[:, None, 2], b[None, :, 2])
    y1 = np.minimum(a[:, None, 3], b[None, :, 3])
    inter = np.clip(x1 - x0, 0, None) * np.clip(y1 - y0, 0, None)
    area_a = (a[:, 2] - a[:, 0]) * (a[:, 3] - a[:, 1])
    area_b = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
    union = area_a[:, None] + area_b[None, :] - inter
    return np.asarray(np.where(union > 0, inter / np.where(union > 0, union, 1.0), 0.0), np.float64)


# --- detection scoring ------------------------------------------------------------------------------------------


@dataclass
class ClassMatch:
    """One class in one frame: prediction scores, their TP flags per IoU threshold, the ground truth's state."""

    scores: F64
    tp: NDArray[np.bool_]  # (len(IOU_THRESHOLDS), p)
    n_gt: int
    gt_found: NDArray[np.bool_]  # (g,) matched at IoU 0.5 by a prediction of score >= conf
    gt_dist_m: F64
    gt_size_px: F64


def match_class(pred: F64, gt: F64, conf: float) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """COCO greedy matching of one class in one frame. pred (p, 5) [x0, y0, x1, y1, score] sorted by score
    descending; gt (g, 4). Returns (tp (T, p), gt found at IoU 0.5 with score >= conf (g,))."""
    ious = box_iou(pred[:, :4], gt)
    tp = np.zeros((len(IOU_THRESHOLDS), len(pred)), bool)
    found = np.zeros(len(gt), bool)
    for ti, thr in enumerate(IOU_THRESHOLDS):
        taken = np.zeros(len(gt), bool)
        for i in range(len(pred)):
            if not len(gt):
                break
            cand = np.where(taken, -1.0, ious[i])
            j = int(np.argmax(cand))
            if cand[j] >= thr - 1e-12:
                taken[j] = True
                tp[ti, i] = True
                if ti == 0 and pred[i, 4] >= conf:
                    found[j] = True
    return tp, found


def average_precision(scores: F64, tp: NDArray[np.bool_], n_gt: int) -> float | None:
    """COCO 101-point interpolated AP of one class at one IoU threshold; None without ground truth."""
    if n_gt <= 0:
        return None
    if len(scores) == 0:
        return 0.0
    order = np.argsort(-scores, kind="mergesort")
    t = tp[order].astype(np.float64)
    ctp, cfp = np.cumsum(t), np.cumsum(1.0 - t)
    rc = ctp / n_gt
    pr = ctp / np.maximum(ctp + cfp, np.finfo(np.float64).eps)
    pr = np.maximum.accumulate(pr[::-1])[::-1]
    idx = np.searchsorted(rc, np.linspace(0.0, 1.0, 101), side="left")
    q = np.where(idx < len(pr), pr[np.minimum(idx, len(pr) - 1)], 0.0)
    return float(q.mean())


def det_frame(gt: GtObjects, preds: F64, classes: Sequence[int], conf: float) -> dict[int, ClassMatch]:
    preds = preds[np.argsort(-preds[:, 5], kind="stable")][:MAX_DETS] if len(preds) else preds
    out: dict[int, ClassMatch] = {}
    for c in classes:
        p = preds[preds[:, 4] == c] if len(preds) else np.zeros((0, 6))
        sel = gt.cls == c
        g = gt.boxes[sel]
        tp, found = match_class(p[:, [0, 1, 2, 3, 5]], g, conf)
        out[c] = ClassMatch(p[:, 5].copy(), tp, int(sel.sum()), found, gt.dist_m[sel], gt.size_px[sel])
    return out


def det_metrics(frames: Sequence[dict[int, ClassMatch]], classes: Sequence[int], conf: float,
                radius_m: float, groups: dict[str, list[int]]) -> dict[str, float | None]:  # fmt: skip
    """Headline detection metrics of a set of frames (None: unavailable)."""
    aps50, aps = [], []
    tp_c = fp_c = n_gt_all = found_all = 0
    for c in classes:
        ms = [f[c] for f in frames]
        n_gt = sum(m.n_gt for m in ms)
        scores = np.concatenate([m.scores for m in ms]) if ms else np.zeros(0)
        tp = np.concatenate([m.tp for m in ms], axis=1) if ms else np.zeros((len(IOU_THRESHOLDS), 0), bool)
        if n_gt:
            per_t = [average_precision(scores, tp[ti], n_gt) for ti in range(len(IOU_THRESHOLDS))]
            aps50.append(per_t[0])
            aps.append(float(np.mean([v for v in per_t if v is not None])))
        hi = scores >= conf
        tp_c += int(tp[0][hi].sum())
        fp_c += int((~tp[0][hi]).sum())
        n_gt_all += n_gt
        found_all += int(sum(m.gt_found.sum() for m in ms))
    out: dict[str, float | None] = {
        "map50": float(np.mean(aps50)) if aps50 else None,  # type: ignore[arg-type]
        "map50_95": float(np.mean(aps)) if aps else None,
        "precision": tp_c / (tp_c + fp_c) if tp_c + fp_c else None,
        "recall": found_all / n_gt_all if n_gt_all else None,
    }
    for name, cls in groups.items():
        near = found = 0
        sizes: list[F64] = []
        for c in cls:
            for f in frames:
                m = f[c]
                sel = m.gt_dist_m <= radius_m
                near += int(sel.sum())
                found += int(m.gt_found[sel].sum())
                sizes.append(m.gt_size_px)
        allsz = np.concatenate(sizes) if sizes else np.zeros(0)
        out[f"recall_near_{name}"] = found / near if near else None
        out[f"size_px_{name}"] = float(np.median(allsz)) if len(allsz) else None
    for name in ("people", "vehicles"):
        out.setdefault(f"recall_near_{name}", None)
        out.setdefault(f"size_px_{name}", None)
    return out


def det_per_class(frames: Sequence[dict[int, ClassMatch]], available: Sequence[int], conf: float,
                  n_pred: dict[int, int]) -> dict[str, dict[str, Any]]:  # fmt: skip
    from viva_sitl.world import ObjectClass

    out: dict[str, dict[str, Any]] = {}
    for oc in ObjectClass:
        c = int(oc)
        row: dict[str, Any] = {"available": c in available, "n_gt": None, "n_pred": n_pred.get(c, 0),
                               "ap50": None, "ap50_95": None, "precision": None, "recall": None}  # fmt: skip
        if c in available:
            ms = [f[c] for f in frames]
            n_gt = sum(m.n_gt for m in ms)
            scores = np.concatenate([m.scores for m in ms]) if ms else np.zeros(0)
            tp = (
                np.concatenate([m.tp for m in ms], axis=1) if ms else np.zeros((len(IOU_THRESHOLDS), 0), bool)
            )
            per_t = [average_precision(scores, tp[ti], n_gt) for ti in range(len(IOU_THRESHOLDS))]
            hi = scores >= conf
            row.update(n_gt=n_gt, n_pred=len(scores), ap50=per_t[0],
                       ap50_95=float(np.mean(per_t)) if n_gt else None,  # type: ignore[arg-type]
                       precision=float(tp[0][hi].mean()) if hi.any() else None,
                       recall=float(sum(m.gt_found.sum() for m in ms) / n_gt) if n_gt else None)  # fmt: skip
        out[oc.label] = row
    return out


# --- segmentation scoring ---------------------------------------------------------------------------------------


def confusion(pred: U8, truth: U8) -> NDArray[np.int64]:
    """6x6 counts (truth row, prediction column); truth 0 (no footage ground) ignored."""
    keep = truth > 0
    return np.bincount(truth[keep].astype(np.int64) * N_LEVELS + pred[keep].astype(np.int64),
                       minlength=N_LEVELS**2).reshape(N_LEVELS, N_LEVELS)  # fmt: skip


def level_iou(cm: NDArray[np.int64]) -> dict[int, float | None]:
    out: dict[int, float | None] = {}
    for c in range(1, N_LEVELS):
        tp = cm[c, c]
        denom = cm[c, :].sum() + cm[1:, c].sum() - tp
        out[c] = float(tp / denom) if cm[c, :].sum() > 0 else None
    return out


def seg_metrics(cm: NDArray[np.int64]) -> dict[str, float | None]:
    iou = [v for v in level_iou(cm).values() if v is not None]
    danger, landing, total = cm[4:, :].sum(), cm[1:3, :].sum(), cm[1:, :].sum()
    return {
        "miou": float(np.mean(iou)) if iou else None,
        "missed_danger": float(cm[4:, 1:3].sum() / danger) if danger else None,
        "lost_landing": float(cm[1:3, 4:].sum() / landing) if landing else None,
        "pixel_acc": float(np.trace(cm[1:, 1:]) / total) if total else None,
    }


# --- the run ----------------------------------------------------------------------------------------------------


@dataclass
class FrameResult:
    record: dict[str, Any]
    score_key: tuple[float, float]  # sorts worst first
    det: dict[int, ClassMatch] | None = None
    cm: NDArray[np.int64] | None = None
    n_pred: dict[int, int] = field(default_factory=dict)


def _available_classes(world: Any) -> list[int]:
    from viva_sitl.world import PEOPLE, VEHICLES, ObjectClass

    a = world.annotated
    if not world.has_objects:
        return []
    if "all" in a:
        return [int(c) for c in ObjectClass]
    out = set()
    if "person" in a:
        out |= {int(c) for c in PEOPLE}
    if "vehicle" in a:
        out |= {int(c) for c in VEHICLES}
    if "moving object" in a:
        out.add(int(ObjectClass.MOVING))
    return sorted(out)


def _ci(values: list[float | None]) -> tuple[float | None, float | None]:
    v = [x for x in values if x is not None]
    if len(v) < 2:
        return None, None
    lo, hi = np.percentile(np.array(v), [2.5, 97.5])
    return float(lo), float(hi)


def _draw(
    img: U8, gt: GtObjects | None, preds: F64 | None, truth: U8 | None, levels: U8 | None, conf: float
) -> U8:
    """The frame with ground truth (green) and predictions (red, score >= conf) boxes, or masks side by side."""
    from viva_sitl.perception.eval_report import level_colours

    out = img.copy()
    if gt is not None and preds is not None:
        for b in gt.boxes:
            cv2.rectangle(out, (int(b[0]), int(b[1])), (int(math.ceil(b[2])) - 1, int(math.ceil(b[3])) - 1),
                          (0, 255, 0), 1)  # fmt: skip
        for r in preds:
            if r[5] >= conf:
                cv2.rectangle(out, (int(r[0]), int(r[1])), (int(r[2]), int(r[3])), (0, 0, 255), 1)
        return out
    assert truth is not None and levels is not None
    lut = level_colours()
    tr = cv2.addWeighted(out, 0.4, lut[truth], 0.6, 0.0)
    pr = cv2.addWeighted(out, 0.4, lut[levels], 0.6, 0.0)
    return np.asarray(np.hstack([tr, pr]), np.uint8)


@dataclass
class _Footage:
    name: str
    index: int
    world: Any
    available: list[int]
    groups: dict[str, list[int]]


@dataclass
class _Cell:
    info: dict[str, Any]
    footage: _Footage
    frames: list[FrameResult] = field(default_factory=list)


def _open_world(spec: EvalSpec, fi: int, name: str, shared_dir: Path | None) -> _Footage:
    from viva_sitl.footage import open_footage
    from viva_sitl.world import PEOPLE, VEHICLES, world_from_source

    src = open_footage(name, shared_dir=shared_dir)
    try:
        world = world_from_source(src)
    finally:
        src.close()
    available = _available_classes(world)
    if spec.task == "detection" and not available:
        raise PerceptionError(f"footage {name} has no object ground truth (its metadata's `annotated` names no "
                              "class): detection cannot be scored on it")  # fmt: skip
    if spec.task == "segmentation" and not world.has_risk_map:
        raise PerceptionError(f"footage {name} has no risk map ([risk] in its metadata): segmentation cannot "
                              "be scored on it")  # fmt: skip
    groups = {"people": sorted(int(c) for c in PEOPLE if int(c) in available),
              "vehicles": sorted(int(c) for c in VEHICLES if int(c) in available)}  # fmt: skip
    return _Footage(name, fi, world, available, {g: v for g, v in groups.items() if v})


def _poses(spec: EvalSpec, fo: _Footage, params: CameraParams) -> dict[tuple[int, int], list[Any]]:
    """The poses of every (altitude, tilt) of a footage, shared by all its speed x SR cells (paired)."""
    out: dict[tuple[int, int], list[Any]] = {}
    for ai, alt in enumerate(spec.altitudes_m):
        for ti, tilt in enumerate(spec.tilts_deg):
            rng = np.random.default_rng([spec.seed, fo.index, ai, ti])
            es = ExportSpec(footages=(fo.name,), n=spec.n_per_cell, seed=spec.seed, split="footage",
                            poses=PoseRanges(alt_m=(alt, alt), tilt_deg=(tilt, tilt)))  # fmt: skip
            try:
                out[ai, ti] = [
                    p for p, _ in sample_poses(fo.world, es, params, rng, [False] * spec.n_per_cell)
                ]
            except PerceptionError:
                raise PerceptionError(f"at {alt:g} m and {tilt:g} deg tilt the view never fits on {fo.name}'s "
                                      "footage: lower --altitudes or --tilt-deg") from None  # fmt: skip
    return out


def _score(
    spec: EvalSpec, fo: _Footage, out: Any, rec: dict[str, Any], img: U8, pose: Any, params: CameraParams,
    src_map: F64 | None,
) -> tuple[FrameResult, Callable[[], U8]]:  # fmt: skip
    """Score one frame's model answer against its ground truth; (result, a function drawing its overlay)."""
    pos, att = np.array(pose.pos_ned_m), np.array(pose.att_rpy_rad)
    if spec.task == "detection":
        gt = gt_objects(fo.world, pose.time_s, pos, att, params, spec.min_visible)
        preds = as_detections(out, dict(spec.class_map))
        cls_ids, counts = np.unique(preds[:, 4].astype(int), return_counts=True)
        n_pred = {int(c): int(n) for c, n in zip(cls_ids, counts, strict=True)}
        keep = np.isin(gt.cls, fo.available)
        gt = GtObjects(gt.cls[keep], gt.boxes[keep], gt.dist_m[keep], gt.size_px[keep])
        m = det_frame(gt, preds, fo.available, spec.conf)
        n_gt = len(gt.cls)
        found = int(sum(x.gt_found.sum() for x in m.values()))
        fp = int(sum((~x.tp[0][x.scores >= spec.conf]).sum() for x in m.values()))
        score = found / n_gt if n_gt else None
        rec.update(score=score, n_gt=n_gt, found=found, false_pos=fp)
        fr = FrameResult(rec, (1.0 if score is None else score, -fp), det=m, n_pred=n_pred)
        return fr, lambda: _draw(img, gt, preds, None, None, spec.conf)
    truth = risk_mask(fo.world, pos, att, pose.time_s, params, src_map)
    levels = as_levels(out, (int(truth.shape[0]), int(truth.shape[1])))
    cm = confusion(levels, truth)
    sm = seg_metrics(cm)
    rec.update(score=sm["miou"], missed_danger=sm["missed_danger"], lost_landing=sm["lost_landing"])
    fr = FrameResult(rec, (1.0 if sm["miou"] is None else sm["miou"], -(sm["missed_danger"] or 0.0)), cm=cm)
    return fr, lambda: _draw(img, None, None, truth, levels, spec.conf)


def _cell_metrics(spec: EvalSpec, cell: _Cell) -> None:
    """Point values, bootstrap CIs and per-class / per-level tables of a cell, into cell.info."""
    fo, mine, info = cell.footage, cell.frames, cell.info
    rng = np.random.default_rng([spec.seed, 7, int(info["index"])])
    metric: Callable[[Sequence[int]], dict[str, float | None]]
    if spec.task == "detection":
        dets = [f.det for f in mine if f.det is not None]

        def metric(sel: Sequence[int]) -> dict[str, float | None]:
            return det_metrics([dets[i] for i in sel], fo.available, spec.conf, spec.radius_m, fo.groups)

        n_pred: dict[int, int] = {}
        for f in mine:
            for c, k in f.n_pred.items():
                n_pred[c] = n_pred.get(c, 0) + k
        info["per_class"] = det_per_class(dets, fo.available, spec.conf, n_pred)
        names: Sequence[str] = DET_METRICS
    else:
        cms = np.stack([f.cm for f in mine if f.cm is not None])

        def metric(sel: Sequence[int]) -> dict[str, float | None]:
            return seg_metrics(cms[list(sel)].sum(axis=0))

        total_cm = cms.sum(axis=0)
        info["per_level"] = {str(lv): {"n_px": int(total_cm[lv, :].sum()), "iou": v}
                             for lv, v in level_iou(total_cm).items()}  # fmt: skip
        names = SEG_METRICS
    n = len(mine)
    point = metric(range(n))
    boots = [metric(rng.integers(0, n, n).tolist()) for _ in range(spec.bootstrap)] if n > 1 else []
    info["metrics"] = {}
    for name in names:
        lo, hi = _ci([b[name] for b in boots]) if point[name] is not None else (None, None)
        info["metrics"][name] = {"value": point[name], "lo": lo, "hi": hi}


def run_eval(
    spec: EvalSpec, command: Sequence[str] = (), progress: Callable[[int, int], None] | None = None,
    shared_dir: Path | None = None,
) -> tuple[dict[str, Any], list[tuple[str, U8]], dict[str, float]]:  # fmt: skip
    """Evaluate; returns (results.json content, worst frames [(caption, image)], timing {frames, seconds})."""
    from viva_sitl.dynamics import EavState
    from viva_sitl.footage import open_footage
    from viva_sitl.perception.config import SRConfig, SRMethod
    from viva_sitl.perception.sr import magnified_render_from_config
    from viva_sitl.sim import Simulator
    from viva_sitl.world import ObjectClass

    spec.check()
    model = load_model(spec.model, spec.task, spec.imgsz)
    base = CameraParams(width_px=spec.width_px, height_px=spec.height_px)
    params = spec.effects.camera(base)
    src_map = distortion_source_map(params, camera_intrinsics(params)) if params.has_distortion else None
    k_list = camera_intrinsics(params).tolist()
    sr_models = dict(spec.sr_models)
    cells: list[_Cell] = []
    frames: list[FrameResult] = []
    footage_info: dict[str, Any] = {}
    total = (len(spec.footages) * len(spec.altitudes_m) * len(spec.tilts_deg) * len(spec.speeds_m_s)
             * len(spec.sr) * spec.n_per_cell)  # fmt: skip
    worst: list[tuple[tuple[float, float], int, str, U8]] = []
    t0 = time.perf_counter()
    for fi, name in enumerate(spec.footages):
        fo = _open_world(spec, fi, name, shared_dir)
        footage_info[name] = {"classes_available": [ObjectClass(c).label for c in fo.available],
                              "risk_map": bool(fo.world.has_risk_map)}  # fmt: skip
        poses = _poses(spec, fo, base)
        for sr in spec.sr:
            cfg = SRConfig(method=SRMethod(sr), model_path=sr_models.get(sr, ""))
            magnifier = magnified_render_from_config(cfg)
            with Simulator(footage=open_footage(name, shared_dir=shared_dir), camera=params) as sim:
                sim.super_resolution = magnifier
                for ai, alt in enumerate(spec.altitudes_m):
                    for ti, tilt in enumerate(spec.tilts_deg):
                        for speed in spec.speeds_m_s:
                            cell = _Cell({"index": len(cells), "footage": name, "altitude_m": alt,
                                          "tilt_deg": tilt, "speed_m_s": speed, "sr": sr}, fo)  # fmt: skip
                            cells.append(cell)
                            for k, pose in enumerate(poses[ai, ti]):
                                pos, att = np.array(pose.pos_ned_m), np.array(pose.att_rpy_rad)
                                heading = np.random.default_rng([spec.seed, fi, ai, ti, k, 1]).uniform(
                                    0, 2 * math.pi
                                )
                                vel = np.array([speed * math.cos(heading), speed * math.sin(heading), 0.0])
                                sim.camera_rng = np.random.default_rng([spec.seed, fi, ai, ti, k, 2])
                                state = EavState.at_rest(pos, yaw_rad=att[2], roll_rad=att[0], pitch_rad=att[1],
                                                         vel_ned_m_s=vel)  # fmt: skip
                                applied = bool(
                                    magnifier is not None and magnifier.magnified(sim.renderer, pos, att)
                                )
                                frame = sim.render(
                                    dataclasses.replace(state, time_s=pose.time_s), wall_time_s=0.0
                                )
                                img = np.ascontiguousarray(frame.image_bgr)
                                meta = {"footage": name, "pos_ned_m": list(pose.pos_ned_m),
                                        "att_rpy_rad": list(pose.att_rpy_rad), "vel_ned_m_s": vel.tolist(),
                                        "time_s": pose.time_s, "width_px": params.width_px,
                                        "height_px": params.height_px, "intrinsics_k": k_list,
                                        "lens_k1_k2": [params.k1, params.k2]}  # fmt: skip
                                try:
                                    out = model.fn(img, meta)
                                except PerceptionError:
                                    raise
                                except Exception as exc:
                                    raise PerceptionError(
                                        f"the model failed on a frame: {_first_line(exc)}"
                                    ) from None
                                rec: dict[str, Any] = {"id": f"{name}/a{alt:g}/t{tilt:g}/s{speed:g}/{sr}/{k}",
                                                       "cell": cell.info["index"], "k": k, "pos_ned_m": meta["pos_ned_m"],
                                                       "att_rpy_rad": meta["att_rpy_rad"], "vel_ned_m_s": meta["vel_ned_m_s"],
                                                       "time_s": pose.time_s, "sr_applied": applied}  # fmt: skip
                                fr, draw = _score(spec, fo, out, rec, img, pose, params, src_map)
                                cell.frames.append(fr)
                                frames.append(fr)
                                if spec.worst > 0 and (
                                    len(worst) < spec.worst or fr.score_key < worst[-1][0]
                                ):
                                    worst.append((fr.score_key, len(frames) - 1, rec["id"], draw()))
                                    worst.sort(key=lambda w: (w[0], w[1]))
                                    del worst[spec.worst :]
                                if progress is not None:
                                    progress(len(frames), total)
                            cell.info["frames"] = len(cell.frames)
                            cell.info["sr_applied_frames"] = sum(
                                1 for f in cell.frames if f.record["sr_applied"]
                            )
    seconds = time.perf_counter() - t0
    for cell in cells:
        _cell_metrics(spec, cell)
    results = {
        "schema": SCHEMA,
        "version": VERSION,
        "task": spec.task,
        "command": list(command),
        "model": {"spec": spec.model, "kind": model.kind},
        "settings": {
            "footages": list(spec.footages),
            "altitudes_m": list(spec.altitudes_m),
            "tilts_deg": list(spec.tilts_deg),
            "speeds_m_s": list(spec.speeds_m_s),
            "sr": list(spec.sr),
            "effects": spec.effects.as_dict(),
            "n_per_cell": spec.n_per_cell,
            "seed": spec.seed,
            "width_px": spec.width_px,
            "height_px": spec.height_px,
            "conf": spec.conf,
            "radius_m": spec.radius_m,
            "min_visible": spec.min_visible,
            "bootstrap": spec.bootstrap,
            "class_map": {str(a): b for a, b in spec.class_map},
            "imgsz": spec.imgsz,
        },  # fmt: skip
        "footages": footage_info,
        "metrics": list(DET_METRICS if spec.task == "detection" else SEG_METRICS),
        "cells": [c.info for c in cells],
        "frames": [f.record for f in frames],
    }
    worst_images = [(f"{wid} (score {_fmt_score(frames[i].record['score'])})", im) for _, i, wid, im in worst]
    return results, worst_images, {"frames": float(len(frames)), "seconds": seconds}


def _fmt_score(v: float | None) -> str:
    return "n/a" if v is None else f"{v:.3f}"


# --- output -----------------------------------------------------------------------------------------------------


def write_csv(results: dict[str, Any], path: Path) -> None:
    import csv

    det = results["task"] == "detection"
    extra: list[str] = []
    if results["cells"]:
        first = results["cells"][0]
        if det:
            for label in first["per_class"]:
                extra += [f"ap50_{label}", f"recall_{label}"]
        else:
            extra += [f"iou_level{lv}" for lv in first["per_level"]]
    head = ["footage", "altitude_m", "tilt_deg", "speed_m_s", "sr", "frames"]
    for m in results["metrics"]:
        head += [m, f"{m}_lo", f"{m}_hi"]
    with path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(head + extra)
        for c in results["cells"]:
            row: list[Any] = [
                c["footage"],
                c["altitude_m"],
                c["tilt_deg"],
                c["speed_m_s"],
                c["sr"],
                c["frames"],
            ]
            for m in results["metrics"]:
                v = c["metrics"][m]
                row += ["" if v[k] is None else f"{v[k]:.6g}" for k in ("value", "lo", "hi")]
            if det:
                for r in c["per_class"].values():
                    row += ["" if r[k] is None else f"{r[k]:.6g}" for k in ("ap50", "recall")]
            else:
                row += ["" if r["iou"] is None else f"{r['iou']:.6g}" for r in c["per_level"].values()]
            w.writerow(row)


def write_outputs(
    out_dir: Path, results: dict[str, Any], worst: list[tuple[str, U8]], timing: dict[str, float]
) -> None:
    from viva_sitl.perception.eval_report import build_html

    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "results.json").write_text(json.dumps(results, indent=1, allow_nan=False) + "\n")
    write_csv(results, out_dir / "cells.csv")
    (out_dir / "report.html").write_text(build_html(results, worst, timing))


def iter_cells(results: dict[str, Any]) -> Iterator[dict[str, Any]]:
    yield from results["cells"]


def load_results(path: Path) -> dict[str, Any]:
    """An evaluation's results.json (a directory or the file); PerceptionError when it is not one."""
    p = Path(path)
    if p.is_dir():
        p = p / "results.json"
    if not p.is_file():
        raise PerceptionError(f"no results.json at {path} (an output directory of `perception eval`)")
    try:
        r = json.loads(p.read_text())
    except (OSError, ValueError) as exc:
        raise PerceptionError(f"{p} is not readable JSON: {_first_line(exc)}") from None
    if not isinstance(r, dict) or r.get("schema") != SCHEMA:
        raise PerceptionError(f"{p} is not a perception-eval results file")
    if r.get("version") != VERSION:
        raise PerceptionError(f"{p} has results version {r.get('version')}, this viva-sitl reads {VERSION}")
    return r


# --- CLI --------------------------------------------------------------------------------------------------------


def add_eval_arguments(p: Any) -> None:
    """The arguments of `viva-sitl perception eval` (parsed in perception/cli.py)."""
    m = p.add_mutually_exclusive_group(required=True)
    m.add_argument("--detector", metavar="W", help="detector: .pt (ultralytics), .onnx, or module:factory")
    m.add_argument(
        "--segmenter", metavar="W", help="risk segmenter: .pt (our U-Net), .onnx, or module:factory"
    )
    m.add_argument(
        "--compare", nargs=2, metavar=("OUT_A", "OUT_B"), help="paired differences of two evaluations"
    )
    p.add_argument("--footage", default="", help="catalog name(s) or path(s), comma-separated")
    p.add_argument(
        "--altitudes", default="10:120:10", help="m: START:STOP:STEP or a list (default 10:120:10)"
    )
    p.add_argument("--tilt-deg", default="0", help="camera tilts off nadir, deg (list or START:STOP:STEP)")
    p.add_argument("--speed-m-s", default="0", help="vehicle speeds (motion blur with --effects blur)")
    p.add_argument("--sr", default="none", help="super-resolution methods: none,bicubic,fsrcnn,espcn,edsr")
    p.add_argument("--sr-model", action="append", default=[], metavar="METHOD=PATH",
                   help="model file of an SR method (fsrcnn/espcn .pb, edsr .pt); repeatable")  # fmt: skip
    p.add_argument("--effects", default="", help="camera effects: blur,noise,distortion (default none)")
    p.add_argument("--exposure-s", type=float, default=0.02, help="exposure for blur (s)")
    p.add_argument("--noise-std", type=float, default=3.0, help="sensor noise (8-bit levels)")
    p.add_argument("--k1", type=float, default=-0.1, help="radial distortion k1 for --effects distortion")
    p.add_argument("--n-per-cell", type=int, default=8, help="frames per cell (and footage)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--size", default="640x480", help="VAC size WxH")
    p.add_argument("--conf", type=float, default=0.25, help="detector score threshold for precision/recall")
    p.add_argument("--radius-m", type=float, default=10.0, help="near-centre radius of the safety recall (m)")
    p.add_argument("--imgsz", type=int, default=640,
                   help="inference size of an ultralytics .pt detector (its training size; ONNX: its input)")  # fmt: skip
    p.add_argument("--class-map", default="", help="model class id -> ObjectClass id, e.g. 0=2,1=0")
    p.add_argument("--bootstrap", type=int, default=200, help="bootstrap resamples for the CIs (0: none)")
    p.add_argument("--worst", type=int, default=8, help="worst frames shown in the report")
    p.add_argument("-o", "--output", required=True, help="new (or empty) output directory")


def _pairs(text: str, what: str) -> list[tuple[str, str]]:
    out = []
    for part in filter(None, (t.strip() for t in text.split(","))):
        a, sep, b = part.partition("=")
        if not sep or not a.strip() or not b.strip():
            raise PerceptionError(f"{what} items must be KEY=VALUE, got {part!r}")
        out.append((a.strip(), b.strip()))
    return out


def eval_cli(args: Any, argv: Sequence[str] = ()) -> int:
    """`viva-sitl perception eval` (arguments from `add_eval_arguments`)."""
    from tqdm import tqdm

    from viva_sitl.perception.eval_report import compare, compare_html

    out_dir = Path(args.output)
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise PerceptionError(f"output directory {out_dir} is not empty (choose a new -o)")
    if args.compare:
        diff = compare(load_results(Path(args.compare[0])), load_results(Path(args.compare[1])))
        out_dir.mkdir(parents=True, exist_ok=True)
        (out_dir / "compare.json").write_text(json.dumps(diff, indent=1, allow_nan=False) + "\n")
        (out_dir / "report.html").write_text(compare_html(diff))
        print(f"wrote {out_dir}/compare.json and report.html ({len(diff['cells'])} paired cells)")
        return 0
    footages = tuple(f.strip() for f in args.footage.split(",") if f.strip())
    if not footages:
        raise PerceptionError("--footage is required (catalog names or paths, comma-separated)")
    try:
        w, h = (int(v) for v in args.size.lower().split("x"))
        CameraParams(width_px=w, height_px=h)
    except ValueError:
        raise PerceptionError(f"--size must be WxH (positive), got {args.size!r}") from None
    try:
        class_map = tuple((int(a), int(b)) for a, b in _pairs(args.class_map, "--class-map"))
    except ValueError:
        raise PerceptionError(f"--class-map must map integer ids, got {args.class_map!r}") from None
    spec = EvalSpec(
        task="detection" if args.detector else "segmentation",
        model=args.detector or args.segmenter,
        footages=footages,
        altitudes_m=parse_values(args.altitudes, "--altitudes"),
        tilts_deg=parse_values(args.tilt_deg, "--tilt-deg"),
        speeds_m_s=parse_values(args.speed_m_s, "--speed-m-s"),
        sr=tuple(s.strip().lower() for s in args.sr.split(",") if s.strip()) or ("none",),
        sr_models=tuple(_pairs(",".join(args.sr_model), "--sr-model")),
        effects=EffectSpec.parse(args.effects, args.exposure_s, args.noise_std, args.k1),
        n_per_cell=args.n_per_cell, seed=args.seed, width_px=w, height_px=h, conf=args.conf,
        radius_m=args.radius_m, bootstrap=args.bootstrap, class_map=class_map, worst=args.worst, imgsz=args.imgsz,
    )  # fmt: skip
    spec.check()
    n = (len(spec.footages) * len(spec.altitudes_m) * len(spec.tilts_deg) * len(spec.speeds_m_s) * len(spec.sr)
         * spec.n_per_cell)  # fmt: skip
    command = ["viva-sitl", "perception", *argv]
    with tqdm(total=n, unit="frame", disable=None) as bar:
        results, worst, timing = run_eval(spec, command, lambda done, total: bar.update(1))
    write_outputs(out_dir, results, worst, timing)
    fps = timing["frames"] / timing["seconds"] if timing["seconds"] > 0 else math.nan
    head = results["metrics"][:2]
    summary = ", ".join(
        f"{m} {np.mean(vals):.3f}" if (vals := [c['metrics'][m]['value'] for c in results['cells']
                                                if c['metrics'][m]['value'] is not None]) else f"{m} n/a"
        for m in head
    )  # fmt: skip
    print(f"wrote {out_dir}/results.json, cells.csv, report.html ({len(results['cells'])} cells, "
          f"{int(timing['frames'])} frames, {fps:.2f} frames/s; mean over cells: {summary})")  # fmt: skip
    return 0
