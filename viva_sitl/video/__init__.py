"""Video outputs of the VAC: H.264 and MJPEG over RTP (with SDP files), the frame-and-pose socket, a recorder.

from viva_sitl.video import VideoConfig, VideoPipeline, FrameScheduler, FrameClient
"""

from viva_sitl.video.config import FrameEncoding, VideoConfig
from viva_sitl.video.frame_socket import TOPIC, FrameClient, FramePublisher, decode_message, encode_message
from viva_sitl.video.outputs import H264RtpOutput, MjpegRtpOutput, Mp4Recorder, PtsClock, VideoOutput
from viva_sitl.video.pipeline import FrameScheduler, VideoPipeline
from viva_sitl.video.receiver import RtpReceiver
from viva_sitl.video.sdp import h264_sdp, jpeg_sdp, write_sdp
from viva_sitl.video.stamp import read_counter, stamp_counter

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
