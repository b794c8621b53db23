"""A bench-only shim (not part of viva-sitl) for running ultralytics on CPU-only torch without pulling CUDA torch.

PyPI's torchvision 0.28 wheel ships a _C.so linked against CUDA torch (libtorch_cuda, libc10_cuda), so next to
torch 2.13.0+cpu it cannot load and `import torchvision` fails on register_fake("torchvision::nms") ("operator
torchvision::nms does not exist"). This defines torchvision::nms / qnms in pure torch (greedy NMS, torchvision's
semantics) before torchvision imports, and marks its ops present, so ultralytics imports, trains and predicts
(detection uses only nms; roi_align & co. stay unavailable). Install into a separate venv (how issue 23's bench did):

    python3 -m venv V && V/bin/pip install /opt/wheels/torch-2.13.0+cpu-*.whl torchvision==0.28.0 \
        ultralytics-opencv-headless==8.4.190 onnx onnxruntime av pymavlink pyzmq tqdm aiohttp zstandard
    cp bench/torchvision_cpu_shim.py V/lib/python3.11/site-packages/tv_cpu_shim.py
    echo "import tv_cpu_shim" > V/lib/python3.11/site-packages/tv_cpu_shim.pth
    PYTHONPATH=. YOLO_OFFLINE=1 V/bin/python -m viva_sitl perception train-detector ...
"""

import torch

_lib = torch.library.Library("torchvision", "DEF")
_lib.define("nms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")
_lib.define("qnms(Tensor dets, Tensor scores, float iou_threshold) -> Tensor")


def _nms(dets: torch.Tensor, scores: torch.Tensor, iou_threshold: float) -> torch.Tensor:
    if dets.numel() == 0:
        return torch.empty((0,), dtype=torch.long, device=dets.device)
    x1, y1, x2, y2 = dets.unbind(1)
    areas = (x2 - x1) * (y2 - y1)
    order = scores.argsort(descending=True)
    keep = []
    while order.numel() > 0:
        i = order[0]
        keep.append(i)
        if order.numel() == 1:
            break
        rest = order[1:]
        xx1 = torch.maximum(x1[i], x1[rest])
        yy1 = torch.maximum(y1[i], y1[rest])
        xx2 = torch.minimum(x2[i], x2[rest])
        yy2 = torch.minimum(y2[i], y2[rest])
        inter = (xx2 - xx1).clamp(min=0) * (yy2 - yy1).clamp(min=0)
        iou = inter / (areas[i] + areas[rest] - inter)
        order = rest[iou <= iou_threshold]
    return torch.stack(keep).to(torch.long)


_lib.impl("nms", _nms, "CompositeExplicitAutograd")
_lib.impl("qnms", _nms, "CompositeExplicitAutograd")

import torchvision.extension as _ext  # noqa: E402

_ext._has_ops = lambda: True
