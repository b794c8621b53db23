"""SDP session descriptions for the RTP streams, written by hand: PyAV cannot produce one (FFmpeg's av_sdp_create is
not exposed), and a receiver (QGC, VLC, FFmpeg, GStreamer, OpenCV) needs one to open a plain RTP/UDP stream.

    ffplay -protocol_whitelist file,udp,rtp -fflags nobuffer -flags low_delay viva-sitl-h264-5600.sdp
"""

from __future__ import annotations

import ipaddress
import os
import tempfile
from pathlib import Path

H264_PAYLOAD_TYPE = (
    96  # dynamic payload type (RFC 3551); FFmpeg's RTP muxer uses 96 for the first dynamic stream
)
JPEG_PAYLOAD_TYPE = 26  # static payload type of JPEG (RFC 2435 / RFC 3551)


def _addr_type(host: str) -> str:
    try:
        return "IP6" if ipaddress.ip_address(host).version == 6 else "IP4"
    except ValueError:
        return "IP4"  # a host name


def _session(host: str, name: str) -> list[str]:
    at = _addr_type(host)
    return ["v=0", f"o=- 0 0 IN {at} {host}", f"s={name}", f"c=IN {at} {host}", "t=0 0"]


def h264_sdp(host: str, port: int, fps: int, name: str = "viva-sitl VAC H.264") -> str:
    """SDP of an H.264 RTP stream (payload 96, SPS/PPS in band, so no sprop-parameter-sets are needed)."""
    lines = _session(host, name) + [
        f"m=video {port} RTP/AVP {H264_PAYLOAD_TYPE}",
        f"a=rtpmap:{H264_PAYLOAD_TYPE} H264/90000",
        f"a=fmtp:{H264_PAYLOAD_TYPE} packetization-mode=1",
        f"a=framerate:{fps}",
    ]
    return "\r\n".join(lines) + "\r\n"


def jpeg_sdp(host: str, port: int, fps: int, name: str = "viva-sitl VAC MJPEG") -> str:
    """SDP of a JPEG RTP stream (RFC 2435, static payload 26)."""
    lines = _session(host, name) + [
        f"m=video {port} RTP/AVP {JPEG_PAYLOAD_TYPE}",
        f"a=rtpmap:{JPEG_PAYLOAD_TYPE} JPEG/90000",
        f"a=framerate:{fps}",
    ]
    return "\r\n".join(lines) + "\r\n"


def write_sdp(path: str | Path, text: str) -> Path:
    """Write `text` to `path` atomically (a temp file renamed over it); returns the absolute path."""
    p = Path(path).resolve()
    if not p.parent.is_dir():
        raise ValueError(f"SDP directory {str(p.parent)!r} does not exist")
    fd, tmp = tempfile.mkstemp(prefix=p.name, suffix=".tmp", dir=p.parent)
    try:
        with os.fdopen(fd, "w", newline="") as f:
            f.write(text)
        os.replace(tmp, p)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return p
