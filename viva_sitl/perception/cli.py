"""`viva-sitl dataset ...` and `viva-sitl perception ...`: dataset export and training of the perception models."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from viva_sitl.cliargs import OneLineErrors, positive_int
from viva_sitl.perception.errors import PerceptionError


def _run(fn: object, prog: str) -> int:
    from viva_sitl.footage import FootageError

    try:
        from viva_sitl.footage.tiles import TileSettings, set_process_settings

        set_process_settings(TileSettings.from_environ(os.environ))  # the top floor reads $VIVA_SITL_TILE_*
        assert callable(fn)
        return int(fn())
    except (PerceptionError, FootageError) as exc:
        print(f"{prog}: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


def dataset_main(argv: list[str]) -> int:
    p = OneLineErrors(prog="viva-sitl dataset", description="labelled VAC datasets from footage ground truth")
    sub = p.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("export", help="VAC images at seeded random poses + YOLO boxes, risk masks, poses")
    e.add_argument("--footage", required=True, help="catalog name(s) or path(s), comma-separated")
    e.add_argument("--n", type=positive_int, required=True, help="images per footage")
    e.add_argument("--seed", type=int, default=0)
    e.add_argument("--poses", default="", metavar="SPEC", help="e.g. alt=15:60,tilt=0:15,yaw=0:360,radius=60")
    e.add_argument("--split", choices=["region", "footage"], default="region")
    e.add_argument("--val", type=float, default=0.2, help="region split: share of ground and images for val")
    e.add_argument("--val-footage", default="", help="footage split: the footage used for val")
    e.add_argument("--min-visible", type=float, default=0.5, help="drop boxes less visible than this")
    e.add_argument("--size", default="640x480", help="VAC size WxH")
    e.add_argument("-o", "--output", required=True, help="new (or empty) output directory")
    args = p.parse_args(argv)

    def export() -> int:
        from tqdm import tqdm

        from viva_sitl.perception.dataset import ExportSpec, PoseRanges, export_dataset

        try:
            w, h = (int(v) for v in args.size.lower().split("x"))
        except ValueError:
            raise PerceptionError(f"--size must be WxH, got {args.size!r}") from None
        spec = ExportSpec(
            footages=tuple(f.strip() for f in args.footage.split(",") if f.strip()),
            n=args.n, seed=args.seed, poses=PoseRanges.parse(args.poses), split=args.split,
            val_fraction=args.val, val_footage=args.val_footage, min_visible=args.min_visible,
            width_px=w, height_px=h,
        )  # fmt: skip
        with tqdm(total=args.n * len(spec.footages), unit="img", disable=None) as bar:
            counts = export_dataset(spec, Path(args.output), lambda done, total: bar.update(1))
        n_img = counts["train_images"] + counts["val_images"]
        print(
            f"wrote {n_img} images (train {counts['train_images']}, val {counts['val_images']}), "
            f"{counts['boxes']} boxes to {args.output} (data.yaml)"
        )
        return 0

    return _run(export, "viva-sitl dataset export")


def perception_main(argv: list[str]) -> int:
    p = OneLineErrors(
        prog="viva-sitl perception", description="train the perception models (needs the extras)"
    )
    sub = p.add_subparsers(dest="cmd", required=True)
    sr = sub.add_parser("train-sr", help="train our EDSR self-supervised on footage frames")
    sr.add_argument("--footage", required=True, help="catalog name(s) or path(s), comma-separated")
    sr.add_argument("--frames", type=positive_int, default=8, help="frames per footage (evenly spread)")
    sr.add_argument("--scale", type=int, choices=[2, 3, 4], default=2)
    sr.add_argument("--steps", type=positive_int, default=300)
    sr.add_argument("--feats", type=positive_int, default=32)
    sr.add_argument("--blocks", type=positive_int, default=8)
    sr.add_argument("--seed", type=int, default=0)
    sr.add_argument("-o", "--output", required=True, help="checkpoint (.pt)")
    seg = sub.add_parser("train-segmenter", help="train the risk U-Net on an exported dataset")
    seg.add_argument("--data", required=True, help="dataset directory (from `viva-sitl dataset export`)")
    seg.add_argument("--epochs", type=positive_int, default=10)
    seg.add_argument("--size", default="320x240", help="training/inference size WxH (images are resized)")
    seg.add_argument("--width", type=positive_int, default=16, help="U-Net base channels")
    seg.add_argument("--batch", type=positive_int, default=8)
    seg.add_argument("--lr", type=float, default=3e-3, help="peak learning rate (one-cycle)")
    seg.add_argument(
        "--patience", type=int, default=0, help="stop after N epochs without val mIoU gain (0: off)"
    )
    seg.add_argument("--time-limit-min", type=float, default=0.0, help="stop after the epoch crossing this")
    seg.add_argument(
        "--no-class-weights", action="store_true", help="plain cross-entropy (no rare-level weights)"
    )
    seg.add_argument(
        "--no-augment", action="store_true", help="left-right flips only (no flips/turns/jitter)"
    )
    seg.add_argument("--seed", type=int, default=0)
    seg.add_argument(
        "-o", "--output", required=True, help="checkpoint (.pt): the best val epoch, written as it improves"
    )
    det = sub.add_parser("train-detector", help="train a YOLO detector (ultralytics) on an exported dataset")
    det.add_argument("--data", required=True, help="dataset directory or its data.yaml")
    det.add_argument("--epochs", type=positive_int, default=30)
    det.add_argument("--imgsz", type=positive_int, default=640)
    det.add_argument("--batch", type=positive_int, default=8)
    det.add_argument("--model", default="yolov8n.yaml", help="architecture .yaml (offline) or starting .pt")
    det.add_argument("--seed", type=int, default=0)
    det.add_argument(
        "--width", type=float, default=0.0, help="rescale the architecture's channels (n = 0.25)"
    )
    det.add_argument(
        "--nbs", type=int, default=0, help="nominal batch (ultralytics: 64); = --batch: step each batch"
    )
    det.add_argument("--time-h", type=float, default=0.0, help="train this many hours (re-plans the epochs)")
    det.add_argument("--patience", type=int, default=100, help="stop after N epochs without val gain")
    det.add_argument("--classes", default="", help="keep only these class ids, e.g. 0,2 (person, car)")
    det.add_argument(
        "--recipe", action="store_true", help="from-scratch nadir recipe (flips, turns, mosaic...)"
    )
    det.add_argument("--copy-best", default="", help="also copy best.pt here each time it improves")
    det.add_argument("--onnx", action="store_true", help="export the best weights to ONNX at the end")
    det.add_argument(
        "-o", "--output", required=True, help="output directory (weights in OUTPUT/train/weights)"
    )
    from viva_sitl.perception.evaluate import add_eval_arguments

    add_eval_arguments(
        sub.add_parser("eval", help="score a detector or risk segmenter on the VAC vs ground truth")
    )
    args = p.parse_args(argv)

    if args.cmd == "eval":
        from viva_sitl.perception.evaluate import eval_cli

        return _run(lambda: eval_cli(args, argv), "viva-sitl perception eval")
    if args.cmd == "train-detector":
        return _run(lambda: _train_detector(args), "viva-sitl perception train-detector")
    if args.cmd == "train-sr":
        return _run(lambda: _train_sr(args), "viva-sitl perception train-sr")
    return _run(lambda: _train_segmenter(args), "viva-sitl perception train-segmenter")


def _train_sr(args: argparse.Namespace) -> int:
    import numpy as np
    from tqdm import tqdm

    from viva_sitl.footage import open_footage
    from viva_sitl.perception.errors import require_torch

    require_torch()
    from viva_sitl.perception.edsr import save_edsr, train_edsr

    images = []
    for name in (f.strip() for f in args.footage.split(",") if f.strip()):
        with open_footage(name) as src:
            for i in np.linspace(0, src.frame_count - 1, min(args.frames, src.frame_count)).astype(int):
                images.append(np.ascontiguousarray(src.frame(int(i))))
    with tqdm(total=args.steps, unit="step", disable=None) as bar:

        def tick(step: int, loss: float) -> None:
            bar.update(1)
            bar.set_postfix(l1=f"{loss:.4f}")

        model, losses = train_edsr(images, scale=args.scale, steps=args.steps, seed=args.seed,
                                   n_feats=args.feats, n_resblocks=args.blocks, progress=tick)  # fmt: skip
    out = Path(args.output)
    save_edsr(model, out)
    print(f"wrote {out} (EDSR x{args.scale}, {len(images)} frames, L1 {losses[0]:.4f} -> {losses[-1]:.4f})")
    return 0


def _train_segmenter(args: argparse.Namespace) -> int:
    from viva_sitl.perception.errors import require_torch

    require_torch()
    from viva_sitl.perception.segment import train_segmenter_cli

    return train_segmenter_cli(args)


def _train_detector(args: argparse.Namespace) -> int:
    import shutil

    from viva_sitl.perception.detect import export_onnx, train_detector

    try:
        classes = [int(c) for c in args.classes.split(",") if c.strip()]
    except ValueError:
        raise PerceptionError(f"--classes must be comma-separated class ids, got {args.classes!r}") from None
    copy_to = Path(args.copy_best) if args.copy_best else None

    def copy_best(best: Path, metrics: dict[str, float]) -> None:
        if copy_to is not None:
            tmp = copy_to.with_name(copy_to.name + ".tmp")
            shutil.copyfile(best, tmp)
            tmp.replace(copy_to)
            print(f"best so far -> {copy_to} (val mAP50 {metrics['map50']:.3f})", flush=True)

    best, m = train_detector(
        args.data, epochs=args.epochs, imgsz=args.imgsz, model=args.model, batch=args.batch, out_dir=args.output,
        seed=args.seed, width=args.width, nbs=args.nbs, time_h=args.time_h, patience=args.patience,
        classes=classes or None, recipe=args.recipe, on_best=copy_best if copy_to else None,
    )  # fmt: skip
    print(f"wrote {best} (val mAP50 {m['map50']:.3f}, mAP50-95 {m['map50_95']:.3f})")
    if copy_to is not None:
        shutil.copyfile(best, copy_to)
    if args.onnx:
        onnx = export_onnx(copy_to or best, args.imgsz)
        print(f"wrote {onnx}")
    return 0
