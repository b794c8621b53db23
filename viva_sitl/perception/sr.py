"""Super-resolution of the footage region the VAC magnifies (low flight): FSRCNN/ESPCN via OpenCV dnn, EDSR in torch.

When the camera flies low, one footage pixel covers more than one VAC pixel and the bilinear warp shows blocky,
soft footage. `MagnifiedRender` (set as `Simulator.super_resolution`) then crops the footage region the VAC sees,
upscales it with a learned model and warps from the upscaled crop instead:

    cfg = SRConfig(method="fsrcnn", model_path="models/sr/FSRCNN_x2.pb", min_magnification=1.0)
    sim.super_resolution = magnified_render_from_config(cfg)      # None for method "none"

Methods (`SRConfig.method`): none | bicubic | fsrcnn | espcn | edsr.
- fsrcnn / espcn: the TensorFlow graphs of OpenCV's dnn_superres model zoo (FSRCNN_x2.pb, ESPCN_x3.pb, ...), loaded
  from a user path (none shipped). opencv-python-headless has no `cv2.dnn_superres`, and OpenCV 5's TensorFlow
  importer rejects their `DepthToSpace` node (it expects an attribute named differently), so `OpenCVSR` removes the
  graph's tail (DepthToSpace, then Tanh / BiasAdd, Transpose) before handing it to `cv2.dnn`, and does the pixel
  shuffle and the tail's arithmetic in numpy. The models see the luma channel (YCrCb, 0..1); chroma is bicubic, as
  dnn_superres does.
- edsr: our EDSR (viva_sitl/perception/edsr.py, torch), trained self-supervised on footage (downscaled/original
  pairs) by `viva-sitl perception train-sr`; checkpoints written by `save_edsr`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Protocol

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from viva_sitl.camera.effects import add_sensor_noise, apply_motion_blur
from viva_sitl.camera.projection import (
    _vec3,
    camera_extrinsics,
    footage_to_image_homography,
    image_corners_px,
)
from viva_sitl.camera.renderer import Renderer, RenderResult
from viva_sitl.imaging import check_bgr
from viva_sitl.perception.config import SRConfig, SRMethod
from viva_sitl.perception.errors import PerceptionError, require_torch

U8 = NDArray[np.uint8]
F64 = NDArray[np.float64]


class Upscaler(Protocol):
    name: str
    scale: int

    def upscale(self, image_bgr: U8) -> U8: ...


class BicubicUpscaler:
    """The reference: cv2.resize INTER_CUBIC."""

    def __init__(self, scale: int) -> None:
        self.name = f"bicubic_x{scale}"
        self.scale = scale

    def upscale(self, image_bgr: U8) -> U8:
        img = check_bgr(image_bgr, error=PerceptionError)
        h, w = img.shape[:2]
        return np.asarray(cv2.resize(img, (w * self.scale, h * self.scale), interpolation=cv2.INTER_CUBIC))


# --- TensorFlow GraphDef surgery (protobuf wire format; hand-written: no protobuf schema for GraphDef here) ---------


def _varint(b: bytes, i: int) -> tuple[int, int]:
    r = s = 0
    while True:
        if i >= len(b):
            raise ValueError("truncated varint")
        c = b[i]
        i += 1
        r |= (c & 0x7F) << s
        s += 7
        if c < 0x80:
            return r, i


def _fields(b: bytes) -> list[tuple[int, int, bytes | int, bytes]]:
    """Top-level fields of a protobuf message: (number, wire type, payload or int, raw bytes of the whole field)."""
    out: list[tuple[int, int, bytes | int, bytes]] = []
    i = 0
    while i < len(b):
        start = i
        key, i = _varint(b, i)
        num, wt = key >> 3, key & 7
        val: bytes | int
        if wt == 0:
            val, i = _varint(b, i)
        elif wt == 2:
            n, i = _varint(b, i)
            val = b[i : i + n]
            if len(val) != n:
                raise ValueError("truncated field")
            i += n
        elif wt == 5:
            val, i = b[i : i + 4], i + 4
        elif wt == 1:
            val, i = b[i : i + 8], i + 8
        else:
            raise ValueError(f"unsupported wire type {wt}")
        out.append((num, wt, val, b[start:i]))
    return out


@dataclass
class _Node:
    name: str
    op: str
    inputs: list[str]
    attrs: dict[str, bytes]
    raw: bytes


def _parse_nodes(graph: bytes) -> tuple[list[_Node], list[bytes]]:
    nodes: list[_Node] = []
    other: list[bytes] = []
    for num, wt, val, raw in _fields(graph):
        if num == 1 and wt == 2 and isinstance(val, bytes):
            name = op = ""
            inputs: list[str] = []
            attrs: dict[str, bytes] = {}
            for n2, _, v2, _ in _fields(val):
                if not isinstance(v2, bytes):
                    continue
                if n2 == 1:
                    name = v2.decode()
                elif n2 == 2:
                    op = v2.decode()
                elif n2 == 3:
                    inputs.append(v2.decode())
                elif n2 == 5:
                    entry = {k: v for k, _, v, _ in _fields(v2)}
                    key, value = entry.get(1), entry.get(2)
                    if isinstance(key, bytes) and isinstance(value, bytes):
                        attrs[key.decode()] = value
            nodes.append(_Node(name, op, inputs, attrs, raw))
        else:
            other.append(raw)
    return nodes, other


def _attr_int(attr: bytes) -> int | None:
    for num, wt, val, _ in _fields(attr):
        if num == 3 and wt == 0 and isinstance(val, int):
            return val
    return None


def _const_floats(node: _Node) -> NDArray[np.float32]:
    """Values of a float Const node (tensor_content or float_val)."""
    tensor = next((v for n, _, v, _ in _fields(node.attrs.get("value", b"")) if n == 8), None)
    if not isinstance(tensor, bytes):
        raise ValueError(f"Const {node.name} has no tensor")
    for num, wt, val, _ in _fields(tensor):
        if num == 4 and isinstance(val, bytes):
            return np.frombuffer(val, "<f4").copy()
        if num == 5 and wt == 2 and isinstance(val, bytes):
            return np.frombuffer(val, "<f4").copy()
        if num == 5 and wt == 5 and isinstance(val, bytes):
            return np.frombuffer(val, "<f4").copy()
    raise ValueError(f"Const {node.name} holds no float values")


def _pixel_shuffle(x: NDArray[np.float32], s: int) -> NDArray[np.float32]:
    """TF DepthToSpace (DCR) of one output channel: (s*s, H, W) -> (H*s, W*s); channel i*s + j -> offset (i, j)."""
    c, h, w = x.shape
    if c != s * s:
        raise ValueError(f"expected {s * s} channels before the pixel shuffle, got {c}")
    return np.ascontiguousarray(x.reshape(s, s, h, w).transpose(2, 0, 3, 1).reshape(h * s, w * s))


class OpenCVSR:
    """FSRCNN / ESPCN .pb of OpenCV's dnn_superres zoo, run by cv2.dnn (see the module docstring)."""

    def __init__(self, model_path: str | Path, expect: SRMethod | None = None) -> None:
        path = Path(model_path)
        if not path.is_file():
            raise PerceptionError(
                f"super-resolution model not found: {path} (give the path of e.g. FSRCNN_x2.pb)"
            )
        data = path.read_bytes()
        try:
            nodes, other = _parse_nodes(data)
        except (ValueError, UnicodeDecodeError):
            nodes, other = [], []
        d2s = next((n for n in nodes if n.op == "DepthToSpace"), None)
        if d2s is None or len(d2s.inputs) != 1:
            raise PerceptionError(
                f"{path} is not an FSRCNN/ESPCN TensorFlow graph of OpenCV's dnn_superres zoo (no DepthToSpace node)"
            )
        scale = _attr_int(d2s.attrs.get("block_size", b""))
        if scale not in (2, 3, 4):
            raise PerceptionError(f"{path}: unsupported DepthToSpace block size {scale!r}")
        by_name = {n.name: n for n in nodes}
        # the tail after DepthToSpace: a chain of single-input consumers
        tail: list[_Node] = []
        cur = d2s.name
        while True:
            nxt = [n for n in nodes if n.inputs and n.inputs[0] == cur]
            if not nxt:
                break
            tail.append(nxt[0])
            cur = nxt[0].name
        self._post: list[tuple[str, NDArray[np.float32] | None]] = []
        for n in tail:
            if n.op == "Tanh":
                self._post.append(("tanh", None))
            elif n.op in ("BiasAdd", "Add") and len(n.inputs) == 2 and n.inputs[1] in by_name:
                self._post.append(("add", _const_floats(by_name[n.inputs[1]])))
            elif n.op in ("Transpose", "Identity"):
                pass
            else:
                raise PerceptionError(f"{path}: unsupported op {n.op} after DepthToSpace")
        kind = SRMethod.ESPCN if any(op == "tanh" for op, _ in self._post) else SRMethod.FSRCNN
        if expect is not None and expect is not kind:
            raise PerceptionError(f"{path} is an {kind.value} model, but the method asks for {expect.value}")
        removed = {d2s.name} | {n.name for n in tail}
        still_used = {i.split(":")[0].lstrip("^") for n in nodes if n.name not in removed for i in n.inputs}
        removed |= {i for n in tail for i in n.inputs[1:] if i not in still_used}
        graph = b"".join([n.raw for n in nodes if n.name not in removed] + other)
        try:
            self._net = cv2.dnn.readNetFromTensorflow(np.frombuffer(graph, np.uint8))
        except cv2.error as exc:
            msg = str(exc).strip().splitlines()[-1] if str(exc).strip() else "unknown error"
            raise PerceptionError(f"OpenCV cannot load {path}: {msg}") from None
        self.scale = int(scale)
        self.kind = kind
        self.name = f"{kind.value}_x{scale}"

    def upscale_luma(self, y01: NDArray[np.float32]) -> NDArray[np.float32]:
        """Luma (H, W) in 0..1 -> (H*s, W*s) in about 0..1."""
        self._net.setInput(y01[None, None].astype(np.float32))
        out = np.asarray(self._net.forward(), np.float32)[0]
        y = _pixel_shuffle(out, self.scale)
        for op, val in self._post:
            if op == "tanh":
                y = np.tanh(y)
            elif val is not None:
                y = y + val.reshape(-1)[0]
        return y

    def upscale(self, image_bgr: U8) -> U8:
        img = check_bgr(image_bgr, error=PerceptionError)
        h, w = img.shape[:2]
        ycc = cv2.cvtColor(img, cv2.COLOR_BGR2YCrCb)
        y = self.upscale_luma(ycc[..., 0].astype(np.float32) / 255.0)
        out = np.asarray(cv2.resize(ycc, (w * self.scale, h * self.scale), interpolation=cv2.INTER_CUBIC))
        out[..., 0] = np.clip(y * 255.0 + 0.5, 0, 255).astype(np.uint8)
        return np.asarray(cv2.cvtColor(out, cv2.COLOR_YCrCb2BGR))


def load_upscaler(config: SRConfig) -> Upscaler | None:
    """The upscaler the config names (None for method none); PerceptionError with one line on bad input."""
    m = config.method
    if m is SRMethod.NONE:
        return None
    if m is SRMethod.BICUBIC:
        return BicubicUpscaler(config.scale)
    if not config.model_path:
        raise PerceptionError(f"super-resolution method {m.value} needs model_path (a weights file)")
    if m in (SRMethod.FSRCNN, SRMethod.ESPCN):
        return OpenCVSR(config.model_path, expect=m)
    require_torch()
    from viva_sitl.perception.edsr import load_edsr

    return load_edsr(config.model_path)


# --- the render path ---------------------------------------------------------------------------------------------

_W_EPS = 1e-9
_MARGIN_PX = 3  # footage pixels around the footprint's bounding box (bicubic/bilinear reads neighbours)


class MagnifiedRender:
    """Renders the VAC from an upscaled footage crop when it magnifies the footage more than `min_magnification`.

    `magnified(renderer, pos, att)` is the cheap test (no image); `render(...)` does the work. Both use the same
    homography as `Renderer.render`, so the geometry of the image is unchanged; only the texture is sharper.
    """

    def __init__(self, upscaler: Upscaler, min_magnification: float = 1.0) -> None:
        if not (math.isfinite(min_magnification) and min_magnification > 0.0):
            raise PerceptionError(f"min_magnification must be a positive number, got {min_magnification!r}")
        self.upscaler = upscaler
        self.min_magnification = float(min_magnification)
        self.renders = 0  # statistics: frames served upscaled

    @staticmethod
    def _vac_to_geometry(renderer: Renderer, pos: F64, att: F64) -> tuple[F64, F64]:
        h_f2i = footage_to_image_homography(renderer.geometry, pos, att, renderer.params)
        m = np.linalg.inv(h_f2i)
        return h_f2i, m / np.max(np.abs(m))

    def magnification(self, renderer: Renderer, pos_ned_m: ArrayLike, att_rpy_rad: ArrayLike) -> float:
        """VAC pixels per full-resolution footage pixel at the image centre (nan: the centre sees no ground)."""
        _, m = self._vac_to_geometry(
            renderer, _vec3("pos_ned_m", pos_ned_m), _vec3("att_rpy_rad", att_rpy_rad)
        )
        _, rho = renderer.choose_level(m, 0)
        return 1.0 / rho if math.isfinite(rho) and rho > 0.0 else math.nan

    def magnified(self, renderer: Renderer, pos_ned_m: ArrayLike, att_rpy_rad: ArrayLike) -> bool:
        """True when this pose should render from an upscaled crop (magnified, every corner ray hits the ground)."""
        p = renderer.params
        if p.has_distortion or renderer.geometry.unbounded:
            return False
        pos, att = _vec3("pos_ned_m", pos_ned_m), _vec3("att_rpy_rad", att_rpy_rad)
        _, m = self._vac_to_geometry(renderer, pos, att)
        _, rho = renderer.choose_level(m, 0)
        if not (math.isfinite(rho) and rho > 0.0 and 1.0 / rho > self.min_magnification):
            return False
        c = np.column_stack([image_corners_px(p), np.ones(4)]) @ m.T
        return bool(np.all(c[:, 2] > _W_EPS))

    def render(
        self,
        renderer: Renderer,
        image0_bgr: U8,
        pos_ned_m: ArrayLike,
        att_rpy_rad: ArrayLike,
        vel_ned_m_s: ArrayLike | None = None,
        rng: np.random.Generator | None = None,
    ) -> RenderResult:
        """The VAC image warped from the upscaled footage crop (`image0_bgr`: the full-resolution footage frame)."""
        p = renderer.params
        pos, att = _vec3("pos_ned_m", pos_ned_m), _vec3("att_rpy_rad", att_rpy_rad)
        src = check_bgr(image0_bgr, "footage frame", PerceptionError)
        geom_to_src = renderer._image_scale(src)
        h_f2i, _ = self._vac_to_geometry(renderer, pos, att)
        vac_to_src = np.linalg.inv(h_f2i @ np.linalg.inv(geom_to_src))
        vac_to_src /= np.max(np.abs(vac_to_src))
        src_h, src_w = src.shape[:2]
        _, rho = renderer.choose_level(vac_to_src, 0)
        cam_rot_body, _ = camera_extrinsics(p, att)
        coverage = renderer.coverage(vac_to_src, src_w, src_h)
        c = np.column_stack([image_corners_px(p), np.ones(4)]) @ vac_to_src.T
        if coverage == 0.0 or not np.all(c[:, 2] > _W_EPS):
            return renderer.render(src, pos, att, vel_ned_m_s, rng)  # not a magnified nadir-ish view
        xy = c[:, :2] / c[:, 2:3]
        x0 = max(0, math.floor(float(xy[:, 0].min())) - _MARGIN_PX)
        y0 = max(0, math.floor(float(xy[:, 1].min())) - _MARGIN_PX)
        x1 = min(src_w, math.ceil(float(xy[:, 0].max())) + _MARGIN_PX + 1)
        y1 = min(src_h, math.ceil(float(xy[:, 1].max())) + _MARGIN_PX + 1)
        if x1 <= x0 or y1 <= y0:
            return renderer.render(src, pos, att, vel_ned_m_s, rng)
        up = self.upscaler.upscale(np.ascontiguousarray(src[y0:y1, x0:x1]))
        s = float(self.upscaler.scale)
        # upscaled pixel (U, V) has its centre at crop pixel ((U + 0.5) / s - 0.5): pixel edges stay aligned
        up_to_src = np.array(
            [[1 / s, 0.0, x0 + 0.5 / s - 0.5], [0.0, 1 / s, y0 + 0.5 / s - 0.5], [0.0, 0.0, 1.0]]
        )
        vac_to_up = np.linalg.inv(up_to_src) @ vac_to_src
        fill = tuple(float(v) for v in p.fill_bgr)
        image = np.asarray(
            cv2.warpPerspective(
                up,
                vac_to_up,
                (p.width_px, p.height_px),
                flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                borderMode=cv2.BORDER_CONSTANT,
                borderValue=fill,
            ),  # fmt: skip
            np.uint8,
        )
        vel = None if vel_ned_m_s is None else _vec3("vel_ned_m_s", vel_ned_m_s)
        if p.motion_blur and vel is not None and p.exposure_s > 0.0:
            image = apply_motion_blur(image, renderer._blur_shift_px(pos, att, vel))
        if p.noise_std > 0.0 and rng is not None:
            image = add_sensor_noise(image, p.noise_std, rng)
        self.renders += 1
        return RenderResult(np.asarray(image, np.uint8), coverage, h_f2i, 0, rho, cam_rot_body)


def magnified_render_from_config(config: SRConfig) -> MagnifiedRender | None:
    """What `Simulator.super_resolution` should hold for a config (None for method none)."""
    up = load_upscaler(config)
    return None if up is None else MagnifiedRender(up, config.min_magnification)
