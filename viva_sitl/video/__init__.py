"""Video outputs of the VAC: H.264 and MJPEG over RTP (with SDP files), the frame-and-pose socket, a recorder.

from viva_sitl.video import VideoConfig, VideoPipeline, FrameScheduler, FrameClient

The face loads its parts on first use: `VideoConfig` (what viva_sitl.config needs), the SDP writer and the frame
stamp import at once; the outputs (PyAV), the frame socket (ZeroMQ), the pipeline and the RTP receiver only when one
of their names is asked for, so that importing the configuration never loads PyAV or ZeroMQ.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from viva_sitl.video.config import FrameEncoding, VideoConfig
from viva_sitl.video.sdp import h264_sdp, jpeg_sdp, write_sdp
from viva_sitl.video.stamp import read_counter, stamp_counter

if TYPE_CHECKING:
    from viva_sitl.video.frame_socket import (
        TOPIC,
        FrameClient,
        FramePublisher,
        decode_message,
        encode_message,
    )
    from viva_sitl.video.outputs import H264RtpOutput, MjpegRtpOutput, Mp4Recorder, PtsClock, VideoOutput
    from viva_sitl.video.pipeline import FrameScheduler, VideoPipeline
    from viva_sitl.video.receiver import RtpReceiver

_FRAME_SOCKET = {"TOPIC", "FrameClient", "FramePublisher", "decode_message", "encode_message"}
_OUTPUTS = {"H264RtpOutput", "MjpegRtpOutput", "Mp4Recorder", "PtsClock", "VideoOutput"}
_PIPELINE = {"FrameScheduler", "VideoPipeline"}


def __getattr__(name: str) -> Any:
    if name in _FRAME_SOCKET:
        from viva_sitl.video import frame_socket

        return getattr(frame_socket, name)
    if name in _OUTPUTS:
        from viva_sitl.video import outputs

        return getattr(outputs, name)
    if name in _PIPELINE:
        from viva_sitl.video import pipeline

        return getattr(pipeline, name)
    if name == "RtpReceiver":
        from viva_sitl.video import receiver

        return receiver.RtpReceiver
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = [
    "TOPIC",
    "FrameClient",
    "FrameEncoding",
    "FramePublisher",
    "FrameScheduler",
    "H264RtpOutput",
    "MjpegRtpOutput",
    "Mp4Recorder",
    "PtsClock",
    "RtpReceiver",
    "VideoConfig",
    "VideoOutput",
    "VideoPipeline",
    "decode_message",
    "encode_message",
    "h264_sdp",
    "jpeg_sdp",
    "read_counter",
    "stamp_counter",
    "write_sdp",
]
