"""EDSR (Lim et al. 2017) in torch, small, trained self-supervised on footage: (downscaled, original) patch pairs.

Needs the `perception` extra (torch). Differences from the paper, for a model trained in minutes on a CPU from one
footage: fewer features/blocks by default, and the network predicts the residual over a bicubic upscale (so an
untrained or briefly trained model starts at bicubic quality instead of at noise).

    model, losses = train_edsr([frame_bgr, ...], scale=2, steps=300)
    save_edsr(model, "edsr_x2.pt");  up = load_edsr("edsr_x2.pt");  up.upscale(image_bgr)
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import torch
from numpy.typing import NDArray
from torch import nn

from viva_sitl.imaging import check_bgr
from viva_sitl.perception.errors import PerceptionError
from viva_sitl.perception.quality import degrade_area

U8 = NDArray[np.uint8]
CHECKPOINT_FORMAT = "viva-sitl-edsr"


class _ResBlock(nn.Module):
    def __init__(self, n_feats: int, res_scale: float) -> None:
        super().__init__()
        self.body = nn.Sequential(
            nn.Conv2d(n_feats, n_feats, 3, padding=1),
            nn.ReLU(inplace=True),
            nn.Conv2d(n_feats, n_feats, 3, padding=1),
        )
        self.res_scale = res_scale

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.body(x) * self.res_scale


class EDSR(nn.Module):
    """RGB in 0..1 (N, 3, H, W) -> (N, 3, H*scale, W*scale)."""

    def __init__(
        self, scale: int = 2, n_feats: int = 32, n_resblocks: int = 8, res_scale: float = 0.1
    ) -> None:
        super().__init__()
        if scale not in (2, 3, 4):
            raise PerceptionError(f"EDSR scale must be 2, 3 or 4, got {scale!r}")
        self.scale, self.n_feats, self.n_resblocks, self.res_scale = scale, n_feats, n_resblocks, res_scale
        self.head = nn.Conv2d(3, n_feats, 3, padding=1)
        self.body = nn.Sequential(
            *[_ResBlock(n_feats, res_scale) for _ in range(n_resblocks)],
            nn.Conv2d(n_feats, n_feats, 3, padding=1),
        )
        up: list[nn.Module] = []
        for s in [2, 2] if scale == 4 else [scale]:
            up += [nn.Conv2d(n_feats, n_feats * s * s, 3, padding=1), nn.PixelShuffle(s)]
        last = nn.Conv2d(n_feats, 3, 3, padding=1)
        nn.init.zeros_(last.weight)  # starts as exactly bicubic
        assert last.bias is not None
        nn.init.zeros_(last.bias)
        self.tail = nn.Sequential(*up, last)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        base = nn.functional.interpolate(x, scale_factor=self.scale, mode="bicubic", align_corners=False)
        f = self.head(x)
        return base + self.tail(f + self.body(f))


class EDSRUpscaler:
    """An EDSR as an `Upscaler` (BGR uint8 in and out), inference on the CPU without autograd."""

    def __init__(self, model: EDSR) -> None:
        self.model = model.eval()
        self.scale = int(model.scale)
        self.name = f"edsr_x{self.scale}"

    def upscale(self, image_bgr: U8) -> U8:
        img = check_bgr(image_bgr, error=PerceptionError)
        x = torch.from_numpy(np.ascontiguousarray(img[..., ::-1])).permute(2, 0, 1)[None].float() / 255.0
        with torch.inference_mode():
            y = self.model(x)[0].clamp_(0.0, 1.0).mul_(255.0).add_(0.5)
        return np.ascontiguousarray(y.byte().permute(1, 2, 0).numpy()[..., ::-1])


def save_edsr(model: EDSR, path: str | Path) -> None:
    torch.save(
        {
            "format": CHECKPOINT_FORMAT,
            "version": 1,
            "scale": model.scale,
            "n_feats": model.n_feats,
            "n_resblocks": model.n_resblocks,
            "res_scale": model.res_scale,
            "state_dict": model.state_dict(),
        },
        Path(path),
    )


def load_edsr(path: str | Path) -> EDSRUpscaler:
    """An EDSR checkpoint written by `save_edsr`; PerceptionError (one line) for a missing or foreign file."""
    p = Path(path)
    if not p.is_file():
        raise PerceptionError(
            f"EDSR weights not found: {p} (train them with `viva-sitl perception train-sr`)"
        )
    try:
        ck: Any = torch.load(p, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises many types for a foreign file (pickle, zip, runtime)
        raise PerceptionError(f"{p} is not a torch checkpoint: {str(exc).splitlines()[0][:120]}") from None
    if not isinstance(ck, dict) or ck.get("format") != CHECKPOINT_FORMAT:
        raise PerceptionError(f"{p} is not a viva-sitl EDSR checkpoint (expected one saved by save_edsr)")
    try:
        model = EDSR(int(ck["scale"]), int(ck["n_feats"]), int(ck["n_resblocks"]), float(ck["res_scale"]))
        model.load_state_dict(ck["state_dict"])
    except (KeyError, RuntimeError, TypeError, ValueError) as exc:
        raise PerceptionError(
            f"{p}: EDSR checkpoint does not match the model: {str(exc).splitlines()[0][:120]}"
        ) from None
    return EDSRUpscaler(model)


def train_edsr(
    images_bgr: Sequence[U8],
    scale: int = 2,
    steps: int = 300,
    patch_px: int = 32,
    batch: int = 16,
    lr: float = 1e-3,
    seed: int = 0,
    n_feats: int = 32,
    n_resblocks: int = 8,
    progress: Callable[[int, float], None] | None = None,
) -> tuple[EDSR, list[float]]:
    """Self-supervised: random HR patches of the images, their `degrade`d LR versions, L1 loss, Adam."""
    if not images_bgr:
        raise PerceptionError("train_edsr needs at least one image")
    hr_side = patch_px * scale
    for k, im in enumerate(images_bgr):
        if im.shape[0] < hr_side or im.shape[1] < hr_side:
            raise PerceptionError(
                f"training image {k} ({im.shape[1]}x{im.shape[0]}) is smaller than {hr_side} px"
            )
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    model = EDSR(scale, n_feats, n_resblocks)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(1, steps))
    losses: list[float] = []
    model.train()
    for step in range(steps):
        hrs, lrs = [], []
        for _ in range(batch):
            im = images_bgr[int(rng.integers(len(images_bgr)))]
            y = int(rng.integers(0, im.shape[0] - hr_side + 1))
            x = int(rng.integers(0, im.shape[1] - hr_side + 1))
            hr = im[y : y + hr_side, x : x + hr_side]
            if rng.random() < 0.5:
                hr = hr[:, ::-1]
            hr = np.ascontiguousarray(np.rot90(hr, int(rng.integers(4))))
            hrs.append(hr[..., ::-1])
            lrs.append(degrade_area(hr, scale)[..., ::-1])
        t_hr = torch.from_numpy(np.ascontiguousarray(np.stack(hrs))).permute(0, 3, 1, 2).float() / 255.0
        t_lr = torch.from_numpy(np.ascontiguousarray(np.stack(lrs))).permute(0, 3, 1, 2).float() / 255.0
        loss = nn.functional.l1_loss(model(t_lr), t_hr)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        losses.append(float(loss.detach()))
        if progress is not None:
            progress(step, losses[-1])
    if not all(math.isfinite(v) for v in losses):
        raise PerceptionError("EDSR training diverged (non-finite loss); lower the learning rate")
    return model.eval(), losses
