"""The encoding outputs: H.264 over RTP, JPEG over RTP (RFC 2435), and an MP4 recorder (all PyAV / FFmpeg).

Each output is used by one worker thread of VideoPipeline: `open()` (on the caller's thread, so a bad port or path
fails at start), `write(frame)` per frame (worker thread), `close()` after the worker has been joined.

Timestamps: a frame's presentation time comes from the wall clock at which its pose was sampled
(`FrameMeta.wall_time_s`), in units of 1/fps, strictly increasing. At a steady stream rate the RTP timestamp advances by
exactly 90000/fps per frame; a frame dropped upstream leaves a gap of the same length, so receivers play in real time.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from fractions import Fraction
from pathlib import Path
from typing import Protocol

import av
import cv2
import numpy as np
from numpy.typing import NDArray

from viva_sitl.frame import RenderedFrame
from viva_sitl.video.sdp import h264_sdp, jpeg_sdp, write_sdp

log = logging.getLogger(__name__)

RFC2435_MAX_SIZE_PX = 2040  # RFC 2435 carries width/8 and height/8 in one byte each


class VideoOutput(Protocol):
    """What VideoPipeline drives. Implement it to add an output (tests inject a deliberately slow one)."""

    @property
    def name(self) -> str: ...

    def open(self) -> None: ...

    def write(self, frame: RenderedFrame) -> None: ...

    def close(self) -> None: ...


class PtsClock:
    """Presentation timestamps in units of 1/fps from the frames' pose wall times, strictly increasing."""

    def __init__(self, fps: int) -> None:
        self.fps = fps
        self.time_base = Fraction(1, fps)
        self._t0: float | None = None
        self._last = -1

    def pts(self, wall_time_s: float) -> int:
        if self._t0 is None:
            self._t0 = wall_time_s
        pts = max(self._last + 1, round((wall_time_s - self._t0) * self.fps))
        self._last = pts
        return pts


def _check_size(width: int, height: int, what: str) -> None:
    if width < 16 or height < 16 or width % 2 or height % 2:
        raise ValueError(f"{what}: frame size must be even and >= 16 px, got {width}x{height}")


def _i420_frame(image_bgr: NDArray[np.uint8], pts: int, time_base: Fraction) -> av.VideoFrame:
    # cv2's BGR->I420 (BT.601, limited range like yuv420p) is ~10x faster than PyAV's from_ndarray(bgr24) + swscale
    # (measured 0.5 ms vs 4.7 ms at 1280x720 on this machine).
    i420: NDArray[np.uint8] = cv2.cvtColor(image_bgr, cv2.COLOR_BGR2YUV_I420)  # type: ignore[assignment]
    vf = av.VideoFrame.from_ndarray(i420, format="yuv420p")
    vf.pts = pts
    vf.time_base = time_base
    return vf


def _x264_options(preset: str, gop: int, bitrate_kbps: int, threads: int) -> dict[str, str]:
    return {
        "threads": str(threads),  # 0 = auto
        "preset": preset,
        "tune": "zerolatency",  # no lookahead, no frame threading delay: a frame in, its packets out
        "bf": "0",  # no B-frames
        "g": str(gop),  # keyframe interval: a receiver joining mid-stream gets a picture within gop frames
        "keyint_min": str(gop),
        "sc_threshold": "0",  # keyframes exactly every gop frames
        "maxrate": f"{bitrate_kbps}k",
        "bufsize": f"{max(1, bitrate_kbps // 4)}k",  # 1/4 s of VBV: bounded keyframe bursts
        "x264-params": "repeat-headers=1",  # SPS/PPS in band before every keyframe
    }


# An access unit delimiter NAL (type 9, primary_pic_type 7 = any slice type) appended to every encoded frame.
# Why: FFmpeg-based receivers (PyAV, OpenCV, ffplay) run an H.264 parser that only knows a frame has ended when the
# next one starts, so they show each frame one frame period late (measured: 36 ms median at 30 fps). An AUD marks the
# start of the next access unit, so the parser closes the frame at once (measured: 3.5 ms median). It is a valid NAL
# that every decoder skips; the trailing one simply begins the next access unit.
END_OF_FRAME_AUD = b"\x00\x00\x00\x01\x09\xf0"


def _open_rtp(host: str, port: int, label: str) -> av.container.OutputContainer:
    """FFmpeg's RTP muxer to host:port; a ValueError naming the output when it cannot be opened."""
    try:
        return av.open(f"rtp://{host}:{port}", mode="w", format="rtp")
    except (av.FFmpegError, OSError) as exc:
        raise ValueError(f"{label}: cannot open rtp://{host}:{port}: {exc}") from None


class H264RtpOutput:
    """H.264 (libx264, zero latency, no B-frames, in-band SPS/PPS) over RTP to host:port, payload 96, plus its SDP.

    With `end_of_frame_aud` (default) every frame ends with an access unit delimiter: see END_OF_FRAME_AUD.
    """

    name = "h264_rtp"

    def __init__(
        self,
        host: str,
        port: int,
        width: int,
        height: int,
        fps: int = 30,
        bitrate_kbps: int = 4000,
        gop: int = 30,
        preset: str = "ultrafast",
        sdp_path: str | Path | None = None,
        end_of_frame_aud: bool = True,
        threads: int = 0,
        send_rtp: bool = True,
        packet_sink: Callable[[bytes, int, bool], None] | None = None,
    ) -> None:
        _check_size(width, height, "H.264 RTP")
        self.threads = threads
        # send_rtp False: encode only, for packet_sink (the RTSP server with the RTP/UDP stream switched off)
        self.send_rtp = send_rtp
        if not send_rtp:
            self.name = "h264_rtsp"
        # packet_sink(annexb, RTP time at 90 kHz, keyframe): every encoded frame, exactly as it goes out over RTP (AUD and
        # all), on the encoder's thread; the RTSP server fans these out, so RTP and RTSP share one encode
        self.packet_sink = packet_sink
        self.end_of_frame_aud = end_of_frame_aud
        self.host, self.port = host, port
        self.width, self.height, self.fps = width, height, fps
        self.bitrate_kbps, self.gop, self.preset = bitrate_kbps, gop, preset
        self.sdp_path: Path | None = Path(sdp_path) if sdp_path is not None else None
        self._clock = PtsClock(fps)
        self._container: av.container.OutputContainer | None = None
        self._stream: av.VideoStream | None = None
        self._codec: av.VideoCodecContext | None = None  # send_rtp False: the encoder without a muxer

    def open(self) -> None:
        if not self.send_rtp:
            codec = av.CodecContext.create("libx264", "w")
            assert isinstance(codec, av.VideoCodecContext)
            codec.width, codec.height, codec.pix_fmt = self.width, self.height, "yuv420p"
            codec.framerate = Fraction(self.fps, 1)
            codec.time_base = self._clock.time_base
            codec.bit_rate = self.bitrate_kbps * 1000
            codec.options = _x264_options(self.preset, self.gop, self.bitrate_kbps, self.threads)
            self._codec = codec
            return
        if self.sdp_path is not None:
            self.sdp_path = write_sdp(self.sdp_path, h264_sdp(self.host, self.port, self.fps))
        container = _open_rtp(self.host, self.port, "H.264 RTP")
        stream = container.add_stream("libx264", rate=self.fps)
        stream.width, stream.height, stream.pix_fmt = self.width, self.height, "yuv420p"
        stream.codec_context.time_base = self._clock.time_base
        stream.codec_context.bit_rate = self.bitrate_kbps * 1000
        stream.codec_context.options = _x264_options(self.preset, self.gop, self.bitrate_kbps, self.threads)
        self._container, self._stream = container, stream

    def write(self, frame: RenderedFrame) -> None:
        vf = _i420_frame(frame.image_bgr, self._clock.pts(frame.meta.wall_time_s), self._clock.time_base)
        if self._codec is not None:
            for packet in self._codec.encode(vf):
                self._mux(packet)
            return
        assert self._container is not None and self._stream is not None, "write before open()"
        for packet in self._stream.encode(vf):
            self._mux(packet)

    def _mux(self, packet: av.Packet) -> None:
        sink = self.packet_sink
        if self.end_of_frame_aud or sink is not None:
            data = bytes(packet) + END_OF_FRAME_AUD if self.end_of_frame_aud else bytes(packet)
            if sink is not None:
                tb = packet.time_base or self._clock.time_base
                sink(data, round((packet.pts or 0) * tb * 90_000), bool(packet.is_keyframe))
            if self._container is None:
                return
            if self.end_of_frame_aud:
                out = av.Packet(data)
                out.stream = packet.stream
                out.pts, out.dts, out.time_base = packet.pts, packet.dts, packet.time_base
                out.is_keyframe = packet.is_keyframe
                packet = out
        if self._container is not None:
            self._container.mux(packet)

    def close(self) -> None:
        codec = self._codec
        if codec is not None:
            self._codec = None
            try:
                for packet in codec.encode(None):
                    self._mux(packet)
            except (av.FFmpegError, ValueError) as exc:
                log.debug("H.264 flush: %s", exc)
            return
        container, stream = self._container, self._stream
        if container is None or stream is None:
            return
        try:
            for packet in stream.encode(None):
                self._mux(packet)
        except (av.FFmpegError, ValueError) as exc:  # e.g. nothing was ever encoded
            log.debug("H.264 RTP flush: %s", exc)
        finally:
            self._container = self._stream = None
            container.close()


class MjpegRtpOutput:
    """JPEG over RTP (RFC 2435, payload 26) to host:port, plus its SDP.

    Frames are JPEG-coded by cv2.imencode (libjpeg-turbo: baseline, standard Huffman tables, 4:2:0, which is what
    RFC 2435 type 1 requires) and packetised by FFmpeg's RTP muxer through PyAV (no encoder in between). Measured
    here: 1.0 ms vs 2.2 ms per 640x480 frame for PyAV's mjpeg encoder, which also needs thread_count=1 and
    huffman=default to produce a valid RFC 2435 stream with FFmpeg 8 (see shared/reference/media.md).
    """

    name = "mjpeg_rtp"

    def __init__(
        self,
        host: str,
        port: int,
        width: int,
        height: int,
        fps: int = 30,
        quality: int = 80,
        sdp_path: str | Path | None = None,
    ) -> None:
        _check_size(width, height, "MJPEG RTP")
        if width > RFC2435_MAX_SIZE_PX or height > RFC2435_MAX_SIZE_PX:
            raise ValueError(f"MJPEG RTP (RFC 2435) carries at most 2040x2040 px, got {width}x{height}")
        self.host, self.port = host, port
        self.width, self.height, self.fps, self.quality = width, height, fps, quality
        self.sdp_path: Path | None = Path(sdp_path) if sdp_path is not None else None
        self._clock = PtsClock(fps)
        self._params = [
            cv2.IMWRITE_JPEG_QUALITY,
            int(quality),
            cv2.IMWRITE_JPEG_SAMPLING_FACTOR,
            cv2.IMWRITE_JPEG_SAMPLING_FACTOR_420,
            cv2.IMWRITE_JPEG_OPTIMIZE,
            0,  # standard Huffman tables (RFC 2435 has no way to send others)
        ]
        self._container: av.container.OutputContainer | None = None
        self._stream: av.VideoStream | None = None

    def open(self) -> None:
        if self.sdp_path is not None:
            self.sdp_path = write_sdp(self.sdp_path, jpeg_sdp(self.host, self.port, self.fps))
        container = _open_rtp(self.host, self.port, "MJPEG RTP")
        stream = container.add_stream("mjpeg", rate=self.fps)
        # the RTP muxer takes the RFC 2435 type from the stream's pixel format: yuvj420p -> type 1 (4:2:0)
        stream.width, stream.height, stream.pix_fmt = self.width, self.height, "yuvj420p"
        stream.codec_context.time_base = self._clock.time_base
        stream.codec_context.thread_count = 1
        self._container, self._stream = container, stream

    def write(self, frame: RenderedFrame) -> None:
        assert self._container is not None and self._stream is not None, "write before open()"
        ok, jpg = cv2.imencode(".jpg", frame.image_bgr, self._params)
        if not ok:
            raise RuntimeError("cv2.imencode failed")
        pts = self._clock.pts(frame.meta.wall_time_s)
        packet = av.Packet(jpg.tobytes())
        packet.stream = self._stream
        packet.pts = packet.dts = pts
        packet.time_base = self._clock.time_base
        packet.is_keyframe = True
        self._container.mux(packet)

    def close(self) -> None:
        container = self._container
        self._container = self._stream = None
        if container is not None:
            container.close()


class Mp4Recorder:
    """Records frames to an MP4/MKV/MOV file (libx264, or mpeg4 when libx264 is unavailable).

    Written to `<path>.part` and renamed to `path` by close(): a file at `path` is always complete.
    """

    name = "recorder"

    def __init__(
        self,
        path: str | Path,
        width: int,
        height: int,
        fps: int = 30,
        bitrate_kbps: int = 4000,
        preset: str = "ultrafast",
        codec: str = "libx264",
        threads: int = 0,
    ) -> None:
        _check_size(width, height, "recorder")
        self.threads = threads
        self.path = Path(path)
        self.width, self.height, self.fps = width, height, fps
        self.bitrate_kbps, self.preset, self.codec = bitrate_kbps, preset, codec
        self._clock = PtsClock(fps)
        self._tmp = self.path.with_name(self.path.name + ".part")
        self._container: av.container.OutputContainer | None = None
        self._stream: av.VideoStream | None = None
        self.frames_written = 0

    def open(self) -> None:
        if not self.path.parent.is_dir():
            raise ValueError(f"recorder: directory {str(self.path.parent)!r} does not exist")
        fmt = {".mp4": "mp4", ".mov": "mov", ".mkv": "matroska"}.get(self.path.suffix.lower())
        if fmt is None:
            raise ValueError(f"recorder: {str(self.path)!r} must end in .mp4, .mov or .mkv")
        try:
            container = av.open(str(self._tmp), mode="w", format=fmt)
        except (av.FFmpegError, OSError) as exc:
            raise ValueError(f"recorder: cannot write {str(self._tmp)!r}: {exc}") from None
        codec = self.codec if self.codec in av.codecs_available else "mpeg4"
        stream = container.add_stream(codec, rate=self.fps)
        assert isinstance(stream, av.VideoStream)
        stream.width, stream.height, stream.pix_fmt = self.width, self.height, "yuv420p"
        stream.codec_context.time_base = self._clock.time_base
        stream.codec_context.bit_rate = self.bitrate_kbps * 1000
        if codec == "libx264":
            stream.codec_context.options = {
                "preset": self.preset,
                "tune": "zerolatency",
                "bf": "0",
                "threads": str(self.threads),
            }
        self._container, self._stream = container, stream

    def write(self, frame: RenderedFrame) -> None:
        assert self._container is not None and self._stream is not None, "write before open()"
        vf = _i420_frame(frame.image_bgr, self._clock.pts(frame.meta.wall_time_s), self._clock.time_base)
        for packet in self._stream.encode(vf):
            self._container.mux(packet)
        self.frames_written += 1

    def close(self) -> None:
        container, stream = self._container, self._stream
        self._container = self._stream = None
        if container is None or stream is None:
            return
        try:
            for packet in stream.encode(None):
                container.mux(packet)
            container.close()
        except BaseException:
            container.close()
            self._tmp.unlink(missing_ok=True)
            raise
        if self.frames_written == 0:
            self._tmp.unlink(missing_ok=True)  # nothing recorded: leave no empty file
            return
        os.replace(self._tmp, self.path)
