"""Risk segmentation: a small U-Net (ours, torch) mapping a VAC frame to the 5 SORA-style risk levels.

    model, history = train_segmenter(Path("data/synth"), epochs=10)        # a `viva-sitl dataset export` folder
    save_segmenter(model, "unet.pt");  seg = Segmenter.load("unet.pt")
    levels = seg.predict(frame_bgr)                                          # (H, W) uint8, 1..5
    ground = seg.on_ground(levels, meta=frame_meta)                         # GroundRisk raster in NED (or pose+params)

Classes: 1..5 are the levels; mask value 0 (no ground seen) is ignored by the loss and never predicted. Frames are
resized to the model's input size (default 320x240) and the prediction back to the frame size (nearest).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import torch
from numpy.typing import ArrayLike, NDArray
from torch import nn

from viva_sitl.camera import CameraParams
from viva_sitl.camera.projection import ground_to_image_homography
from viva_sitl.perception.errors import PerceptionError
from viva_sitl.perception.geometry import ground_homography_from_meta, image_to_ground

U8 = NDArray[np.uint8]
CHECKPOINT_FORMAT = "viva-sitl-unet"
N_CLASSES = 6  # 0 (ignored) + levels 1..5


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
        nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
    )  # fmt: skip


class UNet(nn.Module):
    """U-Net with `depth` down/up stages; (N, 3, H, W) in 0..1 -> (N, 6, H, W) logits; H, W multiples of 2**depth."""

    def __init__(self, width: int = 16, depth: int = 3) -> None:
        super().__init__()
        self.width, self.depth = width, depth
        chans = [width * 2**k for k in range(depth + 1)]
        self.down = nn.ModuleList(
            [_block(3, chans[0])] + [_block(chans[k], chans[k + 1]) for k in range(depth)]
        )
        self.up = nn.ModuleList(
            [nn.ConvTranspose2d(chans[k + 1], chans[k], 2, stride=2) for k in range(depth)]
        )
        self.merge = nn.ModuleList([_block(2 * chans[k], chans[k]) for k in range(depth)])
        self.head = nn.Conv2d(chans[0], N_CLASSES, 1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        skips = []
        for k, blk in enumerate(self.down):
            x = blk(x if k == 0 else nn.functional.max_pool2d(x, 2))
            skips.append(x)
        x = skips.pop()
        for k in reversed(range(self.depth)):
            x = self.merge[k](torch.cat([self.up[k](x), skips.pop()], dim=1))
        return self.head(x)


def _to_tensor(images_bgr: list[U8]) -> torch.Tensor:
    a = np.stack([im[..., ::-1] for im in images_bgr]).astype(np.float32) / 255.0
    return torch.from_numpy(np.ascontiguousarray(a)).permute(0, 3, 1, 2)


@dataclass
class SegData:
    images: list[U8]
    masks: list[U8]


def load_split(data_dir: Path, split: str, size: tuple[int, int]) -> SegData:
    """Images and masks of one split of an exported dataset, resized to `size` (w, h) (masks: nearest)."""
    img_dir, mask_dir = Path(data_dir) / "images" / split, Path(data_dir) / "masks" / split
    if not img_dir.is_dir() or not mask_dir.is_dir():
        raise PerceptionError(
            f"{data_dir} has no images/{split} and masks/{split} (export it with `viva-sitl dataset export`)"
        )
    out = SegData([], [])
    for p in sorted(img_dir.glob("*.jpg")):
        m = mask_dir / (p.stem + ".png")
        img, mask = cv2.imread(str(p)), cv2.imread(str(m), cv2.IMREAD_GRAYSCALE)
        if img is None or mask is None:
            raise PerceptionError(f"cannot read {p} or its mask {m}")
        out.images.append(np.asarray(cv2.resize(img, size, interpolation=cv2.INTER_AREA)))
        out.masks.append(np.asarray(cv2.resize(mask, size, interpolation=cv2.INTER_NEAREST)))
    if not out.images:
        raise PerceptionError(f"{img_dir} holds no images")
    return out


def class_weights(masks: list[U8], power: float = 0.5, max_ratio: float = 10.0) -> NDArray[np.float32]:
    """Per-class loss weights (index 0..5) from the training masks: freq**-power over the levels present, clipped to
    `max_ratio` times the smallest, scaled so the mean weight over labelled pixels is 1; 0 for absent levels and the
    ignored 0. power 0.5 (inverse square root of the frequency) lifts rare levels without letting a few pixels rule."""
    counts = np.zeros(N_CLASSES, np.int64)
    for m in masks:
        counts += np.bincount(np.asarray(m, np.int64).ravel(), minlength=N_CLASSES)[:N_CLASSES]
    counts[0] = 0
    w = np.zeros(N_CLASSES, np.float64)
    present = counts > 0
    if not present.any():
        return w.astype(np.float32)
    freq = counts[present] / counts.sum()
    raw = freq**-power
    w[present] = np.minimum(raw, max_ratio * raw.min())
    w /= float((counts * w).sum() / counts.sum())
    return w.astype(np.float32)


def budget_lr(frac: float, lr: float, warmup: float = 0.05, final: float = 0.01) -> float:
    """One-cycle shape over a fraction of a budget (time): linear warm-up from lr/10 over `warmup`, then cosine decay
    to lr*final at frac = 1."""
    frac = min(max(frac, 0.0), 1.0)
    if frac < warmup:
        return lr * (0.1 + 0.9 * frac / warmup)
    c = (frac - warmup) / (1.0 - warmup)
    return lr * (final + (1.0 - final) * 0.5 * (1.0 + math.cos(math.pi * c)))


def augment(x: torch.Tensor, y: torch.Tensor, rng: np.random.Generator) -> tuple[torch.Tensor, torch.Tensor]:
    """Free augmentations of a nadir view, per sample: the symmetries of the frame (left-right and up-down flips,
    so also the half turn; and a transpose when the frame is square: all 8 quarter-turn symmetries) applied to the
    image and its mask together; brightness/contrast jitter (x0.8..1.2, +-0.08) on the image only.
    x (N, 3, H, W) in 0..1, y (N, H, W) -> new tensors."""
    xs, ys = [], []
    square = x.shape[-1] == x.shape[-2]
    for i in range(x.shape[0]):
        xi, yi = x[i], y[i]
        if rng.random() < 0.5:
            xi, yi = xi.flip(-1), yi.flip(-1)
        if rng.random() < 0.5:
            xi, yi = xi.flip(-2), yi.flip(-2)
        if square and rng.random() < 0.5:
            xi, yi = xi.transpose(-1, -2), yi.transpose(-1, -2)
        gain, bias = rng.uniform(0.8, 1.2), rng.uniform(-0.08, 0.08)
        xs.append((xi * gain + bias).clamp(0.0, 1.0))
        ys.append(yi)
    return torch.stack(xs).contiguous(), torch.stack(ys).contiguous()


def train_segmenter(
    data_dir: Path,
    epochs: int = 10,
    size: tuple[int, int] = (320, 240),
    width: int = 16,
    batch: int = 8,
    lr: float = 3e-3,
    seed: int = 0,
    progress: Callable[[int, float], None] | None = None,
    *,
    weighted: bool = True,
    augmented: bool = True,
    patience: int = 0,
    time_limit_s: float = 0.0,
    on_best: Callable[[UNet, dict[str, Any]], None] | None = None,
    log: Callable[[str], None] | None = None,
) -> tuple[UNet, dict[str, Any]]:
    """Train on images/train + masks/train of an exported dataset; returns the model and {loss, val_miou, ...}.

    Recipe: cross-entropy with `class_weights` (weighted=True) so the rare levels count; `augment` (flips, half
    turns, photometric jitter); AdamW with a one-cycle schedule (warm-up then cosine decay) over the steps of
    `epochs`, or, with `time_limit_s` > 0, over that wall time (`budget_lr`: on a shared CPU the step rate is
    unknown, so the schedule follows the clock and training stops when the budget is spent, `epochs` then being a
    cap). With a val split the model is evaluated after every epoch (and at the end) and the best val mIoU is kept:
    the returned model is the best evaluation's, and `on_best(model, metrics)` is called at every improvement, e.g.
    to write a checkpoint; `patience` > 0 stops after that many epochs without improvement."""
    import copy
    import time

    w, h = size
    depth = 3
    if w % 2**depth or h % 2**depth:
        raise PerceptionError(f"segmenter size {w}x{h} must be a multiple of {2**depth} on both sides")
    data = load_split(data_dir, "train", size)
    val_dir = Path(data_dir) / "images" / "val"
    val = load_split(data_dir, "val", size) if val_dir.is_dir() and any(val_dir.glob("*.jpg")) else None
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = UNet(width, depth)
    model.input_size = size  # type: ignore[assignment]
    opt = torch.optim.AdamW(model.parameters(), lr=lr, weight_decay=1e-4)
    x_all = _to_tensor(data.images)
    y_all = torch.from_numpy(np.stack(data.masks).astype(np.int64))
    cw = class_weights(data.masks) if weighted else None
    weight = torch.from_numpy(cw) if cw is not None else None
    n = len(data.images)
    steps = max(1, epochs * math.ceil(n / batch))
    sched = (
        torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=lr, total_steps=steps) if not time_limit_s else None
    )
    losses: list[float] = []
    curve: list[dict[str, Any]] = []
    best: dict[str, Any] = {}
    best_state: dict[str, torch.Tensor] | None = None
    step = 0
    t0 = time.perf_counter()
    for epoch in range(epochs):
        order = rng.permutation(n)
        model.train()
        for k in range(0, n, batch):
            if time_limit_s:
                frac = (time.perf_counter() - t0) / time_limit_s
                if frac >= 1.0 and losses:  # at least one step, whatever the budget
                    break
                for g in opt.param_groups:
                    g["lr"] = budget_lr(frac, lr)
            idx = torch.from_numpy(order[k : k + batch])
            x, y = x_all[idx], y_all[idx]
            if augmented:
                x, y = augment(x, y, rng)
            elif rng.random() < 0.5:
                x, y = x.flip(-1), y.flip(-1)
            if (y > 0).sum() == 0:
                continue
            loss = nn.functional.cross_entropy(model(x), y, weight=weight, ignore_index=0)
            opt.zero_grad()
            loss.backward()
            opt.step()
            if sched is not None and step + 1 < steps:
                sched.step()
            losses.append(float(loss.detach()))
            if progress is not None:
                progress(step, losses[-1])
            step += 1
        model.eval()
        row: dict[str, Any] = {"epoch": epoch + 1, "step": step, "time_s": time.perf_counter() - t0,
                               "loss": float(np.mean(losses[-max(1, math.ceil(n / batch)) :])) if losses else math.nan}  # fmt: skip
        if val is not None:
            row.update(evaluate(Segmenter(model, size, None), val))
            if not best or row["val_miou"] > best["val_miou"]:
                best = dict(row)
                best_state = copy.deepcopy(model.state_dict())
                if on_best is not None:
                    on_best(model, best)
        curve.append(row)
        if log is not None:
            log(" ".join(f"{k}={v:.4f}" if isinstance(v, float) else f"{k}={v}" for k, v in row.items()))
        if patience and best and epoch + 1 - int(best["epoch"]) >= patience:
            break
        if time_limit_s and time.perf_counter() - t0 > time_limit_s:
            break
    if not losses:
        raise PerceptionError(f"{data_dir}: the training masks hold no labelled pixel (all 0)")
    if best_state is not None:
        model.load_state_dict(best_state)
    model.eval()
    history: dict[str, Any] = {"loss": losses, "train_images": n, "curve": curve, "epochs_run": len(curve),
                               "class_weights": None if cw is None else cw.tolist()}  # fmt: skip
    if best:
        history.update({k: v for k, v in best.items() if k.startswith("val_")})
        history["best_epoch"] = best["epoch"]
    return model, history


def confusion(pred: U8, truth: U8) -> NDArray[np.int64]:
    """6x6 confusion counts (truth row, prediction column), truth 0 ignored."""
    keep = truth > 0
    return np.bincount(truth[keep].astype(np.int64) * N_CLASSES + pred[keep], minlength=N_CLASSES**2).reshape(
        N_CLASSES, N_CLASSES
    )


def evaluate(seg: Segmenter, data: SegData) -> dict[str, Any]:
    """mIoU over the levels present in the truth, per-level IoU, pixel accuracy (inputs at the model's size)."""
    cm = np.zeros((N_CLASSES, N_CLASSES), np.int64)
    for img, mask in zip(data.images, data.masks, strict=True):
        cm += confusion(seg.predict(img), mask)
    iou: dict[int, float] = {}
    for c in range(1, N_CLASSES):
        tp = cm[c, c]
        denom = cm[c, :].sum() + cm[:, c].sum() - tp
        if cm[c, :].sum() > 0:
            iou[c] = float(tp / denom) if denom else 0.0
    total = cm[1:, :].sum()
    hazard, safe = cm[4:, :].sum(), cm[1:4, :].sum()
    return {
        # for a landing choice: share of level 4-5 ground called 1-3 (missed hazard) and of level 1-3 called 4-5
        "val_missed_hazard": float(cm[4:, 1:4].sum() / hazard) if hazard else math.nan,
        "val_false_hazard": float(cm[1:4, 4:].sum() / safe) if safe else math.nan,
        "val_miou": float(np.mean(list(iou.values()))) if iou else math.nan,
        "val_iou_by_level": iou,
        "val_pixel_acc": float(np.trace(cm) / total) if total else math.nan,
        "val_images": len(data.images),
    }


def save_segmenter(model: UNet, path: str | Path, frame_size: tuple[int, int] | None = None) -> None:
    size = getattr(model, "input_size", (320, 240))
    torch.save(
        {"format": CHECKPOINT_FORMAT, "version": 1, "width": model.width, "depth": model.depth,
         "input_size": list(size), "frame_size": list(frame_size) if frame_size else None,
         "state_dict": model.state_dict()},
        Path(path),
    )  # fmt: skip


@dataclass(frozen=True)
class GroundRisk:
    """Predicted levels on a north/east grid: levels[row, col] at (north0 + row*cell, east0 + col*cell); 0 = unseen."""

    levels: U8
    north0_m: float
    east0_m: float
    cell_m: float

    def level_at(self, north_m: float, east_m: float) -> int:
        r = round((north_m - self.north0_m) / self.cell_m)
        c = round((east_m - self.east0_m) / self.cell_m)
        if 0 <= r < self.levels.shape[0] and 0 <= c < self.levels.shape[1]:
            return int(self.levels[r, c])
        return 0


class Segmenter:
    """Inference helper around a trained U-Net (CPU, no autograd)."""

    def __init__(self, model: UNet, input_size: tuple[int, int], frame_size: tuple[int, int] | None) -> None:
        self.model = model.eval()
        self.input_size = (int(input_size[0]), int(input_size[1]))
        self.frame_size = None if frame_size is None else (int(frame_size[0]), int(frame_size[1]))

    @classmethod
    def load(cls, path: str | Path) -> Segmenter:
        p = Path(path)
        if not p.is_file():
            raise PerceptionError(
                f"segmenter weights not found: {p} (train them with `viva-sitl perception train-segmenter`)"
            )
        try:
            ck: Any = torch.load(p, map_location="cpu", weights_only=True)
        except Exception as exc:  # torch raises many types for a foreign file
            raise PerceptionError(
                f"{p} is not a torch checkpoint: {str(exc).splitlines()[0][:120]}"
            ) from None
        fmt = ck.get("format") if isinstance(ck, dict) else None
        if fmt != CHECKPOINT_FORMAT:
            kind = f"a {fmt} checkpoint" if isinstance(fmt, str) else "not a viva-sitl checkpoint"
            raise PerceptionError(
                f"{p} is {kind}, not a risk segmenter (expected one saved by train-segmenter)"
            )
        try:
            model = UNet(int(ck["width"]), int(ck["depth"]))
            model.load_state_dict(ck["state_dict"])
        except (KeyError, RuntimeError, TypeError, ValueError) as exc:
            raise PerceptionError(
                f"{p}: checkpoint does not match the U-Net: {str(exc).splitlines()[0][:120]}"
            ) from None
        fs = ck.get("frame_size")
        return cls(model, tuple(ck["input_size"]), tuple(fs) if fs else None)  # type: ignore[arg-type]

    def predict(self, image_bgr: U8) -> U8:
        """Risk level 1..5 per pixel of the frame (H, W) uint8."""
        img = np.asarray(image_bgr)
        if img.dtype != np.uint8 or img.ndim != 3 or img.shape[2] != 3:
            raise PerceptionError(f"frame must be an HxWx3 uint8 BGR image, got {img.dtype} {img.shape}")
        h, w = img.shape[:2]
        if self.frame_size is not None and (w, h) != self.frame_size:
            fw, fh = self.frame_size
            raise PerceptionError(f"frame is {w}x{h}, but this segmenter was trained on {fw}x{fh} VAC frames")
        x = (
            cv2.resize(img, self.input_size, interpolation=cv2.INTER_AREA)
            if (w, h) != self.input_size
            else img
        )
        with torch.inference_mode():
            logits = self.model(_to_tensor([np.asarray(x)]))[0, 1:]
        pred = (logits.argmax(0) + 1).to(torch.uint8).numpy()
        if (w, h) != self.input_size:
            pred = cv2.resize(pred, (w, h), interpolation=cv2.INTER_NEAREST)
        return np.asarray(pred, np.uint8)

    @staticmethod
    def on_ground(
        levels: U8,
        pos_ned_m: ArrayLike | None = None,
        att_rpy_rad: ArrayLike | None = None,
        params: CameraParams | None = None,
        cell_m: float = 0.5,
        meta: Any = None,
    ) -> GroundRisk:
        """The image's levels on the ground (nearest pixel per ground cell) through the frame's pose: either
        (pos_ned_m, att_rpy_rad, params) or `meta` (a FrameMeta from the frame-and-pose socket, or its dict)."""
        if meta is not None:
            h = ground_homography_from_meta(meta)
        elif pos_ned_m is not None and att_rpy_rad is not None and params is not None:
            h = ground_to_image_homography(pos_ned_m, att_rpy_rad, params)
        else:
            raise PerceptionError(
                "on_ground needs the frame's pose: meta=FrameMeta, or pos_ned_m, att_rpy_rad, params"
            )
        rows_px, cols_px = levels.shape
        corners = np.array(
            [[-0.5, -0.5], [cols_px - 0.5, -0.5], [cols_px - 0.5, rows_px - 0.5], [-0.5, rows_px - 0.5]]
        )
        fp = image_to_ground(h, corners)
        if not np.all(np.isfinite(fp)):
            raise PerceptionError("the view reaches the horizon: no bounded ground footprint to map")
        n0, e0 = fp[:, 0].min(), fp[:, 1].min()
        rows = int(math.ceil((fp[:, 0].max() - n0) / cell_m)) + 1
        cols = int(math.ceil((fp[:, 1].max() - e0) / cell_m)) + 1
        if rows * cols > 16_000_000:
            raise PerceptionError(
                f"ground grid {cols}x{rows} at {cell_m} m is too large: use a larger cell_m"
            )
        nn_, ee = np.meshgrid(n0 + cell_m * np.arange(rows), e0 + cell_m * np.arange(cols), indexing="ij")
        q = np.stack([nn_.ravel(), ee.ravel(), np.ones(nn_.size)], axis=1) @ h.T
        ok = q[:, 2] > 1e-9
        u = np.full(nn_.size, -1.0)
        v = np.full(nn_.size, -1.0)
        u[ok], v[ok] = q[ok, 0] / q[ok, 2], q[ok, 1] / q[ok, 2]
        ui, vi = np.rint(u).astype(np.int64), np.rint(v).astype(np.int64)
        inside = ok & (ui >= 0) & (ui < cols_px) & (vi >= 0) & (vi < rows_px)
        out = np.zeros(nn_.size, np.uint8)
        out[inside] = levels[vi[inside], ui[inside]]
        return GroundRisk(out.reshape(rows, cols), float(n0), float(e0), float(cell_m))


def train_segmenter_cli(args: Any) -> int:
    """`viva-sitl perception train-segmenter` (arguments parsed in perception/cli.py)."""
    import json

    from tqdm import tqdm

    try:
        w, h = (int(v) for v in str(args.size).lower().split("x"))
    except ValueError:
        raise PerceptionError(f"--size must be WxH, got {args.size!r}") from None
    data_dir = Path(args.data)
    frame_size = None
    poses = sorted((data_dir / "poses" / "train").glob("*.json"))
    if poses:
        meta = json.loads(poses[0].read_text())
        frame_size = (int(meta["width_px"]), int(meta["height_px"]))
    out = Path(args.output)

    def keep_best(
        model: UNet, metrics: dict[str, Any]
    ) -> None:  # the best epoch so far, written as it improves
        tmp = out.with_name(out.name + ".tmp")
        save_segmenter(model, tmp, frame_size)
        tmp.replace(out)

    def log(line: str) -> None:
        print(line, flush=True)

    with tqdm(unit="step", disable=None) as bar:
        model, hist = train_segmenter(
            data_dir, args.epochs, (w, h), args.width, args.batch, lr=args.lr, seed=args.seed,
            progress=lambda s, loss: bar.update(1), weighted=not args.no_class_weights,
            augmented=not args.no_augment, patience=args.patience, time_limit_s=60.0 * args.time_limit_min,
            on_best=keep_best, log=log,
        )  # fmt: skip
    save_segmenter(model, out, frame_size)
    miou = hist.get("val_miou", math.nan)
    iou = ", ".join(f"L{k} {v:.2f}" for k, v in hist.get("val_iou_by_level", {}).items())
    print(
        f"wrote {out} (U-Net width {args.width}, {hist['train_images']} train images, {hist['epochs_run']} epochs, "
        f"loss {hist['loss'][0]:.3f} -> {hist['loss'][-1]:.3f}, val mIoU {miou:.3f}"
        + (f" at epoch {hist['best_epoch']}: {iou})" if "best_epoch" in hist else ")")
    )
    return 0
