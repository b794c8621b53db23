"""What the MAVLink camera component needs from the vehicle's camera: the CameraLink protocol and its data types.

A leaf module (no viva_sitl.mavlink imports), so base.py's VehicleLink can name CameraLink without an import cycle.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Protocol
from urllib.parse import urlparse

from pymavlink.dialects.v20 import common as mavlink2

from viva_sitl.frame import FrameMeta

M = mavlink2


class StreamEncoding(enum.Enum):
    H264 = "h264"
    MJPEG = "mjpeg"  # RTP/JPEG (RFC 2435); MAVLink has no code for it: encoding UNKNOWN on the wire


@dataclass(frozen=True)
class VideoStreamSpec:
    """One video stream of the camera."""

    uri: str  # "udp://127.0.0.1:5600" (RTP over UDP) or "rtsp://..." ...
    encoding: StreamEncoding = StreamEncoding.H264
    name: str = "VAC"
    framerate_hz: float = 30.0
    width_px: int = 1280
    height_px: int = 720
    bitrate_bps: int = 4_000_000
    hfov_deg: float = 82.1

    def __post_init__(self) -> None:
        if not self.uri:
            raise ValueError("video stream uri must not be empty")
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError(f"video stream size must be positive, got {self.width_px}x{self.height_px}")

    @property
    def stream_type(self) -> int:
        scheme = urlparse(self.uri).scheme.lower()
        if scheme == "rtsp":
            return M.VIDEO_STREAM_TYPE_RTSP
        if scheme == "tcp":
            return M.VIDEO_STREAM_TYPE_TCP_MPEG
        return M.VIDEO_STREAM_TYPE_RTPUDP

    @property
    def wire_uri(self) -> str:
        """VIDEO_STREAM_INFORMATION.uri: the port alone for RTP/UDP (QGC's reading), the URL otherwise."""
        if self.stream_type == M.VIDEO_STREAM_TYPE_RTPUDP:
            if self.uri.isdigit():
                return self.uri
            port = urlparse(self.uri).port
            if port is not None:
                return str(port)
        return self.uri

    @property
    def wire_encoding(self) -> int:
        return (
            M.VIDEO_STREAM_ENCODING_H264
            if self.encoding == StreamEncoding.H264
            else M.VIDEO_STREAM_ENCODING_UNKNOWN
        )


@dataclass(frozen=True)
class CameraInfo:
    """What CAMERA_INFORMATION and VIDEO_STREAM_INFORMATION say about the camera."""

    width_px: int
    height_px: int
    hfov_deg: float
    streams: tuple[VideoStreamSpec, ...] = ()
    vendor: str = "viva-sitl"
    model: str = "VAC"
    firmware_version: int = 0
    focal_length_mm: float = 0.0  # 0 = unknown
    sensor_width_mm: float = 0.0
    sensor_height_mm: float = 0.0

    def __post_init__(self) -> None:
        if self.width_px <= 0 or self.height_px <= 0:
            raise ValueError(f"camera size must be positive, got {self.width_px}x{self.height_px}")
        if not (math.isfinite(self.hfov_deg) and 0 < self.hfov_deg < 180):
            raise ValueError(f"camera hfov_deg must be in (0, 180), got {self.hfov_deg!r}")


@dataclass(frozen=True)
class CaptureResult:
    """What a capture produced: the saved file and the frame metadata (pose) it was rendered at."""

    ok: bool
    path: str  # absolute path of the saved image ("" when not ok)
    meta: FrameMeta | None = None


# What the camera component advertises when the CameraLink cannot say (viva-sitl's default VAC and RTP port)
DEFAULT_CAMERA_INFO = CameraInfo(
    width_px=640,
    height_px=480,
    hfov_deg=82.1,
    streams=(VideoStreamSpec("udp://127.0.0.1:5600", width_px=640, height_px=480),),
)


class CameraLink(Protocol):
    """The vehicle's camera as the MAVLink camera component sees it (the app implements it).

    `capture_image` is called on a worker thread (never on the event loop): it may encode and write files.
    """

    def camera_info(self) -> CameraInfo: ...
    def capture_image(self, seq: int) -> CaptureResult: ...
