"""`viva-sitl perception eval` (issue 23): detection and risk segmentation scored on real VAC renders of the synthetic
field (and a Songdo still where ../shared has it) against the footage's ground truth. The models are oracles from
tests/perception_oracles.py that answer through `dataset export`'s label geometry, so every expected score is exact:
perfect = 1, nothing = 0, a known pixel shift fails exactly the boxes whose IoU falls below the threshold."""

from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import perception_oracles as oracles
import pytest
from conftest import SHARED_DIR

from viva_sitl.camera import CameraParams
from viva_sitl.camera.effects import distortion_source_map
from viva_sitl.camera.projection import camera_intrinsics
from viva_sitl.perception import PerceptionError
from viva_sitl.perception.cli import perception_main
from viva_sitl.perception.effects import EffectSpec, distort_px
from viva_sitl.perception.eval_report import compare
from viva_sitl.perception.evaluate import (
    EvalSpec,
    average_precision,
    load_results,
    parse_values,
    run_eval,
    write_outputs,
)

REPO = Path(__file__).resolve().parents[1]
TESTS = Path(__file__).resolve().parent
SMALL = {
    "footages": ("synthetic",),
    "altitudes_m": (20.0, 45.0),
    "n_per_cell": 3,
    "bootstrap": 20,
    "worst": 2,
}


def _run(model: str, task: str = "detection", **kw: Any) -> dict[str, Any]:
    spec = EvalSpec(task=task, model=f"perception_oracles:{model}", **{**SMALL, **kw})
    return run_eval(spec)[0]


def _values(r: dict[str, Any], metric: str) -> list[Any]:
    return [c["metrics"][metric]["value"] for c in r["cells"]]


def test_ground_truth_detector_scores_one_and_unannotated_is_null() -> None:
    r = _run("gt_detector")
    assert r["schema"] == "viva-sitl/perception-eval" and r["version"] == 1
    assert sum(f["n_gt"] for f in r["frames"]) > 10  # real objects in view
    for m in ("map50", "map50_95", "precision", "recall"):
        assert _values(r, m) == [1.0, 1.0], m
    for c in r["cells"]:
        assert c["metrics"]["map50"]["lo"] == 1.0 and c["metrics"]["map50"]["hi"] == 1.0
        bus = c["per_class"][
            "bus"
        ]  # the synthetic field annotates everything but has no bus: no AP, never 0/1
        assert bus["available"] and bus["n_gt"] == 0 and bus["ap50"] is None and bus["recall"] is None
        assert c["per_class"]["person"]["ap50"] == 1.0


def test_empty_detector_scores_zero() -> None:
    r = _run("empty_detector")
    assert _values(r, "map50") == [0.0, 0.0] and _values(r, "map50_95") == [0.0, 0.0]
    assert _values(r, "recall") == [0.0, 0.0]
    assert _values(r, "precision") == [None, None]  # no prediction: precision is undefined, not 0 or 1
    assert all(f["score"] == 0.0 for f in r["frames"] if f["n_gt"])


def test_pixel_shift_fails_exactly_the_boxes_below_the_iou_threshold() -> None:
    r = _run("shifted_detector", altitudes_m=(20.0, 60.0))
    d = oracles.SHIFT_PX
    n_expected = 0
    for f in r["frames"]:
        meta = {**f, "footage": "synthetic", "width_px": 640, "height_px": 480}
        rows = oracles.truth_rows(meta)
        w = rows[:, 2] - rows[:, 0]
        iou = (w - d) / (w + d)  # same height, moved sideways by d
        expect = int((iou >= 0.5).sum())
        assert f["n_gt"] == len(rows) and f["found"] == expect, (f["id"], iou)
        n_expected += expect
    assert 0 < n_expected < sum(f["n_gt"] for f in r["frames"])  # some boxes pass, some fail: the test bites


def test_shift_by_a_fifth_of_the_width_passes_iou_thresholds_up_to_two_thirds() -> None:
    r = _run("fraction_shifted_detector")  # IoU = 0.8 / 1.2 = 2/3 for every box: 0.50..0.65 pass, 0.70.. fail
    assert _values(r, "map50") == [1.0, 1.0]
    assert _values(r, "map50_95") == pytest.approx([0.4, 0.4], abs=1e-12)


def test_ground_truth_segmenter_scores_one_and_all_safe_misses_all_danger() -> None:
    r = _run("gt_segmenter", task="segmentation")
    assert _values(r, "miou") == [1.0, 1.0] and _values(r, "pixel_acc") == [1.0, 1.0]
    assert _values(r, "missed_danger") == [0.0, 0.0] and _values(r, "lost_landing") == [0.0, 0.0]
    bad = _run("all_safe_segmenter", task="segmentation")
    assert _values(bad, "missed_danger") == [1.0, 1.0]  # the synthetic field's roads are level 4+
    assert _values(bad, "lost_landing") == [0.0, 0.0]
    assert all(v is not None and v < 0.5 for v in _values(bad, "miou"))


def test_effects_are_seeded_and_the_ground_truth_follows_the_lens(tmp_path: Path) -> None:
    fx = EffectSpec.parse("blur,noise,distortion", exposure_s=0.05)
    kw = {"effects": fx, "speeds_m_s": (0.0, 10.0), "altitudes_m": (20.0,), "n_per_cell": 2, "width_px": 320,
          "height_px": 240}  # fmt: skip
    lens = _run("lens_gt_segmenter", task="segmentation", **kw)
    assert _values(lens, "miou") == [1.0, 1.0]  # a model that knows the lens is perfect through it
    pinhole = _run("gt_segmenter", task="segmentation", **kw)
    assert all(v < 0.99 for v in _values(pinhole, "miou"))  # the mask moved with the distortion
    spec = EvalSpec(task="detection", model="perception_oracles:gt_detector", **{**SMALL, **kw})
    for out in ("a", "b"):
        write_outputs(tmp_path / out, *run_eval(spec, ["viva-sitl", "perception", "eval"]))
    a, b = ((tmp_path / o / "results.json").read_bytes() for o in ("a", "b"))
    assert a == b  # same seed: byte-identical
    write_outputs(tmp_path / "c", *run_eval(replace(spec, seed=1)))
    assert (tmp_path / "c" / "results.json").read_bytes() != a
    r = json.loads(a)
    assert r["settings"]["effects"]["names"] == ["blur", "noise", "distortion"]
    html = (tmp_path / "a" / "report.html").read_text()
    assert "<svg" in html and "data:image/jpeg;base64," in html and "viva-sitl perception eval" in html
    csv = (tmp_path / "a" / "cells.csv").read_text().splitlines()
    assert len(csv) == 1 + len(r["cells"]) and csv[0].startswith("footage,altitude_m,tilt_deg,speed_m_s,sr")


def test_distort_px_inverts_the_renderers_lens_map() -> None:
    p = CameraParams(width_px=160, height_px=120, k1=-0.2, k2=0.05)
    src = distortion_source_map(p, camera_intrinsics(p))
    vv, uu = np.mgrid[0:120:7, 0:160:9]
    back = distort_px(src[vv, uu].reshape(-1, 2), p)
    assert np.allclose(back, np.column_stack([uu.ravel(), vv.ravel()]), atol=1e-3)


def test_average_precision_reference_values() -> None:
    tp = np.array([True, False, True])
    # precision 1, 1/2, 2/3 at recall 1/2, 1/2, 1 -> interpolated 1 up to r = 0.5, then 2/3 (COCO 101 points)
    ap = average_precision(np.array([0.9, 0.8, 0.7]), tp, 2)
    assert ap == pytest.approx((51 * 1.0 + 50 * 2.0 / 3.0) / 101)
    assert average_precision(np.zeros(0), np.zeros(0, bool), 3) == 0.0
    assert average_precision(np.zeros(0), np.zeros(0, bool), 0) is None


def test_compare_gives_paired_differences(tmp_path: Path) -> None:
    spec = EvalSpec(task="detection", model="perception_oracles:gt_detector", **SMALL)
    write_outputs(tmp_path / "a", *run_eval(spec))
    write_outputs(tmp_path / "b", *run_eval(replace(spec, model="perception_oracles:empty_detector")))
    d = compare(load_results(tmp_path / "a"), load_results(tmp_path / "b"))
    assert [c["diff"]["map50"]["value"] for c in d["cells"]] == [-1.0, -1.0]
    fs = [c["diff"]["frame_score"] for c in d["cells"]]
    assert all(f["value"] == -1.0 for f in fs) and sum(f["pairs"] for f in fs) >= 3  # frames with objects
    seg = EvalSpec(task="segmentation", model="perception_oracles:gt_segmenter", **SMALL)
    write_outputs(tmp_path / "s", *run_eval(seg))
    with pytest.raises(PerceptionError, match="cannot compare a detection"):
        compare(load_results(tmp_path / "a"), load_results(tmp_path / "s"))


def test_parse_values() -> None:
    assert parse_values("10:120:10", "--altitudes") == tuple(float(a) for a in range(10, 121, 10))
    assert parse_values("0,15", "--tilt-deg") == (0.0, 15.0)
    with pytest.raises(PerceptionError, match="START:STOP:STEP"):
        parse_values("10:5:1", "--altitudes")


@pytest.mark.skipif(not (SHARED_DIR / "footage" / "songdo" / "00003.jpg").is_file(), reason="needs ../shared")
def test_songdo_still_people_are_unavailable_vehicles_scored() -> None:
    r = _run("gt_detector", footages=("songdo-00003",), altitudes_m=(30.0,), n_per_cell=2)
    c = r["cells"][0]
    assert r["footages"]["songdo-00003"]["classes_available"] == ["car", "bus", "truck"]
    assert c["per_class"]["person"] == {"available": False, "n_gt": None, "n_pred": 0, "ap50": None,
                                        "ap50_95": None, "precision": None, "recall": None}  # fmt: skip
    assert c["metrics"]["recall_near_people"]["value"] is None and c["metrics"]["map50"]["value"] == 1.0


def _cli(args: list[str], tmp_path: Path) -> subprocess.CompletedProcess[str]:
    env = {"PYTHONPATH": str(TESTS), "PATH": "/usr/bin:/bin", "HOME": str(tmp_path)}
    return subprocess.run([sys.executable, "-m", "viva_sitl.cli", "perception", "eval", *args], cwd=REPO, env=env,
                          capture_output=True, text=True, timeout=300)  # fmt: skip


def test_cli_bad_inputs_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    still = tmp_path / "plain.png"
    import cv2

    cv2.imwrite(str(still), np.full((300, 400, 3), 90, np.uint8))
    (tmp_path / "garbage.pt").write_bytes(
        b"not a checkpoint"
    )  # no torch: needs PyTorch; torch: not a checkpoint
    small = ["--altitudes", "20", "--n-per-cell", "1"]
    cases = {
        "detector weights not found": ["--detector", str(tmp_path / "nope.onnx"), "--footage", "synthetic"],
        "expected (k, 6) rows": ["--detector", "perception_oracles:gt_segmenter", "--footage", "synthetic"],
        "expected the frame's (480, 640)": [
            "--segmenter",
            "perception_oracles:gt_detector",
            "--footage",
            "synthetic",
        ],
        "has no object ground truth": [
            "--detector",
            "perception_oracles:gt_detector",
            "--footage",
            str(still),
        ],
        "has no risk map": ["--segmenter", "perception_oracles:gt_segmenter", "--footage", str(still)],
        "failed: weights file corrupt": [
            "--detector",
            "perception_oracles:broken_factory",
            "--footage",
            "synthetic",
        ],
        "garbage.pt": ["--segmenter", str(tmp_path / "garbage.pt"), "--footage", "synthetic"],
        "--imgsz must be in [32, 4096] px": [
            "--detector",
            "perception_oracles:gt_detector",
            "--footage",
            "synthetic",
            "--imgsz",
            "0",
        ],
        "unknown effect 'fog'": [
            "--detector",
            "perception_oracles:gt_detector",
            "--footage",
            "synthetic",
            "--effects",
            "fog",
        ],  # fmt: skip
    }
    for i, (msg, args) in enumerate(cases.items()):
        if i == 0:  # a real process once: exit status, nothing but the line on stderr
            r = _cli([*args, *small, "-o", str(tmp_path / f"o{i}")], tmp_path)
            rc, stderr = r.returncode, r.stderr
        else:  # the same entry point in-process (a process start costs seconds on this machine)
            rc = perception_main(["eval", *args, *small, "-o", str(tmp_path / f"o{i}")])
            stderr = capsys.readouterr().err
        lines = stderr.strip().splitlines()
        err = lines[-1] if lines else ""
        assert rc == 2 and "Traceback" not in stderr, (msg, stderr)
        # one error line (a plain image's footage loader may warn first that it assumes a recording scale)
        assert all("viva-sitl perception eval" not in ln for ln in lines[:-1]), stderr
        assert msg in err and err.startswith("viva-sitl perception eval: "), (msg, err)


@pytest.mark.slow
def test_cli_writes_the_outputs(tmp_path: Path) -> None:
    out = tmp_path / "out"
    r = _cli(["--detector", "perception_oracles:gt_detector", "--footage", "synthetic", "--altitudes", "20:40:20",
              "--tilt-deg", "0,15", "--speed-m-s", "0,5", "--effects", "blur,noise", "--n-per-cell", "2",
              "-o", str(out)], tmp_path)  # fmt: skip
    assert r.returncode == 0, r.stderr
    res = json.loads((out / "results.json").read_text())
    vals = _values(res, "map50")  # None: no object in that cell's two views (unavailable, not 0 or 1)
    assert len(res["cells"]) == 2 * 2 * 2 and set(vals) <= {1.0, None} and vals.count(1.0) >= 4
    assert res["command"][:4] == ["viva-sitl", "perception", "eval", "--detector"]
    r = _cli(["--compare", str(out), str(out), "-o", str(tmp_path / "cmp")], tmp_path)
    assert r.returncode == 0, r.stderr
    d = json.loads((tmp_path / "cmp" / "compare.json").read_text())
    assert {c["diff"]["map50"]["value"] for c in d["cells"]} <= {0.0, None}


def test_average_precision_matches_pycocotools() -> None:
    """Our COCO-style AP against the reference implementation on random frames (skipped without pycocotools)."""
    pytest.importorskip("pycocotools", reason="the cross-check needs pycocotools (not a dependency)")
    from pycocotools.coco import COCO
    from pycocotools.cocoeval import COCOeval

    from viva_sitl.perception.evaluate import GtObjects, det_frame, det_metrics

    rng = np.random.default_rng(3)
    images, anns, dets, frames = [], [], [], []
    for i in range(12):
        g = int(rng.integers(0, 6))
        xy = rng.uniform(0, 500, (g, 2))
        wh = rng.uniform(8, 60, (g, 2))
        gt_boxes = np.column_stack([xy, xy + wh])
        gt_cls = rng.integers(0, 2, g)
        # predictions: jittered copies of some ground truth plus clutter, random scores
        keep = rng.random(g) < 0.8
        jit = gt_boxes[keep] + rng.normal(0, 4, (int(keep.sum()), 4))
        clutter_xy = rng.uniform(0, 500, (3, 2))
        clutter = np.column_stack([clutter_xy, clutter_xy + rng.uniform(8, 60, (3, 2))])
        pb = np.vstack([jit, clutter])
        pc = np.concatenate([gt_cls[keep], rng.integers(0, 2, 3)])
        ps = rng.uniform(0.05, 1.0, len(pb))
        preds = np.column_stack([pb, pc, ps])
        images.append({"id": i, "width": 640, "height": 640})
        for b, c in zip(gt_boxes, gt_cls, strict=True):
            w, h = b[2] - b[0], b[3] - b[1]
            anns.append({"id": len(anns) + 1, "image_id": i, "category_id": int(c), "iscrowd": 0,
                         "bbox": [b[0], b[1], w, h], "area": w * h})  # fmt: skip
        for r in preds:
            dets.append({"image_id": i, "category_id": int(r[4]), "score": float(r[5]),
                         "bbox": [r[0], r[1], r[2] - r[0], r[3] - r[1]]})  # fmt: skip
        gt = GtObjects(gt_cls.astype(np.int64), gt_boxes, np.zeros(g), np.zeros(g))
        frames.append(det_frame(gt, preds, [0, 1], 0.25))
    coco = COCO()
    coco.dataset = {"images": images, "annotations": anns, "categories": [{"id": 0}, {"id": 1}]}
    coco.createIndex()
    ev = COCOeval(coco, coco.loadRes(dets), "bbox")
    ev.evaluate()
    ev.accumulate()
    ev.summarize()
    ours = det_metrics(frames, [0, 1], 0.25, 10.0, {})
    assert ours["map50_95"] == pytest.approx(ev.stats[0], abs=1e-9)
    assert ours["map50"] == pytest.approx(ev.stats[1], abs=1e-9)


def _onnx_model(
    path: Path,
    out: np.ndarray | None = None,
    bias: list[float] | None = None,
    hw: tuple[int, int] = (480, 640),
) -> None:
    """A tiny ONNX model on a 1x3x480x640 input: a constant output (detector) or a 1x1 conv whose bias picks the
    level (segmenter)."""
    onnx = pytest.importorskip("onnx", reason="building an ONNX model needs onnx (extra perception-onnx)")
    from onnx import TensorProto, helper, numpy_helper

    x = helper.make_tensor_value_info("images", TensorProto.FLOAT, [1, 3, *hw])
    if out is not None:  # detector: output = out + 0 * sum(input)
        nodes = [helper.make_node("ReduceSum", ["images"], ["s"], keepdims=0),
                 helper.make_node("Mul", ["s", "zero"], ["z"]), helper.make_node("Add", ["c", "z"], ["output0"])]  # fmt: skip
        inits = [numpy_helper.from_array(out.astype(np.float32), "c"),
                 numpy_helper.from_array(np.array(0.0, np.float32), "zero")]  # fmt: skip
        y = helper.make_tensor_value_info("output0", TensorProto.FLOAT, list(out.shape))
    else:
        assert bias is not None
        nodes = [helper.make_node("Conv", ["images", "w", "b"], ["output0"])]
        inits = [numpy_helper.from_array(np.zeros((len(bias), 3, 1, 1), np.float32), "w"),
                 numpy_helper.from_array(np.array(bias, np.float32), "b")]  # fmt: skip
        y = helper.make_tensor_value_info("output0", TensorProto.FLOAT, [1, len(bias), 480, 640])
    model = helper.make_model(
        helper.make_graph(nodes, "t", [x], [y], inits), opset_imports=[helper.make_opsetid("", 17)]
    )
    onnx.save(model, str(path))


def test_onnx_models_run_without_torch(tmp_path: Path) -> None:
    pytest.importorskip("onnxruntime", reason="ONNX inference needs onnxruntime (extra perception-onnx)")
    # segmenter: 6 channels, the bias makes level 1 win everywhere: scored as the all-safe callable is
    _onnx_model(tmp_path / "seg.onnx", bias=[9.0, 5.0, 0.0, 0.0, 0.0, 0.0])
    small = {**SMALL, "altitudes_m": (30.0,)}
    spec = EvalSpec(task="segmentation", model=str(tmp_path / "seg.onnx"), **small)
    onnx_r = run_eval(spec)[0]
    assert onnx_r["model"]["kind"] == "onnx"
    ref = run_eval(replace(spec, model="perception_oracles:all_safe_segmenter"))[0]
    assert [c["metrics"] for c in onnx_r["cells"]] == [c["metrics"] for c in ref["cells"]]
    # detector, raw YOLOv8 layout (1, 4 + 7 classes, N): one person box at (90..110, 90..110) of score 0.9
    raw = np.zeros((1, 11, 20), np.float32)  # N > 4 + classes, as in any real export (8400 at 640)
    raw[0, :4, 0] = [100, 100, 20, 20]
    raw[0, 4, 0] = 0.9
    # ... and the (1, N, 6) nms layout [x1, y1, x2, y2, score, class]: the same box
    nms = np.zeros((1, 3, 6), np.float32)
    nms[0, 0] = [90, 90, 110, 110, 0.9, 0]
    for name, out in (("raw", raw), ("nms", nms)):
        _onnx_model(tmp_path / f"{name}.onnx", out=out)
        r = run_eval(EvalSpec(task="detection", model=str(tmp_path / f"{name}.onnx"), **small))[0]
        for f in r["frames"]:  # the fixed box hits nothing real: one false positive per frame
            assert f["false_pos"] == 1 and f["found"] == 0, (name, f)
        assert {c["per_class"]["person"]["n_pred"] for c in r["cells"]} == {small["n_per_cell"]}
    (tmp_path / "bad.onnx").write_bytes(b"not onnx")
    with pytest.raises(PerceptionError, match="is not a loadable ONNX model"):
        run_eval(EvalSpec(task="detection", model=str(tmp_path / "bad.onnx"), **small))
    with pytest.raises(PerceptionError, match="not a segmenter"):
        run_eval(EvalSpec(task="segmentation", model=str(tmp_path / "raw.onnx"), **small))


def test_blur_follows_the_speed_and_noise_is_added() -> None:
    """The effects reach the evaluated frames: the same poses blurred at 10 m/s are softer than at rest, noisy ones
    sharper (higher Laplacian variance) than clean ones."""
    kw = {"altitudes_m": (10.0,), "n_per_cell": 2, "bootstrap": 0}
    oracles.SHARPNESS.clear()
    run_eval(EvalSpec("detection", "perception_oracles:sharpness_probe", speeds_m_s=(0.0, 10.0),
                      effects=EffectSpec.parse("blur"), **kw))  # fmt: skip
    still, moving = oracles.SHARPNESS[:2], oracles.SHARPNESS[2:]
    assert [s for s, _ in still] == [0.0, 0.0] and [s for s, _ in moving] == pytest.approx([10.0, 10.0])
    assert all(m[1] < 0.5 * s[1] for s, m in zip(still, moving, strict=True))
    oracles.SHARPNESS.clear()
    run_eval(
        EvalSpec("detection", "perception_oracles:sharpness_probe", effects=EffectSpec.parse("noise"), **kw)
    )
    assert all(n[1] > 2.0 * s[1] for s, n in zip(still, oracles.SHARPNESS, strict=True))


def test_detector_answers_are_checked_and_class_ids_renamed() -> None:
    from viva_sitl.perception.detect import Detection
    from viva_sitl.perception.evaluate import as_detections, as_levels

    rows = as_detections([[1, 2, 5, 6, 0, 0.9]], {0: 2})
    assert rows.tolist() == [[1, 2, 5, 6, 2, 0.9]]  # a one-class vehicle model's 0 -> car
    assert as_detections([Detection(4, "truck", 0.5, (0, 0, 3, 3))], {}).tolist() == [[0, 0, 3, 3, 4, 0.5]]
    assert as_detections([], {}).shape == (0, 6)
    with pytest.raises(PerceptionError, match="x2 < x1"):
        as_detections([[10, 10, 4, 4, 0, 0.9]], {})
    with pytest.raises(PerceptionError, match="non-finite"):
        as_detections([[0, 0, 4, 4, 0, float("nan")]], {})
    with pytest.raises(PerceptionError, match="integer levels 0..5"):
        as_levels(np.full((4, 4), 7, np.uint8), (4, 4))


def test_onnx_detector_sees_the_frame_letterboxed_as_ultralytics_does(tmp_path: Path) -> None:
    # a 480x480 export (ultralytics `export imgsz=480`) on a 640x480 frame: scaled by 3/4 to 480x360, 60 px grey bars
    # above and below; a box the model reports at input (90..110, 150..170) is the frame's (120..146.7, 120..146.7),
    # not the stretched (120..146.7, 150..170) that squashed every object by 3/4 before
    pytest.importorskip("onnxruntime", reason="ONNX inference needs onnxruntime (extra perception-onnx)")
    from viva_sitl.perception.evaluate import OnnxModel

    nms = np.zeros((1, 3, 6), np.float32)
    nms[0, 0] = [90, 150, 110, 170, 0.9, 0]
    _onnx_model(tmp_path / "sq.onnx", out=nms, hw=(480, 480))
    rows = OnnxModel(tmp_path / "sq.onnx", "detection")(np.zeros((480, 640, 3), np.uint8))
    assert rows.shape == (1, 6)
    np.testing.assert_allclose(rows[0], [120, 120, 110 / 0.75, 110 / 0.75, 0, 0.9], rtol=1e-5)
