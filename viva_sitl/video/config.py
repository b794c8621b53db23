"""VideoConfig: which video outputs run, where they send, and how they encode (the `[video]` TOML table)."""

from __future__ import annotations

import enum
import re
from dataclasses import dataclass, replace

# Each RTP stream uses two UDP ports (RTP on the even port, RTCP on the next one), and a receiver binds both;
# instance i moves both RTP streams by this many ports so that instances never share a port.
RTP_INSTANCE_STRIDE = 4

_TCP_ENDPOINT = re.compile(r"^tcp://(?P<host>[^:/]+|\[[0-9a-fA-F:]+\]):(?P<port>\d+)$")


class FrameEncoding(enum.Enum):
    """How the frame-and-pose socket carries the image (part 3 of a message)."""

    RAW = (
        "bgr24"  # the uint8 BGR pixels, row-major, shape in the metadata: no codec loss, ~2.8 MB at 1280x720
    )
    JPEG = "jpeg"  # a baseline JPEG (cv2.imencode at `jpeg_quality`): ~20x smaller, lossy


@dataclass(frozen=True)
class VideoConfig:
    """The video outputs of one vehicle. Width and height come from the camera, not from here."""

    h264_rtp: bool = True  # H.264 over RTP (QGroundControl's default port 5600)
    mjpeg_rtp: bool = False  # JPEG over RTP (RFC 2435): the low-latency alternative
    frame_socket: bool = True  # ZeroMQ PUB of every frame with its pose (see viva_sitl.video.frame_socket)
    record_path: str = ""  # "" = no recording; else an .mp4 path (written as <path>.part, renamed on stop)
    host: str = "127.0.0.1"  # destination of the RTP streams (IPv4 address or name)
    h264_port: int = 5600  # RTP port of the H.264 stream (RTCP on h264_port + 1)
    mjpeg_port: int = 5602  # RTP port of the MJPEG stream (RTCP on mjpeg_port + 1)
    frame_socket_endpoint: str = "tcp://127.0.0.1:5700"  # ZeroMQ endpoint the PUB socket binds
    frame_socket_encoding: FrameEncoding = FrameEncoding.RAW
    fps: int = 30  # stream rate (frames per second); RTP timestamps advance by 90000 / fps per frame
    bitrate_kbps: int = 4000  # H.264 target bitrate (RTP and recording)
    gop_frames: int = 0  # H.264 keyframe interval in frames; 0 = fps (one keyframe per second)
    x264_preset: str = "ultrafast"  # libx264 preset (tune is always zerolatency, no B-frames)
    x264_threads: int = 0  # libx264 (sliced) threads; 0 = x264's choice (1.5 x cores)
    h264_end_of_frame_aud: bool = True  # end each frame with an AUD: FFmpeg receivers show it ~1 frame sooner
    jpeg_quality: int = 80  # 1..100, MJPEG stream and JPEG frame-socket images
    queue_size: int = (
        2  # frames waiting per output; when full the oldest waiting frame is dropped and counted
    )
    sdp_dir: str = "."  # SDP files are written here (viva-sitl-h264-<port>.sdp, viva-sitl-mjpeg-<port>.sdp)
    stamp_counter: bool = False  # paint the frame counter as a barcode in the top-left corner (see stamp.py)
    # RTSP server of the H.264 stream (video/rtsp.py): rtsp://rtsp_host:rtsp_port/vac, same encode as the RTP stream
    rtsp: bool = False
    rtsp_port: int = 8554  # TCP port (0 = any free port); instance i serves on rtsp_port + i
    rtsp_host: str = "127.0.0.1"  # address the RTSP server binds ("0.0.0.0": every interface)

    def __post_init__(self) -> None:
        if isinstance(
            self.frame_socket_encoding, str
        ):  # accept "raw" / "jpeg" / "bgr24" from code, like TOML
            name = self.frame_socket_encoding
            try:
                enc = (
                    FrameEncoding[name.upper()]
                    if name.upper() in FrameEncoding.__members__
                    else FrameEncoding(name)
                )
            except ValueError:
                raise ValueError(f"video.frame_socket_encoding must be raw or jpeg, got {name!r}") from None
            object.__setattr__(self, "frame_socket_encoding", enc)
        if not self.host:
            raise ValueError("video.host must not be empty")
        for key in ("h264_port", "mjpeg_port"):
            port = getattr(self, key)
            if not (1 <= port <= 65534):
                raise ValueError(f"video.{key} must be in 1..65534 (RTCP uses port + 1), got {port}")
        if self.h264_rtp and self.mjpeg_rtp and abs(self.h264_port - self.mjpeg_port) < 2:
            raise ValueError(
                f"video.h264_port {self.h264_port} and video.mjpeg_port {self.mjpeg_port} overlap "
                "(each RTP stream also uses port + 1 for RTCP)"
            )
        if not (0 <= self.rtsp_port <= 65535):
            raise ValueError(f"video.rtsp_port must be in 0..65535 (0 = any free port), got {self.rtsp_port}")
        if self.rtsp and not self.rtsp_host:
            raise ValueError("video.rtsp_host must not be empty when rtsp is on")
        if self.frame_socket and not self.frame_socket_endpoint:
            raise ValueError("video.frame_socket_endpoint must not be empty when frame_socket is on")
        if not (1 <= self.fps <= 240):
            raise ValueError(f"video.fps must be in 1..240, got {self.fps}")
        if not (50 <= self.bitrate_kbps <= 200_000):
            raise ValueError(f"video.bitrate_kbps must be in 50..200000, got {self.bitrate_kbps}")
        if self.gop_frames < 0:
            raise ValueError(f"video.gop_frames must be >= 0 (0 = fps), got {self.gop_frames}")
        if not (1 <= self.jpeg_quality <= 100):
            raise ValueError(f"video.jpeg_quality must be in 1..100, got {self.jpeg_quality}")
        if not (1 <= self.queue_size <= 16):
            raise ValueError(
                f"video.queue_size must be in 1..16 (small: frames are dropped, not queued), got {self.queue_size}"
            )
        if not (0 <= self.x264_threads <= 16):
            raise ValueError(f"video.x264_threads must be in 0..16 (0 = auto), got {self.x264_threads}")
        if self.x264_preset not in _X264_PRESETS:
            raise ValueError(
                f"video.x264_preset must be one of {', '.join(_X264_PRESETS)}, got {self.x264_preset!r}"
            )
        if self.record_path and not self.record_path.lower().endswith((".mp4", ".mkv", ".mov")):
            raise ValueError(f"video.record_path must end in .mp4, .mkv or .mov, got {self.record_path!r}")

    @property
    def gop(self) -> int:
        """Keyframe interval in frames (a receiver that joins mid-stream shows a picture within this many frames)."""
        return self.gop_frames if self.gop_frames > 0 else self.fps

    def with_instance(self, instance: int) -> VideoConfig:
        """The config of vehicle `instance` (0 = unchanged): RTP ports + 4*i, frame-socket and RTSP TCP ports + i.

        An `ipc://` or `inproc://` frame-socket endpoint gets a "-<i>" suffix instead.
        """
        if instance < 0:
            raise ValueError(f"instance must be >= 0, got {instance}")
        if instance == 0:
            return self
        endpoint = self.frame_socket_endpoint
        m = _TCP_ENDPOINT.match(endpoint)
        if m:
            endpoint = f"tcp://{m.group('host')}:{int(m.group('port')) + instance}"
        elif endpoint:
            endpoint = f"{endpoint}-{instance}"
        record = self.record_path
        if record:
            stem, dot, ext = record.rpartition(".")
            record = f"{stem}-{instance}{dot}{ext}"
        return replace(
            self,
            h264_port=self.h264_port + RTP_INSTANCE_STRIDE * instance,
            mjpeg_port=self.mjpeg_port + RTP_INSTANCE_STRIDE * instance,
            frame_socket_endpoint=endpoint,
            record_path=record,
            rtsp_port=self.rtsp_port + instance if self.rtsp_port else 0,
        )


_X264_PRESETS = (
    "ultrafast",
    "superfast",
    "veryfast",
    "faster",
    "fast",
    "medium",
    "slow",
    "slower",
    "veryslow",
)
