"""Footage sources: the frame shown at simulation time t, decoded on demand.

Threading: a source is meant to be used by one thread (the renderer's worker). `frame()` holds an internal lock, so
calls from several threads are safe but serialised; `frame_index_at()`, `annotations()` and the properties are
cheap and side-effect free. Returned frames are read-only BGR uint8 arrays owned by the source's cache: copy before
writing into them.
"""

from __future__ import annotations

import abc
import enum
import logging
import math
import threading
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import TYPE_CHECKING, Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

from viva_sitl.footage.annotations import Annotation, AnnotationStore
from viva_sitl.footage.errors import FootageError
from viva_sitl.footage.geometry import FootageGeometry
from viva_sitl.footage.metadata import FootageMetadata

if TYPE_CHECKING:
    import av  # PyAV loads when a video is opened: sources of stills and the synthetic field never need it

log = logging.getLogger(__name__)

# Decoding forward is cheaper than seeking (seek = back to the previous keyframe, then decode forward) for short
# jumps; beyond this many frames ahead we seek.
SEEK_AHEAD_FRAMES = 48
# Widest frame converted to BGR by swscale; wider ones go through OpenCV (see to_bgr).
SWSCALE_MAX_WIDTH_PX = 4096
# Decoded (YUV) frames a decoder keeps: the current one and a prefetched next one, plus one spare.
RECENT_RAW_FRAMES = 3


def _readonly(img: NDArray[np.uint8]) -> NDArray[np.uint8]:
    img.setflags(write=False)
    return img


class RegionRead(enum.Enum):
    """How a source can serve part of a frame (what the renderer's region path reads)."""

    NONE = "none"  # whole frames only (`frame`)
    CROP = "crop"  # `frame_region`: the decoded frame, only the asked crop converted to BGR (a 4:2:0 video)
    TILES = "tiles"  # `region`: stored pyramid levels, only the tiles under the region decoded (a tile cache)


@dataclass(frozen=True)
class FootageCapabilities:
    """What a footage source can do beyond `frame(index)`: declared by the source, asked by its users (the
    Simulator's render paths, ingest) instead of switching on the source's type.

    `region`: the partial reads it serves (RegionRead). `reduced_copies`: `frame(index, level=k)` /
    `frame_region(..., level=k)` decode a separately stored 1/2^k copy (an ingest cache's levels; `level_count`,
    `level_size_px` say which exist). `prefetch`: `prefetch()` decodes ahead, worth a read-ahead thread (a stateful
    decoder). `ground_view`: an edgeless procedural ground, rendered through `ground_view()` from a window drawn
    around the camera's footprint. `per_view`: the source keeps state that follows ONE camera (the ground window),
    so each concurrent view needs its own source; without it one open source may serve several views (a vector env
    shares it). `region_decodes`: each region read decodes compressed data (a tile cache's jpeg / yuv420z tiles; not
    raw tiles), so a coarser level is cheaper to derive by halving a finer one than to read.
    """

    region: RegionRead = RegionRead.NONE
    reduced_copies: bool = False
    prefetch: bool = False
    ground_view: bool = False
    per_view: bool = False
    region_decodes: bool = False


class FootageSource(abc.ABC):
    """A footage (video, still or synthetic field) with its ground geometry.

    Optional abilities (`capabilities` says which a source has) have harmless defaults here, so that callers
    need no type checks: `frame_region` returns None, `prefetch` does nothing, `level_count` is 1; `region` and
    `ground_view` raise NotImplementedError on a source that does not declare them.
    """

    geometry: FootageGeometry
    metadata: FootageMetadata

    @property
    def capabilities(self) -> FootageCapabilities:
        """What this source can do beyond whole frames (default: nothing)."""
        return FootageCapabilities()

    @property
    @abc.abstractmethod
    def fps(self) -> float:
        """Playback rate, frames per second of simulation time."""

    @property
    @abc.abstractmethod
    def frame_count(self) -> int: ...

    @property
    def duration_s(self) -> float:
        return self.frame_count / self.fps

    def frame_index_at(self, t_s: float) -> int:
        """The frame shown at simulation time t: floor(t * fps) mod frame_count (looping, deterministic)."""
        if not math.isfinite(t_s):
            raise ValueError(f"time must be finite, got {t_s!r}")
        if self.frame_count <= 1:
            return 0
        # the 1e-9 keeps t = k / fps on frame k despite float rounding (k / fps * fps may be k - 1e-15)
        return int(math.floor(t_s * self.fps + 1e-9)) % self.frame_count

    @abc.abstractmethod
    def frame(self, index: int) -> NDArray[np.uint8]:
        """Frame `index` (0-based, taken modulo frame_count) as a read-only BGR uint8 array (H, W, 3)."""

    def frame_at(self, t_s: float) -> NDArray[np.uint8]:
        return self.frame(self.frame_index_at(t_s))

    def annotations(self, index: int) -> list[Annotation]:
        """Ground-truth/labelled objects in frame `index` (empty when the footage has none)."""
        return []

    # --- optional abilities (see `capabilities`) ---------------------------------------------------------
    @property
    def frame_size_px(self) -> tuple[int, int]:
        """(width, height) of the level-0 frames."""
        return (self.geometry.width_px, self.geometry.height_px)

    @property
    def level_count(self) -> int:
        """Resolution levels `frame(index, level)` / `level_size_px` know (1: the frame only)."""
        return 1

    def level_size_px(self, level: int) -> tuple[int, int] | None:
        """(width, height) of level `level` (0: the frame); None where the source has no such level."""
        return self.frame_size_px if level == 0 else None

    def frame_region(
        self, index: int, x0: int, y0: int, x1: int, y1: int, level: int = 0
    ) -> NDArray[np.uint8] | None:
        """`frame(index)[y0:y1, x0:x1]` converting only that region (RegionRead.CROP); None: not available, read
        the whole frame."""
        return None

    def region(
        self,
        index: int,
        level: int,
        x0: int,
        y0: int,
        x1: int,
        y1: int,
        out: NDArray[np.uint8] | None = None,
        quad: NDArray[np.float64] | None = None,
        margin_px: float = 0.0,
    ) -> NDArray[np.uint8]:
        """Pixels [y0:y1, x0:x1] of pyramid level `level` of frame `index` (RegionRead.TILES)."""
        raise NotImplementedError(f"{type(self).__name__} serves no pyramid regions (capabilities.region)")

    def prefetch(self, index: int, level: int = 0, only_next: bool = False) -> None:  # noqa: B027 - optional
        """Decode frame `index` ahead of its read (capabilities.prefetch); nothing to do by default."""

    def ground_view(
        self,
        index: int,
        camera_ned_m: ArrayLike,
        rays_ned: NDArray[np.float64],
        ground_px_m: float,
    ) -> tuple[NDArray[np.uint8], FootageGeometry]:
        """A window of an edgeless ground around the camera's footprint and its geometry
        (capabilities.ground_view)."""
        raise NotImplementedError(f"{type(self).__name__} has no edgeless ground (capabilities.ground_view)")

    def close(self) -> None:  # noqa: B027 - optional hook, nothing to release by default
        """Release decoders and files. Idempotent."""

    def __enter__(self) -> FootageSource:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def describe(self) -> dict[str, Any]:
        """A flat summary for `viva-sitl footage info` and logs."""
        g = self.geometry
        out: dict[str, Any] = {
            "name": self.metadata.name,
            "title": self.metadata.title,
            "kind": self.metadata.kind.value,
            "path": self.metadata.path,
            "size_px": f"{g.width_px}x{g.height_px}",
            "fps": round(self.fps, 4),
            "frame_count": self.frame_count,
            "duration_s": round(self.duration_s, 3),
            "gsd_m_per_px": round(g.gsd_m_per_px, 5),
            "recording_altitude_m": round(g.recording_altitude_m, 2),
            "recording_hfov_deg": round(g.recording_hfov_deg, 2),
            "heading_deg": round(g.heading_deg, 2),
            "ground_size_m": f"{g.ground_width_m:.1f} x {g.ground_height_m:.1f}",
        }
        if g.unbounded:
            out["ground_size_m"] = (
                f"unbounded (procedural; nominal frame {g.ground_width_m:.1f} x {g.ground_height_m:.1f})"
            )
        if g.geo_origin is not None:
            out["geo_origin"] = f"{g.geo_origin.lat_deg:.7f}, {g.geo_origin.lon_deg:.7f}"
        for key in ("licence", "attribution", "annotations_path", "notes"):
            if getattr(self.metadata, key):
                out[key] = getattr(self.metadata, key)
        return out


class StillSource(FootageSource):
    """A still image (one frame, read once with cv2.imread)."""

    def __init__(
        self, metadata: FootageMetadata, geometry: FootageGeometry, image: NDArray[np.uint8]
    ) -> None:
        self.metadata = metadata
        self.geometry = geometry
        self._image = _readonly(image)
        self._fps = metadata.fps or 30.0
        self._annotations = AnnotationStore(
            metadata.annotations_path, metadata.annotations_format, geometry, metadata.class_names, still=True
        )

    @staticmethod
    def read(path: Path) -> NDArray[np.uint8]:
        if not path.is_file():
            raise FootageError(f"footage not found: {path}")
        img = cv2.imread(str(path), cv2.IMREAD_COLOR)
        if img is None or img.size == 0:
            raise FootageError(f"cannot read image {path} (not an image OpenCV can decode)")
        return np.ascontiguousarray(img, dtype=np.uint8)

    @property
    def fps(self) -> float:
        return self._fps

    @property
    def frame_count(self) -> int:
        return 1

    def frame_index_at(self, t_s: float) -> int:
        return 0

    def frame(self, index: int) -> NDArray[np.uint8]:
        return self._image

    def annotations(self, index: int) -> list[Annotation]:
        return self._annotations.get(0)


class _Decoder:
    """One PyAV decoder over one file: sequential fast path, keyframe seek for backward or long jumps."""

    def __init__(self, path: Path) -> None:
        import av

        try:
            self.container = av.open(str(path), mode="r")
        except (av.FFmpegError, OSError) as exc:
            raise FootageError(f"cannot open video {path}: {getattr(exc, 'strerror', None) or exc}") from None
        try:
            if not self.container.streams.video:
                raise FootageError(f"{path} has no video stream")
            self.stream = self.container.streams.video[0]
            self.stream.thread_type = "AUTO"  # frame+slice threads: decode uses the free cores
            rate = self.stream.average_rate or self.stream.guessed_rate or self.stream.base_rate
            if not rate or rate <= 0:
                raise FootageError(f"{path}: the video stream has no frame rate")
            self.native_fps = float(rate)
            self._rate = Fraction(rate)
            self.time_base = self.stream.time_base or Fraction(1, 90000)
            self.start_pts = self.stream.start_time or 0
            self.width = int(self.stream.codec_context.width)
            self.height = int(self.stream.codec_context.height)
            if self.width <= 0 or self.height <= 0:
                raise FootageError(f"{path}: the video stream has no picture size")
            self.frame_count = self._count_frames()
        except av.FFmpegError as exc:
            self.container.close()
            raise FootageError(f"cannot read video {path}: {exc}") from None
        except BaseException:
            self.container.close()  # nothing half-open
            raise
        self.path = path
        self._iter: Any = None
        self._last_index = -1
        # the last RECENT_RAW_FRAMES decoded frames (YUV) by index, newest last: a prefetch of frame i + 1 must not
        # make a second request for frame i seek back
        self._recent: dict[int, av.VideoFrame] = {}
        # the last frame decoded (returned past the end of the stream)
        self._newest: av.VideoFrame | None = None
        self._last: NDArray[np.uint8] | None = None  # the one converted frame, see `_last_bgr`
        self._last_bgr: tuple[int, bool] = (-1, True)  # (index, converted to BGR) of `_last`
        self._scratch: list[av.VideoFrame] = []  # crop_to_bgr's reusable frames (one per recent crop size)
        self.seeks = 0  # statistics (tests, bench)
        self.decoded = 0

    def _count_frames(self) -> int:
        n = int(self.stream.frames or 0)
        if n > 0:
            return n
        if self.stream.duration:  # no frame count in the header (e.g. MKV): duration x rate
            return max(1, round(float(self.stream.duration * self.time_base * self._rate)))
        if self.container.duration:
            import av

            return max(1, round(self.container.duration / av.time_base * self.native_fps))
        count = sum(1 for p in self.container.demux(self.stream) if p.size > 0)  # last resort: count packets
        self.container.seek(0, stream=self.stream)
        return count

    def _index_of(self, frame: av.VideoFrame) -> int:
        pts = frame.pts if frame.pts is not None else frame.dts
        if pts is None:
            return self._last_index + 1
        return round((pts - self.start_pts) * self.time_base * self._rate)

    def _pts_of(self, index: int) -> int:
        return int(self.start_pts + round(Fraction(index) / self._rate / self.time_base))

    def _restart(self, index: int) -> None:
        if index > 0:
            self.container.seek(self._pts_of(index), stream=self.stream, backward=True, any_frame=False)
        else:
            self.container.seek(self.start_pts, stream=self.stream, backward=True, any_frame=False)
        self.seeks += 1
        self._iter = self.container.decode(self.stream)
        self._last_index = -1

    def _next(self) -> av.VideoFrame | None:
        import av

        try:
            f: av.VideoFrame = next(self._iter)
        except StopIteration:
            return None
        except av.FFmpegError as exc:
            raise FootageError(f"{self.path}: decode error after frame {self._last_index}: {exc}") from None
        self.decoded += 1
        return f

    def get(self, index: int, convert: bool = True) -> NDArray[np.uint8]:
        raw = self.get_raw(index)
        key = (self._key_of(raw), convert)
        if self._last is not None and self._last_bgr == key:
            return self._last
        # convert=False: planar YUV (bench)
        conv = to_bgr(raw) if convert else np.asarray(raw.to_ndarray(), dtype=np.uint8)
        self._last, self._last_bgr = _readonly(conv), key
        return self._last

    def get_region(self, index: int, x0: int, y0: int, x1: int, y1: int) -> NDArray[np.uint8] | None:
        """`get(index)[y0:y1, x0:x1]`, bit-identical, converting only that region (None: not a 4:2:0 frame)."""
        raw = self.get_raw(index)
        if self._last is not None and self._last_bgr == (self._key_of(raw), True):
            return self._last[y0:y1, x0:x1]  # already converted in full
        return crop_to_bgr(raw, x0, y0, x1, y1, self._scratch)

    def _key_of(self, raw: av.VideoFrame) -> int:
        return next((i for i, f in self._recent.items() if f is raw), -1)

    def is_next(self, index: int, frame_count: int) -> bool:
        """True when `index` is the frame right after the decoder's position (or the loop's wrap to frame 0 from
        the clip's last two frames), is kept already, or nothing was decoded yet: what a prefetch is for. Any other
        index is a prefetch that ran late, after its caller moved on: decoding it would seek back, or decode ahead
        past the caller's next frames, and the caller's next read would seek again."""
        if self._iter is None or index in self._recent or index == self._last_index + 1:
            return True
        return index == 0 and self._last_index >= frame_count - 2

    def get_raw(self, index: int) -> av.VideoFrame:
        """The decoded frame `index` (YUV, as the codec outputs it; the last one at the end of the stream)."""
        cached = self._recent.get(index)
        if cached is not None:
            return cached
        restarted = False
        if self._iter is None or index <= self._last_index or index > self._last_index + SEEK_AHEAD_FRAMES:
            self._restart(index)
            restarted = True
        frame: av.VideoFrame | None = None
        fell_back = False
        while True:
            f = self._next()
            if f is None:
                break
            i = self._index_of(f)
            if i > index and frame is None and restarted and index > 0 and not fell_back:
                # the seek landed after the target (an odd index or an open GOP): decode from the start instead
                self._restart(0)
                fell_back = True
                continue
            frame, self._last_index = f, i
            if i >= index:
                break
        if frame is None:
            if self._newest is not None:
                return self._newest
            raise FootageError(f"{self.path}: no frame could be decoded (corrupt or empty video)")
        if self._last_index != index:
            log.debug("%s: asked for frame %d, got %d (end of stream)", self.path, index, self._last_index)
        self._newest = frame
        self._recent[self._last_index] = frame
        while len(self._recent) > RECENT_RAW_FRAMES:
            del self._recent[next(iter(self._recent))]
        return frame

    def close(self) -> None:
        self._iter = None
        self._recent.clear()
        self._newest = self._last = None
        self._scratch.clear()
        self.container.close()


def to_bgr(frame: av.VideoFrame) -> NDArray[np.uint8]:
    """Decoded frame -> BGR uint8 (H, W, 3).

    swscale (PyAV's `bgr24`) is fastest up to 4K (2.2 ms vs 5.0 ms through OpenCV on this 2-core machine) but
    leaves its SIMD path above 4096 px wide (8K: 55 ms); there, I420 planes + cv2.cvtColor take 25 ms
    (bench/results_decode.md). So: swscale up to 4096 px, OpenCV beyond.
    """
    if (
        frame.width > SWSCALE_MAX_WIDTH_PX
        and frame.format.name in ("yuv420p", "yuvj420p")
        and frame.width % 2 == 0
        and frame.height % 2 == 0
    ):
        planes = frame.to_ndarray()  # (h * 3 / 2, w) I420, strides removed
        return np.asarray(cv2.cvtColor(planes, cv2.COLOR_YUV2BGR_I420), dtype=np.uint8)
    return np.asarray(frame.to_ndarray(format="bgr24"), dtype=np.uint8)


_CROP_FORMATS = ("yuv420p", "yuvj420p")
SCRATCH_FRAMES = 16  # crop_to_bgr's reusable frames kept (one per crop size) ...
SCRATCH_FRAME_AREAS = 1  # ... holding at most this many source frames' pixels together (beyond the newest)


def _plane_views(frame: av.VideoFrame) -> list[NDArray[np.uint8]]:
    """(h, w) uint8 views of the planes of a planar 8-bit frame (no copy; line padding cut off)."""
    return [
        np.frombuffer(memoryview(p), np.uint8).reshape(p.height, p.line_size)[:, : p.width]
        for p in frame.planes
    ]


def crop_to_bgr(
    frame: av.VideoFrame, x0: int, y0: int, x1: int, y1: int, scratch: list[av.VideoFrame] | None = None
) -> NDArray[np.uint8] | None:
    """`to_bgr(frame)[y0:y1, x0:x1]`, bit-identical, converting only that region; None for a frame that is not
    4:2:0 8-bit (yuv420p/yuvj420p) with even size. x0, y0 must be even; x1, y1 even or the frame's width/height.

    Why: the VAC reads a small part of a 4K frame when low (a 640x480 view at z = 50 m, yaw 30 deg, of 471 m
    footage reads 512x474 px, 3 % of it), and converting all of it costs 2-4.5 ms here. The 4:2:0 planes are cropped with numpy views at
    an even offset (chroma stays on its 2x2 grid) and converted by the same converter as `to_bgr` (swscale via a
    reusable frame, or OpenCV above SWSCALE_MAX_WIDTH_PX), both of which convert each pixel from its own Y and its
    2x2 block's U, V, so the crop equals the crop of the full conversion (tests/test_sim_speed_paths.py).
    `scratch`: a list the caller keeps between calls (holds up to SCRATCH_FRAMES reusable frames, one per size).
    """
    w, h = frame.width, frame.height
    if frame.format.name not in _CROP_FORMATS or w % 2 or h % 2:
        return None
    if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h) or x0 % 2 or y0 % 2 or x1 % 2 or y1 % 2:
        raise ValueError(f"crop ({x0}, {y0})-({x1}, {y1}) must be even and inside the {w}x{h} frame")
    cw, ch = x1 - x0, y1 - y0
    yp, up, vp = _plane_views(frame)
    ys, cs = np.s_[y0:y1, x0:x1], np.s_[y0 // 2 : y1 // 2, x0 // 2 : x1 // 2]
    if w > SWSCALE_MAX_WIDTH_PX:  # to_bgr converts these with OpenCV: same here, on a packed I420 crop
        buf = np.empty((ch * 3 // 2, cw), np.uint8)
        buf[:ch] = yp[ys]
        flat = buf.reshape(-1)
        n = (ch // 2) * (cw // 2)
        flat[ch * cw : ch * cw + n] = up[cs].reshape(-1)
        flat[ch * cw + n :] = vp[cs].reshape(-1)
        return np.asarray(cv2.cvtColor(buf, cv2.COLOR_YUV2BGR_I420), dtype=np.uint8)
    # one reusable frame per crop size (each keeps its own swscale context): several views sharing one decoder
    # (viva_sitl.gym's vector env) read crops of different sizes in turn
    box = scratch if scratch is not None else []
    small = next((f for f in box if (f.width, f.height, f.format.name) == (cw, ch, frame.format.name)), None)
    if small is None:
        import av

        small = av.VideoFrame(cw, ch, frame.format.name)
        box.append(small)
        # bounded: at most SCRATCH_FRAMES frames and, beyond the newest, SCRATCH_FRAME_AREAS source frames of pixels
        while len(box) > 1 and (
            len(box) > SCRATCH_FRAMES or sum(f.width * f.height for f in box) > SCRATCH_FRAME_AREAS * w * h
        ):
            del box[0]
    # the same conversion matrix and range as the decoded frame
    small.colorspace, small.color_range = frame.colorspace, frame.color_range
    dy, du, dv = _plane_views(small)
    dy[...] = yp[ys]
    du[...] = up[cs]
    dv[...] = vp[cs]
    return np.asarray(small.to_ndarray(format="bgr24"), dtype=np.uint8)


_VIDEO_CAPABILITIES = FootageCapabilities(region=RegionRead.CROP, reduced_copies=True, prefetch=True)


class VideoSource(FootageSource):
    """A video file decoded with PyAV (any FFmpeg-readable codec)."""

    def __init__(self, metadata: FootageMetadata, geometry_factory: Any) -> None:
        """`geometry_factory(width_px, height_px) -> FootageGeometry` is called once the stream size is known."""
        self.metadata = metadata
        self._decoder = _Decoder(Path(metadata.path))
        try:
            self.geometry = geometry_factory(self._decoder.width, self._decoder.height)
        except BaseException:
            self._decoder.close()
            raise
        self._fps = metadata.fps or self._decoder.native_fps
        self._levels: dict[int, _Decoder] = {}
        self._lock = threading.Lock()
        self._closed = False
        self._annotations = AnnotationStore(
            metadata.annotations_path, metadata.annotations_format, self.geometry, metadata.class_names
        )

    @property
    def capabilities(self) -> FootageCapabilities:
        """Crops of the decoded frame, the ingest cache's reduced copies, decoding ahead."""
        return _VIDEO_CAPABILITIES

    @property
    def fps(self) -> float:
        return self._fps

    @property
    def native_fps(self) -> float:
        return self._decoder.native_fps

    @property
    def frame_count(self) -> int:
        return self._decoder.frame_count

    @property
    def frame_size_px(self) -> tuple[int, int]:
        """(width, height) of the decoded level-0 frames."""
        return (self._decoder.width, self._decoder.height)

    @property
    def decoder_stats(self) -> dict[str, int]:
        return {"seeks": self._decoder.seeks, "decoded": self._decoder.decoded}

    @property
    def level_count(self) -> int:
        """1 + the number of reduced-resolution copies (from `viva-sitl footage ingest`)."""
        return 1 + len(self.metadata.levels)

    def frame(self, index: int, level: int = 0) -> NDArray[np.uint8]:
        """Frame `index`; `level` k > 0 reads the ingest cache's 1/2^k resolution copy (when it has one)."""
        index = int(index) % self.frame_count
        with self._lock:
            if self._closed:
                raise FootageError(f"footage {self.metadata.name!r} is closed")
            if level <= 0 or level > len(self.metadata.levels):
                return self._decoder.get(index)
            dec = self._levels.get(level)
            if dec is None:
                dec = self._levels[level] = _Decoder(Path(self.metadata.levels[level - 1]))
            return dec.get(index)

    def frame_region(
        self, index: int, x0: int, y0: int, x1: int, y1: int, level: int = 0
    ) -> NDArray[np.uint8] | None:
        """`frame(index, level)[y0:y1, x0:x1]` (bit-identical), converting only that region of the decoded frame.

        None when the stream is not 4:2:0 8-bit with an even size (use `frame`). x0, y0 even; x1, y1 even or the
        frame's width/height. The whole frame is still decoded (H.264 cannot decode a region).
        """
        index = int(index) % self.frame_count
        with self._lock:
            return self._level_decoder(level).get_region(index, x0, y0, x1, y1)

    def level_size_px(self, level: int) -> tuple[int, int] | None:
        """(width, height) of the ingest cache's level `level` copy (level 0: the source); None without one."""
        if level < 0 or level > len(self.metadata.levels):
            return None
        with self._lock:
            dec = self._level_decoder(level)
            return (dec.width, dec.height)

    def _level_decoder(self, level: int) -> _Decoder:
        """The decoder of level `level` (0 or beyond the copies: the source), opened on first use. Holds the lock."""
        if self._closed:
            raise FootageError(f"footage {self.metadata.name!r} is closed")
        if level <= 0 or level > len(self.metadata.levels):
            return self._decoder
        dec = self._levels.get(level)
        if dec is None:
            dec = self._levels[level] = _Decoder(Path(self.metadata.levels[level - 1]))
        return dec

    def prefetch(self, index: int, level: int = 0, only_next: bool = False) -> None:
        """Decode frame `index` (no conversion) so that a later `frame`/`frame_region` of it returns at once.

        `only_next` (a read-ahead thread's call): decode only when `index` is the frame after the decoder's
        position (or the wrap to frame 0 at the clip's end); a job that ran late, after its caller moved on, is
        skipped instead of seeking (see `_Decoder.is_next`). The check and the decode hold the source's lock."""
        index = int(index) % self.frame_count
        with self._lock:
            if not self._closed:
                dec = self._level_decoder(level)
                if not only_next or dec.is_next(index, self.frame_count):
                    dec.get_raw(index)

    def annotations(self, index: int) -> list[Annotation]:
        return self._annotations.get(int(index) % self.frame_count)

    def close(self) -> None:
        with self._lock:
            if self._closed:
                return
            self._closed = True
            self._decoder.close()
            for dec in self._levels.values():
                dec.close()
            self._levels.clear()
