"""Perception benchmarks: super-resolution, risk segmentation, detection (quality on held-out ground, ms per frame).

    python bench/bench_perception.py sr  [--edsr-steps 200] [--out FILE]       (torch for EDSR: extra perception)
    python bench/bench_perception.py seg [--epochs 15] [--data DIR] [--out FILE]   (extra perception)
    python bench/bench_perception.py det [--epochs 15] [--imgsz 320] [--data DIR] [--out FILE]  (perception-yolo)
    python bench/bench_perception.py seg-synth --data DIR --weights FILE [--time-limit-min 50]  (extra perception)
    python bench/bench_perception.py det-synth --data DIR --weights FILE [--imgsz 480] [--time-limit-min 50]

seg-synth / det-synth: the synthetic field (exact ground truth), region split (val = ground east of the cut). They
export the dataset into --data unless it is there (the same export as `viva-sitl dataset export --footage synthetic
--n 2400 --seed 1` / `--n 800 --seed 2 --val 0.4 --poses alt=10:30,tilt=0:15`), train with the recipe (time-budgeted) unless
--weights names an existing checkpoint, then report held-out mIoU + per-level IoU vs the majority level / mAP50 (+
per class), ms per 640x480 frame and the load average.

seg / det: a Songdo dataset exported by `export_dataset` (footage split: train on stills 00003 + 00972, validate on
03936, so validation never sees training ground), `--n` VAC images per still at alt 15..40 m, tilt 0..10 deg, seed 0;
reused when --data names an existing export. seg trains our U-Net (320x240 input) and reports mIoU over the risk
levels present in the val masks (plus the majority-level baseline); det trains yolov8n from its architecture file
(no pretrained weights: none can be downloaded here) with ultralytics' trainer and reports its val mAP50.

SR: held-out footage = Songdo 03936 and interchange frames 120/170 (EDSR trains on Songdo 00003/00972 and interchange
frames 0..60 only). Each test image gives 640x480 high-resolution crops; the low-resolution input is their area
downscale by the model's scale (what the VAC reads when it magnifies the footage by that factor at 640x480), and each
method upscales it back; PSNR / SSIM on luma against the crop (scale px border ignored), medians over crops. ms per
frame: one upscale of that input (640x480 output), median of N after a warm-up, OpenCV/torch threads as set. End to end:
Simulator.render over the interchange at 40 m (x4 magnification), with and without the hook, medians interleaved.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from viva_sitl.perception import BicubicUpscaler, MagnifiedRender, OpenCVSR, Upscaler  # noqa: E402
from viva_sitl.perception.quality import degrade_area, psnr_db, ssim  # noqa: E402

SHARED = ROOT.parent / "shared"
SR_DIR = SHARED / "models" / "sr"
SONGDO = SHARED / "footage" / "songdo"
CLIP = SHARED / "footage" / "interchange" / "interchange_1080p.mp4"


def _median_ms(fn: Callable[[], object], n: int) -> float:
    fn()
    out = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        out.append((time.perf_counter() - t) * 1e3)
    return statistics.median(out)


def _video_frames(indices: list[int]) -> dict[int, np.ndarray]:
    cap = cv2.VideoCapture(str(CLIP))
    out: dict[int, np.ndarray] = {}
    i = 0
    while len(out) < len(indices):
        ok, frame = cap.read()
        if not ok:
            break
        if i in indices:
            out[i] = frame
        i += 1
    cap.release()
    return out


def _crops(img: np.ndarray, n: int, seed: int) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    h, w = img.shape[:2]
    out = []
    for _ in range(n):
        y, x = int(rng.integers(0, h - 480 + 1)), int(rng.integers(0, w - 640 + 1))
        out.append(np.ascontiguousarray(img[y : y + 480, x : x + 640]))
    return out


def bench_sr(args: argparse.Namespace) -> str:
    cv2.setNumThreads(args.threads)
    frames = _video_frames(list(range(0, 61, 10)) + [120, 170])
    train = [cv2.imread(str(SONGDO / f"{k}.jpg")) for k in ("00003", "00972")] + [
        frames[i] for i in range(0, 61, 10)
    ]
    test = {"songdo 03936": cv2.imread(str(SONGDO / "03936.jpg")), "interchange f120": frames[120],
            "interchange f170": frames[170]}  # fmt: skip
    methods: dict[str, Upscaler] = {}
    for s in (2, 3, 4):
        methods[f"bicubic_x{s}"] = BicubicUpscaler(s)
    for name in (
        "FSRCNN_x2",
        "FSRCNN-small_x2",
        "ESPCN_x2",
        "FSRCNN_x3",
        "ESPCN_x3",
        "FSRCNN_x4",
        "ESPCN_x4",
    ):
        methods[name] = OpenCVSR(SR_DIR / f"{name}.pb")
    edsr_note = (
        "EDSR: not measured (torch absent: pip install torch==2.13.0 && pip install 'viva-sitl[perception]')"
    )
    try:
        import torch

        from viva_sitl.perception.edsr import EDSRUpscaler, train_edsr

        torch.set_num_threads(args.threads)
        t0 = time.perf_counter()
        model, losses = train_edsr(
            train,
            scale=2,
            steps=args.edsr_steps,
            patch_px=24,
            batch=16,
            seed=0,
            n_feats=args.edsr_feats,
            n_resblocks=args.edsr_blocks,
        )
        train_s = time.perf_counter() - t0
        methods["EDSR_x2 (ours)"] = EDSRUpscaler(model)
        n_params = sum(p.numel() for p in model.parameters())
        edsr_note = (
            f"EDSR (ours): {args.edsr_feats} features, {args.edsr_blocks} residual blocks, {n_params} parameters, bicubic global residual; trained "
            f"self-supervised for {args.edsr_steps} steps (batch 16, 48 px HR patches, L1, Adam 1e-3 cosine) on "
            f"Songdo 00003/00972 + interchange frames 0..60 in {train_s:.0f} s on this CPU (torch {torch.__version__}, "
            f"{args.threads} threads); L1 loss first/last 20 steps {np.mean(losses[:20]):.4f} / {np.mean(losses[-20:]):.4f}"
        )
    except ImportError:
        pass
    rows = []
    for name, up in methods.items():
        s = up.scale
        psnrs, ssims, gains = [], [], []
        for k, img in enumerate(test.values()):
            for crop in _crops(img, args.crops, seed=k):
                lr = degrade_area(crop, s)
                hr = crop[: lr.shape[0] * s, : lr.shape[1] * s]
                out = up.upscale(lr)
                p, q = psnr_db(out, hr, s), ssim(out, hr, s)
                b = psnr_db(BicubicUpscaler(s).upscale(lr), hr, s)
                psnrs.append(p)
                ssims.append(q)
                gains.append(p - b)
        lr0 = degrade_area(_crops(test["songdo 03936"], 1, 0)[0], s)
        ms = _median_ms(lambda up=up, lr0=lr0: up.upscale(lr0), args.n)  # type: ignore[misc]
        rows.append(
            (name, s, statistics.median(psnrs), statistics.median(gains), statistics.median(ssims), ms)
        )
    lines = [
        "## Super-resolution (held-out footage)",
        "",
        f"- {edsr_note}",
        f"- {len(test)} held-out images x {args.crops} crops of 640x480; input = area downscale by the scale; "
        f"ms = one upscale to ~640x480 (median of {args.n}), cv2/torch threads {args.threads}",
        "",
        "| method | scale | PSNR dB (median) | gain over bicubic dB (median) | SSIM (median) | ms per 640x480 output |",
        "|---|---|---|---|---|---|",
    ]
    for name, s, p, g, q, ms in rows:
        lines.append(f"| {name} | x{s} | {p:.2f} | {g:+.2f} | {q:.4f} | {ms:.1f} |")
    print("\n".join(lines), flush=True)  # the quality table survives a failure of the end-to-end part
    lines += ["", _bench_sr_sim(args, methods)]
    return "\n".join(lines)


def _bench_sr_sim(args: argparse.Namespace, methods: dict[str, Upscaler]) -> str:
    from viva_sitl.sim import Simulator

    out = [
        "### End to end: Simulator.render at 40 m over the interchange (x4 magnification, 640x480), ms per frame",
        "",
        "| hook | ms per frame (median) | ratio to no SR |",
        "|---|---|---|",
    ]
    with Simulator(footage="interchange") as sim:
        sim.reset(pos_ned_m=(0.0, 0.0, -40.0))
        sim.render()
        choice = ["none"] + [k for k in ("bicubic_x2", "FSRCNN-small_x2", "FSRCNN_x2", "ESPCN_x2", "ESPCN_x4",
                                         "EDSR_x2 (ours)") if k in methods]  # fmt: skip
        times: dict[str, list[float]] = {k: [] for k in choice}
        hooks = {k: (None if k == "none" else MagnifiedRender(methods[k], 1.0)) for k in choice}
        for _ in range(args.n):
            for k in choice:
                sim.super_resolution = hooks[k]
                t = time.perf_counter()
                sim.render()
                times[k].append((time.perf_counter() - t) * 1e3)
        base = statistics.median(times["none"])
        for k in choice:
            m = statistics.median(times[k])
            out.append(f"| {k} | {m:.1f} | {m / base:.1f}x |")
    return "\n".join(out)


def _songdo_dataset(args: argparse.Namespace) -> Path:
    from viva_sitl.perception.dataset import ExportSpec, PoseRanges, export_dataset

    data = Path(args.data)
    if (data / "data.yaml").is_file():
        return data
    spec = ExportSpec(
        footages=("songdo-00003", "songdo-00972", "songdo-03936"), n=args.n_images, seed=0,
        poses=PoseRanges.parse("alt=15:40,tilt=0:10"), split="footage", val_footage="songdo-03936",
    )  # fmt: skip
    t = time.perf_counter()
    counts = export_dataset(spec, data)
    print(f"exported {counts} to {data} in {time.perf_counter() - t:.0f} s", flush=True)
    return data


def bench_seg(args: argparse.Namespace) -> str:
    import torch

    from viva_sitl.perception.segment import Segmenter, evaluate, load_split, train_segmenter

    torch.set_num_threads(args.threads)
    data = _songdo_dataset(args)
    size = (320, 240)
    t = time.perf_counter()
    model, hist = train_segmenter(
        data, epochs=args.epochs, size=size, width=16, batch=8, seed=0,
        progress=lambda k, loss: print(f"step {k} loss {loss:.3f} {time.perf_counter() - t:.0f} s", flush=True),
    )  # fmt: skip
    train_s = time.perf_counter() - t
    seg = Segmenter(model, size, (640, 480))
    val = load_split(data, "val", size)
    train = load_split(data, "train", size)
    counts = np.bincount(np.concatenate([m.ravel() for m in train.masks]), minlength=6)
    majority = int(np.argmax(counts[1:]) + 1)

    class _Const:
        def predict(self, img: np.ndarray) -> np.ndarray:
            return np.full(img.shape[:2], majority, np.uint8)

    base = evaluate(_Const(), val)  # type: ignore[arg-type]
    frame = cv2.imread(str(next((data / "images" / "val").glob("*.jpg"))))
    ms = _median_ms(lambda: seg.predict(frame), args.n)
    n_params = sum(p.numel() for p in model.parameters())
    iou = ", ".join(f"L{k} {v:.2f}" for k, v in hist["val_iou_by_level"].items())
    biou = ", ".join(f"L{k} {v:.2f}" for k, v in base["val_iou_by_level"].items())
    return "\n".join([
        "## Risk segmentation (U-Net, ours)",
        "",
        f"- Data: {data} — {hist['train_images']} train images (Songdo 00003 + 00972), {hist['val_images']} val "
        "images (Songdo 03936: held-out ground); masks = the hand-made risk polygons + object buffers",
        f"- Model: U-Net width 16, depth 3, {n_params} parameters, input 320x240 (frames resized), AdamW one-cycle "
        f"3e-3, batch 8, {args.epochs} epochs, trained in {train_s:.0f} s on this CPU (torch {torch.__version__}, "
        f"{args.threads} threads); loss {hist['loss'][0]:.3f} -> {hist['loss'][-1]:.3f}",
        "",
        "| predictor | val mIoU | per-level IoU | pixel accuracy |",
        "|---|---|---|---|",
        f"| U-Net | {hist['val_miou']:.3f} | {iou} | {hist['val_pixel_acc']:.3f} |",
        f"| majority level ({majority}) everywhere | {base['val_miou']:.3f} | {biou} | {base['val_pixel_acc']:.3f} |",
        "",
        f"- Inference: Segmenter.predict on a 640x480 frame (resize, U-Net at 320x240, argmax, resize back): "
        f"{ms:.1f} ms median of {args.n} ({1000.0 / ms:.1f} fps)",
    ])  # fmt: skip


def bench_det(args: argparse.Namespace) -> str:
    import torch

    from viva_sitl.perception.detect import Detector, train_detector

    torch.set_num_threads(args.threads)
    data = _songdo_dataset(args)
    out = Path(args.det_dir)
    t = time.perf_counter()
    best, m = train_detector(data, epochs=args.epochs, imgsz=args.imgsz, batch=8, out_dir=out, seed=0)
    train_s = time.perf_counter() - t
    frame = cv2.imread(str(next((data / "images" / "val").glob("*.jpg"))))
    rows = []
    for imgsz in (args.imgsz, 640):
        det = Detector(best, imgsz=imgsz)
        rows.append((imgsz, _median_ms(lambda det=det: det.detect(frame), args.n)))  # type: ignore[misc]
    import ultralytics

    lines = [
        "## Detection (YOLO via ultralytics)",
        "",
        f"- Data: {data} (Songdo: train on 00003 + 00972, validate on 03936; class 'car' = the stills' vehicles)",
        f"- Model: yolov8n.yaml from scratch (no pretrained weights offline), ultralytics {ultralytics.__version__}, "
        f"torch {torch.__version__}; {args.epochs} epochs at imgsz {args.imgsz}, batch 8, CPU, {train_s:.0f} s",
        f"- Held-out (03936) val: mAP50 {m['map50']:.3f}, mAP50-95 {m['map50_95']:.3f}, precision "
        f"{m['precision']:.3f}, recall {m['recall']:.3f}",
        "",
        "| inference imgsz | ms per 640x480 frame (median) |",
        "|---|---|",
    ]
    lines += [f"| {s} | {ms:.1f} |" for s, ms in rows]
    return "\n".join(lines)


# `viva-sitl dataset export --footage synthetic --n N --seed S --val V [--poses P]`: the detector's val cut is further
# west (val = east 40 %), else the held-out ground holds no person (the walkers and the crowd live west of E+36 m)
SEG_SYNTH_SPEC = dict(n=2400, seed=1, val=0.2, poses="")
DET_SYNTH_SPEC = dict(n=800, seed=2, val=0.4, poses="alt=10:30,tilt=0:15")


def _synthetic_dataset(data: Path, n: int, seed: int, val: float, poses: str) -> Path:
    """The synthetic field exported as `viva-sitl dataset export --footage synthetic --n N --seed S --val V [--poses
    P]` (region split: val sees only the ground east of the cut); reused when `data` already holds it."""
    from viva_sitl.perception.dataset import ExportSpec, PoseRanges, export_dataset

    if (data / "data.yaml").is_file():
        return data
    spec = ExportSpec(
        footages=("synthetic",), n=n, seed=seed, val_fraction=val, poses=PoseRanges.parse(poses)
    )
    t = time.perf_counter()
    counts = export_dataset(spec, data)
    print(f"exported {counts} to {data} in {time.perf_counter() - t:.0f} s", flush=True)
    return data


def _load() -> str:
    return "/".join(f"{v:.1f}" for v in os.getloadavg())


def _synthetic_dataset_of(spec: dict[str, object], data: Path) -> Path:
    """`_synthetic_dataset` with the export settings of one bench part (SEG_SYNTH_SPEC / DET_SYNTH_SPEC)."""
    return _synthetic_dataset(
        data, int(str(spec["n"])), int(str(spec["seed"])), float(str(spec["val"])), str(spec["poses"])
    )


def bench_seg_synth(args: argparse.Namespace) -> str:
    """The risk U-Net on the synthetic field (exact risk ground truth): train with the recipe unless --weights
    already exists, then held-out (east of the cut) mIoU and per-level IoU vs the majority level, ms per frame."""
    import torch

    from viva_sitl.perception.segment import Segmenter, evaluate, load_split, save_segmenter, train_segmenter

    torch.set_num_threads(args.threads)
    load0 = _load()
    data = _synthetic_dataset_of(SEG_SYNTH_SPEC, Path(args.data))
    weights = Path(args.weights) if args.weights else None
    trained = ""
    if weights is None or not weights.is_file():
        w, h = (int(v) for v in args.size.split("x"))
        t = time.perf_counter()
        model, hist = train_segmenter(
            data, epochs=args.epochs, size=(w, h), width=args.width, batch=args.batch, lr=args.lr, seed=0,
            time_limit_s=60.0 * args.time_limit_min, log=lambda line: print(line, flush=True),
        )  # fmt: skip
        if weights is not None:
            save_segmenter(model, weights, (640, 480))
        trained = (
            f"- Trained here in {time.perf_counter() - t:.0f} s: {hist['epochs_run']} epochs, best epoch "
            f"{hist.get('best_epoch')}; class weights {[round(v, 2) for v in hist['class_weights']]}"
        )
        seg = Segmenter(model, (w, h), (640, 480))
    else:
        seg = Segmenter.load(weights)
    size = seg.input_size
    val = load_split(data, "val", size)
    train = load_split(data, "train", size)
    counts = np.bincount(np.concatenate([m.ravel() for m in train.masks]), minlength=6)
    majority = int(np.argmax(counts[1:]) + 1)

    class _Const:
        def predict(self, img: np.ndarray) -> np.ndarray:
            return np.full(img.shape[:2], majority, np.uint8)

    res = evaluate(Segmenter(seg.model, size, None), val)  # val images already at the model's input size
    base = evaluate(_Const(), val)  # type: ignore[arg-type]
    frame = cv2.imread(str(next((data / "images" / "val").glob("*.jpg"))))
    ms = _median_ms(lambda: seg.predict(frame), args.n)
    n_params = sum(p.numel() for p in seg.model.parameters())
    share = counts[1:] / counts[1:].sum()

    def levels(r: dict) -> str:
        return ", ".join(f"L{k} {v:.3f}" for k, v in r["val_iou_by_level"].items())

    return "\n".join([
        "## Risk segmentation on the synthetic field (U-Net, ours)",
        "",
        f"- Data: {data} — {len(train.images)} train / {len(val.images)} val images (region split: val sees only "
        "ground east of the cut); masks = the exact risk map + object buffers; train pixel share by level "
        + ", ".join(f"L{k + 1} {v:.3f}" for k, v in enumerate(share) if v > 0),
        f"- Model: {weights or 'in memory'}: U-Net width {seg.model.width}, depth {seg.model.depth}, {n_params} "
        f"parameters, input {size[0]}x{size[1]} (frames resized); torch {torch.__version__}, {args.threads} threads",
        *([trained] if trained else []),
        "",
        "| predictor | val mIoU | per-level IoU | pixel accuracy | missed hazard | false hazard |",
        "|---|---|---|---|---|---|",
        f"| U-Net | {res['val_miou']:.3f} | {levels(res)} | {res['val_pixel_acc']:.3f} | "
        f"{res['val_missed_hazard']:.3f} | {res['val_false_hazard']:.3f} |",
        f"| majority level ({majority}) everywhere | {base['val_miou']:.3f} | {levels(base)} | "
        f"{base['val_pixel_acc']:.3f} | {base['val_missed_hazard']:.3f} | {base['val_false_hazard']:.3f} |",
        "",
        "(missed hazard: share of level 4-5 val pixels predicted 1-3; false hazard: share of level 1-3 predicted 4-5)",
        "",
        f"- Inference: Segmenter.predict on a 640x480 frame (resize to {size[0]}x{size[1]}, U-Net, argmax, resize "
        f"back): {ms:.1f} ms median of {args.n} ({1000.0 / ms:.1f} fps)",
        f"- Load average (1/5/15 min) at start / end: {load0} / {_load()} (nproc {os.cpu_count()})",
    ])  # fmt: skip


def bench_det_synth(args: argparse.Namespace) -> str:
    """The detector on the synthetic field's people and cars: train with the from-scratch recipe unless --weights
    already exists, then ultralytics' val on the held-out ground (mAP50 overall and per class), ms per frame."""
    import torch

    from viva_sitl.perception.detect import Detector, require_ultralytics, train_detector

    torch.set_num_threads(args.threads)
    load0 = _load()
    data = _synthetic_dataset_of(DET_SYNTH_SPEC, Path(args.data))
    weights = Path(args.weights) if args.weights else None
    trained = ""
    if weights is None or not weights.is_file():
        t = time.perf_counter()
        best, m = train_detector(
            data, epochs=args.epochs, imgsz=args.imgsz, batch=args.batch, out_dir=args.det_dir, seed=0,
            width=args.det_width, nbs=args.batch, time_h=args.time_limit_min / 60.0, classes=[0, 2], recipe=True,
        )  # fmt: skip
        trained = f"- Trained here in {time.perf_counter() - t:.0f} s: {best}"
        if weights is not None:
            import shutil

            shutil.copyfile(best, weights)
        weights = best
    yolo = require_ultralytics()
    met = yolo(str(weights), task="detect").val(
        data=str((data / "data.yaml").resolve()), imgsz=args.imgsz, batch=args.batch, device="cpu", plots=False,
        verbose=False, workers=0, classes=[0, 2],
    )  # fmt: skip
    names = met.names
    per_class = ", ".join(
        f"{names[int(c)]} {float(a):.3f}" for c, a in zip(met.box.ap_class_index, met.box.ap50, strict=True)
    )
    n_val = sum(1 for _ in (data / "images" / "val").glob("*.jpg"))
    frame = cv2.imread(str(next((data / "images" / "val").glob("*.jpg"))))
    rows = []
    for imgsz in sorted({args.imgsz, 640}):
        det = Detector(weights, imgsz=imgsz)
        rows.append((imgsz, _median_ms(lambda det=det: det.detect(frame), args.n)))  # type: ignore[misc]
    onnx = weights.with_suffix(".onnx")
    if onnx.is_file():  # exported at the training imgsz (fixed input)
        det = Detector(onnx, imgsz=args.imgsz)
        rows.append((f"{args.imgsz} (ONNX Runtime)", _median_ms(lambda: det.detect(frame), args.n)))
    import ultralytics

    lines = [
        "## Detection on the synthetic field (YOLO via ultralytics, from scratch)",
        "",
        f"- Data: {data} (region split; {n_val} val images of held-out ground; classes person 0, car 2)",
        f"- Weights: {weights} (ultralytics {ultralytics.__version__}, torch {torch.__version__})",
        *([trained] if trained else []),
        f"- Held-out val at imgsz {args.imgsz}: mAP50 {met.box.map50:.3f}, mAP50-95 {met.box.map:.3f}, precision "
        f"{met.box.mp:.3f}, recall {met.box.mr:.3f}; mAP50 per class: {per_class}",
        "",
        "| inference imgsz | ms per 640x480 frame (median) |",
        "|---|---|",
        *[f"| {s} | {ms:.1f} |" for s, ms in rows],
        "",
        f"- Load average (1/5/15 min) at start / end: {load0} / {_load()} (nproc {os.cpu_count()})",
    ]
    return "\n".join(lines)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("part", choices=["sr", "seg", "det", "seg-synth", "det-synth"])
    ap.add_argument("--epochs", type=int, default=15)
    ap.add_argument("--imgsz", type=int, default=320)
    ap.add_argument("--n-images", type=int, default=60, help="seg/det: VAC images exported per Songdo still")
    ap.add_argument("--data", default="/tmp/viva-sitl-bench-songdo", help="seg/det: dataset dir (reused)")
    ap.add_argument("--det-dir", default="/tmp/viva-sitl-bench-det", help="det: ultralytics run directory")
    ap.add_argument("--n", type=int, default=10)
    ap.add_argument("--crops", type=int, default=4)
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--edsr-steps", type=int, default=200)
    ap.add_argument("--edsr-feats", type=int, default=24)
    ap.add_argument("--edsr-blocks", type=int, default=4)
    ap.add_argument("--weights", default="", help="seg-synth/det-synth: evaluate this (train it if missing)")
    ap.add_argument("--size", default="160x120", help="seg-synth: U-Net input WxH")
    ap.add_argument("--width", type=int, default=16, help="seg-synth: U-Net base channels")
    ap.add_argument("--batch", type=int, default=16, help="seg-synth/det-synth: batch")
    ap.add_argument("--lr", type=float, default=3e-3, help="seg-synth: peak learning rate")
    ap.add_argument("--time-limit-min", type=float, default=50.0, help="seg-synth/det-synth: training budget")
    ap.add_argument("--det-width", type=float, default=0.125, help="det-synth: yolov8n channel multiple")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    parts = {"sr": bench_sr, "seg": bench_seg, "det": bench_det, "seg-synth": bench_seg_synth,
             "det-synth": bench_det_synth}  # fmt: skip
    body = parts[args.part](args)
    head = (
        f"# Perception benchmark: {args.part} (bench/bench_perception.py)\n\n"
        f"- Command: `python bench/bench_perception.py {' '.join(sys.argv[1:])}`\n"
        f"- Machine: {platform.processor() or platform.machine()}, nproc {os.cpu_count()}, Python "
        f"{platform.python_version()}, OpenCV {cv2.__version__}; shared with other jobs while it ran (noisy ms)\n\n"
    )
    text = head + body + "\n"
    print(text)
    if args.out:
        args.out.write_text(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
